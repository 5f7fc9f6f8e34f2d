import copy

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from nbvs_drake.config import Expected, Ort, RandomSampling, Roadmap, ViewSampling
from nbvs_drake.mapping import view_metrics as K
from nbvs_drake.planning import PlanRequest, make_planner
from nbvs_drake.planning.utility import ExpectedUtilityScore
from nbvs_drake.planning.views import director_ray_hits, registration_overlap
from nbvs_drake.systems.messages import Belief, PlanReport
from nbvs_drake.systems.nbvs_planner import NBVSPlanner
from nbvs_drake.world.motion import (
    detour_waypoints,
    path_length,
    rollout,
    steer,
    steer_arc,
    steer_together,
    steer_via,
    wrap_angle,
)


def _request(omap, q0, seed=0, cov=None):
    return PlanRequest(omap, np.asarray(q0, float), np.random.default_rng(seed), cov)


@pytest.fixture(scope="module")
def planner(kin, first_scan_map):
    sc, _ = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.n_candidates = 1500
    return make_planner(sc, kin)


def test_filter_cascade_stages(planner, first_scan_map, kin):
    sc, omap = first_scan_map
    sc = planner.sc
    q0 = np.array(sc.robot.start)
    res = planner.plan(_request(omap, q0))
    assert res.status == "ok"
    st = res.stages
    # every stage keeps a subset of the previous one
    assert st["sampled"] >= st["director_ray"] == 1500
    assert st["director_ray"] >= st["position"] >= st["registration"] >= st["surface"] >= st["top_k"]
    assert st["top_k"] >= st["with_path"] >= 1
    assert st["top_k"] <= sc.planner.top_k
    # the chosen state: collision free, passes the registration filter, sees unknown space
    f = res.factors
    obstacles = planner.obstacles.for_map(omap)
    assert obstacles.free(res.q_goal)[0]
    assert f["overlap"] > sc.planner.overlap_h and f["un_o"] > 0
    assert f["metric"] == sc.planner.metric
    assert res.utility == pytest.approx(f["pos"] * f["reg"] * f["info"] * f["dist"])
    assert f["dist"] == pytest.approx(1 / (1 + path_length(res.states, sc.planner.weights)))
    # its controls, replayed without noise, reach it exactly and stay collision free
    end = rollout(q0, res.controls, sc.robot.control_dt)[-1]
    np.testing.assert_allclose(end[:2], res.q_goal[:2], atol=1e-9)
    assert abs(wrap_angle(end[2] - res.q_goal[2])) < 1e-9
    np.testing.assert_allclose(end[3:], res.q_goal[3:], atol=1e-9)
    assert obstacles.collision.path_free(res.states)
    # the metrics of the chosen view agree with a fresh evaluation
    met = planner.evaluator.evaluate(omap, res.q_goal[None])
    assert met[0, K.M_UN_O] == f["un_o"]
    assert registration_overlap(met)[0] == pytest.approx(f["overlap"])


def test_director_ray_filter(kin):
    q = np.array([[-1.45, 0, 0, 0, 0.35, -0.35, -0.25, 0],  # looks at the table
                  [-1.45, 0, np.pi, 0, 0.35, -0.35, -0.25, 0]])  # looks away
    hits = director_ray_hits(kin.camera_poses(q), [-0.4, -0.4, 0.43], [0.4, 0.4, 0.95], 0.4, 5.0)
    np.testing.assert_array_equal(hits, [True, False])


def test_steering_variants_are_exact(scenario):
    rc = scenario.robot
    q0 = np.array([-1.2, 0.3, 0.2, 0.1, 0.4, -0.3, 0.0, 0.0])
    q1 = np.array([0.5, 1.4, -2.8, -0.5, 0.9, 0.2, -0.6, 1.0])
    for kind, U in steer(q0, q1, rc):
        end = rollout(q0, U, rc.control_dt)[-1]
        np.testing.assert_allclose(end[:2], q1[:2], atol=1e-9, err_msg=kind)
        assert abs(wrap_angle(end[2] - q1[2])) < 1e-9
        np.testing.assert_allclose(end[3:], q1[3:], atol=1e-9)
        assert np.all(np.abs(U[:, 0]) <= rc.max_linear_velocity + 1e-12)
        assert np.all(np.abs(U[:, 1]) <= rc.max_angular_velocity + 1e-12)
        assert np.all(np.abs(U[:, 2:]) <= rc.max_arm_velocity + 1e-12)
        # turn-drive-turn: never turning and driving in the same step
        assert not np.any((U[:, 0] != 0) & (U[:, 1] != 0))


