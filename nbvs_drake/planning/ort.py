"""The Object Reconstruction Tree (seed 003, Algorithms 2-3): a tree grown from the current
state like an RRT for k vertices; every vertex is evaluated with the utility (its distance
factor from the tree path); the best vertex is the NBVS and its tree path the trajectory."""

from __future__ import annotations

import time

import numpy as np

from ..mapping import kernels as K
from ..mapping.occupancy import OccupancyMap
from ..motion import rollout
from .random_sampling import PlanResult, RandomSamplingPlanner, director_ray_hits, registration_overlap
from .rrt import Tree, extend


class ORTPlanner(RandomSamplingPlanner):
    """Shares the state sampler, collision model and view evaluator of random sampling. The
    vertices are evaluated in one batch after the tree is grown: a vertex's evaluation does
    not steer the growth, so this equals evaluating each vertex as it is added."""

    def targets(self, rng: np.random.Generator):
        """Random states whose director ray meets W_box (seed 000 §7.6 step 1): the tree grows
        towards states that look at the object (seed 003's proposed bias to the view space)."""
        bmin, bmax = self.sc.scene.bbox_min, self.sc.scene.bbox_max
        while True:
            batch = self.sample_states(rng, 4096)
            ok = director_ray_hits(self.kin.camera_poses(batch), bmin, bmax, self.z_near, self.z_far)
            yield from batch[ok]

    def tree_path_free(self, states: np.ndarray) -> bool:
        """Tree edges are checked at 4 cm resolution."""
        return self.path_free(states, max_step=0.04)

    def grow(self, q_current: np.ndarray, rng: np.random.Generator) -> tuple[Tree, int]:
        p = self.sc.planner
        w = np.asarray(p.weights)
        tree = Tree(np.asarray(q_current, float), p.ort_vertices)
        it = 0
        targets = self.targets(rng)
        while tree.n < p.ort_vertices + 1 and it < 20 * p.ort_vertices:
            it += 1
            extend(tree, next(targets), p.tree_step, w, self.sc.robot, self.tree_path_free, self.kin.clip_arm)
        return tree, it

    def plan(self, omap: OccupancyMap, q_current: np.ndarray, rng: np.random.Generator,
             start_cov: np.ndarray | None = None) -> PlanResult:  # start_cov: no EU here
        p = self.sc.planner
        times, stages = {}, {}
        stages.update(self.update_obstacles(omap))
        t = time.perf_counter()
        tree, it = self.grow(q_current, rng)
        times["tree_s"] = time.perf_counter() - t
        stages["iterations"] = it
        stages["vertices"] = tree.n - 1
        if tree.n < 2:
            return PlanResult("no_candidate", stages=stages, times=times)

        t = time.perf_counter()
        q = tree.q[1: tree.n]
        met = self.evaluator.evaluate(omap, q)
        times["visibility_s"] = time.perf_counter() - t
        overlap = registration_overlap(met)
        reg = overlap > self.overlap_threshold()
        un_total = max(omap.unknown_count(), 1)
        info = self.evaluator.information(omap, q, met, p.metric, un_total)
        rho = tree.cost[1: tree.n]
        dist = 1.0 / (1.0 + rho) if p.use_distance else np.ones_like(rho)
        g = reg * info * dist
        stages["registration"] = int(reg.sum())
        stages["surface"] = int(np.count_nonzero(reg & (info > 0)))
        b = int(np.argmax(g))
        if g[b] <= 0:
            return PlanResult("no_candidate", stages=stages, times=times)
        i = b + 1
        controls = tree.controls_to(i)
        states = rollout(tree.q[0], controls, self.sc.robot.control_dt)
        factors = {"pos": 1.0, "reg": 1.0, "info": float(info[b]), "metric": p.metric, "dist": float(dist[b]),
                   "rho": float(rho[b]), "un_o": int(met[b, K.M_UN_O]), "oc_o": int(met[b, K.M_OC_O]),
                   "overlap": float(overlap[b]), "un_total": int(un_total), "du": float(g[b]),
                   "depth": len(tree.path_to(i)) - 1}
        # the root's children, for reference: the NBVS is at least as good as the best of them
        children = np.flatnonzero(tree.parent[1: tree.n] == 0)
        factors["best_root_child"] = float(g[children].max()) if len(children) else 0.0
        return PlanResult("ok", tree.q[i].copy(), controls, states, "ort", float(g[b]), factors, stages, times)
