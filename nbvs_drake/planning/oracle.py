"""The ceiling and the greedy oracle: how close a run comes to the best any planner could do.

- **The ceiling** (`coverage_ceiling`): the share of the ground-truth surface (3 mm coverage,
  as the runs measure it) that any reachable, collision-free robot pose can see with the
  scenario's sensor. Measured over a dense set of poses (`CEILING_POSES` uniform states whose
  director ray meets W_box and that are free of the true world: table, chairs and the object
  itself, by Drake), each view ray-cast at full resolution against the true scene (Open3D's
  RaycastingScene: the object and the environment's boxes, which occlude). A ground-truth
  sample counts as seeable when a return of some view lies within 3 mm of it. The samples
  are a fixed draw (not the run's seed), so the ceiling is a property of the object, its
  pose, the scene and the sensor, computed once and cached on disk
  (`$NBVS_CACHE` or `~/.cache/nbvs_drake/ceiling/`).
- **The greedy oracle** (`planner.strategy: oracle`): a planner that knows the ground truth.
  Each plan ray-casts every candidate view against the true scene and picks, among the ones
  it can reach, the view whose returns add the most ground-truth surface not yet within
  3 mm of the model. Coverage per scan never falls (a scan only adds points).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from ..config import Scenario, resolve_sensor
from ..world.objects import ObjectMesh, sample_surface
from ..world.robot import RobotKinematics
from ..world.sensor import intrinsics, projector_shadow, ray_directions
from .interface import PlanRequest, PlanResult
from .motion_planner import reached_goal

#: poses the ceiling is measured over, and its fixed ground-truth draw
CEILING_POSES = 2000
CEILING_SAMPLES = 40000
COVER_RADIUS = 0.003  #: a sample is covered when a return lies this close (the runs' 3 mm coverage)
CACHE_VERSION = 2


def _box_triangles(center, size, yaw):
    """The 12 triangles of a box (vertices (8, 3), triangles (12, 3))."""
    from ..world.pose import rot_z
    h = 0.5 * np.asarray(size, float)
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * h
    V = V @ rot_z(yaw).T + np.asarray(center, float)
    T = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, T


class TruthScene:
    """The true scene for ray casting: the object mesh and the environment's boxes (Open3D
    RaycastingScene); `object_hits` gives the returns of a camera pose that land on the object
    within the sensor's range (the boxes only occlude). A sensor with faults (the Kinect's
    `DepthFaults`) returns nothing where they are certain, as its scans do: at grazing
    incidence (the angle between the ray and the true surface normal over grazing_deg) and in
    the projector's shadow (world.sensor.projector_shadow on the grid of rays, the baseline in
    its columns); its noise does not change what is seeable and is left out."""

    def __init__(self, sc: Scenario, mesh: ObjectMesh, stride: int = 1):
        import open3d as o3d

        from ..world.scene import environment_boxes
        self.scene = o3d.t.geometry.RaycastingScene()
        self.object_id = self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                                  o3d.core.Tensor(np.asarray(mesh.triangles, np.uint32)))
        for b in environment_boxes(sc.scene):
            V, T = _box_triangles(b.center, b.size, b.yaw)
            self.scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(T.astype(np.uint32)))
        self.dirs, self.t_near, self.t_far = ray_directions(sc.sensor, stride)
        w, h, fx, _, _, _ = intrinsics(sc.sensor)
        faults = resolve_sensor(sc.sensor).faults
        self.grid = (-(-h // stride), -(-w // stride))
        self.cos_grazing = float(np.cos(np.radians(faults.grazing_deg))) if faults.grazing_deg < 90.0 else None
        self.shadow_fb = fx * faults.baseline_m / stride  # in the grid's columns

    def object_hits(self, X_WC: np.ndarray) -> np.ndarray:
        import open3d as o3d
        D = self.dirs @ X_WC[:3, :3].T
        O = np.broadcast_to(X_WC[:3, 3], D.shape)
        r = self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(np.c_[O, D], np.float32)))
        t = r["t_hit"].numpy()
        ok = np.isfinite(t) & (t >= self.t_near) & (t <= self.t_far) & (r["geometry_ids"].numpy() == self.object_id)
        if self.cos_grazing is not None:
            n = r["primitive_normals"].numpy()
            ok &= np.abs(np.sum(n * D, axis=1)) >= self.cos_grazing
        if self.shadow_fb:
            z = np.where(np.isfinite(t), t * self.dirs[:, 2], np.inf).reshape(self.grid)
            ok &= ~projector_shadow(z, self.shadow_fb).ravel()
        return O[ok] + t[ok, None] * D[ok]


def newly_covered(hits: np.ndarray, gt: np.ndarray, candidates: np.ndarray, radius: float = COVER_RADIUS):
    """Indices (into gt) among `candidates` that lie within `radius` of a hit."""
    if not len(hits) or not len(candidates):
        return candidates[:0]
    from scipy.spatial import cKDTree
    d, _ = cKDTree(hits).query(gt[candidates], distance_upper_bound=radius * 1.0001)
    return candidates[np.isfinite(d) & (d <= radius)]


def uncovered(gt: np.ndarray, object_points: np.ndarray) -> np.ndarray:
    """Indices of the ground-truth samples gt not yet within COVER_RADIUS (3 mm) of the model's
    points."""
    model = np.asarray(object_points, float)
    if not len(model):
        return np.arange(len(gt))
    from scipy.spatial import cKDTree
    d, _ = cKDTree(model).query(gt, distance_upper_bound=COVER_RADIUS * 1.0001)
    return np.flatnonzero(~(np.isfinite(d) & (d <= COVER_RADIUS)))


def reference_samples(sc: Scenario, mesh: ObjectMesh, n: int = CEILING_SAMPLES) -> np.ndarray:
    """A fixed draw of ground-truth samples (not the run's seed), without the band at the
    table that no scan keeps (as `objects.ground_truth_points`)."""
    pts = sample_surface(mesh, 2 * n, np.random.default_rng([29, n]))
    return pts[pts[:, 2] >= sc.scene.base_z() + sc.mapper.table_clearance][:n]


def ceiling_poses(sc: Scenario, kin: RobotKinematics, mesh_obj: str | None, n: int, rng) -> np.ndarray:
    """n uniform states whose director ray meets W_box and that are free of the true world
    (Drake's check against the table, the chairs and the object mesh `mesh_obj`)."""
    from .candidates import StateSampler
    from .collision import CollisionModel
    sampler = StateSampler(sc, kin)
    truth = CollisionModel(sc, kin, object_obj=mesh_obj)
    out, tries = [], 0
    while sum(len(o) for o in out) < n and tries < 50:
        q = sampler.sample_states(rng, 8 * n)
        q = q[sampler.looks_at_wbox(q)]
        out.append(q[truth.free(q)])
        tries += 1
    return np.concatenate(out)[:n]


def _cache_key(sc: Scenario, mesh: ObjectMesh, n_poses: int) -> str:
    import dataclasses as dc
    d = {"v": CACHE_VERSION, "n": n_poses, "samples": CEILING_SAMPLES, "scene": dc.asdict(sc.scene),
         "sensor": dc.asdict(resolve_sensor(sc.sensor)), "robot": dc.asdict(sc.robot),
         "clearance": sc.mapper.table_clearance,
         "mesh": hashlib.sha1(np.ascontiguousarray(mesh.vertices).tobytes()
                              + np.ascontiguousarray(mesh.triangles).tobytes()).hexdigest()}
    d["scene"].pop("gt_points", None)
    if resolve_sensor(sc.sensor).faults.any():  # since the sensor's faults bound what is seeable
        d["faults"] = 1
    return hashlib.sha1(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


def cache_dir() -> Path:
    return Path(os.environ.get("NBVS_CACHE") or Path.home() / ".cache" / "nbvs_drake") / "ceiling"


def coverage_ceiling(sc: Scenario, kin: RobotKinematics, mesh: ObjectMesh, mesh_obj: str | None = None,
                     n_poses: int = CEILING_POSES, use_cache: bool = True) -> dict:
    """{"ceiling", "ceiling_1cm", "poses", "samples", "seconds", "cached"}: the share of the ground-truth
    surface seeable from `n_poses` reachable collision-free poses (module docstring)."""
    path = cache_dir() / f"{_cache_key(sc, mesh, n_poses)}.json"
    if use_cache and path.is_file():
        try:
            return dict(json.loads(path.read_text()), cached=True)
        except (OSError, ValueError):
            pass
    t = time.perf_counter()
    if mesh_obj is None:
        import tempfile
        with tempfile.TemporaryDirectory() as tmp:
            obj = mesh.write_obj(Path(tmp) / "object.obj")
            q = ceiling_poses(sc, kin, str(obj), n_poses, np.random.default_rng([31, n_poses]))
    else:
        q = ceiling_poses(sc, kin, mesh_obj, n_poses, np.random.default_rng([31, n_poses]))
    gt = reference_samples(sc, mesh)
    # one ray per model pixel (sensor.model_binning: the Kinect's 3 x 3 pixels, rays 4 mm apart
    # at 1 m; the SR4000's every pixel)
    truth = TruthScene(sc, mesh, stride=resolve_sensor(sc.sensor).model_binning)
    covered = np.zeros(len(gt), bool)
    covered_1cm = np.zeros(len(gt), bool)  # the same at 1 cm (coarse maps: scene.mapper.voxel_size 3 cm)
    for X in kin.camera_poses(q):
        hits = truth.object_hits(X)
        covered[newly_covered(hits, gt, np.flatnonzero(~covered))] = True
        covered_1cm[newly_covered(hits, gt, np.flatnonzero(~covered_1cm), 0.01)] = True
    out = {"ceiling": round(float(covered.mean()), 6), "ceiling_1cm": round(float(covered_1cm.mean()), 6),
           "poses": int(len(q)), "samples": int(len(gt)), "seconds": round(time.perf_counter() - t, 2)}
    if use_cache:
        from ..files import write_atomic
        try:
            write_atomic(path, json.dumps(out), mkdir=True)
        except OSError:
            pass  # a read-only home: computed again next time
    return dict(out, cached=False)


class OraclePlanner:
    """planner.strategy "oracle": the greedy oracle (module docstring). Candidates as random
    sampling draws them (planner.n_candidates, the position filter against the plan's
    obstacles); each is ray-cast against the true scene (every 2nd pixel first, the best
    4 x top_k again at full resolution) and scored by the ground-truth surface its returns
    add (samples not yet within 3 mm of the model's points); the top_k go to motion planning
    and the reachable one that adds the most is chosen."""

    def __init__(self, sc: Scenario, kin: RobotKinematics, sampler, obstacles, motion, truth_mesh: ObjectMesh):
        self.sc = sc
        self.kin = kin
        self.sampler = sampler
        self.obstacles = obstacles
        self.motion = motion
        self.truth = TruthScene(sc, truth_mesh)
        self.coarse = TruthScene(sc, truth_mesh, stride=2)
        self.gt = reference_samples(sc, truth_mesh, sc.scene.gt_points)

    def uncovered(self, object_points: np.ndarray) -> np.ndarray:
        """Indices of the ground-truth samples not yet within 3 mm of the model's points."""
        return uncovered(self.gt, object_points)

    def _gain(self, scene: TruthScene, q: np.ndarray, todo: np.ndarray) -> np.ndarray:
        return np.array([len(newly_covered(scene.object_hits(X), self.gt, todo)) for X in self.kin.camera_poses(q)])

    def plan(self, request: PlanRequest) -> PlanResult:
        from ..world.motion import path_length
        from .candidates import free_candidates
        p = self.sc.planner
        times, stages = {}, {}
        obstacles = self.obstacles.for_map(request.omap)
        cand = free_candidates(self.sampler, obstacles, request.rng, request.omap, stages, times)
        t = time.perf_counter()
        todo = self.uncovered(request.omap.object_points)
        gain = self._gain(self.coarse, cand, todo).astype(float)
        best = np.argsort(-gain, kind="stable")[: 4 * p.top_k]
        best = best[gain[best] > 0]
        fine = self._gain(self.truth, cand[best], todo).astype(float)
        order = best[np.argsort(-fine, kind="stable")]
        fine_of = dict(zip(best.tolist(), fine.tolist()))
        times["view_evaluation_s"] = time.perf_counter() - t
        stages["surface"] = int(len(order))
        if not len(order):
            return PlanResult("no_candidate", stages=stages, times=times)
        t = time.perf_counter()
        for start in range(0, len(order), p.top_k):
            batch = order[start:start + p.top_k]
            found = self.motion.connect_many(request.q_start, cand[batch], obstacles, request.rng)
            for i, f in zip(batch, found):
                if f is None:
                    continue
                times["motion_planning_s"] = time.perf_counter() - t
                kind, controls, states = f
                g = fine_of[int(i)] / max(len(self.gt), 1)
                return PlanResult("ok", reached_goal(self.sc, cand[i], states), controls, states, kind, float(g), {
                    "pos": 1.0, "reg": 1.0, "info": float(g), "metric": "oracle", "dist": 1.0,
                    "rho": float(path_length(states, p.weights)), "du": float(g)}, stages, times, path_nodes=f.nodes)
        times["motion_planning_s"] = time.perf_counter() - t
        return PlanResult("no_path", stages=stages, times=times)
