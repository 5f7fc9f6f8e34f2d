"""Scan registration and re-localisation (Vasquez-Gomez et al. 2017 §1, the ORT paper Algorithm 1).

Each new scan arrives in the world frame at the *believed* camera pose. `register_scan`
aligns it with the model accumulated from the earlier (corrected) scans by a planar
maximum-a-posteriori point-to-plane ICP: base noise moves the robot in the plane (x, y,
theta; the arm is exact in Table 4), so the unknown is a *correction* (dx, dy, dyaw) — a
rotation about z plus a planar translation, `pose.Correction` — that is applied to the scan (the map
integrates it at the corrected pose) and to the believed robot state. Its prior comes from
rollouts of the executed plan through the noise model (`motion_prior`).

The model starts as the known environment (`environment_model`: points with exact normals
on the table top's faces and legs, the chairs, inside the registration region) and keeps the
returns of that region (the table top and what stands on it: W_box grown in x, y, from just
below the table top up to the top of W_box) of every registered scan, voxel-downsampled, so
that it stays a few ten thousand points however many scans are merged. The table's straight
edges fix the pose where the object alone cannot (a body of revolution seen from one side,
or a scan that misses the object), and a candidate pose must not make the scan see through
a known solid (`KnownSolids.seen_through`): at a wrong pose the floor beyond the table's
edge shows through the table top.
"""

from __future__ import annotations

import dataclasses as dc

import numba
import numpy as np

from ..config import LocalisationConfig, SceneConfig
from ..world.motion import rollout, sample_control_noise, wrap_angle
from ..world.pose import Correction, rot_z


@dc.dataclass
class RegistrationConfig:
    region_margin_xy: float = 0.5  #: m around W_box in x and y
    #: m around W_box in a room or among obstacles (scene.clutter room, obstacles): the known
    #: walls and furniture are the landmarks, as the table's edges are on a table
    region_margin_known: float = 2.2
    #: m above the floor: the region's top there (W_box's top elsewhere): a room's walls and
    #: tall furniture above the object are landmarks too
    region_top_known: float = 2.0
    #: the model's and the scan's downsampling beyond `near` (m): the walls and furniture of a
    #: room are big planes, a few hundred points each fix them
    far_voxel: float = 0.1
    #: (x_min, y_min, x_max, y_max): W_box grown by region_margin_xy, within which points are
    #: kept at model_voxel; None: everywhere (no room around). Set by `registration_config`
    near: tuple | None = None
    region_below_table: float = 0.08  #: m below the table top (its edges and legs' tops)
    #: m above the floor where the object stands on it: the floor's plane fixes nothing of a
    #: planar correction, and its returns would be most of the region's points
    region_above_floor: float = 0.02
    model_voxel: float = 0.01  #: downsampling of the accumulated model (m)
    #: coarse-to-fine ICP: (downsampling voxel, max correspondence distance) per stage (m)
    stages: tuple = ((0.03, 0.15), (0.02, 0.06), (0.01, 0.02))
    max_iterations: int = 30
    #: the coarse stage's iterations (every grid start runs it)
    max_coarse_iterations: int = 30
    #: a stage has converged when no step component exceeds this (m, rad)
    step_tol: float = 1e-6
    #: the same for the stages that see beyond `near` (the coarse stage in a room, which every
    #: grid start runs): its Cauchy-weighted steps over the walls' noisy far points creep
    #: below 0.1 mm for many iterations, while the finer stages settle the pose anyway
    far_step_tol: float = 1e-4
    point_sigma: float = 0.005  #: m, std of a point-to-plane residual
    min_fitness: float = 0.3  #: share of the scan with a model point within the last distance
    #: fewer region points than this (the object mostly out of view): keep the odometry
    min_scan_points: int = 1500
    #: two starts converging this far apart (m, rad) with costs within this fraction: ambiguous
    ambiguity_m: float = 0.05
    ambiguity_rad: float = 0.05
    ambiguity_cost: float = 0.05
    max_rmse: float = 0.01  #: m, inlier point-to-plane RMSE of the last stage
    #: m: the fit caps each point's residual here (0: at the last stage's correspondence
    #: distance, 2 cm, which is also what a point with no model point near costs)
    residual_cap: float = 0.0
    see_through_tol: float = 0.03  #: m a ray may run inside a known solid (edges, noise)
    #: start grid along the prior's two main axes (in its standard deviations)
    grid_major: tuple = (-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0)
    grid_minor: tuple = (-1.5, 0.0, 1.5)
    refine_best: int = 4  #: grid starts refined to the last stage
    #: at most this many scan points per stage (and for the free-space and see-through checks),
    #: evenly thinned after the stage's downsampling: in a room a Kinect scan keeps tens of
    #: thousands of points at 1 cm, where the fit needs a few thousand (the table scenes' scans
    #: stay below these)
    max_points: int = 8000
    #: the first (coarse) stage, which every grid start runs: at most this many
    max_coarse_points: int = 1500
    max_view_points: int = 20000  #: the whole scan's points the free-space and see-through checks use
    #: beyond `near` (a room's known walls and furniture): the std of a point-to-plane residual
    #: (the Kinect's depth error at 2-3 m), the residual at which a point costs its most (a wall
    #: this far off), and the distance within which a model point is its match (the model is
    #: one point per far_voxel there: the plane through it, with its known normal, is the match)
    far_sigma: float = 0.01
    far_cap: float = 0.05
    far_match: float = 0.15
    #: with `oriented`: the least dot product of a matched pair's normals
    facing_cos: float = 0.0
    #: match only surfaces that face the same way in every scene (`oriented`), not only in a
    #: room or among obstacles (localisation.facing_matches)
    facing_matches: bool = False
    #: in a room or among obstacles (`near`): a fit below min_fitness is still applied when at
    #: least this share of the far points (walls, furniture: known exactly) lies on their
    #: planes (within 2 far_sigma); a view of mostly new surface of the object matches little of
    #: the model, while the walls fix the pose
    min_far_fitness: float = 0.5
    #: ... and when those far points' planes fix the pose in the plane (`far_spread`, the
    #: weaker horizontal direction's share of their normals): a single wall or box face fits a
    #: pose slid along it (the suitcase's seed 2: a relocalisation at fitness 0.07 applied 8 cm
    #: and 0.09 rad off, and the run collided later)
    min_far_spread: float = 0.1

    @property
    def oriented(self) -> bool:
        """Match only surfaces that face the same way: in a room or among obstacles (`near`).
        The scan's and the model's normals, each turned towards the camera that saw it, must
        agree (their dot product above `facing_cos`), or the pair is no match. A thin part seen
        from its other side (a chair's backrest, 4 cm thick) has its new face within the
        correspondence distance of the face seen first; matched to it, the new face pulled the
        pose by the part's thickness against every wall in view. In the table scenes with
        `facing_matches`: a thin wall's inner face (a crate's, a cup's) pulls the same way."""
        return self.near is not None or self.facing_matches


