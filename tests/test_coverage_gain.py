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
