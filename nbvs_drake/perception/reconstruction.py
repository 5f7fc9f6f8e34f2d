"""The reconstruction as 3D reconstruction research measures it: a surface mesh by TSDF fusion
of the registered depth scans, and accuracy, completeness, Chamfer distance and the F-score
(Knapitsch et al. 2017, Tanks and Temples) against the ground truth, for the point model and
for the mesh.

Definitions (d(p, S): distance of a point p to a set or surface S; G: the ground-truth
surface, the object mesh; G_s: its samples, `objects.ground_truth_points`, without the band
at the table; M: the reconstruction, points or mesh surface samples):

- accuracy (m): mean over p in M of d(p, G), point to triangle, exact; `accuracy_p90_m` its
  90th percentile;
- completeness (m): mean over g in G_s of d(g, M), to the nearest model point (points) or
  exactly to the mesh's triangles (mesh);
- chamfer (m): (accuracy + completeness) / 2;
- precision(tau): share of M within tau of G; recall(tau): share of G_s within tau of M
  (the point model's recall at 3 mm is the coverage); fscore(tau) = 2 P R / (P + R), at
  tau = 3 mm, 5 mm and one voxel.

The mesh's accuracy is over surface samples of the mesh (as many as G_s, area-weighted).
"""

from __future__ import annotations

import math

import numpy as np

#: the F-score thresholds by name; "voxel": the map's voxel size
TAUS = ("3mm", "5mm", "voxel")


def _scene(V: np.ndarray, T: np.ndarray):
    import open3d as o3d
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(V, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(T, np.uint32)))
    return scene


