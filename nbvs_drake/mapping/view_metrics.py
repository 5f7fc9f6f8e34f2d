"""View evaluation: the metrics of simulated scans from candidate camera poses.

`evaluate_views` traces every ray voxel by voxel (exact DDA, walking the 4 x 4 x 4 cell
bitmasks of mapping.cells); `evaluate_views_hrt` is the approximate hierarchical ray tracing
of Vasquez-Gomez et al. 2017 §5.4 (one ray per pixel block over level-a cells, refined where classes mix).
Both return one row of N_METRICS per view, columns M_*.

The sensor model is the camera's (sensor.ray_directions: its pixel grid and field of view,
each ray's [t_near, t_far] from its depth range; systems.depth_camera's DepthRange):
- every ray starts at the camera. A surface nearer than the minimum range (depth z_near)
  returns nothing and hides what lies behind it, so a ray that meets an occupied voxel among
  the voxels it enters before t_near ends there with nothing counted (no unknown, no
  occupied voxel, no overlap: M_BLIND_RAYS). Unknown and free voxels before t_near are passed
  through uncounted (raycast.blinded_within). `near_unknown_blinds` True treats an unknown
  voxel there like a surface (the ray ends with nothing counted); that conservative rule was
  measured wrong in practice: the unknown space near a candidate camera is nearly always air
  the early scans have not cleared (on a first-scan map 47 of 300 candidates predicted blind
  returned 100+ object points), and it cut the default run's coverage from 0.93 to 0.75;
- beyond t_near, rays pass through unknown voxels and stop at the first occupied one, up to
  t_far (the sensor's maximum range).
The robot itself does not hide the map from its candidate views, so the rays carry no
self-occlusion bound: in the label images of 2,300 scans rendered at the planner's candidates
(director ray and collision filter, with or without W_box as an obstacle; teapot and bunny
scenes) 2 views saw the robot's base, on
under 1 % of their pixels, all nearer than z_near and none on a ray into the map.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .cells import ALL_BITS, U64_1, bits_entropy, cell_masks, cell_step, coarse_summary, popcount, skip_cell
from .raycast import axis_start, axis_start_in, blinded_within, clip_ray, dda_step, world_ray
from .voxel import C_FREE, C_UNKNOWN, OCCUPIED, UNKNOWN, classes_grid, entropy_grid

# columns of the per-view metrics returned by evaluate_views
M_UN_O = 0  #: distinct visible unknown voxels (first unknown voxel of each ray) = VUV
M_OC_O = 1  #: distinct occupied voxels hit with at most `max_unknown_before_hit` unknown voxels before them
M_FIG = 2  #: sum of entropies of distinct unknown voxels touched (each once per view)
M_SIG = 3  #: sum of entropies of unknown voxels touched, per ray (Kriegel)
M_RSV = 4  #: rays that hit an occupied voxel whose next voxel along the ray is unknown
M_RAYS = 5  #: rays that reach the map within the sensor's range and are not blinded (M_BLIND_RAYS)
M_OC_RAYS = 6  #: rays whose first non-free voxel is occupied (the scan lands on known surface)
M_UN_RAYS = 7  #: rays whose first non-free voxel is unknown
M_N_POSTERIOR = 8  #: Santos et al. 2020 n_posterior: distinct unknown voxels touched only behind another unknown voxel
#: rays that enter the map but meet an occupied or unknown voxel within the minimum range
#: (before t_near): they return nothing and count in no other column
M_BLIND_RAYS = 9
#: rays that cross more than `max_unknown_before_hit` unknown voxels and then meet an occupied
#: voxel: the surface they met from behind bounds a closed object, so the unknown stretch
#: before it holds unseen surface (a return on new surface)
M_NEW_RAYS = 10
#: expected rays that return on new surface: M_NEW_RAYS, plus each ray that crosses more than
#: `max_unknown_before_hit` unknown voxels and leaves the map (or its range) without meeting an
#: occupied one, weighted by 1 - (1 - q)^n for its n unknown voxels, q being the chance that an
#: unknown voxel holds surface (`surface_q`; ViewEvaluator estimates it from the map)
M_NEW_EXPECTED = 11
#: expected covered surface area the view adds (m^2; 0 unless a density grid is given): each
#: ray stands for the area its pixels sample at the range t where it lands, stride^2 (pitch t)^2,
#: and adds the sample density 1 / (pitch t)^2 there. A patch sampled at density D is covered
#: (every surface point within r of a sample) for the share 1 - exp(-pi r^2 D) (samples
#: scattered uniformly; cov_k = pi r^2). Only the unknown voxels marked `near` (next to known
#: surface) may hold new surface: a ray that meets an occupied voxel after at most
#: `max_unknown_before_hit` of them lands on known surface and counts the gain over the
#: voxel's density so far (it crossed air: free voxels, or unknown ones far from any surface);
#: after more, it met that surface from behind and returns on new surface; a ray that meets
#: none crosses n near voxels and returns on new surface with the chance 1 - (1 - near_q)^n.
#: Rays on new surface count the full gain from zero density at the range of their first
#: near unknown voxel
M_COVER_GAIN = 12
N_METRICS = 13
M_VUV = M_UN_O  #: the ORT paper VUV


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
    return 0 <= i < nx and 0 <= j < ny and 0 <= k < nz and cls[i, j, k] == UNKNOWN


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
    i, si, ti, di = axis_start_in(ox, dx, t_in, bmin[0], res, i_lo, i_hi)
    j, sj, tj, dj = axis_start_in(oy, dy, t_in, bmin[1], res, j_lo, j_hi)
    k, sk, tk, dk = axis_start_in(oz, dz, t_in, bmin[2], res, k_lo, k_hi)
    tag = vid << 2
    while True:
        c = cls[i, j, k]
        if c == OCCUPIED:
            if n_unknown <= max_unknown_before_hit:
                out[M_OC_RAYS] += w
                flat = (i * ny + j) * nz + k
                if mark[flat] >> 2 != vid:
                    mark[flat] = tag | _FIRST
                    out[M_OC_O] += fac
            if _rear_is_unknown(cls, i, j, k, si, sj, sk, ti, tj, tk):  # rear side voxel
                out[M_RSV] += w
            return n_unknown, True
        if c == UNKNOWN:
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
        i, j, k, ti, tj, tk, inside = dda_step(i, j, k, si, sj, sk, ti, tj, tk, di, dj, dk,
                                               i_lo, i_hi, j_lo, j_hi, k_lo, k_hi)
        if not inside:
            return n_unknown, False


# --------------------------------------------------------------------------------------
# Exact evaluation. The traversal keeps the distinct voxel sets of a view (touched unknown T,
# first-unknown F, counted occupied OH) as per-cell bitmasks (mapping.cells) held in
# registers while a ray is inside a cell, so a step writes no per-voxel marks.
# --------------------------------------------------------------------------------------


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
def _view_sets_to_metrics(H, hc, cy, cz, cT, cF, cOH, touched, nt, out):
    """FIG, un_o (= VUV = n_first), n_posterior and oc_o from the view's distinct voxel sets."""
    fig = 0.0
    n_first = 0
    n_post = 0
    n_occ = 0
    for q in range(nt):
        cf = touched[q]
        T, F = cT[cf], cF[cf]
        n_first += popcount(F)
        n_post += popcount(T & ~F)
        n_occ += popcount(cOH[cf])
        h = hc[cf]
        if h >= 0.0:
            fig += h * popcount(T)
        elif T != 0:
            fig += bits_entropy(H, cf, cy, cz, T)
    out[M_FIG] += fig
    out[M_UN_O] += n_first
    out[M_N_POSTERIOR] += n_post
    out[M_OC_O] += n_occ


