"""The planner's sensor model is the sensor's: what the view evaluation predicts for a robot
state is what the rendered camera (RgbdSensor, DepthRange(z_near, z_far)) then returns.
The map is the default scene's after the real first scan (conftest.first_scan_map); the
scans are rendered by ScanRenderer at the same states."""
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from nbvs_drake.config import SensorConfig, resolve_sensor
from nbvs_drake.mapping import view_metrics as K
from nbvs_drake.mapping.voxel import OCCUPIED
from nbvs_drake.perception.evaluation import BLIND_SCAN_POINTS
from nbvs_drake.world.sensor import intrinsics, ray_directions

#: the camera 0.245 m from the teapot's known front surface (along its optical axis), with
#: the surface filling the view: nearer than the SR4000's 0.4 m minimum range
Q_NEAR = [-1.11, 0.059, 0.008, -0.19, 0.171, -1.033, 0.493, -0.02]
#: the camera 0.725 m from the known surface (the planner's working range)
Q_FAR = [-1.417, -0.065, -0.28, 0.312, 1.558, -1.544, -0.364, -2.485]


@pytest.fixture(scope="module")
def scene(first_scan_map, kin):
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.planning.views import ViewEvaluator
    sc, omap = first_scan_map
    with tempfile.TemporaryDirectory() as tmp:
        renderer = ScanRenderer(sc, Path(tmp), kin)
    return sc, omap, renderer, {a: ViewEvaluator(kin, sc, hrt_a=a) for a in (0, 2)}


def _axis_depth_to_known_surface(omap, X, t_max=1.5):
    """Distance along the optical axis to the first occupied voxel (inf: none)."""
    ts = np.arange(0.0, t_max, 0.002)
    idx = np.floor((X[:3, 3] + ts[:, None] * X[:3, 2] - omap.spec.bmin) / omap.spec.res).astype(int)
    inside = np.all((idx >= 0) & (idx < np.array(omap.spec.dims)), axis=1)
    cls = omap.classes()
    hit = [t for t, i, ok in zip(ts, idx, inside) if ok and cls[tuple(i)] == OCCUPIED]
    return hit[0] if hit else math.inf


def _object_points(sc, omap, renderer, q):
    scan = renderer.scan(np.asarray(q, float))
    return int(omap.object_mask(scan.points, sc.mapper.table_clearance).sum())


def test_camera_nearer_than_the_minimum_range_predicts_and_gets_nothing(scene, kin):
    sc, omap, renderer, evaluators = scene
    z_near = resolve_sensor(sc.sensor).z_near
    d = _axis_depth_to_known_surface(omap, kin.camera_poses(np.array(Q_NEAR))[0])
    assert 0.2 < d < z_near  # the premise: the known surface is ~0.25 m ahead
    for a, ev in evaluators.items():
        m = ev.evaluate(omap, np.array(Q_NEAR))[0]
        n_rays = len(ev.dirs)
        # the known surface within the minimum range blinds the rays (about half the image;
        # the rest sees past the teapot's silhouette into air): ~no return predicted on the
        # map (on known or new surface), no known surface overlapped
        assert m[K.M_BLIND_RAYS] > 0.45 * n_rays, a
        assert m[K.M_OC_RAYS] + m[K.M_NEW_EXPECTED] < 0.02 * n_rays, (a, m)
        assert m[K.M_OC_RAYS] == 0 and m[K.M_OC_O] == 0, (a, m)
    # and the camera returns no object point there
    assert _object_points(sc, omap, renderer, Q_NEAR) < BLIND_SCAN_POINTS


def test_camera_at_the_working_range_predicts_and_gets_returns(scene, kin):
    sc, omap, renderer, evaluators = scene
    d = _axis_depth_to_known_surface(omap, kin.camera_poses(np.array(Q_FAR))[0])
    assert 0.65 < d < 0.8
    for a, ev in evaluators.items():
        m = ev.evaluate(omap, np.array(Q_FAR))[0]
        n_rays = len(ev.dirs)
        assert m[K.M_OC_RAYS] > 0.05 * n_rays and m[K.M_OC_O] > 50, (a, m)  # the known surface, overlapped
        assert m[K.M_UN_O] > 50, (a, m)
    n_obj = _object_points(sc, omap, renderer, Q_FAR)
    assert n_obj > 1000
    # the share of the image on the known surface is about the share of rays predicted on it
    w, h = resolve_sensor(sc.sensor).width, resolve_sensor(sc.sensor).height
    m = evaluators[0].evaluate(omap, np.array(Q_FAR))[0]
    assert n_obj / (w * h) == pytest.approx(m[K.M_OC_RAYS] / len(evaluators[0].dirs), abs=0.05)


