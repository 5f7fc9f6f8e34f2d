"""How much coverage did re-localisation cost? Re-integrates a run's scans at their TRUE poses.

    python scripts/true_pose_coverage.py RUN_DIR [RUN_DIR ...]

For each run directory written by `nbvs reconstruct` (scenario.yaml, iterations.jsonl) it
renders every scan again from the state the robot really reached (`true_state`; the scene is
the run's own, so each scan is the one the run took), integrates them in order into a fresh
map as if registration had been perfect, and measures coverage as the run does. Prints JSON:
per run the run's coverage, this true-pose coverage, and both per scan.

The difference is what registration errors cost; what remains between the true-pose coverage
and a noise-free run of the same scenario is what the views themselves cost (the robot
looked from where the noise took it, not from where the planner wanted). Without noise both
coverages are the same.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np


def true_pose_coverage(run: Path) -> dict:
    from nbvs_drake.config import load_scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.perception.evaluation import coverage
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.world.objects import build_object, ground_truth_points

    run = Path(run)
    sc = load_scenario(run / "scenario.yaml")
    recs = [json.loads(x) for x in (run / "iterations.jsonl").read_text().splitlines()]
    gt = ground_truth_points(build_object(sc), sc)
    with tempfile.TemporaryDirectory() as tmp:
        renderer = ScanRenderer(sc, Path(tmp))
        omap = OccupancyMap.for_scenario(sc)
        run_cov, true_cov = [], []
        for rec in recs:
            omap = renderer.integrate(omap, renderer.scan(np.asarray(rec["true_state"], float)))
            true_cov.append(round(coverage(gt, omap.object_points)[0], 6))  # the run's "coverage"
            run_cov.append(rec["coverage"])
    return {"run": str(run), "scenario": sc.name, "seed": sc.seed, "scans": len(recs),
            "coverage": run_cov[-1] if recs else None,
            "coverage_true_poses": true_cov[-1] if recs else None,
            "per_scan": {"coverage": run_cov, "coverage_true_poses": true_cov}}


if __name__ == "__main__":
    print(json.dumps([true_pose_coverage(Path(p)) for p in sys.argv[1:]]))
