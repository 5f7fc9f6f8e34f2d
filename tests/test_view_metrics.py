"""Every view metric of the DDA kernel against a brute-force reference (fine-step sampling
along each ray from the camera, with the sensor's minimum range) on small random grids, and
against its defining property."""
import math

import numpy as np
import pytest

from nbvs_drake.mapping import cells, voxel
from nbvs_drake.mapping import view_metrics as VM

L_FREE, L_OCC = math.log(0.45 / 0.55), math.log(0.55 / 0.45)


def _entropy(l):
    p = 1 / (1 + math.exp(-l))
    return -p * math.log(p) - (1 - p) * math.log(1 - p)


def _brute(logodds, bmin, res, o, dirs, t_near, t_far, max_unk=2, unknown_blinds=True, q=0.0):
    """Reference: voxels along each ray from the camera (t = 0), found by sorting every
    crossing of a voxel boundary plane along the ray in [0, t_far] and sampling each segment
    between consecutive crossings at its middle (exact, where fixed-step sampling misses the
    short segments of a ray passing close to a voxel edge).
    The sensor model: a ray meeting an occupied or unknown voxel among the voxels it enters
    before t_near is blind (counted only in M_BLIND_RAYS; unknown_blinds False: only an
    occupied one); otherwise the metrics are those of its voxels in [t_near, t_far]."""
    dims = np.array(logodds.shape)
    first, posterior, occ, fig_set = set(), set(), set(), set()
    sig = 0.0
    rsv = oc_rays = un_rays = nrays = blind = new_rays = 0
    new_exp = 0.0
    for d, tn, tf in zip(dirs, t_near, t_far):
        cuts = [0.0, tf]
        for a in range(3):
            if abs(d[a]) > 1e-12:
                cuts.extend((bmin[a] + np.arange(dims[a] + 1) * res - o[a]) / d[a])
        cuts = np.unique(np.clip(cuts, 0.0, tf))
        ts = cuts[:-1]  # segment starts; each segment sampled at its middle
        pts = o + (0.5 * (cuts[:-1] + cuts[1:]))[:, None] * d
        idx = np.floor((pts - bmin) / res).astype(int)
        inside = np.all((idx >= 0) & (idx < dims), axis=1)
        if not inside.any():
            continue
        seq, entry = [], []  # the voxels in the grid and the t at which the ray enters each
        for v, t in zip(map(tuple, idx[inside]), ts[inside]):
            if not seq or seq[-1] != v:
                seq.append(v)
                entry.append(t)
        def blinds(lv):
            return lv > L_OCC or (unknown_blinds and lv >= L_FREE)
        if any(t < tn and blinds(logodds[v]) for v, t in zip(seq, entry)):
            blind += 1
            continue
        if not np.any(inside & (cuts[1:] > tn)):  # no part of the ray in the grid beyond t_near
            continue
        keep = [n for n, t in enumerate(entry) if n + 1 == len(entry) or entry[n + 1] > tn]
        seq = [seq[n] for n in keep]  # the voxels the ray is in beyond t_near
        nrays += 1
        n_unk = 0
        hit = False
        for n, v in enumerate(seq):
            lv = logodds[v]
            if lv > L_OCC:
                hit = True
                if n_unk <= max_unk:
                    occ.add(v)
                    oc_rays += 1
                if n + 1 < len(seq) and L_FREE <= logodds[seq[n + 1]] <= L_OCC:
                    rsv += 1
                break
            if lv >= L_FREE:
                n_unk += 1
                if n_unk == max_unk + 1:
                    un_rays += 1
                sig += _entropy(lv)
                fig_set.add(v)
                (first if n_unk == 1 else posterior).add(v)
        if n_unk > max_unk:  # crossed unknown space: new surface met (hit) or expected (1 - (1 - q)^n)
            new_rays += hit
            new_exp += 1.0 if hit else 1.0 - (1.0 - q) ** n_unk
    return {VM.M_UN_O: len(first), VM.M_OC_O: len(occ), VM.M_FIG: sum(_entropy(logodds[v]) for v in fig_set),
            VM.M_SIG: sig, VM.M_RSV: rsv, VM.M_RAYS: nrays, VM.M_OC_RAYS: oc_rays, VM.M_UN_RAYS: un_rays,
            VM.M_N_POSTERIOR: len(posterior - first), VM.M_BLIND_RAYS: blind, VM.M_NEW_RAYS: new_rays,
            VM.M_NEW_EXPECTED: new_exp}


