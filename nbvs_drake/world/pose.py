"""Planar pose algebra of the mobile base: base noise moves the robot in the plane (x, y,
theta; the arm is exact), so a pose error is a planar rigid *correction* (dx, dy, dyaw) — a
rotation about z plus a planar translation — that maps a believed pose onto the true one.
The registration estimates one per scan (`registration.register_scan`), the localisation
applies it to the scan and the belief, and the expected utility draws start states from the
belief's covariance with it."""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from .motion import wrap_angle


def rot_z(yaw: float) -> np.ndarray:
    """3x3 rotation about z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


#: pose variances below this (1 mm, 1 mrad squared): the pose is known exactly (odometry
#: without noise, a belief the last scan's registration fixed)
EXACT_POSE_VAR = 1e-6


def apply_corrections(q: np.ndarray, xi) -> np.ndarray:
    """States (n, 8): the state q with its base pose moved by each planar correction
    xi = (dx, dy, dyaw) in (n, 3): p' = Rz(dyaw) p + (dx, dy), heading + dyaw, arm unchanged
    (`Correction.apply_state` for one)."""
    q = np.asarray(q, float)
    xi = np.atleast_2d(np.asarray(xi, float))
    c, s = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    out = np.tile(q, (len(xi), 1))
    out[:, 0] = c * q[0] - s * q[1] + xi[:, 0]
    out[:, 1] = s * q[0] + c * q[1] + xi[:, 1]
    out[:, 2] = wrap_angle(q[2] + xi[:, 2])
    return out


@dc.dataclass(frozen=True)
class Correction:
    """Planar rigid correction: p' = Rz(dyaw) p + (dx, dy, 0)."""
    dx: float = 0.0
    dy: float = 0.0
    dyaw: float = 0.0

    def matrix(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = rot_z(self.dyaw)
        T[0, 3], T[1, 3] = self.dx, self.dy
        return T

    def apply_points(self, P: np.ndarray) -> np.ndarray:
        T = self.matrix()
        return np.asarray(P, float) @ T[:3, :3].T + T[:3, 3]

    def apply_pose(self, X: np.ndarray) -> np.ndarray:
        return self.matrix() @ np.asarray(X, float)

    def apply_state(self, q: np.ndarray) -> np.ndarray:
        """The robot state whose base pose is T times the base pose of q (arm unchanged)."""
        return apply_corrections(q, [[self.dx, self.dy, self.dyaw]])[0]

    def to_json(self) -> list[float]:
        return [round(self.dx, 6), round(self.dy, 6), round(self.dyaw, 6)]


def state_error(q_true: np.ndarray, q_est: np.ndarray) -> tuple[float, float]:
    """(planar position error in m, absolute heading error in rad) of a state estimate."""
    d = np.asarray(q_true, float) - np.asarray(q_est, float)
    return float(np.hypot(d[0], d[1])), float(abs(wrap_angle(d[2])))


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """X_WC of a camera at eye looking at target (+z forward, +x right, +y down), its image's
    up as close to the world's +z as the view allows (+x world where it looks straight up or down)."""
    f = np.asarray(target, float) - np.asarray(eye, float)
    f /= np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(f, up)
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    X = np.eye(4)
    X[:3, :3] = np.c_[x, y, f]
    X[:3, 3] = eye
    return X
