"""Runs every benchmark and prints one JSON object (`make bench`)."""
import json

from nbvs_drake.app.bench import bench_motion, bench_planning, bench_visibility

print(json.dumps({"visibility": bench_visibility(), "planning": bench_planning(),
                  "motion": bench_motion()}, indent=2))
