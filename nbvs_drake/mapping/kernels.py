"""Numba kernels of the probabilistic occupancy map: scan integration and view evaluation,
both by exact 3D DDA (Amanatides & Woo) over a dense log-odds grid, and the approximate
hierarchical view evaluation (evaluate_views_hrt, seed 000 §5.4).

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
def _rear_is_unknown(cls, i, j, k, si, sj, sk, ti, tj, tk):
    """RSV: whether the voxel right behind the hit voxel (i, j, k) along the ray (the next
    voxel the DDA would enter) is unknown."""
    if ti <= tj and ti <= tk:
        i += si
    elif tj <= tk:
        j += sj
    else:
        k += sk
    nx, ny, nz = cls.shape
    return 0 <= i < nx and 0 <= j < ny and 0 <= k < nz and cls[i, j, k] == 1


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
                  k_lo, k_hi, max_unknown_before_hit, vid, mark, out, n_unknown, w, est, fac):
    """Exact DDA over the voxels of the ray segment [t_in, t_out] within the index box
    [i_lo..i_hi] x [j_lo..j_hi] x [k_lo..k_hi], adding to the view's metrics `out` (per-ray
    metrics weighted by w, the rays the traced ray stands for; distinct-voxel metrics by voxel;
    `est`: leaves FIG and n_posterior but the first voxel's correction to the caller; `fac`:
    the distinct voxels a newly seen first-unknown or occupied voxel stands for).
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
                out[M_OC_RAYS] += w
                flat = (i * ny + j) * nz + k
                if mark[flat] >> 2 != vid:
                    mark[flat] = tag | _FIRST
                    out[M_OC_O] += fac
            if _rear_is_unknown(cls, i, j, k, si, sj, sk, ti, tj, tk):  # rear side voxel
                out[M_RSV] += w
            return n_unknown, True
        if c == 1:  # unknown
            n_unknown += 1
            if n_unknown == max_unknown_before_hit + 1:
                out[M_UN_RAYS] += w
            h = H[i, j, k]
            out[M_SIG] += w * h
            flat = (i * ny + j) * nz + k
            m = mark[flat]
            if m >> 2 != vid:
                m = tag
            if est:  # the caller estimates FIG and n_posterior; here only the first voxel
                if n_unknown == 1 and m & _FIRST == 0:
                    mark[flat] = m | _FIRST
                    out[M_UN_O] += fac
                    out[M_N_POSTERIOR] -= fac
            else:
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


# --------------------------------------------------------------------------------------
# Cell bitmasks: the grid split into 4 x 4 x 4 cells, one uint64 bit per voxel
# (bit ((i & 3) * 4 + (j & 3)) * 4 + (k & 3)). The traversal keeps the distinct voxel sets of a
# view (touched unknown T, first-unknown F, counted occupied OH) as per-cell bitmasks held in
# registers while a ray is inside a cell, so a step writes no per-voxel marks.
# --------------------------------------------------------------------------------------

_U64_1 = np.uint64(1)


@nb.njit(cache=True, inline="always")
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(cache=True)
def cell_masks(cls, H):
    """Per 4x4x4 cell: unknown-voxel bitmask U, occupied-voxel bitmask O (voxels past the grid's
    edge are neither) and the entropy shared by all its unknown voxels (-1 when they differ)."""
    nx, ny, nz = cls.shape
    cx, cy, cz = (nx + 3) >> 2, (ny + 3) >> 2, (nz + 3) >> 2
    U = np.zeros(cx * cy * cz, np.uint64)
    O = np.zeros(cx * cy * cz, np.uint64)
    hc = np.full(cx * cy * cz, -2.0)
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                c = cls[i, j, k]
                if c == 0:
                    continue
                cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
                bit = _U64_1 << np.uint64(((i & 3) * 4 + (j & 3)) * 4 + (k & 3))
                if c == 2:
                    O[cf] |= bit
                else:
                    U[cf] |= bit
                    h = np.float64(H[i, j, k])
                    if hc[cf] == -2.0:
                        hc[cf] = h
                    elif hc[cf] != h:
                        hc[cf] = -1.0
    return U, O, hc


