"""Random sampling of the next best view/state (Vasquez-Gomez et al. 2017, §7.6): candidates
from a generator (uniform states whose director ray meets W_box; or Santos et al. 2020's
conditional view sampling), the position filter (Drake collision), visibility (ray casting in
the map), the registration filter (reg, eq. 5), the information term, ranking, the top k to
motion planning, and the utility g = pos * reg * info * dist (or its expectation under motion
noise); the best candidate is the NBVS."""

from __future__ import annotations

import time

import numpy as np

from ..config import Scenario
from ..mapping import view_metrics as K
from ..motion import path_length
from .candidates import free_candidates
from .interface import PlanRequest, PlanResult
from .motion_planner import MotionPlanner, ObstacleModel, PlanningObstacles
from .utility import select_best
from .views import ViewEvaluator, registration_overlap


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
        p = self.sc.planner
        omap, rng = request.omap, request.rng
        times, stages = {}, {}
        obstacles: ObstacleModel = self.obstacles.for_map(omap)
        stages.update(obstacles.stats)
        cand = free_candidates(self.generator, obstacles, rng, omap, stages, times)

        t = time.perf_counter()
        met = self.evaluator.evaluate(omap, cand)
        times["visibility_s"] = time.perf_counter() - t
        un, oc, post = met[:, K.M_UN_O], met[:, K.M_OC_O], met[:, K.M_N_POSTERIOR]
        stages["visibility"] = int(np.count_nonzero(met[:, K.M_RAYS] > 0))
        overlap = registration_overlap(met)
        reg = overlap > self.overlap_h if self.overlap_h is not None else np.ones(len(cand), bool)
        stages["registration"] = int(reg.sum())
        un_total = max(omap.unknown_count(), 1)
        info = self.evaluator.information(omap, cand, met, p.metric, un_total)
        keep = reg & (info > 0)
        stages["surface"] = int(keep.sum())
        if not np.any(keep):
            return PlanResult("no_candidate", stages=stages, times=times)

        ranked = np.flatnonzero(keep)
        ranked = ranked[np.argsort(-info[ranked], kind="stable")]

        def batches():
            """Steps 7-8: the top k go to motion planning; when none of them can be reached (or,
            with the expected utility, none is feasible under noise), the next k of the
            ranking, until one qualifies or the ranking runs out."""
            for start in range(0, len(ranked), p.top_k):
                reachable = []
                batch = ranked[start:start + p.top_k]
                # one search for the whole batch (planner.motion_planner)
                for i, found in zip(batch, self.motion.connect_many(request.q_start, cand[batch], obstacles, rng)):
                    if found is None:
                        continue
                    kind, controls, states = found
                    rho = path_length(states, p.weights)
                    dist = 1.0 / (1.0 + rho) if p.use_distance else 1.0
                    du = 1.0 * 1.0 * info[i] * dist  # pos = reg = 1 for the survivors
                    reachable.append(PlanResult("ok", cand[i], controls, states, kind, float(du), {
                        "pos": 1.0, "reg": 1.0, "info": float(info[i]), "metric": p.metric, "dist": float(dist),
                        "rho": float(rho), "un_o": int(un[i]), "un_touched": int(un[i] + post[i]), "oc_o": int(oc[i]),
                        "overlap": float(overlap[i]),
                        "un_total": int(un_total), "du": float(du)}))
                yield reachable, len(batch)

        best = select_best(batches(), self.utility, request, obstacles, un_total, stages, times)
        stages["top_k"] = min(p.top_k, len(ranked))
        if best is None:
            return PlanResult("no_feasible" if stages["with_path"] else "no_path", stages=stages, times=times)
        best.stages, best.times = stages, times
        return best