def _random_map(rng, dims=(9, 8, 7)):
    lo = rng.choice([-1.5, 0.0, 0.1, 1.2], size=dims, p=[0.45, 0.3, 0.1, 0.15]).astype(np.float32)
    lo += rng.uniform(-0.05, 0.05, size=dims).astype(np.float32) * (lo == 0.1)
    return lo


def _camera_and_rays(rng, n_rays):
    """A random map (0.1 m voxels from the origin), a camera just outside it and unit rays
    from the camera towards random points of the grid (identity camera rotation), each with
    a minimum range of 5 cm: (logodds, res, bmin, o, dirs, t_near)."""
    lo = _random_map(rng)
    res = 0.1
    bmin = np.array([0.0, 0.0, 0.0])
    o = np.array([-0.35, 0.41, 0.33]) + rng.uniform(-0.05, 0.05, 3)
    targets = rng.uniform([0, 0, 0], np.array(lo.shape) * res, size=(n_rays, 3))
    dirs = targets - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return lo, res, bmin, o, dirs, np.full(n_rays, 0.05)


@pytest.mark.parametrize("seed", range(6))
def test_kernel_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    lo, res, bmin, o, dirs, t_near = _camera_and_rays(rng, 40)
    t_far = np.full(len(dirs), rng.uniform(0.8, 2.0))
    got = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                            near_unknown_blinds=True, surface_q=0.07)[0]
    ref = _brute(lo, bmin, res, o, dirs, t_near, t_far, q=0.07)
    assert ref[VM.M_NEW_RAYS] > 0 and ref[VM.M_NEW_EXPECTED] > ref[VM.M_NEW_RAYS]  # both kinds of ray occur
    for m, v in ref.items():
        assert got[m] == pytest.approx(v, rel=1e-5, abs=1e-4), (m, got[m], v)


def _one_ray_grid():
    lo = np.full((6, 1, 1), -1.5, np.float32)  # a row of voxels along x
    return lo, np.zeros(3), 1.0, np.array([-0.5, 0.5, 0.5]), np.array([[1.0, 0.0, 0.0]])


def test_fig_counts_a_voxel_once_per_view_sig_once_per_ray():
    lo, bmin, res, o, d = _one_ray_grid()
    lo[2:5] = 0.0  # three unknown voxels
    one = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0),
                          L_FREE, L_OCC, 1)[0]
    two = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], np.repeat(d, 2, 0), np.zeros(2),
                           np.full(2, 10.0), L_FREE, L_OCC, 1)[0]
    assert one[VM.M_FIG] == pytest.approx(3 * math.log(2))
    assert two[VM.M_FIG] == pytest.approx(one[VM.M_FIG])  # FIG: once per view
    assert two[VM.M_SIG] == pytest.approx(2 * one[VM.M_SIG])  # SIG: once per ray
    assert one[VM.M_VUV] == 1 and two[VM.M_VUV] == 1  # VUV: only the first unknown voxel
    assert one[VM.M_N_POSTERIOR] == 2


def test_rsv_only_the_voxel_right_behind_an_occupied_hit():
    lo, bmin, res, o, d = _one_ray_grid()
    lo[2] = 1.2  # occupied
    lo[3] = 0.0  # unknown right behind it
    lo[4] = 0.0
    m = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0),
                          L_FREE, L_OCC, 1)[0]
    assert m[VM.M_RSV] == 1 and m[VM.M_OC_O] == 1
    assert m[VM.M_FIG] == 0 and m[VM.M_VUV] == 0  # the ray stops at the occupied voxel
    lo[3] = -1.5  # free behind it: no rear side voxel, even with unknown further back
    m = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0),
                          L_FREE, L_OCC, 1)[0]
    assert m[VM.M_RSV] == 0


