"""The probabilistic occupancy map over W_box (plus a margin) with OctoMap's sensor model.

`OccupancyMap` is an immutable value: `integrate` returns a new map. That lets Drake keep it
in abstract state and copy contexts freely (copies share the arrays).
"""

from __future__ import annotations

import dataclasses as dc
import functools
import math

import numpy as np

from ..config import MapperConfig, Scenario
from ..files import write_atomic
from .raycast import integrate_scan
from .voxel import FREE, OCCUPIED, UNKNOWN, classes_grid


def logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dc.dataclass(frozen=True)
class SensorModel:
    l_hit: float
    l_miss: float
    l_min: float
    l_max: float
    l_free: float  #: below: free
    l_occ: float  #: above: occupied

    @staticmethod
    def from_config(m: MapperConfig) -> "SensorModel":
        return SensorModel(logit(m.prob_hit), logit(m.prob_miss), logit(m.clamp_min),
                           logit(m.clamp_max), logit(m.free_below), logit(m.occupied_above))


@dc.dataclass(frozen=True)
class GridSpec:
    bmin: np.ndarray  #: lower corner of voxel (0, 0, 0)
    res: float
    dims: tuple[int, int, int]

    @property
    def bmax(self) -> np.ndarray:
        return self.bmin + np.array(self.dims) * self.res

    def key_offset(self) -> np.ndarray:
        """OctoMap key of voxel (0, 0, 0): floor(bmin / res) + 2^15 (tree depth 16)."""
        return np.rint(self.bmin / self.res).astype(np.int64) + 32768

    def voxel_index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(idx (N, 3) int64, inside (N,) bool): the voxel holding each point, and whether it
        lies in the grid."""
        idx = np.floor((np.asarray(points, float) - self.bmin) / self.res).astype(np.int64)
        return idx, np.all((idx >= 0) & (idx < np.array(self.dims)), axis=1)

    def centers(self) -> np.ndarray:
        """Voxel centres (nx, ny, nz, 3)."""
        ax = [self.bmin[a] + (np.arange(self.dims[a]) + 0.5) * self.res for a in range(3)]
        return np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1)


def grid_for_scenario(sc: Scenario) -> GridSpec:
    return grid_for(sc.scene, sc.mapper)


def grid_for(scene, m) -> GridSpec:
    """W_box grown by the margin on the sides and the top (the table bounds it below), on the
    voxel lattice of OctoMap: voxel boundaries at integer multiples of the voxel size, so
    that voxel (i, j, k) is OctoMap's key (i, j, k) + key_offset (see `octomap_key_offset`);
    `scene` and `m` are the scene and mapper sections."""
    res = float(m.voxel_size)
    lo = np.array(scene.bbox_min, float) - np.array([m.margin, m.margin, 0.0])
    hi = np.array(scene.bbox_max, float) + m.margin
    i_lo = np.floor(lo / res + 1e-9).astype(int)
    i_hi = np.ceil(hi / res - 1e-9).astype(int)
    return GridSpec(i_lo * res, res, tuple(int(x) for x in (i_hi - i_lo)))


@functools.lru_cache(maxsize=8)
def _in_box(bmin: tuple, res: float, dims: tuple, lo: tuple, hi: tuple) -> np.ndarray:
    """`OccupancyMap.in_wbox` of a grid and a box (each axis apart: the same centres)."""
    ax = [np.asarray(bmin[a] + (np.arange(dims[a]) + 0.5) * res) for a in range(3)]
    m = [(x >= lo[a]) & (x <= hi[a]) for a, x in enumerate(ax)]
    out = m[0][:, None, None] & m[1][None, :, None] & m[2][None, None, :]
    out.flags.writeable = False
    return out


class OccupancyMap:
    """Immutable occupancy map snapshot: log-odds grid, accumulated object points, counters."""

    __slots__ = ("spec", "model", "logodds", "object_points", "object_normals", "scan_count", "wbox_min",
                 "wbox_max", "_classes")

    def __init__(self, spec: GridSpec, model: SensorModel, logodds: np.ndarray | None = None,
                 object_points: np.ndarray | None = None, scan_count: int = 0,
                 wbox_min=None, wbox_max=None, object_normals: np.ndarray | None = None):
        self.spec = spec
        self.model = model
        if logodds is None:
            logodds = np.zeros(spec.dims, np.float32)
        logodds.flags.writeable = False
        self.logodds = logodds
        if object_points is None:
            object_points = np.zeros((0, 3), np.float32)
        object_points.flags.writeable = False
        self.object_points = object_points
        #: unit surface normal of each object point, towards the camera that saw it
        #: (`scan_normals`; zero where unknown, e.g. a map saved before normals were kept)
        if object_normals is None:
            object_normals = np.zeros((len(object_points), 3), np.float32)
        elif len(object_normals) != len(object_points):
            raise ValueError(f"{len(object_normals)} object normals for {len(object_points)} object points")
        object_normals.flags.writeable = False
        self.object_normals = object_normals
        self.scan_count = scan_count
        self.wbox_min = spec.bmin if wbox_min is None else np.asarray(wbox_min, float)
        self.wbox_max = spec.bmax if wbox_max is None else np.asarray(wbox_max, float)
        self._classes = None

    # immutable: copies share the arrays (Drake clones abstract state on every update)
    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    @staticmethod
    def for_scenario(sc: Scenario) -> "OccupancyMap":
        return OccupancyMap.for_scene(sc.scene, sc.mapper)

    @staticmethod
    def for_scene(scene, mapper) -> "OccupancyMap":
        """The empty map of W_box (the scene section) with the mapper section's settings."""
        return OccupancyMap(grid_for(scene, mapper), SensorModel.from_config(mapper),
                            wbox_min=scene.bbox_min, wbox_max=scene.bbox_max)

    # ---- classes -------------------------------------------------------------------
    def classes(self) -> np.ndarray:
        """int8 class of every voxel (voxel.FREE, UNKNOWN, OCCUPIED); computed once per map (its
        log-odds never change) and shared: callers must not change it (it stays writeable, so
        the numba kernels that take it keep their compiled signatures)."""
        if self._classes is None:
            self._classes = classes_grid(np.ascontiguousarray(self.logodds), self.model.l_free, self.model.l_occ)
        return self._classes

    def counts(self) -> dict:
        c = self.classes()
        return {"unknown": int((c == UNKNOWN).sum()), "free": int((c == FREE).sum()),
                "occupied": int((c == OCCUPIED).sum())}

    def unknown_mask(self) -> np.ndarray:
        """Voxels of the unknown class (l_free <= l <= l_occ)."""
        return self.classes() == UNKNOWN

    def free_at(self, points: np.ndarray) -> np.ndarray:
        """Whether each point lies in a voxel of the free class (False outside the map)."""
        idx, inside = self.spec.voxel_index(points)
        out = np.zeros(len(idx), bool)
        i = idx[inside]
        lo = np.ascontiguousarray(self.logodds[i[:, 0], i[:, 1], i[:, 2]])
        out[inside] = classes_grid(lo, self.model.l_free, self.model.l_occ) == FREE
        return out

    def free_hits(self, points: np.ndarray, table_clearance: float) -> np.ndarray:
        """Points this map would integrate as object hits (`object_mask`) that lie in known
        free space: what a scan at a wrong pose contradicts. Returns on the table top are
        left out (they are misses here, so the voxel above the table is free)."""
        return self.object_mask(np.asarray(points, float), table_clearance) & self.free_at(points)

    def unknown_count(self) -> int:
        return int(np.count_nonzero(self.unknown_mask()))

    def reachable_unknown_count(self) -> int:
        """Unknown voxels a view could still reach: those joined (face to face, through unknown
        voxels) to a free voxel or to the map's sides or top. The unknown voxels walled in by
        occupied ones and the surface the object stands on (the inside of a solid seat, of a box)
        are left out: no view can see them, so a stop on few unknown voxels
        (mission.stop_unknown_voxels) does not wait for them."""
        from scipy import ndimage
        c = self.classes()
        unknown = c == UNKNOWN
        labels, n = ndimage.label(unknown)
        if n == 0:
            return 0
        seeds = ndimage.binary_dilation(c == FREE) & unknown
        for face in (np.s_[0], np.s_[-1]):
            seeds[face] |= unknown[face]
            seeds[:, face] |= unknown[:, face]
        seeds[:, :, -1] |= unknown[:, :, -1]
        reached = np.unique(labels[seeds])
        return int(np.count_nonzero(np.isin(labels, reached[reached > 0])))

    def in_wbox(self) -> np.ndarray:
        """Voxels whose centre lies in W_box (the map also covers a margin around it); read-only,
        one array per grid and box."""
        lo, hi = (tuple(np.asarray(b, float).tolist()) for b in (self.wbox_min, self.wbox_max))
        return _in_box(tuple(self.spec.bmin.tolist()), self.spec.res, self.spec.dims, lo, hi)

    def probabilities(self) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self.logodds.astype(np.float64)))

    def voxel_volume(self) -> float:
        return self.spec.res ** 3

    # ---- update --------------------------------------------------------------------
    def object_mask(self, points: np.ndarray, table_clearance: float) -> np.ndarray:
        """Points that belong to the object: inside W_box and above the table clearance."""
        lo = self.wbox_min.copy()
        lo[2] += table_clearance
        return np.all((points >= lo) & (points <= self.wbox_max), axis=1)

    def integrate(self, origin: np.ndarray, points: np.ndarray, table_clearance: float,
                  free_rays: np.ndarray | None = None) -> tuple["OccupancyMap", dict]:
        """Returns (new map, stats). `points` are world-frame returns (non-finite rows must
        have been dropped); those inside W_box above the table are hits and object points.
        `free_rays` are end points of rays without a return (max range): misses only."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        n_free = 0
        if free_rays is not None and len(free_rays):
            n_free = len(free_rays)
            points = np.concatenate([points, np.asarray(free_rays, np.float64)])
        origin = np.asarray(origin, np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {points.shape}")
        if not np.all(np.isfinite(points)) or not np.all(np.isfinite(origin)):
            raise ValueError("scan has non-finite points or sensor origin; drop them before integrating")
        hit = self.object_mask(points, table_clearance)
        if n_free:
            hit[len(points) - n_free:] = False
        lo = np.array(self.logodds, copy=True)
        m = self.model
        n_upd = integrate_scan(lo, self.spec.bmin.astype(np.float64), self.spec.res, origin, points, hit,
                               m.l_hit, m.l_miss, m.l_min, m.l_max)
        obj = np.concatenate([self.object_points, points[hit].astype(np.float32)])
        nrm = np.concatenate([self.object_normals, scan_normals(origin, points[hit])])
        new = OccupancyMap(self.spec, m, lo, obj, self.scan_count + 1, self.wbox_min, self.wbox_max, nrm)
        return new, {"points": int(len(points) - n_free), "no_return_rays": n_free,
                     "object_points": int(hit.sum()), "voxels_updated": int(n_upd)}

    def skipped(self) -> "OccupancyMap":
        """The same map counting one more scan (a scan taken but not integrated)."""
        return OccupancyMap(self.spec, self.model, self.logodds, self.object_points, self.scan_count + 1,
                            self.wbox_min, self.wbox_max, self.object_normals)

    def obstacle_boxes(self, max_boxes: int = 300) -> tuple[list, int]:
        """The unknown and occupied voxels of W_box as at most `max_boxes` merged boxes
        (centre, size) in metres, conservative (see mapping.boxes). Returns (boxes, block)."""
        from .boxes import conservative_boxes
        mask = self.in_wbox() & (self.classes() != FREE)  # unknown or occupied
        boxes, block = conservative_boxes(mask, max_boxes)
        res = self.spec.res
        out = [(self.spec.bmin + (lo + hi) * res / 2, (hi - lo) * res) for lo, hi in boxes]
        return out, block

    # ---- export --------------------------------------------------------------------
    def save_npz(self, path):
        np.savez_compressed(path, logodds=self.logodds, bmin=self.spec.bmin, res=self.spec.res,
                            object_points=self.object_points, object_normals=self.object_normals,
                            scan_count=self.scan_count,
                            wbox_min=self.wbox_min, wbox_max=self.wbox_max,
                            model=np.array(dc.astuple(self.model)))

    @staticmethod
    def load_npz(path) -> "OccupancyMap":
        z = np.load(path)
        lo = np.array(z["logodds"])
        spec = GridSpec(np.array(z["bmin"]), float(z["res"]), tuple(int(x) for x in lo.shape))
        return OccupancyMap(spec, SensorModel(*[float(x) for x in z["model"]]), lo,
                            np.array(z["object_points"]), int(z["scan_count"]),
                            z["wbox_min"], z["wbox_max"],
                            np.array(z["object_normals"]) if "object_normals" in z else None)


#: neighbours of a scan's point that fit its surface normal (scan_normals)
NORMAL_NEIGHBOURS = 15


def scan_normals(origin: np.ndarray, points: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unit surface normals (N, 3) float32 of one scan's points, each the least-squares plane
    of its k nearest neighbours in the same scan (Open3D), turned towards the camera at
    `origin` that saw it; zero for a scan of fewer than 3 points. From one scan, so the
    neighbours are samples of the surface one view saw, not a blend of registered views."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 3:
        return np.zeros((len(pts), 3), np.float32)
    import open3d as o3d
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(min(k, len(pts))))
    n = np.asarray(pc.normals)
    away = np.einsum("ij,ij->i", n, np.asarray(origin, np.float64) - pts) < 0
    n[away] *= -1.0
    return n.astype(np.float32)


def write_ply(path, points: np.ndarray):
    """Binary little-endian PLY of xyz float32 points (written atomically)."""
    pts = np.ascontiguousarray(points, dtype="<f4")
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
              "end_header\n").encode()
    write_atomic(path, header + pts.tobytes())