def test_arc_steering_is_exact_and_shorter_where_the_base_would_turn_the_same_way_twice(scenario):
    """Turn-arc-turn: exact under the Euler model within the velocity limits; where
    turn-drive-turn turns the same way before and after driving (the base circling the
    table), it is shorter in eq. 8; where the turns have opposite signs there is no arc."""
    rc, w = scenario.robot, scenario.planner.weights
    q0 = np.array([-1.4, 0.0, -1.2, 0.1, 0.4, -0.3, 0.0, 0.0])
    rng = np.random.default_rng(0)
    shorter = 0
    for _ in range(40):
        ang = rng.uniform(-2.5, 2.5)
        q1 = np.concatenate([[1.4 * np.cos(np.pi - ang), 1.4 * np.sin(np.pi - ang)], [rng.uniform(-np.pi, np.pi)],
                             rng.uniform(-0.5, 0.5, 5)])
        U = steer_arc(q0, q1, rc)
        if U is None:
            continue
        st = rollout(q0, U, rc.control_dt)
        np.testing.assert_allclose(st[-1, :2], q1[:2], atol=1e-9)
        assert abs(wrap_angle(st[-1, 2] - q1[2])) < 1e-9
        np.testing.assert_allclose(st[-1, 3:], q1[3:], atol=1e-9)
        assert np.all(np.abs(U[:, 0]) <= rc.max_linear_velocity + 1e-12)
        assert np.all(np.abs(U[:, 1]) <= rc.max_angular_velocity + 1e-12)
        assert np.any((U[:, 0] != 0) & (U[:, 1] != 0))  # turning while driving
        tog = path_length(rollout(q0, steer_together(q0, q1, rc), rc.control_dt), w)
        kinds = [kind for kind, _ in steer(q0, q1, rc, w)]
        assert "arc" not in [kind for kind, _ in steer(q0, q1, rc)]
        if path_length(st, w) < tog:
            shorter += 1
            assert kinds[0] == "arc"
        else:  # a sharp turn over a short drive: the arc is offered after 'together'
            assert kinds[:2] == ["together", "arc"]
    assert shorter >= 10
    # turns of opposite signs (right by 0.3 to face the goal, then left by 0.5; backward
    # likewise): turn-drive-turn is as short, no arc
    q0b = q0.copy()
    q0b[2] = 0.3
    assert steer_arc(q0b, np.array([-0.4, 0.0, 0.5] + list(q0[3:])), rc) is None


def test_detour_steering_is_exact_and_passes_its_waypoint(scenario):
    rc = scenario.robot
    q0 = np.array([-1.45, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])
    q1 = np.array([1.45, 0.1, np.pi, 0.2, 0.5, -0.4, -0.2, 0.3])
    ws = detour_waypoints(q0, q1, rc.xy_bounds)
    assert len(ws) == 6
    for w in ws:
        assert np.all((w >= rc.xy_bounds[0]) & (w <= rc.xy_bounds[1]))
        for kind, U in steer_via(q0, q1, w, rc):
            st = rollout(q0, U, rc.control_dt)
            np.testing.assert_allclose(st[-1, :2], q1[:2], atol=1e-9, err_msg=kind)
            assert abs(wrap_angle(st[-1, 2] - q1[2])) < 1e-9
            np.testing.assert_allclose(st[-1, 3:], q1[3:], atol=1e-9)
            assert np.min(np.linalg.norm(st[:, :2] - w, axis=1)) < 1e-9
            assert np.all(np.abs(U[:, 0]) <= rc.max_linear_velocity + 1e-12)
            assert np.all(np.abs(U[:, 1]) <= rc.max_angular_velocity + 1e-12)
            assert np.all(np.abs(U[:, 2:]) <= rc.max_arm_velocity + 1e-12)
            assert not np.any((U[:, 0] != 0) & (U[:, 1] != 0))