def surface_distance(V: np.ndarray, T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Unsigned distance (N,) of points P (N, 3) to the triangle mesh (V, T)."""
    P = np.asarray(P, float).reshape(-1, 3)
    if not len(P):
        return np.zeros(0)
    import open3d as o3d
    return _scene(V, T).compute_distance(o3d.core.Tensor(np.ascontiguousarray(P, np.float32))).numpy().astype(float)


def _score(acc: np.ndarray, comp: np.ndarray, voxel: float) -> dict:
    """The metrics' dict from the distances of the reconstruction to G (acc) and of G_s to
    the reconstruction (comp); None where they are undefined (an empty reconstruction)."""
    taus = {"3mm": 0.003, "5mm": 0.005, "voxel": float(voxel)}
    r = lambda v: None if v is None or not math.isfinite(v) else round(float(v), 6)  # noqa: E731
    out = {"accuracy_m": None, "accuracy_p90_m": None, "completeness_m": None, "chamfer_m": None,
           "precision": {}, "recall": {}, "fscore": {}}
    if len(acc):
        out["accuracy_m"] = r(acc.mean())
        out["accuracy_p90_m"] = r(np.percentile(acc, 90))
    if len(comp) and np.isfinite(comp).all():
        out["completeness_m"] = r(comp.mean())
    if out["accuracy_m"] is not None and out["completeness_m"] is not None:
        out["chamfer_m"] = r(0.5 * (acc.mean() + comp.mean()))
    for name, tau in taus.items():
        p = float(np.mean(acc <= tau)) if len(acc) else 0.0
        rc = float(np.mean(comp <= tau)) if len(comp) else 0.0
        out["precision"][name], out["recall"][name] = r(p), r(rc)
        out["fscore"][name] = r(2 * p * rc / (p + rc) if p + rc > 0 else 0.0)
    return out


def point_metrics(points: np.ndarray, gt_V: np.ndarray, gt_T: np.ndarray, gt_points: np.ndarray,
                  voxel: float) -> dict:
    """The metrics of a point model against the ground truth (module docstring)."""
    from scipy.spatial import cKDTree
    points = np.asarray(points, float).reshape(-1, 3)
    acc = surface_distance(gt_V, gt_T, points)
    comp = cKDTree(points).query(np.asarray(gt_points, float))[0] if len(points) else np.full(len(gt_points), np.inf)
    return _score(acc, comp, voxel)


def mesh_metrics(V: np.ndarray, T: np.ndarray, gt_V: np.ndarray, gt_T: np.ndarray, gt_points: np.ndarray,
                 voxel: float, rng: np.random.Generator) -> dict:
    """The metrics of a reconstructed mesh (V, T) against the ground truth: its accuracy over
    area-weighted surface samples (as many as gt_points), its completeness exact to its
    triangles."""
    if len(T) == 0:
        return _score(np.zeros(0), np.full(len(gt_points), np.inf), voxel)
    from ..world.objects import ObjectMesh, sample_surface
    samples = sample_surface(ObjectMesh(np.asarray(V, float), np.asarray(T, np.int32)), len(gt_points), rng)
    return _score(surface_distance(gt_V, gt_T, samples), surface_distance(V, T, gt_points), voxel)


# --------------------------------------------------------------------------------------
# TSDF fusion of the registered scans
# --------------------------------------------------------------------------------------


def _pixels(points: np.ndarray, X_WC: np.ndarray, intr: tuple) -> tuple:
    """(z, u, v, ok) (N,): the points' (N, 3, world frame) depth in the camera at X_WC (+z
    forward, +x right, +y down), their nearest pixel (column u, row v) for the intrinsics
    intr = (w, h, fx, fy, cx, cy), and whether they lie in front of the camera and in the
    image: the one projection of the depth images and of every test against them."""
    w, h, fx, fy, cx, cy = intr
    X_WC = np.asarray(X_WC, float)
    p = (np.asarray(points, float).reshape(-1, 3) - X_WC[:3, 3]) @ X_WC[:3, :3]
    z = p[:, 2]
    ok = z > 1e-6
    zs = np.where(ok, z, 1.0)
    u = np.rint(fx * p[:, 0] / zs + cx).astype(np.int64)
    v = np.rint(fy * p[:, 1] / zs + cy).astype(np.int64)
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return z, u, v, ok


def depth_from_points(points: np.ndarray, X_WC: np.ndarray, width: int, height: int, fx: float, fy: float,
                      cx: float, cy: float) -> np.ndarray:
    """The depth image (height, width) float32 that the returns `points` (world frame) make
    in the camera at X_WC (+z forward, +x right, +y down): each point at its nearest pixel,
    the nearest depth kept; 0 where no return fell."""
    z, u, v, ok = _pixels(points, X_WC, (width, height, fx, fy, cx, cy))
    u, v, z = u[ok], v[ok], z[ok]
    depth = np.full(height * width, np.inf)
    np.minimum.at(depth, v * width + u, z)
    depth[~np.isfinite(depth)] = 0.0
    return depth.reshape(height, width).astype(np.float32)


#: a scan's return lies in space another scan saw through when it is nearer that camera than
#: the other's return at the same pixel (the nearest of its 3 x 3 neighbourhood: a silhouette's
#: pixels see past the edge) by more than this plus three sigma of the sensor's axial noise there
CONFLICT_MARGIN_M = 0.02
#: a scan whose returns lie in the others' seen-through space, and theirs in its own, more than
#: this share of the time (pooled over the pairs that overlap) is left out of the model
MAX_CONFLICT = 0.05
#: a scan judged on fewer overlapping returns than this is kept (nothing to judge it against)
MIN_OVERLAP = 200


def scan_points(X_WC: np.ndarray, depth: np.ndarray, intr: tuple, step: int = 1) -> np.ndarray:
    """The world points (N, 3) of a depth image at camera pose X_WC (every `step`-th pixel
    per row and column), the inverse of `depth_from_points`."""
    w, h, fx, fy, cx, cy = intr
    v, u = np.nonzero(np.asarray(depth)[::step, ::step] > 0)
    v, u = v * step, u * step
    z = np.asarray(depth, float)[v, u]
    pc = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
    return pc @ np.asarray(X_WC, float)[:3, :3].T + np.asarray(X_WC, float)[:3, 3]


def _nearest_around(depth: np.ndarray) -> np.ndarray:
    """Each pixel's nearest return among its 3 x 3 neighbours; 0 where the pixel has none."""
    from scipy.ndimage import minimum_filter
    d = np.where(depth > 0, depth, np.inf)
    m = minimum_filter(d, size=3, mode="nearest")
    return np.where(np.isfinite(m) & (depth > 0), m, 0.0)


