"""Compiles the motion planner's numba kernels (planning/bulk.py, planning/clearance.py; and
registration.KnownSolids.blocked) into
numba's on-disk cache, each called once with the types a mission gives it
(`nbvs_drake.warmup`, which `make setup` runs, calls it and then a two-scan run)."""

from __future__ import annotations

import time

import numpy as np


def warm_kernels() -> float:
    """Calls every kernel once on the default scene; returns the seconds it took."""
    from ..config import load_scenario
    from ..robot import RobotKinematics
    from . import bulk
    from .collision import CollisionModel
    t = time.perf_counter()
    sc = load_scenario()
    kin = RobotKinematics(sc.robot.urdf)
    cm = CollisionModel(sc, kin)
    cert = cm.certificate
    q = np.array([sc.robot.start, sc.robot.start], float)
    q[1, 0] += 0.3
    rc = bulk.robot_params(sc.robot)
    w = np.asarray(sc.planner.weights, float)
    cm.free(q)
    cm.bulk_classify(q)
    cm.bulk_path(q)
    cm.bulk_edges(q[:1], q[1:], rc)
    bulk.edge_lengths(q[:1], q[1:], w, rc)
    bulk.knn(q, q, w, 1, False)
    c, r = cert.part_clearances(q)
    bulk.rollout_verdicts(np.ascontiguousarray(q[None]), q, c, r, *cert.model, cm.counter)
    grid = bulk.TreeGrid(sc.robot.xy_bounds, len(q))
    grid.insert(q, 1)
    bulk.tree_extensions(q, np.full((len(q), cert.margin_size), -1.0), q[1:], w, 1.0, rc, kin.arm_lower, kin.arm_upper,
                         *cert.model, 0.04, cm.counter, *grid.arrays, 1)
    from ..registration import KnownSolids  # mission.landmark_occlusion's segment test
    KnownSolids.of(sc).blocked(np.zeros((1, 3)), np.ones((1, 3)), np.ones((1, 1), bool))
    return time.perf_counter() - t


if __name__ == "__main__":
    print(f"warmup: the motion planner's numba kernels compiled in {warm_kernels():.1f} s")