@nb.njit(cache=True, inline="always")
def _voxel_range(bmin, res, i, j, k, ox, oy, oz):
    """Distance from the camera to the centre of voxel (i, j, k)."""
    ex = bmin[0] + (i + 0.5) * res - ox
    ey = bmin[1] + (j + 0.5) * res - oy
    ez = bmin[2] + (k + 0.5) * res - oz
    return math.sqrt(ex * ex + ey * ey + ez * ez)


@nb.njit(cache=True, inline="always")
def _count_near(near, bmin, res, i, j, k, ox, oy, oz, n_near, t_unknown):
    """An unknown voxel (i, j, k) on a ray: one more near known surface if `near` marks it,
    and the range of the ray's first such voxel."""
    if near[i, j, k]:
        if n_near == 0:
            t_unknown = _voxel_range(bmin, res, i, j, k, ox, oy, oz)
        n_near += 1
    return n_near, t_unknown


@nb.njit(cache=True, inline="always")
def _cover_gain(density, cov_k, pitch, stride2, t):
    """Covered area (m^2) a ray adds landing at range t on surface of sample density `density`
    (see M_COVER_GAIN)."""
    s2 = (pitch * t) * (pitch * t)
    return stride2 * s2 * (math.exp(-cov_k * density) - math.exp(-cov_k * (density + 1.0 / s2)))


