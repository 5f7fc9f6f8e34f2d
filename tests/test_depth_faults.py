"""The Kinect's structured-light faults (world.sensor.apply_depth_faults, DepthNoise): the
projector's shadow beside a depth step, depths in disparity steps, no return at grazing
incidence, lateral noise at edges, the same seed giving the same image; and on a scan the
real depth camera renders."""
import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.sensors import ImageDepth32F

from nbvs_drake.config import DepthFaults, Scenario, load_scenario, resolve_sensor
from nbvs_drake.systems.depth_camera import DepthNoise
from nbvs_drake.world.sensor import apply_depth_faults, intrinsics, projector_shadow


def _kinect(**faults):
    sc = Scenario()
    sc.sensor.preset = "kinect"
    sc.sensor.faults = DepthFaults(**{**vars(DepthFaults.none()), **faults})
    return sc.sensor


def test_the_kinect_preset_has_its_faults_and_the_sr4000_none():
    sc = Scenario()
    assert not resolve_sensor(sc.sensor).faults.any()
    sc.sensor.preset = "kinect"
    assert resolve_sensor(sc.sensor).faults == DepthFaults()
    # an old Kinect scenario keeps the axial noise alone it had
    from nbvs_drake.config.legacy import migrate
    assert not resolve_sensor(migrate("sensor:\n  preset: kinect\n  noise_a: -1\n").sensor).faults.any()


def test_the_projectors_shadow_lies_beside_a_depth_step_on_the_far_surface():
    """A near surface (1 m) right of a far one (2 m), the projector 7.5 cm to the right: the far
    surface returns nothing over f b (1/z1 - 1/z2) pixels left of the step."""
    sensor = _kinect(baseline_m=0.075)
    w, h, fx = 640, 480, intrinsics(sensor)[2]
    z = np.full((h, w), 2.0)
    z[:, 400:] = 1.0
    out = apply_depth_faults(z, sensor, np.random.default_rng(0))
    width = fx * 0.075 * (1 / 1.0 - 1 / 2.0)  # ~22 px
    row = np.isnan(out[240])
    assert not row[400:].any()  # the near surface is lit
    shadow = np.flatnonzero(row)
    assert shadow.max() == 399 and abs(len(shadow) - width) <= 1.0, (len(shadow), width)
    # the projector on the other side: the shadow moves to the other side of a near object
    z2 = np.full((h, w), 2.0)
    z2[:, 200:300] = 1.0
    left, right = projector_shadow(z2, +fx * 0.075), projector_shadow(z2, -fx * 0.075)
    assert left[:, :200].any() and not left[:, 300:].any()
    assert right[:, 300:].any() and not right[:, :200].any()


def test_depths_come_in_disparity_steps():
    """At 3 m the Kinect's 1/8-pixel disparity steps are z^2 step / (f b) ~ 2.5 cm apart."""
    sensor = _kinect(baseline_m=0.075, disparity_step_px=0.125)
    fx = intrinsics(sensor)[2]
    z = np.linspace(2.9, 3.1, 640)[None, :].repeat(4, axis=0)
    out = apply_depth_faults(z, sensor, np.random.default_rng(0))
    levels = np.unique(np.round(out[np.isfinite(out)], 6))
    step = 3.0 ** 2 * 0.125 / (fx * 0.075)
    assert 0.02 < step < 0.03
    assert len(levels) <= int(0.2 / step) + 2
    assert np.allclose(np.diff(levels), levels[:-1] ** 2 * 0.125 / (fx * 0.075), rtol=0.05)
    assert np.all(np.abs(out - z) <= 0.5 * z ** 2 * 0.125 / (fx * 0.075) * 1.05)  # within half a local step


