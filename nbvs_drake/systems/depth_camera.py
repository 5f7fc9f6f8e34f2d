"""The depth camera: Drake's RgbdSensor rendering with RenderEngineVtk, DepthImageToPointCloud,
and a small system giving the camera pose from a robot state (the believed one)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (ClippingRange, DepthRange, DepthRenderCamera, MakeRenderEngineVtk,
                              RenderCameraCore, RenderEngineVtkParams)
from pydrake.math import RigidTransform
from pydrake.perception import BaseField, DepthImageToPointCloud
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import PixelType, RgbdSensor

from ..config import SensorConfig, resolve_sensor
from ..robot import CAMERA_BODY, RobotKinematics
from ..sensor import camera_info, render_camera_info

RENDERER = "vtk"


def add_renderer(scene_graph):
    if not scene_graph.HasRenderer(RENDERER):
        scene_graph.AddRenderer(RENDERER, MakeRenderEngineVtk(RenderEngineVtkParams()))


def add_depth_camera(builder, scene_graph, plant, sensor: SensorConfig):
    """Adds an RgbdSensor on the robot's camera_optical frame (SR4000 176x144 by default) and a
    DepthImageToPointCloud. Returns (rgbd_sensor, to_point_cloud). The point cloud's
    camera_pose input is left for the caller: the robot only knows its believed pose."""
    s = resolve_sensor(sensor)
    add_renderer(scene_graph)
    info = camera_info(sensor)
    core = RenderCameraCore(RENDERER, render_camera_info(sensor), ClippingRange(0.05, s.z_far + 1.0),
                            RigidTransform())
    cam = DepthRenderCamera(core, DepthRange(s.z_near, s.z_far))
    fid = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(CAMERA_BODY).index())
    rgbd = builder.AddNamedSystem("depth_camera", RgbdSensor(fid, RigidTransform(), cam, False))
    builder.Connect(scene_graph.get_query_output_port(), rgbd.query_object_input_port())
    to_pc = builder.AddNamedSystem("depth_to_point_cloud",
                                   DepthImageToPointCloud(info, PixelType.kDepth32F, 1.0, BaseField.kXYZs))
    builder.Connect(rgbd.depth_image_32F_output_port(), to_pc.depth_image_input_port())
    return rgbd, to_pc


class CameraPose(LeafSystem):
    """Forward kinematics of the camera frame.

    Input ports:
      - state (8): a robot state q.
    Output ports:
      - camera_pose (abstract RigidTransform): X_WC of the camera optical frame.
    """

    def __init__(self, kin: RobotKinematics):
        super().__init__()
        self.kin = kin
        self._q = self.DeclareVectorInputPort("state", 8)
        self.DeclareAbstractOutputPort("camera_pose", lambda: AbstractValue.Make(RigidTransform()), self._calc)

    def _calc(self, context, output):
        X = self.kin.camera_poses(self._q.Eval(context))[0]
        output.set_value(RigidTransform(np.asarray(X)))