@nb.njit(cache=True, inline="always")
def _flush(cf, Tm, Fm, OHm, vid, ctag, cT, cF, cOH, touched, nt):
    """Merges a ray's register masks of cell cf into the view's sets; returns the touched count."""
    if ctag[cf] != vid:
        ctag[cf] = vid
        cT[cf] = Tm
        cF[cf] = Fm
        cOH[cf] = OHm
        touched[nt] = cf
        return nt + 1
    cT[cf] |= Tm
    cF[cf] |= Fm
    cOH[cf] |= OHm
    return nt


@nb.njit(cache=True, inline="always")
def _bits_entropy(H, cf, cy, cz, m):
    """Sum of the entropies of the voxels of cell cf whose bits are set in m."""
    ci = cf // (cy * cz)
    cj = (cf // cz) % cy
    ck = cf % cz
    s = 0.0
    for b in range(64):
        if (m >> np.uint64(b)) & _U64_1:
            s += H[ci * 4 + (b >> 4), cj * 4 + ((b >> 2) & 3), ck * 4 + (b & 3)]
    return s


@nb.njit(cache=True, inline="always")
def _view_sets_to_metrics(H, hc, cy, cz, cT, cF, cOH, touched, nt, out):
    """FIG, un_o (= VUV = n_first), n_posterior and oc_o from the view's distinct voxel sets."""
    fig = 0.0
    n_first = 0
    n_post = 0
    n_occ = 0
    for q in range(nt):
        cf = touched[q]
        T, F = cT[cf], cF[cf]
        n_first += _popcount(F)
        n_post += _popcount(T & ~F)
        n_occ += _popcount(cOH[cf])
        h = hc[cf]
        if h >= 0.0:
            fig += h * _popcount(T)
        elif T != 0:
            fig += _bits_entropy(H, cf, cy, cz, T)
    out[M_FIG] += fig
    out[M_UN_O] += n_first
    out[M_N_POSTERIOR] += n_post
    out[M_OC_O] += n_occ


_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@nb.njit(cache=True, inline="always")
def _cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk, bi, bj, bk, wi, wj, wk, t1):
    """One DDA step (Amanatides & Woo, ties: i, then j). Returns the new state and a status:
    0 still in the cell, 1 entered a new 4x4x4 cell, 2 the ray ends (next boundary >= t1)."""
    if ti <= tj and ti <= tk:
        if ti >= t1:
            return i, j, k, ti, tj, tk, b, 2
        i += si
        return i, j, k, ti + di, tj, tk, b + bi, 1 if (i & 3) == wi else 0
    if tj <= tk:
        if tj >= t1:
            return i, j, k, ti, tj, tk, b, 2
        j += sj
        return i, j, k, ti, tj + dj, tk, b + bj, 1 if (j & 3) == wj else 0
    if tk >= t1:
        return i, j, k, ti, tj, tk, b, 2
    k += sk
    return i, j, k, ti, tj, tk + dk, b + bk, 1 if (k & 3) == wk else 0


@nb.njit(cache=True, inline="always")
def _axis_skip(i, t, si, dt, t_exit):
    """Advances one axis of the DDA over its boundaries before t_exit within the 4x4x4 cell."""
    if si == 0 or t >= t_exit:
        return i, t
    n = int(math.ceil((t_exit - t) / dt))
    n = min(n, (3 - (i & 3)) if si > 0 else (i & 3))
    return i + si * n, t + n * dt


