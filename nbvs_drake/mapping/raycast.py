"""Ray casting primitives over the dense voxel grid, and scan integration.

Grid convention: voxel (i, j, k) spans [bmin + (i, j, k) * res, bmin + (i+1, j+1, k+1) * res).
Rays are clipped to the grid (slab test), then walked voxel by voxel by exact 3D DDA
(Amanatides & Woo): `axis_start` sets up one axis, `dda_step` moves to the next voxel.
`blinded_within` is the sensor's minimum range as the view evaluation models it.
`integrate_scan` applies OctoMap's sensor model along the rays of one scan.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .voxel import OCCUPIED, UNKNOWN

_MISS = 1  #: integrate_scan's mark of a voxel a ray crossed
_HIT = 2  #: integrate_scan's mark of the voxel of a hit point (wins over misses)


@nb.njit(cache=True, inline="always")
def clip_ray(o0, o1, o2, d0, d1, d2, tmin, tmax, b0, b1, b2, e0, e1, e2):
    """Slab test: clips [tmin, tmax] of the ray o + t d to the box [b, e]. Returns (t0, t1);
    t0 > t1 when the ray misses."""
    t0, t1 = tmin, tmax
    for a in range(3):
        if a == 0:
            o, d, lo, hi = o0, d0, b0, e0
        elif a == 1:
            o, d, lo, hi = o1, d1, b1, e1
        else:
            o, d, lo, hi = o2, d2, b2, e2
        if abs(d) < 1e-12:
            if o < lo or o > hi:
                return 1.0, 0.0
        else:
            ta = (lo - o) / d
            tb = (hi - o) / d
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
    return t0, t1


@nb.njit(cache=True, inline="always")
def axis_start_in(o, d, t0, lo, res, i_min, i_max):
    """axis_start with the index clamped to [i_min, i_max] (a coarse cell's children)."""
    p = o + t0 * d
    i = int(math.floor((p - lo) / res))
    if i < i_min:
        i = i_min
    elif i > i_max:
        i = i_max
    if d > 0:
        return i, 1, (lo + (i + 1) * res - o) / d, res / d
    if d < 0:
        return i, -1, (lo + i * res - o) / d, -res / d
    return i, 0, np.inf, np.inf


@nb.njit(cache=True, inline="always")
def axis_start(o, d, t0, lo, res, n):
    """DDA set-up on one axis at parameter t0: (index, step, t of next boundary, t per voxel)."""
    return axis_start_in(o, d, t0, lo, res, 0, n - 1)


@nb.njit(cache=True, inline="always")
def dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk, i_lo, i_hi, j_lo, j_hi, k_lo, k_hi):
    """Amanatides & Woo: moves to the next voxel along the ray (the axis whose boundary comes
    first). Returns (i, j, k, ti, tj, tk, still inside [lo..hi] on every axis)."""
    if ti <= tj and ti <= tk:
        i += si
        ti += di
        return i, j, k, ti, tj, tk, i_lo <= i <= i_hi
    if tj <= tk:
        j += sj
        tj += dj
        return i, j, k, ti, tj, tk, j_lo <= j <= j_hi
    k += sk
    tk += dk
    return i, j, k, ti, tj, tk, k_lo <= k <= k_hi


@nb.njit(cache=True, inline="always")
def blinded_within(cls, bmin, res, ox, oy, oz, dx, dy, dz, t0, t_near, t1, unknown_blinds=True):
    """The sensor's minimum range: whether the ray o + t d, clipped to the grid as [t0, t1]
    (t0 >= 0: from the camera), meets a voxel that is not free among those it enters before
    t_near (the voxel it starts in included). A surface nearer than the minimum range returns
    nothing (DepthRange's z_near) and hides what lies behind it: an occupied voxel entered
    before t_near blinds the ray, and so, conservatively, does an unknown one (it may hold
    such a surface; `unknown_blinds` False: only occupied voxels blind). Free voxels are passed
    through. `cls`: voxel classes (voxel.classes_grid)."""
    if t0 >= t_near or t0 > t1:
        return False
    nx, ny, nz = cls.shape
    i, si, ti, di = axis_start(ox, dx, t0, bmin[0], res, nx)
    j, sj, tj, dj = axis_start(oy, dy, t0, bmin[1], res, ny)
    k, sk, tk, dk = axis_start(oz, dz, t0, bmin[2], res, nz)
    while True:
        c = cls[i, j, k]
        if c == OCCUPIED or (unknown_blinds and c == UNKNOWN):
            return True
        tnext = min(ti, tj, tk)  # where the ray enters the next voxel
        if tnext >= t_near or tnext >= t1:
            return False
        i, j, k, ti, tj, tk, inside = dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
                                               0, nx - 1, 0, ny - 1, 0, nz - 1)
        if not inside:
            return False