def test_the_motion_planner_drives_around_the_table_to_the_far_side(planner, first_scan_map):
    """From the start, a view of the object's far side: every direct steering path drives
    through the table; a detour reaches it without the RRT (the default has none)."""
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    sc, omap = first_scan_map
    assert sc.planner.rrt_max_nodes() == 0
    obst = PlanningObstacles(sc, planner.motion.kin).for_map(omap)
    q0 = np.array(sc.robot.start)
    q1 = np.array([1.45, 0.0, np.pi] + list(q0[3:]))  # the start's pose mirrored across the table
    assert obst.free(q1[None])[0]
    direct = [planner.motion.path_free(rollout(q0, U, sc.robot.control_dt), obst) for _, U in steer(q0, q1, sc.robot)]
    assert not any(direct)
    found = planner.motion.connect(q0, q1, obst, np.random.default_rng(0))
    assert found is not None and found[0].startswith("detour")
    assert planner.motion.path_free(found[2], obst)
    np.testing.assert_allclose(found[2][-1, :2], q1[:2], atol=1e-9)


def test_free_goal_heading_reaches_the_same_view_by_a_path_no_longer(planner, first_scan_map, kin):
    """planner.free_goal_heading: the path to each goal may end with the base turned about the
    arm's first joint (the same camera pose); it is free by the planner's own check, and no
    longer than the path to the goal itself."""
    from nbvs_drake.planning.motion_planner import MotionPlanner, PlanningObstacles
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    obst = PlanningObstacles(sc, kin).for_map(omap)
    rng = np.random.default_rng(5)
    goals = planner.generator.generate(rng, omap)[0]
    goals = goals[obst.free(goals)][:12]
    q0 = np.array(sc.robot.start)
    sc.planner.steering.arcs, sc.planner.motion_planner.free_goal_heading = True, False
    plain = MotionPlanner(sc, kin, planner.motion.sampler).connect_many(q0, goals, obst, np.random.default_rng(0))
    sc2 = copy.deepcopy(sc)
    sc2.planner.motion_planner.free_goal_heading = True
    mp = MotionPlanner(sc2, kin, planner.motion.sampler)
    turned = mp.connect_many(q0, goals, obst, np.random.default_rng(0))
    w, moved = sc.planner.weights, 0
    for g, a, b in zip(goals, plain, turned):
        if a is None:
            continue
        assert b is not None and mp.path_free(b[2], obst)
        np.testing.assert_allclose(kin.camera_poses(b[2][-1:])[0], kin.camera_poses(g[None])[0], atol=1e-9)
        if a[0] in ("together", "arc"):
            assert path_length(b[2], w) <= path_length(a[2], w) + 1e-9
        moved += not np.allclose(b[2][-1], g, atol=1e-6)
    assert moved >= 3


def test_path_length_eq8():
    w = [10, 10, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05]
    s = np.zeros((3, 8))
    s[1, 0] = 1.0  # 1 m in x
    s[2, 0] = 1.0
    s[2, 2] = 2 * np.pi - 0.1  # wraps to -0.1 rad
    assert path_length(s, w) == pytest.approx(np.sqrt(10) + np.sqrt(0.5) * 0.1)


