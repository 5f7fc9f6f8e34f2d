import signal

import numpy as np
import pytest

from nbvs_drake.config import Scenario, load_scenario
from nbvs_drake.world.robot import RobotKinematics


@pytest.fixture(scope="session")
def kin():
    return RobotKinematics()


@pytest.fixture
def scenario() -> Scenario:
    return load_scenario()


@pytest.fixture(scope="session")
def first_scan_map():
    """The default scene's map after the first scan from the start pose (real rendering), at
    2 cm: the map the tests on it were written for (configurations placed in its free and
    unknown voxels, the noisy scenarios' planner on it). The default's own 1 cm map is run end
    to end by the golden run and test_thin_and_hollow."""
    import tempfile
    from pathlib import Path

    from nbvs_drake.app.diagram import build_mission_diagram
    sc = load_scenario(settings=["mapper.voxel_size=0.02"])
    with tempfile.TemporaryDirectory() as tmp:
        md = build_mission_diagram(sc, Path(tmp), log=None)
        from pydrake.systems.analysis import Simulator
        sim = Simulator(md.diagram)
        sim.Initialize()
        sim.AdvanceTo(0.5 * sc.robot.control_dt)  # the t = 0 scan
        mapper = md.systems["mapper"]
        omap = mapper.GetOutputPort("map").Eval(mapper.GetMyContextFromRoot(sim.get_context()))
    assert omap.scan_count == 1
    return sc, omap


def random_states(kin, n, seed=0):
    rng = np.random.default_rng(seed)
    q = np.empty((n, 8))
    q[:, :2] = rng.uniform(-1.5, 1.5, (n, 2))
    q[:, 2] = rng.uniform(-np.pi, np.pi, n)
    q[:, 3:] = rng.uniform(kin.arm_lower, kin.arm_upper, (n, 5))
    return q


def small_scenario(seed: int = 0, scans: int = 3, n_candidates: int = 600, gt_points: int = 8000) -> Scenario:
    """The default scenario cut down for quick end-to-end runs."""
    sc = load_scenario(seed=seed)
    sc.mission.max_scans = scans
    sc.planner.n_candidates = n_candidates
    sc.scene.gt_points = gt_points
    return sc


def drake_free(model, q):
    """Drake's own verdicts (the CollisionModel's checker, no certificate) for states (N, 8)."""
    q = np.atleast_2d(q)
    return np.asarray(model.checker.CheckConfigsCollisionFree(list(model.kin.to_positions(q)), parallelize=False),
                      bool)


def near_contacts(model, q, free, n_pairs=150, steps=24, both=False):
    """States on the free side of a contact (and, with both, on the colliding side too), within
    2^-steps of the segment between a free and a colliding state (bisection with Drake's
    verdicts)."""
    a, b = q[free][:n_pairs], q[~free][:n_pairs]
    m = min(len(a), len(b))
    a, b = a[:m].copy(), b[:m].copy()
    for _ in range(steps):
        mid = 0.5 * (a + b)
        ok = drake_free(model, mid)
        a[ok], b[~ok] = mid[ok], mid[~ok]
    return np.concatenate([a, b]) if both else a


def ctrl_c_as_in_a_terminal():
    """A subprocess' preexec_fn: SIGINT's default action in the child, as a command started in
    a terminal has it (a test suite started in the background, `make test &`, hands SIGINT on
    ignored, and Ctrl-C tests would see the child run on)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