@nb.njit(cache=True, inline="always")
def _first_solid(occ, ox, oy, oz, dx, dy, dz, t_max):
    """The range along the ray (o, d) at which it enters the first of the known solids `occ`
    (M, 8: centre, half size, cos and sin of the yaw about z), or t_max; a solid the ray
    starts in is ignored (the camera is never inside one)."""
    t_hit = t_max
    for b in range(occ.shape[0]):
        c, s = occ[b, 6], occ[b, 7]
        px, py, pz = ox - occ[b, 0], oy - occ[b, 1], oz - occ[b, 2]
        lo3 = (c * px + s * py, -s * px + c * py, pz)
        ld3 = (c * dx + s * dy, -s * dx + c * dy, dz)
        t_in, t_out = -1e300, 1e300
        miss = False
        for a in range(3):
            h, l, d = occ[b, 3 + a], lo3[a], ld3[a]
            if abs(d) < 1e-12:
                if abs(l) > h:
                    miss = True
                    break
                continue
            t1, t2 = (-h - l) / d, (h - l) / d
            if t1 > t2:
                t1, t2 = t2, t1
            t_in, t_out = max(t_in, t1), min(t_out, t2)
        if not miss and t_in <= t_out and t_in > 0.0 and t_in < t_hit:
            t_hit = t_in
    return t_hit


@nb.njit(cache=True)
def _occluders_in_view(occ, ox, oy, oz, bmin, ex, ey, ez):
    """The rows of `occ` that may stand between the camera and the grid: a box's bounding
    sphere that meets the cone from the camera around the grid's bounding sphere, and not
    beyond the grid (conservative: the rays' verdicts are those of all the boxes)."""
    if occ.shape[0] == 0:
        return occ
    gx, gy, gz = 0.5 * (bmin[0] + ex), 0.5 * (bmin[1] + ey), 0.5 * (bmin[2] + ez)
    rg = 0.5 * math.sqrt((ex - bmin[0]) ** 2 + (ey - bmin[1]) ** 2 + (ez - bmin[2]) ** 2)
    vx, vy, vz = gx - ox, gy - oy, gz - oz
    dg = math.sqrt(vx * vx + vy * vy + vz * vz)
    keep = np.zeros(occ.shape[0], np.bool_)
    for b in range(occ.shape[0]):
        rb = math.sqrt(occ[b, 3] ** 2 + occ[b, 4] ** 2 + occ[b, 5] ** 2)
        cx, cy, cz = occ[b, 0] - ox, occ[b, 1] - oy, occ[b, 2] - oz
        dc = math.sqrt(cx * cx + cy * cy + cz * cz)
        if dc <= rb or dg <= rg:  # the camera at the box or in the grid's sphere: keep it
            keep[b] = True
            continue
        if dc - rb > dg + rg:  # wholly beyond the grid
            continue
        cosang = (cx * vx + cy * vy + cz * vz) / (dc * dg)
        ang = math.acos(max(-1.0, min(1.0, cosang)))
        keep[b] = ang <= math.asin(rg / dg) + math.asin(rb / dc)
    return occ[keep]


