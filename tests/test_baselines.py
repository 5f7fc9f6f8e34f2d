"""The baselines (planner.strategy view_circle and random_views) in the same harness as the
NBV planners: the Planner protocol, the motion planner and collision checks, the factors."""

import copy
import dataclasses as dc
import json

import numpy as np
import pytest

from nbvs_drake.config import apply_setting as _set
from nbvs_drake.config import load_scenario
from nbvs_drake.errors import ScenarioError
from nbvs_drake.planning import PlanRequest, make_planner
from nbvs_drake.planning.interface import FACTOR_NAMES
from nbvs_drake.planning.views import director_ray_hits, registration_overlap
from nbvs_drake.world.motion import path_length, rollout, wrap_angle

#: the factors every strategy reports with the deterministic utility
DU_FACTORS = set(FACTOR_NAMES) - {"eu"}


def _request(omap, q0, seed=0):
    return PlanRequest(omap, np.asarray(q0, float), np.random.default_rng(seed))


def _with_scans(omap, scans):
    """The same map as if `scans` scans had been taken."""
    return omap.__class__(omap.spec, omap.model, np.array(omap.logodds), np.array(omap.object_points),
                          scans, omap.wbox_min, omap.wbox_max)


def _scenario(first_scan_map, strategy, **planner):
    sc = copy.deepcopy(first_scan_map[0])
    # the old flat keys, through the migration (config/legacy.py)
    sc = _set(sc, f"planner.strategy={strategy}")
    for k, v in planner.items():
        sc = _set(sc, f"planner.{k}={v}")
    return sc


@pytest.fixture(scope="module")
def circle_planner(kin, first_scan_map):
    return make_planner(_scenario(first_scan_map, "view_circle"), kin)


def _check_plan(pl, omap, q0, res):
    """A plan as random sampling's: collision free, exact controls, the same factors."""
    sc = pl.sc
    assert res.status == "ok" and set(res.factors) == DU_FACTORS and res.factors["metric"] == sc.planner.metric
    obstacles = pl.obstacles.for_map(omap)
    assert obstacles.free(res.q_goal)[0] and obstacles.collision.path_free(res.states)
    end = rollout(np.asarray(q0, float), res.controls, sc.robot.control_dt)[-1]
    np.testing.assert_allclose(end[[0, 1, 3, 4, 5, 6, 7]], res.q_goal[[0, 1, 3, 4, 5, 6, 7]], atol=1e-9)
    assert abs(wrap_angle(end[2] - res.q_goal[2])) < 1e-9
    f = res.factors
    met = pl.evaluator.evaluate(omap, res.q_goal[None])
    un_total = omap.unknown_count()
    assert f["un_total"] == un_total
    info = pl.evaluator.information(omap, res.q_goal[None], met, sc.planner.metric, un_total)[0]
    assert f["info"] == pytest.approx(info)
    assert f["overlap"] == pytest.approx(registration_overlap(met)[0])
    assert f["reg"] == (1.0 if f["overlap"] > sc.planner.overlap_h else 0.0) and f["pos"] == 1.0
    assert f["dist"] == pytest.approx(1 / (1 + path_length(res.states, sc.planner.weights)))
    assert res.utility == pytest.approx(f["pos"] * f["reg"] * f["info"] * f["dist"]) == pytest.approx(f["du"])


def test_circle_views_are_evenly_spaced_and_aimed_at_the_centre(kin, circle_planner, first_scan_map):
    sc = circle_planner.sc
    c = circle_planner.circle()
    centre = (np.array(sc.scene.bbox_min) + np.array(sc.scene.bbox_max)) / 2
    np.testing.assert_allclose(c.centre, centre)
    # automatic range and height: 0.9 m from the centre, the middle of W_box's upper half
    assert (c.n, c.radius, c.height) == (12, pytest.approx(0.9), pytest.approx(0.82))
    rel = c.positions - centre
    np.testing.assert_allclose(np.hypot(rel[:, 0], rel[:, 1]), 0.9)
    np.testing.assert_allclose(c.positions[:, 2], 0.82)
    az = np.arctan2(rel[:, 1], rel[:, 0])
    np.testing.assert_allclose(wrap_angle(np.diff(az)), 2 * np.pi / 12, atol=1e-9)  # counter-clockwise
    # view 0 is the start scan's: at the azimuth of the start state's camera
    cam0 = kin.camera_poses(np.array(sc.robot.start))[0, :3, 3] - centre
    assert abs(wrap_angle(az[0] - np.arctan2(cam0[1], cam0[0]))) < 1e-9
    # every view has an IK solution whose camera is there and whose optical axis passes
    # through the centre, within the working range, free of the table and W_box
    assert all(len(s) >= 1 for s in c.states)
    q = np.array([s[0] for s in c.states])
    X = kin.camera_poses(q)
    assert np.max(np.linalg.norm(X[:, :3, 3] - c.positions, axis=1)) < 0.01
    to_centre = centre - X[:, :3, 3]
    to_centre /= np.linalg.norm(to_centre, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(np.sum(X[:, :3, 2] * to_centre, axis=1), -1, 1))).max() < 2.0
    assert np.all(director_ray_hits(X, sc.scene.bbox_min, sc.scene.bbox_max, 0.4, sc.planner.max_view_distance))
    assert np.all(circle_planner.obstacles.for_map(first_scan_map[1]).free(q))


