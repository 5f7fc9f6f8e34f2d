"""The "coverage" information term (view_metrics.M_COVER_GAIN): the covered surface area a
view is expected to add, for a wall of known surface and for unknown space, against the
closed form of the sampling model (a patch at sample density D is covered for the share
1 - exp(-pi r^2 D); a ray landing at range t samples stride^2 (pitch t)^2 of it at density
1 / (pitch t)^2)."""
import math

import numpy as np
import pytest

from nbvs_drake.mapping import view_metrics as K
from nbvs_drake.mapping.occupancy import logit

RES = 0.02
DIMS = (40, 21, 21)
L_FREE, L_OCC = logit(0.45), logit(0.55)
PITCH, STRIDE, R_COV = 0.0043, 2, 0.003
COV_K = math.pi * R_COV ** 2
# the camera looks along world +x at the voxel row j = k = 10 (centres at 0.21 m)
R_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns: camera x, y, z


def _rays(n=3, spread=0.002):
    a = np.linspace(-spread, spread, n)
    d = np.array([[u, v, 1.0] for v in a for u in a])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d, np.full(len(d), 0.05), np.full(len(d), 5.0)


def _gain(logodds, x_cam, density, surface_q=0.0):
    dirs, tn, tf = _rays()
    m = K.evaluate_views(logodds.astype(np.float32), np.zeros(3), RES, np.array([[x_cam, 0.21, 0.21]]),
                         R_CAM[None].copy(), dirs, tn, tf, L_FREE, L_OCC, 1, 2, False, surface_q,
                         density.astype(np.float32), COV_K, PITCH, STRIDE)[0]
    return m, len(dirs)


def _closed_form(t, density):
    s2 = (PITCH * t) ** 2
    return STRIDE ** 2 * s2 * (math.exp(-COV_K * density) - math.exp(-COV_K * (density + 1.0 / s2)))


def _wall():
    lo = np.full(DIMS, -2.0)
    lo[30:] = 0.0  # unknown behind the wall
    lo[30] = 2.0  # the wall: occupied voxels at x in [0.60, 0.62]
    return lo


@pytest.mark.parametrize("x_cam", [0.11, 0.31])
def test_known_wall_gain_matches_the_closed_form(x_cam):
    t = 0.61 - x_cam  # the wall voxels' centres
    lo, dens = _wall(), np.zeros(DIMS)
    m, n = _gain(lo, x_cam, dens)
    assert m[K.M_OC_RAYS] == n
    assert m[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(t, 0.0), rel=1e-9)
    # sampled before at the density of this view: what it adds is the step to twice that
    d1 = 1.0 / (PITCH * t) ** 2
    dens[30] = d1
    m2, _ = _gain(lo, x_cam, dens)
    assert m2[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(t, d1), rel=1e-9)
    assert 0 < m2[K.M_COVER_GAIN] < m[K.M_COVER_GAIN]
    # sampled densely already: nothing to gain
    dens[30] = 1e9
    assert _gain(lo, x_cam, dens)[0][K.M_COVER_GAIN] == pytest.approx(0.0, abs=1e-15)


def test_a_nearer_view_gains_more_on_sparsely_sampled_surface():
    """The wall seen so far from 1 m: a view from 0.3 m adds more covered area than another from 1 m."""
    lo, dens = _wall(), np.zeros(DIMS)
    dens[30] = 1.0 / (PITCH * 1.0) ** 2
    near, _ = _gain(lo, 0.31, dens)
    far, _ = _gain(lo, 0.11, dens)
    # per ray, each view samples stride^2 (pitch t)^2 of the wall: compare per unit area
    per_area = [m[K.M_COVER_GAIN] / (STRIDE ** 2 * (PITCH * t) ** 2) for m, t in ((near, 0.30), (far, 0.50))]
    assert per_area[0] > per_area[1] > 0


