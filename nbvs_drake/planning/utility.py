"""The utility as a strategy: how the candidates that have a path are scored.

- `DeterministicUtility` ("du"): g = pos * reg * info * dist of the candidate itself
  (Vasquez-Gomez et al. 2017 eq. 4); the strategies compute it while they rank.
- `ExpectedUtilityScore` ("eu"): Algorithm 1 of Vasquez-Gomez et al. 2017 (§7.2): k rollouts
  of the candidate's controls under the scenario's motion noise, each checked for collision
  with the plan's obstacles, their final states scored with g; a candidate whose rollouts
  collide is unfeasible.

`select_best` is the ranking loop every strategy shares (§7.6 steps 7-8): batches of ranked
candidates go through motion planning and the utility until one qualifies.
"""

from __future__ import annotations

import time
from typing import Iterable

import numpy as np

from ..config import Expected, Scenario
from ..mapping.occupancy import OccupancyMap
from ..world.motion import LegRule
from . import path_verdicts
from .certificate import FREE, UNKNOWN
from .expected_utility import expected_utility, rescored, sample_count_bound
from .interface import PlanRequest, PlanResult
from .motion_planner import MotionPlanner, ObstacleModel
from .views import ViewEvaluator, registration_overlap


class DeterministicUtility:
    """DU: the candidates keep the utility g they were ranked with."""
    name = "du"

    def score(self, request: PlanRequest, reachable: list[PlanResult], obstacles: ObstacleModel,
              un_total: int, gain_tolerance: float = 1.0) -> tuple[list[PlanResult], int]:
        """(the feasible candidates with their utility, how many were feasible)."""
        return reachable, len(reachable)