@nb.njit(cache=True, inline="always")
def _skip_cell(i, j, k, ti, tj, tk, si, sj, sk, di, dj, dk, t1):
    """Moves the DDA across the rest of its 4x4x4 cell at once (the voxels between need no
    visit: the cell is all free). Returns the state in the next cell and status 1, or status 2
    when the ray ends inside the cell."""
    xi = ti + ((3 - (i & 3)) if si > 0 else (i & 3)) * di if si != 0 else np.inf
    xj = tj + ((3 - (j & 3)) if sj > 0 else (j & 3)) * dj if sj != 0 else np.inf
    xk = tk + ((3 - (k & 3)) if sk > 0 else (k & 3)) * dk if sk != 0 else np.inf
    if xi <= xj and xi <= xk:
        if xi >= t1:
            return i, j, k, ti, tj, tk, 2
        j, tj = _axis_skip(j, tj, sj, dj, xi)
        k, tk = _axis_skip(k, tk, sk, dk, xi)
        n = ((3 - (i & 3)) if si > 0 else (i & 3)) + 1
        return i + si * n, j, k, xi + di, tj, tk, 1
    if xj <= xk:
        if xj >= t1:
            return i, j, k, ti, tj, tk, 2
        i, ti = _axis_skip(i, ti, si, di, xj)
        k, tk = _axis_skip(k, tk, sk, dk, xj)
        n = ((3 - (j & 3)) if sj > 0 else (j & 3)) + 1
        return i, j + sj * n, k, ti, xj + dj, tk, 1
    if xk >= t1:
        return i, j, k, ti, tj, tk, 2
    i, ti = _axis_skip(i, ti, si, di, xk)
    j, tj = _axis_skip(j, tj, sj, dj, xk)
    n = ((3 - (k & 3)) if sk > 0 else (k & 3)) + 1
    return i, j, k + sk * n, ti, tj, xk + dk, 1


@nb.njit(cache=True)
def _eval_one_view(cls, H, U, O, hc, bmin, res, o, R, dirs_cam, t_near, t_far, max_unknown_before_hit,
                   vid, ctag, cT, cF, cOH, touched, out):
    """Exact per-voxel DDA of every ray of one view (see evaluate_views). The traversal runs
    cell by cell with a loop per cell kind: all-free (steps only), all-unknown (steps and
    collects the voxels' bits) and mixed (per-voxel class from the cell's bitmasks)."""
    nx, ny, nz = cls.shape
    cy, cz = (ny + 3) >> 2, (nz + 3) >> 2
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    ox, oy, oz = o[0], o[1], o[2]
    mu = max_unknown_before_hit
    nt = 0
    sig = 0.0
    n_rays = 0
    n_oc_rays = 0
    n_un_rays = 0
    n_rsv = 0
    for r in range(dirs_cam.shape[0]):
        dx, dy, dz, t0, t1 = _world_ray(R, dirs_cam[r], t_near[r], t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        n_rays += 1
        i, si, ti, di = _axis_start(ox, dx, t0, bmin[0], res, nx)
        j, sj, tj, dj = _axis_start(oy, dy, t0, bmin[1], res, ny)
        k, sk, tk, dk = _axis_start(oz, dz, t0, bmin[2], res, nz)
        # local bit index steps and the local coordinate at which a step enters a new cell
        bi, bj, bk = 16 * si, 4 * sj, sk
        wi = 0 if si > 0 else 3
        wj = 0 if sj > 0 else 3
        wk = 0 if sk > 0 else 3
        n_unknown = 0
        while True:  # cell by cell
            cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
            Uc, Oc = U[cf], O[cf]
            b = ((i & 3) * 4 + (j & 3)) * 4 + (k & 3)
            st = 0
            if Oc == 0 and Uc == 0:  # all free: jump to the cell's exit
                i, j, k, ti, tj, tk, st = _skip_cell(i, j, k, ti, tj, tk, si, sj, sk, di, dj, dk, t1)
            elif Oc == 0 and Uc == _ALL:  # all unknown
                Tm = np.uint64(0)
                n0 = n_unknown
                if n0 == 0:
                    cF_bit = _U64_1 << np.uint64(b)
                else:
                    cF_bit = np.uint64(0)
                while True:
                    Tm |= _U64_1 << np.uint64(b)
                    n_unknown += 1
                    i, j, k, ti, tj, tk, b, st = _cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk,
                                                           bi, bj, bk, wi, wj, wk, t1)
                    if st != 0:
                        break
                if n0 <= mu < n_unknown:
                    n_un_rays += 1
                h = hc[cf]
                if h >= 0.0:
                    sig += h * (n_unknown - n0)
                else:
                    sig += _bits_entropy(H, cf, cy, cz, Tm)  # each voxel once: a ray visits it once
                nt = _flush(cf, Tm, cF_bit, np.uint64(0), vid, ctag, cT, cF, cOH, touched, nt)
            else:  # mixed
                Tm = np.uint64(0)
                Fm = np.uint64(0)
                h = hc[cf]
                hit = False
                while True:
                    bit = _U64_1 << np.uint64(b)
                    if (Uc | Oc) & bit:
                        if Oc & bit:  # occupied: the ray stops here
                            OHm = np.uint64(0)
                            if n_unknown <= mu:
                                n_oc_rays += 1
                                OHm = bit
                            if _rear_is_unknown(cls, i, j, k, si, sj, sk, ti, tj, tk):  # rear side voxel
                                n_rsv += 1
                            nt = _flush(cf, Tm, Fm, OHm, vid, ctag, cT, cF, cOH, touched, nt)
                            hit = True
                            break
                        n_unknown += 1
                        Tm |= bit
                        if n_unknown == 1:
                            Fm |= bit
                        if n_unknown == mu + 1:
                            n_un_rays += 1
                        if h >= 0.0:
                            sig += h
                        else:
                            sig += H[i, j, k]
                    i, j, k, ti, tj, tk, b, st = _cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk,
                                                           bi, bj, bk, wi, wj, wk, t1)
                    if st != 0:
                        break
                if hit:
                    break
                if Tm != 0:
                    nt = _flush(cf, Tm, Fm, np.uint64(0), vid, ctag, cT, cF, cOH, touched, nt)
            if st == 2 or i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
                break
    out[M_RAYS] += n_rays
    out[M_SIG] += sig
    out[M_OC_RAYS] += n_oc_rays
    out[M_UN_RAYS] += n_un_rays
    out[M_RSV] += n_rsv
    _view_sets_to_metrics(H, hc, cy, cz, cT, cF, cOH, touched, nt, out)


