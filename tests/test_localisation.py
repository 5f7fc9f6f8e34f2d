"""The Localisation system (the owner of the belief) and the sensor-side DepthNoise, in
Drake's style: build the system, FixValue its inputs, advance, Eval its outputs."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.perception import BaseField, Fields, PointCloud
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageDepth32F

from nbvs_drake.config import DepthFaults, Scenario
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.systems.depth_camera import DepthNoise
from nbvs_drake.systems.localisation import Localisation
from nbvs_drake.systems.messages import Belief, ControllerStatus, RegisteredScan
from nbvs_drake.world.motion import ControlSequence, rollout, steer


def _cloud(P):
    c = PointCloud(len(P), Fields(BaseField.kXYZs))
    c.mutable_xyzs()[:] = np.asarray(P).T
    return c


def test_localisation_scans_once_per_finished_plan_and_predicts_the_belief(kin):
    sc = Scenario()
    sc.localisation.method = "none"
    q0 = np.array(sc.robot.start)
    loc = Localisation.for_scenario(sc, kin, q0, 0.1)
    sim = Simulator(loc)
    ctx = sim.get_mutable_context()
    pts = np.array([[0.0, 0.0, 0.6], [0.05, 0.0, 0.6], [np.nan, 0, 0], [np.inf, np.inf, np.inf]])
    loc.GetInputPort("point_cloud").FixValue(ctx, AbstractValue.Make(_cloud(pts)))
    depth = ImageDepth32F(176, 144, np.inf)
    loc.GetInputPort("depth_image").FixValue(ctx, AbstractValue.Make(depth))
    loc.GetInputPort("map").FixValue(ctx, AbstractValue.Make(OccupancyMap.for_scenario(sc)))
    tau = loc.GetInputPort("controls").FixValue(ctx, AbstractValue.Make(ControlSequence.empty(q0)))
    status = loc.GetInputPort("controller_status").FixValue(ctx, ControllerStatus(0, 0, False).to_vector())
    assert isinstance(loc.GetOutputPort("belief").Eval(ctx), Belief)
    sim.AdvanceTo(0.25)  # moving: no scan
    assert loc.GetOutputPort("registered_scan").Eval(ctx).index == 0
    status.GetMutableData().set_value(np.array(ControllerStatus(0, 0, True).to_vector()))  # idle: scan 1
    scan: RegisteredScan = loc.GetOutputPort("registered_scan").Eval(ctx)
    assert scan.index == 1 and len(scan.points) == 2  # invalid returns dropped
    assert len(scan.free_rays) == 176 * 144  # every pixel without a return clears free space
    np.testing.assert_allclose(scan.origin, kin.camera_poses(q0)[0][:3, 3])
    sim.AdvanceTo(0.55)
    assert loc.GetOutputPort("belief").Eval(ctx).scan == 1
    assert loc.GetOutputPort("registered_scan").Eval(ctx).index == 1  # still idle on plan 0: no second scan
    # a new plan: the belief is its predicted end state, then scan 2 when it is done
    q1 = q0.copy()
    q1[:3] = [-1.2, 0.4, 0.5]
    U = steer(q0, q1, sc.robot)[0][1]
    tau.GetMutableData().set_value(ControlSequence(1, 0.1, U, rollout(q0, U, 0.1)))
    status.GetMutableData().set_value(np.array(ControllerStatus(1, 0, False).to_vector()))
    sim.AdvanceTo(0.75)
    np.testing.assert_allclose(loc.GetOutputPort("believed_state").Eval(ctx), rollout(q0, U, 0.1)[-1])
    status.GetMutableData().set_value(np.array(ControllerStatus(1, len(U), True).to_vector()))
    sim.AdvanceTo(0.95)
    b = loc.GetOutputPort("belief").Eval(ctx)
    assert b.scan == 2 and np.array_equal(b.state, b.dead_reckoned)  # relocalization none: no correction
    assert loc.GetOutputPort("registered_scan").Eval(ctx).index == 2


def test_depth_noise_is_the_sensor_model():
    """The ToF preset has no axial noise (the image passes unchanged); the Kinect preset
    perturbs finite depths by sigma_z(z) and keeps no-return pixels, reproducibly."""
    z = np.full((144, 176, 1), 1.5, np.float32)
    z[0, 0, 0] = np.inf
    z[0, 1, 0] = np.nan
    image = ImageDepth32F(176, 144)
    image.mutable_data[:] = z
    tof = Scenario()
    noise = DepthNoise(tof.sensor, 0, 0.1)
    ctx = noise.CreateDefaultContext()
    noise.GetInputPort("depth_image").FixValue(ctx, AbstractValue.Make(image))
    out = np.array(noise.GetOutputPort("depth_image").Eval(ctx).data)
    np.testing.assert_array_equal(out[np.isfinite(z)], z[np.isfinite(z)])
    kinect = Scenario()
    kinect.sensor.preset = "kinect"
    kinect.sensor.faults = DepthFaults.none()  # the axial noise alone (the faults: tests/test_depth_faults.py)
    noise = DepthNoise(kinect.sensor, 3, 0.1)
    ctx = noise.CreateDefaultContext()
    noise.GetInputPort("depth_image").FixValue(ctx, AbstractValue.Make(image))
    out = np.array(noise.GetOutputPort("depth_image").Eval(ctx).data)
    assert np.isposinf(out[0, 0, 0]) and np.isnan(out[0, 1, 0])
    d = out[np.isfinite(z)] - z[np.isfinite(z)]
    sigma = 0.0012 + 0.0019 * (1.5 - 0.4) ** 2
    assert abs(d.std() - sigma) < 0.1 * sigma and abs(d.mean()) < 0.1 * sigma
    ctx2 = noise.CreateDefaultContext()
    noise.GetInputPort("depth_image").FixValue(ctx2, AbstractValue.Make(image))
    again = np.array(noise.GetOutputPort("depth_image").Eval(ctx2).data)
    np.testing.assert_array_equal(again, out)
