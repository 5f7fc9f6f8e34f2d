import numpy as np
import pytest

from nbvs_drake.config import Legs, NoiseConfig, Scenario
from nbvs_drake.planning.collision import CollisionModel
from nbvs_drake.planning.expected_utility import expected_utility, sample_count_bound
from nbvs_drake.world.motion import rollout, steer


def test_eq18_sample_bound():
    assert sample_count_bound(0.01, 0.05, 1 / 0.997) == 90  # Vasquez-Gomez et al. 2017 §7.3
    assert sample_count_bound(0.01, 0.5) < sample_count_bound(0.01, 0.05) < sample_count_bound(0.001, 0.05)
    with pytest.raises(ValueError):
        sample_count_bound(0.01, 1.2)


@pytest.fixture(scope="module")
def grazing(kin):
    """The base turns 0.3 rad in place, then drives 1 m along +y with the arm stretched
    towards W_box (world +x), its tip about 1.5 cm from the box: free without noise, not
    with Table 4 noise."""
    sc = Scenario()
    model = CollisionModel(sc, kin)

    def q_at(x, y):
        return np.array([x, y, np.pi / 2, -np.pi / 2, 0.0, 0.0, 0.0, 0.0])

    lo, hi = -1.6, -0.9  # bisect the x where the arm touches W_box
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if model.free(q_at(mid, -0.5))[0] else (lo, mid)
    x = lo - 0.015
    q0, q1 = q_at(x, -0.5), q_at(x, 0.5)
    # start turned 0.3 rad away: the plan turns in place first, and that commanded turn is
    # what the noise perturbs (driving straight commands omega = 0, executed exactly)
    q0[2] += 0.3
    (_, controls), = [c for c in steer(q0, q1, sc.robot) if c[0] == "together"][:1]
    states = rollout(q0, controls, sc.robot.control_dt)
    assert model.path_free(states)
    return sc, model, q0, controls


def test_zero_noise_expected_utility_equals_deterministic(grazing):
    sc, model, q0, controls = grazing
    util = lambda s: 1.0 / (1.0 + np.abs(s[:, 1] - 0.5))  # noqa: E731
    zero = NoiseConfig(sigma_v=0, sigma_w=0, sigma_arm=[0] * 5)
    eu = expected_utility(q0, controls, sc.robot.control_dt, 50, zero, np.random.default_rng(0), model.free, util)
    du = util(rollout(q0, controls, sc.robot.control_dt)[-1:])[0]
    assert eu.feasible and eu.collided_rollouts == 0
    assert eu.value == pytest.approx(du, rel=1e-12)
    np.testing.assert_allclose(eu.weights, 1 / 50)


def test_grazing_path_is_unfeasible_under_noise_for_large_k(grazing):
    sc, model, q0, controls = grazing
    util = lambda s: np.ones(len(s))  # noqa: E731
    eu = expected_utility(q0, controls, sc.robot.control_dt, 1000, NoiseConfig(), np.random.default_rng(1),
                          model.free, util)
    assert not eu.feasible and eu.value == 0.0 < 1.0  # lower than the deterministic utility 1
    assert eu.collided_rollouts >= 1


def test_probabilities_in_log_space_do_not_underflow(kin):
    # 400 noisy steps: a product of 800 densities underflows in linear space
    controls = np.zeros((400, 7))
    controls[:, 0] = 0.05
    noise = NoiseConfig(sigma_v=0.01, sigma_w=0.05)
    eu = expected_utility(np.array([-1.8, -1.8, 0, 0, 0.3, 0, 0, 0]), controls, 0.1, 64, noise,
                          np.random.default_rng(2), lambda q: np.ones(len(q), bool), lambda s: s[:, 0])
    assert eu.feasible and np.all(np.isfinite(eu.weights)) and eu.weights.sum() == pytest.approx(1.0)
    assert eu.weights.max() < 1.0  # not degenerate
    assert eu.final_states[:, 0].min() <= eu.value <= eu.final_states[:, 0].max()


