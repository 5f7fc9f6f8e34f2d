"""Numba kernels of the probabilistic occupancy map: scan integration and view evaluation,
both by exact 3D DDA (Amanatides & Woo) over a dense log-odds grid.

Grid convention: voxel (i, j, k) spans [bmin + (i, j, k) * res, bmin + (i+1, j+1, k+1) * res).
Log-odds classes: free l < l_free, occupied l > l_occ, unknown otherwise.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# columns of the per-view metrics returned by evaluate_views
M_UN_O = 0  #: distinct visible unknown voxels (first unknown voxel of each ray) = VUV
M_OC_O = 1  #: distinct occupied voxels hit with at most `max_unknown_before_hit` unknown voxels before them
M_FIG = 2  #: sum of entropies of distinct unknown voxels touched (each once per view)
M_SIG = 3  #: sum of entropies of unknown voxels touched, per ray (Kriegel)
M_RSV = 4  #: rays that hit an occupied voxel whose next voxel along the ray is unknown
M_RAYS = 5  #: rays that enter the map
M_OC_RAYS = 6  #: rays whose first non-free voxel is occupied (the scan lands on known surface)
M_UN_RAYS = 7  #: rays whose first non-free voxel is unknown
M_N_POSTERIOR = 8  #: seed 001 n_posterior: distinct unknown voxels touched only behind another unknown voxel
N_METRICS = 9
M_VUV = M_UN_O  #: seed 003 VUV
M_N_FIRST = M_UN_O  #: seed 001 n_first


@nb.njit(cache=True, inline="always")
def _clip(o0, o1, o2, d0, d1, d2, tmin, tmax, b0, b1, b2, e0, e1, e2):
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
def _axis_start_in(o, d, t0, lo, res, i_min, i_max):
    """_axis_start with the index clamped to [i_min, i_max] (a coarse cell's children)."""
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
def _axis_start(o, d, t0, lo, res, n):
    """DDA set-up on one axis at parameter t0: (index, step, t of next boundary, t per voxel)."""
    return _axis_start_in(o, d, t0, lo, res, 0, n - 1)


@nb.njit(cache=True, inline="always")
def _dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk, i_lo, i_hi, j_lo, j_hi, k_lo, k_hi):
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
        t0, t1 = _clip(ox, oy, oz, dx, dy, dz, 0.0, L, bmin[0], bmin[1], bmin[2], ex, ey, ez)
        if t0 > t1:
            continue
        i, si, ti, di = _axis_start(ox, dx, t0, bmin[0], res, nx)
        j, sj, tj, dj = _axis_start(oy, dy, t0, bmin[1], res, ny)
        k, sk, tk, dk = _axis_start(oz, dz, t0, bmin[2], res, nz)
        end_inside = t1 >= L - 1e-9  # the point itself lies in the grid
        while True:
            tnext = min(ti, tj, tk)
            last = tnext >= t1
            if last and end_inside:
                if is_hit[r]:
                    marks[i, j, k] = 2
                # a non-object return (e.g. the table) neither clears nor fills its voxel
                break
            if marks[i, j, k] == 0:
                marks[i, j, k] = 1
            if last:
                break
            i, j, k, ti, tj, tk, inside = _dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
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
        x = flat[v] + (l_hit if m == 2 else l_miss)
        if x < l_min:
            x = l_min
        elif x > l_max:
            x = l_max
        flat[v] = x
        n += 1
    return n


@nb.njit(cache=True, inline="always")
def _entropy_from_logodds(l):
    p = 1.0 / (1.0 + math.exp(-l))
    if p <= 0.0 or p >= 1.0:
        return 0.0
    return -p * math.log(p) - (1.0 - p) * math.log(1.0 - p)


@nb.njit(cache=True)
def entropy_grid(logodds):
    """Entropy H(p) of every voxel (float32, same shape)."""
    out = np.empty(logodds.shape, np.float32)
    fl = logodds.reshape(-1)
    fo = out.reshape(-1)
    for v in range(fl.shape[0]):
        fo[v] = _entropy_from_logodds(fl[v])
    return out


@nb.njit(cache=True)
def classes_grid(logodds, l_free, l_occ):
    """int8 classes: 0 free, 1 unknown, 2 occupied (the kernels' view of the map)."""
    out = np.empty(logodds.shape, np.int8)
    fl = logodds.reshape(-1)
    fo = out.reshape(-1)
    for v in range(fl.shape[0]):
        lv = fl[v]
        fo[v] = 2 if lv > l_occ else (1 if lv >= l_free else 0)
    return out


