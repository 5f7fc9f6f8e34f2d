import numpy as np
from pydrake.systems.analysis import Simulator

from nbvs_drake.systems.kinematic_plant import KinematicPlant
from nbvs_drake.world.motion import euler_step, rollout


def _run(kin, q0, u, dt, T):
    plant = KinematicPlant(kin, q0, dt)
    sim = Simulator(plant)
    ctx = sim.get_mutable_context()
    plant.GetInputPort("velocity").FixValue(ctx, u)
    sim.AdvanceTo(T)
    return plant.GetOutputPort("state").Eval(ctx), plant.GetOutputPort("positions").Eval(ctx)


def test_ports(kin):
    plant = KinematicPlant(kin, np.zeros(8), 0.1)
    assert plant.GetInputPort("velocity").size() == 7
    assert plant.GetOutputPort("state").size() == 8
    assert plant.GetOutputPort("positions").size() == kin.n_positions


def test_euler_steps_match_seed_000_equations(kin):
    q0 = np.array([0.1, -0.2, 0.3, 0.0, 0.5, -0.5, 0.2, 0.0])
    u = np.array([0.25, 0.4, 0.1, -0.1, 0.2, 0.0, -0.3])
    dt = 0.1
    q, pos = _run(kin, q0, u, dt, 1.0 + 1e-9)  # 11 updates at t = 0 .. 1.0
    expect = q0.copy()
    for _ in range(11):
        expect = np.array([expect[0] + u[0] * np.cos(expect[2]) * dt, expect[1] + u[0] * np.sin(expect[2]) * dt,
                           expect[2] + u[1] * dt, *(expect[3:] + u[2:] * dt)])
    np.testing.assert_allclose(q, expect, atol=1e-12)
    np.testing.assert_allclose(pos[kin.q_index], q)


def test_differential_drive_arc(kin):
    # constant v, w: the closed-form arc; Euler converges with O(dt) error
    v, w, T, th0 = 0.3, 0.5, 2.0, 0.4
    q0 = np.array([0.0, 0.0, th0, 0, 0, 0, 0, 0])
    dt = 0.001
    q, _ = _run(kin, q0, np.array([v, w, 0, 0, 0, 0, 0]), dt, T - 0.5 * dt)  # 2000 updates
    x = v / w * (np.sin(th0 + w * T) - np.sin(th0))
    y = -v / w * (np.cos(th0 + w * T) - np.cos(th0))
    assert np.hypot(q[0] - x, q[1] - y) < 2e-4
    assert abs(q[2] - (th0 + w * T)) < 1e-9


def test_rollout_is_the_same_model(kin):
    """The vectorised rollout gives bit for bit the states of stepping euler_step (the
    plant's update), for one plan and for a batch of noisy rollouts from spread starts."""
    rng = np.random.default_rng(0)
    U = rng.normal(size=(40, 7)) * 0.2
    U[rng.random(U.shape) < 0.3] = 0.0
    q0 = np.array([0.3, -1.2, 2.9, 0.1, 0.5, -0.4, 0.2, 1.0])
    s = rollout(q0, U, 0.1)
    q = q0.copy()
    for t, u in enumerate(U):
        q = euler_step(q, u, 0.1)
        assert np.array_equal(s[t + 1], q)
    Uk = U[None] + rng.normal(size=(7, 40, 7)) * 0.01
    q0k = q0 + rng.normal(size=(7, 8)) * 0.05
    sk = rollout(q0k, Uk, 0.1)
    q = q0k.copy()
    for t in range(40):
        q = euler_step(q, Uk[:, t], 0.1)
        assert np.array_equal(sk[:, t + 1], q)
    assert rollout(q0, np.zeros((0, 7)), 0.1).shape == (1, 8)
