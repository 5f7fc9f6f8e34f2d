"""Collision checks in bulk (planning/path_verdicts.py) and the mission roadmap (planning/roadmap.py):
the bulk verdicts never call free what Drake finds in collision (random and near-contact
states, edges and noisy rollouts, in the cluttered room and with voxel obstacles); every path
the roadmap gives is free by Drake's own check and reaches its goal; a goal that cannot be
reached costs a bounded share of the search; an edge through space found occupied since is not
used."""

import copy

import numba as nb
import numpy as np
import pytest
from conftest import drake_free, near_contacts, random_states

from nbvs_drake.config import Ort, Roadmap, RrtExtExt, load_scenario
from nbvs_drake.errors import ScenarioError
from nbvs_drake.planning import neighbours, path_verdicts, steer_kernels
from nbvs_drake.planning.candidates import StateSampler
from nbvs_drake.planning.certificate import (
    COLLIDING,
    FREE,
    UNKNOWN,
    arm_motion_bound,
    free_margins,
    geometry_reaches,
    model_reach,
    pair_reaches,
    robot_scratch,
    unpack,
)
from nbvs_drake.planning.collision import CollisionModel
from nbvs_drake.planning.motion_planner import MotionPlanner, ObstacleModel
from nbvs_drake.planning.roadmap import GROWTH_SAMPLES
from nbvs_drake.world.motion import rollout, sample_control_noise, steer_together, wrap_angle


@nb.njit
def _margins(q, F, I, H):
    """certificate.free_margins at each state q[n]: (N, 3 + P + 2G) rows of m_env, m_self,
    radius, the pairs' clearances, the geometries' clearances and radii; and the motion bounds
    (model_reach, pair_reaches, geometry_reaches's per-joint reach)."""
    model = unpack(F, I, H)
    s = robot_scratch(model)
    P, G = model[19].shape[0], model[2].shape[0]
    out = np.empty((q.shape[0], 3 + P + 2 * G))
    pc, gc, gr = np.empty(P), np.empty(G), np.empty(G)
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = free_margins(q[i], model, s, pc, gc, gr)
        out[i, 3:3 + P], out[i, 3 + P:3 + P + G], out[i, 3 + P + G:] = pc, gc, gr
    return out, model_reach(model), pair_reaches(model), geometry_reaches(model)[0]


@nb.njit
def _arm_bound(a, b, reach):
    return arm_motion_bound(a, b, reach)


@pytest.fixture(scope="module")
def clutter(kin):
    sc = load_scenario("cluttered_room")
    return sc, CollisionModel(sc, kin)


@pytest.fixture(scope="module")
def voxels(kin, first_scan_map):
    sc, omap = first_scan_map
    return sc, CollisionModel(sc, kin, obstacle_boxes=omap.obstacle_boxes(300)[0])


@pytest.mark.parametrize("world", ["clutter", "voxels"])
def test_bulk_states_and_edges_agree_withdrake_free(kin, world, request):
    sc, model = request.getfixturevalue(world)
    q = random_states(kin, 2000, seed=21)
    free = drake_free(model, q)
    q = np.concatenate([q, near_contacts(model, q, free, n_pairs=200, steps=22, both=True)])
    drake = drake_free(model, q)
    v = model.bulk_classify(q)
    assert not np.any((v == FREE) & ~drake) and not np.any((v == COLLIDING) & drake)
    assert np.mean(v[: 2000] != UNKNOWN) > 0.9  # it decides most states itself
    # edges of the steering function from free states: FREE only when Drake finds every
    # interpolated state free, COLLIDING only when it finds one in collision
    rng = np.random.default_rng(3)
    a = q[: 2000][free][:300]
    b = kin.clip_arm(a + rng.normal(0, 0.4, a.shape))
    verdict = model.bulk_edges(a, b, steer_kernels.robot_params(sc.robot))
    for x, y, ve in zip(a, b, verdict):
        states = CollisionModel.interpolate(rollout(x, steer_together(x, y, sc.robot), sc.robot.control_dt))
        ok = bool(np.all(drake_free(model, states)))
        assert ve != FREE or ok
        assert ve != COLLIDING or not ok
    assert {FREE, COLLIDING} <= set(verdict.tolist())