def test_unknown_space_gains_its_expected_share_of_new_surface():
    lo = np.full(DIMS, -2.0)
    lo[30:] = 0.0  # ten unknown voxels along each ray, then the map ends
    q = 0.2
    m, n = _gain(lo, 0.11, np.zeros(DIMS), surface_q=q)
    e = 1.0 - (1.0 - q) ** 10
    assert m[K.M_NEW_EXPECTED] == pytest.approx(n * e)
    assert m[K.M_COVER_GAIN] == pytest.approx(n * e * _closed_form(0.50, 0.0), rel=1e-9)
    # without a density grid the column stays 0 (the other metrics do not pay for it)
    dirs, tn, tf = _rays()
    plain = K.evaluate_views(lo.astype(np.float32), np.zeros(3), RES, np.array([[0.11, 0.21, 0.21]]),
                             R_CAM[None].copy(), dirs, tn, tf, L_FREE, L_OCC, 1, 2, False, q)[0]
    assert plain[K.M_COVER_GAIN] == 0.0
    np.testing.assert_array_equal(plain[: K.M_COVER_GAIN], m[: K.M_COVER_GAIN])


def test_sample_density_is_the_local_density_of_the_samples_on_an_oblique_surface():
    """Points spread at random at D = 40,000 per m^2 (one per 5 x 5 mm) over a plane tilted
    across the voxel grid: every voxel the plane crosses with enough points, slivers at its
    corners included, gets about D (the points per voxel face miss it by more than 60 % in a
tenth of the same voxels);
    voxels without points stay 0, as do points outside the grid."""
    from nbvs_drake.config import Scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.planning.views import sample_density
    sc = Scenario()
    m0 = OccupancyMap.for_scenario(sc)
    rng = np.random.default_rng(0)
    D, side = 40_000.0, 0.2
    n = int(D * side * side)
    u, v = rng.uniform(0, side, n), rng.uniform(0, side, n)
    e1, e2 = np.array([1.0, 0.3, 0.4]), np.array([-0.2, 1.0, 0.5])
    e1 /= np.linalg.norm(e1)
    e2 -= e1 * (e1 @ e2)
    e2 /= np.linalg.norm(e2)
    pts = m0.spec.bmin + 0.2 + u[:, None] * e1 + v[:, None] * e2
    pts = np.concatenate([pts, [[99.0, 99.0, 99.0]]])
    m = OccupancyMap(m0.spec, m0.model, object_points=pts.astype(np.float32), wbox_min=m0.wbox_min,
                     wbox_max=m0.wbox_max)
    d = sample_density(m)
    assert d.shape == m0.spec.dims and d.dtype == np.float32
    idx, inside = m0.spec.voxel_index(pts)
    counts = np.zeros(m0.spec.dims, int)
    np.add.at(counts, tuple(idx[inside].T), 1)
    # voxels away from the patch's border (whose points miss neighbours on one side)
    centre = m0.spec.bmin + (np.indices(m0.spec.dims).reshape(3, -1).T + 0.5) * m0.spec.res
    rel = centre - (m0.spec.bmin + 0.2)
    a, b = rel @ e1, rel @ e2
    interior = ((a > 0.03) & (a < side - 0.03) & (b > 0.03) & (b < side - 0.03)).reshape(m0.spec.dims)
    sel = interior & (counts >= 3)
    assert sel.sum() > 50
    np.testing.assert_allclose(np.median(d[sel]), D, rtol=0.1)
    err = np.abs(d[sel] / D - 1)
    face = np.abs(counts[sel] / m0.spec.res ** 2 / D - 1)  # the points per voxel face: varies with the cut
    assert np.quantile(err, 0.9) < 0.4 and np.quantile(face, 0.9) > 0.6
    assert np.all(d[counts == 0] == 0)
    # the medians over every 9th point (the Kinect's model pixels): the same density, and every
    # voxel with points still gets one, also where none of those falls
    d9 = sample_density(m, thin=9)
    np.testing.assert_allclose(np.median(d9[sel]), D, rtol=0.1)
    assert np.quantile(np.abs(d9[sel] / D - 1), 0.75) < 0.4  # a median of fewer points: noisier
    assert np.all((d9 > 0) == (counts > 0)) and np.all(d9[counts == 0] == 0)



def _wall_behind(unknown):
    """The wall at x = 30 (unknown behind it) seen from x = 0.11 m along free voxels, but for
    the unknown voxels x in range(*unknown)."""
    lo = _wall()
    lo[unknown[0]:unknown[1]] = 0.0
    return lo


def _map(lo):
    from nbvs_drake.config import Scenario
    from nbvs_drake.mapping.occupancy import GridSpec, OccupancyMap, SensorModel
    return OccupancyMap(GridSpec(np.zeros(3), RES, DIMS), SensorModel.from_config(Scenario().mapper),
                        lo.astype(np.float32))


