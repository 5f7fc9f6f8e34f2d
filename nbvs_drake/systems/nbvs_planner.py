"""NBVSPlanner: plans the next best view/state after each scan."""

from __future__ import annotations

import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..motion import ControlSequence
from ..planning.random_sampling import PlanResult, RandomSamplingPlanner
from ..registration import Correction


class PlannerMemory:
    """Immutable planner state: the last plan, the believed state, the last report."""

    def __init__(self, controls: ControlSequence, believed: np.ndarray, planned_for_scan: int = 0,
                 report: dict | None = None, stop_reason: str = ""):
        self.controls = controls
        self.believed = np.asarray(believed, float)
        self.planned_for_scan = planned_for_scan
        self.report = report or {}
        self.stop_reason = stop_reason

    def __deepcopy__(self, memo):
        return self


#: PlanResult.status -> the run's stop_reason when the planner finds no view
STOP_REASONS = {"no_candidate": "no_valid_candidate", "no_path": "no_path",
                "no_feasible": "no_feasible_under_noise"}


class NBVSPlanner(LeafSystem):
    """After each new scan: first the belief is corrected by the scan's registration (the
    mapper's pose_correction for this scan); then the stop criteria (seed 000 §7.5, seed 001
    §3.6): the scan budget (max_scans), the unknown voxels of W_box below
    mission.stop_unknown_voxels (unknown_below_threshold); otherwise it plans the NBVS from
    the believed state with the configured strategy (random_sampling: seed 000 §7.6 filter
    cascade, g = pos * reg * sur * dist) and emits its control sequence — unless no candidate
    survives the filters (no_valid_candidate), none can be reached (no_path), the expected
    utility finds every reachable one unfeasible under the motion noise
    (no_feasible_under_noise), the best
    candidate's information term is below mission.stop_min_surface
    (surface_below_threshold) or its utility below mission.stop_min_utility
    (score_below_threshold). The belief after a plan is the plan's final state (dead
    reckoning) until the next scan's registration corrects it.

    Input ports:
      - map (abstract OccupancyMap).
      - pose_correction (4): [scan index, dx, dy, dyaw] from the mapper's registration.
      - pose_covariance (9, optional): the belief's planar pose covariance (3x3 row-major)
        from the mapper; the expected utility's rollouts start from that spread. Unconnected:
        the belief is taken as exact.
    Output ports:
      - controls (abstract ControlSequence): the current plan tau (plan_id 0: none yet).
      - believed_state (8): where the robot believes it is.
      - report (abstract dict): the last plan's report (chosen state, utility factors,
        candidates per filter stage, time per stage, stop reason).
      - stopped (1): 1 once the mission is over.
    State: abstract PlannerMemory.
    """

    def __init__(self, sc: Scenario, planner: RandomSamplingPlanner, q0):
        super().__init__()
        self.sc = sc
        self.planner = planner
        dt = sc.robot.control_dt
        mem = PlannerMemory(ControlSequence.empty(q0, dt), q0)
        self._map = self.DeclareAbstractInputPort("map", AbstractValue.Make(OccupancyMap.for_scenario(sc)))
        self._corr = self.DeclareVectorInputPort("pose_correction", 4)
        self._cov = self.DeclareVectorInputPort("pose_covariance", 9)
        self._mem = self.DeclareAbstractState(AbstractValue.Make(mem))
        self.DeclareAbstractOutputPort("controls", lambda: AbstractValue.Make(mem.controls), self._calc_controls,
                                       {self.abstract_state_ticket(self._mem)})
        self.DeclareVectorOutputPort("believed_state", 8, self._calc_belief, {self.abstract_state_ticket(self._mem)})
        self.DeclareAbstractOutputPort("report", lambda: AbstractValue.Make({}), self._calc_report,
                                       {self.abstract_state_ticket(self._mem)})
        self.DeclareVectorOutputPort("stopped", 1, self._calc_stopped, {self.abstract_state_ticket(self._mem)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _mem_of(self, context) -> PlannerMemory:
        return context.get_abstract_state(self._mem).get_value()

    def _update(self, context, state):
        mem = self._mem_of(context)
        if mem.stop_reason:
            return
        omap: OccupancyMap = self._map.Eval(context)
        k = omap.scan_count
        if k <= mem.planned_for_scan:
            return
        corr = self._corr.Eval(context)
        believed = mem.believed
        if int(round(corr[0])) == k:
            believed = Correction(*corr[1:]).apply_state(believed)
        states = {"believed_state": [round(float(v), 6) for v in mem.believed],
                  "corrected_state": [round(float(v), 6) for v in believed]}
        mi = self.sc.mission
        if k >= mi.max_scans:
            new = PlannerMemory(mem.controls, believed, k, {"scan": k, "status": "stop", **states}, "max_scans")
        elif mi.stop_unknown_voxels and omap.unknown_count() < mi.stop_unknown_voxels:
            new = PlannerMemory(mem.controls, believed, k, {"scan": k, "status": "stop", **states},
                                "unknown_below_threshold")
        else:
            rng = np.random.default_rng([self.sc.seed, 1, k])
            t = time.perf_counter()
            cov = self._cov.Eval(context).reshape(3, 3) if self._cov.HasValue(context) else None
            res: PlanResult = self.planner.plan(omap, believed, rng, start_cov=cov)
            rep = {"scan": k, **res.to_json(), "plan_s": time.perf_counter() - t, **states}
            if cov is not None and np.any(cov != 0):  # the belief's spread the plan started from
                rep["start_sigma"] = [round(float(v), 5) for v in np.sqrt(np.maximum(np.diag(cov), 0.0))]
            info = res.factors.get("sur", res.factors.get("info", float("inf")))
            if res.status != "ok":
                reason = STOP_REASONS[res.status]
                new = PlannerMemory(mem.controls, believed, k, rep, reason)
            elif mi.stop_min_surface and info < mi.stop_min_surface:
                new = PlannerMemory(mem.controls, believed, k, rep, "surface_below_threshold")
            elif mi.stop_min_utility and res.utility < mi.stop_min_utility:
                new = PlannerMemory(mem.controls, believed, k, rep, "score_below_threshold")
            else:
                tau = ControlSequence(mem.controls.plan_id + 1, self.sc.robot.control_dt, res.controls, res.states)
                rep["plan_id"] = tau.plan_id
                rep["motion_sim_s"] = tau.m * tau.dt
                new = PlannerMemory(tau, res.states[-1], k, rep)
        state.get_mutable_abstract_state(self._mem).set_value(new)

    def _calc_controls(self, context, output):
        output.set_value(self._mem_of(context).controls)

    def _calc_belief(self, context, output: BasicVector):
        output.SetFromVector(self._mem_of(context).believed)

    def _calc_report(self, context, output):
        mem = self._mem_of(context)
        output.set_value({**mem.report, "stop_reason": mem.stop_reason})

    def _calc_stopped(self, context, output: BasicVector):
        output.SetFromVector([1.0 if self._mem_of(context).stop_reason else 0.0])