def test_planner_system_plans_after_a_scan_and_stops_at_the_budget(planner, first_scan_map):
    sc, omap = first_scan_map
    q0 = np.array(sc.robot.start)
    sys_ = NBVSPlanner.for_scenario(sc, planner, q0)
    sim = Simulator(sys_)
    ctx = sim.get_mutable_context()
    port = sys_.GetInputPort("map").FixValue(ctx, AbstractValue.Make(omap))
    sys_.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(Belief.exact(q0)))
    sim.AdvanceTo(0.05)
    tau = sys_.GetOutputPort("controls").Eval(ctx)
    rep: PlanReport = sys_.GetOutputPort("report").Eval(ctx)
    assert isinstance(rep, PlanReport) and rep.scan == 1 and rep.status == "ok" and rep.plan_id == 1
    assert tau.plan_id == 1 and tau.m == rep.result["n_controls"] > 0
    np.testing.assert_allclose(tau.states[0], q0)
    assert sys_.GetOutputPort("stopped").Eval(ctx)[0] == 0
    sim.AdvanceTo(0.35)  # same scan: no re-planning
    assert sys_.GetOutputPort("controls").Eval(ctx).plan_id == 1
    # a map that has reached the scan budget stops the mission
    spent = omap.__class__(omap.spec, omap.model, np.array(omap.logodds), np.array(omap.object_points),
                           sc.mission.max_scans, omap.wbox_min, omap.wbox_max)
    port.GetMutableData().set_value(spent)
    sim.AdvanceTo(0.55)
    assert sys_.GetOutputPort("stopped").Eval(ctx)[0] == 1
    rep = sys_.GetOutputPort("report").Eval(ctx)
    assert rep.stop_reason == "max_scans" and rep.to_json()["status"] == "stop"


def _planner_system_after(sc, planner, omap, belief: Belief):
    q0 = np.array(sc.robot.start)
    sys_ = NBVSPlanner.for_scenario(sc, planner, q0)
    ctx = sys_.CreateDefaultContext()
    sys_.GetInputPort("map").FixValue(ctx, AbstractValue.Make(omap))
    sys_.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(belief))
    sim = Simulator(sys_, ctx)
    sim.AdvanceTo(0.05)
    return sys_, sim.get_context(), q0


def _belief(q0, correction=(0.0, 0.0, 0.0), covariance=None):
    from nbvs_drake.world.pose import Correction
    q0 = np.asarray(q0, float)
    cov = np.zeros((3, 3)) if covariance is None else np.asarray(covariance, float)
    return Belief(1, q0, Correction(*correction).apply_state(q0), cov)


def test_planner_plans_from_the_belief_and_applies_the_stop_criteria(planner, first_scan_map):
    from nbvs_drake.world.pose import Correction
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    q0 = np.array(sc.robot.start)
    # the report carries both states of the belief the stop test and the plan start from
    sc.mission.stop_unknown_voxels = omap.unknown_count() + 1
    sys_, ctx, q0 = _planner_system_after(sc, planner, omap, _belief(q0, (0.05, -0.02, 0.1)))
    rep = sys_.GetOutputPort("report").Eval(ctx).to_json()
    assert rep["stop_reason"] == "unknown_below_threshold"
    np.testing.assert_allclose(rep["corrected_state"], Correction(0.05, -0.02, 0.1).apply_state(q0), atol=1e-6)
    np.testing.assert_allclose(rep["believed_state"], q0, atol=1e-9)
    # the plan starts at the corrected state
    sc.mission.stop_unknown_voxels = 0
    sys_, ctx, q0 = _planner_system_after(sc, planner, omap, _belief(q0, (0.05, -0.02, 0.1)))
    tau = sys_.GetOutputPort("controls").Eval(ctx)
    np.testing.assert_allclose(tau.states[0], Correction(0.05, -0.02, 0.1).apply_state(q0))
    sc.mission.stop_min_surface = 0.99  # no view sees 99 % of the unknown voxels
    sys_, ctx, q0 = _planner_system_after(sc, planner, omap, _belief(q0))
    rep = sys_.GetOutputPort("report").Eval(ctx).to_json()
    assert rep["stop_reason"] == "surface_below_threshold" and rep["status"] == "ok"
    assert 0 < rep["factors"]["info"] < 0.99
    assert sys_.GetOutputPort("controls").Eval(ctx).plan_id == 0  # nothing is executed
    sc.mission.stop_min_surface = 0.0
    sc.mission.stop_min_utility = 0.5
    sys_, ctx, q0 = _planner_system_after(sc, planner, omap, _belief(q0))
    assert sys_.GetOutputPort("report").Eval(ctx).stop_reason == "score_below_threshold"