def _gain_near(lo, dens, near, near_q):
    dirs, tn, tf = _rays()
    return K.evaluate_views(lo.astype(np.float32), np.zeros(3), RES, np.array([[0.11, 0.21, 0.21]]),
                            R_CAM[None].copy(), dirs, tn, tf, L_FREE, L_OCC, 1, 2, False, 0.1,
                            dens.astype(np.float32), COV_K, PITCH, STRIDE, near, near_q)[0], len(dirs)


def test_unknown_air_far_from_known_surface_holds_no_new_surface():
    """Rays that reach the known, sampled wall through unknown voxels 10-20 voxels before it
    (outside the frustums of the scans that saw it) cross air: they gain what the wall's
    density leaves. The first model (near None: every unknown voxel alike) counted them as
    returns on new surface at the unknown stretch's range."""
    from nbvs_drake.planning.views import near_surface
    d1 = 1.0 / (PITCH * 1.0) ** 2
    dens = np.zeros(DIMS)
    dens[30] = d1
    lo = _wall_behind((10, 21))
    near, q_near = near_surface(_map(lo))
    # the unknown voxels within 4 of the wall: behind it; of the known ones, the wall and its
    # 4 free layers in front, so q_near = 1/5
    assert not near[:30].any() and near[31:35].all() and not near[35:].any()
    assert q_near == pytest.approx(1 / 5)
    m, n = _gain_near(lo, dens, near, q_near)
    assert m[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(0.50, d1), rel=1e-6)
    old, _ = _gain_near(lo, dens, None, 0.0)
    assert old[K.M_NEW_RAYS] == n
    assert old[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(10.5 * RES - 0.11, 0.0), rel=1e-3)


def test_rays_that_meet_known_surface_from_unknown_space_next_to_it_return_on_new_surface():
    """Unknown voxels right before the wall (x = 24-29; 26-29 lie within reach): the rays
    met the wall from behind, so the unknown stretch holds new surface, from its first voxel
    near the wall."""
    from nbvs_drake.planning.views import near_surface
    dens = np.zeros(DIMS)
    dens[30] = 1e9  # the wall itself is densely sampled: all the gain is new surface
    lo = _wall_behind((24, 30))
    near, q_near = near_surface(_map(lo))
    assert near[26:30].all() and not near[24:26].any()
    m, n = _gain_near(lo, dens, near, q_near)
    assert m[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(26.5 * RES - 0.11, 0.0), rel=1e-3)
    # two near unknown voxels before the wall are a surface's thickness (max_unknown_before_hit): known surface
    lo = _wall_behind((28, 30))
    near, q_near = near_surface(_map(lo))
    assert _gain_near(lo, dens, near, q_near)[0][K.M_COVER_GAIN] == pytest.approx(0.0, abs=1e-15)


def _closed_form_at(t, density, cos):
    a = (PITCH * t) ** 2 / cos
    return STRIDE ** 2 * a * (math.exp(-COV_K * density) - math.exp(-COV_K * (density + 1.0 / a)))


def _facing_gain(normal, d_side, x_cam=0.11):
    """The wall's voxel the rays meet holds one side of surface, sampled at d_side with the
    normal `normal`; every voxel's plain density is 4 * d_side (what one density per voxel
    would say)."""
    from nbvs_drake.planning.views import _BINS
    lo = _wall()
    dens = np.full(DIMS, 4.0 * d_side, np.float32)
    slot = np.full(DIMS, -1, np.int32)
    slot[30, 10, 10] = 0
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    b = int(np.argmax(_BINS @ n))
    fd = np.zeros((1, len(_BINS)), np.float32)
    fn = np.zeros((1, len(_BINS), 4), np.float32)
    fd[0, b], fn[0, b] = d_side, [*n, 5.0]
    dirs, tn, tf = _rays()
    m = K.evaluate_views(lo.astype(np.float32), np.zeros(3), RES, np.array([[x_cam, 0.21, 0.21]]),
                         R_CAM[None].copy(), dirs, tn, tf, L_FREE, L_OCC, 1, 2, False, 0.0,
                         dens, COV_K, PITCH, STRIDE, facing=(slot, fd, fn), facing_cos=-0.25)[0]
    return m[K.M_COVER_GAIN], len(dirs), 0.61 - x_cam


