"""KinematicPlant: the PatrolBot + Katana as a discrete-time kinematic system."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from ..world.motion import euler_step
from ..world.robot import RobotKinematics
from ..world.state import NQ, NU


class KinematicPlant(LeafSystem):
    """Euler integration of Vasquez-Gomez et al. 2017 §6.2 every `dt`: x += v cos(theta) dt, y += v sin(theta) dt,
    theta += w_b dt, q_i += w_i dt (non-holonomic base, velocity-controlled arm).

    Input ports:
      - velocity (7): [v, w_b, w_1..w_5] applied over the next dt.
    Output ports:
      - state (8): q = [x, y, theta, q1..q5].
      - positions (plant.num_positions()): q in the MultibodyPlant's position order, for
        MultibodyPositionToGeometryPose (rendering and collision use the same model).
    State: discrete q (8).
    """

    def __init__(self, kin: RobotKinematics, q0, dt: float):
        super().__init__()
        self.kin = kin
        self.dt = float(dt)
        self._q = self.DeclareDiscreteState(np.asarray(q0, float))
        self._u = self.DeclareVectorInputPort("velocity", NU)
        self.DeclareVectorOutputPort("state", NQ, self._calc_state, {self.discrete_state_ticket(self._q)})
        self.DeclareVectorOutputPort("positions", kin.n_positions, self._calc_positions,
                                     {self.discrete_state_ticket(self._q)})
        self.DeclarePeriodicDiscreteUpdateEvent(self.dt, 0.0, self._update)

    def _update(self, context, discrete_state):
        q = context.get_discrete_state(self._q).get_value()
        u = self._u.Eval(context)
        discrete_state.get_mutable_vector(self._q).SetFromVector(euler_step(q, u, self.dt))

    def _calc_state(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state(self._q).get_value())

    def _calc_positions(self, context, output: BasicVector):
        output.SetFromVector(self.kin.to_positions(context.get_discrete_state(self._q).get_value()))