def test_circle_range_height_and_count_as_configured(kin, first_scan_map):
    sc = _scenario(first_scan_map, "view_circle", circle_views=8, circle_range=0.85, circle_height=0.78)
    c = make_planner(sc, kin).circle()
    rel = c.positions - c.centre
    assert c.n == 8
    np.testing.assert_allclose(np.hypot(rel[:, 0], rel[:, 1]), 0.85)
    np.testing.assert_allclose(c.positions[:, 2], 0.78)
    np.testing.assert_allclose(wrap_angle(np.diff(np.arctan2(rel[:, 1], rel[:, 0]))), np.pi / 4, atol=1e-9)
    X = kin.camera_poses(np.array([s[0] for s in c.states]))
    assert np.max(np.linalg.norm(X[:, :3, 3] - c.positions, axis=1)) < 0.01


def test_view_circle_plans_advance_around_the_circle(circle_planner, first_scan_map):
    """From the first scan's map at the start: view 1; from view 1: view 2 (the state tells
    which views are used); the scan count is a lower bound (a map of 5 scans: view 5); a map
    of 12 scans has used every view: no_candidate."""
    pl = circle_planner
    _, omap = first_scan_map
    c = pl.circle()
    q0 = np.array(pl.sc.robot.start)
    res = pl.plan(_request(omap, q0))
    _check_plan(pl, omap, q0, res)
    assert res.stages["view"] == 1 and res.stages["used"] == 1 and res.stages["remaining"] == 11
    assert res.stages["skipped"] == [] and res.stages["with_path"] == 1
    # the view's state, or (planner.free_goal_heading) its twin with the same camera pose
    kin = circle_planner.evaluator.kin
    np.testing.assert_allclose(kin.camera_poses(res.q_goal[None]), kin.camera_poses(c.states[1][:1]), atol=1e-9)
    res2 = pl.plan(_request(_with_scans(omap, 2), res.q_goal))
    _check_plan(pl, omap, res.q_goal, res2)
    assert res2.stages["view"] == 2 and res2.stages["used"] == 2
    res5 = pl.plan(_request(_with_scans(omap, 5), res2.q_goal))
    assert res5.status == "ok" and res5.stages["view"] == 5
    done = pl.plan(_request(_with_scans(omap, 12), c.states[11][0]))
    assert done.status == "no_candidate" and done.stages["remaining"] == 0


def test_view_circle_skips_views_without_ik_or_in_collision(kin, first_scan_map):
    sc = _scenario(first_scan_map, "view_circle")
    pl = make_planner(sc, kin)
    c = pl.circle()
    in_table = np.array([0.0, 0.0, 0.0, 0.0, 0.5, -0.3, -0.3, 0.0])  # the base inside the table
    states = list(c.states)
    states[1], states[2] = (), (in_table,)
    pl._circle = dc.replace(c, states=tuple(states))
    _, omap = first_scan_map
    res = pl.plan(_request(omap, sc.robot.start))
    assert res.status == "ok" and res.stages["view"] == 3
    assert res.stages["skipped"] == [[1, "no_ik"], [2, "collision"]]
    assert json.loads(json.dumps(res.to_json()))["stages"]["skipped"] == [[1, "no_ik"], [2, "collision"]]
    pl._circle = dc.replace(c, states=tuple(() for _ in states))
    res = pl.plan(_request(omap, sc.robot.start))
    assert res.status == "no_candidate" and len(res.stages["skipped"]) == 11


