"""What a run writes and shows: plots, the replay, Meshcat drawing, screenshots, the wiring picture, diagnostics."""
