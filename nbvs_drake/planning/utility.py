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

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..motion import wrap_angle
from .expected_utility import expected_utility, sample_count_bound
from .interface import PlanRequest, PlanResult
from .motion_planner import MotionPlanner, ObstacleModel
from .views import ViewEvaluator, registration_overlap


class DeterministicUtility:
    """DU: the candidates keep the utility g they were ranked with."""
    name = "du"

    def score(self, request: PlanRequest, reachable: list[PlanResult], obstacles: ObstacleModel,
              un_total: int) -> tuple[list[PlanResult], int]:
        """(the feasible candidates with their utility, how many were feasible)."""
        return reachable, len(reachable)


class ExpectedUtilityScore:
    """EU: Algorithm 1 for each candidate with its control sequence (planner.eu_samples
    rollouts, planner.eu_weighting, planner.eu_max_collision_rate; the rollouts start from the
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
        self.stats = {"rollout_states": 0, "rollout_states_bounded": 0}
        p = sc.planner
        need = sample_count_bound(p.eu_alpha, p.eu_gamma)
        if p.eu_samples < need:
            import warnings
            warnings.warn(f"planner.eu_samples = {p.eu_samples} is below the eq. 18 bound {need} for "
                          f"alpha = {p.eu_alpha}, gamma = {p.eu_gamma}: collisions may go undetected", stacklevel=2)

    def state_utility(self, omap: OccupancyMap, states: np.ndarray, un_total: int, dist: float,
                      registration: bool = True) -> np.ndarray:
        """g = pos * reg * info * dist of states (N, 8) reached along a path of factor `dist`
        (pos: collision-free states only are passed in); registration False: reg = 1."""
        met = self.evaluator.evaluate(omap, states)
        g = self.evaluator.information(omap, states, met, self.sc.planner.metric, un_total)
        if registration and self.overlap_h is not None:
            g = g * (registration_overlap(met) > self.overlap_h)
        return g * dist

    def _clearance_test(self, nominal: np.ndarray, obstacles: ObstacleModel):
        """within(states (k, m, 8)) -> bool (k, m): the rollout states proved free because they
        stay within the clearance of the nominal state of the same step (clearance.py,
        `_clearance_one`: the robot moved rigidly in the plane by (dx, dy, dtheta) moves no
        point more than hypot(dx, dy) + R |dtheta|, less than the nominal state's distance to
        every obstacle). Only states whose arm equals the nominal's qualify (the Table 4 noise
        leaves the arm exact); the others, and every state without a certificate, are checked."""
        cert = obstacles.collision.certificate
        if cert is None or not self.motion.bulk_checks:
            return lambda s: np.zeros(s.shape[:2], bool)
        t = time.perf_counter()
        cl = cert.clearance(nominal)
        self.checks_s += time.perf_counter() - t
        d, R = cl[:, 0], cl[:, 1]

        def within(s):
            dxy = np.hypot(s[..., 0] - nominal[:, 0], s[..., 1] - nominal[:, 1])
            dth = np.abs(wrap_angle(s[..., 2] - nominal[:, 2]))
            return (dxy + R * dth < d) & np.all(s[..., 3:] == nominal[:, 3:], axis=-1)
        return within

    def expected(self, request: PlanRequest, cand: PlanResult, obstacles: ObstacleModel, un_total: int):
        """Algorithm 1 for one candidate."""
        p = self.sc.planner
        # the nominal path's escape from a colliding start
        skip = self.motion.escape_prefix(cand.states, obstacles) or 0
        within = self._clearance_test(cand.states[1:], obstacles)
        m = len(cand.controls)

        def free(s):  # rows: rollouts x states 1..m
            t = time.perf_counter()
            s = np.asarray(s, float).reshape(-1, m, 8)
            ok = within(s)
            todo = ~ok
            if skip:
                todo[:, :skip - 1] = False  # states 1..skip-1 of each rollout
                ok[:, :skip - 1] = True
            ok[todo] = obstacles.free(s[todo])
            self.stats["rollout_states"] += ok.size
            self.stats["rollout_states_bounded"] += ok.size - int(todo.sum())
            self.checks_s += time.perf_counter() - t
            return ok.reshape(-1)
        omap = request.omap
        return expected_utility(
            request.q_start, cand.controls, self.sc.robot.control_dt, p.eu_samples, self.sc.noise, request.rng,
            free, lambda s: self.state_utility(omap, s, un_total, cand.factors["dist"], p.eu_rollout_registration),
            weighting=p.eu_weighting, max_collision_rate=p.eu_max_collision_rate, start_cov=request.start_cov)

    def score(self, request: PlanRequest, reachable: list[PlanResult], obstacles: ObstacleModel,
              un_total: int) -> tuple[list[PlanResult], int]:
        n_feasible = 0
        for r in reachable:
            eu = self.expected(request, r, obstacles, un_total)
            r.factors["eu"] = eu.to_json()
            r.utility = eu.value
            n_feasible += eu.feasible
        return [r for r in reachable if r.factors["eu"]["feasible"]], n_feasible


def make_utility(sc: Scenario, evaluator: ViewEvaluator, motion: MotionPlanner, overlap_h: float | None):
    """The scenario's utility strategy (planner.utility)."""
    if sc.planner.utility == "eu":
        return ExpectedUtilityScore(sc, evaluator, motion, overlap_h)
    return DeterministicUtility()


def select_best(batches: Iterable[tuple[list[PlanResult], int]], utility, request: PlanRequest,
                obstacles: ObstacleModel, un_total: int, stages: dict, times: dict) -> PlanResult | None:
    """The ranking loop (Vasquez-Gomez et al. 2017 §7.6 steps 7-8): `batches` yields, batch
    after batch of the ranking (planner.top_k each), the candidates that have a path and how
    many were tried; each batch is scored by the utility; the first batch with a feasible
    candidate gives the best one. Fills stages (motion_tried, with_path, eu_feasible) and
    times (motion_s, expected_utility_s); the best result's `candidates` lists every
    feasible candidate scored on the way."""
    t = time.perf_counter()
    if hasattr(utility, "checks_s"):
        utility.checks_s = 0.0
    best = None
    kept = []
    n_path = n_tried = n_feasible = 0
    t_utility = 0.0
    for reachable, tried in batches:
        n_tried += tried
        n_path += len(reachable)
        tu = time.perf_counter()
        feasible, n = utility.score(request, reachable, obstacles, un_total)
        n_feasible += n
        t_utility += time.perf_counter() - tu
        kept += [(r.q_goal, r.utility) for r in feasible]
        for r in feasible:
            if best is None or r.utility > best.utility:
                best = r
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
    return best