@nb.njit(cache=True)
def _eval_one_view(grid, sensor, metric, view, work, out):
    """Exact per-voxel DDA of every ray of one view (see evaluate_views), its arguments grouped
    by concern: `grid` the map (classes, entropies, unknown and occupied bitmasks, cell
    summary, origin, voxel size, the cells' near-surface bitmasks, the occupied voxels'
    centres, the known occluders), `sensor` the rays (camera-frame directions, minimum and
    maximum range, stride squared, pitch, the reach within which a voxel can blind a ray,
    whether unknown voxels blind, the unknown voxels a ray may cross before its return),
    `metric` what is scored (the surface probability of an unknown voxel, sample densities and
    the coverage constant, the near-surface map, score_only, the region of interest, the
    facing densities), `view` (camera origin, rotation, view id), `work` the chunk's scratch
    arrays, `out` the view's row. The traversal runs
    cell by cell with a loop per cell kind: all-free (steps only), all-unknown (steps and
    collects the voxels' bits) and mixed (per-voxel class from the cell's bitmasks).
    When no occupied voxel centre (`occ_centres`) comes within `blind_reach` of the camera
    (the longest minimum range of the rays plus a voxel's half diagonal), no
    ray can be blinded and the per-ray check is skipped (exact; only occupied voxels blind
    unless `unknown_blinds`). `score_only`: the per-ray columns only, for a coarse pass (the
    distinct-voxel columns stay 0): an all-unknown cell whose voxels share one entropy and are
    all or none near known surface (`NB`, the cells' near bitmasks) is crossed at once,
    counting the voxels the ray crosses in it. `roi` (6: a box's lower and upper corner, or
    empty): only the rays whose direction falls in the box's image (the bounds of its
    corners' projections; every ray when the box is not wholly in front of the camera) are
    traced, up to where they leave the box, for a score that no other ray, and no voxel past
    the box, can change (ranking_score's roi_margin)."""
    cls, H, U, O, hc, bmin, res, NB, occ_centres, occ = grid
    dirs_cam, t_near, t_far, stride2, pitch, blind_reach, unknown_blinds, max_unknown_before_hit = sensor
    surface_q, dens, cov_k, near, near_q, score_only, roi = metric
    o, R, vid = view
    ctag, cT, cF, cOH, touched = work
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
    n_blind = 0
    n_new = 0
    e_new = 0.0
    cover = 0.0
    with_cover = dens.shape[0] == nx
    occ = _occluders_in_view(occ, ox, oy, oz, bmin, ex, ey, ez)
    check_blind = True
    if not unknown_blinds:  # can an occupied voxel lie within the minimum range of the camera?
        check_blind = False
        for p in range(occ_centres.shape[0]):
            wx, wy, wz = occ_centres[p, 0] - ox, occ_centres[p, 1] - oy, occ_centres[p, 2] - oz
            if wx * wx + wy * wy + wz * wz <= blind_reach * blind_reach:
                check_blind = True
                break
    use_roi = roi.shape[0] == 6
    txlo, txhi, tylo, tyhi = np.inf, -np.inf, np.inf, -np.inf
    if use_roi:  # the box's image: the bounds of its corners' projections
        for c in range(8):
            wx = (roi[3] if c & 1 else roi[0]) - ox
            wy = (roi[4] if c & 2 else roi[1]) - oy
            wz = (roi[5] if c & 4 else roi[2]) - oz
            zc = R[0, 2] * wx + R[1, 2] * wy + R[2, 2] * wz
            if zc <= 1e-9:  # a corner beside or behind the camera: no bound
                use_roi = False
                break
            tx = (R[0, 0] * wx + R[1, 0] * wy + R[2, 0] * wz) / zc
            ty = (R[0, 1] * wx + R[1, 1] * wy + R[2, 1] * wz) / zc
            txlo, txhi, tylo, tyhi = min(txlo, tx), max(txhi, tx), min(tylo, ty), max(tyhi, ty)
    for r in range(dirs_cam.shape[0]):
        if use_roi:
            tx, ty = dirs_cam[r, 0] / dirs_cam[r, 2], dirs_cam[r, 1] / dirs_cam[r, 2]
            if tx < txlo or tx > txhi or ty < tylo or ty > tyhi:
                continue
        # from the camera: [t0, t1] is the ray's part in the grid up to the maximum range
        dx, dy, dz, t0, t1 = world_ray(R, dirs_cam[r], 0.0, t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        if occ.shape[0]:  # a known solid (a chair) in front of the grid ends the ray there
            t1 = min(t1, _first_solid(occ, ox, oy, oz, dx, dy, dz, t1))
            if t0 > t1:
                continue
        if check_blind and blinded_within(cls, bmin, res, ox, oy, oz, dx, dy, dz, t0, t_near[r], t1,
                                          unknown_blinds):
            n_blind += 1
            continue
        t0 = max(t0, t_near[r])  # nothing but free voxels before the minimum range
        if t0 > t1:
            continue
        if use_roi:  # the ray up to where it leaves the box: nothing after can change the score
            tb0, tb1 = clip_ray(ox, oy, oz, dx, dy, dz, t0, t1, roi[0], roi[1], roi[2], roi[3], roi[4], roi[5])
            if tb0 > tb1:
                continue
            t1 = tb1
        n_rays += 1
        i, si, ti, di = axis_start(ox, dx, t0, bmin[0], res, nx)
        j, sj, tj, dj = axis_start(oy, dy, t0, bmin[1], res, ny)
        k, sk, tk, dk = axis_start(oz, dz, t0, bmin[2], res, nz)
        # local bit index steps and the local coordinate at which a step enters a new cell
        bi, bj, bk = 16 * si, 4 * sj, sk
        wi = 0 if si > 0 else 3
        wj = 0 if sj > 0 else 3
        wk = 0 if sk > 0 else 3
        n_unknown = 0
        n_near = 0  # unknown voxels near known surface (coverage gain only)
        ray_hit = False
        t_unknown = 0.0  # range of the ray's first unknown voxel near known surface (`near`)
        while True:  # cell by cell
            cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
            Uc, Oc = U[cf], O[cf]
            b = ((i & 3) * 4 + (j & 3)) * 4 + (k & 3)
            st = 0
            if Oc == 0 and Uc == 0:  # all free: jump to the cell's exit
                i, j, k, ti, tj, tk, st = skip_cell(i, j, k, ti, tj, tk, si, sj, sk, di, dj, dk, t1)
            elif Oc == 0 and Uc == ALL_BITS:  # all unknown
                crossed = False
                if score_only and hc[cf] >= 0.0 and (NB[cf] == 0 or NB[cf] == ALL_BITS):
                    # one entropy, all or none near surface: across at once when the ray leaves
                    # the cell (status 1; at status 2 skip_cell leaves the state as it was)
                    i2, j2, k2, ti2, tj2, tk2, st = skip_cell(i, j, k, ti, tj, tk, si, sj, sk, di, dj, dk, t1)
                    if st == 1:
                        crossed = True
                        cnt = abs(i2 - i) + abs(j2 - j) + abs(k2 - k)  # the voxels crossed in the cell
                        if with_cover and NB[cf] != 0:
                            if n_near == 0:
                                t_unknown = _voxel_range(bmin, res, i, j, k, ox, oy, oz)
                            n_near += cnt
                        if n_unknown <= mu < n_unknown + cnt:
                            n_un_rays += 1
                        n_unknown += cnt
                        sig += hc[cf] * cnt
                        i, j, k, ti, tj, tk = i2, j2, k2, ti2, tj2, tk2
                    else:
                        st = 0
                if not crossed:  # voxel by voxel, collecting the voxels' bits
                    Tm = np.uint64(0)
                    n0 = n_unknown
                    if n0 == 0:
                        cF_bit = U64_1 << np.uint64(b)
                    else:
                        cF_bit = np.uint64(0)
                    while True:
                        Tm |= U64_1 << np.uint64(b)
                        n_unknown += 1
                        if with_cover:
                            n_near, t_unknown = _count_near(near, bmin, res, i, j, k, ox, oy, oz, n_near,
                                                            t_unknown)
                        i, j, k, ti, tj, tk, b, st = cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk,
                                                               bi, bj, bk, wi, wj, wk, t1)
                        if st != 0:
                            break
                    if n0 <= mu < n_unknown:
                        n_un_rays += 1
                    h = hc[cf]
                    if h >= 0.0:
                        sig += h * (n_unknown - n0)
                    else:
                        sig += bits_entropy(H, cf, cy, cz, Tm)  # each voxel once: a ray visits it once
                    if not score_only:
                        nt = _flush(cf, Tm, cF_bit, np.uint64(0), vid, ctag, cT, cF, cOH, touched, nt)
            else:  # mixed
                Tm = np.uint64(0)
                Fm = np.uint64(0)
                h = hc[cf]
                hit = False
                while True:
                    bit = U64_1 << np.uint64(b)
                    if (Uc | Oc) & bit:
                        if Oc & bit:  # occupied: the ray stops here
                            OHm = np.uint64(0)
                            if n_unknown <= mu:
                                n_oc_rays += 1
                                OHm = bit
                            if with_cover and n_near <= mu:  # lands on known surface
                                cover += _cover_gain(dens[i, j, k], cov_k, pitch, stride2,
                                                     _voxel_range(bmin, res, i, j, k, ox, oy, oz))
                            if _rear_is_unknown(cls, i, j, k, si, sj, sk, ti, tj, tk):  # rear side voxel
                                n_rsv += 1
                            if not score_only:
                                nt = _flush(cf, Tm, Fm, OHm, vid, ctag, cT, cF, cOH, touched, nt)
                            hit = True
                            break
                        n_unknown += 1
                        Tm |= bit
                        if n_unknown == 1:
                            Fm |= bit
                        if with_cover:
                            n_near, t_unknown = _count_near(near, bmin, res, i, j, k, ox, oy, oz, n_near, t_unknown)
                        if n_unknown == mu + 1:
                            n_un_rays += 1
                        if h >= 0.0:
                            sig += h
                        else:
                            sig += H[i, j, k]
                    i, j, k, ti, tj, tk, b, st = cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk,
                                                           bi, bj, bk, wi, wj, wk, t1)
                    if st != 0:
                        break
                if hit:
                    ray_hit = True
                    break
                if Tm != 0 and not score_only:
                    nt = _flush(cf, Tm, Fm, np.uint64(0), vid, ctag, cT, cF, cOH, touched, nt)
            if st == 2 or i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
                break
        if n_unknown > mu:  # the ray crosses unknown space: a return on new surface?
            e = 1.0
            if ray_hit:
                n_new += 1
            else:
                e = 1.0 - (1.0 - surface_q) ** n_unknown
            e_new += e
        if with_cover and n_near > mu:  # expected new surface, in the unknown space near known surface
            e = 1.0 if ray_hit else 1.0 - (1.0 - near_q) ** n_near
            cover += e * _cover_gain(0.0, cov_k, pitch, stride2, max(t_unknown, t_near[r]))
    out[M_RAYS] += n_rays
    out[M_SIG] += sig
    out[M_OC_RAYS] += n_oc_rays
    out[M_UN_RAYS] += n_un_rays
    out[M_RSV] += n_rsv
    out[M_BLIND_RAYS] += n_blind
    out[M_NEW_RAYS] += n_new
    out[M_NEW_EXPECTED] += e_new
    out[M_COVER_GAIN] += cover
    if not score_only:
        _view_sets_to_metrics(H, hc, cy, cz, cT, cF, cOH, touched, nt, out)


