"""Warms the caches of a fresh install, so that its first run waits for nothing (`make setup`
runs `python -m nbvs_drake.app.warmup`): the motion planner's numba kernels
(`warm_kernels`: planning/path_verdicts.py, planning/certificate.py, KnownSolids.blocked), then
everything else a mission calls (scan integration,
view evaluation, coverage) by a two-scan run of the default scenario, which also puts the
default object's coverage ceiling into its cache (planning/oracle.py)."""

from __future__ import annotations

import time

import numpy as np


def warm_kernels() -> float:
    """Calls every kernel once on the default scene; returns the seconds it took."""
    from ..config import load_scenario
    from ..planning import neighbours, path_verdicts, steer_kernels, tree_growth
    from ..planning.collision import CollisionModel
    from ..world.robot import RobotKinematics
    t = time.perf_counter()
    sc = load_scenario()
    kin = RobotKinematics(sc.robot.urdf)
    cm = CollisionModel(sc, kin)
    cert = cm.certificate
    q = np.array([sc.robot.start, sc.robot.start], float)
    q[1, 0] += 0.3
    rc = steer_kernels.robot_params(sc.robot)
    w = np.asarray(sc.planner.weights, float)
    cm.free(q)
    cm.bulk_classify(q)
    cm.bulk_path(q)
    cm.bulk_edges(q[:1], q[1:], rc)
    steer_kernels.edge_lengths(q[:1], q[1:], w, rc)
    neighbours.knn(q, q, w, 1, False)
    cert.part_clearances(q)
    path_verdicts.rollout_verdicts(np.ascontiguousarray(q[None]), np.arange(len(q)), q,
                                   path_verdicts.states_free(q, *cert.model), *cert.part_box_clearances(q),
                                   *cert.model, cm.counter)
    grid = neighbours.TreeGrid(sc.robot.xy_bounds, len(q))
    grid.insert(q, 1)
    tree_growth.tree_extensions(q, np.full((len(q), cert.margin_size), -1.0), q[1:], w, 1.0, rc, kin.arm_lower,
                                kin.arm_upper,
                         *cert.model, 0.04, cm.counter, *grid.arrays, 1)
    from ..perception.registration import KnownSolids  # the landmarks' occlusion test
    KnownSolids.of(sc.scene).blocked(np.zeros((1, 3)), np.ones((1, 3)), np.ones((1, 1), bool))
    return time.perf_counter() - t


def warm_run() -> float:
    """A two-scan run of the default scenario into a temporary folder; returns its seconds."""
    import tempfile

    from ..config import load_scenario
    from .mission import run_mission
    t = time.perf_counter()
    sc = load_scenario(settings=["mission.max_scans=2", "planner.n_candidates=300"])
    with tempfile.TemporaryDirectory() as tmp:
        run_mission(sc, tmp, verbose=False)
    return time.perf_counter() - t


if __name__ == "__main__":
    from ..errors import quiet_library_logs
    quiet_library_logs()
    print(f"warmup: the motion planner's numba kernels compiled in {warm_kernels():.1f} s", flush=True)
    print(f"warmup: a two-scan run (the other kernels, the default object's ceiling) in {warm_run():.1f} s")
