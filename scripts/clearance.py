"""Closest approach of the executed (true) motions to the true world, per trajectory.

    python scripts/clearance.py RUN_DIR [RUN_DIR ...]

For each run directory written by `nbvs reconstruct` (its scenario.yaml is the resolved
scenario; scene/object.obj is the true object) it recomputes with Drake's SceneGraph
(signed distances between the robot's collision geometries and the environment's: the table,
chairs and the real object as the CollisionMonitor sees it; not the floor the wheels stand on)
the smallest distance over every executed state, and prints JSON: per run the minimum per
trajectory and over the run, and which environment geometry it was. A collision is <= 0.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def run_clearance(run: Path, influence: float = 1.0) -> dict:
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.collision import CollisionModel
    from nbvs_drake.world.robot import RobotKinematics

    sc = load_scenario(run / "scenario.yaml")
    kin = RobotKinematics(sc.robot.urdf)
    # the world the CollisionMonitor checks: robot, environment, the true object
    model = CollisionModel(sc, kin, object_obj=str(run / "scene" / "object.obj"))
    diagram, plant = model.diagram, model.diagram.plant()
    robot = model.checker.robot_model_instances()[0]
    ctx = diagram.CreateDefaultContext()
    pctx = plant.GetMyContextFromRoot(ctx)
    sg = diagram.scene_graph()
    sgctx = sg.GetMyContextFromRoot(ctx)
    port = sg.get_query_output_port()
    inspector = port.Eval(sgctx).inspector()

    def is_robot(gid):
        body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        return body is not None and body.model_instance() == robot

    per_traj, nearest = [], []
    for line in (run / "iterations.jsonl").read_text().splitlines():
        path = np.asarray(json.loads(line).get("executed_path") or [], float)
        if len(path) == 0:
            continue
        best, what = influence, ""
        for q in kin.to_positions(path):
            plant.SetPositions(pctx, robot, q)
            for p in port.Eval(sgctx).ComputeSignedDistancePairwiseClosestPoints(influence):
                ra, rb = is_robot(p.id_A), is_robot(p.id_B)
                if ra == rb:
                    continue
                env = p.id_B if ra else p.id_A
                name = inspector.GetName(env)
                if "floor" in name or p.distance >= best:
                    continue
                best, what = float(p.distance), name
        per_traj.append(best)
        nearest.append(what)
    i = int(np.argmin(per_traj)) if per_traj else None
    return {"run": str(run), "scenario": sc.name, "seed": sc.seed, "trajectories": len(per_traj),
            "min_clearance_m": per_traj[i] if per_traj else None,
            "nearest": nearest[i] if per_traj else None,
            "per_trajectory_m": [round(v, 4) for v in per_traj]}


if __name__ == "__main__":
    print(json.dumps([run_clearance(Path(p)) for p in sys.argv[1:]]))
