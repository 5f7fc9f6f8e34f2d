"""Depth sensor model shared by the rendered camera (RgbdSensor) and the planner's simulated
scans (the ray directions of the view-evaluation kernel)."""

from __future__ import annotations

import math

import numpy as np

from ..config import SensorConfig, resolve_sensor


def intrinsics(sensor: SensorConfig) -> tuple[int, int, float, float, float, float]:
    """(width, height, fx, fy, cx, cy) of the pinhole model with the sensor's FOV."""
    s = resolve_sensor(sensor)
    fx = s.width / 2.0 / math.tan(math.radians(s.fov_x_deg) / 2.0)
    fy = s.height / 2.0 / math.tan(math.radians(s.fov_y_deg) / 2.0)
    return s.width, s.height, fx, fy, (s.width - 1) / 2.0, (s.height - 1) / 2.0


def camera_info(sensor: SensorConfig):
    """The intrinsics in pixel-index coordinates (pixel (u, v)'s centre at (u, v)), as
    DepthImageToPointCloud back-projects: x = (u - cx) z / fx."""
    from pydrake.systems.sensors import CameraInfo
    w, h, fx, fy, cx, cy = intrinsics(sensor)
    return CameraInfo(w, h, fx, fy, cx, cy)


def render_camera_info(sensor: SensorConfig):
    """The same camera for the renderer. RenderEngineVtk places the principal point in
    image-plane coordinates whose origin is the top-left *corner* (pixel u's centre at u + 0.5),
    while DepthImageToPointCloud takes it in pixel-index coordinates. Handing both the same
    CameraInfo shifts every ray by half a pixel (2.3 mrad on the SR4000: a plane 1 m away
    comes back tilted by ~2-3 mm, differently for every view, which no registration can
    undo); measured with pydrake 1.51.1 and guarded by tests/test_depth_camera.py."""
    from pydrake.systems.sensors import CameraInfo
    w, h, fx, fy, cx, cy = intrinsics(sensor)
    return CameraInfo(w, h, fx, fy, cx + 0.5, cy + 0.5)