def test_a_ray_gains_over_the_density_of_the_side_it_meets():
    """planner.facing_density: a ray (along +x) that meets the sampled side (normal -x) gains
    over that side's density; one that meets the back of it (normal +x, the unseen side of a
    thin wall) gains as on unsampled surface; a side turned 60 degrees from the ray is met at
    cos 0.5, its samples spread over twice the area."""
    d1 = 1.0 / (PITCH * 0.5) ** 2
    g, n, t = _facing_gain([-1.0, 0.0, 0.0], d1)
    assert g == pytest.approx(n * _closed_form_at(t, d1, 1.0), rel=1e-5)  # rays within 0.002 rad of +x
    g_back, _, _ = _facing_gain([1.0, 0.0, 0.0], d1)
    assert g_back == pytest.approx(n * _closed_form_at(t, 0.0, 1.0), rel=1e-5)
    assert g_back > 2 * g
    g_turned, _, _ = _facing_gain([-0.5, np.sqrt(0.75), 0.0], d1)
    assert g_turned == pytest.approx(n * _closed_form_at(t, d1, 0.5), rel=1e-3)
    # the plain density (4 d1 everywhere) gives the same gain for both sides
    lo, dens = _wall(), np.full(DIMS, 4.0 * d1)
    m, _ = _gain(lo, 0.11, dens)
    assert m[K.M_COVER_GAIN] == pytest.approx(n * _closed_form(t, 4.0 * d1), rel=1e-6)


def test_the_back_side_mode_counts_only_the_unseen_side_as_new():
    """planner.coverage.back_side (bin densities of no column): a ray that meets the sampled
    side, face-on or turned 60 degrees, gains over the voxel's one density and face-on; one
    that meets only the back of the voxel's surface gains as on unsampled surface."""
    from nbvs_drake.planning.views import _BINS
    d1 = 1.0 / (PITCH * 0.5) ** 2
    lo, dens = _wall(), np.full(DIMS, 4.0 * d1, np.float32)
    dirs, tn, tf = _rays()
    n, t = len(dirs), 0.61 - 0.11

    def gain(normal):
        slot = np.full(DIMS, -1, np.int32)
        slot[30, 10, 10] = 0
        nv = np.asarray(normal, float) / np.linalg.norm(normal)
        fn = np.zeros((1, len(_BINS), 4), np.float32)
        fn[0, int(np.argmax(_BINS @ nv))] = [*nv, 5.0]
        return K.evaluate_views(lo.astype(np.float32), np.zeros(3), RES, np.array([[0.11, 0.21, 0.21]]),
                                R_CAM[None].copy(), dirs, tn, tf, L_FREE, L_OCC, 1, 2, False, 0.0, dens, COV_K,
                                PITCH, STRIDE, facing=(slot, np.zeros((1, 0), np.float32), fn),
                                facing_cos=-0.25)[0][K.M_COVER_GAIN]

    seen = n * _closed_form(t, 4.0 * d1)
    assert gain([-1.0, 0.0, 0.0]) == pytest.approx(seen, rel=1e-6)
    assert gain([-0.5, np.sqrt(0.75), 0.0]) == pytest.approx(seen, rel=1e-6)
    assert gain([1.0, 0.0, 0.0]) == pytest.approx(n * _closed_form_at(t, 0.0, 1.0), rel=1e-5)
    assert gain([1.0, 0.0, 0.0]) > 10 * seen


def test_side_normals_bins_each_voxel_like_facing_density():
    """views.side_normals: the same slots and bins as facing_density, no densities."""
    from nbvs_drake.config import Scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.planning.views import facing_density, side_normals
    m0 = OccupancyMap.for_scenario(Scenario())
    rng = np.random.default_rng(2)
    n = 3000
    pts = (np.c_[np.full(n, 0.305), rng.uniform(0, 0.1, n), rng.uniform(0, 0.1, n)] + m0.spec.bmin).astype(np.float32)
    nrm = np.tile(np.float32([-1.0, 0.0, 0.0]), (n, 1))
    m = OccupancyMap(m0.spec, m0.model, object_points=pts, wbox_min=m0.wbox_min, wbox_max=m0.wbox_max,
                     object_normals=nrm)
    slot, tab, norm = side_normals(m)
    fslot, _, fnorm = facing_density(m)
    assert tab.shape == (norm.shape[0], 0)
    np.testing.assert_array_equal(slot, fslot)
    np.testing.assert_allclose(norm, fnorm, atol=1e-6)
    assert side_normals(OccupancyMap(m0.spec, m0.model, object_points=pts)) is None


