"""Baselines that a next-best-view planner must beat, in the same harness: the same Planner
protocol, candidate checks (PlanningObstacles), motion planner (steering, RRT Ext-Ext), utility
strategy and PlanResult factors as random sampling, so their reports compare one to one.

- `ViewCirclePlanner` (planner.strategy "view_circle"): the fixed view sphere the NBV papers
  compare against (Vasquez-Gomez, Sucar & Murrieta-Cid 2017; Vasquez-Gomez et al. 2018):
  planner.strategy.views views evenly spaced on a horizontal circle around W_box's centre, each
  camera aimed at the centre, each turned into a robot state by Drake's InverseKinematics
  (as Santos et al. 2020's views are, planning.view_sampling) and visited in turn.
- `RandomViewsPlanner` (planner.strategy "random_views"): uniform random views, the first
  sampled state that looks at W_box, is collision free and has a path; no ranking.

Neither ranks its views: the factors pos, reg, info, dist, ... of the chosen view are
computed with the same ViewEvaluator for the report only (reg: the registration overlap above
planner.overlap_h; `utility` = g = pos * reg * info * dist, the score random sampling would
give the view). With planner.utility "eu" the expected utility (Algorithm 1) is a feasibility
check of the chosen view: a view unfeasible under the motion noise is passed over like an
unreachable one.
"""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np

from ..config import Scenario, resolve_sensor
from ..mapping import view_metrics as K
from ..mapping.occupancy import OccupancyMap
from ..world.motion import path_length, wrap_angle
from ..world.robot import RobotKinematics
from .candidates import StateSampler, free_candidates
from .interface import PlanRequest, PlanResult, distance_factor
from .motion_planner import MotionPlanner, ObstacleModel, PlanningObstacles, reached_goal
from .utility import select_best
from .view_sampling import camera_ik
from .views import ViewEvaluator, registration_overlap


def view_result(sc: Scenario, evaluator: ViewEvaluator, omap: OccupancyMap, q: np.ndarray, found,
                un_total: int, overlap_h: float | None) -> PlanResult:
    """The PlanResult of a view q reached by `found` = (kind, controls, states), with the factors
    random sampling reports (FACTOR_NAMES), computed with the view evaluator."""
    p = sc.planner
    kind, controls, states = found
    met = evaluator.evaluate(omap, q[None])
    info = float(evaluator.information(omap, q[None], met, p.metric, un_total)[0])
    overlap = float(registration_overlap(met)[0])
    reg = 1.0 if overlap_h is None or overlap > overlap_h else 0.0
    rho = path_length(states, p.weights)
    dist = distance_factor(rho, p.use_distance)
    du = 1.0 * reg * info * dist
    return PlanResult("ok", reached_goal(sc, q, states), controls, states, kind, float(du), {
        "pos": 1.0, "reg": reg, "info": info, "metric": p.metric, "dist": float(dist), "rho": float(rho),
        "un_o": int(met[0, K.M_UN_O]), "un_touched": int(met[0, K.M_UN_O] + met[0, K.M_N_POSTERIOR]),
        "oc_o": int(met[0, K.M_OC_O]), "overlap": overlap, "un_total": int(un_total), "du": float(du),
        "un_near": evaluator.near_range_unknown(omap, q)}, path_nodes=getattr(found, "nodes", 2))


def one_at_a_time(candidates, skip):
    """Batches of one for select_best: each candidate (view, q, result or None) as it comes;
    select_best stops at the first feasible one, so a batch it resumes after was not
    feasible under the utility (`skip(view, "unfeasible")`)."""
    for view, _q, res in candidates:
        if res is None:
            skip(view, "no_path")
            yield [], 1
            continue
        yield [res], 1
        skip(view, "unfeasible")


@dc.dataclass(frozen=True)
class ViewCircle:
    """The circle's views: camera positions (N, 3) and unit viewing directions (N, 3) towards
    `centre`, at horizontal distance `radius` and height `height`; view 0 lies at the
    azimuth of the start state's camera (robot.start), the views follow counter-clockwise.
    `states[i]`: the IK solutions of view i (robot states), possibly none."""
    centre: np.ndarray
    radius: float
    height: float
    positions: np.ndarray
    looks: np.ndarray
    states: tuple

    @property
    def n(self) -> int:
        return len(self.positions)

    def nearest(self, camera_position: np.ndarray) -> int:
        """The view whose camera position is nearest to a camera at `camera_position`."""
        return int(np.argmin(np.linalg.norm(self.positions - camera_position, axis=1)))


