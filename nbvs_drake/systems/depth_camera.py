"""The depth camera: Drake's RgbdSensor rendering with RenderEngineVtk, the sensor's depth
noise, DepthImageToPointCloud, and a small system giving the camera pose from a robot state
(the believed one)."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    ClippingRange,
    DepthRange,
    DepthRenderCamera,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
)
from pydrake.math import RigidTransform
from pydrake.perception import BaseField, DepthImageToPointCloud
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import PixelType, RgbdSensor

from ..config import SensorConfig, resolve_sensor
from ..stage_clock import SCANS, stage
from ..world.robot import CAMERA_BODY, RobotKinematics
from ..world.sensor import axial_noise_sigma, camera_info, noisy_depth, render_camera_info

RENDERER = "vtk"


def add_renderer(scene_graph):
    if not scene_graph.HasRenderer(RENDERER):
        scene_graph.AddRenderer(RENDERER, MakeRenderEngineVtk(RenderEngineVtkParams()))


@dc.dataclass(frozen=True)
class DepthCamera:
    """The camera's systems: the RgbdSensor, its DepthNoise and the DepthImageToPointCloud
    fed by the noisy depth image; `depth_image_port`: the noisy depth image (what the sensor
    returns)."""
    rgbd: object
    noise: "DepthNoise"
    to_pc: object

    @property
    def depth_image_port(self):
        return self.noise.GetOutputPort("depth_image")


def add_depth_camera(builder, scene_graph, plant, sensor: SensorConfig, seed: int = 0, dt: float = 0.1) -> DepthCamera:
    """Adds an RgbdSensor on the robot's camera_optical frame (SR4000 176x144 by default), the
    sensor's axial depth noise (DepthNoise) and a DepthImageToPointCloud. The point cloud's
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
    noise = builder.AddNamedSystem("depth_noise", DepthNoise(sensor, seed, dt))
    builder.Connect(rgbd.depth_image_32F_output_port(), noise.GetInputPort("depth_image"))
    to_pc = builder.AddNamedSystem("depth_to_point_cloud",
                                   DepthImageToPointCloud(info, PixelType.kDepth32F, 1.0, BaseField.kXYZs))
    builder.Connect(noise.GetOutputPort("depth_image"), to_pc.depth_image_input_port())
    return DepthCamera(rgbd, noise, to_pc)


class DepthNoise(LeafSystem):
    """The sensor's depth noise: each finite depth z becomes z + N(0, sigma_z(z)^2) with
    sigma_z = noise_a + noise_b (z - 0.4)^2 (the Kinect model of Nguyen et al. 2012; zero for
    the ToF preset, whose image passes unchanged); then the sensor's structured-light faults
    (`world.sensor.apply_depth_faults`: lateral noise, grazing dropouts, the projector's
    shadow, disparity steps; the Kinect's), whose missing returns are NaN. Pixels without a
    return (+-inf; 0, too close) and NaN stay as they are. The draws are seeded by (seed, control step of the
    image's time), the axial noise's and the faults' apart.

    Input ports:
      - depth_image (abstract ImageDepth32F): the rendered depth image.
    Output ports:
      - depth_image (abstract ImageDepth32F): the image the sensor returns.
    """

    def __init__(self, sensor: SensorConfig, seed: int, dt: float):
        super().__init__()
        from pydrake.systems.sensors import ImageDepth32F
        self.sensor = sensor
        self.seed = int(seed)
        self.dt = float(dt)
        self.axial = bool(np.any(axial_noise_sigma(sensor, np.array([0.4, 5.0])) > 0))
        self.faults = resolve_sensor(sensor).faults.any()
        self.active = self.axial or self.faults
        self._in = self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F()))
        self.DeclareAbstractOutputPort("depth_image", lambda: AbstractValue.Make(ImageDepth32F()), self._calc)

    def _calc(self, context, output):
        with stage(SCANS, "render"):
            self._calc_faulty(context, output)

    def _calc_faulty(self, context, output):
        image = self._in.Eval(context)  # (RgbdSensor renders here)
        if not self.active:
            output.set_value(image)
            return
        step = int(round(context.get_time() / self.dt))
        z = noisy_depth(np.asarray(image.data)[:, :, 0], self.sensor, self.seed, step)[:, :, None]
        out = output.get_mutable_value()
        out.resize(image.width(), image.height())
        out.mutable_data[:] = z.astype(np.float32)


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
