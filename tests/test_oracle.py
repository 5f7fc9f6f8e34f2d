"""The ceiling and the greedy oracle (planning/oracle.py)."""

import numpy as np
import pytest

from nbvs_drake.config import Scenario, load_scenario, validate
from nbvs_drake.planning.oracle import TruthScene, coverage_ceiling, newly_covered, reference_samples
from nbvs_drake.world.objects import build_object


def _box_scenario(tmp_path, size=0.2):
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    T = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
         (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    (tmp_path / "cube.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in V)
                                       + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in T))
    sc = Scenario(base_dir=str(tmp_path))
    sc.scene.object.kind = "mesh"
    sc.scene.object.mesh = "cube.obj"
    sc.scene.object.size = size
    return validate(sc)


def test_the_ceiling_of_a_convex_object_is_its_surface_without_the_underside(tmp_path, kin, monkeypatch):
    """A cube on the table: every face but the one it stands on can be seen from some
    reachable pose, and the reference samples already leave out the underside (and the band
    at the table that no scan keeps), so the ceiling is (nearly) all of them; the area those
    samples stand for is the surface minus the underside. Cached: a second call computes nothing."""
    monkeypatch.setenv("NBVS_CACHE", str(tmp_path / "cache"))
    sc = _box_scenario(tmp_path)
    mesh = build_object(sc)
    gt = reference_samples(sc, mesh, 20000)
    lo = mesh.bounds[0]
    assert not np.any(gt[:, 2] < lo[2] + 1e-9)  # no sample on the underside
    # the samples stand for the top and the four sides above the band at the table
    assert np.mean(np.isclose(gt[:, 2], mesh.bounds[1][2])) == pytest.approx(1 / 5, abs=0.02)
    c = coverage_ceiling(sc, kin, mesh, n_poses=400)
    assert c["ceiling"] > 0.99 and c["poses"] == 400 and not c["cached"]
    again = coverage_ceiling(sc, kin, mesh, n_poses=400)
    assert again["cached"] and again["ceiling"] == c["ceiling"]


def test_the_ceiling_of_an_object_with_a_hidden_part_is_below_one(tmp_path, kin, monkeypatch):
    """The bunny: parts under its chin and belly cannot be seen from any pose (measured once
    by a script at 5.3 % of the surface): its ceiling is clearly below 1."""
    monkeypatch.setenv("NBVS_CACHE", str(tmp_path / "cache"))
    sc = load_scenario(None, settings=["scene.object.kind=bunny"])
    c = coverage_ceiling(sc, kin, build_object(sc), n_poses=400)
    assert 0.85 < c["ceiling"] < 0.985


def test_the_oracle_picks_the_reachable_view_that_adds_the_most(first_scan_map, kin):
    """Brute force on a small candidate set (all of them evaluated at full resolution): the
    oracle's pick adds the most ground-truth surface of every candidate it could reach."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.interface import PlanRequest
    _, omap = first_scan_map
    sc = load_scenario(None, settings=["planner.strategy=oracle", "planner.n_candidates=60", "planner.top_k=25",
                                       "scene.gt_points=8000"])
    mesh = build_object(sc)
    planner = make_planner(sc, kin, truth_mesh=mesh)
    q0 = np.array(sc.robot.start, float)
    res = planner.plan(PlanRequest(omap, q0, np.random.default_rng(5)))
    assert res.status == "ok"
    # the same candidates again (same generator draws) and their full-resolution gains
    from nbvs_drake.planning.candidates import free_candidates
    cand = free_candidates(planner.sampler, planner.obstacles.for_map(omap), np.random.default_rng(5), omap, {}, {})
    assert len(cand) <= 4 * sc.planner.top_k  # so every candidate was evaluated in full
    truth = TruthScene(sc, mesh)
    from scipy.spatial import cKDTree
    d, _ = cKDTree(omap.object_points).query(planner.gt, distance_upper_bound=0.0030003)
    todo = np.flatnonzero(~(d <= 0.003))
    gains = np.array([len(newly_covered(truth.object_hits(X), planner.gt, todo)) for X in kin.camera_poses(cand)])
    reach = np.array([f is not None for f in planner.motion.connect_many(q0, cand, planner.obstacles.for_map(omap),
                                                                           np.random.default_rng(0))])
    i = int(np.flatnonzero(np.all(np.isclose(cand, res.q_goal), axis=1))[0])
    assert reach[i] and gains[i] == gains[reach].max()
    assert res.utility == pytest.approx(gains[i] / len(planner.gt))


def test_the_oracles_coverage_never_falls(tmp_path):
    from nbvs_drake.app.mission import run_mission
    sc = load_scenario(None, settings=["planner.strategy=oracle", "planner.n_candidates=500", "mission.max_scans=4",
                                       "scene.gt_points=6000", "mission.coverage_ceiling=false"])
    s = run_mission(sc, tmp_path / "run", verbose=False)
    cov = s["coverage_by_scan"]
    assert len(cov) == 4 and all(b >= a for a, b in zip(cov, cov[1:])) and cov[-1] > cov[0] + 0.3
    assert s["coverage_ceiling"] is None