def test_facing_density_keeps_the_two_sides_of_a_thin_wall_apart():
    """Two sheets 4 mm apart in the same voxels, each sampled at 40,000 per m^2 with normals
    facing away from each other (a thin wall seen from both sides): each voxel gets two bins,
    each of about that density, where one density per voxel (sample_density) sees both
    sheets' points as one surface."""
    from nbvs_drake.config import Scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.planning.views import _BINS, facing_density, sample_density
    m0 = OccupancyMap.for_scenario(Scenario())
    rng = np.random.default_rng(1)
    D, side = 40_000.0, 0.16
    pts, nrm = [], []
    for dx, nx in ((0.0, -1.0), (0.004, 1.0)):
        n = int(D * side * side)
        p = np.c_[np.full(n, 0.305 + dx), rng.uniform(0, side, n), rng.uniform(0, side, n)] + m0.spec.bmin
        pts.append(p)
        nrm.append(np.tile([nx, 0.0, 0.0], (n, 1)))
    pts, nrm = np.concatenate(pts).astype(np.float32), np.concatenate(nrm).astype(np.float32)
    m = OccupancyMap(m0.spec, m0.model, object_points=pts, wbox_min=m0.wbox_min, wbox_max=m0.wbox_max,
                     object_normals=nrm)
    slot, dens, norm = facing_density(m)
    idx, _ = m0.spec.voxel_index(pts)
    interior = (np.abs(pts[:, 1] - m0.spec.bmin[1] - side / 2) < 0.04) & (
        np.abs(pts[:, 2] - m0.spec.bmin[2] - side / 2) < 0.04)
    rows = np.unique(slot[tuple(idx[interior].T)])
    assert len(rows) > 4 and np.all(rows >= 0)
    minus, plus = int(np.argmax(_BINS @ [-1.0, 0, 0])), int(np.argmax(_BINS @ [1.0, 0, 0]))
    for r in rows:
        assert set(np.flatnonzero(norm[r, :, 3] > 0)) == {minus, plus}
        np.testing.assert_allclose(norm[r, minus, :3], [-1.0, 0, 0], atol=1e-6)
    sides = dens[rows][:, [minus, plus]]
    np.testing.assert_allclose(np.median(sides, axis=0), D, rtol=0.1)
    assert np.quantile(np.abs(sides / D - 1), 0.9) < 0.5
    plain = sample_density(m)[tuple(idx[interior].T)]
    assert np.median(plain) > 1.6 * D
    # a map whose points carry no normals has no sides
    assert facing_density(OccupancyMap(m0.spec, m0.model, object_points=pts)) is None


def test_each_scan_keeps_the_normals_of_its_points_towards_the_camera():
    """OccupancyMap.integrate fits each new point's normal within its own scan, turned towards
    the camera; the normals travel with the points through save_npz / load_npz."""
    import tempfile
    from pathlib import Path

    from nbvs_drake.config import Scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    m0 = OccupancyMap.for_scenario(Scenario())
    c = 0.5 * (m0.wbox_min + m0.wbox_max)
    g = np.linspace(-0.05, 0.05, 21)
    pts = np.array([[c[0] + u, c[1] + v, c[2]] for u in g for v in g])  # a horizontal patch
    m1, _ = m0.integrate(c + [0.0, 0.0, 1.0], pts, 0.0)  # seen from above
    m2, _ = m1.integrate(c + [0.0, 0.0, -1.0], pts + [0, 0, 0.004], 0.0)  # and from below
    assert m2.object_normals.shape == m2.object_points.shape
    n = len(pts)
    np.testing.assert_allclose(m2.object_normals[:n], np.tile([0, 0, 1.0], (n, 1)), atol=1e-5)
    np.testing.assert_allclose(m2.object_normals[n:], np.tile([0, 0, -1.0], (n, 1)), atol=1e-5)
    with tempfile.TemporaryDirectory() as tmp:
        m2.save_npz(Path(tmp) / "m.npz")
        back = OccupancyMap.load_npz(Path(tmp) / "m.npz")
    np.testing.assert_array_equal(back.object_normals, m2.object_normals)
