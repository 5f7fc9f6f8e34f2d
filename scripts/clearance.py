"""Closest approach of the executed (true) motions to the true world, per trajectory.

    python scripts/clearance.py RUN_DIR [RUN_DIR ...]

For each run directory written by `nbvs reconstruct` (its scenario.yaml is the resolved scenario;
scene/object.obj is the true object) it recomputes, with Drake's
SceneGraphCollisionChecker.CalcRobotClearance, the smallest signed distance between the robot
and the environment (table, chairs, the real object) over every executed state, and prints
JSON: per run the minimum per trajectory and over the run. A collision is a distance <= 0.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from nbvs_drake.config import load_scenario
from nbvs_drake.planning.collision import CollisionModel
from nbvs_drake.robot import RobotKinematics


def run_clearance(run: Path, influence: float = 1.0) -> dict:
    sc = load_scenario(run / "scenario.yaml")
    kin = RobotKinematics(sc.robot.urdf)
    model = CollisionModel(sc, kin, object_obj=str(run / "scene" / "object.obj"))
    per_traj = []
    for line in (run / "iterations.jsonl").read_text().splitlines():
        it = json.loads(line)
        path = np.asarray(it.get("executed_path") or [], float)
        if len(path) == 0:
            continue
        d = []
        for q in kin.to_positions(path):
            c = model.checker.CalcRobotClearance(q, influence)
            dist = c.distances()
            d.append(float(dist.min()) if len(dist) else influence)
        per_traj.append(min(d))
    return {"run": str(run), "scenario": sc.name, "seed": sc.seed,
            "trajectories": len(per_traj), "min_clearance_m": min(per_traj) if per_traj else None,
            "per_trajectory_m": [round(v, 4) for v in per_traj]}


if __name__ == "__main__":
    print(json.dumps([run_clearance(Path(p)) for p in sys.argv[1:]], indent=1))
