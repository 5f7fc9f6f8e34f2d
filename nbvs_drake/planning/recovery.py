"""Verified views and recovery under motion noise (beyond Vasquez-Gomez et al. 2017).

Under the Table 4 noise the base's heading error grows with its turning time (sigma_w =
0.28 rad/s on every turning step: ~0.15 rad after a quarter turn), while the arm is exact.
A view planned for the believed state is then taken from somewhere else, and a scan that
misses the object cannot be registered; the belief's spread grows and the next views miss
too (docs/results.md, "planning under noise"). With `mission.verify_views` the robot checks
its pose before it scans:

- when a noisy plan ends, a *localisation frame* (one depth image, not integrated into the
  map and not counted as a sensing scan) is registered against the known environment and the
  earlier scans (registration.py);
- if it registers and the corrected camera pose is within `mission.view_tolerance_m` /
  `view_tolerance_rad` of the planned view, that frame is the sensing scan;
- if it registers but the view is off, a *correction* re-aims the camera from the corrected
  belief: with the arm alone (exact motion: the arm's first joint turns by the heading error,
  aiming the optical axis at the planned view's look-at point) when that brings the camera
  near the planned pose, else a short steering path to the planned state (noisy, so verified
  again);
- if it does not register (the object out of view, an ambiguous fit), a *re-localisation
  view* is chosen, not for information but so that the known environment (the table, the
  object seen so far) is in view for every pose the belief's spread allows: arm-only
  configurations from where the robot is, scored by the expected share of those landmarks in
  the field of view (`relocalisation_scores`).

After `mission.max_recoveries` frames the next one is the sensing scan whatever it is. The
plain functions here do the geometry; `Recovery` plans the corrective motions for the
NBVSPlanner system, against the plan's obstacles, with the motion planner's checks (Drake is
the authority for every path).

`arm_only_candidates` also serves the expected utility's fallback (planner.noise_fallback):
when no candidate is feasible under noise, views from the current base by the arm alone,
whose motion the noise does not touch.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import Scenario, resolve_sensor
from ..world.motion import rollout, steer, wrap_angle
from ..world.pose import apply_corrections
from ..world.robot import RobotKinematics
from ..world.state import NQ
from .interface import PlanResult

#: the look-at point of a view: this far along its optical axis (m), or where it meets W_box
LOOK_AT_DEFAULT = 1.0


def camera_error(kin: RobotKinematics, q_a: np.ndarray, q_b: np.ndarray) -> tuple[float, float]:
    """(position distance m, angle between the optical axes rad) of the cameras of two states."""
    X = kin.camera_poses(np.stack([np.asarray(q_a, float), np.asarray(q_b, float)]))
    d = float(np.linalg.norm(X[0, :3, 3] - X[1, :3, 3]))
    c = float(np.clip(np.dot(X[0, :3, 2], X[1, :3, 2]), -1.0, 1.0))
    return d, math.acos(c)


def look_at_point(kin: RobotKinematics, q: np.ndarray, center=None) -> np.ndarray:
    """The point the view of state q looks at: on its optical axis, at the distance of `center`
    (W_box's centre) along it, or LOOK_AT_DEFAULT."""
    X = kin.camera_poses(np.asarray(q, float)[None])[0]
    o, z = X[:3, 3], X[:3, 2]
    t = LOOK_AT_DEFAULT if center is None else max(0.3, float(np.dot(np.asarray(center, float) - o, z)))
    return o + t * z


def aim_error(kin: RobotKinematics, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Angle (rad) between each state's optical axis and the direction to `point`, (N,)."""
    X = kin.camera_poses(np.atleast_2d(np.asarray(q, float)))
    v = np.asarray(point, float) - X[:, :3, 3]
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    return np.arccos(np.clip(np.einsum("ij,ij->i", v, X[:, :3, 2]), -1.0, 1.0))


def arm_correction(kin: RobotKinematics, q_now: np.ndarray, q_target: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The state with q_now's base and q_target's arm whose first (vertical) joint is turned by
    the heading error, then searched in +-0.3 rad around that for the optical axis through
    `point` (the planned view's look-at point). Clipped to the joint limits."""
    q_now, q_target = np.asarray(q_now, float), np.asarray(q_target, float)
    q = np.concatenate([q_now[:3], q_target[3:]])
    q[3] += float(wrap_angle(q_target[2] - q_now[2]))
    grid = np.repeat(q[None], 61, axis=0)
    grid[:, 3] += np.linspace(-0.3, 0.3, 61)
    grid = kin.clip_arm(grid)
    return grid[int(np.argmin(aim_error(kin, grid, point)))]


def belief_samples(cov: np.ndarray, n: int, rng: np.random.Generator, beta: float = 2.0) -> np.ndarray:
    """n planar pose errors (dx, dy, dyaw) drawn from the belief's covariance, each component
    clipped at beta standard deviations of the draw (the first is zero: the belief itself)."""
    cov = np.asarray(cov, float) + 1e-10 * np.eye(3)
    z = np.clip(rng.standard_normal((n, 3)), -beta, beta)
    z[0] = 0.0
    return z @ np.linalg.cholesky(cov).T


def landmarks_in_view(kin: RobotKinematics, sc: Scenario, states: np.ndarray, landmarks: np.ndarray,
                      margin: float = 0.85, solids=None) -> np.ndarray:
    """Share of the landmark points (L, 3) inside each state's field of view (shrunk by
    `margin`) and depth range, (N,). With `solids` (registration.KnownSolids,
    mission.landmark_occlusion) a landmark hidden behind a known solid from the camera does
    not count; else occlusion is not modelled. Landmarks (L, 6) carry their surface normals
    (`registration_landmarks` with normals, mission.landmark_facing): one whose surface faces
    away from the camera (the far side of the object seen so far, a face of the table turned
    away) does not count either, as the camera would see the surface in front of it instead;
    a zero normal always faces."""
    landmarks = np.asarray(landmarks, float)
    pts = landmarks[:, :3]
    s = resolve_sensor(sc.sensor)
    tx, ty = margin * math.tan(math.radians(s.fov_x_deg) / 2), margin * math.tan(math.radians(s.fov_y_deg) / 2)
    X = kin.camera_poses(np.atleast_2d(states))
    R, o = X[:, :3, :3], X[:, :3, 3]
    # camera frame, R^T (p - o): the einsum "nji,nlj->nli" term by term, in its order (the same
    # bits at a third of its time)
    D = pts[None] - o[:, None]
    x, y, z = (D[..., 0] * R[:, 0, i, None] + D[..., 1] * R[:, 1, i, None] + D[..., 2] * R[:, 2, i, None]
               for i in range(3))
    ok = (z > s.z_near) & (z < min(s.z_far, 3.0)) & (np.abs(x) < tx * z) & (np.abs(y) < ty * z)
    if landmarks.shape[1] == 6:  # back faces: the normal points away from the camera
        ok &= (o @ landmarks[:, 3:].T - np.sum(pts * landmarks[:, 3:], axis=1)[None]) >= 0.0
    if solids is not None:
        ok &= ~solids.blocked(o, pts, ok)
    return ok.mean(axis=1)


def relocalisation_scores(kin: RobotKinematics, sc: Scenario, candidates: np.ndarray, cov: np.ndarray,
                          landmarks: np.ndarray, rng: np.random.Generator, n_samples: int = 24,
                          solids=None) -> np.ndarray:
    """For each candidate state (believed), the mean over poses drawn from the belief's spread
    of the share of landmarks in view (behind no known solid, with `solids`), (N,): how surely
    a scan from there sees what it can be registered against, whatever the true pose within
    the spread."""
    xi = belief_samples(cov, n_samples, rng)
    out = np.zeros(len(candidates))
    for i, q in enumerate(np.atleast_2d(candidates)):
        out[i] = landmarks_in_view(kin, sc, apply_corrections(q, xi), landmarks, solids=solids).mean()
    return out


def arm_only_candidates(kin: RobotKinematics, q_now: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n states with q_now's base and arm configurations uniform within the joint limits."""
    q = np.repeat(np.asarray(q_now, float)[None], n, axis=0)
    q[:, 3:] = rng.uniform(kin.arm_lower, kin.arm_upper, size=(n, NQ - 3))
    return q


def landmark_solids(sc: Scenario):
    """The known solids that hide registration landmarks (mission.landmark_occlusion: the
    table and the chairs, `registration.KnownSolids`), or None (occlusion not modelled)."""
    vv = sc.localisation.verified_views
    if vv is None or not vv.landmarks.occlusion:
        return None
    from ..perception.registration import KnownSolids
    return KnownSolids.of(sc.scene)


def registration_landmarks(sc: Scenario, object_points: np.ndarray, rng: np.random.Generator,
                           n_object: int = 300, n_env: int = 300, object_normals=None) -> np.ndarray:
    """What a scan registers against: points of the object seen so far and of the known
    environment's surfaces in the registration region (registration.environment_model), (L, 3);
    given the object points' normals (`OccupancyMap.object_normals`, turned towards the camera
    that saw each point), (L, 6): each point with its surface normal (the environment's exact
    ones), for `landmarks_in_view`'s back-face test."""
    from ..perception.registration import RegistrationConfig, environment_model
    model = environment_model(sc.scene, RegistrationConfig())
    env = model.points.astype(float)
    obj = np.asarray(object_points, float).reshape(-1, 3)
    if object_normals is not None:  # each point with its normal
        env = np.concatenate([env, model.normals], axis=1)
        obj = np.concatenate([obj, np.asarray(object_normals, float).reshape(-1, 3)], axis=1)
    pick = lambda P, k: P[rng.choice(len(P), k, replace=False)] if len(P) > k else P  # noqa: E731
    return np.concatenate([pick(obj, n_object), pick(env, n_env)])


def landmark_normals(sc: Scenario, omap):
    """The object points' normals when landmarks carry them (mission.landmark_facing), else
    None: `registration_landmarks`' object_normals."""
    vv = sc.localisation.verified_views
    return omap.object_normals if vv is not None and vv.landmarks.facing else None


class Recovery:
    """Plans the corrective motions of verified views (module docstring) with the strategy's
    motion planner and per-plan obstacles."""

    def __init__(self, sc: Scenario, kin: RobotKinematics, motion, obstacles, checker=None):
        """checker: what checks a path's rollouts under the noise (`rollouts_free`, e.g. an
        `ExpectedUtilityScore`; `make_recovery` gives one with mission.recovery_rollouts)."""
        self.sc = sc
        self.kin = kin
        self.motion = motion
        self.obstacles = obstacles
        self._center = 0.5 * (np.asarray(sc.scene.bbox_min, float) + np.asarray(sc.scene.bbox_max, float))
        self.vv = sc.localisation.verified_views
        self._checker = checker if self.vv.recovery_rollouts > 0 else None
        self._checks = 0  # rollout checks so far: each draws from its own seeded generator
        self._solids = landmark_solids(sc)

    #: the pose error a registered belief may still have (m, rad): a recovery path must stay
    #: free with its base moved by this much either way (`_direct`)
    margin_m: float = 0.02
    margin_rad: float = 0.02

    def _direct(self, q0, q1, obs, cov=None):
        """The first steering sequence from q0 to q1 that is free, also with the whole path's
        base shifted by +-margin_m in x and y and turned by +-margin_rad about its own
        centre: a recovery path is not scored by the expected utility, and the belief it
        starts from is only as good as the registration (~1 cm). With
        mission.recovery_rollouts, also in that many rollouts of its controls from the
        belief's spread `cov` (3, 3) plus the registration's (`_noise_free`).
        (kind, controls, states) or None."""
        for kind, controls in steer(q0, q1, self.sc.robot):
            states = rollout(q0, controls, self.sc.robot.control_dt)
            if self.motion.path_free(states, obs) and self.motion.paths_free(self._shifted(states), obs).all() \
                    and self._noise_free(controls, states, obs, cov):
                return kind, controls, states
        return None

    def _noise_free(self, controls, states, obs, cov) -> bool:
        """mission.recovery_rollouts > 0: whether that many rollouts of `controls` are free."""
        if self._checker is None:
            return True
        cov = self._checker.registered_cov(cov)
        self._checks += 1
        rng = np.random.default_rng([self.sc.seed, 23, self._checks])
        return self._checker.rollouts_free(controls, states, obs, cov, rng, self.vv.recovery_rollouts)

    def _shifted(self, states: np.ndarray) -> list[np.ndarray]:
        out = []
        for dx, dy, dth in ((self.margin_m, 0, 0), (-self.margin_m, 0, 0), (0, self.margin_m, 0),
                            (0, -self.margin_m, 0), (0, 0, self.margin_rad), (0, 0, -self.margin_rad)):
            s = np.array(states, float)
            s[:, 0] += dx
            s[:, 1] += dy
            s[:, 2] += dth
            out.append(s)
        return out

    def correct(self, omap, q_now: np.ndarray, q_target: np.ndarray, cov=None) -> PlanResult:
        """Back to the planned view from the corrected belief: the arm alone when that puts the
        camera within 3 x mission.view_tolerance_m of the planned camera and aims it at the
        planned look-at point within mission.view_tolerance_rad (purpose "correct": exact
        motion, its scan is the sensing scan); else the shortest free steering path to the
        planned state (purpose "view": verified again); status "no_path" when neither is free."""
        mi = self.vv
        obs = self.obstacles.for_map(omap)
        point = look_at_point(self.kin, q_target, self._center)
        q_arm = arm_correction(self.kin, q_now, q_target, point)
        d, _ = camera_error(self.kin, q_arm, q_target)
        if d <= 3 * mi.tolerance_m and aim_error(self.kin, q_arm, point)[0] <= mi.tolerance_rad:
            found = self._direct(q_now, q_arm, obs, cov)
            if found is not None:
                return PlanResult("ok", q_arm, found[1], found[2], "arm_correction",
                                  factors={"purpose": "correct", "camera_error_m": round(d, 4)})
        found = self._direct(q_now, q_target, obs, cov)
        if found is None:
            return PlanResult("no_path")
        return PlanResult("ok", np.asarray(q_target, float), found[1], found[2], found[0],
                          factors={"purpose": "view"})

    def leg(self, omap, q_now: np.ndarray, q_end: np.ndarray, cov=None) -> PlanResult:
        """The next leg (mission.legs): the shortest free steering path from the corrected
        belief to the leg's planned end (purpose "leg"), or status "no_path"."""
        found = self._direct(q_now, q_end, self.obstacles.for_map(omap), cov)
        if found is None:
            return PlanResult("no_path")
        return PlanResult("ok", np.asarray(q_end, float), found[1], found[2], found[0], factors={"purpose": "leg"})

    def relocalise(self, omap, q_now: np.ndarray, cov: np.ndarray, rng: np.random.Generator,
                   n: int = 400) -> PlanResult:
        """A re-localisation view from where the robot believes it is: the arm-only
        configuration (exact motion) with the highest `relocalisation_scores` under the
        belief's spread `cov` that has a free path; its factors carry the score."""
        obs = self.obstacles.for_map(omap)
        cand = arm_only_candidates(self.kin, q_now, n, rng)
        cand = cand[obs.free(cand)]
        if not len(cand):
            return PlanResult("no_path")
        marks = registration_landmarks(self.sc, omap.object_points, rng,
                                       object_normals=landmark_normals(self.sc, omap))
        score = relocalisation_scores(self.kin, self.sc, cand, cov, marks, rng, solids=self._solids)
        for i in np.argsort(-score, kind="stable")[:20]:
            found = self._direct(q_now, cand[i], obs, cov)
            if found is not None:
                return PlanResult("ok", cand[i], found[1], found[2], "relocalise", utility=float(score[i]),
                                  factors={"purpose": "relocalise", "landmarks_in_view": round(float(score[i]), 4)})
        return PlanResult("no_path")