#: localisation.fine_stage: the last stage (scan voxel, correspondence distance, m) and the
#: point-to-plane sigma (m) it sets
FINE_STAGE = (0.01, 0.008)
FINE_SIGMA = 0.002


#: in a room or among obstacles, where the known walls and furniture hold every stage: fewer
#: grid starts along the heading axis, a sparser coarse stage, and stages that end at 0.1 mm
#: (coarse: 1 mm); measured on the captured views of a chair run (6 views x 3 starting errors:
#: every one within 0.7 cm and 3.3 mrad of the truth, as with the defaults) at 0.46 s a
#: registration against 1.68 s (docs/decisions.md)
KNOWN_WALLS = dict(grid_major=(-2.0, -1.0, 0.0, 1.0, 2.0), max_coarse_points=700, step_tol=1e-4, far_step_tol=1e-3)


def registration_config(loc: LocalisationConfig, scene: SceneConfig | None = None) -> RegistrationConfig:
    """The registration's settings of the localisation section (residual cap, fine stage,
    search) and of the scene (in a room or among obstacles: the region reaches the known walls and
    furniture, kept coarser beyond the object's surroundings)."""
    cfg = RegistrationConfig(residual_cap=loc.cap(), facing_matches=loc.facing_matches)
    if scene is not None and scene.clutter in ("room", "obstacles"):
        m = cfg.region_margin_xy
        cfg = dc.replace(cfg, near=(scene.bbox_min[0] - m, scene.bbox_min[1] - m, scene.bbox_max[0] + m,
                                    scene.bbox_max[1] + m), **KNOWN_WALLS)
    if loc.fine_stage:
        cfg = dc.replace(cfg, stages=cfg.stages + (FINE_STAGE,), point_sigma=FINE_SIGMA)
    if loc.search is not None:
        s = loc.search
        cfg = dc.replace(cfg, grid_major=tuple(float(v) for v in s.grid_major), max_coarse_points=s.coarse_points,
                         max_coarse_iterations=s.coarse_iterations, step_tol=s.step_tol, far_step_tol=s.far_step_tol)
    return cfg


