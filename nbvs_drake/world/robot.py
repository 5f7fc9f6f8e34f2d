"""The PatrolBot + Katana 6M180 model: loading the URDF into a MultibodyPlant, the state
layout q = [x, y, theta, q1..q5], joint limits, and a vectorised forward kinematics of the
camera frame that is read off the same plant (tests check it against Drake's)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import ScenarioError
from ..resources import model_path

ARM_JOINTS = ["katana_j1", "katana_j2", "katana_j3", "katana_j4", "katana_j5"]
BASE_JOINT = "base"
CAMERA_BODY = "camera_optical"

#: how far (rad) an arm joint may stand outside its limits and still count as within them
LIMIT_TOL = 1e-9


def urdf_path(name: str) -> Path:
    p = model_path(name)
    if not p.is_file():
        raise ScenarioError(f"robot URDF not found: {p}")
    return p


def add_robot(plant, urdf: str):
    """Parses the robot into `plant` (not finalized). Returns its model instance."""
    from pydrake.multibody.parsing import Parser
    (instance,) = Parser(plant).AddModels(str(urdf_path(urdf)))
    return instance


def state_to_positions_index(plant) -> np.ndarray:
    """idx such that plant_positions[idx] = q (the robot state layout)."""
    base = plant.GetJointByName(BASE_JOINT)
    idx = [base.position_start() + i for i in range(3)]
    idx += [plant.GetJointByName(j).position_start() for j in ARM_JOINTS]
    return np.array(idx, dtype=int)


def _X(rt) -> np.ndarray:
    return np.asarray(rt.GetAsMatrix4())


class RobotKinematics:
    """Vectorised kinematics of the camera frame, with the fixed transforms read off the
    URDF through Drake (so it cannot drift from the plant used for rendering/collision)."""

    def __init__(self, urdf: str = "patrolbot_katana.urdf"):
        from pydrake.multibody.plant import MultibodyPlant
        plant = MultibodyPlant(0.0)
        add_robot(plant, urdf)
        plant.Finalize()
        self.plant = plant
        self.q_index = state_to_positions_index(plant)
        self.n_positions = plant.num_positions()
        self.joint_fixed = []  # (X_parent_jointframe, axis) per arm joint
        lower, upper, vmax = [], [], []
        for name in ARM_JOINTS:
            j = plant.GetJointByName(name)
            X_PF = _X(j.frame_on_parent().GetFixedPoseInBodyFrame())
            X_CM = _X(j.frame_on_child().GetFixedPoseInBodyFrame())
            assert np.allclose(X_CM, np.eye(4)), "URDF child frames are expected at the link origin"
            self.joint_fixed.append((X_PF, np.asarray(j.revolute_axis(), float)))
            lower.append(j.position_lower_limits()[0])
            upper.append(j.position_upper_limits()[0])
            vmax.append(j.velocity_upper_limits()[0])
        self.arm_lower = np.array(lower)
        self.arm_upper = np.array(upper)
        self.arm_velocity_limits = np.array(vmax)
        cam = plant.GetBodyByName(CAMERA_BODY)
        ctx = plant.CreateDefaultContext()
        link5 = plant.GetBodyByName("katana_link5")
        self.X_L5C = _X(plant.CalcRelativeTransform(ctx, link5.body_frame(), cam.body_frame()))
        self._ctx = ctx
        self._first_vertical = self._first_joint_is_vertical()
        #: the arm's limits widened by LIMIT_TOL (all_within_limits)
        self._limits = (self.arm_lower - LIMIT_TOL, self.arm_upper + LIMIT_TOL)

    # ---- layout --------------------------------------------------------------------
    def to_positions(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, float)
        out = np.zeros(q.shape[:-1] + (self.n_positions,))
        out[..., self.q_index] = q
        return out

    def clip_arm(self, q: np.ndarray) -> np.ndarray:
        q = np.array(q, float)
        q[..., 3:] = np.clip(q[..., 3:], self.arm_lower, self.arm_upper)
        return q

    def first_joint_vertical(self) -> bool:
        """Whether the arm's first joint turns about the base's vertical axis, with no rotation
        between the base and it (`turned_about_mount` and the director-ray test's arm-plane
        pretest rely on it). Read off the URDF once."""
        return self._first_vertical

    def _first_joint_is_vertical(self) -> bool:
        X0, axis = self.joint_fixed[0]
        return bool(np.allclose(axis / np.linalg.norm(axis), [0.0, 0.0, 1.0]) and np.allclose(X0[:3, :3], np.eye(3)))

    def turned_about_mount(self, q: np.ndarray, headings: np.ndarray) -> np.ndarray:
        """States (H, 8) with the camera pose of state q (8,) and the base headings `headings`
        (H,): the arm's first joint is vertical, so turning the base about that joint's axis
        and turning the joint back by as much leaves every arm link, and the camera, where
        they were (the state has two such redundant dimensions; this is the exact one). Rows
        whose first joint would leave its limits are NaN."""
        from .motion import wrap_angle
        q = np.asarray(q, float)
        headings = np.asarray(headings, float).reshape(-1)
        if not self.first_joint_vertical():
            raise ValueError("turned_about_mount needs the arm's first joint about the base's vertical")
        X0 = self.joint_fixed[0][0]
        ox, oy = X0[0, 3], X0[1, 3]  # the first joint's axis in the base frame
        c, s = math.cos(q[2]), math.sin(q[2])
        mx, my = q[0] + c * ox - s * oy, q[1] + s * ox + c * oy  # its position in the world
        out = np.tile(q, (len(headings), 1))
        ch, sh = np.cos(headings), np.sin(headings)
        out[:, 0] = mx - (ch * ox - sh * oy)
        out[:, 1] = my - (sh * ox + ch * oy)
        out[:, 2] = wrap_angle(headings)
        d = wrap_angle(q[2] - headings)
        j1 = q[3] + np.stack([d, d - 2 * np.pi, d + 2 * np.pi])  # the joint's turn, either way round
        ok = (j1 >= self.arm_lower[0]) & (j1 <= self.arm_upper[0])
        pick = np.argmax(ok, axis=0)  # the shorter turn where both are within the limits
        out[:, 3] = j1[pick, np.arange(len(headings))]
        out[~ok.any(axis=0)] = np.nan
        return out

    def all_within_limits(self, q: np.ndarray) -> bool:
        """Whether every state of q (..., 8) has its arm within the limits
        (`arm_within_limits` of them all)."""
        a = np.asarray(q, float)[..., 3:]
        return bool(((a >= self._limits[0]) & (a <= self._limits[1])).all())

    def arm_within_limits(self, q: np.ndarray, tol: float = LIMIT_TOL) -> np.ndarray:
        q = np.asarray(q, float)
        return np.all((q[..., 3:] >= self.arm_lower - tol) & (q[..., 3:] <= self.arm_upper + tol), axis=-1)

    # ---- forward kinematics --------------------------------------------------------
    def camera_poses(self, q: np.ndarray) -> np.ndarray:
        """X_WC (N, 4, 4) of the camera optical frame (+z forward) for states q (N, 8)."""
        q = np.atleast_2d(np.asarray(q, float))
        n = len(q)
        X = np.zeros((n, 4, 4))
        c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
        X[:, 0, 0], X[:, 0, 1], X[:, 1, 0], X[:, 1, 1] = c, -s, s, c
        X[:, 2, 2] = X[:, 3, 3] = 1.0
        X[:, 0, 3], X[:, 1, 3] = q[:, 0], q[:, 1]
        for i, (X_PF, axis) in enumerate(self.joint_fixed):
            X = X @ X_PF
            X = X @ _axis_rotation(axis, q[:, 3 + i])
        return X @ self.X_L5C

    def camera_pose_drake(self, q: np.ndarray) -> np.ndarray:
        """The same through Drake's MultibodyPlant (slow; for checks)."""
        self.plant.SetPositions(self._ctx, self.to_positions(q))
        cam = self.plant.GetBodyByName(CAMERA_BODY)
        return _X(self.plant.EvalBodyPoseInWorld(self._ctx, cam))


def _axis_rotation(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Homogeneous rotations about a unit axis, (N, 4, 4) (Rodrigues)."""
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(angles), np.cos(angles)
    R = np.eye(3)[None] + s[:, None, None] * K[None] + (1 - c)[:, None, None] * (K @ K)[None]
    out = np.zeros((len(angles), 4, 4))
    out[:, :3, :3] = R
    out[:, 3, 3] = 1.0
    return out
