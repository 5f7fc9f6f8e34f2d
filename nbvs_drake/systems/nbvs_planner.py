"""NBVSPlanner: plans the next best view/state after each scan."""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from ..config import MissionConfig, Scenario
from ..mapping.occupancy import OccupancyMap
from ..planning.interface import Planner, PlanRequest, PlanResult
from ..stage_clock import NBV_PLAN, VERIFICATION, stage
from ..world.motion import ControlSequence, LegRule
from .messages import Belief, PlanReport, rounded_state


class PlannerMemory:
    """Immutable planner state: the last plan, the scan it answered, the last report."""

    def __init__(self, controls: ControlSequence, planned_for_scan: int = 0, report: PlanReport | None = None,
                 answered_frame: int = 0, target: np.ndarray | None = None, legs: tuple = (),
                 recovery_s: float = 0.0, replanned: bool = False):
        self.controls = controls
        self.planned_for_scan = planned_for_scan
        self.report = report or PlanReport()
        #: the belief's last frame answered (mission.verify_views) and the view being verified
        self.answered_frame = answered_frame
        self.target = target
        #: mission.legs: the planned states where the legs still to go end (before the target)
        self.legs = legs
        #: seconds spent answering localisation frames (corrections, legs, re-localisation views)
        #: since the last scan's report
        self.recovery_s = recovery_s
        #: localisation.verified_views.replan: the view of this scan was planned afresh once
        self.replanned = replanned

    def __deepcopy__(self, memo):
        return self


#: PlanResult.status -> the run's stop_reason when the planner finds no view
STOP_REASONS = {"no_candidate": "no_valid_candidate", "no_path": "no_path",
                "no_feasible": "no_feasible_under_noise"}


