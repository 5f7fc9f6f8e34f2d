"""The application: the mission runner and its diagram, the API, the CLI, benchmarks and the warm-up."""