def test_numba_steering_is_the_motion_models(kin, clutter):
    sc, _ = clutter
    rc, params = sc.robot, steer_kernels.robot_params(sc.robot)
    q = random_states(kin, 60, seed=4)
    for a, b in zip(q[:30], q[30:]):
        c = steer_together(a, b, rc)
        np.testing.assert_allclose(steer_kernels.steer_together(a, b, *params), c, rtol=0, atol=1e-12)
        s = rollout(a, c, rc.control_dt)
        # numpy's SIMD cos, sin
        np.testing.assert_allclose(steer_kernels.rollout(a, c, rc.control_dt), s, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(path_verdicts.interpolate(s, 0.02), CollisionModel.interpolate(s))


def test_rollout_verdicts_agree_withdrake_free(kin, clutter):
    """Noisy rollouts (Table 4) of paths that pass close to the chairs and the table: the
    clearance-bounded verdicts are Drake's wherever they decide."""
    sc, model = clutter
    sampler = StateSampler(sc, kin)
    rng = np.random.default_rng(5)
    goals = sampler.sample_states(rng, 400)
    goals = goals[drake_free(model, goals)]
    start = np.array(sc.robot.start)
    n_checked = n_decided = 0
    cert = model.certificate
    for g in goals[:40]:
        controls = steer_together(start, g, sc.robot)
        nominal = rollout(start, controls, sc.robot.control_dt)
        if not all(drake_free(model, CollisionModel.interpolate(nominal))):
            continue
        eps = sample_control_noise(rng, sc.noise, controls, 40)
        states = rollout(start, controls[None] + eps, sc.robot.control_dt)[:, 1:]
        v = path_verdicts.rollout_verdicts(np.ascontiguousarray(states), np.arange(len(nominal) - 1), nominal[1:],
                                          path_verdicts.states_free(nominal[1:], *cert.model),
                                          *cert.part_box_clearances(nominal[1:]), *cert.model, model.counter)
        drake = drake_free(model, states.reshape(-1, 8)).reshape(v.shape)
        assert not np.any((v == FREE) & ~drake) and not np.any((v == COLLIDING) & drake)
        # a part is tested only against the boxes it may reach: the verdicts of testing all
        c, r, slack = cert.part_box_clearances(nominal[1:])
        every = path_verdicts.rollout_verdicts(np.ascontiguousarray(states), np.arange(len(nominal) - 1),
                                               nominal[1:], path_verdicts.states_free(nominal[1:], *cert.model), c, r,
                                               np.full_like(slack, -np.inf), *cert.model, model.counter)
        np.testing.assert_array_equal(v, every)
        np.testing.assert_array_equal(slack.min(axis=-1), c)
        n_checked += v.size
        n_decided += int(np.sum(v != UNKNOWN))
    assert n_checked > 10_000 and n_decided > 0.95 * n_checked


@pytest.fixture(scope="module")
def roadmap_plan(kin, clutter):
    sc, model = clutter
    sc = copy.deepcopy(sc)
    sc.scene.object.kind, sc.scene.object.size = "bunny", -1
    sc.planner.motion_planner = Roadmap()
    sampler = StateSampler(sc, kin)
    motion = MotionPlanner(sc, kin, sampler)
    rng = np.random.default_rng(1)
    cand, _ = sampler.generate(rng)
    goals = cand[model.free(cand)][:25]
    q0 = np.array(sc.robot.start)
    paths = motion.connect_many(q0, goals, ObstacleModel(model), rng)
    return sc, model, motion, q0, goals, paths


def test_roadmap_paths_are_free_by_drake_and_reach_their_goals(roadmap_plan):
    sc, model, motion, q0, goals, paths = roadmap_plan
    kinds = [p[0] for p in paths if p is not None]
    assert len(kinds) >= 20 and "roadmap" in kinds  # the corridor goals need the roadmap
    for g, p in zip(goals, paths):
        if p is None:
            continue
        kind, controls, states = p
        np.testing.assert_allclose(rollout(q0, controls, sc.robot.control_dt), states, atol=1e-12)
        d = states[-1] - g
        d[2] = wrap_angle(d[2])  # the heading may end a full turn away
        np.testing.assert_allclose(d, 0.0, atol=1e-9)
        assert np.all(drake_free(model, CollisionModel.interpolate(states))), kind


def test_roadmap_is_kept_and_shortens_the_rrts_paths(roadmap_plan, kin):
    """The second plan reuses the roadmap (nothing built); the roadmap's paths are no longer
    (eq. 8) than RRT Ext-Ext's to the same goals (here: a few RRT searches, 2,000 vertices)."""
    sc, model, motion, q0, goals, paths = roadmap_plan
    n = len(motion.roadmap.V)
    motion.connect_many(q0, goals[:5], ObstacleModel(model), np.random.default_rng(2))
    assert motion.last_query.get("built", 0) == 0 and len(motion.roadmap.V) >= n
    rrt_sc = copy.deepcopy(sc)
    rrt_sc.planner.motion_planner = RrtExtExt(max_nodes=2000)
    rrt = MotionPlanner(rrt_sc, kin, motion.sampler)
    via = [i for i, p in enumerate(paths) if p is not None and p[0] == "roadmap"][:3]
    got = rrt.connect_many(q0, goals[via], ObstacleModel(model), np.random.default_rng(3))
    both = [(motion.path_log[i][1], rrt.path_log[j][1]) for j, i in enumerate(via) if got[j] is not None]
    assert both and np.mean([a for a, _ in both]) <= np.mean([b for _, b in both])


def test_an_unreachable_goal_costs_a_bounded_share(kin, clutter):
    """A free goal inside a closed cage of obstacle boxes: the query gives up on it after its
    connection edges and one growth round around it, not a full search."""
    sc, _ = clutter
    sc = copy.deepcopy(sc)
    sc.planner.motion_planner = Roadmap()
    c, h, t, a = np.array([-1.3, 1.3]), 2.2, 0.05, 0.45  # cage centre, wall height, thickness, half width
    walls = [((c[0] + dx * a, c[1] + dy * a, h / 2), (t + 2 * a * abs(dy), t + 2 * a * abs(dx), h))
             for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    walls.append(((c[0], c[1], h + t / 2), (2 * a + t, 2 * a + t, t)))
    lo, hi = np.array(sc.scene.bbox_min), np.array(sc.scene.bbox_max)
    walls.append((tuple((lo + hi) / 2), tuple(hi - lo)))  # W_box, as the plans have it
    model = CollisionModel(sc, kin, obstacle_boxes=walls)
    goal = np.array([c[0], c[1], 0.0, 0.0, np.pi / 2, 0.0, 0.0, 0.0])  # the arm tucked up
    assert model.free(goal[None])[0]
    sampler = StateSampler(sc, kin)
    motion = MotionPlanner(sc, kin, sampler)
    rng = np.random.default_rng(0)
    cand, _ = sampler.generate(rng)
    goals = np.concatenate([cand[model.free(cand)][:6], goal[None]])
    paths = motion.connect_many(np.array(sc.robot.start), goals, ObstacleModel(model), rng)
    assert paths[-1] is None and sum(p is not None for p in paths[:-1]) >= 5
    st = motion.last_query
    k = sc.planner.motion_planner.neighbors
    assert st["grown"] <= GROWTH_SAMPLES * 2  # one growth round, for at most the goals not reached
    # its share: its own connection edges (2k in, and its tucked twin's) and the growth round's
    assert st["edges_checked"] <= 400 + (2 * k + 2 * k) * 2 + GROWTH_SAMPLES * 2 * 2 * k


def test_an_edge_through_space_found_occupied_is_not_used(kin, clutter):
    sc, _ = clutter
    sc = copy.deepcopy(sc)
    sc.scene.clutter = "none"
    sc.planner.motion_planner = Roadmap()
    sampler = StateSampler(sc, kin)
    motion = MotionPlanner(sc, kin, sampler)
    tuck = [0.0, np.pi / 2, 0.0, 0.0, 0.0]
    q0 = np.array([-1.5, 0.0, 0.0] + tuck)
    goal = np.array([1.5, 0.0, 0.0] + tuck)  # across the table: no direct path
    open_world = CollisionModel(sc, kin)
    p1 = motion.connect_many(q0, goal[None], ObstacleModel(open_world), np.random.default_rng(0))[0]
    assert p1 is not None and p1[0] == "roadmap"
    # the map now finds a box where the first path passed, halfway
    mid = p1[2][len(p1[2]) // 2]
    box = [((mid[0], mid[1], 0.6), (0.5, 0.5, 1.2))]
    blocked = CollisionModel(sc, kin, obstacle_boxes=box)
    assert not np.all(blocked.free(CollisionModel.interpolate(p1[2])))
    p2 = motion.connect_many(q0, goal[None], ObstacleModel(blocked), np.random.default_rng(0))[0]
    assert p2 is not None
    assert np.all(drake_free(blocked, CollisionModel.interpolate(p2[2])))


def test_motion_planner_setting_is_checked():
    with pytest.raises(ScenarioError, match="planner.motion_planner"):
        load_scenario(settings=["planner.motion_planner=prm"])
    assert isinstance(load_scenario("cluttered_room").planner.motion_planner, Roadmap)


def test_numba_tree_growth_grows_the_python_growths_tree(kin):
    """The ORT's batched growth in numba (tree_growth.tree_extensions) against rrt.extend_batch: the
    same parents, vertices equal to 1e-12 (numpy's SIMD cos and sin differ from libm's in the
    last bit), the same tree paths."""
    from nbvs_drake.planning.ort import ORTPlanner
    sc = load_scenario()
    sc.planner.strategy = Ort(vertices=400)
    sampler = StateSampler(sc, kin)
    obstacles = ObstacleModel(CollisionModel(sc, kin))
    trees = []
    for bulk_checks in (False, True):
        ort = ORTPlanner(sc, sampler, None, None, MotionPlanner(sc, kin, sampler, bulk_checks=bulk_checks), None, 0.0)
        trees.append(ort.grow(np.array(sc.robot.start), np.random.default_rng(4), obstacles)[0])
    a, b = trees
    assert a.n == b.n == 401
    np.testing.assert_array_equal(a.parent[: a.n], b.parent[: b.n])
    np.testing.assert_allclose(a.q[: a.n], b.q[: b.n], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.cost[: a.n], b.cost[: b.n], rtol=1e-12)
    np.testing.assert_allclose(a.controls_to(a.n - 1), b.controls_to(b.n - 1), rtol=0, atol=1e-12)


def test_expected_utility_with_bulk_rollout_checks_is_algorithm_1s(kin, clutter):
    """The same candidates feasible, with the same expected utility, whether the rollouts are
    checked coarse to fine with the clearance bound or state by state."""
    from nbvs_drake.planning.interface import PlanRequest, PlanResult
    from nbvs_drake.planning.utility import ExpectedUtilityScore
    sc, model = clutter
    sc = copy.deepcopy(sc)
    sc.planner.utility.samples = 120
    sampler = StateSampler(sc, kin)
    rng = np.random.default_rng(8)
    goals = sampler.generate(rng)[0]
    goals = goals[model.free(goals)][:12]
    start = np.array(sc.robot.start)
    obstacles = ObstacleModel(model)
    found = MotionPlanner(sc, kin, sampler).connect_many(start, goals, obstacles, rng)
    verdicts = []
    for bulk_checks in (True, False):
        eu = ExpectedUtilityScore(sc, None, MotionPlanner(sc, kin, sampler, bulk_checks=bulk_checks), None)
        eu.state_utility = lambda omap, s, un_total, dist, registration=True, coarse=False: s[:, 0] * dist
        out = []
        for g, f in zip(goals, found):
            if f is None:
                continue
            cand = PlanResult("ok", g, f[1], f[2], f[0], 1.0, {"dist": 1.0})
            r = eu.expected(PlanRequest(None, start, np.random.default_rng(0)), cand, obstacles, 1)
            out.append((r.feasible, r.value))
        verdicts.append(out)
    assert verdicts[0] == verdicts[1]
    assert {True, False} <= {f for f, _ in verdicts[0]}  # both kinds of candidate are there


def test_cluttered_room_mission_with_the_roadmap(tmp_path):
    """A short cluttered-room mission (the bunny, EU under Table 4 noise, the roadmap): every
    executed path is free by Drake's check of the true scene, and the summary separates motion
    planning from view evaluation."""
    import nbvs_drake
    res = nbvs_drake.reconstruct("cluttered_room", out=tmp_path / "run", seed=2, overrides=[
        "scene.object.kind=bunny", "scene.object.size=-1", "mission.max_scans=3", "planner.n_candidates=800",
        "planner.ray_stride=4", "scene.gt_points=4000", "planner.eu_samples=100"])
    s = res.summary
    assert s["scans"] == 3 and s["collisions"] == 0
    assert s["times_s"]["motion_planning"] > 0 and s["times_s"]["view_evaluation"] > 0
    plans = [r["plan"] for r in res.records if r["plan"].get("status") == "ok"]
    assert plans and all("motion_planning_s" in p["times"] and "eu_checks_s" in p["times"] for p in plans)


@pytest.mark.parametrize("world", ["clutter", "voxels"])
def test_a_free_margin_proves_every_state_within_it_free(kin, world, request):
    """certificate.free_margins: a state with margins (m, m_self) > 0 is FREE by the certificate,
    and so is every state whose points moved less than m (the motion bound, with the base's turn
    weighted by the state's radius) and less than m_self relative to each other; near-contact
    states included."""
    sc, model = request.getfixturevalue(world)
    q = random_states(kin, 1500, seed=5)
    free = drake_free(model, q)
    q = np.concatenate([q, near_contacts(model, q, free, n_pairs=150, steps=12, both=True)])
    m, reach = _margins(q, *model.certificate.model)[:2]
    m = m[:, :3]
    ok = (m[:, 0] > 0) & (m[:, 1] > 0)
    assert ok.mean() > 0.15
    assert np.all(model.certificate.classify(q[ok]) == FREE)
    rng = np.random.default_rng(8)
    moved, checked = [], 0
    for qi, (me, ms, r) in zip(q[ok], m[ok]):
        for _ in range(4):  # a random straight move scaled to use up 0.99 of the tighter margin
            d = rng.normal(0, 1, 8) * np.array([0.05, 0.05, 0.05, 0.1, 0.1, 0.1, 0.1, 0.1])
            b = qi + d
            arm = _arm_bound(qi, b, reach)
            total = np.hypot(d[0], d[1]) + (r + arm) * abs(d[2]) + arm
            f = 0.99 * min(me / total, ms / arm if arm > 0 else np.inf)
            b = qi + f * d
            if np.all(kin.arm_within_limits(b)):
                moved.append(b)
        checked += 1
    moved = np.array(moved)
    assert len(moved) > 500
    assert np.all(model.certificate.classify(moved) == FREE)
    assert np.all(drake_free(model, moved))


@pytest.mark.parametrize("world", ["clutter", "voxels"])
def test_each_pairs_and_geometrys_clearance_proves_every_state_within_it_free(kin, world, request):
    """certificate.free_margins' per-pair and per-geometry clearances: states moved so that
    every robot pair's relative motion bound (`pair_reaches`: only the joints between its two
    geometries) uses up 0.99 of that pair's clearance, and every geometry's own motion bound
    (`geometry_reaches`, its own radius for the base's turn) 0.99 of its clearance to the
    environment, are FREE by the certificate and by Drake, though many move further than the
    whole robot's bound against the least clearances would allow; near-contact states
    included."""
    sc, model = request.getfixturevalue(world)
    q = random_states(kin, 1500, seed=6)
    free = drake_free(model, q)
    q = np.concatenate([q, near_contacts(model, q, free, n_pairs=150, steps=12, both=True)])
    m, reach, W, GW = _margins(q, *model.certificate.model)
    P, G = len(W), len(GW)
    ok = (m[:, 0] > 0) & (m[:, 1] > 0)
    assert np.allclose(m[ok, 1], m[ok, 3:3 + P].min(axis=1))
    assert np.allclose(m[ok, 0], m[ok, 3 + P:3 + P + G].min(axis=1))
    assert np.allclose(m[ok, 2], m[ok, 3 + P + G:].max(axis=1))
    rng = np.random.default_rng(9)
    moved, beyond = [], 0
    for qi, row in zip(q[ok], m[ok]):
        me, ms, r = row[0], row[1], row[2]
        pc, gc, gr = row[3:3 + P], row[3 + P:3 + P + G], row[3 + P + G:]
        for _ in range(4):
            d = rng.normal(0, 1, 8) * np.array([0.05, 0.05, 0.05, 0.1, 0.1, 0.1, 0.1, 0.1])
            arm = _arm_bound(qi, qi + d, reach)
            own = GW @ np.abs(d[3:])
            geo = np.hypot(d[0], d[1]) + (gr + own) * abs(d[2]) + own
            pair = W @ np.abs(d[3:])
            f = 0.99 * min(np.min(gc / geo), np.min(np.where(pair > 0, pc / np.maximum(pair, 1e-300), np.inf)))
            b = qi + f * d
            if np.all(kin.arm_within_limits(b)):
                moved.append(b)
                whole = np.hypot(d[0], d[1]) + (r + arm) * abs(d[2]) + arm
                beyond += f * whole > me or f * arm > ms
    moved = np.array(moved)
    assert len(moved) > 500 and beyond > 0.2 * len(moved)
    assert np.all(model.certificate.classify(moved) == FREE)
    assert np.all(drake_free(model, moved))


@pytest.mark.parametrize("world", ["clutter", "voxels"])
def test_skipping_by_margins_gives_the_verdict_of_every_state(kin, world, request):
    """path_verdicts.path_verdict (states proved free by a neighbour's margin are not visited) against
    the certificate's verdict of every interpolated state, on steering edges from random and
    near-contact states; the undecided states it reports are exactly the certificate's UNKNOWN
    ones."""
    sc, model = request.getfixturevalue(world)
    q = random_states(kin, 600, seed=12)
    free = drake_free(model, q)
    rng = np.random.default_rng(13)
    a = np.concatenate([q[free][:150], near_contacts(model, q, free, n_pairs=80, steps=10, both=False)])
    b = kin.clip_arm(a + rng.normal(0, 0.5, a.shape))
    seen = set()
    for x, y in zip(a, b):
        states = rollout(x, steer_together(x, y, sc.robot), sc.robot.control_dt)
        if len(states) < 2:
            continue
        counter = np.zeros(1, np.int64)
        v, allq, und = path_verdicts.path_undecided(states, *model.certificate.model, 0.04, path_verdicts.STRIDE,
                                                    counter)
        every = model.certificate.classify(allq)
        if every[0] != FREE:
            expected = UNKNOWN
        elif np.any(every == COLLIDING):
            expected = COLLIDING
        elif np.any(every == UNKNOWN):
            expected = UNKNOWN
        else:
            expected = FREE
        assert v == expected
        if v == UNKNOWN and every[0] == FREE:
            np.testing.assert_array_equal(und, np.flatnonzero(every == UNKNOWN))
        if v == FREE:
            assert counter[0] < len(allq)  # it skipped states
        seen.add(int(v))
    assert {FREE, COLLIDING} <= seen


def test_the_numba_director_ray_test_is_numpys(kin):
    """StateSampler.looks_at_wbox in numba against views.director_ray_hits of camera_poses."""
    from nbvs_drake.planning.views import director_ray_hits
    for name in ("default", "cluttered_room"):
        sc = load_scenario(name)
        s = StateSampler(sc, kin)
        q = s.sample_states(np.random.default_rng(2), 200_000)
        expected = director_ray_hits(kin.camera_poses(q), sc.scene.bbox_min, sc.scene.bbox_max, s.z_near, s.z_far)
        np.testing.assert_array_equal(s.looks_at_wbox(q), expected)
        assert 0.005 < expected.mean() < 0.1
        assert s._plane_offset < 0.1  # the arm-plane pretest is on for this arm
    # a small box far from the middle, where the pretest rejects most states
    sc = load_scenario(settings=["scene.bbox_min=[0.3, -0.5, 0.5]", "scene.bbox_max=[0.5, -0.3, 0.7]"])
    s = StateSampler(sc, kin)
    q = s.sample_states(np.random.default_rng(3), 200_000)
    expected = director_ray_hits(kin.camera_poses(q), sc.scene.bbox_min, sc.scene.bbox_max, s.z_near, s.z_far)
    np.testing.assert_array_equal(s.looks_at_wbox(q), expected)
    assert expected.sum() > 100


def test_the_tree_grids_nearest_vertex_is_the_brute_forces():
    """neighbours.TreeGrid's ring search against rrt._nearest's scan: the same index, for trees
    grown in steps (vertices inserted as they come), vertices and targets outside the grid's
    bounds, and duplicate vertices (ties go to the lower index, as the scan's)."""
    from nbvs_drake.planning.rrt import _nearest
    rng = np.random.default_rng(7)
    w = np.array([10.0, 10.0, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05])
    Q = np.concatenate([rng.uniform(-2.3, 2.3, (3000, 2)), rng.uniform(-np.pi, np.pi, (3000, 6))], axis=1)
    Q[2000:2100] = Q[1000:1100]  # duplicates
    grid = neighbours.TreeGrid([-1.9, 1.9], len(Q))
    for n in (1, 2, 10, 300, 3000):
        grid.insert(Q, n)
        T = np.concatenate([rng.uniform(-2.5, 2.5, (400, 2)), rng.uniform(-np.pi, np.pi, (400, 6))], axis=1)
        T[:50] = Q[rng.integers(0, n, 50)]  # targets on vertices
        for t in T:
            assert neighbours._nearest_grid(Q, t, w, *grid.arrays) == _nearest(Q[:n], t, w)


@pytest.mark.parametrize("world", ["clutter", "voxels"])
def test_the_leapfrog_walk_gives_the_verdicts_and_undecided_states_of_the_strided_walk(kin, world, request):
    """path_verdicts._walk in the ORT's leapfrog order (stride 0), from a start margin given or not,
    against the strided order (the first, the last, every 8th, the rest): the same verdict,
    and the same undecided states where it is UNKNOWN, on edges from free states towards random and near-contact
    states; the margins it returns for the last state are the ones `free_margins` computes
    there (how many states each order visits is `nbvs bench collision`'s)."""
    sc, model = request.getfixturevalue(world)
    q = random_states(kin, 1500, seed=31)
    free = drake_free(model, q)
    near = near_contacts(model, q, free, n_pairs=150, steps=22, both=True)
    rng = np.random.default_rng(8)
    a = q[free][:300]
    b = np.concatenate([kin.clip_arm(a[:150] + rng.normal(0, 0.5, (150, 8))), near[:150]])
    m = unpack(*model.certificate.model)
    scratch = robot_scratch(m)
    seen = set()
    for x, y in zip(a, b):
        c = steer_together(x, y, sc.robot)
        if len(c) == 0:
            continue
        allq = path_verdicts.interpolate(rollout(x, c, sc.robot.control_dt), 0.04)
        start, last = _margins(allq[[0, -1]], *model.certificate.model)[0]
        n_m = model.certificate.margin_size
        out = {}
        for stride, s0 in ((8, np.full(n_m, -1.0)), (0, np.full(n_m, -1.0)), (0, start)):
            und = np.zeros(len(allq), bool)
            cnt = np.zeros(1, np.int64)
            end = np.empty(n_m)
            v = path_verdicts._walk(allq, m, scratch, stride, cnt, und, s0, end, path_verdicts._bounds(m))
            out[(stride, s0[0] > 0)] = (v, np.flatnonzero(und).tolist())
            if end[0] > 0:
                np.testing.assert_allclose(end, last)
        ref = out[(8, False)]
        assert all(o[0] == ref[0] for o in out.values())
        if ref[0] == UNKNOWN:  # (a COLLIDING walk stops at the first collision it visits)
            assert all(o[1] == ref[1] for o in out.values())
        seen.add(ref[0])
    assert {FREE, COLLIDING, UNKNOWN} <= seen


def test_state_sampling_draws_numpys_uniform_numbers(kin):
    """StateSampler.sample_states writes numpy's uniform(low, high) out as low + (high - low)
    * random(): the same numbers from the same generator state (so the same trees and
    candidates as before)."""
    sc = load_scenario()
    lo, hi = sc.robot.xy_bounds
    q = StateSampler(sc, kin).sample_states(np.random.default_rng(11), 50_000)
    rng = np.random.default_rng(11)
    np.testing.assert_array_equal(q[:, 0:2], rng.uniform(lo, hi, size=(50_000, 2)))
    np.testing.assert_array_equal(q[:, 2], rng.uniform(-np.pi, np.pi, size=50_000))
    np.testing.assert_array_equal(q[:, 3:], rng.uniform(kin.arm_lower, kin.arm_upper, size=(50_000, 5)))
