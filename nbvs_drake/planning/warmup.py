"""Compiles the numba kernels into numba's on-disk cache, so that the first run of a fresh
install does not wait for them (`make setup` runs `python -m nbvs_drake.planning.warmup`):
the motion planner's (planning/bulk.py, planning/clearance.py), each called once with the
types a mission gives it, then everything else a mission calls (scan integration, view
evaluation, coverage) by a two-scan run of the default scenario, which also puts the default
object's coverage ceiling into its cache (planning/oracle.py)."""

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
    bulk.tree_extensions(q, 1, q[1:], w, 1.0, rc, kin.arm_lower, kin.arm_upper, *cert.model, 0.04, bulk.STRIDE,
                         cm.counter)
    return time.perf_counter() - t


def warm_run() -> float:
    """A two-scan run of the default scenario into a temporary folder; returns its seconds."""
    import tempfile

    from ..config import load_scenario
    from ..mission import run_mission
    t = time.perf_counter()
    sc = load_scenario(settings=["mission.max_scans=2", "planner.n_candidates=300"])
    with tempfile.TemporaryDirectory() as tmp:
        run_mission(sc, tmp, verbose=False)
    return time.perf_counter() - t


if __name__ == "__main__":
    print(f"warmup: the motion planner's numba kernels compiled in {warm_kernels():.1f} s", flush=True)
    print(f"warmup: a two-scan run (the other kernels, the default object's ceiling) in {warm_run():.1f} s")