def _depth_at(points: np.ndarray, X_WC: np.ndarray, image: np.ndarray, intr: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(z, d) (N,): each point's depth in the camera at X_WC, and the image's value at the
    pixel it falls on (`depth_from_points`' pixels); d 0 for a point behind the camera or
    outside the image."""
    z, u, v, ok = _pixels(points, X_WC, intr)
    d = np.zeros(len(z))
    d[ok] = np.asarray(image)[v[ok], u[ok]]
    return z, d


def seen_through(points: np.ndarray, X_WC: np.ndarray, near: np.ndarray, intr: tuple,
                 sigma=lambda z: 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(overlap, conflict) (N,) bool: which points fall on a pixel where the scan at X_WC has a
    return (`near`: `_nearest_around` of its depth), and which of those lie nearer the camera
    than that return by more than CONFLICT_MARGIN_M + 3 sigma(z) (the scan's rays passed
    through them)."""
    z, d = _depth_at(points, X_WC, near, intr)
    ok = d > 0
    return ok, ok & (z < d - CONFLICT_MARGIN_M - 3.0 * sigma(d))


def consistent_scans(scans, intr: tuple, sigma=lambda z: 0.0, max_conflict: float = MAX_CONFLICT,
                     step: int = 2) -> tuple[list[int], dict[int, float]]:
    """(kept, left_out): which of the registered scans, each (X_WC (4, 4), depth (h, w)), agree
    with each other, and the conflict share of each scan left out. A scan placed wrong by its
    registration puts its surface where the others saw through, and the others' surface where
    it saw through: for every ordered pair (i, j), the share of scan i's returns (every
    `step`-th pixel) that scan j saw through (`seen_through`) among those on j's returns. A
    scan's conflict pools both directions over the scans kept; the worst scan above
    `max_conflict` is left out and the others judged again without it, until none is. A scan
    with fewer than MIN_OVERLAP returns on the others' (or theirs on its own) is kept. Scans
    registered right (at most 0.006 in the runs measured, noise-free and noisy) stay; the misplaced ones of the noisy
    runs (7-11 cm, 0.1-0.18 rad) scored 0.09-0.17 (docs/decisions.md)."""
    n = len(scans)
    O = np.zeros((n, n))
    C = np.zeros((n, n))
    pts = [scan_points(X, d, intr, step) for X, d in scans]
    near = [_nearest_around(np.asarray(d, float)) for _, d in scans]
    for i in range(n):
        for j in range(n):
            if i != j and len(pts[i]):
                ov, cf = seen_through(pts[i], np.asarray(scans[j][0], float), near[j], intr, sigma)
                O[i, j], C[i, j] = ov.sum(), cf.sum()
    kept = list(range(n))
    left_out: dict[int, float] = {}
    while len(kept) > 2:
        k = np.array(kept)
        over = O[np.ix_(k, k)].sum(1) + O[np.ix_(k, k)].sum(0)
        conf = C[np.ix_(k, k)].sum(1) + C[np.ix_(k, k)].sum(0)
        share = np.where(over >= MIN_OVERLAP, conf / np.maximum(over, 1.0), 0.0)
        worst = int(np.argmax(share))
        if share[worst] <= max_conflict:
            break
        left_out[kept[worst]] = float(share[worst])
        kept.pop(worst)
    return kept, left_out


def owned_by(points: np.ndarray, scans, intr: tuple, tol: float = 0.002) -> np.ndarray:
    """Which points (N, 3) are returns of one of the scans, each (X_WC, depth): they fall on
    a pixel of its depth image whose return is at their depth, within `tol` (the depth image
    holds each pixel's return; `depth_from_points`)."""
    P = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    for X_WC, depth in scans:
        z, d = _depth_at(P, X_WC, depth, intr)
        out |= (d > 0) & (np.abs(z - d) <= tol)
    return out


def fuse_tsdf(scans, intr: tuple, box_min, box_max, voxel: float = 0.003, trunc: float = 0.012,
              z_far: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """TSDF fusion (Curless and Levoy 1996; Open3D's sparse VoxelBlockGrid, blocks of 8^3
    voxels) of the scans, each (X_WC (4, 4), depth (h, w) float32 m), with the pinhole
    intrinsics intr = (w, h, fx, fy, cx, cy); the marching-cubes surface of every voxel
    observed at least once, cropped to the box [box_min, box_max]. Returns (vertices (V, 3),
    triangles (T, 3)). (The grid carries a constant colour channel: Open3D 0.20's extraction
    fails without one, and its legacy ScalableTSDFVolume returns no surface at all.)"""
    import open3d as o3d
    import open3d.core as o3c
    w, h, fx, fy, cx, cy = intr
    cpu = o3c.Device("CPU:0")
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=8, block_count=4000, device=cpu)
    K = o3c.Tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], o3c.float64)
    color = o3d.t.geometry.Image(o3c.Tensor(np.zeros((int(h), int(w), 3), np.float32)))
    for X_WC, depth in scans:
        if not np.any((depth > 0) & (depth < z_far)):
            continue  # nothing of the object region in view
        d = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth, np.float32)[:, :, None]))
        ext = o3c.Tensor(np.linalg.inv(np.asarray(X_WC, float)), o3c.float64)
        try:
            blocks = vbg.compute_unique_block_coordinates(d, K, ext, depth_scale=1.0, depth_max=z_far,
                                                          trunc_voxel_multiplier=trunc / voxel)
        except RuntimeError:  # Open3D: "No block is touched"
            continue
        if blocks.shape[0] == 0:
            continue
        vbg.integrate(blocks, d, color, K, K, ext, depth_scale=1.0, depth_max=z_far,
                      trunc_voxel_multiplier=trunc / voxel)
    try:
        mesh = vbg.extract_triangle_mesh(weight_threshold=0.5).to_legacy()
    except RuntimeError:  # nothing integrated: Open3D cannot build an empty mesh
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    if len(mesh.triangles):
        mesh = mesh.crop(o3d.geometry.AxisAlignedBoundingBox(np.asarray(box_min, float), np.asarray(box_max, float)))
        mesh.remove_unreferenced_vertices()
    return canonical_mesh(np.asarray(mesh.vertices, float), np.asarray(mesh.triangles, np.int32))