# packed per-voxel marks of one view: (view id << 2) | bits
_FIRST = 1  #: unknown voxel seen first on some ray (or occupied voxel counted in oc_o)
_POST = 2  #: unknown voxel seen behind another unknown voxel


@nb.njit(cache=True, inline="always")
def _fine_segment(cls, H, bmin, res, ox, oy, oz, dx, dy, dz, t_in, t_out, i_lo, i_hi, j_lo, j_hi,
                  k_lo, k_hi, max_unknown_before_hit, vid, mark, out, n_unknown):
    """Exact DDA over the voxels of the ray segment [t_in, t_out] within the index box
    [i_lo..i_hi] x [j_lo..j_hi] x [k_lo..k_hi], adding to the view's metrics `out`.
    `n_unknown`: unknown voxels met earlier on this ray. Returns (n_unknown, hit occupied)."""
    nx, ny, nz = cls.shape
    i, si, ti, di = _axis_start_in(ox, dx, t_in, bmin[0], res, i_lo, i_hi)
    j, sj, tj, dj = _axis_start_in(oy, dy, t_in, bmin[1], res, j_lo, j_hi)
    k, sk, tk, dk = _axis_start_in(oz, dz, t_in, bmin[2], res, k_lo, k_hi)
    tag = vid << 2
    while True:
        c = cls[i, j, k]
        if c == 2:  # occupied
            if n_unknown <= max_unknown_before_hit:
                out[M_OC_RAYS] += 1
                flat = (i * ny + j) * nz + k
                if mark[flat] >> 2 != vid:
                    mark[flat] = tag | _FIRST
                    out[M_OC_O] += 1
            # rear side voxel: the next voxel along the ray
            i2, j2, k2 = i, j, k
            if ti <= tj and ti <= tk:
                i2 += si
            elif tj <= tk:
                j2 += sj
            else:
                k2 += sk
            if 0 <= i2 < nx and 0 <= j2 < ny and 0 <= k2 < nz and cls[i2, j2, k2] == 1:
                out[M_RSV] += 1
            return n_unknown, True
        if c == 1:  # unknown
            n_unknown += 1
            if n_unknown == max_unknown_before_hit + 1:
                out[M_UN_RAYS] += 1
            h = H[i, j, k]
            out[M_SIG] += h
            flat = (i * ny + j) * nz + k
            m = mark[flat]
            if m >> 2 != vid:
                m = tag
            if m & 3 == 0:
                out[M_FIG] += h
            if n_unknown == 1:
                if m & _FIRST == 0:
                    if m & _POST:  # was posterior on an earlier ray: now first
                        out[M_N_POSTERIOR] -= 1
                    m |= _FIRST
                    out[M_UN_O] += 1
            elif m & 3 == 0:
                m |= _POST
                out[M_N_POSTERIOR] += 1
            mark[flat] = m
        if min(ti, tj, tk) >= t_out:
            return n_unknown, False
        i, j, k, ti, tj, tk, inside = _dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
                                                i_lo, i_hi, j_lo, j_hi, k_lo, k_hi)
        if not inside:
            return n_unknown, False


@nb.njit(cache=True, inline="always")
def _world_ray(R, dcam, tn, tf, ox, oy, oz, bmin, ex, ey, ez):
    """Ray direction in the world (R @ dcam) and its range [tn, tf] clipped to the grid."""
    dx = R[0, 0] * dcam[0] + R[0, 1] * dcam[1] + R[0, 2] * dcam[2]
    dy = R[1, 0] * dcam[0] + R[1, 1] * dcam[1] + R[1, 2] * dcam[2]
    dz = R[2, 0] * dcam[0] + R[2, 1] * dcam[1] + R[2, 2] * dcam[2]
    t0, t1 = _clip(ox, oy, oz, dx, dy, dz, tn, tf, bmin[0], bmin[1], bmin[2], ex, ey, ez)
    return dx, dy, dz, t0, t1