class ExpectedUtilityScore:
    """EU: Algorithm 1 for each candidate with its control sequence (planner.utility.samples
    rollouts, planner.utility.weighting, planner.utility.max_collision_rate; the rollouts start from the
    belief's spread `request.start_cov`). Each rollout's final state is scored with
    g = reg * info * dist (reg only with planner.eu_rollout_registration)."""
    name = "eu"

    def __init__(self, sc: Scenario, evaluator: ViewEvaluator, motion: MotionPlanner, overlap_h: float | None):
        self.sc = sc
        self.evaluator = evaluator
        self.motion = motion
        self.overlap_h = overlap_h
        #: seconds spent checking rollouts for collision (reset by `select_best` per plan)
        self.checks_s = 0.0
        p = sc.planner
        #: the rollouts' settings: the expected utility's, or its defaults where the scorer
        #: only checks paths (the recovery paths of a deterministic planner)
        self.u = p.utility if isinstance(p.utility, Expected) else Expected()
        #: where each plan's legs end (their rollouts start from each leg's re-localised start)
        self.legs = LegRule.of(sc.localisation.verified_views, sc.noise, sc.robot.control_dt)
        need = sample_count_bound(self.u.alpha, self.u.gamma)
        if self.u.samples < need:
            import warnings
            warnings.warn(f"planner.utility.samples = {self.u.samples} is below the eq. 18 bound {need} for "
                          f"alpha = {self.u.alpha}, gamma = {self.u.gamma}: collisions may go undetected", stacklevel=2)

    def state_utility(self, omap: OccupancyMap, states: np.ndarray, un_total: int, dist: float,
                      registration: bool = True, coarse: bool = False) -> np.ndarray:
        """g = pos * reg * info * dist of states (N, 8) reached along a path of factor `dist`
        (pos: collision-free states only are passed in); registration False: reg = 1; coarse:
        their views evaluated by the coarse pass (`ViewEvaluator.evaluate_coarse`)."""
        met = (self.evaluator.evaluate_coarse if coarse else self.evaluator.evaluate)(omap, states)
        g = self.evaluator.information(omap, states, met, self.sc.planner.metric, un_total)
        if registration and self.overlap_h is not None:
            g = g * (registration_overlap(met) > self.overlap_h)
        return g * dist

    def _rollout_verdicts(self, nominal: np.ndarray, obstacles: ObstacleModel):
        """verdicts(states (k, L, 8), steps (L,)) -> int8 (k, L): FREE, COLLIDING or UNKNOWN
        (Drake decides) of the rollout states at those steps of the plan (1..m), by
        `path_verdicts.rollout_verdicts`: a state that differs from the nominal state of its step by a
        planar rigid motion (the Table 4 noise leaves the arm exact) has the nominal's
        self-distances, and only the parts of the robot that the motion may bring within their
        clearance (clearance.py, `_part_clearances`) are tested against the environment. Without
        a certificate (or bulk checks) every state is UNKNOWN."""
        cert = obstacles.collision.certificate
        if cert is None or not self.motion.bulk_checks:
            return lambda s, steps: np.full(s.shape[:2], UNKNOWN, np.int8)
        nominal = np.ascontiguousarray(nominal, float)
        col = obstacles.collision
        # per nominal state, found once for all the rollouts where they are first asked: whether
        # it is proved free, and its parts' clearances
        P, M = cert.n_parts(), len(cert.e_p)
        known = np.zeros(len(nominal), bool)
        nom_free = np.zeros(len(nominal), bool)
        c, r, slack = np.empty((len(nominal), P)), np.empty((len(nominal), P)), np.empty((len(nominal), P, M))

        def verdicts(s, steps):
            i = steps - 1
            new = i[~known[i]]
            if len(new):
                nom_free[new] = path_verdicts.states_free(nominal[new], *cert.model)
                c[new], r[new], slack[new] = cert.part_box_clearances(nominal[new])
                known[new] = True
            return path_verdicts.rollout_verdicts(np.ascontiguousarray(s, float), np.ascontiguousarray(i, np.int64),
                                                  nominal, nom_free, c, r, slack, *cert.model, col.counter)
        return verdicts

    def registered_cov(self, belief_cov=None) -> np.ndarray:
        """The registration's own spread (planner.eu_registered_sigma), plus the belief's
        `belief_cov` (3, 3) when given: with verified views every rollout starts from it, a
        registered belief being only as good as the registration."""
        cov = np.diag(np.square(np.asarray(self.sc.localisation.verified_views.registered_sigma, float)))
        return cov if belief_cov is None else np.asarray(belief_cov, float) + cov

    def leg_cov(self) -> np.ndarray:
        """The spread a later leg's rollouts start from: the registration's, and with
        mission.leg_turns also one control step of corrective turn (the re-planned leg turns
        back onto its line before it drives, and a turn's noise is per step)."""
        cov = self.registered_cov()
        vv = self.sc.localisation.verified_views
        if vv is not None and vv.legs is not None and vv.legs.after_turns:
            cov[2, 2] += (self.sc.noise.sigma_w * self.sc.robot.control_dt) ** 2
        return cov

    def uses_legs(self) -> bool:
        """mission.legs with verified views under motion noise: plans run in legs."""
        return self.legs.on

    def coarse_rollouts(self) -> bool:
        """Whether the rollouts' views are scored coarse to fine: the evaluator has a coarse
        pass (planner.evaluator.coarse_stride) and the rollouts' final states are scored by
        their views (without verified views; with them, by the landmarks they keep in view)."""
        return self.evaluator.coarse is not None and self.sc.localisation.verified_views is None

    def expected(self, request: PlanRequest, cand: PlanResult, obstacles: ObstacleModel, un_total: int,
                 coarse: bool = False):
        """Algorithm 1 for one candidate. With legs (`uses_legs`, `LegRule`) each leg's
        rollouts start from its nominal start (the first from the belief and its spread, the
        others re-localised by the frame at the previous leg's end); the candidate is feasible
        when every leg is, and its value is the last leg's. coarse: the final states' views
        by the coarse pass (`coarse_rollouts`)."""
        omap = request.omap
        if self.sc.localisation.verified_views is not None:
            final_utility = self._verified_utility(request, cand)
        else:
            def final_utility(s):
                return self.state_utility(omap, s, un_total, cand.factors["dist"], True, coarse)
        ends = self.legs.ends(cand.controls)
        start, checked, collided, eu = 0, 0, 0, None
        for j, end in enumerate(ends):
            last = j == len(ends) - 1
            if self.sc.localisation.verified_views is None:
                cov = request.start_cov if j == 0 else None
            else:
                cov = self.registered_cov(request.start_cov) if j == 0 else self.leg_cov()
            eu = self._expected_leg(request, cand.controls[start:end], cand.states[start:end + 1], obstacles, cov,
                                    final_utility if last else (lambda s: np.ones(len(s))), escape=j == 0)
            checked, collided = checked + eu.rollouts_checked, collided + eu.collided_rollouts
            if not eu.feasible or last:
                break
            start = end
        eu.rollouts_checked, eu.collided_rollouts = checked, collided
        return eu

    def rollouts_free(self, controls: np.ndarray, states: np.ndarray, obstacles: ObstacleModel, cov,
                      rng: np.random.Generator, k: int) -> bool:
        """Whether k rollouts of `controls` from states[0] moved by draws of `cov` (3, 3) are
        free at every state (Algorithm 1's feasibility, no collision allowed): the check of
        a path no expected utility scores (mission.recovery_rollouts)."""
        eu = self._expected_leg(PlanRequest(None, states[0], rng, cov), controls, states, obstacles, cov,
                                lambda s: np.ones(len(s)), k=k, max_collision_rate=0.0, free_start=True,
                                clearance=False)
        return eu.feasible

    def _expected_leg(self, request: PlanRequest, controls: np.ndarray, states: np.ndarray, obstacles: ObstacleModel,
                      start_cov, final_utility, escape: bool = True, k: int | None = None,
                      max_collision_rate: float | None = None, free_start: bool | None = None,
                      clearance: bool = True):
        """Algorithm 1 over one stretch of a plan: controls (m, 7) from states[0], its nominal
        states (m+1, 8); k, max_collision_rate and free_start (planner.utility.free_start) default
        to the planner's; clearance: the rollouts keep planner.utility.clearance from the
        obstacles (`obstacles.rollouts`, None when a plan is made again without it)."""
        k = self.u.samples if k is None else k
        rate = self.u.max_collision_rate if max_collision_rate is None else max_collision_rate
        stand = obstacles  # where the rollouts' starts may stand (the true obstacles)
        if clearance and obstacles.rollouts is not None:
            obstacles = obstacles.rollouts  # planner.utility.clearance: every body keeps the margin
        # the nominal path's escape from a colliding start
        skip = (self.motion.escape_prefix(states, obstacles) or 0) if escape else 0
        verdicts = self._rollout_verdicts(states[1:], obstacles)
        m = len(controls)

        def block_free(s, steps):  # s: rollouts x steps (1..m) of the plan
            t = time.perf_counter()
            v = verdicts(s, steps)
            ok = v == FREE
            todo = v == UNKNOWN  # Drake decides (through the certificate)
            if skip:  # states 1..skip-1 of each rollout: the nominal path's escape
                todo[:, steps < skip] = False
                ok[:, steps < skip] = True
            ok[todo] = obstacles.free(s[todo])
            self.checks_s += time.perf_counter() - t
            return ok

        def free(s):  # rows: rollouts x states 1..m
            return block_free(np.asarray(s, float).reshape(-1, m, 8), np.arange(1, m + 1)).reshape(-1)
        return expected_utility(
            states[0], controls, self.sc.robot.control_dt, k, self.sc.noise, request.rng,
            free, final_utility,
            weighting=self.u.weighting, max_collision_rate=rate, start_cov=start_cov,
            block_free=block_free if self.motion.bulk_checks else None,
            start_free=stand.free if (self.u.free_start if free_start is None else free_start) else None)

    def _verified_utility(self, request: PlanRequest, cand: PlanResult):
        """The utility of a rollout's final state when views are verified (mission.verify_views,
        planning/recovery.py): the robot re-aims at the planned view before it scans, so the
        scan's information is the candidate's own g; what the drift risks is the localisation
        frame that finds the error. A rollout counts with g times the share of the planned
        view's registration landmarks (the object seen so far, the known environment) that
        stay in its field of view (at most 1): a drift that loses them costs a re-localisation."""
        from .recovery import landmark_normals, landmark_solids, landmarks_in_view, registration_landmarks
        key = request.omap.scan_count
        if getattr(self, "_marks_key", None) != key:
            self._marks = registration_landmarks(self.sc, request.omap.object_points,
                                                 np.random.default_rng([self.sc.seed, 19, key]),
                                                 object_normals=landmark_normals(self.sc, request.omap))
            self._marks_key = key
            self._solids = landmark_solids(self.sc)
        kin, marks, solids = self.evaluator.kin, self._marks, self._solids
        nominal = max(float(landmarks_in_view(kin, self.sc, cand.states[-1:], marks, solids=solids)[0]), 1e-9)
        g = cand.utility
        return lambda s: g * np.minimum(1.0, landmarks_in_view(kin, self.sc, s, marks, solids=solids) / nominal)

    def score(self, request: PlanRequest, reachable: list[PlanResult], obstacles: ObstacleModel,
              un_total: int, gain_tolerance: float = 1.0) -> tuple[list[PlanResult], int]:
        """Algorithm 1 for each candidate of a batch. With `coarse_rollouts`, coarse to fine:
        every candidate's rollouts are scored by the coarse pass, then the best candidate's
        again at the full ray stride (the same rollouts), until the best is one scored at full
        stride: the chosen view's E(x) is exact and above every other estimate (among the views
        `choose` keeps with `gain_tolerance`, as select_best chooses)."""
        n_feasible = 0
        coarse = self.coarse_rollouts()
        pending = {}
        for r in reachable:
            eu = self.expected(request, r, obstacles, un_total, coarse)
            r.factors["eu"] = eu.to_json()
            r.utility = eu.value
            n_feasible += eu.feasible
            if coarse and eu.feasible:
                pending[id(r)] = eu
        feasible = [r for r in reachable if r.factors["eu"]["feasible"]]
        while pending:
            best = choose(feasible, gain_tolerance)  # as select_best takes it
            eu = pending.pop(id(best), None)
            if eu is None:
                break
            dist = best.factors["dist"]
            fine = rescored(eu, lambda s, d=dist: self.state_utility(request.omap, s, un_total, d))
            best.factors["eu"] = dict(fine.to_json(), eu_coarse=eu.value)
            best.utility = fine.value
        return feasible, n_feasible