def test_views_in_parallel_equal_views_one_by_one():
    rng = np.random.default_rng(9)
    lo = _random_map(rng, (12, 10, 8))
    dirs = rng.normal(size=(200, 3)) + [0, 0, 3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    n = 7
    pos = rng.uniform(-0.3, 0.0, (n, 3)) + [0.5, 0.5, -0.2]
    rot = np.repeat(np.eye(3)[None], n, 0)
    tn, tf = np.zeros(len(dirs)), np.full(len(dirs), 3.0)
    batch = VM.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 3)
    for i in range(n):
        single = VM.evaluate_views(lo, np.zeros(3), 0.1, pos[i:i + 1], rot[i:i + 1], dirs, tn, tf, L_FREE, L_OCC, 1)
        np.testing.assert_allclose(batch[i], single[0])


@pytest.mark.parametrize("a", [1, 2])
def test_hrt_is_exact_where_every_cell_is_refined(a):
    # random fine-grained maps: every coarse cell mixes classes, so HRT refines everywhere
    rng = np.random.default_rng(a)
    lo = _random_map(rng, (16, 12, 8))
    dirs = rng.normal(size=(300, 3)) + [0, 0, 2.5]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pos = np.array([[0.8, 0.6, -0.6], [0.3, 0.2, -0.3]])
    rot = np.repeat(np.eye(3)[None], 2, 0)
    tn, tf = np.zeros(len(dirs)), np.full(len(dirs), 3.0)
    uni = VM.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)
    bits, _, _ = cells.coarse_summary(lo, voxel.entropy_grid(lo), a, L_FREE, L_OCC)
    assert not np.any(bits == voxel.C_UNKNOWN)
    hrt = VM.evaluate_views_hrt(lo, a, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)
    skipped = np.all(bits == voxel.C_FREE)
    assert not skipped
    np.testing.assert_allclose(hrt, uni, rtol=1e-9)


def test_hrt_skips_free_cells_and_accounts_unknown_cells():
    # a free half and an all-unknown half along x; one ray along +x through the middle
    lo = np.full((16, 4, 4), -1.5, np.float32)
    lo[8:] = 0.0
    d = np.array([[1.0, 0.0, 0.0]])
    o = np.array([-0.5, 0.2, 0.2])
    args = (np.zeros(3), 0.1, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 5.0), L_FREE, L_OCC, 1)
    uni = VM.evaluate_views(lo, *args)[0]
    hrt = VM.evaluate_views_hrt(lo, 2, *args)[0]
    assert hrt[VM.M_VUV] == uni[VM.M_VUV] == 1  # the entry voxel of the unknown region
    assert hrt[VM.M_SIG] == pytest.approx(uni[VM.M_SIG])  # 8 voxels crossed
    # FIG estimates the distinct voxels touched from the voxels crossed: exact for one ray
    assert hrt[VM.M_FIG] == pytest.approx(uni[VM.M_FIG]) == pytest.approx(8 * math.log(2))
    assert hrt[VM.M_N_POSTERIOR] == pytest.approx(uni[VM.M_N_POSTERIOR]) == 7
    # many parallel rays through the same cells saturate at the cells' 2 x 64 unknown voxels
    d2 = np.repeat(d, 50, 0)
    many = VM.evaluate_views_hrt(lo, 2, np.zeros(3), 0.1, o[None], np.eye(3)[None], d2, np.zeros(50),
                                np.full(50, 5.0), L_FREE, L_OCC, 1)[0]
    assert many[VM.M_FIG] == pytest.approx(2 * 64 * math.log(2))