def test_planner_with_expected_utility(kin, first_scan_map):
    import copy
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.n_candidates = 600
    sc.planner.utility = Expected(samples=100)
    sc.noise.sigma_v = sc.noise.sigma_w = 0.0
    pl = make_planner(sc, kin)
    res = pl.plan(_request(omap, sc.robot.start))
    assert res.status == "ok"
    eu = res.factors["eu"]
    assert eu["feasible"] and eu["k"] == 100 and eu["collided_rollouts"] == 0
    assert res.utility == pytest.approx(res.factors["du"], rel=1e-9)  # sigma -> 0: EU = DU
    assert res.stages["eu_feasible"] >= 1 and "expected_utility_s" in res.times


def test_rollout_utility_with_and_without_the_registration_factor(planner, first_scan_map):
    """state_utility: with reg (Vasquez-Gomez et al. 2017's g) a state whose simulated scan
    overlaps the known surface by h or less scores 0; without it every state keeps info *
    dist. States that pass the filter score the same."""
    sc, omap = first_scan_map
    sc = planner.sc
    q, _ = planner.generator.generate(np.random.default_rng(3), omap)  # states that look at W_box
    q = q[planner.obstacles.for_map(omap).free(q)][:400]
    un_total = omap.unknown_count()
    h = 0.3  # the noisy scenarios' h (the default scenario, without noise, needs no overlap)
    eu = ExpectedUtilityScore(sc, planner.evaluator, planner.motion, h)
    with_reg = eu.state_utility(omap, q, un_total, 0.5)
    without = eu.state_utility(omap, q, un_total, 0.5, registration=False)
    met = planner.evaluator.evaluate(omap, q)
    passes = registration_overlap(met) > h
    sur = planner.evaluator.information(omap, q, met, sc.planner.metric, un_total)
    np.testing.assert_allclose(without, 0.5 * sur)
    np.testing.assert_allclose(with_reg, np.where(passes, 0.5 * sur, 0.0))
    assert np.any(~passes & (sur > 0)) and np.any(passes & (sur > 0))  # both kinds are in the sample


def test_planner_system_passes_the_belief_covariance_to_the_expected_utility(kin, first_scan_map):
    """The belief's covariance (a scan that could not be registered leaves the belief
    uncertain) reaches the EU: with exact controls the rollouts spread only through the start,
    so the chosen plan's utilities vary and its report gives the start's sigmas."""
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.n_candidates = 600
    sc.planner.utility = Expected(samples=100, weighting="mean", max_collision_rate=0.5)
    sc.noise.sigma_v = sc.noise.sigma_w = 0.0
    pl = make_planner(sc, kin)
    q0 = np.array(sc.robot.start)
    sys_, ctx, _ = _planner_system_after(sc, pl, omap, _belief(q0, covariance=np.diag([1e-4, 1e-4, 0.2 ** 2])))
    rep = sys_.GetOutputPort("report").Eval(ctx).to_json()
    assert rep["status"] == "ok" and rep["start_sigma"] == pytest.approx([0.01, 0.01, 0.2])
    # the rollouts' final states spread: their utilities vary, and their mean is not the DU
    assert rep["factors"]["eu"]["g_std"] > 0 and rep["utility"] != pytest.approx(rep["factors"]["du"], rel=1e-6)
    # a zero covariance (the last scan registered) is an exact start: EU = DU
    sys_, ctx, _ = _planner_system_after(sc, pl, omap, _belief(q0))
    rep = sys_.GetOutputPort("report").Eval(ctx).to_json()
    assert "start_sigma" not in rep and rep["utility"] == pytest.approx(rep["factors"]["du"], rel=1e-9)


