"""NoisyVelocityController: replays a control sequence with truncated Gaussian noise."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from ..config import NoiseConfig
from ..world.motion import ControlSequence, sample_control_noise
from ..world.state import NU
from .messages import ControllerStatus


class _Noise:
    """Immutable per-plan noise table (shared on context copies)."""

    def __init__(self, plan_id: int, eps: np.ndarray):
        self.plan_id = plan_id
        self.eps = eps
        eps.flags.writeable = False

    def __deepcopy__(self, memo):
        return self


def plan_noise(seed: int, plan_id: int, controls: np.ndarray, noise: NoiseConfig) -> np.ndarray:
    """The noise added to plan `plan_id`'s controls (m, 7): seeded by (seed, plan_id) only, so
    a run is reproducible whatever else draws random numbers; zero on components commanded 0
    unless `noise.perturb_zero_commands`."""
    rng = np.random.default_rng([int(seed), 7, int(plan_id)])
    return sample_control_noise(rng, noise, controls)


class NoisyVelocityController(LeafSystem):
    """Replays tau = {u_1..u_m}, each u held for dt, adding zero-mean Gaussian noise truncated
    to [-beta sigma, beta sigma] per component (Vasquez-Gomez et al. 2017 §6.1: sigma_v, sigma_w on the base,
    sigma_arm per joint); a component commanded 0 is exact unless
    `noise.perturb_zero_commands`. A new plan (larger plan_id on the input) starts at the next tick;
    zero sigmas reproduce the plan exactly.

    Input ports:
      - controls (abstract ControlSequence).
    Output ports:
      - velocity (7): the noisy command u + eps applied over the current dt.
      - status (3): `ControllerStatus` [plan_id being executed, steps done, idle (1 when the
        plan is finished)].
    State: discrete [plan_id, step, idle, u(7)]; abstract noise table of the current plan.
    """

    def __init__(self, noise: NoiseConfig, seed: int, dt: float):
        super().__init__()
        self.noise = noise
        self.seed = int(seed)
        self.dt = float(dt)
        self._in = self.DeclareAbstractInputPort("controls", AbstractValue.Make(ControlSequence.empty(np.zeros(8))))
        x0 = np.zeros(3 + NU)
        x0[2] = 1.0  # idle: plan 0 (no motion) is complete at start
        self._x = self.DeclareDiscreteState(x0)
        self._eps = self.DeclareAbstractState(AbstractValue.Make(_Noise(0, np.zeros((0, NU)))))
        self.DeclareVectorOutputPort("velocity", NU, self._calc_u, {self.discrete_state_ticket(self._x)})
        self.DeclareVectorOutputPort("status", ControllerStatus.SIZE, self._calc_status,
                                     {self.discrete_state_ticket(self._x)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.dt, 0.0, self._update)

    def _update(self, context, state):
        tau: ControlSequence = self._in.Eval(context)
        x = np.array(context.get_discrete_state(self._x).get_value())
        noise = context.get_abstract_state(self._eps).get_value()
        plan_id, step = int(x[0]), int(x[1])
        if tau.plan_id > plan_id:
            plan_id, step = tau.plan_id, 0
            noise = _Noise(plan_id, plan_noise(self.seed, plan_id, tau.controls, self.noise))
            state.get_mutable_abstract_state(self._eps).set_value(noise)
        if step < tau.m and tau.plan_id == plan_id:
            u = tau.controls[step] + noise.eps[step]
            x[:] = [plan_id, step + 1, 0.0, *u]
        else:
            x[:] = [plan_id, step, 1.0] + [0.0] * NU
        state.get_mutable_discrete_state().get_mutable_vector(self._x).SetFromVector(x)

    def _calc_u(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state(self._x).get_value()[3:])

    def _calc_status(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state(self._x).get_value()[:3])