def _block_map(rng, dims=(17, 14, 11)):
    """Homogeneous 4x4x4 blocks (all free, all unknown with one or several entropies, some with
    occupied voxels) so that every cell kind of the traversal occurs, grid edges included."""
    lo = np.empty(dims, np.float32)
    for ci in range(0, dims[0], 4):
        for cj in range(0, dims[1], 4):
            for ck in range(0, dims[2], 4):
                kind = rng.integers(4)
                blk = (slice(ci, ci + 4), slice(cj, cj + 4), slice(ck, ck + 4))
                if kind == 0:
                    lo[blk] = -1.5
                elif kind == 1:
                    lo[blk] = 0.0
                elif kind == 2:  # unknown with differing entropies
                    lo[blk] = rng.uniform(-0.15, 0.15, lo[blk].shape)
                else:
                    lo[blk] = rng.choice([-1.5, 0.0, 1.2], size=lo[blk].shape, p=[0.6, 0.3, 0.1])
    return lo


@pytest.mark.parametrize("seed", range(4))
def test_kernel_matches_brute_force_on_homogeneous_cells(seed):
    # all-free cells are jumped over, all-unknown cells collected as bitmasks: still exact
    rng = np.random.default_rng(100 + seed)
    lo = _block_map(rng)
    res, bmin = 0.1, np.array([0.0, 0.0, 0.0])
    o = np.array([-0.45, 0.37, 0.52]) + rng.uniform(-0.05, 0.05, 3)
    targets = rng.uniform([0, 0, 0], np.array(lo.shape) * res, size=(40, 3))
    dirs = targets - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_near, t_far = np.full(len(dirs), 0.05), np.full(len(dirs), 3.0)
    got = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                            near_unknown_blinds=True, surface_q=0.07)[0]
    ref = _brute(lo, bmin, res, o, dirs, t_near, t_far, q=0.07)
    assert ref[VM.M_NEW_RAYS] > 0 and ref[VM.M_NEW_EXPECTED] > ref[VM.M_NEW_RAYS]  # both kinds of ray occur
    for m, v in ref.items():
        assert got[m] == pytest.approx(v, rel=1e-5, abs=1e-4), (m, got[m], v)


def test_cell_masks_hold_the_classes():
    rng = np.random.default_rng(3)
    lo = _block_map(rng, (9, 6, 7))
    cls = voxel.classes_grid(lo, L_FREE, L_OCC)
    H = voxel.entropy_grid(lo)
    U, O, hc = cells.cell_masks(cls, H)
    cy, cz = 2, 2
    for i, j, k in np.ndindex(lo.shape):
        cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
        b = ((i & 3) * 4 + (j & 3)) * 4 + (k & 3)
        assert bool((int(U[cf]) >> b) & 1) == (cls[i, j, k] == voxel.UNKNOWN)
        assert bool((int(O[cf]) >> b) & 1) == (cls[i, j, k] == voxel.OCCUPIED)
        if cls[i, j, k] == voxel.UNKNOWN and hc[cf] >= 0:
            assert hc[cf] == pytest.approx(H[i, j, k])


def test_all_free_region_is_skipped_exactly():
    # a long free corridor, then an occupied voxel with unknown behind it
    lo = np.full((40, 4, 4), -1.5, np.float32)
    lo[33] = 1.2
    lo[34:] = 0.0
    d = np.array([[1.0, 0.013, -0.007]])
    d /= np.linalg.norm(d)
    o = np.array([-0.3, 0.21, 0.19])
    m = VM.evaluate_views(lo, np.zeros(3), 0.1, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 9.0),
                         L_FREE, L_OCC, 1)[0]
    assert m[VM.M_RAYS] == 1 and m[VM.M_OC_RAYS] == 1 and m[VM.M_OC_O] == 1 and m[VM.M_RSV] == 1
    assert m[VM.M_FIG] == 0 and m[VM.M_SIG] == 0 and m[VM.M_UN_O] == 0
    lo[33] = -1.5  # now the ray crosses the unknown end: 6 voxels
    m = VM.evaluate_views(lo, np.zeros(3), 0.1, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 9.0),
                         L_FREE, L_OCC, 1)[0]
    assert m[VM.M_UN_O] == 1 and m[VM.M_N_POSTERIOR] == 5 and m[VM.M_FIG] == pytest.approx(6 * math.log(2))


