"""Builds the mission diagram of a scenario (docs/design.md). Data flows one way: camera ->
localisation -> mapper -> planner -> controller -> plant:

 NBVSPlanner --controls--> NoisyVelocityController --u--> KinematicPlant (x, y, theta, q1..q5)
      ^ map, belief                                               | positions
 OctreeMapper <-- registered scan -- Localisation <-- cloud, depth -- DepthImageToPointCloud
   (maps only)       (ICP; owns the belief: state + covariance)          ^ DepthNoise <- RgbdSensor
                                                      MultibodyPositionToGeometryPose -> SceneGraph
The Localisation also reads the plan (its odometry: the belief between scans is the plan's
predicted end) and the map of the earlier scans (the free space its registration must respect);
the believed camera pose (CameraPose of the belief) places the cloud.
"""

from __future__ import annotations

import dataclasses as dc
from pathlib import Path

import numpy as np

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..planning import make_planner
from ..planning.collision import CollisionModel
from ..world.objects import ObjectMesh, build_object, ground_truth_points
from ..world.robot import RobotKinematics, add_robot
from ..world.scene import add_environment


@dc.dataclass
class MissionDiagram:
    diagram: object
    systems: dict
    kin: RobotKinematics
    mesh: ObjectMesh
    gt_points: np.ndarray
    plant: object  # kept alive: MultibodyPositionToGeometryPose refers to it