def make_utility(sc: Scenario, evaluator: ViewEvaluator, motion: MotionPlanner, overlap_h: float | None):
    """The scenario's utility strategy (planner.utility)."""
    if sc.planner.is_expected():
        return ExpectedUtilityScore(sc, evaluator, motion, overlap_h)
    return DeterministicUtility()


def choose(results: list[PlanResult], gain_tolerance: float = 1.0) -> PlanResult | None:
    """The candidate of highest utility g (the first of the highest) among those whose gain
    g / dist(x) is at least (1 - gain_tolerance) x the best gain of `results`
    (planner.gain_tolerance): the travel factor decides only between views of about the best
    gain. gain_tolerance 1: among all, g as eq. 4 writes it; 0: the best gain (the nearest of
    equal gains). None when `results` is empty."""
    if not results:
        return None
    gains = [r.utility / r.factors.get("dist", 1.0) for r in results]
    floor = (1.0 - gain_tolerance) * max(gains)
    best = None
    for r, g in zip(results, gains):
        if g >= floor and (best is None or r.utility > best.utility):
            best = r
    return best


def select_best(batches: Iterable[tuple[list[PlanResult], int]], utility, request: PlanRequest,
                obstacles: ObstacleModel, un_total: int, stages: dict, times: dict,
                gain_tolerance: float = 1.0) -> PlanResult | None:
    """The ranking loop (Vasquez-Gomez et al. 2017 §7.6 steps 7-8): `batches` yields, batch
    after batch of the ranking (planner.top_k each), the candidates that have a path and how
    many were tried; each batch is scored by the utility; the first batch with a feasible
    candidate gives the best one (`choose`, with planner.gain_tolerance). Fills stages
    (motion_tried, with_path, eu_feasible) and times (motion_s, expected_utility_s); the best
    result's `candidates` lists every feasible candidate scored on the way."""
    t = time.perf_counter()
    if hasattr(utility, "checks_s"):
        utility.checks_s = 0.0
    best = None
    kept, alternatives = [], []
    n_path = n_tried = n_feasible = 0
    t_utility = 0.0
    for reachable, tried in batches:
        n_tried += tried
        n_path += len(reachable)
        tu = time.perf_counter()
        feasible, n = utility.score(request, reachable, obstacles, un_total, gain_tolerance)
        n_feasible += n
        t_utility += time.perf_counter() - tu
        kept += [(r.q_goal, r.utility) for r in feasible]
        alternatives += feasible
        best = choose(feasible, gain_tolerance)
        if best is not None:
            break
    eu = utility.name == "eu"
    times["motion_s"] = time.perf_counter() - t - (t_utility if eu else 0.0)
    # motion planning = the path search and every collision check (the rollouts' included);
    # the rest of the expected utility is view evaluation of the rollouts' final states
    times["motion_planning_s"] = times["motion_s"]
    if eu:
        times["expected_utility_s"] = t_utility
        times["eu_checks_s"] = utility.checks_s
        times["motion_planning_s"] += utility.checks_s
        stages["eu_feasible"] = n_feasible
    times["view_evaluation_s"] = times.get("visibility_s", 0.0) + (
        t_utility - utility.checks_s if eu else 0.0)
    stages["motion_tried"] = n_tried
    stages["with_path"] = n_path
    if best is not None:
        best.candidates = kept
        best.alternatives = alternatives
    return best
