"""CollisionMonitor: detects real collisions of the executed (true) motion."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from ..planning.collision import CollisionModel
from ..stage_clock import SIMULATOR, stage
from ..world.state import NQ
from .messages import ControllerStatus


class CollisionMonitor(LeafSystem):
    """Checks the true robot state against the true world (environment, the real object mesh,
    self-collision) with Drake every dt, and counts executed trajectories and those that
    collided (a trajectory counts once however long it stays in contact).

    Input ports:
      - state (8): the true robot state.
      - controller_status (3): `ControllerStatus`.
    Output ports:
      - counts (3): [collided trajectories, executed trajectories, in collision now].
      - collision_state (8): the true state at which the last collision began (the state the
        check found in contact; the plant has moved one step on when the run stops).
    State: discrete [collided, executed, last plan_id, current trajectory collided, now]; the
    state at the last collision's start (8).
    """

    def __init__(self, truth: CollisionModel, dt: float):
        super().__init__()
        self.truth = truth
        self._q = self.DeclareVectorInputPort("state", 8)
        self._status = self.DeclareVectorInputPort("controller_status", ControllerStatus.SIZE)
        self._x = self.DeclareDiscreteState(np.zeros(5))
        self._hit = self.DeclareDiscreteState(np.zeros(NQ))
        self.DeclareVectorOutputPort("counts", 3, self._calc, {self.discrete_state_ticket(self._x)})
        self.DeclareStateOutputPort("collision_state", self._hit)
        self.DeclarePeriodicDiscreteUpdateEvent(dt, 0.0, self._update)

    def _update(self, context, discrete_state):
        collided, executed, last_plan, cur, _ = context.get_discrete_state(self._x).get_value()
        status = ControllerStatus.of(self._status.Eval(context))
        if status.plan_id > last_plan:
            executed += 1
            last_plan = status.plan_id
            cur = 0.0
        now = 0.0
        q = self._q.Eval(context)
        if not status.idle or cur > 0:  # only motion can cause new contact
            with stage(SIMULATOR, "collision_monitor"):
                now = 0.0 if self.truth.free(q)[0] else 1.0
        if now and not cur and last_plan > 0:
            cur = 1.0
            collided += 1
            discrete_state.get_mutable_vector(self._hit).SetFromVector(q)
        discrete_state.get_mutable_vector(self._x).SetFromVector([collided, executed, last_plan, cur, now])

    def _calc(self, context, output: BasicVector):
        x = context.get_discrete_state(self._x).get_value()
        output.SetFromVector([x[0], x[1], x[4]])