@nb.njit(cache=True, parallel=True)
def evaluate_views(logodds, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                   n_chunks, max_unknown_before_hit=2, near_unknown_blinds=False, surface_q=0.0,
                   density=None, cov_k=0.0, pitch=0.0, stride=1, near=None, near_q=0.0, occluders=None,
                   score_only=False, roi_margin=-1.0):
    """Per-view metrics (N, N_METRICS) for camera poses (cam_pos (N, 3), cam_rot (N, 3, 3),
    columns = camera axes in the world, +z forward) and unit ray directions in the camera
    frame `dirs_cam` (R, 3) whose ranges are [t_near[r], t_far[r]] along the ray (the
    sensor's minimum and maximum range). Rays start at the camera: one that meets an occupied
    or (conservatively) an unknown voxel among those it enters before t_near is blinded and
    counts only in M_BLIND_RAYS (see the module's sensor model; `near_unknown_blinds` False:
    only occupied voxels blind, for measuring the conservative rule). Beyond t_near rays pass
    through unknown voxels and stop at the first occupied one; an occupied voxel counts as
    overlap (oc_o) when at most `max_unknown_before_hit` unknown voxels precede it on the ray
    (a surface's thickness: grazing rays cross uncleared voxels just in front of it).
    M_NEW_RAYS / M_NEW_EXPECTED: the rays expected to return on new surface, with `surface_q`
    the chance that an unknown voxel holds surface (see the columns).
    M_COVER_GAIN when `density` (the map's sample density per voxel, samples per m^2) is given,
    with cov_k = pi r^2 for the coverage radius r, the sensor's `pitch` (rad per pixel) and the
    ray `stride` (pixels per ray along a row); `near` (bool grid) marks the unknown voxels
    that may hold new surface, each with the chance `near_q` (planning.views.near_surface;
    None: every unknown voxel, with the chance `surface_q`).
    `occluders` (M, 8: centre, half size, cos and sin of the yaw; `known_occluders`): known
    solids outside the grid (chairs) that end a ray where it enters them; None: the grid
    alone decides what a ray sees.
    Every ray is traced voxel by voxel (exact DDA); views are split into `n_chunks` chunks
    evaluated in parallel. `score_only`: the per-ray columns only, faster (the coarse pass of
    the coarse-to-fine evaluation; see _eval_one_view), the distinct-voxel columns 0.
    `roi_margin` >= 0 (with score_only): only the rays towards the occupied voxels' bounding
    box grown by that many voxels are traced (the others count in no column): for a score
    that only rays on known surface, or on unknown voxels that near it, can change."""
    n = cam_pos.shape[0]
    H = entropy_grid(logodds)
    cls = classes_grid(logodds, l_free, l_occ)
    U, O, hc = cell_masks(cls, H)
    if density is None:
        dens = np.zeros((0, 0, 0), np.float32)
        nr = np.zeros((0, 0, 0), np.bool_)
    else:
        dens = density
        if near is None:  # every unknown voxel may hold surface, with the chance surface_q
            nr = np.ones(cls.shape, np.bool_)
            near_q = surface_q
        else:
            nr = near
    stride2 = float(stride * stride)
    occ = np.zeros((0, 8)) if occluders is None else occluders
    occ_centres = occupied_centres(cls, bmin, res)
    blind_reach = t_near.max() + 0.8660254037844386 * res  # a voxel's half diagonal beyond the minimum range
    NB = near_cell_masks(nr, U) if score_only and density is not None else np.zeros(U.size, np.uint64)
    roi = np.zeros(0)
    if score_only and roi_margin >= 0.0 and occ_centres.shape[0] > 0:
        g = (0.5 + roi_margin) * res
        roi = np.empty(6)
        for a in range(3):
            roi[a] = occ_centres[:, a].min() - g
            roi[3 + a] = occ_centres[:, a].max() + g
    nc = U.size
    out = np.zeros((n, N_METRICS))
    ctag = np.zeros((n_chunks, nc), np.int32)
    cT = np.zeros((n_chunks, nc), np.uint64)
    cF = np.zeros((n_chunks, nc), np.uint64)
    cOH = np.zeros((n_chunks, nc), np.uint64)
    touched = np.zeros((n_chunks, nc), np.int32)
    per = (n + n_chunks - 1) // n_chunks
    grid = (cls, H, U, O, hc, bmin, res, NB, occ_centres, occ)
    sensor = (dirs_cam, t_near, t_far, stride2, pitch, blind_reach, near_unknown_blinds, max_unknown_before_hit)
    metric = (surface_q, dens, cov_k, nr, near_q, score_only, roi)
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        work = (ctag[c], cT[c], cF[c], cOH[c], touched[c])
        for v in range(lo, hi):
            _eval_one_view(grid, sensor, metric, (cam_pos[v], cam_rot[v], v + 1), work, out[v])
    return out


