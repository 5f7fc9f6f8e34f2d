"""The depth camera renders Drake's scene with RenderEngineVtk; depths match analytic distances."""
import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from nbvs_drake.app.diagram import add_robot_and_scene
from nbvs_drake.config import Scenario
from nbvs_drake.systems.depth_camera import CameraPose, add_depth_camera
from nbvs_drake.world.sensor import clean_scan


def _camera_diagram(kin, q):
    sc = Scenario()
    builder = DiagramBuilder()
    sg, plant, to_pose = add_robot_and_scene(builder, sc, None)  # floor + table, no object
    src = builder.AddSystem(ConstantVectorSource(kin.to_positions(q)))
    builder.Connect(src.get_output_port(), to_pose.get_input_port())
    camera = add_depth_camera(builder, sg, plant, sc.sensor)
    rgbd, to_pc = camera.rgbd, camera.to_pc
    pose = builder.AddSystem(CameraPose(kin))
    qsrc = builder.AddSystem(ConstantVectorSource(q))
    builder.Connect(qsrc.get_output_port(), pose.get_input_port())
    builder.Connect(pose.get_output_port(), to_pc.camera_pose_input_port())
    d = builder.Build()
    return d, rgbd, to_pc, plant


def test_depth_of_the_floor_seen_straight_down(kin):
    # arm raised 0.6 rad, wrist pitched so that the optical axis points straight down
    q = np.array([-1.7, 0.0, 0.0, 0.0, 0.6, 0.0, -np.pi / 2 - 0.6, 0.0])
    X = kin.camera_poses(q)[0]
    np.testing.assert_allclose(X[:3, 2], [0, 0, -1], atol=1e-12)
    d, rgbd, to_pc, _ = _camera_diagram(kin, q)
    ctx = d.CreateDefaultContext()
    depth = np.array(rgbd.depth_image_32F_output_port().Eval(rgbd.GetMyContextFromRoot(ctx)).data)[:, :, 0]
    assert depth.shape == (144, 176)  # SR4000
    # a plane perpendicular to the optical axis has constant depth = camera height
    centre = depth[36:108, 44:132]
    np.testing.assert_allclose(centre, X[2, 3], atol=1e-3)
    # the world-frame cloud of those pixels lies on the floor (z = 0)
    pts = clean_scan(to_pc.point_cloud_output_port().Eval(to_pc.GetMyContextFromRoot(ctx)).xyzs())
    assert len(pts) > 0.5 * depth.size
    floor = pts[np.abs(pts[:, 2]) < 0.01]
    assert len(floor) > 0.4 * depth.size


def test_depth_of_the_floor_at_45_degrees_pixel_by_pixel(kin, scenario):
    from nbvs_drake.world.sensor import intrinsics
    q = np.array([-1.7, 0.0, 0.0, 0.0, 0.6, 0.0, -np.pi / 4 - 0.6, 0.0])
    X = kin.camera_poses(q)[0]
    d, rgbd, _, _ = _camera_diagram(kin, q)
    ctx = d.CreateDefaultContext()
    depth = np.array(rgbd.depth_image_32F_output_port().Eval(rgbd.GetMyContextFromRoot(ctx)).data)[:, :, 0]
    w, h, fx, fy, cx, cy = intrinsics(scenario.sensor)
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u, float)], axis=-1) @ X[:3, :3].T
    expected = -X[2, 3] / rays[..., 2]  # depth (camera z) where the pixel's ray meets z = 0
    window = (slice(100, 144), slice(40, 136))  # lower rows: the floor in front of the robot
    # float32 depth; a half-pixel shift of the rays would be off by ~2e-3 here
    np.testing.assert_allclose(depth[window], expected[window], rtol=1e-5)
    # every pixel whose floor point lies in front of the table (x < -0.45) matches too
    hit_x = X[0, 3] + expected * rays[..., 0]
    sel = hit_x < -0.45
    assert sel.sum() > 0.2 * depth.size
    np.testing.assert_allclose(depth[sel], expected[sel], rtol=1e-5)


def test_point_cloud_of_an_oblique_plane_lies_on_it(kin):
    # the renderer and DepthImageToPointCloud must agree on the principal point: a half-pixel
    # disagreement tilts the cloud of a plane seen obliquely by ~2 mm per metre of depth
    q = np.array([-1.7, 0.0, 0.3, 0.2, 0.6, 0.0, -np.pi / 4 - 0.6, 0.0])
    d, _, to_pc, _ = _camera_diagram(kin, q)
    ctx = d.CreateDefaultContext()
    pts = clean_scan(to_pc.point_cloud_output_port().Eval(to_pc.GetMyContextFromRoot(ctx)).xyzs())
    floor = pts[(np.abs(pts[:, 2]) < 0.01) & (pts[:, 0] < -0.45)]
    assert len(floor) > 5000
    np.testing.assert_allclose(floor[:, 2], 0.0, atol=2e-5)
