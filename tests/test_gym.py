"""nbvs_drake.gym: the Gymnasium environments over the real mission and over the view sphere."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

QUICK = ["mission.max_scans=3", "scene.gt_points=4000", "mission.coverage_ceiling=false"]


@pytest.fixture(scope="module")
def env():
    import nbvs_drake.gym  # noqa: F401 - registers the environments
    e = gym.make("nbvs_drake/Reconstruct-v0", settings=QUICK, n_candidates=6, disable_env_checker=False)
    yield e
    e.close()


def _episode(env, seed, choose):
    obs, info = env.reset(seed=seed)
    rewards, infos, done = [], [info], False
    while not done:
        obs, r, done, truncated, info = env.step(choose(obs))
        rewards.append(r)
        infos.append(info)
    return rewards, infos


def test_the_planners_own_choice_every_step_is_the_mission_nbvs_reconstruct_runs(env, tmp_path):
    """Action 0 is the scenario planner's own choice: an episode of it is the run `nbvs
    reconstruct` makes with the same scenario and seed, and the rewards add up to its coverage."""
    from nbvs_drake.app.api import reconstruct
    rewards, infos = _episode(env, 4, lambda obs: 0)
    run = reconstruct(None, tmp_path / "run", seed=4, overrides=QUICK)
    summary = infos[-1]["summary"]
    assert summary["coverage"] == pytest.approx(run.summary["coverage"], abs=1e-12)
    assert summary["scans"] == run.summary["scans"] == 3 and summary["stop_reason"] == "max_scans"
    assert sum(rewards) + infos[0]["coverage"] == pytest.approx(summary["coverage"], abs=1e-9)
    assert [i["scan"] for i in infos] == [1, 2, 3]


def test_the_same_seed_gives_the_same_episode_and_another_candidate_another(env):
    a = _episode(env, 5, lambda obs: int(np.flatnonzero(obs["candidate_mask"])[-1]))
    b = _episode(env, 5, lambda obs: int(np.flatnonzero(obs["candidate_mask"])[-1]))
    c = _episode(env, 5, lambda obs: 0)
    assert a[0] == b[0] and a[1][-1]["summary"]["coverage"] == b[1][-1]["summary"]["coverage"]
    assert a[1][-1]["summary"]["distance"] != c[1][-1]["summary"]["distance"]
    # each episode is a run folder; only the last one is kept (keep_runs False)
    runs = list(env.unwrapped.out_dir.glob("episode_*"))
    assert len(runs) == 1 and (runs[0] / "summary.json").is_file()


def test_the_observation_holds_the_map_the_depth_image_the_belief_and_the_candidates(env):
    from nbvs_drake.mapping.voxel import OCCUPIED, UNKNOWN
    obs, info = env.reset(seed=6)
    assert env.observation_space.contains(obs)
    assert info["scan"] == 1 and 0 < info["coverage"] < 1
    v = obs["voxels"]
    assert np.count_nonzero(v == OCCUPIED) > 50 and np.count_nonzero(v == UNKNOWN) > 0.5 * v.size
    assert np.count_nonzero(obs["depth"] > 0) > 1000
    n = int(obs["candidate_mask"].sum())
    c = obs["candidates"][:n]
    assert n >= 2 and np.all(c[:, 8] > 0) and np.all(c[:, 10] > 0) and np.all(c[:, 12] == 1)
    assert c[0, 8] == c[:, 8].max()  # the planner's own choice first: the best utility
    assert np.allclose(obs["believed_state"], env.unwrapped.sc.robot.start)


def test_a_state_action_is_reached_by_the_motion_planner_or_reported_unreachable():
    import nbvs_drake.gym  # noqa: F401
    e = gym.make("nbvs_drake/Reconstruct-v0", settings=QUICK, action="state")
    try:
        obs, info = e.reset(seed=7)
        inside_table = np.r_[0.0, 0.0, 0.0, e.unwrapped.sc.robot.start[3:]]
        obs2, r, done, _, info2 = e.step(inside_table)
        assert info2["reachable"] is False and r == 0.0 and not done and info2["scan"] == 1
        assert np.array_equal(obs2["voxels"], obs["voxels"])
        second = obs["candidates"][1, :8]  # a state the planner reached: a plan to it, and a scan
        obs3, r3, done3, _, info3 = e.step(second)
        assert info3["reachable"] and info3["scan"] == 2 and r3 > 0
        assert np.allclose(obs3["believed_state"][:2], second[:2], atol=0.05)
    finally:
        e.close()


def test_the_view_sphere_shares_the_sensor_map_and_reward_and_scores_by_auc():
    import nbvs_drake.gym  # noqa: F401
    from nbvs_drake.gym.sphere import N_VIEWS, arc_length
    e = gym.make("nbvs_drake/ViewSphere-v0", settings=["scene.gt_points=4000"], include_depth=False)
    try:
        def run(seed, order):
            obs, info = e.reset(seed=seed)
            views, rewards, done = [info["view"]], [info["coverage"]], False
            while not done:
                obs, r, done, _, info = e.step(order(obs))
                views.append(info["view"])
                rewards.append(r)
            return views, rewards, info
        views, rewards, info = run(1, lambda obs: int(np.flatnonzero(obs["visited"] == 0)[0]))
        again = run(1, lambda obs: int(np.flatnonzero(obs["visited"] == 0)[0]))
        assert again[1] == rewards and len(views) == 10 and len(set(views)) == 10
        curve = np.cumsum(rewards)
        assert info["auc"] == pytest.approx(curve.mean()) and info["coverage"] == pytest.approx(curve[-1])
        sphere = e.unwrapped
        assert info["distance"] == pytest.approx(sum(arc_length(sphere.dirs[a], sphere.dirs[b], sphere.radius)
                                                     for a, b in zip(views, views[1:])))
        assert info["collisions"] == 0 and curve[-1] <= info["ceiling"] + 0.01 and info["ceiling"] > 0.9
        # taking a view again gains nothing new
        e.reset(seed=2)
        _, r_same, *_ = e.step(sphere.view)
        assert r_same < 0.01 and N_VIEWS == 33
    finally:
        e.close()


def test_a_vector_of_view_spheres_runs_in_processes():
    import nbvs_drake.gym  # noqa: F401
    envs = gym.make_vec("nbvs_drake/ViewSphere-v0", num_envs=2, vectorization_mode="async",
                        settings=["scene.gt_points=2000"], include_depth=False)
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs["visited"].shape == (2, 33) and obs["visited"].sum() == 2
        obs, r, term, trunc, info = envs.step(np.array([0, 32]))
        assert r.shape == (2,) and np.all(r >= 0) and obs["visited"].sum() >= 3
    finally:
        envs.close()


@pytest.mark.slow
def test_a_vector_of_missions_runs_in_processes():
    import nbvs_drake.gym  # noqa: F401
    envs = gym.make_vec("nbvs_drake/Reconstruct-v0", num_envs=2, vectorization_mode="async",
                        settings=QUICK, include_depth=False)
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs["candidate_mask"].shape[0] == 2
        obs, r, term, trunc, info = envs.step(np.array([0, 0]))
        assert np.all(r > 0)
    finally:
        envs.close()