def _grid_rays(w, h, f):
    u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
    d = np.stack([u.ravel() / f, v.ravel() / f, np.ones(u.size)], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_sparse_rays_cover_the_image_once():
    d = _grid_rays(10, 7, 20.0)
    assert VM.ray_grid_width(d) == 10
    assert VM.ray_grid_width(np.random.default_rng(0).normal(size=(12, 3)) + [0, 0, 5]) == 0
    for a in (1, 2):
        idx, w = VM.sparse_rays(len(d), 10, a)
        assert w.sum() == len(d) and len(np.unique(idx)) == len(idx)
    idx, w = VM.sparse_rays(len(d), 0, 2)
    assert len(idx) == len(d) and np.all(w == 1)


@pytest.mark.parametrize("a", [1, 2, 3])
def test_hrt_tracing_every_ray_equals_uniform_where_every_cell_is_refined(a):
    # grid rays with width=0: every ray is traced; on a map where every cell with an unknown
    # voxel is refined HRT = uniform
    for seed in range(100):  # a map without all-unknown cells (all-free ones are skipped exactly)
        lo = _random_map(np.random.default_rng(seed), (16, 12, 8))
        bits, _, _ = cells.coarse_summary(lo, voxel.entropy_grid(lo), a, L_FREE, L_OCC)
        if not np.any(bits == voxel.C_UNKNOWN):
            break
    dirs = _grid_rays(24, 18, 19.73)
    # generic positions: a grid ray through a voxel edge is a tie the two traversals may
    # break differently
    pos = np.array([[0.8137, 0.6171, -0.6093], [0.3091, 0.2053, -0.3127]])
    rot = np.repeat(np.eye(3)[None], 2, 0)
    tn, tf = np.zeros(len(dirs)), np.full(len(dirs), 3.0)
    assert not np.any(bits == voxel.C_UNKNOWN)
    uni = VM.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)
    hrt = VM.evaluate_views_hrt(lo, a, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1, width=0)
    np.testing.assert_allclose(hrt, uni, rtol=1e-9)


def test_hrt_block_rays_estimate_the_uniform_metrics():
    # one traced ray per 4x4 pixel block, weighted: per-ray metrics stay close to uniform
    rng = np.random.default_rng(5)
    lo = _block_map(rng, (24, 24, 16))
    dirs = _grid_rays(48, 40, 60.0)
    pos = np.array([[1.2, 1.2, -1.0]])
    rot = np.eye(3)[None]
    tn, tf = np.zeros(len(dirs)), np.full(len(dirs), 6.0)
    uni = VM.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)[0]
    hrt = VM.evaluate_views_hrt(lo, 2, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)[0]
    assert hrt[VM.M_RAYS] == pytest.approx(uni[VM.M_RAYS], rel=0.05)
    assert hrt[VM.M_SIG] == pytest.approx(uni[VM.M_SIG], rel=0.15)
    assert hrt[VM.M_FIG] == pytest.approx(uni[VM.M_FIG], rel=0.25)


# --------------------------------------------------------------------------------------
# The sensor's minimum range: rays start at the camera; a non-free voxel entered before
# t_near blinds the ray
# --------------------------------------------------------------------------------------


def _near_map(rng, o, res, dims=(12, 11, 10), r_clear=0.3, p_near=0.03):
    """A random map whose voxels within r_clear of the camera o are free but for a few
    (p_near) occupied or unknown ones, so that some rays are blinded within t_near and others
    pass."""
    lo = _random_map(rng, dims)
    c = (np.stack(np.meshgrid(*[np.arange(n) for n in dims], indexing="ij"), -1) + 0.5) * res
    near = np.linalg.norm(c - o, axis=-1) < r_clear
    keep = rng.random(dims) < p_near
    lo[near & ~keep] = -1.5
    return lo