def _look_along(o, forward, up=(0.0, 0.0, 1.0)):
    """Camera pose X_WC at o looking along `forward` (+z), +y down."""
    z = np.asarray(forward, float) / np.linalg.norm(forward)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.stack([x, y, z], axis=1)
    X[:3, 3] = o
    return X


def test_camera_inside_wbox_next_to_unknown_space_predicts_nothing_behind_it(scene):
    sc, omap, _, evaluators = scene
    # low behind the teapot (in the first scan's shadow: unknown), looking back at it
    X_in = _look_along([0.25, 0.0, 0.55], [-1.0, 0.0, 0.0])
    X_out = _look_along([1.0, 0.0, 0.55], [-1.0, 0.0, 0.0])  # 0.56 m outside the map
    idx = np.floor((X_in[:3, 3] - omap.spec.bmin) / omap.spec.res).astype(int)
    assert omap.classes()[tuple(idx)] != OCCUPIED and omap.in_wbox()[tuple(idx)]
    from nbvs_drake.planning.views import ViewEvaluator
    conservative = {a: ViewEvaluator(evaluators[0].kin, sc, hrt_a=a, near_unknown_blinds=True) for a in (0, 2)}
    for a, ev in conservative.items():
        inside, outside = ev.evaluate_poses(omap, np.stack([X_in, X_out]))
        # the conservative rule: the unknown voxels within the minimum range may hold a surface,
        # so nothing is predicted behind them
        assert inside[K.M_BLIND_RAYS] > 0.9 * len(ev.dirs), a
        for col in (K.M_UN_O, K.M_OC_O, K.M_FIG, K.M_SIG, K.M_N_POSTERIOR, K.M_OC_RAYS, K.M_UN_RAYS, K.M_RSV):
            assert inside[col] < 0.02 * outside[col] + 1e-9 or inside[col] == 0, (a, col, inside[col])
        # from outside the minimum range the same unknown space is seen
        assert outside[K.M_BLIND_RAYS] == 0 and outside[K.M_UN_O] > 100, (a, outside)
    # the default (only known surface blinds: the unknown space near a camera is nearly always
    # air the early scans have not cleared): the unknown space beyond the minimum range counts
    # from inside too, and the rays that cross it to the known surface behind are returns on
    # new surface (expected)
    relaxed = evaluators[0].evaluate_poses(omap, X_in[None])[0]
    assert relaxed[K.M_UN_O] > 20 and relaxed[K.M_NEW_EXPECTED] > 0


