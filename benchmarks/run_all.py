"""Runs every benchmark and prints one JSON object (`make bench`)."""
import json

from nbvs_drake.bench import bench_visibility

print(json.dumps({"visibility": bench_visibility()}, indent=2))
