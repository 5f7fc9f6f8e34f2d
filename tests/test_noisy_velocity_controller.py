import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from nbvs_drake.config import NoiseConfig
from nbvs_drake.systems.noisy_velocity_controller import NoisyVelocityController, plan_noise
from nbvs_drake.world.motion import ControlSequence, noise_sigmas, sample_truncated_normal, truncated_normal_logpdf


def _plan(m=20, plan_id=1):
    rng = np.random.default_rng(5)
    U = rng.uniform(-0.3, 0.3, (m, 7))
    return ControlSequence(plan_id, 0.1, U, np.zeros((m + 1, 8)))


def _replay(noise, seed, tau):
    ctrl = NoisyVelocityController(noise, seed, 0.1)
    sim = Simulator(ctrl)
    ctx = sim.get_mutable_context()
    ctrl.GetInputPort("controls").FixValue(ctx, AbstractValue.Make(tau))
    applied = []
    for k in range(tau.m + 2):
        sim.AdvanceTo(k * 0.1 + 0.05)
        applied.append(np.array(ctrl.GetOutputPort("velocity").Eval(ctx)))
    status = ctrl.GetOutputPort("status").Eval(ctx)
    return np.array(applied), status


def test_zero_sigma_reproduces_the_plan():
    tau = _plan()
    zero = NoiseConfig(sigma_v=0, sigma_w=0, sigma_arm=[0] * 5)
    applied, status = _replay(zero, 0, tau)
    np.testing.assert_array_equal(applied[: tau.m], tau.controls)
    np.testing.assert_array_equal(applied[tau.m:], 0.0)
    np.testing.assert_array_equal(status, [1, tau.m, 1])  # plan 1 done, idle


def test_noise_is_seeded_and_added_per_plan():
    tau = _plan()
    noise = NoiseConfig()  # Table 4: sigma_v 1.65 mm/s, sigma_w 0.28 rad/s, arm exact
    a1, _ = _replay(noise, 3, tau)
    a2, _ = _replay(noise, 3, tau)
    a3, _ = _replay(noise, 4, tau)
    np.testing.assert_array_equal(a1, a2)
    assert not np.allclose(a1, a3)
    eps = a1[: tau.m] - tau.controls
    np.testing.assert_allclose(eps, plan_noise(3, 1, tau.controls, noise), atol=1e-15)
    np.testing.assert_allclose(eps[:, 2:], 0.0, atol=1e-15)  # arm exact (sigma 0)
    assert np.all(np.abs(eps[:, 1]) <= 3 * 0.28 + 1e-12)


def test_truncated_noise_statistics():
    rng = np.random.default_rng(0)
    sigma = np.array([0.00165, 0.28, 0.0, 0.01, 0.0, 0.0, 0.0])
    eps = sample_truncated_normal(rng, sigma, 3.0, (200_000,))
    assert np.all(np.abs(eps) <= 3.0 * sigma + 1e-15)
    # std of a normal truncated at +-3 sigma: sigma * sqrt(1 - 2*3*phi(3)/(2*Phi(3)-1)) = 0.98656 sigma
    np.testing.assert_allclose(eps.std(axis=0)[[0, 1, 3]], 0.98656 * sigma[[0, 1, 3]], rtol=0.01)
    np.testing.assert_allclose(eps.mean(axis=0)[[0, 1, 3]], 0.0, atol=0.01 * sigma[[0, 1, 3]].max())
    # beta = 1: every sample within one sigma
    e1 = sample_truncated_normal(rng, sigma, 1.0, (10_000,))
    assert np.all(np.abs(e1) <= sigma + 1e-15)


def test_truncated_logpdf_normalised():
    sigma = np.array([0.5])
    x = np.linspace(-1.5, 1.5, 20001)[:, None]
    p = np.exp(truncated_normal_logpdf(x, sigma, 3.0))
    assert abs(np.trapezoid(p, x[:, 0]) - 1.0) < 1e-4
    # zero-sigma components contribute nothing
    assert truncated_normal_logpdf(np.array([0.1, 0.0]), np.array([0.5, 0.0]), 3.0) == pytest.approx(
        truncated_normal_logpdf(np.array([0.1]), np.array([0.5]), 3.0))


def test_noise_sigmas_layout():
    n = NoiseConfig(sigma_v=1, sigma_w=2, sigma_arm=[3, 4, 5, 6, 7])
    np.testing.assert_array_equal(noise_sigmas(n), [1, 2, 3, 4, 5, 6, 7])


def test_a_component_commanded_zero_is_executed_exactly():
    """The authors' library (vpl) perturbs only non-zero velocities: driving straight (omega = 0)
    keeps the heading, a turn in place (v = 0) keeps the position."""
    tau = _plan(m=30)
    U = tau.controls.copy()
    U[:10, 1] = 0.0   # drive straight
    U[10:20, 0] = 0.0  # turn in place
    U[20:, :2] = 0.0   # base at rest
    tau = ControlSequence(1, 0.1, U, np.zeros((31, 8)))
    noise = NoiseConfig()
    eps = _replay(noise, 3, tau)[0][: tau.m] - U
    np.testing.assert_array_equal(eps[U == 0.0], 0.0)
    assert np.all(eps[:10, 0] != 0) and np.all(eps[10:20, 1] != 0)
