"""The coarse-to-fine view evaluation (planner.coarse_stride): frustum culling, the per-ray-only
coarse pass and the ranking whose head is exact."""

import numpy as np
import pytest
from test_view_metrics import L_FREE, L_OCC, _block_map

from nbvs_drake.config import load_scenario
from nbvs_drake.mapping import view_metrics as VM
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.planning.candidates import StateSampler
from nbvs_drake.planning.views import ViewEvaluator, ranking_score, scaled_score
from nbvs_drake.world.robot import RobotKinematics


def _ray_meets_sphere(o, d, c, r, t_far):
    w = c - o
    t = np.clip(w @ d, 0.0, t_far)
    return np.linalg.norm(w - t * d) <= r


@pytest.mark.parametrize("seed", range(3))
def test_a_culled_view_has_no_ray_that_can_reach_a_sphere(seed):
    rng = np.random.default_rng(seed)
    # a small sensor: 9 x 7 rays through a 40 x 30 degree field of view
    u, v = np.meshgrid(np.linspace(-0.36, 0.36, 9), np.linspace(-0.27, 0.27, 7))
    dirs = np.c_[u.ravel(), v.ravel(), np.ones(u.size)]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    planes = VM.frustum_planes(dirs)
    centres = rng.uniform(-0.3, 0.3, size=(25, 3))
    radius, t_far = 0.04, 2.5
    n = 400
    pos = rng.uniform(-2.0, 2.0, size=(n, 3))
    rot = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(n)])
    rot[np.linalg.det(rot) < 0, :, 0] *= -1
    seen = VM.views_see_spheres(centres, radius, pos, rot, planes, t_far)
    assert 0 < seen.sum() < n  # both verdicts occur
    for v in np.flatnonzero(~seen):
        world = dirs @ rot[v].T
        assert not any(_ray_meets_sphere(pos[v], d, c, radius, t_far) for d in world for c in centres)


@pytest.mark.parametrize("seed", range(4))
def test_the_per_ray_only_pass_gives_the_full_pass_per_ray_columns(seed):
    # all-unknown cells are crossed at once in the score-only pass: the voxels they count
    # are the ones the exact walk visits
    rng = np.random.default_rng(300 + seed)
    lo = _block_map(rng)
    res, bmin = 0.1, np.zeros(3)
    near = (rng.random(lo.shape) < 0.5) & (np.abs(lo) < 0.5)
    near[:8] = True  # whole cells near surface as well as mixed ones
    near[8:12] = False
    dens = rng.uniform(0.0, 3e4, lo.shape).astype(np.float32)
    o = np.array([-0.45, 0.37, 0.52]) + rng.uniform(-0.05, 0.05, 3)
    targets = rng.uniform([0, 0, 0], np.array(lo.shape) * res, size=(200, 3))
    dirs = targets - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_near, t_far = np.full(len(dirs), 0.05), np.full(len(dirs), 3.0)
    args = (lo, bmin, res, o[None], np.eye(3)[None], dirs, t_near, t_far, L_FREE, L_OCC, 1)
    kw = dict(surface_q=0.07, density=dens, cov_k=np.pi * 9e-6, pitch=0.004, stride=2, near=near, near_q=0.2)
    full = VM.evaluate_views(*args, **kw)[0]
    fast = VM.evaluate_views(*args, **kw, score_only=True)[0]
    per_ray = [VM.M_SIG, VM.M_RSV, VM.M_RAYS, VM.M_OC_RAYS, VM.M_UN_RAYS, VM.M_BLIND_RAYS, VM.M_NEW_RAYS,
               VM.M_NEW_EXPECTED, VM.M_COVER_GAIN]
    assert full[VM.M_COVER_GAIN] > 0 and full[VM.M_NEW_RAYS] > 0
    np.testing.assert_allclose(fast[per_ray], full[per_ray], rtol=1e-9, atol=1e-12)
    assert np.all(fast[[VM.M_UN_O, VM.M_OC_O, VM.M_FIG, VM.M_N_POSTERIOR]] == 0)


@pytest.fixture(scope="module")
def ball_scene():
    """The default scene with a map of a 12 cm ball on the table whose camera-facing half is
    known (occupied, free in front), the rest unknown, and 600 candidate states."""
    sc = load_scenario()
    kin = RobotKinematics(sc.robot.urdf)
    omap = OccupancyMap.for_scenario(sc)
    c = omap.spec.centers()
    ctr = np.array([0.0, 0.0, 0.55])
    r = np.linalg.norm(c - ctr, axis=-1)
    lo = np.zeros(omap.spec.dims, np.float32)
    front = c[..., 0] < ctr[0]
    lo[front & (r > 0.14)] = -2.0
    lo[front & (np.abs(r - 0.12) < 0.015)] = 2.0
    omap = OccupancyMap(omap.spec, omap.model, lo)
    sc.planner.n_candidates = 600
    q = StateSampler(sc, kin).generate(np.random.default_rng(4))[0]
    return sc, kin, omap, q