@nb.njit(cache=True, parallel=True)
def evaluate_views(logodds, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                   n_chunks, max_unknown_before_hit=2):
    """Per-view metrics (N, N_METRICS) for camera poses (cam_pos (N, 3), cam_rot (N, 3, 3),
    columns = camera axes in the world, +z forward) and unit ray directions in the camera
    frame `dirs_cam` (R, 3) whose ranges are [t_near[r], t_far[r]] along the ray. Rays pass
    through unknown voxels and stop at the first occupied one; an occupied voxel counts as
    overlap (oc_o) when at most `max_unknown_before_hit` unknown voxels precede it on the ray
    (a surface's thickness: grazing rays cross uncleared voxels just in front of it).
    Every ray is traced voxel by voxel (exact DDA); views are split into `n_chunks` chunks
    evaluated in parallel."""
    n = cam_pos.shape[0]
    H = entropy_grid(logodds)
    cls = classes_grid(logodds, l_free, l_occ)
    U, O, hc = cell_masks(cls, H)
    nc = U.size
    out = np.zeros((n, N_METRICS))
    ctag = np.zeros((n_chunks, nc), np.int32)
    cT = np.zeros((n_chunks, nc), np.uint64)
    cF = np.zeros((n_chunks, nc), np.uint64)
    cOH = np.zeros((n_chunks, nc), np.uint64)
    touched = np.zeros((n_chunks, nc), np.int32)
    per = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        for v in range(lo, hi):
            _eval_one_view(cls, H, U, O, hc, bmin, res, cam_pos[v], cam_rot[v], dirs_cam, t_near, t_far,
                           max_unknown_before_hit, v + 1, ctag[c], cT[c], cF[c], cOH[c], touched[c], out[v])
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


def ray_grid_width(dirs_cam: np.ndarray) -> int:
    """Pixels per image row of rays laid out row by row (sensor.ray_directions): the rays of a
    row share y/z. 0 when the rays do not form such a grid."""
    d = np.asarray(dirs_cam)
    if len(d) == 0 or np.any(d[:, 2] <= 0):
        return 0
    yz = d[:, 1] / d[:, 2]
    w = int(np.argmax(np.abs(yz - yz[0]) > 1e-12)) if np.any(np.abs(yz - yz[0]) > 1e-12) else len(d)
    if w < 2 or len(d) % w:
        return 0
    rows = yz.reshape(-1, w)
    if np.any(np.abs(rows - rows[:, :1]) > 1e-12):
        return 0
    return w


