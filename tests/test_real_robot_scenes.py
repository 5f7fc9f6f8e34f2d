"""The real-robot scenes (Vasquez-Gomez et al. 2017 §8.4): the office chair in a room, the
suitcase among obstacles, the humanoid on a box; objects on the floor or on a box; the
automatic W_box; the stop on the unknown voxels a view can reach; the Kinect's planner model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nbvs_drake.config import load_scenario
from nbvs_drake.errors import ScenarioError
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.world.objects import build_object
from nbvs_drake.world.primitives import box, cylinder, sphere
from nbvs_drake.world.scene import environment_boxes
from nbvs_drake.world.sensor import binned_cloud
from nbvs_drake.world.shapes import SHAPES

SCENES = ["real_robot", "real_robot_obstacles", "real_robot_humanoid"]


def _closed_volume(V, T) -> float:
    """The signed volume of a closed mesh (positive when its triangles face outwards)."""
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize("make, volume", [
    (lambda: box((0, 0, 0), (0.2, 0.3, 0.4)), 0.024),
    (lambda: box((0, 0, 0), (0.2, 0.3, 0.4), yaw=0.7, about=(0.1, 0.1)), 0.024),
    (lambda: cylinder((0.1, 0.2), 0.0, 0.5, 0.1, sides=64), np.pi * 0.01 * 0.5),
    (lambda: cylinder((0.1, 0.2), 0.0, 0.5, 0.1, sides=64, axis="x"), np.pi * 0.01 * 0.5),
    (lambda: cylinder((0.1, 0.2), 0.0, 0.5, 0.1, sides=64, axis="y"), np.pi * 0.01 * 0.5),
    (lambda: sphere((0, 0, 1), 0.2, rings=32, sectors=64), 4 / 3 * np.pi * 0.008),
])
def test_primitives_are_closed_and_face_outwards(make, volume):
    V, T = make()
    assert _closed_volume(V, T) == pytest.approx(volume, rel=0.02)


@pytest.mark.parametrize("kind, extent", [("chair", (0.58, 0.6, 0.9)), ("suitcase", (0.26, 0.42, 0.9)),
                                          ("humanoid", (0.11, 0.27, 0.58))])
def test_the_built_objects_have_their_real_size_and_convex_parts(kind, extent):
    V, T, parts = SHAPES[kind]()
    size = V.max(axis=0) - V.min(axis=0)
    assert np.allclose(size, extent, atol=0.03)
    assert V[:, 2].min() == pytest.approx(0.0)
    assert parts.max() >= 8  # thin parts, each its own convex piece
    for k in np.unique(parts):  # every part closed and facing outwards
        assert _closed_volume(V, T[parts == k]) > 0


@pytest.mark.parametrize("support, top", [("floor", 0.0), ("box", 0.3), ("table", 0.43)])
@pytest.mark.parametrize("kind", ["bunny", "chair"])
def test_an_object_rests_on_its_support_inside_an_automatic_wbox(support, top, kind):
    sc = load_scenario(settings=[f"scene.object.kind={kind}", f"scene.support={support}",
                                 "scene.box_size=[0.4, 0.4, 0.3]", "scene.bbox_min=null", "scene.bbox_max=null"])
    mesh = build_object(sc)
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(top)
    assert sc.scene.bbox_min[2] == pytest.approx(top)
    assert np.all(lo[:2] >= np.array(sc.scene.bbox_min[:2]) + 0.049)
    assert np.all(hi <= np.array(sc.scene.bbox_max) - 0.049)
    names = [b.name for b in environment_boxes(sc.scene)]
    assert ("table_top" in names) == (support == "table")
    assert ("support_box" in names) == (support == "box")


def test_a_reconstructed_box_is_part_of_the_object_and_not_of_the_environment():
    sc = load_scenario("real_robot_humanoid")
    mesh = build_object(sc)
    assert mesh.bounds[0][2] == pytest.approx(0.0)
    assert mesh.bounds[1][2] == pytest.approx(0.3 + 0.58, abs=0.01)
    assert sc.scene.base_z() == 0.0 and sc.scene.bbox_min[2] == 0.0
    assert "support_box" not in [b.name for b in environment_boxes(sc.scene)]
    with pytest.raises(ScenarioError, match="box_reconstructed needs"):
        load_scenario(settings=["scene.box_reconstructed=true"])


def test_the_scenes_have_their_known_obstacles():
    names = {n: [b.name for b in environment_boxes(load_scenario(n).scene)] for n in SCENES}
    assert {"wall_px", "wall_nx", "wall_py", "wall_ny", "desk", "bookcase"} <= set(names["real_robot"])
    assert {"crate", "cabinet", "bin"} <= set(names["real_robot_obstacles"])
    assert "table_top" not in names["real_robot"]


def test_preset_setting_runs_the_same_scene_with_the_papers_planner():
    ours, paper = load_scenario("real_robot"), load_scenario("real_robot", settings=["preset=real_robot_paper"])
    assert (ours.scene.object.kind, paper.scene.object.kind) == ("chair", "chair")
    assert paper.scene.clutter == ours.scene.clutter == "room"
    assert paper.planner.n_candidates == 100_000 and paper.planner.overlap_h == 0.65
    assert paper.planner.rrt_max_nodes() == 10_000 and paper.planner.utility.samples == 500
    assert ours.planner.n_candidates == 4000 and ours.planner.is_roadmap()
    for sc in (ours, paper):
        assert sc.sensor.preset == "kinect" and sc.mapper.voxel_size == 0.03
        assert sc.mission.stop_unknown_voxels == 30 and sc.mission.on_collision == "stop"
        assert sc.noise.sigma_w == 0.28


def test_the_support_band_follows_the_sensors_depth_error():
    assert load_scenario().mapper.table_clearance == 0.005
    assert load_scenario(settings=["sensor.preset=kinect"]).mapper.table_clearance == pytest.approx(0.0137, abs=1e-4)
    assert load_scenario(settings=["mapper.table_clearance=0.01"]).mapper.table_clearance == 0.01


def test_unknown_voxels_walled_in_by_surface_are_not_left_to_reach():
    sc = load_scenario()
    m = OccupancyMap.for_scenario(sc)
    lo = m.logodds.copy()
    lo[:] = m.model.l_free - 1.0  # everything seen free
    shell = np.zeros(lo.shape, bool)
    shell[10:16, 10:16, 5:11] = True
    lo[shell] = m.model.l_occ + 1.0  # a solid's surface
    lo[11:15, 11:15, 6:10] = 0.0  # its inside, unknown (4 x 4 x 4)
    lo[0:3, 0:3, 3:6] = 0.0  # an unknown pocket in the open, on the map's side
    lo[20:23, 20:23, 4:7] = 0.0  # and one in free space
    m2 = OccupancyMap(m.spec, m.model, lo.astype(np.float32))
    assert m2.unknown_count() == 64 + 27 + 27
    assert m2.reachable_unknown_count() == 54


def test_binned_cloud_keeps_each_blocks_centre_pixel():
    w, h = 7, 5
    P = np.arange(3 * w * h, dtype=float).reshape(3, h * w)
    B = binned_cloud(P, (w, h), 3)
    assert B.shape == (3, 2 * 2)
    img = P.reshape(3, h, w)
    assert np.array_equal(B.reshape(3, 2, 2), img[:, 1::3, 1::3])


@pytest.mark.parametrize("name", SCENES)
def test_each_scene_renders_the_object_from_the_start(name, tmp_path):
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.world.robot import RobotKinematics
    sc = load_scenario(name)
    kin = RobotKinematics(sc.robot.urdf)
    r = ScanRenderer(sc, tmp_path, kin)
    scan = r.scan(np.array(sc.robot.start))
    m = r.integrate(OccupancyMap.for_scenario(sc), scan)
    assert len(m.object_points) > 2000  # the object is beyond the Kinect's 0.7 m and in view


#: a short run of a real-robot scene: two scans, few candidates and rollouts, no ceiling
SHORT = ["mission.max_scans=2", "planner.n_candidates=300", "planner.utility.samples=20",
         "planner.motion_planner.vertices=300", "localisation.verified_views.recovery_rollouts=20",
         "mission.coverage_ceiling=false", "scene.gt_points=4000"]


@pytest.mark.parametrize("name", SCENES)
def test_each_scene_is_reconstructed_in_a_short_run(name, tmp_path):
    from nbvs_drake.app.mission import run_mission
    s = run_mission(load_scenario(name, settings=SHORT), tmp_path, verbose=False)
    assert s["scans"] >= 1 and s["coverage_voxel"] > 0.2, s
    assert s["reachable_unknown_voxels"] <= s["unknown_voxels"]
    iters = [json.loads(x) for x in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    assert all("coverage_1cm" in r for r in iters)
    plans = [r["plan"] for r in iters if r["plan"].get("status") == "ok"]
    assert all(p["path_nodes"] >= 2 for p in plans)
    assert (tmp_path / "replay.html").stat().st_size > 0
    assert len(list((tmp_path / "scene").glob("object_part*.obj"))) >= 10  # collided part by part


@pytest.mark.slow
def test_real_robot_chair_with_eu_reconstructs_most_of_what_a_view_can_see(tmp_path):
    """`nbvs reconstruct --scenario real_robot` as it is: no collision, most of the ceiling at 1 cm
    (the record EU-nbvs_s1 at 3da1b05: 100.5 %; at f88d17c it drove into the chair after 75 paths,
    its frames registered 0.1-0.4 m off)."""
    from nbvs_drake.app.mission import run_mission
    s = run_mission(load_scenario("real_robot"), tmp_path, verbose=False)
    assert s["collisions"] == 0
    assert s["coverage_of_ceiling_1cm"] >= 0.85, s["coverage_of_ceiling_1cm"]


@pytest.fixture(scope="module")
def room_scans(tmp_path_factory):
    """The real_robot scene: the registration config and model after the exact first scan,
    and a renderer."""
    from nbvs_drake.perception.registration import environment_model, region_mask, registration_config
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.world.robot import RobotKinematics
    sc = load_scenario("real_robot")
    r = ScanRenderer(sc, tmp_path_factory.mktemp("room"), RobotKinematics(sc.robot.urdf))
    cfg = registration_config(sc.localisation, sc.scene)
    q0 = np.array(sc.robot.start)
    s1 = r.scan(q0).points
    model = environment_model(sc.scene, cfg).merged(s1[region_mask(sc.scene, s1, cfg)], cfg,
                                                    r.kin.camera_poses(q0)[0][:3, 3])
    return sc, r, cfg, model


def test_the_room_model_has_only_the_faces_a_camera_in_the_room_can_see(room_scans):
    """A wall's outer face and the cabinet's back (against the wall) would share the far
    voxels of the faces they back onto and lend them their normals."""
    from nbvs_drake.world.scene import ROOM_HALF
    sc, _, cfg, _ = room_scans
    from nbvs_drake.perception.registration import environment_model
    m = environment_model(sc.scene, cfg)
    P, N = m.points.astype(float), m.normals.astype(float)
    assert np.all(np.abs(P[:, :2]) <= ROOM_HALF + 1e-5)
    on_wall_ny = np.abs(P[:, 1] + ROOM_HALF) < 1e-3  # the -y wall's inner face: its normal points in
    assert on_wall_ny.sum() > 50 and np.all(N[on_wall_ny, 1] > 0.99)
    assert P[:, 2].max() > 1.5  # the walls above the chair are in the region


@pytest.mark.parametrize("q_true, offset, tol_m", [
    # beside the chair: most of the scan is the seat's side, new surface; the desk and the +y wall
    # fix y and the heading. Before surfaces had to face the same way to match, the chair
    # pulled x ~4 cm (the new side tucked into the front seen first): tolerance 6 cm then
    ([0.0, -1.5, 1.5708, 0.0, 1.6, -1.7, -0.135, 0.0], (0.12, -0.10, 0.06), 0.015),
    # the chair's other side, its backrest's front (4 cm from the rear face the first scan saw):
    # matched to that rear face it pulled the pose ~4.5 cm against every wall in view
    ([1.0, 0.85, -2.4, 0.0, 1.6, -1.7, -0.135, 0.0], (0.05, -0.04, 0.04), 0.015),
    # turned away from the chair, to the room's corner: the bookcase, the desk and two walls
    ([0.6, 0.2, 0.8, 0.0, 1.6, -1.4, -0.2, 0.0], (-0.10, 0.08, -0.05), 0.02)])
def test_in_the_room_the_known_walls_fix_the_pose_where_the_chair_does_not(room_scans, q_true, offset, tol_m):
    """A scan expressed at a believed pose `offset` (dx, dy, dyaw) from the true one registers
    back to within `tol_m` and 0.01 rad: the walls and furniture beyond the chair's
    surroundings are matched point to plane in every stage and in the fit. At f88d17c only the
    coarse stage saw them, and localisation frames of mostly new surface were registered
    0.1-0.4 m off, or not at all when they saw no chair (measured 0.037 m and 0.012 m here)."""
    from nbvs_drake.perception.registration import KnownSolids, ScanView, region_mask, register_scan
    from nbvs_drake.world.pose import Correction, state_error
    sc, r, cfg, model = room_scans
    qt = np.array(q_true)
    qb = Correction(*offset).apply_state(qt)  # the belief: the truth moved by the offset
    Xt, Xb = r.kin.camera_poses(qt)[0], r.kin.camera_poses(qb)[0]
    M = Xb @ np.linalg.inv(Xt)
    P = r.scan(qt).points @ M[:3, :3].T + M[:3, 3]  # rendered at the truth, placed at the belief
    prior = np.diag(np.square([0.1, 0.1, 0.06]))
    view = ScanView(Xb[:3, 3], P, KnownSolids.of(sc.scene))
    res = register_scan(P[region_mask(sc.scene, P, cfg)], model, prior, cfg, view=view)
    assert res.applied, res.to_json()
    err = state_error(qt, res.correction.apply_state(qb))
    assert err[0] < tol_m and err[1] < 0.01, (err, res.to_json())
