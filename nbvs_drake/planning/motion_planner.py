"""The motion planner: collision-free paths from the believed state to a candidate, as exact
control sequences (the steering function's direct paths, optionally paths through a detour
waypoint, then RRT Ext-Ext, Vasquez-Gomez et al. 2017 §7.4), and the path checks the trees
use. The obstacles are passed per plan: an `ObstacleModel` holds the collision model of one
plan's world (the known environment plus W_box, or the map's unknown and occupied voxels after
a given scan)."""

from __future__ import annotations

import dataclasses as dc
import itertools
import time

import numpy as np

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..world.motion import detour_waypoints, path_length, rollout, steer, steer_arc, steer_together, steer_via
from ..world.robot import RobotKinematics
from . import steer_kernels
from .candidates import StateSampler
from .certificate import FREE, UNKNOWN
from .collision import CollisionModel
from .path_verdicts import STRIDE

#: planner.free_goal_heading(): the turned goals tried, evenly spaced in heading (with the goal's own)
GOAL_HEADINGS = 12
#: planner.free_goal_heading(): of those, the ones with the shortest 'together' paths that are
#: steered in full (and checked, shortest first, with the goal's own paths)
TURNED_GOALS = 3


@dc.dataclass(frozen=True)
class ObstacleModel:
    """The planning obstacles of one plan: `collision` checks states against the known
    environment and the unknown region (W_box, or the map's unknown and occupied voxels
    after scan `scan`); `stats` describes how they were built (for the plan report)."""
    collision: CollisionModel
    scan: int = -1
    stats: dict = dc.field(default_factory=dict)
    #: planner.obstacles.base_clearance: the same obstacles with the base padded, for the paths and the
    #: candidates' positions (None: these obstacles)
    padded: "ObstacleModel | None" = None
    #: planner.utility.clearance: the same obstacles with every robot body padded by it, for
    #: the expected utility's rollouts (None: these obstacles)
    rollouts: "ObstacleModel | None" = None

    def free(self, q: np.ndarray) -> np.ndarray:
        return self.collision.free(q)

    def for_paths(self) -> "ObstacleModel":
        """The obstacles the motion planner and the position filter use: `padded` when given."""
        return self.padded or self


class PlanningObstacles:
    """Builds each plan's ObstacleModel (Vasquez-Gomez et al. 2017 §3: O = W_obj u W_unk u
    O_env). planner.obstacles.map "wbox": one model with the whole W_box, built once;
    "voxels": the map's unknown and occupied voxels as at most planner.obstacles.max_boxes
    merged boxes, built once per scan (the last one is kept: plans of the same map share it)."""

    def __init__(self, sc: Scenario, kin: RobotKinematics, wbox_model: CollisionModel | None = None):
        self.sc = sc
        self.kin = kin
        self._wbox = wbox_model
        self._wbox_padded: ObstacleModel | None = None
        self._wbox_rollouts: ObstacleModel | None = None
        self._last: ObstacleModel | None = None

    def for_map(self, omap: OccupancyMap) -> ObstacleModel:
        p = self.sc.planner
        if p.obstacles.map != "voxels":
            if self._wbox is None:
                self._wbox = CollisionModel(self.sc, self.kin)
            if self._wbox_padded is None:  # also beside a W_box model given to the constructor
                self._wbox_padded = self._padded(None, -1)
                self._wbox_rollouts = self._rollout_model(None, -1)
            return ObstacleModel(self._wbox, padded=self._wbox_padded, rollouts=self._wbox_rollouts)
        if self._last is not None and self._last.scan == omap.scan_count:
            return ObstacleModel(self._last.collision, self._last.scan, padded=self._last.padded,
                                 rollouts=self._last.rollouts)
        t = time.perf_counter()
        boxes, block = omap.obstacle_boxes(p.obstacles.max_boxes)
        model = CollisionModel(self.sc, self.kin, obstacle_boxes=boxes)
        padded = self._padded(boxes, omap.scan_count)
        self._last = ObstacleModel(model, omap.scan_count, {
            "obstacle_boxes": len(boxes), "obstacle_block": block, "obstacles_s": time.perf_counter() - t},
            padded, self._rollout_model(boxes, omap.scan_count))
        return self._last

    def _rollout_model(self, boxes, scan: int) -> ObstacleModel | None:
        """planner.utility.clearance > 0 (the expected utility): the same obstacles (the map's
        `boxes`, or W_box when None) with every robot body padded by it; else None."""
        u = self.sc.planner.utility
        c = float(getattr(u, "clearance", 0.0) or 0.0)
        if c <= 0:
            return None
        return ObstacleModel(CollisionModel(self.sc, self.kin, obstacle_boxes=boxes, padding=c), scan)

    def _padded(self, boxes, scan: int) -> ObstacleModel | None:
        """planner.obstacles.base_clearance or arm_clearance > 0: the same obstacles (the map's `boxes`,
        or W_box when None) with the robot padded by them; else None."""
        o = self.sc.planner.obstacles
        if o.base_clearance <= 0 and o.arm_clearance <= 0:
            return None
        # every robot body keeps arm_clearance, the base the larger of the two
        return ObstacleModel(CollisionModel(self.sc, self.kin, obstacle_boxes=boxes, padding=o.arm_clearance,
                                            base_padding=max(o.base_clearance - o.arm_clearance, 0.0)), scan)