@nb.njit(cache=True)
def occupied_centres(cls, bmin, res):
    """The centres (P, 3) of the occupied voxels."""
    nx, ny, nz = cls.shape
    n = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                n += cls[i, j, k] == OCCUPIED
    out = np.empty((n, 3))
    n = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if cls[i, j, k] == OCCUPIED:
                    out[n, 0] = bmin[0] + (i + 0.5) * res
                    out[n, 1] = bmin[1] + (j + 0.5) * res
                    out[n, 2] = bmin[2] + (k + 0.5) * res
                    n += 1
    return out


@nb.njit(cache=True)
def near_cell_masks(near, U):
    """Per 4x4x4 cell (cell_masks' layout): the bitmask of its unknown voxels marked `near`."""
    nx, ny, nz = near.shape
    cy, cz = (ny + 3) >> 2, (nz + 3) >> 2
    NB = np.zeros(U.size, np.uint64)
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if near[i, j, k]:
                    cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
                    NB[cf] |= U64_1 << np.uint64(((i & 3) * 4 + (j & 3)) * 4 + (k & 3))
    return NB & U


@nb.njit(cache=True, parallel=True)
def views_see_spheres(centres, radius, cam_pos, cam_rot, planes, t_far):
    """Whether any sphere (centres (P, 3), one radius) may lie in each camera's view
    (cam_pos (N, 3), cam_rot (N, 3, 3), columns = camera axes): not wholly outside one of the
    frustum's side planes through the camera (`planes` (4, 3): inward unit normals in the
    camera frame) nor beyond t_far from it. Conservative: a view that returns False has no
    ray that can reach any sphere (the frustum's sides bound every ray of the sensor)."""
    n = cam_pos.shape[0]
    out = np.zeros(n, np.bool_)
    for v in nb.prange(n):
        R = cam_rot[v]
        ox, oy, oz = cam_pos[v, 0], cam_pos[v, 1], cam_pos[v, 2]
        reach = t_far + radius
        for p in range(centres.shape[0]):
            wx, wy, wz = centres[p, 0] - ox, centres[p, 1] - oy, centres[p, 2] - oz
            if wx * wx + wy * wy + wz * wz > reach * reach:
                continue
            x = R[0, 0] * wx + R[1, 0] * wy + R[2, 0] * wz
            y = R[0, 1] * wx + R[1, 1] * wy + R[2, 1] * wz
            z = R[0, 2] * wx + R[1, 2] * wy + R[2, 2] * wz
            inside = True
            for f in range(planes.shape[0]):
                if planes[f, 0] * x + planes[f, 1] * y + planes[f, 2] * z < -radius:
                    inside = False
                    break
            if inside:
                out[v] = True
                break
    return out