def test_no_view_feasible_under_the_noise_stops_the_run_and_says_why(kin, first_scan_map):
    """Reachable candidates that all collide in some rollout under a huge control noise
    (Algorithm 1's any-collision rule): the plan fails with no_feasible, not no_path, and
    the planner system stops with stop_reason no_feasible_under_noise."""
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.n_candidates = 600
    sc.planner.utility = Expected(samples=100, max_collision_rate=0.0)
    sc.planner.overlap_h = 0.3  # the noisy scenarios' registration filter
    sc.planner.metric = "sur"  # the noisy scenarios' metric (with it every top candidate collides here)
    sc.planner.steering.arcs = False  # the noisy scenarios' paths
    if isinstance(sc.planner.motion_planner, Roadmap):
        sc.planner.motion_planner.free_goal_heading = False
    sc.noise.sigma_v, sc.noise.sigma_w = 1.0, 4.0
    pl = make_planner(sc, kin)
    sys_, ctx, _ = _planner_system_after(sc, pl, omap, _belief(sc.robot.start))
    rep = sys_.GetOutputPort("report").Eval(ctx).to_json()
    assert rep["status"] == "no_feasible" and rep["stop_reason"] == "no_feasible_under_noise"
    assert rep["stages"]["with_path"] > 0 and rep["stages"]["eu_feasible"] == 0
    assert sys_.GetOutputPort("stopped").Eval(ctx)[0] == 1.0


def test_ort_with_the_expected_utility(kin, first_scan_map):
    """ORT ranks its vertices by g and scores the best top_k tree paths by the expected
    utility: the chosen vertex is feasible under the noise and its report carries the EU."""
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.strategy = Ort(vertices=300)
    sc.planner.utility = Expected(samples=60, max_collision_rate=0.05)
    sc.planner.top_k = 5
    res = make_planner(sc, kin).plan(_request(omap, sc.robot.start))
    assert res.status == "ok" and res.path_kind == "ort"
    assert res.factors["eu"]["feasible"] and res.factors["eu"]["k"] == 60
    assert res.utility == res.factors["eu"]["eu"] <= res.factors["du"] + 1e-12
    assert res.stages["eu_feasible"] >= 1 and len(res.candidates) >= 1


def test_view_sampling_has_no_registration_filter(kin, first_scan_map):
    sc, _ = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.strategy = ViewSampling()
    assert make_planner(sc, kin).overlap_h is None
    sc.planner.strategy = RandomSampling()
    assert make_planner(sc, kin).overlap_h == sc.planner.overlap_h


def test_surface_metric_and_overlap_count_the_expected_returns(planner, first_scan_map):
    """metric "surface" is the share of a view's rays expected on new surface; the overlap
    counts known-surface rays against those; q is the map's occupied share of seen W_box."""
    from nbvs_drake.mapping.voxel import FREE, OCCUPIED
    from nbvs_drake.planning.views import information, surface_probability
    _, omap = first_scan_map
    c = omap.classes()[omap.in_wbox()]
    q = surface_probability(omap)
    assert q == (c == OCCUPIED).sum() / ((c == OCCUPIED).sum() + (c == FREE).sum()) and 0 < q < 0.2
    states, _ = planner.generator.generate(np.random.default_rng(5), omap)
    met = planner.evaluator.evaluate(omap, states[:300])
    n = len(planner.evaluator.dirs)
    info = information(met, "surface", omap.unknown_count(), n)
    np.testing.assert_allclose(info, met[:, K.M_NEW_EXPECTED] / n)
    assert np.all(met[:, K.M_NEW_EXPECTED] >= met[:, K.M_NEW_RAYS]) and info.max() > 0.01
    ov = registration_overlap(met)
    oc, new = met[:, K.M_OC_RAYS], met[:, K.M_NEW_EXPECTED]
    np.testing.assert_allclose(ov[oc + new > 0], (oc / (oc + new))[oc + new > 0])


def test_surface_factor_ranks_views_as_vuv(planner, first_scan_map):
    """Vasquez-Gomez et al. 2017's surface factor (eq. 6, un_o / un_total) and the ORT paper's
    VUV are the same count over the same constant, so they order every view alike (why the
    metrics experiment has no surface-factor level); FIG, an entropy sum, orders them otherwise."""
    from nbvs_drake.planning.views import information
    _, omap = first_scan_map
    states, _ = planner.generator.generate(np.random.default_rng(7), omap)
    met = planner.evaluator.evaluate(omap, states[:300])
    un_total = omap.unknown_count()
    sur, vuv = information(met, "sur", un_total), information(met, "vuv", un_total)
    np.testing.assert_array_equal(sur, vuv)
    assert sur.max() > 0
    fig = information(met, "fig", un_total)
    assert not np.allclose(fig / fig.max(), sur / sur.max())


