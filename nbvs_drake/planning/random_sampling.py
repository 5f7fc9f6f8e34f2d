"""Seed 000's random sampling NBVS planner (§7.6): generate states whose director ray meets
W_box, position filter (Drake collision), visibility (ray casting in the map), registration
filter, surface factor, rank, keep the top k, plan a path to each, utility
g = pos * reg * sur * dist; the best candidate is the NBVS."""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np

from ..config import Scenario, resolve_sensor
from ..mapping import kernels as K
from ..mapping.occupancy import OccupancyMap
from ..motion import path_length, rollout, steer
from ..robot import RobotKinematics
from ..sensor import ray_directions
from .collision import CollisionModel
from .expected_utility import expected_utility, sample_count_bound


class ViewEvaluator:
    """Scores robot states by simulating their scans in the map (batch numba kernel)."""

    def __init__(self, kin: RobotKinematics, sc: Scenario, stride: int | None = None, hrt_a: int | None = None):
        self.kin = kin
        self.sensor = sc.sensor
        self.stride = stride or sc.planner.ray_stride
        self.hrt_a = sc.planner.hrt_a if hrt_a is None else hrt_a
        self.dirs, self.t_near, self.t_far = ray_directions(sc.sensor, self.stride)
        import numba
        self.n_chunks = max(1, numba.get_num_threads())

    def evaluate(self, omap: OccupancyMap, q: np.ndarray) -> np.ndarray:
        """Metrics (N, K.N_METRICS) of the states q (N, 8); see kernels.M_*."""
        q = np.atleast_2d(q)
        if len(q) == 0:
            return np.zeros((0, K.N_METRICS))
        X = self.kin.camera_poses(q)
        return self.evaluate_poses(omap, X)

    def seed001_score(self, omap: OccupancyMap, q: np.ndarray, w: float = 0.5) -> np.ndarray:
        """Seed 001's score of states q (voxel-sorted ray casting), within the sensor's range."""
        from ..mapping import seed001
        from ..sensor import intrinsics
        q = np.atleast_2d(q)
        if len(q) == 0:
            return np.zeros(0)
        X = self.kin.camera_poses(q)
        m = omap.model
        cls = K.classes_grid(np.ascontiguousarray(omap.logodds, dtype=np.float32), m.l_free, m.l_occ)
        wd, ht, fx, fy, cx, cy = intrinsics(self.sensor)
        s = resolve_sensor(self.sensor)
        res = seed001.voxel_sorted_views(cls, omap.spec.bmin.astype(np.float64), omap.spec.res,
                                         np.ascontiguousarray(X[:, :3, 3]), np.ascontiguousarray(X[:, :3, :3]),
                                         fx, fy, cx, cy, wd, ht, s.z_near, s.z_far, min(self.n_chunks, len(q)))
        outer, inner = seed001.unknown_volumes(cls == 1, omap.spec.res)
        return seed001.score(res[:, 0], res[:, 1], omap.spec.res, outer, inner, w)

    def information(self, omap: OccupancyMap, q: np.ndarray, met: np.ndarray, metric: str, un_total: int):
        """The information term of states q whose ray metrics are `met`."""
        if metric == "seed001":
            return self.seed001_score(omap, q)
        return information(met, metric, un_total)

    def evaluate_poses(self, omap: OccupancyMap, X: np.ndarray) -> np.ndarray:
        pos = np.ascontiguousarray(X[:, :3, 3])
        rot = np.ascontiguousarray(X[:, :3, :3])
        m = omap.model
        lo = np.ascontiguousarray(omap.logodds, dtype=np.float32)
        args = (omap.spec.bmin.astype(np.float64), omap.spec.res, pos, rot, self.dirs, self.t_near,
                self.t_far, m.l_free, m.l_occ, min(self.n_chunks, len(pos)))
        if self.hrt_a > 0:
            return K.evaluate_views_hrt(lo, self.hrt_a, *args)
        return K.evaluate_views(lo, *args)