def add_robot_and_scene(builder, sc: Scenario, object_obj: str | None):
    """SceneGraph (with the VTK renderer) + a MultibodyPlant of the robot and the scene whose
    poses come from a MultibodyPositionToGeometryPose. Returns (scene_graph, plant, to_pose);
    to_pose's input takes the plant positions. The plant is not part of the diagram: keep a
    reference to it as long as the diagram lives."""
    from pydrake.geometry import SceneGraph
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.rendering import MultibodyPositionToGeometryPose

    from ..systems.depth_camera import add_renderer

    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    add_renderer(scene_graph)
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    add_robot(plant, sc.robot.urdf)
    add_environment(plant, sc, object_obj=object_obj)
    plant.Finalize()
    to_pose = builder.AddNamedSystem("position_to_geometry_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    return scene_graph, plant, to_pose


def build_mission_diagram(sc: Scenario, work_dir: Path, log=None, meshcat=None) -> MissionDiagram:
    """`work_dir` receives the object's OBJ (rendered by VTK); `log` is the IterationLog the
    MissionRecorder writes to (None: no recorder, e.g. for drawing the wiring); `meshcat`: a
    pydrake Meshcat for the live view (MeshcatVisualizer + MeshcatMapView), None: none."""
    from pydrake.systems.framework import DiagramBuilder

    from ..systems.collision_monitor import CollisionMonitor
    from ..systems.depth_camera import CameraPose, add_depth_camera
    from ..systems.kinematic_plant import KinematicPlant
    from ..systems.localisation import Localisation
    from ..systems.mission_recorder import MissionRecorder
    from ..systems.nbvs_planner import NBVSPlanner
    from ..systems.noisy_velocity_controller import NoisyVelocityController
    from ..systems.octree_mapper import OctreeMapper
    from ..systems.surface_fusion import SurfaceFusion

    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    kin = RobotKinematics(sc.robot.urdf)
    mesh = build_object(sc)
    obj_path = mesh.write_obj(work_dir / "object.obj")
    gt = ground_truth_points(mesh, sc)
    q0 = np.array(sc.robot.start, float)
    dt = sc.robot.control_dt

    builder = DiagramBuilder()
    scene_graph, plant, to_pose = add_robot_and_scene(builder, sc, str(obj_path))

    truth_model = CollisionModel(sc, kin, object_obj=str(obj_path))
    planner_impl = make_planner(sc, kin, truth_mesh=mesh)

    kplant = builder.AddNamedSystem("kinematic_plant", KinematicPlant(kin, q0, dt))
    ctrl = builder.AddNamedSystem("noisy_velocity_controller", NoisyVelocityController(sc.noise, sc.seed, dt))
    camera = add_depth_camera(builder, scene_graph, plant, sc.sensor, sc.seed, dt)
    rgbd, to_pc = camera.rgbd, camera.to_pc
    belief_pose = builder.AddNamedSystem("believed_camera_pose", CameraPose(kin))
    loc = builder.AddNamedSystem("localisation", Localisation.for_scenario(sc, kin, q0, dt))
    mapper = builder.AddNamedSystem("octree_mapper", OctreeMapper(sc.scene, sc.mapper, dt))
    recovery = None
    if sc.localisation.verified_views is not None:
        from ..planning import make_recovery
        recovery = make_recovery(sc, kin, planner_impl)
    planner = builder.AddNamedSystem("nbvs_planner", NBVSPlanner.for_scenario(sc, planner_impl, q0, recovery))
    monitor = builder.AddNamedSystem("collision_monitor", CollisionMonitor(truth_model, dt))
    fusion = builder.AddNamedSystem("surface_fusion", SurfaceFusion(sc.scene, sc.mapper, sc.sensor, dt))

    builder.Connect(planner.GetOutputPort("controls"), ctrl.GetInputPort("controls"))
    builder.Connect(ctrl.GetOutputPort("velocity"), kplant.GetInputPort("velocity"))
    builder.Connect(kplant.GetOutputPort("positions"), to_pose.get_input_port())
    builder.Connect(loc.GetOutputPort("believed_state"), belief_pose.GetInputPort("state"))
    builder.Connect(belief_pose.GetOutputPort("camera_pose"), to_pc.camera_pose_input_port())
    builder.Connect(to_pc.point_cloud_output_port(), loc.GetInputPort("point_cloud"))
    builder.Connect(camera.depth_image_port, loc.GetInputPort("depth_image"))
    builder.Connect(ctrl.GetOutputPort("status"), loc.GetInputPort("controller_status"))
    builder.Connect(planner.GetOutputPort("controls"), loc.GetInputPort("controls"))
    builder.Connect(mapper.GetOutputPort("map"), loc.GetInputPort("map"))
    builder.Connect(loc.GetOutputPort("registered_scan"), mapper.GetInputPort("registered_scan"))
    builder.Connect(loc.GetOutputPort("registered_scan"), fusion.GetInputPort("registered_scan"))
    builder.Connect(mapper.GetOutputPort("map"), planner.GetInputPort("map"))
    builder.Connect(loc.GetOutputPort("belief"), planner.GetInputPort("belief"))
    builder.Connect(kplant.GetOutputPort("state"), monitor.GetInputPort("state"))
    builder.Connect(ctrl.GetOutputPort("status"), monitor.GetInputPort("controller_status"))

    systems = dict(scene_graph=scene_graph, kinematic_plant=kplant, controller=ctrl, rgbd=rgbd,
                   depth_noise=camera.noise, to_point_cloud=to_pc, localisation=loc, mapper=mapper,
                   planner=planner, monitor=monitor, surface_fusion=fusion,
                   believed_camera_pose=belief_pose)
    if log is not None:
        rec = builder.AddNamedSystem("mission_recorder", MissionRecorder(
            log, gt, sc.mapper.voxel_size, dt, OccupancyMap.for_scenario(sc)))
        builder.Connect(mapper.GetOutputPort("map"), rec.GetInputPort("map"))
        builder.Connect(mapper.GetOutputPort("scan_report"), rec.GetInputPort("scan_report"))
        builder.Connect(planner.GetOutputPort("report"), rec.GetInputPort("plan_report"))
        builder.Connect(kplant.GetOutputPort("state"), rec.GetInputPort("true_state"))
        builder.Connect(ctrl.GetOutputPort("status"), rec.GetInputPort("controller_status"))
        builder.Connect(monitor.GetOutputPort("counts"), rec.GetInputPort("collisions"))
        builder.Connect(loc.GetOutputPort("belief"), rec.GetInputPort("belief"))
        systems["recorder"] = rec
    if meshcat is not None:  # live view (nbvs reconstruct --meshcat)
        from ..systems.meshcat_map_view import add_meshcat_views
        systems["meshcat_visualizer"], systems["meshcat_map_view"] = add_meshcat_views(
            builder, meshcat, scene_graph, mapper, planner, kin, OccupancyMap.for_scenario(sc), dt, fusion)
    diagram = builder.Build()
    diagram.set_name(f"nbvs_mission_{sc.name}")
    return MissionDiagram(diagram, systems, kin, mesh, gt, plant)