def canonical_mesh(V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same mesh with its vertices in lexicographic order and its triangles sorted: the
    parallel extraction lists them in a different order from run to run, and the same seed
    must give the same mesh file and the same metrics."""
    if not len(V):
        return V.reshape(-1, 3), T.reshape(-1, 3)
    order = np.lexsort(V.T[::-1])
    rank = np.empty(len(V), np.int64)
    rank[order] = np.arange(len(V))
    T = rank[T]
    first = np.argmin(T, axis=1)
    T = np.stack([T[np.arange(len(T)), (first + k) % 3] for k in range(3)], axis=1)  # start at its smallest
    T = T[np.lexsort(T.T[::-1])]
    return V[order], T.astype(np.int32)


def write_mesh_ply(path, V: np.ndarray, T: np.ndarray):
    """A binary PLY of the triangle mesh (written whole: temporary file, then rename)."""
    from ..files import write_atomic
    V = np.asarray(V, "<f4").reshape(-1, 3)
    T = np.asarray(T, "<i4").reshape(-1, 3)
    head = (f"ply\nformat binary_little_endian 1.0\ncomment nbvs_drake model_mesh (TSDF fusion, world frame, m)\n"
            f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(T)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    faces = np.zeros(len(T), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, T
    write_atomic(path, head + V.tobytes() + faces.tobytes())
