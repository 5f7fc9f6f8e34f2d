"""RRT Ext-Ext and the Object Reconstruction Tree."""
import copy

import numpy as np
import pytest

from nbvs_drake.config import Scenario
from nbvs_drake.config import apply_setting as _set
from nbvs_drake.planning.rrt import Tree, rrt_ext_ext, weighted_dist
from nbvs_drake.world.motion import rollout, wrap_angle

W = np.array([10, 10, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05])


def _wall_free(states):
    """A wall at |x| < 0.15 for y < 1.0 (base position only), inside x, y in [-2, 2]."""
    s = np.atleast_2d(states)
    # densify: base moves at most 3 cm per control step, check the midpoints too
    mid = 0.5 * (s[1:] + s[:-1]) if len(s) > 1 else s
    allq = np.concatenate([s, mid])
    hit = (np.abs(allq[:, 0]) < 0.15) & (allq[:, 1] < 1.0)
    out = (np.abs(allq[:, :2]) > 2.0).any(axis=1)
    return not (hit.any() or out.any())


def _sampler(rng, n):
    q = np.zeros((n, 8))
    q[:, :2] = rng.uniform(-2, 2, (n, 2))
    q[:, 2] = rng.uniform(-np.pi, np.pi, n)
    q[:, 4] = 1.2
    return q


def test_rrt_finds_a_path_around_a_wall_and_its_controls_reach_the_goal():
    rc = Scenario().robot
    q0 = np.array([-1.0, 0.0, 0.0, 0, 1.2, 0, 0, 0])
    q1 = np.array([1.0, 0.0, np.pi, 0, 1.2, 0, 0, 0])
    # the straight line is blocked
    assert not _wall_free(rollout(q0, np.tile([0.3, 0, 0, 0, 0, 0, 0], (67, 1)), rc.control_dt))
    res = rrt_ext_ext(q0, q1, rc, W, _sampler, _wall_free, lambda q: q, np.random.default_rng(0),
                      max_nodes=4000, step=1.5)
    assert res.found
    states = rollout(q0, res.controls, rc.control_dt)  # replayed without noise
    np.testing.assert_allclose(states[-1, :2], q1[:2], atol=1e-9)
    assert abs(wrap_angle(states[-1, 2] - q1[2])) < 1e-9
    assert _wall_free(states)
    assert states[:, 1].max() > 1.0  # it went around the end of the wall


def test_rrt_gives_up_when_neither_tree_can_grow():
    """Start and goal in pockets that no extension leaves: the search stops after its
    iteration budget (20 x max_nodes) instead of running for ever."""
    rc = Scenario().robot
    q0 = np.array([-1.0, 0.0, 0.0, 0, 1.2, 0, 0, 0])
    q1 = np.array([1.0, 0.0, np.pi, 0, 1.2, 0, 0, 0])
    res = rrt_ext_ext(q0, q1, rc, W, _sampler, lambda states: False, lambda q: q, np.random.default_rng(0),
                      max_nodes=50, step=1.5)
    assert not res.found and res.vertices == 2 and res.iterations == 20 * 50  # ITERATIONS_PER_VERTEX x max_nodes


def test_tree_paths_and_costs():
    t = Tree(np.zeros(8), 10)
    a = t.add(0, np.ones(8), np.zeros((3, 7)), 2.0)
    b = t.add(a, 2 * np.ones(8), np.zeros((4, 7)), 1.5)
    assert t.path_to(b) == [0, a, b] and t.cost[b] == 3.5 and len(t.controls_to(b)) == 7
    assert t.nearest(np.full(8, 1.9), W) == b
    full_turn = np.array([0, 0, 2 * np.pi, 0, 0, 0, 0, 0])
    assert weighted_dist(np.zeros((1, 8)), full_turn, W)[0] == pytest.approx(0, abs=1e-9)


def test_nearest_is_the_argmin_of_the_weighted_distance():
    """The numba nearest-vertex search picks numpy's argmin of weighted_dist, ties and the
    wrapped angle included."""
    from nbvs_drake.config import PlannerConfig
    rng = np.random.default_rng(3)
    for w in (W, np.asarray(PlannerConfig().weights)):  # the default: the base's x, y dominate
        for n in (1, 2, 17, 500):
            for rounded in (False, True):
                t = Tree(np.zeros(8), n)
                for _ in range(n - 1):
                    q = rng.normal(size=8) * 3
                    t.add(0, np.round(q, 1) if rounded else q, np.zeros((0, 7)), 0.0)
                for _ in range(20):
                    q = rng.normal(size=8) * 3
                    q = np.round(q, 1) if rounded else q
                    assert t.nearest(q, w) == int(np.argmin(weighted_dist(t.q[: t.n], q, w)))