def test_mean_weighting_is_the_plain_monte_carlo_average_and_probability_weights_collapse():
    """Table 4 noise on a 100-step turn: the rollouts' final headings spread by ~0.28 rad. The
    plain average sees that spread (a view that needs the heading within 0.1 rad is worth
    ~0.3 of its nominal value); the normalised product-of-densities weights of Algorithm 1
    have an effective sample size of a few rollouts out of 500."""
    controls = np.zeros((100, 7))
    controls[:, 1] = 0.1  # turn in place 1 rad
    q0 = np.array([0, 0, 0, 0, 0.3, 0, 0, 0], float)
    nominal = rollout(q0, controls, 0.1)[-1, 2]
    util = lambda s: (np.abs(s[:, 2] - nominal) < 0.1).astype(float)  # noqa: E731
    free = lambda q: np.ones(len(q), bool)  # noqa: E731
    mean = expected_utility(q0, controls, 0.1, 500, NoiseConfig(), np.random.default_rng(3), free, util,
                            weighting="mean")
    prob = expected_utility(q0, controls, 0.1, 500, NoiseConfig(), np.random.default_rng(3), free, util)
    heading = mean.final_states[:, 2] - nominal
    assert 0.2 < heading.std() < 0.35
    assert mean.value == pytest.approx(util(mean.final_states).mean()) and mean.ess == pytest.approx(500)
    assert 0.15 < mean.value < 0.45
    assert prob.ess < 10
    np.testing.assert_allclose(prob.final_states, mean.final_states)  # same draws, other weights
    with pytest.raises(ValueError, match="weighting"):
        expected_utility(q0, controls, 0.1, 5, NoiseConfig(), np.random.default_rng(3), free, util, weighting="max")


def test_collision_rate_threshold_counts_colliding_rollouts_as_zero_utility(grazing):
    """The weighted alternative to Algorithm 1's line 7: the grazing path collides in some of
    its rollouts; with a tolerated collision rate above that share it stays feasible, and its
    expected utility (plain average of g = 1 for every free rollout) is the free share."""
    sc, model, q0, controls = grazing
    util = lambda s: np.ones(len(s))  # noqa: E731
    args = (q0, controls, sc.robot.control_dt, 400, NoiseConfig())
    strict = expected_utility(*args, np.random.default_rng(5), model.free, util, weighting="mean")
    assert not strict.feasible
    loose = expected_utility(*args, np.random.default_rng(5), model.free, util, weighting="mean",
                             max_collision_rate=0.99)
    assert loose.feasible and loose.rollouts_checked == 400
    rate = loose.collided_rollouts / 400
    assert 0 < rate < 0.99
    assert loose.value == pytest.approx(1.0 - rate)
    # a threshold just below the observed rate rules it out again
    tight = expected_utility(*args, np.random.default_rng(5), model.free, util, weighting="mean",
                             max_collision_rate=max(rate - 0.05, 0.0))
    assert not tight.feasible and tight.value == 0.0
    with pytest.raises(ValueError, match="max_collision_rate"):
        expected_utility(*args, np.random.default_rng(5), model.free, util, max_collision_rate=1.0)


def test_uncertain_start_spreads_the_rollouts():
    """A belief no scan has corrected (heading sigma 0.3 rad, the spread of one ~100-control
    plan): with exact controls the rollouts' final headings spread by that sigma, and a view
    that needs the heading within 0.1 rad is worth about a quarter of its nominal value; with
    no start covariance (or a zero one) the rollouts all end at the nominal state."""
    from nbvs_drake.world.pose import Correction, apply_corrections
    q0 = np.array([1.0, 2.0, 0.3, 0, 0.3, 0, 0, 0])
    xi = np.array([[0.1, -0.2, 0.4], [0.0, 0.0, 0.0]])
    starts = apply_corrections(q0, xi)
    np.testing.assert_allclose(starts[0], Correction(*xi[0]).apply_state(q0), atol=1e-12)
    np.testing.assert_allclose(starts[1], q0, atol=1e-12)
    q0 = np.array([0.0, 0.0, 0.3, 0, 0.3, 0, 0, 0])  # at the origin the correction turns the base in place
    controls = np.zeros((50, 7))
    controls[:, 0] = 0.2  # drive 1 m
    exact = NoiseConfig(sigma_v=0, sigma_w=0, sigma_arm=[0] * 5)
    free = lambda q: np.ones(len(q), bool)  # noqa: E731
    util = lambda s: (np.abs(s[:, 2] - 0.3) < 0.1).astype(float)  # noqa: E731
    cov = np.diag([1e-4, 1e-4, 0.3 ** 2])
    for known in (None, np.zeros((3, 3))):
        eu = expected_utility(q0, controls, 0.1, 500, exact, np.random.default_rng(0), free, util,
                              weighting="mean", start_cov=known)
        assert eu.value == pytest.approx(1.0) and np.ptp(eu.final_states[:, 2]) < 1e-12
    eu = expected_utility(q0, controls, 0.1, 500, exact, np.random.default_rng(0), free, util,
                          weighting="mean", start_cov=cov)
    assert 0.25 < eu.final_states[:, 2].std() < 0.33
    assert 0.15 < eu.value < 0.4
    # each rollout still executes the plan: 1 m along its own (perturbed) start heading
    heading = eu.final_states[:, 2]
    np.testing.assert_allclose(eu.final_states[:, :2], np.stack([np.cos(heading), np.sin(heading)], 1), atol=0.04)