def circle_geometry(sc: Scenario) -> tuple[np.ndarray, float, float]:
    """(W_box centre, the circle's horizontal radius, the cameras' height). Automatic radius
    (planner.strategy.range 0): 0.1 m beyond both the distance at which W_box's nearest side
    face lies at the sensor's z_near (z_near + the larger half-extent of its footprint) and
    W_box's footprint corners plus 0.15 m for the camera and arm; the default scene and
    SR4000: max(0.4 + 0.4, 0.566 + 0.15) + 0.1 = 0.9 m, so the director ray meets W_box at
    about 0.5 m, within planner.max_view_distance (1 m). Automatic height (planner.strategy.height
    0): the middle of W_box's upper half (0.82 m in the default scene)."""
    p, s = sc.planner, sc.scene
    bmin, bmax = np.asarray(s.bbox_min, float), np.asarray(s.bbox_max, float)
    centre = 0.5 * (bmin + bmax)
    half = 0.5 * (bmax - bmin)
    z_near = resolve_sensor(sc.sensor).z_near
    radius = p.strategy.range or max(z_near + max(half[0], half[1]), float(np.hypot(half[0], half[1])) + 0.15) + 0.1
    height = p.strategy.height or float(bmin[2] + 0.75 * (bmax[2] - bmin[2]))
    return centre, float(radius), float(height)


class ViewCirclePlanner:
    """Visits the circle's views in turn, counter-clockwise from the view nearest to the start
    (the start scan counts as that view's: with N views and mission.max_scans N the robot
    visits the N - 1 others). Which views are used is derived from the request, not kept: the
    view nearest to the believed state's camera is the last one reached, and every scan but
    the first followed one plan, so at least omap.scan_count views are used. The next plan
    goes to the next view that has an IK solution, is collision free against the plan's
    obstacles and can be reached (and, with the expected utility, is feasible); the views
    passed over are in `stages["skipped"]` ([view, reason] each: no_ik, collision, no_path,
    unfeasible). When every view is used, or none of the rest qualifies, the plan is
    "no_candidate" (the mission stops with no_valid_candidate; "no_path" / "no_feasible" when
    the rest had states but none could be reached / was feasible)."""

    pos_tol = 0.003  #: IK: camera position within 3 mm (each coordinate)
    angle_tol = np.radians(1.0)  #: IK: optical axis within 1 deg of the direction to the centre
    #: IK initial guesses: the base this far behind the camera facing the centre, and the arm
    back_distances = (0.75, 0.6, 0.9)
    arm_guess = (0.0, 0.5, -0.3, -0.3, 0.0)

    def __init__(self, sc: Scenario, kin: RobotKinematics, evaluator: ViewEvaluator, obstacles: PlanningObstacles,
                 motion: MotionPlanner, utility, overlap_h: float | None):
        self.sc = sc
        self.kin = kin
        self.evaluator = evaluator
        self.obstacles = obstacles
        self.motion = motion
        self.utility = utility
        self.overlap_h = overlap_h
        self._circle: ViewCircle | None = None
        self.ik_s = 0.0

    # ---- the circle (deterministic: built once, on the first plan) ------------------
    def circle(self) -> ViewCircle:
        if self._circle is None:
            t = time.perf_counter()
            self._circle = self._build_circle()
            self.ik_s = time.perf_counter() - t
        return self._circle

    def _build_circle(self) -> ViewCircle:
        n = self.sc.planner.strategy.views
        centre, radius, height = circle_geometry(self.sc)
        cam0 = self.kin.camera_poses(np.asarray(self.sc.robot.start, float))[0, :3, 3]
        phi0 = float(np.arctan2(cam0[1] - centre[1], cam0[0] - centre[0]))
        phi = phi0 + 2 * np.pi * np.arange(n) / n
        pos = np.stack([centre[0] + radius * np.cos(phi), centre[1] + radius * np.sin(phi),
                        np.full(n, height)], axis=1)
        looks = centre - pos
        looks /= np.linalg.norm(looks, axis=1, keepdims=True)
        states = tuple(tuple(self._solutions(p, d)) for p, d in zip(pos, looks))
        return ViewCircle(centre, radius, height, pos, looks, states)

    def _solutions(self, p: np.ndarray, look: np.ndarray) -> list[np.ndarray]:
        """The distinct IK solutions of one view, one per initial guess that converges."""
        out = []
        flat = look[:2] / max(np.linalg.norm(look[:2]), 1e-9)
        heading = float(np.arctan2(look[1], look[0]))
        for back in self.back_distances:
            base = p[:2] - back * flat
            guess = np.array([base[0], base[1], heading, *self.arm_guess])
            q = self._ik(p, look, guess)
            if q is not None and not any(np.allclose(q, o, atol=1e-3) for o in out):
                out.append(q)
        return out

    def _ik(self, p: np.ndarray, look: np.ndarray, guess: np.ndarray) -> np.ndarray | None:
        """A state whose camera is at p (within pos_tol) with its optical axis along `look`
        (within angle_tol), roll free, within the joint limits and the base bounds; or None."""
        x = camera_ik(self.kin, p, look, guess, self.sc.robot.xy_bounds, self.pos_tol, self.angle_tol)
        if x is None:
            return None
        x = np.array(x, float)
        x[2] = float(wrap_angle(x[2]))
        return self.kin.clip_arm(x)

    # ---- progress, derived from the request -----------------------------------------
    def used_views(self, request: PlanRequest) -> int:
        """How many views of the circle's order are used (view 0 = the start scan's): the
        offset of the view nearest to the believed camera, plus one, and at least the scans."""
        c = self.circle()
        cam = self.kin.camera_poses(np.asarray(request.q_start, float))[0, :3, 3]
        return max(c.nearest(cam), request.omap.scan_count - 1) + 1

    def plan(self, request: PlanRequest) -> PlanResult:
        omap, rng = request.omap, request.rng
        c = self.circle()
        times, stages = {}, {}
        if self.ik_s:
            times["ik_s"], self.ik_s = self.ik_s, 0.0
        used = self.used_views(request)
        order = list(range(used, c.n))
        stages.update(circle_views=c.n, with_ik=sum(1 for s in c.states if s), used=used, remaining=len(order))
        skipped = []
        stages["skipped"] = skipped
        if not order:
            return PlanResult("no_candidate", stages=stages, times=times)
        obstacles: ObstacleModel = self.obstacles.for_map(omap)
        stages.update(obstacles.stats)
        un_total = max(omap.unknown_count(), 1)
        skip = lambda view, why: skipped.append([view, why])  # noqa: E731
        n_free = [0]

        def candidates():
            for i in order:
                if not c.states[i]:
                    skip(i, "no_ik")
                    continue
                free = [q for q in c.states[i] if obstacles.free(q[None])[0]]
                if not free:
                    skip(i, "collision")
                    continue
                n_free[0] += 1
                found = self.motion.connect_many(request.q_start, free[0][None], obstacles, rng)[0]
                res = None if found is None else view_result(self.sc, self.evaluator, omap, free[0], found,
                                                               un_total, self.overlap_h)
                if res is not None:
                    res.stages["view"] = i
                yield i, free[0], res

        best = select_best(one_at_a_time(candidates(), skip), self.utility, request, obstacles, un_total,
                           stages, times)
        stages["position"] = n_free[0]
        if best is None:
            status = "no_candidate" if not n_free[0] else ("no_feasible" if stages["with_path"] else "no_path")
            return PlanResult(status, stages=stages, times=times)
        stages["view"] = best.stages["view"]
        best.stages, best.times = stages, times
        return best


