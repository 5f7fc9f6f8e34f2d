"""Santos et al. 2020 (Santos et al. 2020): voxel-sorted ray casting (§3.5, Algorithm 1), its pose score
(§3.6) and the clusters of unknown voxels with their centroids (§3.2) used by its view
sampling.

Voxel-sorted ray casting starts from the unknown voxels instead of the pixels: the unknown
voxels whose centres project inside the image within the depth range are sorted farthest
first; a ray is cast from the camera through the centre of each voxel not yet intercepted.
Along the ray, the first unknown voxel is counted in n_first, later unknown voxels in
n_posterior; every intercepted voxel is never cast again. Past an occupied voxel, the
voxels the ray would cross up to the end of the frustum are marked intercepted but not
discovered (occluded).

The sensor model is the view evaluation's (mapping.view_metrics): a ray starts at the camera
and one that meets an occupied or (conservatively) an unknown voxel among the voxels it
enters before the minimum range (depth z_near) is blinded: it discovers nothing and the
voxels it would cross beyond the minimum range, its target included, are marked intercepted
(occluded).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import ndimage

from .raycast import axis_start, blinded_within, clip_ray, dda_step
from .voxel import OCCUPIED, UNKNOWN


@nb.njit(cache=True)
def _voxel_sorted_one(cls, bmin, res, o, R, fx, fy, cx, cy, w, h, z_near, z_far, visited, tag, unknown_blinds):
    nx, ny, nz = cls.shape
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    # unknown voxels inside the frustum, with their distances
    idx = np.empty(cls.size, np.int64)
    dist = np.empty(cls.size)
    n = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if cls[i, j, k] != UNKNOWN:
                    continue
                px = bmin[0] + (i + 0.5) * res - o[0]
                py = bmin[1] + (j + 0.5) * res - o[1]
                pz = bmin[2] + (k + 0.5) * res - o[2]
                zc = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
                if zc < z_near or zc > z_far:
                    continue
                xc = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
                yc = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
                u = fx * xc / zc + cx
                v = fy * yc / zc + cy
                if u < -0.5 or u > w - 0.5 or v < -0.5 or v > h - 0.5:
                    continue
                idx[n] = (i * ny + j) * nz + k
                dist[n] = math.sqrt(px * px + py * py + pz * pz)
                n += 1
    order = np.argsort(-dist[:n])
    n_first = 0
    n_post = 0
    rays = 0
    for q in range(n):
        flat = idx[order[q]]
        if visited[flat] == tag:
            continue
        k0 = flat % nz
        j0 = (flat // nz) % ny
        i0 = flat // (ny * nz)
        dx = bmin[0] + (i0 + 0.5) * res - o[0]
        dy = bmin[1] + (j0 + 0.5) * res - o[1]
        dz = bmin[2] + (k0 + 0.5) * res - o[2]
        L = math.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx / L, dy / L, dz / L
        dcz = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz  # depth per unit length
        t_near = z_near / dcz
        # from the camera up to the maximum range; blinded within the minimum range?
        t0, t1 = clip_ray(o[0], o[1], o[2], dx, dy, dz, 0.0, z_far / dcz, bmin[0], bmin[1], bmin[2], ex, ey, ez)
        occluded = blinded_within(cls, bmin, res, o[0], o[1], o[2], dx, dy, dz, t0, t_near, t1, unknown_blinds)
        t0 = max(t0, t_near)
        if t0 > t1:
            visited[flat] = tag
            continue
        rays += 1
        i, si, ti, di = axis_start(o[0], dx, t0, bmin[0], res, nx)
        j, sj, tj, dj = axis_start(o[1], dy, t0, bmin[1], res, ny)
        k, sk, tk, dk = axis_start(o[2], dz, t0, bmin[2], res, nz)
        seen_unknown = False
        while True:
            f = (i * ny + j) * nz + k
            c = cls[i, j, k]
            if occluded:
                visited[f] = tag
            elif c == OCCUPIED:
                occluded = True
            elif c == UNKNOWN:
                if visited[f] != tag:
                    visited[f] = tag
                    if seen_unknown:
                        n_post += 1
                    else:
                        n_first += 1
                seen_unknown = True
            if min(ti, tj, tk) >= t1:
                break
            i, j, k, ti, tj, tk, inside = dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
                                                   0, nx - 1, 0, ny - 1, 0, nz - 1)
            if not inside:
                break
        visited[flat] = tag  # the target itself is intercepted (occluded or counted)
    return n_first, n_post, rays


@nb.njit(cache=True, parallel=True)
def voxel_sorted_views(cls, bmin, res, cam_pos, cam_rot, fx, fy, cx, cy, w, h, z_near, z_far, n_chunks,
                       near_unknown_blinds=False):
    """(N, 3) per view: n_first, n_posterior, rays cast. cls: int8 classes (voxel.classes_grid);
    cam_rot columns are the camera axes (+z forward). near_unknown_blinds False: only occupied
    voxels blind a ray within the minimum range."""
    n = cam_pos.shape[0]
    out = np.zeros((n, 3))
    visited = np.zeros((n_chunks, cls.size), np.int32)
    per = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        for v in range(lo, hi):
            a, b, r = _voxel_sorted_one(cls, bmin, res, cam_pos[v], cam_rot[v], fx, fy, cx, cy, w, h,
                                        z_near, z_far, visited[c], v + 1, near_unknown_blinds)
            out[v, 0] = a
            out[v, 1] = b
            out[v, 2] = r
    return out


def unknown_volumes(unknown: np.ndarray, res: float) -> tuple[float, float]:
    """(V_outer, V_inner): volume of the unknown voxels with at least one face exposed (a face
    neighbour that is not unknown, or the map's edge), and of those with none."""
    pad = np.pad(unknown, 1, constant_values=False)
    inner = unknown.copy()
    for a in range(3):
        for s in (-1, 1):
            inner &= np.roll(pad, s, axis=a)[1:-1, 1:-1, 1:-1]
    v = res ** 3
    return float((unknown & ~inner).sum() * v), float(inner.sum() * v)


def score(n_first, n_posterior, res: float, v_outer: float, v_inner: float, w: float = 0.5):
    """score = (n_first + w n_posterior) res^3 / (V_outer + w V_inner) (§3.6)."""
    den = v_outer + w * v_inner
    return (np.asarray(n_first) + w * np.asarray(n_posterior)) * res ** 3 / max(den, 1e-18)


def unknown_clusters(unknown: np.ndarray, centers: np.ndarray, link: float = 2.05):
    """Clusters of unknown voxels linked to a neighbour at most `link` voxels away (Santos et al. 2020:
    just over twice the resolution), measured per axis (Chebyshev distance, so diagonal
    neighbours up to 2 voxels per axis link too). Returns (labels (same shape, 0 = none),
    centroids (n, 3) in metres, sizes (n,))."""
    # voxels at most 2 apart per axis share a voxel of their one-voxel dilations: dilate,
    # label the dilated set with 26-connectivity, keep the labels of the unknown voxels
    r = int(math.floor(link / 2.0))
    grown = ndimage.binary_dilation(unknown, structure=np.ones((3, 3, 3), bool), iterations=max(r, 0)) \
        if r > 0 else unknown
    lab, n = ndimage.label(grown, structure=np.ones((3, 3, 3), bool))
    lab = np.where(unknown, lab, 0)
    ids = np.unique(lab[lab > 0])
    remap = np.zeros(lab.max() + 1, np.int64)
    remap[ids] = np.arange(1, len(ids) + 1)
    lab = remap[lab]
    pts = centers[lab > 0]
    lbl = lab[lab > 0]
    sizes = np.bincount(lbl, minlength=len(ids) + 1)[1:]
    cent = np.stack([np.bincount(lbl, weights=pts[:, a], minlength=len(ids) + 1)[1:] for a in range(3)], axis=1)
    return lab, cent / np.maximum(sizes, 1)[:, None], sizes