def test_starts_where_the_robot_cannot_stand_are_dropped_with_eu_free_start():
    """A belief 10 cm unsure in x next to a wall at x = 0.1 (the robot stands at x = 0): the
    rollouts that start beyond the wall make Algorithm 1 refuse every path; conditioned on
    the robot standing free (start_free), a drive away from the wall is feasible and every
    kept rollout starts on the free side."""
    q0 = np.array([0.0, 0.0, np.pi, 0, 0.3, 0, 0, 0])
    controls = np.zeros((20, 7))
    controls[:, 0] = 0.2  # 0.4 m away from the wall
    exact = NoiseConfig(sigma_v=0, sigma_w=0, sigma_arm=[0] * 5)
    free = lambda q: np.asarray(q)[..., 0] < 0.1  # noqa: E731
    one = lambda s: np.ones(len(s))  # noqa: E731
    cov = np.diag([0.1 ** 2, 1e-6, 1e-6])
    plain = expected_utility(q0, controls, 0.1, 300, exact, np.random.default_rng(0), free, one, start_cov=cov)
    assert not plain.feasible
    kept = expected_utility(q0, controls, 0.1, 300, exact, np.random.default_rng(0), free, one, start_cov=cov,
                            start_free=free)
    assert kept.feasible and 150 < kept.rollouts < 300  # about 84 % of the draws are free
    starts_x = kept.final_states[:, 0] + 0.4  # each drove 0.4 m in -x
    assert np.all(starts_x < 0.1 + 1e-9)
    # a belief wholly inside the wall: nothing to keep
    inside = expected_utility(q0 + np.array([0.5, 0, 0, 0, 0, 0, 0, 0]), controls, 0.1, 100, exact,
                              np.random.default_rng(0), free, one, start_cov=np.diag([1e-4, 1e-6, 1e-6]),
                              start_free=free)
    assert not inside.feasible and inside.rollouts == 0