@pytest.mark.parametrize("overlap_h", [0.0, None])
def test_coarse_to_fine_ranking_has_an_exact_head_and_culls_only_views_that_score_nothing(ball_scene, overlap_h):
    sc, kin, omap, q = ball_scene
    sc.planner.metric, sc.planner.evaluator.coarse_stride, sc.planner.evaluator.refine = "coverage", None, None
    exact_ev = ViewEvaluator(kin, sc)
    score = ranking_score(exact_ev, omap, "coverage", overlap_h, omap.unknown_count())
    exact = exact_ev.evaluate(omap, q)
    met0, order0 = exact_ev.evaluate_ranked(omap, q, score)
    np.testing.assert_array_equal(met0, exact)  # off: every view at ray_stride, the exact ranking
    np.testing.assert_array_equal(order0, np.argsort(-score(exact), kind="stable"))

    sc.planner.evaluator.coarse_stride = 6
    ev = ViewEvaluator(kin, sc)
    met, order = ev.evaluate_ranked(omap, q, score)
    assert sorted(order) == list(range(len(q)))
    head = order[:sc.planner.top_k]
    np.testing.assert_array_equal(met[head], exact[head])  # the head is evaluated exactly
    s_exact = score(exact)
    assert s_exact[head[0]] == s_exact.max()  # the best view is found
    culled = ~ev.may_score(omap, kin.camera_poses(q), score.surface_margin)
    assert culled.sum() > 0.1 * len(q)
    assert np.all(s_exact[culled] == 0) and np.all(met[culled] == 0)
    # the ORT's distance factor keeps the culling and the per-ray pass
    g = scaled_score(score, np.full(len(q), 0.5))
    assert g.surface_margin == score.surface_margin and g.per_ray
    np.testing.assert_allclose(g(exact), 0.5 * s_exact)


@pytest.mark.parametrize("seed", range(3))
def test_the_rays_towards_known_surface_alone_give_its_coverage_gain_and_overlap(seed):
    # roi_margin: only the rays towards the occupied voxels' box (grown by the near-surface
    # reach) are traced, up to where they leave it; the unknown voxels near surface lie in it
    from scipy import ndimage
    rng = np.random.default_rng(400 + seed)
    dims = (24, 22, 18)
    lo = np.full(dims, -1.5, np.float32)
    lo[11:20, 5:19, 4:16] = 0.0  # unknown space behind the front of the object
    occ = np.zeros(dims, bool)
    occ[10:14, 9:15, 7:12] = rng.random((4, 6, 5)) < 0.5
    lo[occ] = 1.2
    near = (ndimage.distance_transform_edt(~occ) <= 2.0) & (lo == 0.0)
    res, bmin = 0.1, np.zeros(3)
    dens = rng.uniform(0.0, 3e4, dims).astype(np.float32)
    o = np.array([-0.6, 1.2, 0.95]) + rng.uniform(-0.05, 0.05, 3)  # looking along +x at the object
    d_cam = np.c_[rng.normal(0.0, 0.2, size=(300, 2)), np.ones(300)]  # in front of the camera (+z)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    R = np.array([[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])  # camera z along world x
    t_near, t_far = np.full(len(d_cam), 0.05), np.full(len(d_cam), 4.0)
    args = (lo, bmin, res, o[None], R, d_cam, t_near, t_far, L_FREE, L_OCC, 1)
    kw = dict(surface_q=0.07, density=dens, cov_k=np.pi * 9e-6, pitch=0.004, stride=2, near=near, near_q=0.2)
    full = VM.evaluate_views(*args, **kw)[0]
    roi = VM.evaluate_views(*args, **kw, score_only=True, roi_margin=2.0)[0]
    assert full[VM.M_OC_RAYS] > 0 and full[VM.M_COVER_GAIN] > 0
    assert roi[VM.M_RAYS] < full[VM.M_RAYS]  # some rays were not traced
    for m in (VM.M_OC_RAYS, VM.M_COVER_GAIN, VM.M_RSV):
        assert roi[m] == pytest.approx(full[m], rel=1e-9, abs=1e-12), m
