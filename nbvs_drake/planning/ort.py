"""The Object Reconstruction Tree (the ORT paper, Vasquez-Gomez et al. 2018, Algorithms 2-3): a
tree grown from the believed state like an RRT for k vertices, towards random states that look
at W_box; every vertex is scored with the utility g = reg * info * dist (its distance factor
from the tree path); the best vertex is the NBVS and its tree path the trajectory. With
planner.utility "eu" the vertices are ranked by g and the best planner.top_k at a time are
scored by the expected utility of their tree paths (Vasquez-Gomez et al. 2017, Algorithm 1),
as random sampling does with its ranked candidates."""

from __future__ import annotations

import time

import numba
import numpy as np

from ..config import Scenario
from ..mapping import view_metrics as K
from ..world.motion import rollout, steer_together
from . import neighbours, steer_kernels, tree_growth
from .candidates import StateSampler
from .certificate import COLLIDING, FREE, UNKNOWN
from .interface import PlanRequest, PlanResult, distance_factor
from .motion_planner import MotionPlanner, ObstacleModel, PlanningObstacles, undecided_free
from .rrt import ITERATIONS_PER_VERTEX, Tree, extend_batch
from .utility import select_best
from .views import ViewEvaluator, ranking_score, registration_overlap, scaled_score


class ORTPlanner:
    """The vertices are evaluated in one batch after the tree is grown: a vertex's evaluation
    does not steer the growth, so this equals evaluating each vertex as it is added."""

    def __init__(self, sc: Scenario, sampler: StateSampler, evaluator: ViewEvaluator, obstacles: PlanningObstacles,
                 motion: MotionPlanner, utility, overlap_h: float):
        self.sc = sc
        self.sampler = sampler
        self.evaluator = evaluator
        self.obstacles = obstacles
        self.motion = motion
        self.utility = utility
        self.overlap_h = overlap_h

    def grow(self, q_current: np.ndarray, rng: np.random.Generator, obstacles: ObstacleModel) -> tuple[Tree, int]:
        p = self.sc.planner
        w = np.asarray(p.weights)
        tree = Tree(np.asarray(q_current, float), p.strategy.vertices, self.sc.robot)
        it = 0
        targets = self.sampler.targets(rng)
        paths_free = lambda paths: self.motion.tree_paths_free(paths, obstacles)  # noqa: E731
        budget = ITERATIONS_PER_VERTEX * p.strategy.vertices
        bulk_growth = self.motion.bulk_checks and obstacles.collision.certificate is not None
        grid = neighbours.TreeGrid(self.sc.robot.xy_bounds, tree.q.shape[0]) if bulk_growth else None
        # each vertex's clearance margins (path_verdicts._walk), where its edge's check computed them
        margins = np.full((tree.q.shape[0], obstacles.collision.certificate.margin_size), -1.0) \
            if bulk_growth else None
        while tree.n < p.strategy.vertices + 1 and it < budget:
            b = min(p.strategy.batch, budget - it)
            it += b
            batch = np.stack([next(targets) for _ in range(b)])
            if bulk_growth:
                self._extend_bulk(tree, batch, w, obstacles, grid, margins)
            else:
                extend_batch(tree, batch, p.tree_step, w, self.sc.robot, paths_free, self.sampler.kin.clip_arm)
        return tree, it

    def _extend_bulk(self, tree: Tree, batch: np.ndarray, w: np.ndarray, obstacles: ObstacleModel,
                     grid: neighbours.TreeGrid, margins: np.ndarray):
        """`extend_batch` with the steering and the checks of the whole batch in one numba call
        (tree_growth.tree_extensions: the same nearest vertices, edges and verdicts); the edges it
        cannot decide go through MotionPlanner.tree_paths_free (the certificate, then Drake).
        The same vertices are added in the same order (their eq. 8 lengths equal to ~1e-15
        relative); their controls are computed when a path needs them. `margins` keeps each
        vertex's clearance margins, so the edges from it start from them."""
        p, rc, kin = self.sc.planner, self.sc.robot, self.sampler.kin
        col = obstacles.collision
        grid.insert(tree.q, tree.n)
        with col.timed():
            near, aim, new, verdict, length, first, offsets, und, end = tree_growth.tree_extensions(
                tree.q, margins, np.ascontiguousarray(batch, float), w, p.tree_step, steer_kernels.robot_params(rc),
                kin.arm_lower, kin.arm_upper, *col.certificate.model, self.motion.tree_max_step,
                col.counter, *grid.arrays, 4 * numba.get_num_threads())
        unknown = np.flatnonzero(verdict == UNKNOWN)
        if len(unknown):  # Drake about the states the model could not decide (the rest proved free)
            asks = {b: und[offsets[b]:offsets[b + 1]] for b in unknown if not first[b]}
            for b, ok in undecided_free(asks, obstacles).items():
                verdict[b] = FREE if ok else COLLIDING
            whole = unknown[first[unknown]]  # the edge's first state undecided: the whole edge's checks
            if len(whole):
                states = [rollout(tree.q[near[b]], steer_together(tree.q[near[b]], aim[b], rc), rc.control_dt)
                          for b in whole]
                ok = self.motion.tree_paths_free(states, obstacles)
                verdict[whole] = np.where(ok, FREE, COLLIDING)
        for b in np.flatnonzero(verdict == FREE):
            if tree.n >= tree.q.shape[0]:
                break
            margins[tree.add(int(near[b]), new[b], None, float(length[b]), aim[b])] = end[b]

    def plan(self, request: PlanRequest) -> PlanResult:
        p = self.sc.planner
        omap = request.omap
        times, stages = {}, {}
        obstacles = self.obstacles.for_map(omap)
        stages.update(obstacles.stats)
        t = time.perf_counter()
        tree, it = self.grow(request.q_start, request.rng, obstacles)
        times["tree_s"] = time.perf_counter() - t
        stages["iterations"] = it
        stages["vertices"] = tree.n - 1
        if tree.n < 2:
            return PlanResult("no_candidate", stages=stages, times=times)

        t = time.perf_counter()
        q = tree.q[1: tree.n]
        un_total = max(omap.unknown_count(), 1)
        rho = tree.cost[1: tree.n]
        dist = distance_factor(rho, p.use_distance)
        if p.metric == "seed001":  # its own ray casting: no coarse pass
            met, order = self.evaluator.evaluate(omap, q), None
        else:  # the vertices ranked by g (coarse to fine with planner.coarse_stride())
            score = ranking_score(self.evaluator, omap, p.metric, self.overlap_h, un_total)
            met, order = self.evaluator.evaluate_ranked(omap, q, scaled_score(score, dist))
        times["visibility_s"] = time.perf_counter() - t
        overlap = registration_overlap(met)
        reg = overlap > self.overlap_h
        info = self.evaluator.information(omap, q, met, p.metric, un_total)
        g = reg * info * dist
        stages["registration"] = int(reg.sum())
        stages["surface"] = int(np.count_nonzero(reg & (info > 0)))
        # the root's children, for reference: the NBVS is at least as good as the best of them
        children = np.flatnonzero(tree.parent[1: tree.n] == 0)
        stages["best_root_child"] = float(g[children].max()) if len(children) else 0.0
        if order is None:
            ranked = np.flatnonzero(g > 0)
            ranked = ranked[np.argsort(-g[ranked], kind="stable")]  # the first is argmax(g)
        else:
            ranked = order[g[order] > 0]
        if len(ranked) == 0:
            return PlanResult("no_candidate", stages=stages, times=times)

        def vertex(b: int) -> PlanResult:
            i = b + 1
            controls = tree.controls_to(i)
            states = rollout(tree.q[0], controls, self.sc.robot.control_dt)
            return PlanResult("ok", tree.q[i].copy(), controls, states, "ort", float(g[b]), {
                "pos": 1.0, "reg": 1.0, "info": float(info[b]), "metric": p.metric, "dist": float(dist[b]),
                "rho": float(rho[b]), "un_o": int(met[b, K.M_UN_O]),
                "un_touched": int(met[b, K.M_UN_O] + met[b, K.M_N_POSTERIOR]), "oc_o": int(met[b, K.M_OC_O]),
                "overlap": float(overlap[b]), "un_total": int(un_total), "du": float(g[b]),
                "depth": len(tree.path_to(i)) - 1})

        batches = (([vertex(b) for b in ranked[s:s + p.top_k]], len(ranked[s:s + p.top_k]))
                   for s in range(0, len(ranked), p.top_k))
        best = select_best(batches, self.utility, request, obstacles, un_total, stages, times)
        stages["top_k"] = min(p.top_k, len(ranked))
        times["motion_planning_s"] += times["tree_s"]  # the tree's growth is its path search
        if best is None:
            return PlanResult("no_feasible", stages=stages, times=times)
        best.factors["un_near"] = self.evaluator.near_range_unknown(request.omap, best.q_goal)
        best.stages, best.times = stages, times
        return best
