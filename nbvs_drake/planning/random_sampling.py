"""Random sampling of the next best view/state (Vasquez-Gomez et al. 2017, §7.6): candidates
from a generator (uniform states whose director ray meets W_box; or Santos et al. 2020's
conditional view sampling), the position filter (Drake collision), visibility (ray casting in
the map), the registration filter (reg, eq. 5), the information term, ranking, the top k to
motion planning, and the utility g = pos * reg * info * dist (or its expectation under motion
noise); the best candidate is the NBVS."""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np

from ..config import Scenario
from ..mapping import view_metrics as K
from ..world.motion import path_length
from .candidates import free_candidates
from .interface import PlanRequest, PlanResult, distance_factor
from .motion_planner import MotionPlanner, ObstacleModel, PlanningObstacles, reached_goal
from .utility import select_best
from .views import ViewEvaluator, ranking_score, registration_overlap


class RandomSamplingPlanner:
    """Composes a candidate generator (`generate(rng, omap) -> (states, raw samples)`), the view
    evaluator, the per-plan obstacles, the motion planner and the utility strategy.
    overlap_h: the registration filter's threshold h (None: no registration filter, as in
    Santos et al. 2020, whose robot knows the arm's pose)."""

    def __init__(self, sc: Scenario, generator, evaluator: ViewEvaluator, obstacles: PlanningObstacles,
                 motion: MotionPlanner, utility, overlap_h: float | None):
        self.sc = sc
        self.generator = generator
        self.evaluator = evaluator
        self.obstacles = obstacles
        self.motion = motion
        self.utility = utility
        self.overlap_h = overlap_h

    def plan(self, request: PlanRequest) -> PlanResult:
        res = self._plan(request, self.generator)
        margin = True
        if res.status == "no_feasible" and getattr(self.sc.planner.utility, "clearance", 0.0) > 0:
            # planner.utility.clearance: no candidate is feasible with the rollouts' margin; the
            # plan made again, with new draws, under Algorithm 1's rule (and so the arm-only
            # views after it, whose motion is exact anyway)
            margin = False
            res = _made_again(res, self._plan(request, self.generator, margin), None, "with_clearance", res.stages)
            res.factors = dict(res.factors, clearance="dropped")
        if res.status in ("no_feasible", "no_path") and self.sc.planner.noise_fallback:
            # planner.noise_fallback: views from where the robot is, by the arm alone (its
            # motion is exact under Table 4's noise), before the run gives up
            fb = self._plan(request, _ArmOnly(self.sc, self.evaluator.kin, request.q_start), margin)
            fb = _made_again(res, fb, res.stages, "fallback", fb.stages)
            fb.factors = dict(fb.factors, fallback="arm_only", **({} if margin else {"clearance": "dropped"}))
            if fb.status != "ok":
                fb.status = res.status
            return fb
        return res

    def _plan(self, request: PlanRequest, generator, margin: bool = True) -> PlanResult:
        """One attempt; margin False: the rollouts under Algorithm 1's rule, without
        planner.utility.clearance (the plan's obstacles without their `rollouts`)."""
        p = self.sc.planner
        omap, rng = request.omap, request.rng
        times, stages = {}, {}
        obstacles: ObstacleModel = self.obstacles.for_map(omap)
        if not margin:
            obstacles = dc.replace(obstacles, rollouts=None)
        stages.update(obstacles.stats)
        # planner.obstacles.base_clearance: the positions and the paths keep the base clear of the
        # environment; the expected utility's rollouts meet the true obstacles. The arm-only
        # views keep the base where it stands, which the noise may have left nearer than that:
        # their positions and paths meet the true obstacles (the padded ones would refuse every
        # arm configuration there, and the run would stop)
        own = generator is self.generator
        paths = obstacles.for_paths() if own else obstacles
        # planner.free_candidates: the scenario's generator only (not the arm-only fallback's)
        want = p.free_candidates if own else 0
        cand = free_candidates(generator, paths, rng, omap, stages, times, want)

        un_total = max(omap.unknown_count(), 1)

        t = time.perf_counter()
        if p.metric == "seed001":  # its own ray casting: no coarse pass
            met = self.evaluator.evaluate(omap, cand)
            order = None
        else:  # the candidates ranked by reg * info (coarse to fine with planner.coarse_stride())
            met, order = self.evaluator.evaluate_ranked(
                omap, cand, ranking_score(self.evaluator, omap, p.metric, self.overlap_h, un_total))
        times["visibility_s"] = time.perf_counter() - t
        un, oc, post = met[:, K.M_UN_O], met[:, K.M_OC_O], met[:, K.M_N_POSTERIOR]
        stages["visibility"] = int(np.count_nonzero(met[:, K.M_RAYS] > 0))
        overlap = registration_overlap(met)
        reg = overlap > self.overlap_h if self.overlap_h is not None else np.ones(len(cand), bool)
        stages["registration"] = int(reg.sum())
        info = self.evaluator.information(omap, cand, met, p.metric, un_total)
        keep = reg & (info > 0)
        stages["surface"] = int(keep.sum())
        if not np.any(keep):
            return PlanResult("no_candidate", stages=stages, times=times)

        if order is None:
            ranked = np.flatnonzero(keep)
            ranked = ranked[np.argsort(-info[ranked], kind="stable")]
        else:
            ranked = order[keep[order]]

        def batches():
            """Steps 7-8: the top k go to motion planning; when none of them can be reached (or,
            with the expected utility, none is feasible under noise), the next k of the
            ranking, until one qualifies or the ranking runs out."""
            for start in range(0, len(ranked), p.top_k):
                reachable = []
                batch = ranked[start:start + p.top_k]
                # one search for the whole batch (planner.motion_planner)
                for i, found in zip(batch, self.motion.connect_many(request.q_start, cand[batch], paths, rng)):
                    if found is None:
                        continue
                    kind, controls, states = found
                    rho = path_length(states, p.weights)
                    dist = distance_factor(rho, p.use_distance)
                    du = 1.0 * 1.0 * info[i] * dist  # pos = reg = 1 for the survivors
                    reachable.append(PlanResult("ok", reached_goal(self.sc, cand[i], states), controls, states, kind,
                                                float(du), {
                        "pos": 1.0, "reg": 1.0, "info": float(info[i]), "metric": p.metric, "dist": float(dist),
                        "rho": float(rho), "un_o": int(un[i]), "un_touched": int(un[i] + post[i]), "oc_o": int(oc[i]),
                        "overlap": float(overlap[i]),
                        "un_total": int(un_total), "du": float(du)}, path_nodes=found.nodes))
                yield reachable, len(batch)

        best = select_best(batches(), self.utility, request, obstacles, un_total, stages, times, p.gain_tolerance)
        stages["top_k"] = min(p.top_k, len(ranked))
        if best is None:
            return PlanResult("no_feasible" if stages["with_path"] else "no_path", stages=stages, times=times)
        best.factors["un_near"] = self.evaluator.near_range_unknown(omap, best.q_goal)
        best.stages, best.times = stages, times
        return best


def _made_again(first: PlanResult, then: PlanResult, stages: dict | None, key: str, nested: dict) -> PlanResult:
    """`then`, a plan made after `first` failed, with `stages` (None: its own) and the other
    attempt's stages `nested` under `key`, and the times of both attempts added."""
    then.stages = dict(then.stages if stages is None else stages, **{key: nested})
    then.times = {k: first.times.get(k, 0.0) + then.times.get(k, 0.0) for k in set(first.times) | set(then.times)}
    return then


class _ArmOnly:
    """planner.noise_fallback's candidates: the current base with arm configurations uniform
    within the joint limits whose director ray meets W_box (planner.n_candidates of them at
    most, from 4 x as many draws)."""

    def __init__(self, sc: Scenario, kin, q_now: np.ndarray):
        from .candidates import StateSampler
        self.sampler = StateSampler(sc, kin)
        self.q_now = np.asarray(q_now, float)

    def generate(self, rng: np.random.Generator, omap=None) -> tuple[np.ndarray, int]:
        from .recovery import arm_only_candidates
        n = self.sampler.sc.planner.n_candidates
        q = arm_only_candidates(self.sampler.kin, self.q_now, 4 * n, rng)
        return q[self.sampler.looks_at_wbox(q)][:n], 4 * n