class NBVSPlanner(LeafSystem):
    """After each new scan (a map with more scans than the last plan answered, and the
    Localisation's belief after that scan): first the stop criteria (Vasquez-Gomez et al. 2017
    §7.5, Santos et al. 2020 §3.6): the scan budget (max_scans), the unknown voxels of W_box
    below mission.stop_unknown_voxels (unknown_below_threshold); otherwise it plans the NBVS
    from the believed state with the configured strategy (a `Planner`) and emits its control
    sequence — unless no candidate survives the filters (no_valid_candidate), none can be
    reached (no_path), the expected utility finds every reachable one unfeasible under the
    motion noise (no_feasible_under_noise), the best candidate's information term is below
    mission.stop_min_surface (surface_below_threshold) or its utility below
    mission.stop_min_utility (score_below_threshold).

    With mission.verify_views and a `recovery` (planning/recovery.py), a localisation frame
    that asks for a correction (`Belief.check`) is answered by a plan back to the view being
    verified, and one that asks for re-localisation by a re-localisation view; neither
    counts as a plan of the scan budget (the report keeps its scan), and a frame that cannot
    be answered leaves the next frame to be the scan. With mission.legs the plan is emitted
    leg by leg (purpose "leg"): each frame at a leg's end is answered by a steering path from
    the corrected belief to the next leg's end, the last by the correction to the view.

    Input ports:
      - map (abstract OccupancyMap).
      - belief (abstract Belief): the Localisation's belief (state and planar covariance);
        the expected utility's rollouts start from its spread.
    Output ports:
      - controls (abstract ControlSequence): the current plan tau (plan_id 0: none yet).
      - report (abstract PlanReport): the last plan's report (chosen state, utility factors,
        candidates per filter stage, time per stage, stop reason).
      - stopped (1): 1 once the mission is over.
    State: abstract PlannerMemory.
    """

    @staticmethod
    def for_scenario(sc: Scenario, planner: Planner, q0, recovery=None) -> "NBVSPlanner":
        """The planner system of a scenario: each of its parts gets its own section."""
        vv = sc.localisation.verified_views
        legs = LegRule.of(vv, sc.noise, sc.robot.control_dt)
        return NBVSPlanner(sc.mission, legs, planner, q0, sc.robot.control_dt, sc.seed,
                           OccupancyMap.for_scene(sc.scene, sc.mapper), recovery,
                           replan=bool(vv is not None and vv.replan))

    def __init__(self, mission: MissionConfig, legs: LegRule, planner: Planner, q0, dt: float, seed: int,
                 empty_map: OccupancyMap, recovery=None, replan: bool = False):
        """`mission`: the stop criteria; `legs`: where plans' legs end (verified views under
        noise); `empty_map`: the map port's model value; `seed`: the plans' random draws;
        `replan`: a frame no path answers gets a fresh plan (localisation.verified_views.replan)."""
        super().__init__()
        self.mission, self.legs, self.dt, self.seed, self.replan = mission, legs, dt, seed, replan
        self.planner = planner
        self.recovery = recovery
        mem = PlannerMemory(ControlSequence.empty(q0, dt))
        self._map = self.DeclareAbstractInputPort("map", AbstractValue.Make(empty_map))
        self._belief = self.DeclareAbstractInputPort("belief", AbstractValue.Make(Belief.exact(q0)))
        self._mem = self.DeclareAbstractState(AbstractValue.Make(mem))
        self.DeclareAbstractOutputPort("controls", lambda: AbstractValue.Make(mem.controls), self._calc_controls,
                                       {self.abstract_state_ticket(self._mem)})
        self.DeclareAbstractOutputPort("report", lambda: AbstractValue.Make(PlanReport()), self._calc_report,
                                       {self.abstract_state_ticket(self._mem)})
        self.DeclareVectorOutputPort("stopped", 1, self._calc_stopped, {self.abstract_state_ticket(self._mem)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _mem_of(self, context) -> PlannerMemory:
        return context.get_abstract_state(self._mem).get_value()

    def _update(self, context, state):
        mem = self._mem_of(context)
        if mem.report.stop_reason:
            return
        omap: OccupancyMap = self._map.Eval(context)
        k = omap.scan_count
        if k <= mem.planned_for_scan:
            belief: Belief = self._belief.Eval(context)
            if belief.check and belief.frame > mem.answered_frame and self.recovery is not None:
                with stage(VERIFICATION, "recovery_planning"):
                    state.get_mutable_abstract_state(self._mem).set_value(self._recover(mem, omap, belief))
            return
        belief: Belief = self._belief.Eval(context)
        base = PlanReport(scan=k, believed_state=rounded_state(belief.dead_reckoned),
                          corrected_state=rounded_state(belief.state),
                          recovery_s=round(mem.recovery_s, 4) if mem.recovery_s else None)
        mi = self.mission
        if k >= mi.max_scans:
            new = PlannerMemory(mem.controls, k, dc.replace(base, status="stop", stop_reason="max_scans"))
        elif mi.stop_unknown_voxels and omap.reachable_unknown_count() < mi.stop_unknown_voxels:
            new = PlannerMemory(mem.controls, k, dc.replace(base, status="stop", stop_reason="unknown_below_threshold"))
        else:
            rng = np.random.default_rng([self.seed, 1, k])
            t = time.perf_counter()
            cov = belief.covariance
            with stage(NBV_PLAN, "plan"):
                res: PlanResult = self.planner.plan(PlanRequest(omap, belief.state, rng, cov))
            plan_s = time.perf_counter() - t
            sigma = None
            if np.any(cov != 0):  # the belief's spread the plan started from
                sigma = [round(float(v), 5) for v in np.sqrt(np.maximum(np.diag(cov), 0.0))]
            rep = PlanReport(k, res.status, "", res.to_json(), plan_s, base.believed_state, base.corrected_state, sigma,
                             recovery_s=base.recovery_s)
            info = res.factors.get("info", float("inf"))
            if res.status != "ok":
                new = PlannerMemory(mem.controls, k, dc.replace(rep, stop_reason=STOP_REASONS[res.status]))
            elif mi.stop_min_surface and info < mi.stop_min_surface:
                new = PlannerMemory(mem.controls, k, dc.replace(rep, stop_reason="surface_below_threshold"))
            elif mi.stop_min_utility and res.utility < mi.stop_min_utility:
                new = PlannerMemory(mem.controls, k, dc.replace(rep, stop_reason="score_below_threshold"))
            else:
                tau, legs = self._first_of(res, mem.controls.plan_id + 1)
                rep = dc.replace(rep, plan_id=tau.plan_id, motion_sim_s=len(res.controls) * tau.dt)
                new = PlannerMemory(tau, k, rep, belief.frame, res.states[-1], legs)
        state.get_mutable_abstract_state(self._mem).set_value(new)

    def _first_of(self, res: PlanResult, plan_id: int) -> tuple[ControlSequence, tuple]:
        """A view's plan as it is emitted: its first leg (purpose "leg", or "view" when it has
        one), targeting the plan's end, and the planned states where its later legs end."""
        ends = self._legs(res.controls)
        first = ends[0]
        tau = ControlSequence(plan_id, self.dt, res.controls[:first], res.states[:first + 1],
                              "leg" if len(ends) > 1 else "view", res.states[-1])
        return tau, tuple(res.states[e] for e in ends[1:-1])

    def _legs(self, controls) -> list[int]:
        """Where the plan's legs end (`LegRule`: verified views' legs under noise), else [m]."""
        if self.recovery is None:
            return [len(controls)]
        return self.legs.ends(controls)

    def _recover(self, mem: PlannerMemory, omap: OccupancyMap, belief: Belief) -> PlannerMemory:
        """The answer to a localisation frame: a correction back to the view being verified or
        a re-localisation view (`Recovery`), emitted as the next plan with the same target;
        without a path, the last plan stays (its frame is re-taken as the scan: the controller
        is idle, so the Localisation takes the next plan's end; here none comes, so the view is
        given up and the frame count reaches max_recoveries)."""
        t0 = time.perf_counter()
        rng = np.random.default_rng([self.seed, 17, belief.frame])
        legs = mem.legs
        if belief.check == "relocalise":
            res = self.recovery.relocalise(omap, belief.state, belief.covariance, rng)
        else:
            res = None
            if legs:  # on to the end of the next leg, from where the frame put the robot
                res = self.recovery.leg(omap, belief.state, legs[0], belief.covariance)
                legs = legs[1:]
                if res.status == "ok":  # legs.after_turns: a long turn back onto the line is a leg
                    res, legs = self._first_leg(res, legs)
            if res is None or res.status != "ok":
                legs = ()
                res = self.recovery.correct(omap, belief.state, mem.target, belief.covariance)
        if res.status != "ok" and belief.check == "correct" and self.replan and not mem.replanned:
            again = self._replan(mem, omap, belief, t0)
            if again is not None:
                return again
        if res.status != "ok":
            # nothing to execute: an empty plan ends at once where the robot is, and its frame
            # is taken again (counted towards mission.max_recoveries)
            res.controls, res.states = np.zeros((0, 7)), np.asarray(belief.state, float)[None]
            res.factors = {"purpose": "stay"}
        purpose = res.factors.get("purpose", "view")
        tau = ControlSequence(mem.controls.plan_id + 1, self.dt, res.controls, res.states,
                              "relocalise" if purpose == "stay" else purpose, mem.target)
        return PlannerMemory(tau, mem.planned_for_scan, mem.report, belief.frame, mem.target, legs,
                             mem.recovery_s + time.perf_counter() - t0, mem.replanned)

    def _replan(self, mem: PlannerMemory, omap: OccupancyMap, belief: Belief, t0: float) -> PlannerMemory | None:
        """localisation.verified_views.replan: the next view planned afresh from the registered
        belief (the scan's plan made again, its seed drawn from the frame), emitted leg by leg
        as a scan's plan is; the report's plan becomes it (the prediction the scan is judged by)
        and says that it was re-planned. None when the planner finds no view either."""
        rng = np.random.default_rng([self.seed, 23, belief.frame])
        res: PlanResult = self.planner.plan(PlanRequest(omap, belief.state, rng, belief.covariance))
        if res.status != "ok":
            return None
        tau, legs = self._first_of(res, mem.controls.plan_id + 1)
        result = {**res.to_json(), "replanned_at_frame": int(belief.frame)}
        rep = dc.replace(mem.report, result=result, plan_id=tau.plan_id, motion_sim_s=len(res.controls) * tau.dt)
        return PlannerMemory(tau, mem.planned_for_scan, rep, belief.frame, res.states[-1], legs,
                             mem.recovery_s + time.perf_counter() - t0, replanned=True)

    def _first_leg(self, res: PlanResult, legs: tuple) -> tuple[PlanResult, tuple]:
        """A re-planned leg (turn, drive, turn) cut after its first turn when that is a leg of
        its own (legs.after_turns, `LegRule.turn_ends`): that turn, and the leg's end
        ahead of `legs`."""
        ends = self.legs.turn_ends(res.controls)
        if len(ends) == 1:
            return res, legs
        rest = tuple(res.states[e] for e in ends[1:])
        res.controls, res.states = res.controls[:ends[0]], res.states[:ends[0] + 1]
        return res, rest + legs

    def _calc_controls(self, context, output):
        output.set_value(self._mem_of(context).controls)

    def _calc_report(self, context, output):
        output.set_value(self._mem_of(context).report)

    def _calc_stopped(self, context, output: BasicVector):
        output.SetFromVector([1.0 if self._mem_of(context).report.stop_reason else 0.0])
