"""Every view metric of the DDA kernel against a brute-force reference (fine-step sampling
along each ray) on small random grids, and against its defining property."""
import math

import numpy as np
import pytest

from nbvs_drake.mapping import kernels as K

L_FREE, L_OCC = math.log(0.45 / 0.55), math.log(0.55 / 0.45)


def _entropy(l):
    p = 1 / (1 + math.exp(-l))
    return -p * math.log(p) - (1 - p) * math.log(1 - p)


def _brute(logodds, bmin, res, o, dirs, t_near, t_far, max_unk=2):
    """Reference: voxels along each ray by sampling every res/4000."""
    dims = np.array(logodds.shape)
    first, posterior, occ, fig_set = set(), set(), set(), set()
    sig = 0.0
    rsv = oc_rays = un_rays = nrays = 0
    for d, tn, tf in zip(dirs, t_near, t_far):
        ts = np.arange(tn, tf, res / 4000)
        pts = o + ts[:, None] * d
        idx = np.floor((pts - bmin) / res).astype(int)
        inside = np.all((idx >= 0) & (idx < dims), axis=1)
        if not inside.any():
            continue
        nrays += 1
        seq = []
        for v in map(tuple, idx[inside]):
            if not seq or seq[-1] != v:
                seq.append(v)
        n_unk = 0
        for n, v in enumerate(seq):
            lv = logodds[v]
            if lv > L_OCC:
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
    return {K.M_UN_O: len(first), K.M_OC_O: len(occ), K.M_FIG: sum(_entropy(logodds[v]) for v in fig_set),
            K.M_SIG: sig, K.M_RSV: rsv, K.M_RAYS: nrays, K.M_OC_RAYS: oc_rays, K.M_UN_RAYS: un_rays,
            K.M_N_POSTERIOR: len(posterior - first)}


def _random_map(rng, dims=(9, 8, 7)):
    lo = rng.choice([-1.5, 0.0, 0.1, 1.2], size=dims, p=[0.45, 0.3, 0.1, 0.15]).astype(np.float32)
    lo += rng.uniform(-0.05, 0.05, size=dims).astype(np.float32) * (lo == 0.1)
    return lo


@pytest.mark.parametrize("seed", range(6))
def test_kernel_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    lo = _random_map(rng)
    res = 0.1
    bmin = np.array([0.0, 0.0, 0.0])
    o = np.array([-0.35, 0.41, 0.33]) + rng.uniform(-0.05, 0.05, 3)
    # rays from the camera towards random points of the grid (identity camera rotation)
    targets = rng.uniform([0, 0, 0], np.array(lo.shape) * res, size=(40, 3))
    dirs = targets - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_near = np.full(len(dirs), 0.05)
    t_far = np.full(len(dirs), rng.uniform(0.8, 2.0))
    got = K.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1)[0]
    ref = _brute(lo, bmin, res, o, dirs, t_near, t_far)
    for m, v in ref.items():
        assert got[m] == pytest.approx(v, rel=1e-5, abs=1e-4), (m, got[m], v)


def _one_ray_grid():
    lo = np.full((6, 1, 1), -1.5, np.float32)  # a row of voxels along x
    return lo, np.zeros(3), 1.0, np.array([-0.5, 0.5, 0.5]), np.array([[1.0, 0.0, 0.0]])


def test_fig_counts_a_voxel_once_per_view_sig_once_per_ray():
    lo, bmin, res, o, d = _one_ray_grid()
    lo[2:5] = 0.0  # three unknown voxels
    one = K.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0), L_FREE, L_OCC, 1)[0]
    two = K.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], np.repeat(d, 2, 0), np.zeros(2),
                           np.full(2, 10.0), L_FREE, L_OCC, 1)[0]
    assert one[K.M_FIG] == pytest.approx(3 * math.log(2))
    assert two[K.M_FIG] == pytest.approx(one[K.M_FIG])  # FIG: once per view
    assert two[K.M_SIG] == pytest.approx(2 * one[K.M_SIG])  # SIG: once per ray
    assert one[K.M_VUV] == 1 and two[K.M_VUV] == 1  # VUV: only the first unknown voxel
    assert one[K.M_N_POSTERIOR] == 2


