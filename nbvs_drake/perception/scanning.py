"""Rendering scans of a scenario's scene at given robot states, outside a mission: the same
plant, scene and RgbdSensor as the mission diagram, for benchmarks, parity checks and
notebooks."""

from __future__ import annotations

import dataclasses as dc
from pathlib import Path

import numpy as np

from ..config import Scenario, resolve_sensor
from ..mapping.occupancy import OccupancyMap
from ..world.objects import build_object
from ..world.robot import RobotKinematics
from ..world.sensor import clean_scan, no_return_rays, ray_directions


@dc.dataclass
class Scan:
    X_WC: np.ndarray  #: camera pose (4, 4)
    points: np.ndarray  #: finite returns, world frame (N, 3)
    free_rays: np.ndarray  #: end points at maximum range of the no-return pixels (M, 3)

    @property
    def origin(self) -> np.ndarray:
        return self.X_WC[:3, 3]


class ScanRenderer:
    def __init__(self, sc: Scenario, work_dir: Path, kin: RobotKinematics | None = None):
        from pydrake.systems.framework import DiagramBuilder

        from ..app.diagram import add_robot_and_scene
        from ..systems.depth_camera import CameraPose, add_depth_camera

        self.sc = sc
        self.kin = kin or RobotKinematics(sc.robot.urdf)
        obj = build_object(sc).write_obj(Path(work_dir) / "object.obj")
        builder = DiagramBuilder()
        sg, plant, to_pose = add_robot_and_scene(builder, sc, str(obj))
        self.camera = add_depth_camera(builder, sg, plant, sc.sensor, sc.seed, sc.robot.control_dt)
        self.to_pc = self.camera.to_pc
        pose = builder.AddSystem(CameraPose(self.kin))
        builder.Connect(pose.get_output_port(), self.to_pc.camera_pose_input_port())
        builder.ExportInput(to_pose.get_input_port(), "positions")
        builder.ExportInput(pose.get_input_port(), "state")
        self.plant = plant
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.dirs = ray_directions(sc.sensor, 1)[0]
        self.z_far = resolve_sensor(sc.sensor).z_far

    def _at(self, q) -> np.ndarray:
        """Puts the robot at state q (the diagram's inputs); returns q as an array."""
        q = np.asarray(q, float)
        self.diagram.get_input_port(0).FixValue(self.context, self.kin.to_positions(q))
        self.diagram.get_input_port(1).FixValue(self.context, q)
        return q

    def _depth_data(self) -> np.ndarray:
        """The depth image (h, w, 1) at the current state, its noise and faults applied."""
        noise = self.camera.noise
        return self.camera.depth_image_port.Eval(noise.GetMyContextFromRoot(self.context)).data

    def depth(self, q) -> np.ndarray:
        """The depth image (h, w) the sensor returns at state q (its noise and faults applied)."""
        self._at(q)
        return np.array(self._depth_data())[:, :, 0]

    def organised_cloud(self, q) -> np.ndarray:
        """The (3, w h) point cloud of the state q's image, row by row (no return: NaN, +-inf)."""
        self._at(q)
        ctx_pc = self.to_pc.GetMyContextFromRoot(self.context)
        return np.array(self.to_pc.point_cloud_output_port().Eval(ctx_pc).xyzs())

    def scan(self, q) -> Scan:
        q = np.asarray(q, float)
        pts = clean_scan(self.organised_cloud(q))
        X = self.kin.camera_poses(q)[0]
        return Scan(X, pts, no_return_rays(self._depth_data(), X, self.dirs, self.z_far))

    def integrate(self, omap: OccupancyMap, scan: Scan) -> OccupancyMap:
        return omap.integrate(scan.origin, scan.points, self.sc.mapper.table_clearance, scan.free_rays)[0]