def test_no_return_at_grazing_incidence():
    """A plane seen obliquely returns nothing where the incidence angle exceeds 80 degrees and
    returns where it is below; a plane seen at 30 degrees returns everywhere."""
    sensor = _kinect(grazing_deg=80.0)
    w, h, fx, fy, cx, cy = intrinsics(sensor)
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    X, Y = (uu - cx) / fx, (vv - cy) / fy

    def plane(deg):  # the plane through (0, 0, 2) with its normal tilted by deg about y; the true incidence
        n = np.array([np.sin(np.radians(deg)), 0.0, -np.cos(np.radians(deg))])
        den = n[0] * X + n[1] * Y + n[2]
        t = (n @ [0, 0, 2.0]) / den
        inc = np.degrees(np.arccos(np.abs(den) / np.sqrt(X ** 2 + Y ** 2 + 1)))
        return np.where(t > 0, t, np.inf), inc
    z, inc = plane(80.0)
    out = apply_depth_faults(z, sensor, np.random.default_rng(0))
    inner = np.zeros(z.shape, bool)
    inner[2:-2, 2:-2] = True
    steep, mild = inner & np.isfinite(z) & (inc > 81), inner & np.isfinite(z) & (inc < 79)
    assert steep.sum() > 1000 and mild.sum() > 1000
    assert np.isnan(out[steep]).mean() > 0.95 and np.isnan(out[mild]).mean() < 0.05
    z30, _ = plane(30.0)
    assert not np.isnan(apply_depth_faults(z30, sensor, np.random.default_rng(0))[inner]).any()


def test_lateral_noise_frays_edges_and_the_same_seed_gives_the_same_image():
    sensor = _kinect(lateral_px=0.8, lateral_gain=0.035)
    z = np.full((480, 640), 2.0)
    z[:, 320:] = 1.0
    a = apply_depth_faults(z, sensor, np.random.default_rng([3, 12, 5]))
    b = apply_depth_faults(z, sensor, np.random.default_rng([3, 12, 5]))
    c = apply_depth_faults(z, sensor, np.random.default_rng([4, 12, 5]))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert set(np.unique(a)) <= {1.0, 2.0}  # depths move sideways, not in depth
    changed = a != z
    assert changed[:, 314:326].any() and not changed[:, :300].any() and not changed[:, 340:].any()


def _noisy(sensor, seed, z):
    image = ImageDepth32F(z.shape[1], z.shape[0])
    image.mutable_data[:] = z[:, :, None].astype(np.float32)
    noise = DepthNoise(sensor, seed, 0.1)
    ctx = noise.CreateDefaultContext()
    noise.GetInputPort("depth_image").FixValue(ctx, AbstractValue.Make(image))
    return np.array(noise.GetOutputPort("depth_image").Eval(ctx).data)[:, :, 0]


def test_depth_noise_gives_the_kinect_its_faults_reproducibly():
    """DepthNoise applies the preset's faults after the axial noise; no return is NaN (never
    free space), a pixel without a return before stays +inf; the same seed, the same image."""
    sc = Scenario()
    sc.sensor.preset = "kinect"
    z = np.full((480, 640), 2.0)
    z[:, 400:] = 1.0
    z[0, 0] = np.inf
    out = _noisy(sc.sensor, 3, z)
    assert np.isposinf(out[0, 0]) and np.isnan(out[240, 380:399]).all()
    np.testing.assert_array_equal(out, _noisy(sc.sensor, 3, z))


@pytest.mark.parametrize("x", [-1.45])
def test_a_rendered_kinect_scan_has_the_faults(tmp_path, x):
    """The default scene rendered by the real depth camera (RgbdSensor + VTK) with the Kinect:
    the object's silhouette casts a projector shadow (NaN on the table beside it), and its
    returns stay within the disparity steps of the exact rendering."""
    from nbvs_drake.perception.scanning import ScanRenderer
    exact = load_scenario(settings=["sensor.preset=kinect", "sensor.noise_a=0.0", "sensor.noise_b=0.0",
                                    "sensor.faults={baseline_m: 0.0, disparity_step_px: 0.0, lateral_px: 0.0, "
                                    "lateral_gain: 0.0, grazing_deg: 90.0}"])
    faulty = load_scenario(settings=["sensor.preset=kinect"])
    q = np.array(exact.robot.start)
    z0 = ScanRenderer(exact, tmp_path / "a").depth(q)
    z1 = ScanRenderer(faulty, tmp_path / "b").depth(q)
    lit0, lit1 = np.isfinite(z0) & (z0 > 0), np.isfinite(z1) & (z1 > 0)
    assert lit0.sum() > 10000
    assert np.isnan(z1[lit0]).sum() > 200  # shadows and grazing dropouts where the exact image has a surface
    assert not np.isnan(z0).any()
    # every return lies on a disparity step: f b / z is a multiple of 1/8 pixel
    fb = intrinsics(faulty.sensor)[2] * 0.075
    steps = fb / z1[lit1].astype(np.float64) / 0.125
    assert np.abs(steps - np.rint(steps)).max() < 1e-2  # float32 depths