class RandomViewsPlanner:
    """Uniform random views: planner.n_candidates states from the StateSampler (director ray
    meets W_box within the working range), the position filter, then the first of them in
    the sampled order (request.rng) that has a path (and, with the expected utility, is
    feasible) is the next view, whatever it would see."""

    def __init__(self, sc: Scenario, sampler: StateSampler, evaluator: ViewEvaluator, obstacles: PlanningObstacles,
                 motion: MotionPlanner, utility, overlap_h: float | None):
        self.sc = sc
        self.sampler = sampler
        self.evaluator = evaluator
        self.obstacles = obstacles
        self.motion = motion
        self.utility = utility
        self.overlap_h = overlap_h

    def plan(self, request: PlanRequest) -> PlanResult:
        omap, rng = request.omap, request.rng
        times, stages = {}, {}
        obstacles: ObstacleModel = self.obstacles.for_map(omap)
        stages.update(obstacles.stats)
        cand = free_candidates(self.sampler, obstacles, rng, omap, stages, times)
        if len(cand) == 0:
            return PlanResult("no_candidate", stages=stages, times=times)
        un_total = max(omap.unknown_count(), 1)

        def candidates():
            for q in cand:
                found = self.motion.connect_many(request.q_start, q[None], obstacles, rng)[0]
                yield None, q, (None if found is None else
                                view_result(self.sc, self.evaluator, omap, q, found, un_total, self.overlap_h))

        best = select_best(one_at_a_time(candidates(), lambda view, why: None), self.utility, request, obstacles,
                           un_total, stages, times)
        if best is None:
            return PlanResult("no_feasible" if stages["with_path"] else "no_path", stages=stages, times=times)
        best.stages, best.times = stages, times
        return best


def make_baseline(sc: Scenario, kin: RobotKinematics, sampler: StateSampler, evaluator: ViewEvaluator,
                  obstacles: PlanningObstacles, motion: MotionPlanner, utility, overlap_h: float | None):
    """The baseline planner.strategy names ("view_circle" or "random_views")."""
    if sc.planner.strategy_name() == "ViewCircle":
        return ViewCirclePlanner(sc, kin, evaluator, obstacles, motion, utility, overlap_h)
    return RandomViewsPlanner(sc, sampler, evaluator, obstacles, motion, utility, overlap_h)