def test_rsv_only_the_voxel_right_behind_an_occupied_hit():
    lo, bmin, res, o, d = _one_ray_grid()
    lo[2] = 1.2  # occupied
    lo[3] = 0.0  # unknown right behind it
    lo[4] = 0.0
    m = K.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0), L_FREE, L_OCC, 1)[0]
    assert m[K.M_RSV] == 1 and m[K.M_OC_O] == 1
    assert m[K.M_FIG] == 0 and m[K.M_VUV] == 0  # the ray stops at the occupied voxel
    lo[3] = -1.5  # free behind it: no rear side voxel, even with unknown further back
    m = K.evaluate_views(lo, bmin, res, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 10.0), L_FREE, L_OCC, 1)[0]
    assert m[K.M_RSV] == 0


def test_views_in_parallel_equal_views_one_by_one():
    rng = np.random.default_rng(9)
    lo = _random_map(rng, (12, 10, 8))
    dirs = rng.normal(size=(200, 3)) + [0, 0, 3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    n = 7
    pos = rng.uniform(-0.3, 0.0, (n, 3)) + [0.5, 0.5, -0.2]
    rot = np.repeat(np.eye(3)[None], n, 0)
    tn, tf = np.zeros(len(dirs)), np.full(len(dirs), 3.0)
    batch = K.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 3)
    for i in range(n):
        single = K.evaluate_views(lo, np.zeros(3), 0.1, pos[i:i + 1], rot[i:i + 1], dirs, tn, tf, L_FREE, L_OCC, 1)
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
    uni = K.evaluate_views(lo, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)
    bits, _, _ = K.coarse_summary(lo, K.entropy_grid(lo), a, L_FREE, L_OCC)
    assert not np.any(bits == K.C_UNKNOWN)
    hrt = K.evaluate_views_hrt(lo, a, np.zeros(3), 0.1, pos, rot, dirs, tn, tf, L_FREE, L_OCC, 1)
    skipped = np.all(bits == K.C_FREE)
    assert not skipped
    np.testing.assert_allclose(hrt, uni, rtol=1e-9)


def test_hrt_skips_free_cells_and_accounts_unknown_cells():
    # a free half and an all-unknown half along x; one ray along +x through the middle
    lo = np.full((16, 4, 4), -1.5, np.float32)
    lo[8:] = 0.0
    d = np.array([[1.0, 0.0, 0.0]])
    o = np.array([-0.5, 0.2, 0.2])
    args = (np.zeros(3), 0.1, o[None], np.eye(3)[None], d, np.zeros(1), np.full(1, 5.0), L_FREE, L_OCC, 1)
    uni = K.evaluate_views(lo, *args)[0]
    hrt = K.evaluate_views_hrt(lo, 2, *args)[0]
    assert hrt[K.M_VUV] == uni[K.M_VUV] == 1  # the entry voxel of the unknown region
    assert hrt[K.M_SIG] == pytest.approx(uni[K.M_SIG])  # 8 voxels crossed
    # FIG estimates the distinct voxels touched from the voxels crossed: exact for one ray
    assert hrt[K.M_FIG] == pytest.approx(uni[K.M_FIG]) == pytest.approx(8 * math.log(2))
    assert hrt[K.M_N_POSTERIOR] == pytest.approx(uni[K.M_N_POSTERIOR]) == 7
    # many parallel rays through the same cells saturate at the cells' 2 x 64 unknown voxels
    d2 = np.repeat(d, 50, 0)
    many = K.evaluate_views_hrt(lo, 2, np.zeros(3), 0.1, o[None], np.eye(3)[None], d2, np.zeros(50),
                                np.full(50, 5.0), L_FREE, L_OCC, 1)[0]
    assert many[K.M_FIG] == pytest.approx(2 * 64 * math.log(2))