def frustum_planes(dirs_cam: np.ndarray) -> np.ndarray:
    """The inward unit normals (4, 3), in the camera frame, of the side planes through the
    camera that bound the rays `dirs_cam` (+z forward): x/z and y/z between their extremes."""
    d = np.asarray(dirs_cam, float)
    tx, ty = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
    planes = np.array([[1.0, 0.0, -tx.min()], [-1.0, 0.0, tx.max()], [0.0, 1.0, -ty.min()], [0.0, -1.0, ty.max()]])
    return np.ascontiguousarray(planes / np.linalg.norm(planes, axis=1, keepdims=True))


def known_occluders(scene) -> np.ndarray:
    """The known environment's boxes but the floor (the table, its legs, the chairs) as
    `evaluate_views`' occluders (M, 8)."""
    from ..world.scene import box_arrays
    centers, half, yaw = box_arrays(scene, floor=False)
    return np.ascontiguousarray(np.c_[centers, half, np.cos(yaw), np.sin(yaw)])


# --------------------------------------------------------------------------------------
# Hierarchical ray tracing (Vasquez-Gomez et al. 2017 §5.4)
# --------------------------------------------------------------------------------------


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
def _eval_one_view_hrt(grid, sensor, metric, view, work, out):
    """Hierarchical traversal of one view, its arguments grouped as `_eval_one_view`'s: `grid`
    (classes, entropies, the level-a cells' bits, entropy sums and unknown counts, a, origin,
    voxel size), `sensor` (camera-frame directions, minimum and maximum range, the traced rays
    and their weights, pitch, whether unknown voxels blind, the unknown voxels a ray may cross),
    `metric` (the surface probability of an unknown voxel), `view` (origin, rotation, view id),
    `work` (the chunk's scratch arrays), `out`. Each coarse ray (standing for ray_w[q] rays of its
    pixel block) runs a DDA over the level-a cells. All-free cells are skipped; cells with an
    occupied voxel or mixed classes are refined (exact voxel DDA inside the cell); all-unknown
    cells are accounted at the coarse level like a coarse voxel: the first ray of the view that
    touches one adds all its unknown voxels to FIG and n_posterior, SIG adds the voxels the
    segment crosses times the cell's mean entropy, and the entry voxel of a ray's first unknown
    cell is its first unknown voxel (exact)."""
    cls, H, bits, hsum, nunk, a, bmin, res = grid
    dirs_cam, t_near, t_far, ray_idx, ray_w, pitch, unknown_blinds, max_unknown_before_hit = sensor
    (surface_q,) = metric
    o, R, vid = view
    mark, ctag, acc = work
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
        dx, dy, dz, t0, t1 = world_ray(R, dirs_cam[r], 0.0, t_far[r], ox, oy, oz, bmin, ex, ey, ez)
        if t0 > t1:
            continue
        # the minimum range, exactly (voxel by voxel) for the traced ray
        if blinded_within(cls, bmin, res, ox, oy, oz, dx, dy, dz, t0, t_near[r], t1, unknown_blinds):
            out[M_BLIND_RAYS] += w
            continue
        t0 = max(t0, t_near[r])
        if t0 > t1:
            continue
        out[M_RAYS] += w
        crossing = (abs(dx) + abs(dy) + abs(dz)) / res  # voxel boundaries crossed per metre
        ci, sci, tci, dci = axis_start(ox, dx, t0, bmin[0], cres, cnx)
        cj, scj, tcj, dcj = axis_start(oy, dy, t0, bmin[1], cres, cny)
        ck, sck, tck, dck = axis_start(oz, dz, t0, bmin[2], cres, cnz)
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
            ci, cj, ck, tci, tcj, tck, inside = dda_step(ci, cj, ck, sci, scj, sck, tci, tcj, tck, dci, dcj, dck,
                                                         0, cnx - 1, 0, cny - 1, 0, cnz - 1)
            if not inside:
                break
        if n_unknown > max_unknown_before_hit:  # the ray crosses unknown space: a return on new surface?
            if stop:
                out[M_NEW_RAYS] += w
                out[M_NEW_EXPECTED] += w
            else:
                out[M_NEW_EXPECTED] += w * (1.0 - (1.0 - surface_q) ** n_unknown)