def test_random_views_picks_the_first_reachable_collision_free_view_looking_at_wbox(kin, first_scan_map):
    sc = _scenario(first_scan_map, "random_views", n_candidates=300)
    pl = make_planner(sc, kin)
    _, omap = first_scan_map
    q0 = np.array(sc.robot.start)
    res = pl.plan(_request(omap, q0, seed=4))
    _check_plan(pl, omap, q0, res)
    st = res.stages
    assert st["director_ray"] == 300 >= st["position"] >= st["motion_tried"] >= st["with_path"] == 1
    X = kin.camera_poses(res.q_goal[None])
    assert director_ray_hits(X, sc.scene.bbox_min, sc.scene.bbox_max, pl.sampler.z_near, pl.sampler.z_far)[0]
    # the first candidate of the sampled order that passes the position filter and has a path
    cand, _ = pl.sampler.generate(np.random.default_rng(4), omap)
    cand = cand[pl.obstacles.for_map(omap).free(cand)]
    np.testing.assert_allclose(kin.camera_poses(res.q_goal[None]), kin.camera_poses(cand[st["motion_tried"] - 1][None]),
                               atol=1e-9)  # the candidate, or its twin with the same view (free_goal_heading)
    # not the best view: no ranking
    infos = pl.evaluator.information(omap, cand, pl.evaluator.evaluate(omap, cand), sc.planner.metric,
                                     omap.unknown_count())
    assert res.factors["info"] < infos.max()


def test_baselines_with_the_expected_utility_as_a_feasibility_check(kin, first_scan_map):
    sc = _scenario(first_scan_map, "view_circle", utility="eu", eu_samples=100)
    sc.noise.sigma_v = sc.noise.sigma_w = 0.0
    _, omap = first_scan_map
    res = make_planner(sc, kin).plan(_request(omap, sc.robot.start))
    assert res.status == "ok" and res.stages["view"] == 1 and res.stages["eu_feasible"] == 1
    assert res.factors["eu"]["feasible"] and res.factors["eu"]["k"] == 100
    assert res.utility == pytest.approx(res.factors["du"], abs=1e-12)  # no noise: EU = DU


@pytest.mark.parametrize("setting, message", [
    ("planner.strategy=nearest", "planner.strategy must be one of random_sampling, ort, view_sampling, "
                                 "view_circle, random_views, oracle, got 'nearest'"),
    ("planner.strategy=!ViewCircle {views: 1}", "planner.strategy.views must be >= 2"),
    ("planner.strategy=!ViewCircle {range: -0.5}", "planner.strategy.range must be > 0 (m) or null"),
    ("planner.strategy=!ViewCircle {height: 0.3}", "planner.strategy.height must be above the table top"),
])
def test_baseline_settings_are_validated(setting, message):
    with pytest.raises(ScenarioError) as e:
        load_scenario(settings=[setting])
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


@pytest.mark.parametrize("settings, message", [
    (["planner.circle_range=0.5"], "planner.strategy.range 0.5 m puts the view circle inside W_box"),
    (["mission.stop_min_surface=0.01"], "mission.stop_min_surface/stop_min_utility stop on the best candidate's"),
    (["mission.stop_min_utility=0.01"], "mission.stop_min_surface/stop_min_utility stop on the best candidate's"),
])
def test_baseline_combinations_that_make_no_sense_are_refused(settings, message):
    with pytest.raises(ScenarioError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        load_scenario(settings=["planner.strategy=view_circle"] + settings)
    load_scenario(settings=settings)  # fine with random sampling


@pytest.mark.parametrize("strategy", ["view_circle", "random_views"])
def test_baseline_reconstructs_end_to_end(tmp_path, strategy):
    from nbvs_drake.app.cli import main
    out = tmp_path / strategy
    assert main(["reconstruct", "--out", str(out), "--quiet", "--set", f"planner.strategy={strategy}",
                 "--set", "mission.max_scans=3", "--set", "planner.n_candidates=300",
                 "--set", "scene.gt_points=8000"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["planner"] == strategy and s["scans"] == 3 and s["stop_reason"] == "max_scans"
    assert s["collisions"] == 0 and s["executed_trajectories"] == 2
    cov = s["coverage_by_scan"]
    assert len(cov) == 3 and cov[-1] > cov[0] > 0
    plans = [json.loads(line)["plan"] for line in (out / "iterations.jsonl").read_text().splitlines()]
    assert [p["status"] for p in plans] == ["ok", "ok", "stop"]
    for p in plans[:2]:
        assert set(p["factors"]) == DU_FACTORS
    if strategy == "view_circle":
        assert [p["stages"]["view"] for p in plans[:2]] == [1, 2]