def sparse_rays(n_rays: int, width: int, a: int):
    """HRT's coarse rays: the centre pixel of every 2^a x 2^a block of the ray grid (row by row,
    `width` per row) and the rays each stands for. Every ray (weight 1) when width is 0."""
    if width <= 0 or a <= 0:
        return np.arange(n_rays, dtype=np.int64), np.ones(n_rays)
    s = 1 << a
    h = n_rays // width
    idx, wts = [], []
    for v0 in range(0, h, s):
        nv = min(s, h - v0)
        v = v0 + nv // 2
        for u0 in range(0, width, s):
            nu = min(s, width - u0)
            idx.append(v * width + u0 + nu // 2)
            wts.append(float(nu * nv))
    return np.array(idx, dtype=np.int64), np.array(wts)


@nb.njit(cache=True, inline="always")
def _tube(pitch, t, res, w):
    """Distinct voxels per voxel of a traced ray that the w rays of its pixel block touch at
    range t: the block's rays fill a tube (1 + block width in voxels) voxels wide; at most w."""
    if w <= 1.0:
        return 1.0
    bw = pitch * t * math.sqrt(w) / res
    return min(w, (1.0 + bw) * (1.0 + bw))


@nb.njit(cache=True, inline="always")
def _patch(pitch, t, res, w):
    """Voxels of a surface (first-unknown or occupied voxels) per voxel that the traced ray of
    a pixel block of w rays finds at range t: the block's footprint in voxels, 1 to w."""
    if w <= 1.0:
        return 1.0
    bw = pitch * t * math.sqrt(w) / res
    return min(w, max(1.0, (0.5 + bw) * (0.5 + bw)))


@nb.njit(cache=True)
def _eval_one_view_hrt(cls, H, bits, hsum, nunk, a, bmin, res, o, R, dirs_cam, t_near, t_far, ray_idx,
                       ray_w, pitch, max_unknown_before_hit, vid, mark, ctag, acc, out):
    """Hierarchical traversal of one view: each coarse ray (standing for ray_w[q] rays of its
    pixel block) runs a DDA over the level-a cells. All-free cells are skipped; cells with an
    occupied voxel or mixed classes are refined (exact voxel DDA inside the cell); all-unknown
    cells are accounted at the coarse level like a coarse voxel: the first ray of the view that
    touches one adds all its unknown voxels to FIG and n_posterior, SIG adds the voxels the
    segment crosses times the cell's mean entropy, and the entry voxel of a ray's first unknown
    cell is its first unknown voxel (exact)."""
    nx, ny, nz = cls.shape
    cnx, cny, cnz = bits.shape
    s = 1 << a
    cres = res * s
    ex, ey, ez = bmin[0] + nx * res, bmin[1] + ny * res, bmin[2] + nz * res
    ox, oy, oz = o[0], o[1], o[2]
    for q in range(ray_idx.shape[0]):
        r = ray_idx[q]
        w = ray_w[q]
        est = w > 1.0  # a block's ray: FIG and n_posterior of refined cells estimated too
        dx, dy, dz, t0, t1 = _world_ray(R, dirs_cam[r], t_near[r], t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        out[M_RAYS] += w
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
                if tc_out > tc_in:
                    # voxels the segment crosses: one per boundary crossed, plus the voxel
                    # the ray starts in when it starts inside this cell
                    nvox_here = (tc_out - tc_in) * crossing + (1.0 if tc_in == t0 else 0.0)
                    hs, nu = hsum[ci, cj, ck], nunk[ci, cj, ck]
                    out[M_SIG] += w * nvox_here * hs / nu
                    cflat = (ci * cny + cj) * cnz + ck
                    if ctag[cflat] != vid:
                        ctag[cflat] = vid
                        acc[cflat] = 0.0
                    # distinct voxels the block's rays touch: a tube (1 + bw) voxels wide
                    add = min(nvox_here * _tube(pitch, 0.5 * (tc_in + tc_out), res, w), nu - acc[cflat])
                    if add > 0.0:
                        acc[cflat] += add
                        out[M_FIG] += add * hs / nu
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
                            fac = _patch(pitch, tc_in, res, w)
                            out[M_UN_O] += fac
                            out[M_N_POSTERIOR] -= fac
                    prev = n_unknown
                    n_unknown += max(int(nvox_here + 0.5), 1)
                    if prev <= max_unknown_before_hit < n_unknown:
                        out[M_UN_RAYS] += w
            elif b != C_FREE and b != 0:
                # refine: exact fine DDA inside this cell
                prev = n_unknown
                n_unknown, stop = _fine_segment(
                    cls, H, bmin, res, ox, oy, oz, dx, dy, dz, tc_in, tc_out,
                    ci * s, min(ci * s + s, nx) - 1, cj * s, min(cj * s + s, ny) - 1, ck * s, min(ck * s + s, nz) - 1,
                    max_unknown_before_hit, vid, mark, out, n_unknown, w, est, _patch(pitch, tc_in, res, w))
                if est and n_unknown > prev:
                    hs, nu = hsum[ci, cj, ck], nunk[ci, cj, ck]
                    cflat = (ci * cny + cj) * cnz + ck
                    if ctag[cflat] != vid:
                        ctag[cflat] = vid
                        acc[cflat] = 0.0
                    add = min((n_unknown - prev) * _tube(pitch, 0.5 * (tc_in + tc_out), res, w), nu - acc[cflat])
                    if add > 0.0:
                        acc[cflat] += add
                        out[M_FIG] += add * hs / nu
                        out[M_N_POSTERIOR] += add
            if stop or tc_out >= t1:
                break
            tc_in = tc_out
            ci, cj, ck, tci, tcj, tck, inside = _dda_step(ci, cj, ck, sci, scj, sck, tci, tcj, tck, dci, dcj, dck,
                                                          0, cnx - 1, 0, cny - 1, 0, cnz - 1)
            if not inside:
                break


@nb.njit(cache=True, parallel=True)
def _evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                        n_chunks, max_unknown_before_hit, ray_idx, ray_w, pitch):
    n = cam_pos.shape[0]
    H = entropy_grid(logodds)
    bits, hsum, nunk = coarse_summary(logodds, H, a, l_free, l_occ)
    cls = classes_grid(logodds, l_free, l_occ)
    ncell = bits.size
    out = np.zeros((n, N_METRICS))
    mark = np.zeros((n_chunks, logodds.size), np.int32)
    ctag = np.zeros((n_chunks, ncell), np.int32)
    acc = np.zeros((n_chunks, ncell), np.float64)
    per = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        for v in range(lo, hi):
            _eval_one_view_hrt(cls, H, bits, hsum, nunk, a, bmin, res, cam_pos[v], cam_rot[v], dirs_cam,
                               t_near, t_far, ray_idx, ray_w, pitch, max_unknown_before_hit, v + 1, mark[c], ctag[c], acc[c],
                               out[v])
    return out


def evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                       n_chunks, max_unknown_before_hit=2, width=None):
    """evaluate_views with hierarchical ray tracing at resolution parameter a >= 1 (seed 000
    §5.4): rays are traced in the level-a map (cells of 2^a x 2^a x 2^a voxels) and only one ray
    per 2^a x 2^a pixel block is traced, standing for the block's rays (per-ray metrics: SIG,
    RSV, ray counts are weighted by the block's size); cells with an occupied voxel or mixed
    classes are refined to voxels. `width`: rays per image row of `dirs_cam` (row by row, as
    sensor.ray_directions gives them); None infers it, 0 traces every ray."""
    if width is None:
        width = ray_grid_width(dirs_cam)
    idx, wts = sparse_rays(len(dirs_cam), width, a)
    pitch = 0.0  # angle between neighbouring rays of a row
    if width > 1:
        pitch = float(np.arccos(np.clip(np.dot(dirs_cam[0], dirs_cam[1]), -1.0, 1.0)))
    return _evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                               n_chunks, max_unknown_before_hit, idx, wts, pitch)
