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