def test_the_registered_spread_the_rollouts_start_from_is_the_scenarios():
    """localisation.verified_views.registered_sigma is the spread of a registered belief that verified views'
    rollouts (each leg after a frame, the recovery paths) start from: by default
    motion.REGISTERED_SIGMA; a scenario may set what its registrations measured."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.errors import ScenarioError
    from nbvs_drake.planning.utility import ExpectedUtilityScore
    from nbvs_drake.world.motion import REGISTERED_SIGMA
    sc = load_scenario("cluttered_room", settings=["localisation.verified_views={}"])
    assert sc.localisation.verified_views.registered_sigma == list(REGISTERED_SIGMA)
    np.testing.assert_allclose(ExpectedUtilityScore(sc, None, None, None).registered_cov(),
                               np.diag(np.square(REGISTERED_SIGMA)))
    sc = load_scenario("cluttered_room",
                       settings=["localisation.verified_views={registered_sigma: [0.002, 0.003, 0.004]}"])
    eu = ExpectedUtilityScore(sc, None, None, None)
    belief = np.diag([1e-4, 2e-4, 3e-4])
    np.testing.assert_allclose(eu.registered_cov(belief), belief + np.diag([0.002 ** 2, 0.003 ** 2, 0.004 ** 2]))
    turn = (sc.noise.sigma_w * sc.robot.control_dt) ** 2  # mission.leg_turns: one step of corrective turn
    sc.localisation.verified_views.legs = Legs(after_turns=True)
    np.testing.assert_allclose(eu.leg_cov(), np.diag([0.002 ** 2, 0.003 ** 2, 0.004 ** 2 + turn]))
    with pytest.raises(ScenarioError, match="localisation.verified_views.registered_sigma"):
        load_scenario("cluttered_room", settings=["localisation.verified_views={registered_sigma: [0.01, -1, 0.01]}"])


def test_probability_weighting_scores_only_the_rollouts_that_carry_weight():
    """Algorithm 1's probability weights put almost all mass on a few rollouts: those below
    WEIGHT_FLOOR of the largest are not scored, and E(x) is the full weighted sum's to far
    below any difference between two views; the plain mean scores every rollout."""
    from nbvs_drake.planning.expected_utility import WEIGHT_FLOOR
    noise = NoiseConfig(sigma_v=0.00165, sigma_w=0.28)
    controls = np.zeros((60, 7))
    controls[:30, 1] = 0.5  # a turn in place, then a drive
    controls[30:, 0] = 0.3
    scored = []

    def utility(finals):
        scored.append(len(finals))
        return 1.0 + finals[:, 0] + finals[:, 2]
    free = lambda s: np.ones(len(s), bool)  # noqa: E731
    eu = expected_utility(np.zeros(8), controls, 0.1, 500, noise, np.random.default_rng(3), free, utility)
    assert eu.feasible and eu.scored == scored[0] < 500
    assert np.all(eu.weights[eu.utilities == 0] < WEIGHT_FLOOR * eu.weights.max())
    full = float(np.dot(eu.weights, 1.0 + eu.final_states[:, 0] + eu.final_states[:, 2]))
    assert eu.value == pytest.approx(full, rel=500 * WEIGHT_FLOOR)
    assert eu.spread == pytest.approx(np.sqrt(np.dot(eu.weights, (eu.utilities - eu.value) ** 2)))
    mean = expected_utility(np.zeros(8), controls, 0.1, 500, noise, np.random.default_rng(3), free, utility,
                            weighting="mean")
    assert mean.scored == 500 and mean.spread == pytest.approx(np.std(mean.utilities))


def test_noise_drawn_per_chunk_is_the_noise_drawn_at_once():
    """NoiseDraws: any rollouts' noise is what one sample_control_noise call for all k gives
    them, and the generator is left where that call leaves it (a candidate ruled out by its
    first rollouts changes no later draw)."""
    from nbvs_drake.planning.expected_utility import NoiseDraws
    from nbvs_drake.world.motion import sample_control_noise
    noise = NoiseConfig(sigma_v=0.00165, sigma_w=0.28, sigma_arm=[0.01, 0.0, 0.0, 0.0, 0.0])
    controls = np.zeros((40, 7))
    controls[:10, 1], controls[10:, 0], controls[20:25, 2] = 0.5, 0.3, 0.2
    at_once, lazy = np.random.default_rng(11), np.random.default_rng(11)
    every = sample_control_noise(at_once, noise, controls, 300)
    draws = NoiseDraws(lazy, noise, controls, 300)
    assert lazy.uniform() == at_once.uniform()
    for idx in (np.arange(100), np.arange(100, 300), np.array([3, 7, 250]), np.arange(0)):
        np.testing.assert_array_equal(draws.rows(idx), every[idx])
    assert np.all(every[:, :10, 0] == 0) and np.all(every[:, :10, 1] != 0) and np.all(every[:, 20:25, 2] != 0)


def test_rollouts_checked_coarse_to_fine_give_the_verdicts_of_every_state(grazing):
    """With a tolerated collision rate, the rollouts checked set by set (`chunk_bounds`: a
    first few, then hundreds) and coarse to fine, each no further than its first collision,
    give the candidate the feasibility, value and utilities of checking every state of every
    rollout."""
    from nbvs_drake.planning.expected_utility import FIRST_CHUNK, chunk_bounds
    assert chunk_bounds(500, 100) == [(0, FIRST_CHUNK), (FIRST_CHUNK, 100), (100, 200), (200, 300), (300, 400),
                                      (400, 500)]
    assert chunk_bounds(7, 100) == [(0, 7)]
    sc, model, q0, controls = grazing
    util = lambda s: 1.0 + s[:, 0]  # noqa: E731
    seen = set()
    for rate in (0.0, 0.01, 0.05, 0.2, 0.6):
        for seed in range(4):
            def run(seed=seed, rate=rate, **kw):
                return expected_utility(q0, controls, sc.robot.control_dt, 300, NoiseConfig(),
                                        np.random.default_rng(seed), model.free, util, max_collision_rate=rate, **kw)
            every = run()
            coarse = run(block_free=lambda s, steps: model.free(s.reshape(-1, 8)).reshape(s.shape[:2]))
            assert (coarse.feasible, coarse.value) == (every.feasible, every.value)
            if every.feasible:
                np.testing.assert_array_equal(coarse.utilities, every.utilities)
                assert coarse.collided_rollouts == every.collided_rollouts
            else:
                assert coarse.rollouts_checked <= every.rollouts_checked
            seen.add(every.feasible)
    assert seen == {True, False}