@pytest.mark.parametrize("preset", ["sr4000", "kinect"])
@pytest.mark.parametrize("stride", [1, 2, 3, 5])
def test_rays_are_the_sensors_pixel_grid_field_of_view_and_depth_range(preset, stride):
    sensor = SensorConfig(preset=preset)
    s = resolve_sensor(sensor)
    w, h, fx, fy, cx, cy = intrinsics(sensor)
    d, tn, tf = ray_directions(sensor, stride)
    nu, nv = -(-w // stride), -(-h // stride)
    assert d.shape == (nu * nv, 3) and K.ray_grid_width(d) == nu
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    u = d[:, 0] / d[:, 2] * fx + cx  # pixel coordinates of the rays (centres at integers)
    v = d[:, 1] / d[:, 2] * fy + cy
    for p, n in ((u, w), (v, h)):
        lo, hi = p.min(), p.max()
        assert lo > -0.5 and hi < n - 0.5  # inside the image (its edges are the FOV)
        assert lo <= (stride - 1) / 2 + 1e-9 and hi >= n - 1 - (stride - 1) / 2 - 1e-9  # keeps its edges
        assert lo == pytest.approx(n - 1 - hi)  # symmetrically
    if stride == 1:  # every pixel centre, as DepthImageToPointCloud back-projects it
        uu, vv = np.meshgrid(np.arange(w), np.arange(h))
        np.testing.assert_allclose(u, uu.ravel(), atol=1e-9)
        np.testing.assert_allclose(v, vv.ravel(), atol=1e-9)
    # the image's edge (half a pixel beyond the outer centres) is the field of view
    assert 2 * math.degrees(math.atan((w / 2) / fx)) == pytest.approx(s.fov_x_deg)
    assert 2 * math.degrees(math.atan((h / 2) / fy)) == pytest.approx(s.fov_y_deg)
    # the depth range along each ray
    np.testing.assert_allclose(tn * d[:, 2], s.z_near)
    np.testing.assert_allclose(tf * d[:, 2], s.z_far)


def test_the_view_evaluator_uses_the_sensors_rays(kin):
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.views import ViewEvaluator
    sc = load_scenario()
    ev = ViewEvaluator(kin, sc)
    d, tn, tf = ray_directions(sc.sensor, sc.planner.evaluator.stride)
    np.testing.assert_array_equal(ev.dirs, d)
    np.testing.assert_array_equal(ev.t_near, tn)
    np.testing.assert_array_equal(ev.t_far, tf)


def test_the_coarse_pass_counts_its_stride_in_the_sensors_coarse_blocks(kin):
    """planner.evaluator.coarse_stride 6: the SR4000's coarse rays every 6 pixels, the
    Kinect's every 18 (sensor.coarse_binning 3; its fine rays every 2 x 3 model pixels), its
    second look every 12 (recheck_binning 2); the SR4000 has none."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.planning.views import ViewEvaluator
    sr, kinect = load_scenario(), load_scenario(settings=["sensor.preset=kinect"])
    assert sr.planner.coarse_stride() == kinect.planner.coarse_stride() == 6
    ev_sr, ev_k = ViewEvaluator(kin, sr), ViewEvaluator(kin, kinect)
    assert (ev_sr.stride, ev_sr.coarse_stride, ev_sr.recheck) == (2, 6, None)
    assert (ev_k.stride, ev_k.coarse_stride, ev_k.recheck_stride) == (6, 18, 12)
    np.testing.assert_array_equal(ev_k.coarse[0], ray_directions(kinect.sensor, 18)[0])
    np.testing.assert_array_equal(ev_k.recheck[0], ray_directions(kinect.sensor, 12)[0])
    custom = load_scenario(settings=["sensor.preset=kinect", "sensor.coarse_binning=2", "sensor.recheck_binning=0"])
    ev_c = ViewEvaluator(kin, custom)
    assert (ev_c.coarse_stride, ev_c.recheck) == (12, None)


def test_the_second_look_finds_the_views_whose_coarse_rays_missed_the_known_surface(kin, first_scan_map):
    """The Kinect's coarse pass (one ray per 18 x 18 pixels) misses slivers of known surface
    between its rays: a view that sees a little of it scores 0 under the registration filter
    (overlap > 0). The second look (12 x 12) evaluates again the views whose coarse rays came
    near known surface without landing on it: against every pixel's rays (stride 1), it only
    adds views that pass the filter, and fewer of those that do stay at 0."""
    import copy

    from nbvs_drake.planning.candidates import StateSampler
    from nbvs_drake.planning.views import ViewEvaluator, ranking_score
    sc, omap = first_scan_map
    sc = copy.deepcopy(sc)
    sc.sensor.preset = "kinect"
    sc.planner.n_candidates = 600
    q = StateSampler(sc, kin).generate(np.random.default_rng(3))[0]
    with_look = ViewEvaluator(kin, sc)
    plain_sc = copy.deepcopy(sc)
    plain_sc.sensor.recheck_binning = 0
    plain = ViewEvaluator(kin, plain_sc)
    assert with_look.recheck is not None and plain.recheck is None
    score = ranking_score(with_look, omap, sc.planner.metric, sc.planner.overlap_h, max(omap.unknown_count(), 1))
    full = score(ViewEvaluator(kin, sc, stride=1).evaluate(omap, q)) > 0
    a = score(with_look.evaluate_ranked(omap, q, score)[0]) > 0
    b = score(plain.evaluate_ranked(omap, q, score)[0]) > 0
    assert not (a & ~full).any() and not (b & ~full).any()  # the coarse rays are pixels' rays
    assert not (b & ~a).any()  # the second look only adds
    assert (a & ~b).sum() >= 3, (a & ~b).sum()
    assert (full & ~a).sum() < (full & ~b).sum()