@pytest.mark.parametrize("unknown_blinds", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_kernel_matches_brute_force_from_inside_the_grid(seed, unknown_blinds):
    rng = np.random.default_rng(200 + seed)
    res, bmin = 0.1, np.zeros(3)
    o = np.array([0.53, 0.47, 0.42]) + rng.uniform(-0.05, 0.05, 3)
    lo = _near_map(rng, o, res)
    dirs = rng.normal(size=(60, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_near = rng.uniform(0.1, 0.35, len(dirs))
    t_far = np.full(len(dirs), 2.0)
    got = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                            near_unknown_blinds=unknown_blinds)[0]
    ref = _brute(lo, bmin, res, o, dirs, t_near, t_far, unknown_blinds=unknown_blinds)
    assert ref[VM.M_BLIND_RAYS] < len(dirs) and ref[VM.M_RAYS] > 0
    assert ref[VM.M_BLIND_RAYS] > 0 or not unknown_blinds  # both kinds of ray occur
    for m, v in ref.items():
        assert got[m] == pytest.approx(v, rel=1e-5, abs=1e-4), (m, got[m], v)
    hrt = VM.evaluate_views_hrt(lo, 1, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                                width=0, near_unknown_blinds=unknown_blinds)[0]
    bits, _, _ = cells.coarse_summary(lo, voxel.entropy_grid(lo), 1, L_FREE, L_OCC)
    if not np.any(bits == voxel.C_UNKNOWN):  # every cell refined: HRT is exact too
        np.testing.assert_allclose(hrt, got, rtol=1e-9)
    assert hrt[VM.M_BLIND_RAYS] == got[VM.M_BLIND_RAYS]  # the minimum range is exact in HRT


def _row(lo, t_near, o=(-0.5, 0.5, 0.5), t_far=10.0, a=0, blinds=True):
    """One ray along +x; blinds: the conservative rule (unknown space within the minimum range
    blinds the ray too)."""
    d = np.array([[1.0, 0.0, 0.0]])
    args = (np.zeros(3), 1.0, np.array([o]), np.eye(3)[None], d, np.full(1, t_near), np.full(1, t_far),
            L_FREE, L_OCC, 1)
    kw = dict(near_unknown_blinds=blinds)
    return VM.evaluate_views_hrt(lo, a, *args, **kw)[0] if a else VM.evaluate_views(lo, *args, **kw)[0]


@pytest.mark.parametrize("a", [0, 1])
def test_surface_within_the_minimum_range_blinds_the_ray(a):
    # voxels x in [0, 6) along the ray, the camera at x = -0.5
    lo, *_ = _one_ray_grid()
    lo[2] = 1.2  # occupied, entered at t = 2.5
    lo[3:] = 0.0  # unknown behind it
    far = _row(lo, 2.4, a=a)  # beyond the minimum range: overlap, as before
    assert far[VM.M_OC_RAYS] == 1 and far[VM.M_OC_O] == 1 and far[VM.M_RAYS] == 1 and far[VM.M_BLIND_RAYS] == 0
    for blinds in (False, True):  # the surface is nearer than the minimum range: nothing at all
        near = _row(lo, 2.6, a=a, blinds=blinds)
        assert near[VM.M_BLIND_RAYS] == 1
        assert not np.any(np.delete(near, VM.M_BLIND_RAYS)), near
    # the conservative rule: an unknown voxel entered before t_near may hold such a surface,
    # so the ray ends there too; by default it is passed through (most likely air)
    lo[2] = 0.0
    near = _row(lo, 2.6, a=a)
    assert near[VM.M_BLIND_RAYS] == 1 and not np.any(np.delete(near, VM.M_BLIND_RAYS))
    passed = _row(lo, 2.6, a=a, blinds=False)
    assert passed[VM.M_BLIND_RAYS] == 0 and passed[VM.M_RAYS] == 1 and passed[VM.M_UN_O] == 1
    # free voxels before t_near are passed through; the voxel straddling t_near counts as
    # entered before it
    lo[:] = -1.5
    lo[3:] = 0.0  # unknown from t = 3.5
    assert _row(lo, 3.5, a=a)[VM.M_UN_O] == 1 and _row(lo, 3.4, a=a)[VM.M_UN_O] == 1
    assert _row(lo, 3.6, a=a)[VM.M_BLIND_RAYS] == 1 and _row(lo, 3.6, a=a)[VM.M_UN_O] == 0
    # the camera standing in an unknown voxel is blinded at once
    blind = _row(lo, 0.2, o=(3.5, 0.5, 0.5), a=a)
    assert blind[VM.M_BLIND_RAYS] == 1 and blind[VM.M_UN_O] == 0 and blind[VM.M_FIG] == 0


def test_camera_inside_wbox_next_to_unknown_space_predicts_nothing_behind_it():
    # free space around the camera (cleared by earlier scans), unknown space 0.2 m ahead and
    # a known surface behind it; minimum range 0.4 m: the unknown voxels within 0.4 m may hold
    # a surface that blinds the camera, so nothing behind them is predicted
    res = 0.02
    lo = np.full((60, 20, 20), -1.5, np.float32)
    lo[20:40] = 0.0  # unknown from x = 0.40 m
    lo[40] = 1.2  # occupied at x = 0.80 m
    o = np.array([0.2, 0.2, 0.2])
    rng = np.random.default_rng(1)
    dirs = np.array([1.0, 0.0, 0.0]) + rng.uniform(-0.05, 0.05, (200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    tn = 0.4 / dirs[:, 0]  # the depth range along each ray (camera +z along world +x)
    tf = 5.0 / dirs[:, 0]
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # camera +z along world +x
    dcam = dirs @ R  # the same rays in the camera frame
    args = (np.zeros(3), res, o[None], R[None], dcam, tn, tf, L_FREE, L_OCC, 1)
    met = VM.evaluate_views(lo, *args, near_unknown_blinds=True)[0]
    assert met[VM.M_BLIND_RAYS] == len(dirs)
    assert met[VM.M_UN_O] == met[VM.M_OC_O] == met[VM.M_FIG] == met[VM.M_OC_RAYS] == met[VM.M_RAYS] == 0
    hrt = VM.evaluate_views_hrt(lo, 2, *args, near_unknown_blinds=True)[0]
    assert hrt[VM.M_BLIND_RAYS] == len(dirs) and hrt[VM.M_UN_O] == hrt[VM.M_FIG] == hrt[VM.M_RAYS] == 0
    # the default: the unknown space within the minimum range is most likely air; the rays cross
    # it and the unknown stretch, and meet the known surface behind: returns on new surface
    met = VM.evaluate_views(lo, *args)[0]
    assert met[VM.M_BLIND_RAYS] == 0 and met[VM.M_NEW_RAYS] == met[VM.M_NEW_EXPECTED] == len(dirs)
    # 0.7 m back the unknown space lies beyond the minimum range: it is seen
    o2 = np.array([-0.3, 0.2, 0.2])
    met2 = VM.evaluate_views(lo, np.zeros(3), res, o2[None], R[None], dcam, tn, tf, L_FREE, L_OCC, 1)[0]
    assert met2[VM.M_BLIND_RAYS] == 0 and met2[VM.M_UN_O] > 0 and met2[VM.M_RAYS] > 0


def _inside_box(p, row):
    c, h, cs, sn = row[:3], row[3:6], row[6], row[7]
    d = p - c
    loc = np.stack([cs * d[..., 0] + sn * d[..., 1], -sn * d[..., 0] + cs * d[..., 1], d[..., 2]], -1)
    return np.all(np.abs(loc) <= h, axis=-1)


def test_first_solid_is_where_the_ray_enters_the_nearest_box():
    rng = np.random.default_rng(4)
    occ = np.array([[1.0, 0.2, 0.5, 0.2, 0.1, 0.3, np.cos(0.7), np.sin(0.7)],
                    [2.0, -0.1, 0.4, 0.05, 0.3, 0.2, np.cos(-0.3), np.sin(-0.3)]])
    ts = np.linspace(0.0, 3.0, 30001)
    hits = 0
    for _ in range(300):
        o = rng.uniform([-0.5, -0.5, 0.0], [0.0, 0.5, 1.0])
        d = np.array([1.0, *rng.uniform(-0.4, 0.4, 2)])
        d /= np.linalg.norm(d)
        got = VM._first_solid(occ, *o, *d, 3.0)
        P = o + ts[:, None] * d
        inside = _inside_box(P, occ[0]) | _inside_box(P, occ[1])
        want = ts[np.argmax(inside)] if inside.any() else 3.0
        hits += inside.any()
        assert got == pytest.approx(want, abs=2e-4)
    assert 50 < hits < 250  # both hits and misses


@pytest.mark.parametrize("seed", range(4))
def test_occluders_end_the_rays_that_meet_a_known_solid_before_the_grid(seed):
    """planner.view_occluders: with boxes between the camera and the grid, the metrics are
    those of the rays that miss the boxes (brute force with the blocked rays dropped);
    without boxes nothing changes."""
    rng = np.random.default_rng(seed)
    lo, res, bmin, o, dirs, t_near = _camera_and_rays(rng, 60)
    t_far = np.full(len(dirs), 2.0)
    yaw = rng.uniform(-1, 1)
    c = o + np.array([0.15, *rng.uniform(-0.04, 0.04, 2)])  # in front of the camera, outside the grid
    occ = np.array([[*c, 0.02, 0.04, 0.04, np.cos(yaw), np.sin(yaw)]])
    blocked = np.array([VM._first_solid(occ, *o, *d, 9.0) < 9.0 for d in dirs])
    assert 5 < blocked.sum() < len(dirs) - 5
    kw = dict(near_unknown_blinds=True, surface_q=0.07)
    got = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                            occluders=occ, **kw)[0]
    ref = _brute(lo, bmin, res, o, dirs[~blocked], t_near[~blocked], t_far[~blocked], q=0.07)
    for m, v in ref.items():
        assert got[m] == pytest.approx(v, rel=1e-5, abs=1e-4), (m, got[m], v)
    plain = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1, **kw)
    none = VM.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1,
                             occluders=np.zeros((0, 8)), **kw)
    np.testing.assert_array_equal(plain, none)


def test_the_boxes_kept_for_a_view_are_all_that_can_stop_its_rays_into_the_grid():
    """_occluders_in_view drops only boxes no ray from the camera into the grid can meet."""
    rng = np.random.default_rng(7)
    bmin, emax = np.array([-0.3, -0.3, 0.7]), np.array([0.3, 0.3, 1.2])
    n_box = 40
    occ = np.zeros((n_box, 8))
    occ[:, :3] = rng.uniform([-2, -2, 0], [2, 2, 1.5], (n_box, 3))
    occ[:, 3:6] = rng.uniform(0.02, 0.25, (n_box, 3))
    yaw = rng.uniform(-np.pi, np.pi, n_box)
    occ[:, 6], occ[:, 7] = np.cos(yaw), np.sin(yaw)
    dropped_some = False
    for _ in range(20):
        o = rng.uniform([-2, -2, 0.3], [2, 2, 1.5])
        kept = VM._occluders_in_view(occ, *o, bmin, *emax)
        dropped_some |= len(kept) < n_box
        pts = rng.uniform(bmin, emax, (400, 3))  # rays to points of the grid
        for p in pts:
            d = p - o
            L = np.linalg.norm(d)
            d = d / L
            assert VM._first_solid(occ, *o, *d, L) == VM._first_solid(kept, *o, *d, L)
    assert dropped_some