def reached_goal(sc: Scenario, goal: np.ndarray, states: np.ndarray) -> np.ndarray:
    """The state a path from `connect_many` to `goal` ends on: the goal, or with
    planner.free_goal_heading() its twin turned about the arm's mount (the same view; the exact
    steering ends on it to ~1e-14)."""
    return states[-1].copy() if sc.planner.free_goal_heading() else np.array(goal, float)


def undecided_free(asks: dict, obstacles: ObstacleModel) -> dict:
    """{key: whether every state of asks[key] is free}, for the states of paths that the bulk
    model could not decide (the rest of each path proved free): only those go to Drake (through
    the certificate), in three batches: the last of each path, every STRIDE-th, the rest (a
    failing path usually fails early)."""
    ok = {k: True for k in asks}
    for rnd in range(3):
        keys = [k for k in asks if ok[k] and (rnd < 2 or len(asks[k]) > 1)]
        if not keys:
            break
        parts = []
        for k in keys:
            n = len(asks[k])
            sel = np.zeros(n, bool)
            if rnd == 0:
                sel[-1] = True
            else:
                sel[: n - 1: STRIDE] = True
                if rnd == 2:
                    sel = ~sel
                    sel[-1] = False
            parts.append(asks[k][sel])
        free = obstacles.collision.free(np.concatenate(parts))
        split = np.cumsum([len(a) for a in parts])[:-1]
        for k, f in zip(keys, np.split(free, split)):
            ok[k] = bool(np.all(f))
    return ok


class FoundPath(tuple):
    """A path found: (kind, controls, states), and `nodes`: its vertices in the search that
    found it (a tree's or the roadmap's, its two ends included; a steering path's 2, a detour's
    3: its waypoint)."""

    def __new__(cls, kind: str, controls, states, nodes: int | None = None):
        out = super().__new__(cls, (kind, controls, states))
        out.nodes = int(nodes) if nodes is not None else (3 if kind == "detour" else 2)
        return out