@nb.njit(cache=True)
def _eval_one_view(cls, H, bmin, res, o, R, dirs_cam, t_near, t_far, max_unknown_before_hit, vid, mark, out):
    nx, ny, nz = cls.shape
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    ox, oy, oz = o[0], o[1], o[2]
    for r in range(dirs_cam.shape[0]):
        dx, dy, dz, t0, t1 = _world_ray(R, dirs_cam[r], t_near[r], t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        out[M_RAYS] += 1
        _fine_segment(cls, H, bmin, res, ox, oy, oz, dx, dy, dz, t0, t1, 0, nx - 1, 0, ny - 1, 0, nz - 1,
                      max_unknown_before_hit, vid, mark, out, 0)


@nb.njit(cache=True, parallel=True)
def evaluate_views(logodds, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                   n_chunks, max_unknown_before_hit=2):
    """Per-view metrics (N, N_METRICS) for camera poses (cam_pos (N, 3), cam_rot (N, 3, 3),
    columns = camera axes in the world, +z forward) and unit ray directions in the camera
    frame `dirs_cam` (R, 3) whose ranges are [t_near[r], t_far[r]] along the ray. Rays pass
    through unknown voxels and stop at the first occupied one; an occupied voxel counts as
    overlap (oc_o) when at most `max_unknown_before_hit` unknown voxels precede it on the ray
    (a surface's thickness: grazing rays cross uncleared voxels just in front of it).
    Views are split into `n_chunks` chunks evaluated in parallel."""
    n = cam_pos.shape[0]
    H = entropy_grid(logodds)
    cls = classes_grid(logodds, l_free, l_occ)
    out = np.zeros((n, N_METRICS))
    mark = np.zeros((n_chunks, logodds.size), np.int32)
    per = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        for v in range(lo, hi):
            _eval_one_view(cls, H, bmin, res, cam_pos[v], cam_rot[v], dirs_cam, t_near, t_far,
                           max_unknown_before_hit, v + 1, mark[c], out[v])
    return out


# --------------------------------------------------------------------------------------
# Hierarchical ray tracing (seed 000 §5.4)
# --------------------------------------------------------------------------------------

C_UNKNOWN, C_OCCUPIED, C_FREE = 1, 2, 4  # bits of a coarse cell's summary


@nb.njit(cache=True)
def coarse_summary(logodds, H, a, l_free, l_occ):
    """Level-a pyramid cell summaries: class bits (C_*) of the 2^a x 2^a x 2^a children, the
    entropy sum and the count of their unknown children. Cells past the grid's edge hold
    only the children that exist."""
    s = 1 << a
    nx, ny, nz = logodds.shape
    cx, cy, cz = (nx + s - 1) // s, (ny + s - 1) // s, (nz + s - 1) // s
    bits = np.zeros((cx, cy, cz), np.uint8)
    hsum = np.zeros((cx, cy, cz), np.float64)
    nunk = np.zeros((cx, cy, cz), np.int32)
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                lv = logodds[i, j, k]
                ci, cj, ck = i // s, j // s, k // s
                if lv > l_occ:
                    bits[ci, cj, ck] |= C_OCCUPIED
                elif lv >= l_free:
                    bits[ci, cj, ck] |= C_UNKNOWN
                    hsum[ci, cj, ck] += H[i, j, k]
                    nunk[ci, cj, ck] += 1
                else:
                    bits[ci, cj, ck] |= C_FREE
    return bits, hsum, nunk


@nb.njit(cache=True)
def _eval_one_view_hrt(cls, H, bits, hmean, nunk, a, bmin, res, o, R, dirs_cam, t_near, t_far,
                       max_unknown_before_hit, vid, mark, st_cfig, acc, out):
    """Two-level hierarchical traversal. Exact in refined cells (those with an occupied voxel or
    mixed classes); all-free cells are skipped; all-unknown cells are accounted at the coarse
    level: the entry voxel is the ray's first unknown voxel (exact); SIG adds the number of
    voxels the segment crosses times the cell's mean entropy; FIG and n_posterior add the
    voxels crossed, accumulated over the view's rays and capped at the cell's unknown count
    (an estimate of the distinct voxels touched)."""
    nx, ny, nz = cls.shape
    cnx, cny, cnz = bits.shape
    s = 1 << a
    cres = res * s
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    ox, oy, oz = o[0], o[1], o[2]
    for r in range(dirs_cam.shape[0]):
        dx, dy, dz, t0, t1 = _world_ray(R, dirs_cam[r], t_near[r], t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        out[M_RAYS] += 1
        crossing = (abs(dx) + abs(dy) + abs(dz)) / res  # voxel boundaries crossed per metre
        ci, sci, tci, dci = _axis_start(ox, dx, t0, bmin[0], cres, cnx)
        cj, scj, tcj, dcj = _axis_start(oy, dy, t0, bmin[1], cres, cny)
        ck, sck, tck, dck = _axis_start(oz, dz, t0, bmin[2], cres, cnz)
        tc_in = t0
        n_unknown = 0
        stop = False
        while not stop:
            tc_out = min(tci, tcj, tck, t1)
            b = bits[ci, cj, ck]
            if b == C_UNKNOWN:
                # homogeneous unknown cell
                if tc_out > tc_in:
                    # voxels the segment crosses: one per boundary crossed, plus the voxel
                    # the ray starts in when it starts inside this cell
                    nvox_here = (tc_out - tc_in) * crossing + (1.0 if tc_in == t0 else 0.0)
                    mean_h = hmean[ci, cj, ck]
                    out[M_SIG] += nvox_here * mean_h
                    cflat = (ci * cny + cj) * cnz + ck
                    if st_cfig[cflat] != vid:
                        st_cfig[cflat] = vid
                        acc[cflat] = 0.0
                    # distinct voxels of the cell touched in this view: the voxels the rays
                    # cross, accumulated over rays, capped at the cell's unknown voxels
                    add = min(nvox_here, nunk[ci, cj, ck] - acc[cflat])
                    if add > 0.0:
                        acc[cflat] += add
                        out[M_FIG] += add * mean_h
                        out[M_N_POSTERIOR] += add
                    if n_unknown == 0:  # the entry voxel is the ray's first unknown voxel
                        tm = tc_in + 1e-9
                        fi = min(max(int(math.floor((ox + tm * dx - bmin[0]) / res)), 0), nx - 1)
                        fj = min(max(int(math.floor((oy + tm * dy - bmin[1]) / res)), 0), ny - 1)
                        fk = min(max(int(math.floor((oz + tm * dz - bmin[2]) / res)), 0), nz - 1)
                        flat = (fi * ny + fj) * nz + fk
                        m = mark[flat]
                        if m >> 2 != vid:
                            m = vid << 2
                        if m & _FIRST == 0:
                            mark[flat] = m | _FIRST
                            out[M_UN_O] += 1
                            out[M_N_POSTERIOR] -= 1
                    prev = n_unknown
                    n_unknown += int(nvox_here + 0.5)
                    if prev <= max_unknown_before_hit < n_unknown:
                        out[M_UN_RAYS] += 1
            elif b != C_FREE and b != 0:
                # refine: exact fine DDA inside this cell
                n_unknown, stop = _fine_segment(
                    cls, H, bmin, res, ox, oy, oz, dx, dy, dz, tc_in, tc_out,
                    ci * s, min(ci * s + s, nx) - 1, cj * s, min(cj * s + s, ny) - 1, ck * s, min(ck * s + s, nz) - 1,
                    max_unknown_before_hit, vid, mark, out, n_unknown)
            if stop or tc_out >= t1:
                break
            tc_in = tc_out
            ci, cj, ck, tci, tcj, tck, inside = _dda_step(ci, cj, ck, sci, scj, sck, tci, tcj, tck, dci, dcj, dck,
                                                          0, cnx - 1, 0, cny - 1, 0, cnz - 1)
            if not inside:
                break


@nb.njit(cache=True, parallel=True)
def evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                       n_chunks, max_unknown_before_hit=2):
    """evaluate_views with hierarchical ray tracing at resolution parameter a >= 1 (voxel size
    2^a x res at the coarse level)."""
    n = cam_pos.shape[0]
    H = entropy_grid(logodds)
    bits, hsum, nunk = coarse_summary(logodds, H, a, l_free, l_occ)
    hmean = hsum / np.maximum(nunk, 1)
    cls = classes_grid(logodds, l_free, l_occ)
    ncell = bits.size
    out = np.zeros((n, N_METRICS))
    mark = np.zeros((n_chunks, logodds.size), np.int32)
    st_cfig = np.zeros((n_chunks, ncell), np.int32)
    acc = np.zeros((n_chunks, ncell), np.float64)
    per = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        for v in range(lo, hi):
            _eval_one_view_hrt(cls, H, bits, hmean, nunk, a, bmin, res, cam_pos[v], cam_rot[v], dirs_cam,
                               t_near, t_far, max_unknown_before_hit, v + 1, mark[c], st_cfig[c], acc[c], out[v])
    return out
