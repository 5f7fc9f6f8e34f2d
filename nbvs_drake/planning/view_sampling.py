"""Santos et al. 2020's conditional view sampling as a candidate generator: the unknown voxels
of W_box are grouped into clusters; N poses are spread evenly over the clusters (their eq. 1),
each a camera position at a random distance and direction from its cluster's centroid looking
at it; each pose becomes a robot state through Drake's InverseKinematics (camera position
within 1 cm, optical axis within 5 deg of the centroid direction, roll free, joint limits and
base bounds). The states then go through random sampling's filter cascade and utility, but for
the registration filter, which Santos et al. do not have (their robot knows the arm's pose)."""

from __future__ import annotations

import numpy as np

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..mapping.voxel_sorting import unknown_clusters
from ..world.robot import CAMERA_BODY, RobotKinematics
from ..world.state import NQ
from .candidates import StateSampler


def camera_ik(kin: RobotKinematics, p: np.ndarray, look: np.ndarray, guess: np.ndarray, xy_bounds,
              pos_tol: float, angle_tol: float) -> np.ndarray | None:
    """Drake InverseKinematics: a robot state whose camera is at p (within pos_tol per
    coordinate) with its optical axis along `look` (within angle_tol), roll free, within the
    joint limits and the base bounds `xy_bounds`, from the initial guess; None if it fails."""
    from pydrake.multibody.inverse_kinematics import InverseKinematics
    from pydrake.solvers import Solve
    plant = kin.plant
    cam = plant.GetBodyByName(CAMERA_BODY).body_frame()
    ik = InverseKinematics(plant)
    ik.AddPositionConstraint(cam, np.zeros(3), plant.world_frame(), p - pos_tol, p + pos_tol)
    ik.AddAngleBetweenVectorsConstraint(cam, np.array([0.0, 0.0, 1.0]), plant.world_frame(), look, 0.0, angle_tol)
    q = ik.q()
    lo, hi = xy_bounds
    for a in (0, 1):
        ik.prog().AddBoundingBoxConstraint(lo, hi, q[kin.q_index[a]])
    ik.prog().SetInitialGuess(q, kin.to_positions(guess))
    res = Solve(ik.prog())
    if not res.is_success():
        return None
    return res.GetSolution(q)[kin.q_index]


class ClusterViewGenerator:
    pos_tol = 0.01
    angle_tol = np.radians(5.0)

    def __init__(self, sc: Scenario, kin: RobotKinematics, sampler: StateSampler):
        self.sc = sc
        self.kin = kin
        self.z_near, self.z_far = sampler.z_near, sampler.z_far

    def _ik(self, p: np.ndarray, look: np.ndarray, guess: np.ndarray):
        """A state whose camera is at p looking along `look`, or None."""
        return camera_ik(self.kin, p, look, guess, self.sc.robot.xy_bounds, self.pos_tol, self.angle_tol)

    def generate(self, rng: np.random.Generator, omap: OccupancyMap | None = None) -> tuple[np.ndarray, int]:
        p = self.sc.planner
        if omap is None:
            return np.zeros((0, NQ)), 0
        _, centroids, sizes = unknown_clusters(omap.in_wbox() & omap.unknown_mask(), omap.spec.centers())
        if len(sizes) == 0:
            return np.zeros((0, NQ)), 0
        per = max(1, p.strategy.poses // len(sizes))  # eq. 1: poses per cluster
        d_max = p.max_view_distance
        states, tried = [], 0
        for c in centroids:
            for _ in range(per):
                tried += 1
                u = rng.normal(size=3)
                u[2] = abs(u[2]) * 0.5  # the front hemisphere above the table
                u /= np.linalg.norm(u)
                dist = rng.uniform(self.z_near + 0.1, max(self.z_near + 0.15, d_max))
                pos = c + dist * u
                look = (c - pos) / np.linalg.norm(c - pos)
                # initial guess: base behind the camera, facing the centroid, arm half raised
                back = pos[:2] - 0.75 * look[:2] / max(np.linalg.norm(look[:2]), 1e-9)
                heading = np.arctan2(look[1], look[0])
                guess = np.array([back[0], back[1], heading, 0.0, 0.5, -0.3, -0.3, 0.0])
                q = self._ik(pos, look, guess)
                if q is not None:
                    states.append(q)
        out = np.array(states) if states else np.zeros((0, NQ))
        return out, tried