class MotionPlanner:
    """Paths between states against a plan's obstacles (`ObstacleModel`)."""

    #: a believed start state in collision (the belief is uncertain; W_box is a conservative
    #: obstacle) may be left within this many control steps; the rest of the path is checked
    max_escape_steps: int = 15

    def __init__(self, sc: Scenario, kin: RobotKinematics, sampler: StateSampler, bulk_checks: bool = True):
        self.sc = sc
        self.kin = kin
        self.sampler = sampler
        #: paths are first checked whole by the bulk kernels (planning/path_verdicts.py) and go to the
        #: certificate-then-Drake checks only when those cannot decide (False: as before them)
        self.bulk_checks = bulk_checks
        self._roadmap = None
        #: what the last `connect_many` did (roadmap queries: rounds, edges checked, ...)
        self.last_query: dict = {}
        #: every goal `connect_many` was asked for and the eq. 8 length of its path (nan: not
        #: reached), in order (benchmarks compare planners on the goals both reach)
        self.path_log: list[tuple[np.ndarray, float]] = []

    def _bulk(self, states: np.ndarray, obstacles: ObstacleModel, max_step: float) -> int:
        """The bulk verdict of a path (FREE, COLLIDING or UNKNOWN: ask the certificate and Drake)."""
        if not self.bulk_checks or obstacles.collision.certificate is None:
            return UNKNOWN
        return obstacles.collision.bulk_path(states, max_step)

    def escape_prefix(self, states: np.ndarray, obstacles: ObstacleModel) -> int | None:
        """0 when the path starts collision-free; else the index of its first free state if
        that comes within max_escape_steps, else None."""
        if obstacles.free(states[:1])[0]:
            return 0
        head = states[: self.max_escape_steps + 1]
        free = np.flatnonzero(obstacles.free(head))
        return int(free[0]) if len(free) else None

    def path_free(self, states: np.ndarray, obstacles: ObstacleModel, max_step: float = 0.02) -> bool:
        """Arm limits, then the end state alone (one check rejects most failing tree
        extensions), then the whole path at `max_step` resolution; a path that fails only
        because its start state is in collision is accepted when it leaves the collision
        within the escape prefix and is free from there on."""
        if not self.kin.all_within_limits(states):
            return False
        v = self._bulk(states, obstacles, max_step)
        if v != UNKNOWN:
            return v == FREE
        if not obstacles.free(states[-1:])[0]:
            return False
        if obstacles.collision.path_free(states, max_step=max_step):
            return True
        start = self.escape_prefix(states, obstacles)
        return bool(start) and obstacles.collision.path_free(states[start:], max_step=max_step)

    def paths_free(self, paths: list[np.ndarray], obstacles: ObstacleModel, max_step: float = 0.02) -> np.ndarray:
        """`path_free` of many paths, (N,) bool, the same verdicts with the collision checks
        batched: arm limits, the end states in one batch, the paths of the survivors in two
        (`CollisionModel.paths_free`); a path that fails there and starts in collision gets
        the escape-prefix test of `path_free`."""
        ok = np.array([self.kin.all_within_limits(s) for s in paths], bool)
        undecided = ok.copy()
        asks = {}  # path -> the interpolated states the model cannot decide (its first is FREE)
        bulk_ok = self.bulk_checks and obstacles.collision.certificate is not None
        for i in np.flatnonzero(ok):
            if not bulk_ok:
                break
            v, allq, idx = obstacles.collision.bulk_path_undecided(paths[i], max_step)
            if v != UNKNOWN:
                ok[i], undecided[i] = v == FREE, False
            elif len(idx):
                asks[i] = allq[idx]
                undecided[i] = False
        for i, free in undecided_free(asks, obstacles).items():
            ok[i] = free
        idx = np.flatnonzero(undecided)
        if len(idx):
            ok[idx] = obstacles.free(np.stack([paths[i][-1] for i in idx]))
        idx = idx[ok[idx]]
        if len(idx):
            ok[idx] = obstacles.collision.paths_free([paths[i] for i in idx], max_step=max_step)
        for i in idx[~ok[idx]]:
            start = self.escape_prefix(paths[i], obstacles)
            ok[i] = bool(start) and obstacles.collision.path_free(paths[i][start:], max_step=max_step)
        return ok

    #: tree edges of the Object Reconstruction Tree are checked at this resolution (m)
    tree_max_step: float = 0.04

    def tree_path_free(self, states: np.ndarray, obstacles: ObstacleModel) -> bool:
        """A tree edge of the Object Reconstruction Tree (checked at `tree_max_step`)."""
        return self.path_free(states, obstacles, max_step=self.tree_max_step)

    def tree_paths_free(self, paths: list[np.ndarray], obstacles: ObstacleModel) -> np.ndarray:
        return self.paths_free(paths, obstacles, max_step=self.tree_max_step)

    def connect(self, q0: np.ndarray, q1: np.ndarray, obstacles: ObstacleModel,
                rng: np.random.Generator | None = None):
        """A collision-free path from q0 to q1: (kind, controls, states) or None. The steering
        function's direct paths first (a tree that connects at its first extension); then, with
        planner.steering.detours, paths whose base drives through a waypoint beside the straight
        line (`steer_via`, `detour_waypoints`: around the table, from one side of the object to
        the other); then RRT Ext-Ext with up to planner.rrt_max_nodes() vertices."""
        rc, p = self.sc.robot, self.sc.planner
        arcs = p.weights if p.steering.arcs else None
        found = self._first_free(q0, itertools.chain(steer(q0, q1, rc, arcs), self._detours(q0, q1)), obstacles)
        if found is not None:
            return found
        if p.rrt_max_nodes() > 0 and rng is not None:
            from .rrt import rrt_ext_ext
            res = rrt_ext_ext(q0, q1, self.sc.robot, np.asarray(p.weights), self.sampler.sample_states,
                              lambda s: self.path_free(s, obstacles), self.kin.clip_arm, rng,
                              max_nodes=p.rrt_max_nodes(), step=p.tree_step)
            if res.found:
                return FoundPath("rrt", res.controls, res.states, res.path_nodes)
        return None

    def _detours(self, q0: np.ndarray, q1: np.ndarray):
        """The detour sequences (`steer_via` through each of `detour_waypoints`) when
        planner.steering.detours, else none."""
        if not self.sc.planner.steering.detours:
            return iter(())
        rc = self.sc.robot
        return (s for w in detour_waypoints(q0, q1, rc.xy_bounds) for s in steer_via(q0, q1, w, rc))

    def _turned_goal_options(self, q0: np.ndarray, goal: np.ndarray) -> list:
        """planner.free_goal_heading(): (kind, controls, states) of direct steering paths to the
        goal turned about the arm's mount (`RobotKinematics.turned_about_mount`, the same
        camera pose) to each of GOAL_HEADINGS headings around its own and to the headings
        that face the direction of travel on arrival (forward or backward: no final turn):
        'together' (and 'arc' with planner.steering.arcs) to the TURNED_GOALS of them with the
        shortest 'together' (eq. 8, `steer_kernels.edge_lengths`). The path's last state is the
        turned goal."""
        rc, p = self.sc.robot, self.sc.planner
        h = goal[2] + np.arange(1, GOAL_HEADINGS) * (2 * np.pi / GOAL_HEADINGS)
        t = np.array([goal, goal], float)  # facing the travel forward, and backward
        for _ in range(3):  # turning moves the base: a few fixed-point steps (a NaN row stays NaN)
            t = self.kin.turned_about_mount(goal, np.arctan2(t[:, 1] - q0[1], t[:, 0] - q0[0]) + (0.0, np.pi))
        twins = np.vstack([self.kin.turned_about_mount(goal, h), t])
        twins = twins[~np.isnan(twins[:, 0])]
        if len(twins) == 0:
            return []
        lengths = steer_kernels.edge_lengths(np.repeat(np.asarray(q0, float)[None], len(twins), 0), twins,
                                    np.asarray(p.weights, float), steer_kernels.robot_params(rc))
        out = []
        for t in twins[np.argsort(lengths, kind="stable")[:TURNED_GOALS]]:
            out.append(("together", steer_together(q0, t, rc)))
            if p.steering.arcs:
                c = steer_arc(q0, t, rc)
                if c is not None:
                    out.append(("arc", c))
        return [(kind, c, rollout(q0, c, rc.control_dt)) for kind, c in out]

    def _first_free(self, q0: np.ndarray, sequences, obstacles: ObstacleModel):
        """The first of the (kind, controls) sequences from q0 whose path is free, as
        (kind, controls, states), or None."""
        for kind, controls in sequences:
            states = rollout(q0, controls, self.sc.robot.control_dt)
            if self.path_free(states, obstacles):
                return FoundPath(kind, controls, states)
        return None

    @property
    def roadmap(self):
        """The mission's roadmap (planning/roadmap.py), created on first use."""
        if self._roadmap is None:
            from .roadmap import Roadmap
            self._roadmap = Roadmap(self.sc, self.kin, self.sampler)
        return self._roadmap

    def connect_many(self, q0: np.ndarray, goals: np.ndarray, obstacles: ObstacleModel,
                     rng: np.random.Generator | None = None) -> list:
        """Paths from q0 to each of goals (K, 8), as `connect`'s (kind, controls, states) or None.
        planner.motion_planner "rrt_ext_ext": `connect` for one goal after the other (the
        paper's way). "roadmap": the shortest free direct steering path of each goal (`steer`);
        one search of the mission's roadmap for all goals whose shortest steering path
        ('together') is blocked (`Roadmap.query`), its path taken where it is shorter (kind
        "roadmap"); detours (planner.steering.detours) for the goals still without a path. Every
        path returned has passed `path_free` (Drake decides what the conservative model
        cannot)."""
        goals = np.asarray(goals, float).reshape(-1, 8)
        out = self._connect_many(q0, goals, obstacles, rng)
        w = self.sc.planner.weights
        self.path_log += [(g, path_length(r[2], w) if r is not None else float("nan")) for g, r in zip(goals, out)]
        return out

    def _connect_many(self, q0, goals, obstacles, rng) -> list:
        p, rc = self.sc.planner, self.sc.robot
        if not p.is_roadmap() or obstacles.collision.certificate is None or rng is None:
            return [self.connect(q0, g, obstacles, rng) for g in goals]
        out: list = [None] * len(goals)
        length = np.full(len(goals), np.inf)
        for i, g in enumerate(goals):  # the shortest free direct steering path
            options = [(kind, c, rollout(q0, c, rc.control_dt))
                       for kind, c in steer(q0, g, rc, p.weights if p.steering.arcs else None)]
            if p.free_goal_heading():  # the same view with the base turned about the arm's mount
                options += self._turned_goal_options(q0, g)
            lengths = [path_length(o[2], p.weights) for o in options]
            for j in np.argsort(lengths, kind="stable"):
                if self.path_free(options[j][2], obstacles):
                    out[i], length[i] = FoundPath(*options[j]), lengths[j]
                    break
        # the roadmap for every goal whose turn-drive-turn with the arm moving alongside (the
        # shortest steering path; or an arc) is blocked: its path around may be shorter
        todo = [i for i in range(len(goals)) if out[i] is None or out[i][0] not in ("together", "arc")]
        self.last_query = {}
        if todo:
            paths, st = self.roadmap.query(q0, goals[todo], obstacles.collision,
                                           lambda s: self.path_free(s, obstacles), rng)
            self.last_query = st.to_json()
            for i, r in zip(todo, paths):
                if r is None:
                    continue
                if path_length(r[1], p.weights) < length[i] and self.path_free(r[1], obstacles):
                    out[i] = FoundPath("roadmap", r[0], r[1], r[2])
        for i in range(len(goals)):
            if out[i] is None:
                out[i] = self._first_free(q0, self._detours(q0, goals[i]), obstacles)
        return out