@nb.njit(cache=True, parallel=True)
def _evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                        n_chunks, max_unknown_before_hit, ray_idx, ray_w, pitch, unknown_blinds, surface_q):
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
    grid = (cls, H, bits, hsum, nunk, a, bmin, res)
    sensor = (dirs_cam, t_near, t_far, ray_idx, ray_w, pitch, unknown_blinds, max_unknown_before_hit)
    metric = (surface_q,)
    for c in nb.prange(n_chunks):
        lo = c * per
        hi = min(n, lo + per)
        work = (mark[c], ctag[c], acc[c])
        for v in range(lo, hi):
            _eval_one_view_hrt(grid, sensor, metric, (cam_pos[v], cam_rot[v], v + 1), work, out[v])
    return out


def evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                       n_chunks, max_unknown_before_hit=2, width=None, near_unknown_blinds=False, surface_q=0.0):
    """evaluate_views with hierarchical ray tracing at resolution parameter a >= 1 (Vasquez-Gomez et al. 2017
    §5.4): rays are traced in the level-a map (cells of 2^a x 2^a x 2^a voxels) and only one ray
    per 2^a x 2^a pixel block is traced, standing for the block's rays (per-ray metrics: SIG,
    RSV, ray counts are weighted by the block's size); cells with an occupied voxel or mixed
    classes are refined to voxels. The sensor model is evaluate_views': each traced ray's
    minimum range is checked voxel by voxel from the camera (a blinded ray blinds its block).
    `width`: rays per image row of `dirs_cam` (row by row, as
    sensor.ray_directions gives them); None infers it, 0 traces every ray."""
    if width is None:
        width = ray_grid_width(dirs_cam)
    idx, wts = sparse_rays(len(dirs_cam), width, a)
    pitch = 0.0  # angle between neighbouring rays of a row
    if width > 1:
        pitch = float(np.arccos(np.clip(np.dot(dirs_cam[0], dirs_cam[1]), -1.0, 1.0)))
    return _evaluate_views_hrt(logodds, a, bmin, res, cam_pos, cam_rot, dirs_cam, t_near, t_far, l_free, l_occ,
                               n_chunks, max_unknown_before_hit, idx, wts, pitch, near_unknown_blinds, surface_q)