def test_tree_edges_are_the_first_steering_sequence():
    from nbvs_drake.config import RobotConfig
    from nbvs_drake.world.motion import steer, steer_together
    rc = RobotConfig()
    rng = np.random.default_rng(4)
    for _ in range(50):
        q0, q1 = rng.normal(size=8), rng.normal(size=8)
        kind, controls = steer(q0, q1, rc)[0]
        assert kind == "together" and np.array_equal(steer_together(q0, q1, rc), controls)


def test_ort_returns_a_vertex_at_least_as_good_as_the_roots_children(kin, first_scan_map):
    from nbvs_drake.planning import PlanRequest, make_planner
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc = _set(sc, "planner.strategy=!Ort {vertices: 300}")
    pl = make_planner(sc, kin)
    res = pl.plan(PlanRequest(omap, np.array(sc.robot.start), np.random.default_rng(1)))
    assert res.stages["vertices"] == 300
    assert res.status == "ok"
    assert res.utility >= res.stages["best_root_child"]
    assert res.utility == pytest.approx(res.factors["info"] * res.factors["dist"])
    end = rollout(np.array(sc.robot.start), res.controls, sc.robot.control_dt)[-1]
    np.testing.assert_allclose(end, res.q_goal, atol=1e-9)
    assert pl.obstacles.for_map(omap).collision.path_free(rollout(np.array(sc.robot.start), res.controls,
                                                                    sc.robot.control_dt))


def test_view_sampling_ik_states_look_at_unknown_clusters(kin, first_scan_map):
    from nbvs_drake.mapping.voxel_sorting import unknown_clusters
    from nbvs_drake.planning import PlanRequest, make_planner
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc = _set(sc, "planner.strategy=!ViewSampling {poses: 20}")
    pl = make_planner(sc, kin)
    q, tried = pl.generator.generate(np.random.default_rng(3), omap)
    assert tried >= 20 and len(q) >= 5
    assert np.all(kin.arm_within_limits(q))
    _, centroids, _ = unknown_clusters(omap.in_wbox() & omap.unknown_mask(), omap.spec.centers())
    X = kin.camera_poses(q)
    for x in X:
        o, z = x[:3, 3], x[:3, 2]
        v = centroids - o
        along = v @ z
        off = np.linalg.norm(v - along[:, None] * z, axis=1)
        # some centroid lies on the optical axis within the IK tolerances (5 deg, 1 cm)
        assert np.any((along > 0) & (off <= along * np.tan(np.radians(5.0)) + 0.012))
    res = pl.plan(PlanRequest(omap, np.array(sc.robot.start), np.random.default_rng(3)))
    assert res.status == "ok" and res.stages["director_ray"] == len(q)


def test_batched_tree_growth_checks_edges_as_one_at_a_time(kin, first_scan_map):
    """The ORT grows in batches (planner.ort_batch): the batched edge checks give the verdicts
    of path_free edge by edge, and a batch of one target extends the tree as `extend` does."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.rrt import edge, extend, extend_batch
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc = _set(sc, "planner.strategy=!Ort {}")
    pl = make_planner(sc, kin)
    obstacles = pl.obstacles.for_map(omap)
    rng = np.random.default_rng(4)
    q0 = np.array(sc.robot.start)
    targets = pl.sampler.sample_states(rng, 120)
    paths = [edge(q0, q0 + 0.6 * (t - q0), sc.robot)[1] for t in targets]
    one_by_one = np.array([pl.motion.tree_path_free(p, obstacles) for p in paths])
    assert 0 < one_by_one.sum() < len(paths)  # both verdicts occur
    np.testing.assert_array_equal(pl.motion.tree_paths_free(paths, obstacles), one_by_one)

    w = np.asarray(sc.planner.weights)
    a, b = Tree(q0, 10), Tree(q0, 10)
    free_one = lambda s: pl.motion.tree_path_free(s, obstacles)  # noqa: E731
    free_many = lambda ps: pl.motion.tree_paths_free(ps, obstacles)  # noqa: E731
    for t in targets[:10]:
        extend(a, t, sc.planner.tree_step, w, sc.robot, free_one, kin.clip_arm)
        extend_batch(b, t[None], sc.planner.tree_step, w, sc.robot, free_many, kin.clip_arm)
    assert a.n == b.n > 1
    np.testing.assert_array_equal(a.q[: a.n], b.q[: b.n])
    np.testing.assert_array_equal(a.parent[: a.n], b.parent[: b.n])