def test_the_travel_factor_chooses_only_among_views_of_about_the_best_gain():
    """planner.gain_tolerance: g = gain * dist(x) decides only between views whose gain is at
    least (1 - tolerance) x the best's; 1 is eq. 4 as written, 0 the best gain."""
    from nbvs_drake.planning.interface import PlanResult
    from nbvs_drake.planning.utility import choose

    def view(gain, rho):
        d = 1.0 / (1.0 + rho)
        return PlanResult("ok", utility=gain * d, factors={"info": gain, "dist": d, "rho": rho})

    near, mid, far = view(0.003, 1.0), view(0.0085, 6.0), view(0.010, 20.0)
    views = [near, mid, far]
    assert choose(views, 1.0) is near  # 0.0015 against 0.0012: eq. 4 takes the near, poor view
    assert choose(views, 0.25) is mid  # within 25 % of the best gain, the shorter path
    assert choose(views, 0.1) is far  # only the best gain is within 10 %
    assert choose(views, 0.0) is far
    assert choose([], 0.5) is None


def test_the_planner_picks_within_its_gain_tolerance(kin, first_scan_map):
    """With planner.gain_tolerance, the chosen view's gain is within the tolerance of the best
    gain among the feasible candidates the plan scored, and its utility is the highest of
    those."""
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.planner.n_candidates = 1500
    sc.planner.gain_tolerance = 0.2
    res = make_planner(sc, kin).plan(_request(omap, sc.robot.start))
    assert res.status == "ok" and len(res.alternatives) >= 5
    gains = np.array([r.factors["info"] for r in res.alternatives])
    assert res.factors["info"] >= 0.8 * gains.max() - 1e-15
    within = [r for r, g in zip(res.alternatives, gains) if g >= 0.8 * gains.max()]
    assert res.utility == max(r.utility for r in within)


def test_free_candidates_draw_rounds_until_enough_are_free_among_the_chairs(kin, first_scan_map):
    """planner.free_candidates: among the chairs few draws are free; further rounds of
    n_candidates draws gather at least the number asked (each one free by Drake's own check),
    and 0 keeps the single round, draw for draw."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.candidates import MAX_FREE_ROUNDS, StateSampler, free_candidates
    from nbvs_drake.planning.collision import CollisionModel
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    _, omap = first_scan_map
    sc = load_scenario("cluttered_room_nbvs", settings=["planner.n_candidates=500"])
    sampler = StateSampler(sc, kin)
    paths = PlanningObstacles(sc, kin).for_map(omap).for_paths()
    one = free_candidates(sampler, paths, np.random.default_rng(3), omap, {}, {})
    stages = {}
    again = free_candidates(sampler, paths, np.random.default_rng(3), omap, stages, {}, 0)
    assert np.array_equal(one, again) and "rounds" not in stages and stages["director_ray"] == 500
    assert len(one) < 150  # among the chairs most of 500 draws collide
    want = 3 * len(one) + 1
    stages = {}
    more = free_candidates(sampler, paths, np.random.default_rng(3), omap, stages, {}, want)
    assert len(more) >= want and 1 < stages["rounds"] <= MAX_FREE_ROUNDS
    assert stages["director_ray"] == 500 * stages["rounds"] and stages["position"] == len(more)
    assert np.array_equal(more[:len(one)], one)  # the first round is the single round's
    world = CollisionModel(sc, kin)
    assert np.all(world.free(more[::17]))


def test_arm_clearance_keeps_the_arm_and_camera_off_the_chairs(kin, first_scan_map):
    """planner.obstacles.arm_clearance: the positions and paths keep every robot body this far
    from the environment (the base its own base_clearance): the margin only removes states,
    some near the chairs, and 0 leaves the base-only padding as it was."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.candidates import StateSampler
    from nbvs_drake.planning.collision import CollisionModel
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    _, omap = first_scan_map
    sc0 = load_scenario("cluttered_room_nbvs")
    sc3 = load_scenario("cluttered_room_nbvs", settings=["planner.obstacles.arm_clearance=0.03"])
    q = StateSampler(sc0, kin).sample_states(np.random.default_rng(11), 6000)
    f0 = PlanningObstacles(sc0, kin).for_map(omap).for_paths().free(q)
    f3 = PlanningObstacles(sc3, kin).for_map(omap).for_paths().free(q)
    assert not np.any(f3 & ~f0) and np.count_nonzero(f0 & ~f3) > 0
    # the states the margin removes: free of the chairs themselves, but some robot body other
    # than the base comes within 3 cm of them (the base's own 0.15 m already holds in f0)
    lost = q[f0 & ~f3][:20]
    assert np.all(CollisionModel(sc0, kin).free(lost))
    assert not np.any(CollisionModel(sc0, kin, padding=0.03, base_padding=0.12).free(lost))
    # no arm margin: the base-only padding of before, state for state
    base_only = CollisionModel(sc0, kin, base_padding=0.15)
    paths0 = PlanningObstacles(sc0, kin).for_map(omap).for_paths()
    assert np.array_equal(base_only.free(q[:2000]), paths0.free(q[:2000]))


