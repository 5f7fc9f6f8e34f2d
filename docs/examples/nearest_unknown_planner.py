"""A next-best-view planner as a plug-in: the reachable view that sees the most unknown
voxels per metre of path. It uses the project's parts (state sampler, view evaluator,
obstacles, motion planner) and nothing else of the package changes.

Run it (from this folder, or with it on PYTHONPATH):

    nbvs reconstruct --planner nearest_unknown_planner:NearestUnknownPlanner --out results/nearest

or name it in a scenario:

    planner:
      strategy: !Plugin
        entry: nearest_unknown_planner:NearestUnknownPlanner
        options: {samples: "300"}
"""

import numpy as np

from nbvs_drake.mapping import view_metrics as K
from nbvs_drake.planning import PlanResult
from nbvs_drake.planning.motion_planner import reached_goal
from nbvs_drake.world.motion import path_length


class NearestUnknownPlanner:
    def __init__(self, parts, samples: int = 400, top: int = 10):
        self.parts, self.samples, self.top = parts, int(samples), int(top)

    def plan(self, request):
        p = self.parts
        obstacles = p.obstacles.for_map(request.omap).for_paths()
        q = p.sampler.sample_states(request.rng, self.samples)
        q = q[p.sampler.looks_at_wbox(q)]
        q = q[obstacles.free(q)]
        if not len(q):
            return PlanResult("no_candidate")
        seen = p.evaluator.evaluate(request.omap, q)[:, K.M_UN_O]  # unknown voxels each view sees first
        order = np.argsort(-seen, kind="stable")[:self.top]
        order = order[seen[order] > 0]
        if not len(order):
            return PlanResult("no_candidate")
        best = None
        for i, found in zip(order, p.motion.connect_many(request.q_start, q[order], obstacles, request.rng)):
            if found is None:
                continue
            kind, controls, states = found
            rho = path_length(states, p.sc.planner.weights)
            g = float(seen[i] / (1.0 + rho))
            if best is None or g > best.utility:
                best = PlanResult("ok", reached_goal(p.sc, q[i], states), controls, states, kind, g,
                                  {"info": float(seen[i]), "rho": float(rho), "un_o": int(seen[i])})
        return best or PlanResult("no_path")