def region_mask(scene: SceneConfig, P: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """The scan points of the registration region: W_box grown by region_margin_xy in x and y
    (region_margin_known among obstacles; in a room, all of it: its walls bound it),
    from just below a raised support's top (its edges; region_below_table) or just above the
    floor (region_above_floor) up to W_box's top (in a room or among obstacles, up to
    region_top_known)."""
    s = scene
    z0 = s.base_z() + cfg.region_above_floor if s.on_floor() else s.base_z() - cfg.region_below_table
    m = cfg.region_margin_known if cfg.near is not None else cfg.region_margin_xy
    lo = np.array([s.bbox_min[0] - m, s.bbox_min[1] - m, z0])
    top = s.bbox_max[2] if cfg.near is None else max(s.bbox_max[2], cfg.region_top_known)
    hi = np.array([s.bbox_max[0] + m, s.bbox_max[1] + m, top])
    if cfg.near is not None and s.clutter == "room":
        # the walls bound the region: a bound near a wall, in the believed frame of a scan
        # turned by the heading error, would cut the wall's noisy returns on one side only,
        # more at one end than at the other, and tilt the wall the registration fits
        lo[:2], hi[:2] = -np.inf, np.inf
    return np.all((P >= lo) & (P <= hi), axis=1)


class RegistrationModel:
    """Immutable accumulated model: points (N, 3) float32 of the registration region and
    their normals (N, 3) float32, known for the environment's surfaces and zero where they
    are to be estimated from the points (the merged scans)."""

    __slots__ = ("points", "normals")

    def __init__(self, points: np.ndarray | None = None, normals: np.ndarray | None = None):
        pts = np.zeros((0, 3), np.float32) if points is None else np.asarray(points, np.float32)
        nrm = np.zeros_like(pts) if normals is None else np.asarray(normals, np.float32)
        if nrm.shape != pts.shape:
            raise ValueError(f"normals {nrm.shape} do not match points {pts.shape}")
        pts.flags.writeable = False
        nrm.flags.writeable = False
        self.points, self.normals = pts, nrm

    def __deepcopy__(self, memo):
        return self

    def merged(self, P: np.ndarray, cfg: RegistrationConfig, origin=None) -> "RegistrationModel":
        """The model with the points P merged (`model_index`: downsampled). Beyond `cfg.near`
        (a room's walls and furniture) the model is the known environment alone, with its exact
        normals: a scan's points there are not merged (normals estimated from points a
        far_voxel apart point anywhere, and a match on them pulls anywhere). With
        `cfg.oriented` and the camera position `origin` the new points keep their normals,
        estimated from the scan and turned towards the camera (the side that was seen);
        otherwise theirs are left zero, to be estimated from the model."""
        P = np.asarray(P, np.float32)
        if cfg.near is not None:
            P = P[_near_mask(P, cfg.near)]
        N = np.zeros_like(P)
        if cfg.oriented and origin is not None and len(P):
            # (the first point of each voxel, as model_index keeps: the same points survive)
            P = P[voxel_downsample_index(P, cfg.model_voxel)]
            N = oriented_normals(P, origin, 2.5 * cfg.model_voxel).astype(np.float32)
        allp = np.concatenate([self.points, P])
        idx = model_index(allp, cfg)
        return RegistrationModel(allp[idx], np.concatenate([self.normals, N])[idx])


def model_index(P: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """Indices of the model points kept: one per model_voxel, and beyond `cfg.near` (a room's
    walls and furniture) one per far_voxel."""
    if cfg.near is None:
        return voxel_downsample_index(P, cfg.model_voxel)
    near = _near_mask(P, cfg.near)
    i_near, i_far = np.flatnonzero(near), np.flatnonzero(~near)
    return np.sort(np.concatenate([i_near[voxel_downsample_index(P[i_near], cfg.model_voxel)],
                                   i_far[voxel_downsample_index(P[i_far], cfg.far_voxel)]]))


def _inside_box(P: np.ndarray, box, tol: float) -> np.ndarray:
    """Whether each point lies in the (yawed) box grown by tol."""
    local = (np.asarray(P, float) - np.asarray(box.center, float)) @ rot_z(box.yaw)
    return np.all(np.abs(local) <= 0.5 * np.asarray(box.size, float) + tol, axis=1)


def _near_mask(P: np.ndarray, near: tuple) -> np.ndarray:
    x0, y0, x1, y1 = near
    return (P[:, 0] >= x0) & (P[:, 0] <= x1) & (P[:, 1] >= y0) & (P[:, 1] <= y1)


def box_surface_points(center, size, yaw: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of a box (a grid of about `spacing` on each face) and their
    outward normals, world frame."""
    c = np.asarray(center, float)
    h = 0.5 * np.asarray(size, float)
    pts, nrm = [], []
    for ax in range(3):
        u, v = [a for a in range(3) if a != ax]
        nu, nv = (max(2, int(np.ceil(2 * h[a] / spacing)) + 1) for a in (u, v))
        gu, gv = np.meshgrid(np.linspace(-h[u], h[u], nu), np.linspace(-h[v], h[v], nv), indexing="ij")
        for sgn in (-1.0, 1.0):
            F = np.zeros((gu.size, 3))
            F[:, u], F[:, v], F[:, ax] = gu.ravel(), gv.ravel(), sgn * h[ax]
            N = np.zeros_like(F)
            N[:, ax] = sgn
            pts.append(F)
            nrm.append(N)
    R = rot_z(yaw)
    return np.concatenate(pts) @ R.T + c, np.concatenate(nrm) @ R.T


def environment_model(scene: SceneConfig, cfg: RegistrationConfig) -> RegistrationModel:
    """The known environment (the table top, its legs, chairs) as points on its surfaces,
    with their exact normals, inside the registration region: the model every scan is
    registered against before any scan is merged. The robot knows this environment (the
    planner checks collisions with it), and its straight edges fix the pose where the object
    alone cannot (a body of revolution seen from one side)."""
    from ..world.scene import ROOM_HALF, environment_boxes
    boxes = [b for b in environment_boxes(scene) if b.name != "floor"]
    faces = [box_surface_points(b.center, b.size, b.yaw, cfg.model_voxel) for b in boxes]
    if not faces:
        return RegistrationModel()
    P, N = np.concatenate([f[0] for f in faces]), np.concatenate([f[1] for f in faces])
    keep = region_mask(scene, P, cfg)
    if cfg.near is not None:
        # a room's or the obstacles' model is one point per far_voxel away from the object:
        # there a face no camera sees (a wall's outer face, a cabinet's back against the wall)
        # would share voxels with the face it backs onto and lend it its normal
        owner = np.repeat(np.arange(len(boxes)), [len(f[0]) for f in faces])
        for k, b in enumerate(boxes):
            keep &= ~((owner != k) & _inside_box(P, b, 1e-3))
        if scene.clutter == "room":
            keep &= np.all(np.abs(P[:, :2]) <= ROOM_HALF + 1e-6, axis=1)
    P, N = P[keep], N[keep]
    idx = model_index(P, cfg)
    return RegistrationModel(P[idx], N[idx])


@dc.dataclass(frozen=True)
class KnownSolids:
    """Boxes of the known environment (centre, half size, yaw each) that no ray can pass."""
    centers: np.ndarray  #: (M, 3)
    half: np.ndarray  #: (M, 3)
    yaw: np.ndarray  #: (M,)

    @staticmethod
    def of(scene: SceneConfig) -> "KnownSolids":
        from ..world.scene import box_arrays
        return KnownSolids(*box_arrays(scene))

    def seen_through(self, origin: np.ndarray, P: np.ndarray, tol: float) -> np.ndarray:
        """Whether the ray from `origin` to each return runs more than `tol` through a solid:
        a return the scene cannot have produced (it lies behind a known surface)."""
        P = np.asarray(P, float).reshape(-1, 3)
        return self.blocked(np.asarray(origin, float)[None], P, np.ones((1, len(P)), bool), tol)[0]

    def blocked(self, origins: np.ndarray, P: np.ndarray, pairs: np.ndarray, tol: float = 0.01) -> np.ndarray:
        """Whether the segment from each origin (N, 3) to each point (L, 3) runs more than
        `tol` through a solid, (N, L) bool, tested only where `pairs` (N, L) is True (False
        elsewhere): a point on a known surface is hidden from that origin (a chair's back
        between the camera and the table)."""
        out = np.zeros(pairs.shape, np.bool_)
        if len(self.centers):
            _blocked_pairs(np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(P, np.float64),
                           np.ascontiguousarray(pairs, np.bool_), np.ascontiguousarray(self.centers, np.float64),
                           np.ascontiguousarray(self.half, np.float64), np.cos(self.yaw), np.sin(self.yaw),
                           float(tol), out)
        return out


@numba.njit(cache=True, nogil=True)
def _blocked_pairs(O, P, pairs, centers, half, cos_y, sin_y, tol, out):
    """`KnownSolids.blocked`'s kernel: slab tests of each segment in each box's frame."""
    for n in range(O.shape[0]):
        for i in range(P.shape[0]):
            if not pairs[n, i]:
                continue
            for m in range(centers.shape[0]):
                c, s = cos_y[m], sin_y[m]
                ox, oy, oz = O[n, 0] - centers[m, 0], O[n, 1] - centers[m, 1], O[n, 2] - centers[m, 2]
                px, py, pz = P[i, 0] - centers[m, 0], P[i, 1] - centers[m, 1], P[i, 2] - centers[m, 2]
                o = (ox * c + oy * s, -ox * s + oy * c, oz)
                d = (px * c + py * s - o[0], -px * s + py * c - o[1], pz - o[2])
                t0, t1 = 0.0, 1.0
                for a in range(3):
                    h = half[m, a]
                    if d[a] == 0.0:
                        if abs(o[a]) > h:
                            t0, t1 = 1.0, 0.0
                    else:
                        ta, tb = (-h - o[a]) / d[a], (h - o[a]) / d[a]
                        if ta > tb:
                            ta, tb = tb, ta
                        t0, t1 = max(t0, ta), min(t1, tb)
                if (t1 - t0) * np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) > tol:
                    out[n, i] = True
                    break


@dc.dataclass(frozen=True)
class ScanView:
    """The whole scan (believed world frame) seen from `origin`, and the known solids its
    rays cannot have passed: what the registration checks a candidate pose against."""
    origin: np.ndarray
    points: np.ndarray
    solids: KnownSolids


def voxel_downsample_index(P: np.ndarray, voxel: float) -> np.ndarray:
    """Indices of one point per occupied voxel (the first), in order: deterministic."""
    if len(P) == 0:
        return np.zeros(0, np.int64)
    # keys from the float32 values the model stores, so that re-merging a model keeps it
    key = np.floor(np.asarray(P, np.float32).astype(float) / voxel).astype(np.int64)
    _, idx = np.unique(key, axis=0, return_index=True)
    return np.sort(idx)


@dc.dataclass
class IcpResult:
    correction: Correction
    fitness: float  #: share of the scan's points with a model point within the last distance
    rmse: float  #: inlier point-to-plane RMSE (m)
    applied: bool
    reason: str = ""
    model_points: int = 0
    scan_points: int = 0
    prior_sigma: tuple = (0.0, 0.0, 0.0)  #: prior std of (dx, dy, dyaw) from the motion model

    def to_json(self) -> dict:
        return {"correction": self.correction.to_json(), "fitness": round(self.fitness, 4),
                "rmse": round(self.rmse, 5), "applied": self.applied, "reason": self.reason,
                "model_points": self.model_points, "scan_points": self.scan_points,
                "prior_sigma": [round(float(v), 5) for v in self.prior_sigma]}


def motion_prior(q_start: np.ndarray, controls: np.ndarray, dt: float, believed_end: np.ndarray,
                 noise, rng: np.random.Generator, n: int = 256) -> np.ndarray:
    """Covariance (3, 3) of the correction (dx, dy, dyaw) that maps the believed end state
    onto the true one, from n rollouts of the noisy motion model over the executed plan (the
    NoisyVelocityController's model). Zero noise gives a tiny covariance (ICP stays put)."""
    controls = np.asarray(controls, float)
    if len(controls) == 0:
        return np.diag([1e-8, 1e-8, 1e-8])
    eps = sample_control_noise(rng, noise, controls, n)
    finals = rollout(q_start, controls[None] + eps, dt)[:, -1]
    # X_final X_believed^-1 in the plane: dyaw = theta_f - theta_b, t = p_f - Rz(dyaw) p_b
    b = np.asarray(believed_end, float)
    dyaw = wrap_angle(finals[:, 2] - b[2])
    c, s = np.cos(dyaw), np.sin(dyaw)
    xi = np.stack([finals[:, 0] - (c * b[0] - s * b[1]), finals[:, 1] - (s * b[0] + c * b[1]), dyaw], axis=1)
    return np.cov(xi.T) + np.diag([1e-8, 1e-8, 1e-8])


def _normals(P: np.ndarray, radius: float) -> np.ndarray:
    import open3d as o3d
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(P, float)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    return np.asarray(pc.normals)


def oriented_normals(P: np.ndarray, origin, radius: float) -> np.ndarray:
    """Unit normals of the points P (N, 3) (Open3D, neighbours within `radius`), each turned
    towards the camera at `origin`, the side of the surface that was seen."""
    N = _normals(P, radius)
    flip = np.sum(N * (np.asarray(origin, float) - np.asarray(P, float)), axis=1) < 0
    N[flip] *= -1.0
    return N


def _with_normals(P: np.ndarray, origin, cfg: RegistrationConfig) -> np.ndarray:
    """The scan's points (M, 3) as (K, 6) rows of points and normals: within `cfg.near`
    downsampled at model_voxel, each with its normal turned towards the camera at `origin`;
    beyond it, every point with a zero normal (matched to the known planes without the test)."""
    near = _near_mask(P, cfg.near) if cfg.near is not None else np.ones(len(P), bool)
    D = _downsample(P[near], cfg.model_voxel)
    N = oriented_normals(D, origin, 2.5 * cfg.model_voxel) if len(D) else np.zeros((0, 3))
    F = P[~near]
    return np.concatenate([np.concatenate([D, N], axis=1), np.concatenate([F, np.zeros_like(F)], axis=1)])


def _stage_points(P: np.ndarray, voxel: float, cfg: RegistrationConfig, dist: float) -> np.ndarray:
    """The scan downsampled at `voxel` for a stage of correspondence distance `dist`; beyond
    `cfg.near`, at far_voxel, and only in the stages that look that far for a match (the
    model is that sparse there)."""
    if cfg.near is None:
        return _downsample(P, voxel)
    near = _near_mask(P, cfg.near)
    if dist < cfg.far_voxel:
        return _downsample(P[near], voxel)
    return np.concatenate([_downsample(P[near], voxel), _far_sample(P[~near], max(voxel, cfg.far_voxel))])


def _far_sample(P: np.ndarray, voxel: float) -> np.ndarray:
    """The points P (N, 3 or 6) beyond `near` (walls and furniture), as many as the voxels of
    `voxel` they occupy, evenly spaced in their order (the image's): a sample of the returns as
    they are. Averaged per voxel, as nearer the object, a noisy wall (the Kinect's depth error
    is 1.5-2.5 cm at 3-4 m) splits at the voxel faces into means pulled towards each voxel's
    middle, and one mean per voxel whatever its count: the fitted wall moves with the grid and,
    in the believed frame of a turned scan, tilts (2-4 cm and 0.03 rad off for a wall-only
    frame of the humanoid's run, docs/decisions.md)."""
    P = np.asarray(P, float)
    if len(P) == 0:
        return P
    n = len(np.unique(np.floor(P[:, :3] / voxel).astype(np.int64), axis=0))
    return _thin(P, n)


def _thin(P: np.ndarray, n: int) -> np.ndarray:
    """At most n of the points, evenly spaced in their order (all when there are fewer)."""
    if len(P) <= n:
        return P
    return P[np.linspace(0, len(P) - 1, n).astype(np.int64)]


def _downsample(P: np.ndarray, voxel: float) -> np.ndarray:
    """P (N, 3) averaged per voxel; P (N, 6), points and their normals: both averaged per
    voxel, the normals made unit again."""
    import open3d as o3d
    P = np.asarray(P, float)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P[:, :3]))
    if P.shape[1] == 3:
        return np.asarray(pc.voxel_down_sample(voxel).points)
    pc.normals = o3d.utility.Vector3dVector(P[:, 3:])
    d = pc.voxel_down_sample(voxel)
    N = np.asarray(d.normals)
    N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    return np.concatenate([np.asarray(d.points), N], axis=1)


def _point_to_plane(xi, x, n, q, sigma):
    """The Gauss-Newton terms (J^T W J, J^T W r) of points x (M, 3) matched to planes through q
    (M, 3) with normals n (M, 3), at residual std sigma. Cauchy weights: a wrong
    correspondence's pull fades with its residual (Huber weights keep it constant, and at the
    coarse stage's 15 cm the many wrong matches of a partial overlap dragged even the true
    pose off)."""
    r = np.sum(n * (x - q), axis=1)
    rx, ry = x[:, 0] - xi[0], x[:, 1] - xi[1]
    J = np.stack([n[:, 0], n[:, 1], n[:, 0] * -ry + n[:, 1] * rx], axis=1)
    w = 1.0 / (1.0 + (r / (2.0 * sigma)) ** 2)
    s2 = sigma ** 2
    return (J * w[:, None]).T @ J / s2, (J * w[:, None]).T @ r / s2


class PlanarIcp:
    """The planar MAP point-to-plane problem of one scan against one model (see
    `register_scan`): `refine(xi)` runs the coarse-to-fine Gauss-Newton from xi, `evaluate(xi)`
    gives (MAP cost, fitness, rmse) of a correction."""

    def __init__(self, scan_pts, model: RegistrationModel, prior_cov, cfg: RegistrationConfig, free_at=None,
                 view: ScanView | None = None):
        from scipy.spatial import cKDTree
        self.cfg, self.free_at, self.view = cfg, free_at, view
        self.view_pts = (_thin(_stage_points(view.points, cfg.model_voxel, cfg, np.inf), cfg.max_view_points)
                         if view is not None and len(view.points) else None)
        self.Q = np.asarray(model.points, float)
        known = np.any(model.normals != 0, axis=1)
        self.NQ = np.asarray(model.normals, float).copy() if known.all() else _normals(self.Q, 2.5 * cfg.model_voxel)
        self.NQ[known] = model.normals[known]
        #: model normals turned towards the side that was seen (cfg.oriented: the known
        #: environment's outward ones, and those merged with their camera)
        self.q_facing = known if cfg.oriented else None
        self.tree = cKDTree(self.Q)
        self.Cinv = np.linalg.inv(prior_cov)
        S = np.asarray(scan_pts, float)
        if cfg.oriented and view is not None and len(S):  # the scan's points with their seen side's normals
            S = _with_normals(S, view.origin, cfg)
        self.fine = _thin(_stage_points(S, cfg.model_voxel, cfg, 0.0), cfg.max_points)
        caps = [cfg.max_coarse_points] + [cfg.max_points] * (len(cfg.stages) - 1)
        self.coarse = {(v, d): (_thin(_stage_points(S, v, cfg, d), cap)
                                if v > cfg.model_voxel or d >= cfg.far_voxel else self.fine)
                       for cap, (v, d) in zip(caps, cfg.stages)}
        #: the scan beyond `near` (a room's walls and furniture, known exactly), at far_voxel: the
        #: finer stages and the fit match it too, point to plane, so a pose that tucks the
        #: object's new surface into the model pays for every wall it moves
        self.far = np.zeros((0, 3))
        if cfg.near is not None:
            P = np.asarray(scan_pts, float)
            self.far = _thin(_far_sample(P[~_near_mask(P, cfg.near)], cfg.far_voxel), cfg.max_coarse_points)

    def _far_matches(self, xi):
        """(points (M, 3), their model matches (M, 3) and the matches' normals (M, 3), how many
        found no match) of the far points at correction xi, matched within cfg.far_match."""
        X = Correction(*xi).apply_points(self.far)
        d, j = self.tree.query(X, distance_upper_bound=self.cfg.far_match)
        ok = np.isfinite(d)
        return X[ok], self.Q[j[ok]], self.NQ[j[ok]], int(np.count_nonzero(~ok))

    def _facing(self, S, j, ok, xi) -> np.ndarray:
        """Whether each scan point of S (M, 6: points, seen-side normals) and its match j face
        the same way at correction xi (cfg.oriented; a model point without a seen-side normal
        matches either way). Not a match where `ok` is False."""
        jj = np.where(ok, j, 0)
        c, s = np.cos(xi[2]), np.sin(xi[2])
        n = self.NQ[jj]
        dot = (c * S[:, 3] - s * S[:, 4]) * n[:, 0] + (s * S[:, 3] + c * S[:, 4]) * n[:, 1] + S[:, 5] * n[:, 2]
        seen = np.any(S[:, 3:] != 0, axis=1)  # (a far point's normal is zero: no test)
        return ok & (~seen | ~self.q_facing[jj] | (dot > self.cfg.facing_cos))

    def _matches(self, S, xi, dist):
        """(the points of S (M, 3 or 6) at correction xi (M, 3), their nearest model points'
        indices, which of them are matches: within `dist` and, for oriented points, facing the
        same way)."""
        X = Correction(*xi).apply_points(S[:, :3])
        d, j = self.tree.query(X, distance_upper_bound=dist)
        ok = np.isfinite(d)
        if S.shape[1] == 6:
            ok = self._facing(S, j, ok, xi)
        return X, j, ok

    def refine(self, xi, stages=None):
        cfg, Cinv = self.cfg, self.Cinv
        xi = np.array(xi, float)
        for n, (voxel, dist) in enumerate(cfg.stages if stages is None else stages):
            P = self.coarse[voxel, dist]
            walls = len(self.far) > 0 and dist < cfg.far_voxel  # (the coarse stage has them in P)
            tol = cfg.far_step_tol if cfg.near is not None and dist >= cfg.far_voxel else cfg.step_tol
            for _ in range(cfg.max_coarse_iterations if n == 0 else cfg.max_iterations):
                X, j, ok = self._matches(P, xi, dist)
                terms = []
                if ok.sum() >= 10:
                    terms.append(_point_to_plane(xi, X[ok], self.NQ[j[ok]], self.Q[j[ok]], cfg.point_sigma))
                if walls:  # the known walls and furniture, at their own sigma
                    x, q, n, _ = self._far_matches(xi)
                    if len(x) >= 10:
                        terms.append(_point_to_plane(xi, x, n, q, cfg.far_sigma))
                if not terms:
                    break
                A = sum(t[0] for t in terms) + Cinv
                step = -np.linalg.solve(A, sum(t[1] for t in terms) + Cinv @ xi)
                xi = xi + step
                if np.abs(step).max() < tol:
                    break
        return xi

    def far_fitness(self, xi) -> float:
        """The share of the far points (beyond `cfg.near`) within 2 far_sigma of their known
        planes at correction xi (0 without far points)."""
        if not len(self.far):
            return 0.0
        x, q, n, _ = self._far_matches(np.asarray(xi, float))
        return float(np.count_nonzero(np.abs(np.sum(n * (x - q), axis=1)) < 2.0 * self.cfg.far_sigma)) / len(self.far)

    def far_spread(self, xi) -> float:
        """How well the far points on their planes at correction xi fix the pose in the plane:
        the least eigenvalue of the mean outer product of their normals' horizontal parts, over
        its trace (0: every such plane faces one way, a wall alone, which leaves the pose free
        along it; 0.5: two perpendicular walls seen alike). 0 without far points."""
        if not len(self.far):
            return 0.0
        x, q, n, _ = self._far_matches(np.asarray(xi, float))
        on = np.abs(np.sum(n * (x - q), axis=1)) < 2.0 * self.cfg.far_sigma
        h = n[on, :2]
        if len(h) < 10:
            return 0.0
        M = h.T @ h / len(h)
        tr = float(np.trace(M))
        return float(np.linalg.eigvalsh(M)[0]) / tr if tr > 1e-12 else 0.0

    def evaluate(self, xi):
        """(MAP cost, fitness, rmse): the cost caps residuals at `cfg.residual_cap` (or the
        last distance) and sums them over the points on structure that plane motion can
        observe (non-horizontal surfaces, or no model point near); fitness and rmse are over
        all points. A point with no model point near costs the cap: new surface, which a view
        from a new side always brings, then costs less than a misalignment of two caps, so a
        wrong pose that tucks the new surface into the model does not win by it (a point in
        known free space, or seen through a known solid, still costs the full last distance)."""
        cfg, Q, NQ = self.cfg, self.Q, self.NQ
        s2 = cfg.point_sigma ** 2
        xi = np.asarray(xi, float)
        corr = Correction(*xi)
        dmax = cfg.stages[-1][1]
        X, j, ok = self._matches(self.fine, xi, dmax)
        jj = np.where(ok, j, 0)
        r = np.where(ok, np.sum(NQ[jj] * (X - Q[jj]), axis=1), dmax)
        structure = np.where(ok, np.abs(NQ[jj][:, 2]) < 0.7, True)
        rs = r[structure]
        cap = cfg.residual_cap or dmax
        cost = float(np.sum(np.minimum(rs * rs, cap * cap)) / s2 + xi @ self.Cinv @ xi)
        inliers, total = int(np.count_nonzero(ok)), len(ok)
        if len(self.far):  # the known walls and furniture: a point off its plane costs up to far_cap
            x, q, n, unmatched = self._far_matches(xi)  # (everything there is known: unmatched is off)
            rf = np.sum(n * (x - q), axis=1)
            inliers += int(np.count_nonzero(np.abs(rf) < 2.0 * cfg.far_sigma))
            total += len(self.far)
            rf = rf[np.abs(n[:, 2]) < 0.7]
            cost += float(np.sum(np.minimum(rf * rf, cfg.far_cap ** 2)) + unmatched * cfg.far_cap ** 2) \
                / cfg.far_sigma ** 2
        if self.free_at is not None:  # surface in known free space costs like an unmatched point
            cost += float(np.count_nonzero(self.free_at(X))) * dmax * dmax / s2
        if self.view_pts is not None:  # so does a return seen through a known solid
            o = corr.apply_points(np.asarray(self.view.origin, float)[None])[0]
            bad = self.view.solids.seen_through(o, corr.apply_points(self.view_pts), cfg.see_through_tol)
            cost += float(np.count_nonzero(bad)) * dmax * dmax / s2
        fit = inliers / total if total else 0.0
        rmse = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else 0.0
        return cost, fit, rmse


def _map_threads(fn, items) -> list:
    """[fn(x) for x in items], on numba's thread count of Python threads: the grid starts are
    independent, and their KD-tree queries, numpy and the see-through kernel release the GIL
    (the same results, in order; one thread where the experiments run one per worker)."""
    n = min(numba.get_num_threads(), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, items))


def register_scan(scan_pts: np.ndarray, model: RegistrationModel, prior_cov: np.ndarray,
                  cfg: RegistrationConfig, free_at=None, view: ScanView | None = None) -> IcpResult:
    """Planar maximum-a-posteriori point-to-plane ICP of the scan's region points (believed
    world frame) against the model: Gauss-Newton over the correction xi = (dx, dy, dyaw)
    (p' = Rz(dyaw) p + (dx, dy, 0)), minimising sum_i w_i (n_i . (p_i' - q_i))^2 / s^2 +
    xi^T C^-1 xi, with the model's normals n_i (Open3D), robust (Cauchy) weights
    w_i = 1 / (1 + (r_i / 2s)^2),
    s = `cfg.point_sigma`, and C the motion model's prior covariance (`motion_prior`).
    Only the robot's motion space is searched, so tilt never trades against translation
    (the failure of unconstrained 6-DOF ICP on these partial views), and directions the
    overlap does not observe (a body of revolution turned about its axis) stay at the
    odometry estimate instead of sliding. Starts on a grid along the prior's two main axes
    (`cfg.grid_major` x `cfg.grid_minor` standard deviations), each refined at the coarse
    stage; the `cfg.refine_best` best distinct ones are refined coarse to fine over
    `cfg.stages`, and the best fit wins, where the fit also charges every scan point that
    lands in space the map has seen free (`free_at(points) -> bool`, e.g.
    `OccupancyMap.free_hits`) and, given the whole scan (`view`), every return whose ray
    passes through a known solid: partial overlaps let a wrong pose match as many points as
    the right one, but not without putting surface into known free space or seeing through
    the table. In a room or among obstacles (`cfg.near`) the scan's points beyond the
    object's surroundings (the known walls and furniture, the model there) are matched point
    to plane in every stage and in the fit at their own sigma (`cfg.far_sigma`), and count in
    the fitness. Rejected (identity, applied=False) when the model or the scan is too small,
    when another start ends far away with nearly the same fit (ambiguous), or when the final
    fit is poor."""
    n_model, n_scan = len(model.points), len(scan_pts)
    sig = tuple(np.sqrt(np.diag(prior_cov)))
    if n_model < 100 or n_scan < cfg.min_scan_points:
        return IcpResult(Correction(), 0.0, 0.0, False, "too_few_points", n_model, n_scan, sig)
    prob = PlanarIcp(scan_pts, model, prior_cov, cfg, free_at, view)
    # starts: a grid along the prior's two main axes (heading error and the sideways drift
    # it causes dominate), each refined at the coarse stage; the best few go to the end
    evals, evecs = np.linalg.eigh(prior_cov)
    sd = np.sqrt(np.maximum(evals, 0.0))
    starts = [a * sd[2] * evecs[:, 2] + b * sd[1] * evecs[:, 1] for a in cfg.grid_major for b in cfg.grid_minor]
    def from_start(x0):
        xi = prob.refine(x0, cfg.stages[:1])
        return prob.evaluate(xi)[0], tuple(np.round(xi, 4)), xi
    coarse = _map_threads(from_start, starts)
    coarse.sort(key=lambda r: r[:2])
    results, seen = [], []
    for _, _, x0 in coarse:
        if len(results) >= cfg.refine_best:
            break
        if any(np.hypot(*(x0[:2] - y[:2])) < 0.01 and abs(x0[2] - y[2]) < 0.01 for y in seen):
            continue  # same basin
        seen.append(x0)
        xi = prob.refine(x0)
        results.append((*prob.evaluate(xi), xi))
    results.sort(key=lambda r: r[0])
    best_cost, fitness, rmse, xi = results[0]
    # ambiguity: another start converged elsewhere to (nearly) as good a fit -> the overlap
    # does not determine the pose (a body of revolution, a small patch): keep the odometry
    for cost, _, _, other in results[1:]:
        far = np.hypot(*(other[:2] - xi[:2])) > cfg.ambiguity_m or abs(other[2] - xi[2]) > cfg.ambiguity_rad
        if far and cost <= best_cost * (1 + cfg.ambiguity_cost):
            return IcpResult(Correction(), fitness, rmse, False, "ambiguous", n_model, n_scan, sig)
    corr = Correction(float(xi[0]), float(xi[1]), float(xi[2]))
    if fitness < cfg.min_fitness and not (cfg.near is not None and prob.far_fitness(xi) >= cfg.min_far_fitness
                                          and prob.far_spread(xi) >= cfg.min_far_spread):
        return IcpResult(Correction(), fitness, rmse, False, "low_fitness", n_model, n_scan, sig)
    if rmse > cfg.max_rmse:
        return IcpResult(Correction(), fitness, rmse, False, "high_rmse", n_model, n_scan, sig)
    return IcpResult(corr, fitness, rmse, True, "", n_model, n_scan, sig)