@nb.njit(cache=True, inline="always")
def world_ray(R, dcam, tn, tf, ox, oy, oz, bmin, ex, ey, ez):
    """Ray direction in the world (R @ dcam) and its range [tn, tf] clipped to the grid."""
    dx = R[0, 0] * dcam[0] + R[0, 1] * dcam[1] + R[0, 2] * dcam[2]
    dy = R[1, 0] * dcam[0] + R[1, 1] * dcam[1] + R[1, 2] * dcam[2]
    dz = R[2, 0] * dcam[0] + R[2, 1] * dcam[1] + R[2, 2] * dcam[2]
    t0, t1 = clip_ray(ox, oy, oz, dx, dy, dz, tn, tf, bmin[0], bmin[1], bmin[2], ex, ey, ez)
    return dx, dy, dz, t0, t1


@nb.njit(cache=True)
def integrate_scan(logodds, bmin, res, origin, points, is_hit, l_hit, l_miss, l_min, l_max):
    """Integrates one scan in place (OctoMap's sensor model): every voxel a ray crosses from
    `origin` to its point is a miss, the voxel of a hit point (is_hit) a hit. Each voxel is
    updated once per scan and hits win over misses. Rays are clipped to the grid first.
    Returns the number of voxels updated."""
    nx, ny, nz = logodds.shape
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    ox, oy, oz = origin[0], origin[1], origin[2]
    marks = np.zeros(logodds.shape, np.int8)
    for r in range(points.shape[0]):
        dx, dy, dz = points[r, 0] - ox, points[r, 1] - oy, points[r, 2] - oz
        L = math.sqrt(dx * dx + dy * dy + dz * dz)
        if L < 1e-9:
            continue
        dx, dy, dz = dx / L, dy / L, dz / L
        t0, t1 = clip_ray(ox, oy, oz, dx, dy, dz, 0.0, L, bmin[0], bmin[1], bmin[2], ex, ey, ez)
        if t0 > t1:
            continue
        i, si, ti, di = axis_start(ox, dx, t0, bmin[0], res, nx)
        j, sj, tj, dj = axis_start(oy, dy, t0, bmin[1], res, ny)
        k, sk, tk, dk = axis_start(oz, dz, t0, bmin[2], res, nz)
        end_inside = t1 >= L - 1e-9  # the point itself lies in the grid
        while True:
            tnext = min(ti, tj, tk)
            last = tnext >= t1
            if last and end_inside:
                if is_hit[r]:
                    marks[i, j, k] = _HIT
                # a non-object return (e.g. the table) neither clears nor fills its voxel
                break
            if marks[i, j, k] == 0:
                marks[i, j, k] = _MISS
            if last:
                break
            i, j, k, ti, tj, tk, inside = dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
                                                   0, nx - 1, 0, ny - 1, 0, nz - 1)
            if not inside:
                break
    n = 0
    flat = logodds.reshape(-1)
    fm = marks.reshape(-1)
    for v in range(flat.shape[0]):
        m = fm[v]
        if m == 0:
            continue
        x = flat[v] + (l_hit if m == _HIT else l_miss)
        if x < l_min:
            x = l_min
        elif x > l_max:
            x = l_max
        flat[v] = x
        n += 1
    return n