def test_utility_clearance_keeps_the_rollouts_off_the_chairs(kin, first_scan_map):
    """planner.utility.clearance: a rollout counts as free only where every robot body keeps the
    margin from the environment. A state free of the chairs but within 1 cm of one passes
    Algorithm 1's rule and fails with a 1 cm margin; the recovery paths' check keeps the rule."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.candidates import StateSampler
    from nbvs_drake.planning.collision import CollisionModel
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    from nbvs_drake.world.motion import NU
    _, omap = first_scan_map
    sc0 = load_scenario("cluttered_room_nbvs", settings=["planner.utility.clearance=0.0"])
    sc1 = load_scenario("cluttered_room_nbvs")  # the preset nbvs_room: 1 cm
    assert sc1.planner.utility.clearance == 0.01
    q = StateSampler(sc0, kin).sample_states(np.random.default_rng(5), 4000)
    near = q[CollisionModel(sc0, kin, padding=0.004).free(q) & ~CollisionModel(sc0, kin, padding=0.01).free(q)]
    assert len(near) >= 3  # free by 4 mm, within 1 cm of something
    planner = make_planner(sc1, kin)
    eu = planner.utility
    controls = np.zeros((1, NU))  # standing still: no noise acts, every rollout is the state
    by_margin = {0.0: PlanningObstacles(sc0, kin).for_map(omap), 0.01: PlanningObstacles(sc1, kin).for_map(omap)}
    assert by_margin[0.0].rollouts is None and by_margin[0.01].rollouts is not None
    for x in near[:3]:
        states = np.stack([x, x])
        verdicts = {c: eu._expected_leg(_request(omap, x), controls, states, obstacles, None,
                                        lambda s: np.ones(len(s)), escape=False, k=20).feasible
                    for c, obstacles in by_margin.items()}
        assert verdicts == {0.0: True, 0.01: False}
        # the recovery paths' check (rollouts_free) keeps Algorithm 1's rule
        assert eu.rollouts_free(controls, states, by_margin[0.01], np.zeros((3, 3)), np.random.default_rng(0), 20)


def test_utility_clearance_gives_way_to_algorithm_1_when_nothing_is_feasible(kin, first_scan_map):
    """With a margin no candidate can keep (0.3 m), the plan is made again under Algorithm 1's
    rule: it succeeds, says so, and keeps the first attempt's stages (none feasible)."""
    from nbvs_drake.config import load_scenario
    sc, omap = first_scan_map
    sets = ["mapper.voxel_size=0.02", "planner.n_candidates=600"]
    plain = load_scenario("teapot_eu_mu_nbvs", settings=sets)
    wide = load_scenario("teapot_eu_mu_nbvs", settings=sets + ["planner.utility.clearance=0.3"])
    res0 = make_planner(plain, kin).plan(_request(omap, plain.robot.start))
    res = make_planner(wide, kin).plan(_request(omap, wide.robot.start))
    assert res0.status == "ok" and "clearance" not in res0.factors
    assert res.status == "ok" and res.factors["clearance"] == "dropped"
    assert res.stages["with_clearance"]["eu_feasible"] == 0 and res.stages["eu_feasible"] > 0