@dc.dataclass
class PlanResult:
    #: "ok", "no_candidate" (nothing passed the filters), "no_path" (none reachable) or
    #: "no_feasible" (reachable, but every one unfeasible under the expected utility)
    status: str
    q_goal: np.ndarray | None = None
    controls: np.ndarray | None = None  #: (m, 7)
    states: np.ndarray | None = None  #: (m+1, 8) planned states
    path_kind: str = ""
    utility: float = 0.0
    factors: dict = dc.field(default_factory=dict)
    stages: dict = dc.field(default_factory=dict)  #: candidates surviving each filter
    times: dict = dc.field(default_factory=dict)  #: seconds per stage
    #: the candidates that reached motion planning with a path: (state, utility) each
    candidates: list = dc.field(default_factory=list)

    def to_json(self) -> dict:
        d = {"status": self.status, "utility": self.utility, "factors": self.factors,
             "stages": self.stages, "times": self.times, "path_kind": self.path_kind}
        if self.q_goal is not None:
            d["q_goal"] = [round(float(v), 6) for v in self.q_goal]
            d["n_controls"] = int(len(self.controls))
            step = max(1, len(self.states) // 60)
            path = np.concatenate([self.states[::step], self.states[-1:]])
            d["path"] = [[round(float(v), 4) for v in s] for s in path]
        if self.candidates:
            d["candidates"] = [{"q": [round(float(v), 4) for v in q], "g": round(float(g), 6)}
                               for q, g in self.candidates]
        return d


def registration_overlap(met: np.ndarray) -> np.ndarray:
    """Share of the simulated scan's returns in the map that land on known surface:
    oc_rays / (oc_rays + un_rays). reg(x) = 1 when this exceeds h (seed 000 eq. 5, measured
    per ray: ICP needs overlapping points, and distinct-voxel counts let the large side
    faces of the occlusion shadow behind a first scan veto every nearby view)."""
    oc, un = met[:, K.M_OC_RAYS], met[:, K.M_UN_RAYS]
    tot = oc + un
    return np.where(tot > 0, oc / np.maximum(tot, 1), 0.0)


def information(met: np.ndarray, metric: str, un_total: int) -> np.ndarray:
    """The information term I(x) of the utility, normalised by the unknown voxels (entropy
    metrics also by ln 2, a voxel's maximum entropy): sur = VUV = un_o (seed 000 eq. 6),
    fig, sig, rsv (seed 003)."""
    col = {"sur": K.M_UN_O, "vuv": K.M_VUV, "fig": K.M_FIG, "sig": K.M_SIG, "rsv": K.M_RSV}[metric]  # seed001: ViewEvaluator
    norm = un_total * (np.log(2.0) if metric in ("fig", "sig") else 1.0)
    return met[:, col] / max(norm, 1e-12)


def director_ray_hits(X: np.ndarray, bmin, bmax, t_near: float, t_far: float) -> np.ndarray:
    """Whether each camera's optical axis meets the box within [t_near, t_far] (it enters
    the box before t_far and leaves it after t_near)."""
    o = X[:, :3, 3]
    d = X[:, :3, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (np.asarray(bmin) - o) * inv
        tb = (np.asarray(bmax) - o) * inv
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return (t0 <= t1) & (t1 >= t_near) & (t0 <= t_far)


class RandomSamplingPlanner:
    def __init__(self, sc: Scenario, kin: RobotKinematics, collision: CollisionModel,
                 evaluator: ViewEvaluator | None = None):
        self.sc = sc
        self.kin = kin
        self.collision = collision
        self.evaluator = evaluator or ViewEvaluator(kin, sc)
        self._obstacles_for = None  #: scan count the voxel obstacles were built for
        s = resolve_sensor(sc.sensor)
        self.z_near = s.z_near
        self.z_far = min(s.z_far, sc.planner.max_view_distance or s.z_far)
        p = sc.planner
        if p.utility == "eu":
            need = sample_count_bound(p.eu_alpha, p.eu_gamma)
            if p.eu_samples < need:
                import warnings
                warnings.warn(f"planner.eu_samples = {p.eu_samples} is below the eq. 18 bound {need} for "
                              f"alpha = {p.eu_alpha}, gamma = {p.eu_gamma}: collisions may go undetected")

    def overlap_threshold(self) -> float:
        """h of the registration filter reg(x) (seed 000 eq. 5)."""
        return self.sc.planner.overlap_h

    def sample_states(self, rng: np.random.Generator, n: int) -> np.ndarray:
        lo, hi = self.sc.robot.xy_bounds
        q = np.empty((n, 8))
        q[:, 0:2] = rng.uniform(lo, hi, size=(n, 2))
        q[:, 2] = rng.uniform(-np.pi, np.pi, size=n)
        q[:, 3:] = rng.uniform(self.kin.arm_lower, self.kin.arm_upper, size=(n, 5))
        return q

    def generate(self, rng: np.random.Generator, omap: OccupancyMap | None = None) -> tuple[np.ndarray, int]:
        """Step 1: uniform samples of the state space whose director ray meets W_box. Returns
        (states, raw samples drawn)."""
        p = self.sc.planner
        bmin, bmax = self.sc.scene.bbox_min, self.sc.scene.bbox_max
        kept, raw = [], 0
        need = p.n_candidates
        while need > 0 and raw < p.max_generation_factor * p.n_candidates:
            batch = self.sample_states(rng, max(4 * need, 1024))
            raw += len(batch)
            ok = director_ray_hits(self.kin.camera_poses(batch), bmin, bmax, self.z_near, self.z_far)
            sel = batch[ok][:need]
            kept.append(sel)
            need -= len(sel)
        q = np.concatenate(kept) if kept else np.zeros((0, 8))
        return q, raw

    def update_obstacles(self, omap: OccupancyMap) -> dict:
        """With planner.map_obstacles = voxels, rebuild the collision model from the map's
        unknown and occupied voxels (once per scan). Returns stats for the report."""
        p = self.sc.planner
        if p.map_obstacles != "voxels" or self._obstacles_for == omap.scan_count:
            return {}
        t = time.perf_counter()
        boxes, block = omap.obstacle_boxes(p.max_obstacle_boxes)
        self.collision = CollisionModel(self.sc, self.kin, obstacle_boxes=boxes)
        self._obstacles_for = omap.scan_count
        return {"obstacle_boxes": len(boxes), "obstacle_block": block, "obstacles_s": time.perf_counter() - t}

    def plan(self, omap: OccupancyMap, q_current: np.ndarray, rng: np.random.Generator,
             start_cov: np.ndarray | None = None) -> PlanResult:
        """The NBVS from the believed state q_current. start_cov (3, 3): the belief's planar
        pose covariance (zero after a registered scan); the expected utility's rollouts start
        from that spread."""
        p = self.sc.planner
        times, stages = {}, {}
        stages.update(self.update_obstacles(omap))
        t = time.perf_counter()
        cand, raw = self.generate(rng, omap)
        stages["sampled"] = raw
        stages["director_ray"] = len(cand)
        times["generate_s"] = time.perf_counter() - t

        t = time.perf_counter()
        cand = cand[self.collision.free(cand)]
        stages["position"] = len(cand)
        times["position_s"] = time.perf_counter() - t

        t = time.perf_counter()
        met = self.evaluator.evaluate(omap, cand)
        times["visibility_s"] = time.perf_counter() - t
        un, oc = met[:, K.M_UN_O], met[:, K.M_OC_O]
        stages["visibility"] = int(np.count_nonzero(met[:, K.M_RAYS] > 0))
        overlap = registration_overlap(met)
        reg = overlap > self.overlap_threshold()
        stages["registration"] = int(reg.sum())
        un_total = max(omap.unknown_count(), 1)
        sur = self.evaluator.information(omap, cand, met, p.metric, un_total)
        keep = reg & (sur > 0)
        stages["surface"] = int(keep.sum())
        if not np.any(keep):
            return PlanResult("no_candidate", stages=stages, times=times)

        ranked = np.flatnonzero(keep)
        ranked = ranked[np.argsort(-sur[ranked], kind="stable")]

        # steps 7-8: the top k go to motion planning; when none of them can be reached (or,
        # with the expected utility, none is feasible under noise), the next k of the ranking
        # are tried, until one qualifies or the ranking runs out
        t = time.perf_counter()
        best = None
        kept = []
        n_path = n_tried = n_eu_feasible = 0
        t_eu = 0.0
        for start in range(0, len(ranked), p.top_k):
            reachable = []
            for i in ranked[start:start + p.top_k]:
                n_tried += 1
                found = self.connect(q_current, cand[i], rng)
                if found is None:
                    continue
                kind, controls, states = found
                rho = path_length(states, p.weights)
                dist = 1.0 / (1.0 + rho) if p.use_distance else 1.0
                du = 1.0 * 1.0 * sur[i] * dist  # pos = reg = 1 for the survivors
                reachable.append(PlanResult("ok", cand[i], controls, states, kind, float(du), {
                    "pos": 1.0, "reg": 1.0, "sur": float(sur[i]), "dist": float(dist), "rho": float(rho),
                    "un_o": int(un[i]), "oc_o": int(oc[i]), "overlap": float(overlap[i]),
                    "un_total": int(un_total), "du": float(du)}))
            n_path += len(reachable)
            if p.utility == "eu":
                te = time.perf_counter()
                for r in reachable:
                    eu = self.expected_utility(omap, q_current, r, un_total, rng, start_cov)
                    r.factors["eu"] = eu.to_json()
                    r.utility = eu.value
                    n_eu_feasible += eu.feasible
                reachable = [r for r in reachable if r.factors["eu"]["feasible"]]
                t_eu += time.perf_counter() - te
            kept += [(r.q_goal, r.utility) for r in reachable]
            for r in reachable:
                if best is None or r.utility > best.utility:
                    best = r
            if best is not None:
                break
        times["motion_s"] = time.perf_counter() - t - t_eu
        if p.utility == "eu":
            times["expected_utility_s"] = t_eu
            stages["eu_feasible"] = n_eu_feasible
        stages["top_k"] = min(p.top_k, len(ranked))
        stages["motion_tried"] = n_tried
        stages["with_path"] = n_path
        if best is None:
            return PlanResult("no_feasible" if n_path else "no_path", stages=stages, times=times)
        best.stages, best.times, best.candidates = stages, times, kept
        return best

    def state_utility(self, omap: OccupancyMap, states: np.ndarray, un_total: int, dist: float,
                      registration: bool = True) -> np.ndarray:
        """g = pos * reg * sur * dist of states (N, 8) reached along a path of factor `dist`
        (pos: collision-free states only are passed in); registration False: reg = 1."""
        met = self.evaluator.evaluate(omap, states)
        g = self.evaluator.information(omap, states, met, self.sc.planner.metric, un_total)
        if registration:
            g = g * (registration_overlap(met) > self.overlap_threshold())
        return g * dist

    def expected_utility(self, omap: OccupancyMap, q0: np.ndarray, cand: PlanResult, un_total: int,
                         rng: np.random.Generator, start_cov: np.ndarray | None = None):
        """Algorithm 1 for one candidate with its control sequence."""
        p = self.sc.planner
        skip = self.escape_prefix(cand.states) or 0  # the nominal path's escape from a colliding start
        free = self.collision.free
        if skip:
            def free(s, m=len(cand.controls)):  # rows: rollouts x states 1..m
                ok = np.array(self.collision.free(s), bool).reshape(-1, m)
                ok[:, :skip - 1] = True  # states 1..skip-1 of each rollout
                return ok.reshape(-1)
        return expected_utility(
            q0, cand.controls, self.sc.robot.control_dt, p.eu_samples, self.sc.noise, rng,
            free, lambda s: self.state_utility(omap, s, un_total, cand.factors["dist"], p.eu_rollout_registration),
            weighting=p.eu_weighting, max_collision_rate=p.eu_max_collision_rate, start_cov=start_cov)

    #: a believed start state in collision (the belief is uncertain; W_box is a conservative
    #: obstacle) may be left within this many control steps; the rest of the path is checked
    max_escape_steps: int = 15

    def escape_prefix(self, states: np.ndarray) -> int | None:
        """0 when the path starts collision-free; else the index of its first free state if
        that comes within max_escape_steps, else None."""
        if self.collision.free(states[:1])[0]:
            return 0
        head = states[: self.max_escape_steps + 1]
        free = np.flatnonzero(self.collision.free(head))
        return int(free[0]) if len(free) else None

    def path_free(self, states: np.ndarray, max_step: float = 0.02) -> bool:
        """Arm limits, then the end state alone (one check rejects most failing tree
        extensions), then the whole path at `max_step` resolution; a path that fails only
        because its start state is in collision is accepted when it leaves the collision
        within the escape prefix and is free from there on."""
        if not np.all(self.kin.arm_within_limits(states)) or not self.collision.free(states[-1:])[0]:
            return False
        if self.collision.path_free(states, max_step=max_step):
            return True
        start = self.escape_prefix(states)
        return bool(start) and self.collision.path_free(states[start:], max_step=max_step)

    def connect(self, q0: np.ndarray, q1: np.ndarray, rng: np.random.Generator | None = None):
        """A collision-free path from q0 to q1: (kind, controls, states) or None. The steering
        function's direct paths first (a tree that connects at its first extension); then
        RRT Ext-Ext with up to planner.rrt_max_nodes vertices."""
        dt = self.sc.robot.control_dt
        for kind, controls in steer(q0, q1, self.sc.robot):
            states = rollout(q0, controls, dt)
            if self.path_free(states):
                return kind, controls, states
        p = self.sc.planner
        if p.rrt_max_nodes > 0 and rng is not None:
            from .rrt import rrt_ext_ext
            res = rrt_ext_ext(q0, q1, self.sc.robot, np.asarray(p.weights), self.sample_states, self.path_free,
                              self.kin.clip_arm, rng, max_nodes=p.rrt_max_nodes, step=p.tree_step)
            if res.found:
                return "rrt", res.controls, res.states
        return None