def ray_directions(sensor: SensorConfig, stride: int = 1):
    """Unit ray directions in the camera frame (+z forward, +x right, +y down), row by row, and
    each ray's [t_near, t_far] (the sensor's depth range z_near..z_far along the ray: a surface
    at depth below z_near returns nothing). stride 1: through every pixel centre. stride n:
    one ray per n x n pixel block, through the block's centre; the ceil(w / n) x ceil(h / n)
    blocks are centred on the image, so the outermost rays lie within (n - 1) / 2 pixels of
    the outermost pixel centres on every side (the field of view keeps its edges, symmetrically,
    also when n does not divide the image; for an n that divides it, the blocks tile it)."""
    s = resolve_sensor(sensor)
    w, h, fx, fy, cx, cy = intrinsics(sensor)
    nu, nv = -(-w // stride), -(-h // stride)
    u = cx + (np.arange(nu) - (nu - 1) / 2.0) * stride
    v = cy + (np.arange(nv) - (nv - 1) / 2.0) * stride
    uu, vv = np.meshgrid(u, v)
    d = np.stack([(uu.ravel() - cx) / fx, (vv.ravel() - cy) / fy, np.ones(uu.size)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.ascontiguousarray(d), s.z_near / d[:, 2], s.z_far / d[:, 2]


def axial_noise_sigma(sensor: SensorConfig, z: np.ndarray) -> np.ndarray:
    """sigma_z = a + b (z - 0.4)^2 (Kinect model of Nguyen et al. 2012; zero for the ToF preset)."""
    s = resolve_sensor(sensor)
    return s.noise_a + s.noise_b * (np.asarray(z) - 0.4) ** 2


def noisy_depth(z: np.ndarray, sensor: SensorConfig, seed: int, step: int) -> np.ndarray:
    """The depth image (h, w) the sensor returns for the exact depth z (metres; +-inf or 0
    where nothing returns): its axial noise (`axial_noise_sigma`, drawn from the generator of
    (seed, 11, step)), then its faults (`apply_depth_faults`, from (seed, 12, step)). The
    camera's DepthNoise system and the view sphere (nbvs_drake.gym) both return this."""
    z = np.array(z, np.float64)
    finite = np.isfinite(z) & (z > 0)  # 0: too close, no return (as +inf: too far)
    if np.any(axial_noise_sigma(sensor, np.array([0.4, 5.0])) > 0):
        rng = np.random.default_rng([seed, 11, step])
        dz = rng.normal(0.0, 1.0, z.shape) * axial_noise_sigma(sensor, np.where(finite, z, 0.4))
        z = np.where(finite, z + dz, z)
    if resolve_sensor(sensor).faults.any():
        z = apply_depth_faults(z, sensor, np.random.default_rng([seed, 12, step]))
    return z


def apply_depth_faults(z: np.ndarray, sensor: SensorConfig, rng: np.random.Generator) -> np.ndarray:
    """A structured-light sensor's faults (`DepthFaults`) applied to a depth image z (h, w),
    metres, after its axial noise; returns a new image. Pixels that return nothing become NaN
    (no return, but not free space either: a surface is there), except those that had no
    return already (+-inf, NaN), which stay as they are.

    - Lateral noise (Nguyen, Izadi & Lovell 2012): each pixel takes the depth of the pixel
      sigma_L pixels off, sigma_L = lateral_px + lateral_gain theta / (pi/2 - theta) at the
      surface's incidence angle theta (normals from the image's neighbours).
    - Grazing incidence: no return where theta > grazing_deg.
    - The projector's shadow: the projector sits baseline_m along the image's +x; a pixel whose
      projector ray passes behind a nearer surface of its row (its projector column
      u - f b / z above the least of those of the pixels towards the projector) returns nothing.
    - Disparity steps (Khoshelham & Elberink 2012): the disparity f b / z is rounded to
      disparity_step_px, so depth comes in steps of about z^2 step / (f b)."""
    faults = resolve_sensor(sensor).faults
    z = np.array(z, np.float64)
    if not faults.any():
        return z
    h, w = z.shape
    _, _, fx, fy, cx, cy = intrinsics(sensor)
    valid = np.isfinite(z) & (z > 0)
    lateral = bool(faults.lateral_px or faults.lateral_gain)
    if lateral or faults.grazing_deg < 90.0:
        theta = np.nan_to_num(incidence_angles(z, fx, fy, cx, cy), nan=0.0)
    out = z.copy()
    if lateral:
        th = np.clip(theta, 0.0, np.radians(89.0))
        sig = faults.lateral_px + faults.lateral_gain * th / (np.pi / 2 - th)
        du = np.rint(rng.normal(0.0, 1.0, z.shape) * sig).astype(int)
        dv = np.rint(rng.normal(0.0, 1.0, z.shape) * sig).astype(int)
        vv, uu = np.mgrid[0:h, 0:w]
        src = z[np.clip(vv + dv, 0, h - 1), np.clip(uu + du, 0, w - 1)]
        out = np.where(valid, src, z)
        out = np.where(valid & ~(np.isfinite(out) & (out > 0)), np.nan, out)
    drop = np.zeros(z.shape, bool)
    if faults.grazing_deg < 90.0:
        drop |= valid & (theta > np.radians(faults.grazing_deg))
    fb = fx * faults.baseline_m
    if fb:
        drop |= valid & projector_shadow(z, fb)
    if faults.disparity_step_px and fb:  # the disparity f b / z needs a baseline
        ok = np.isfinite(out) & (out > 0)
        d = np.where(ok, abs(fb) / np.where(ok, out, 1.0), 0.0)
        dq = np.maximum(np.rint(d / faults.disparity_step_px), 1.0) * faults.disparity_step_px
        out = np.where(ok, abs(fb) / dq, out)
    out[drop] = np.nan
    return out


def incidence_angles(z: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The angle (rad) between each pixel's ray and the surface normal estimated from its
    neighbours' back-projected points (central differences); NaN where a neighbour is missing."""
    h, w = z.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    P = np.stack([(uu - cx) / fx * z, (vv - cy) / fy * z, z], axis=-1)
    P = np.where(np.isfinite(P), P, np.nan)
    du = np.full_like(P, np.nan)
    dv = np.full_like(P, np.nan)
    du[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dv[1:-1, :] = P[2:, :] - P[:-2, :]
    n = np.cross(du, dv)
    with np.errstate(invalid="ignore", divide="ignore"):  # zero-depth pixels: NaN, as missing ones
        ray = P / np.linalg.norm(P, axis=-1, keepdims=True)
        c = np.abs(np.sum(n * ray, axis=-1)) / np.linalg.norm(n, axis=-1)
        return np.arccos(np.clip(c, 0.0, 1.0))


def projector_shadow(z: np.ndarray, fb: float) -> np.ndarray:
    """Pixels in the projector's shadow: the projector sits at fb / fx metres along +x (fb > 0)
    or -x; a pixel's projector column is u - fb / z, and along its row the projector lights
    it only when that column does not exceed the least of the columns of the pixels between it
    and the projector (a nearer surface there would block the projector's ray)."""
    h, w = z.shape
    ok = np.isfinite(z) & (z > 0)
    p = np.where(ok, np.arange(w)[None, :] - fb / np.where(ok, z, 1.0), np.inf)
    if fb < 0:  # the projector on the other side: mirror the rows
        return projector_shadow(z[:, ::-1], -fb)[:, ::-1]
    # towards the projector is +u: the least projector column of the pixels to the right
    right = np.minimum.accumulate(p[:, ::-1], axis=1)[:, ::-1]
    beyond = np.full_like(p, np.inf)
    beyond[:, :-1] = right[:, 1:]
    return ok & (p > beyond + 1e-9)


def binned_cloud(points_xyz: np.ndarray, size: tuple[int, int], binning: int) -> np.ndarray:
    """A (3, w h) Drake point cloud of a (width, height) image, row by row, thinned to the
    centre pixel of each binning x binning block (pixels b // 2, b // 2 + b, ... of each row and column)."""
    w, h = size
    b = int(binning)
    P = np.asarray(points_xyz).reshape(3, h, w)
    return P[:, b // 2::b, b // 2::b].reshape(3, -1)


def clean_scan(points_xyz: np.ndarray) -> np.ndarray:
    """(N, 3) finite returns of a (3, N) Drake point cloud: pixels with no return (+-inf) and
    NaN depth are dropped, never passed to the map."""
    P = np.asarray(points_xyz, float).T
    return P[np.all(np.isfinite(P), axis=1)]


def no_return_rays(depth: np.ndarray, X_WC: np.ndarray, dirs_cam: np.ndarray, z_far: float) -> np.ndarray:
    """World-frame end points at the sensor's maximum range for the pixels with no return
    (+inf depth: nothing within z_far). Integrated as free-space rays (OctoMap's max-range
    insertion): they clear space but never mark a hit. NaN and too-close pixels are ignored."""
    mask = np.isposinf(np.asarray(depth, float).reshape(-1))
    d = dirs_cam[mask]
    if len(d) == 0:
        return np.zeros((0, 3))
    p_cam = d * (z_far / d[:, 2])[:, None]
    return p_cam @ X_WC[:3, :3].T + X_WC[:3, 3]
