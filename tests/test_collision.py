import numpy as np
import pytest

from nbvs_drake.config import Scenario
from nbvs_drake.planning.collision import CollisionModel


@pytest.fixture(scope="module")
def model(kin):
    return CollisionModel(Scenario(), kin)


def test_start_is_free_and_table_collides(model):
    sc = Scenario()
    assert model.free(np.array(sc.robot.start))[0]
    inside_table = np.array([0.0, 0.0, 0.0, 0, 0.3, 0, 0, 0])  # base at the table centre
    near_table = np.array([-0.5, 0.0, 0.0, 0, 0.0, 0, 0, 0])  # body overlaps the table edge
    clear = np.array([-1.6, 1.0, 0.3, 0, 0.4, -0.3, -0.3, 0])
    np.testing.assert_array_equal(model.free(np.array([inside_table, near_table, clear])), [False, False, True])


def test_arm_into_the_bounding_box_is_a_collision(model):
    # base 0.9 m from the table centre, arm horizontal at 0.70 m height: the wrist reaches
    # x = -0.9 + 0.787 = -0.11, inside W_box (the unknown region is an obstacle), above the table
    q = np.array([-0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert not model.free(q)[0]
    q[0] = -1.3  # wrist at x = -0.51: clear of W_box and the table
    assert model.free(q)[0]


def test_self_collision(model):
    # J3 folded fully back: link 4 into link 2
    q = np.array([-1.6, 1.0, 0.0, 0.0, 0.5, -2.2, -2.0, 0.0])
    assert not model.free(q)[0]


def test_path_free_detects_an_obstacle_between_two_free_states(model):
    a = np.array([-1.3, -0.9, 0.0, 0, 0.0, 0, 0, 0])
    b = np.array([-1.3, 0.9, 0.0, 0, 0.0, 0, 0, 0])
    assert model.free(np.array([a, b])).all()
    # base sliding sideways (a straight line in q) sweeps the arm through W_box? no: the arm
    # tip stays at x = -0.51; but turning it to face +y at x=-0.9 puts the arm over the table
    assert model.path_free(np.array([a, b]))
    c = a.copy()
    c[0] = -0.9
    c[1] = -0.9
    d = c.copy()
    d[1] = 0.9
    assert not model.path_free(np.array([c, d]))  # passes x=-0.9, y=0 (wrist in W_box)


def test_robot_collision_shapes_are_not_boxes(model):
    """Drake 1.51 aborts the whole process (BoxBoxGradient, drake#21947) when a box of the
    robot touches a box of the environment or the map within round-off; two long EU runs
    died that way. The robot's collision shapes are therefore cylinders."""
    from pydrake.geometry import Box, Role
    plant = model.diagram.plant()
    inspector = model.diagram.scene_graph().model_inspector()
    shapes = {}
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        if body is not None and body.model_instance() != plant.world_body().model_instance():
            shapes[inspector.GetName(gid)] = type(inspector.GetShape(gid)).__name__
    assert len(shapes) >= 8 and {"pedestal", "camera_housing"} <= {n.split("::")[-1] for n in shapes}, shapes
    assert not any(s == Box.__name__ for s in shapes.values()), shapes


def test_path_free_coarse_pass_gives_the_full_check(model):
    """path_free checks every 8th interpolated state first; its verdict is that of checking
    every state at once, on free paths and on paths that clip an obstacle briefly."""
    rng = np.random.default_rng(5)
    verdicts = []
    for _ in range(40):
        a = np.array([-1.4, rng.uniform(-1.2, 1.2), rng.uniform(-np.pi, np.pi), 0, 0.3, -0.2, 0, 0])
        b = a.copy()
        b[0] = rng.uniform(-1.4, -0.6)
        b[1] = rng.uniform(-1.2, 1.2)
        b[3:] += rng.normal(size=5) * 0.4
        ok = model.path_free(np.array([a, b]))
        assert ok == model.path_free(np.array([a, b]), coarse_stride=0)  # one pass over every state
        verdicts.append(ok)
    assert any(verdicts) and not all(verdicts)


def test_contacts_name_what_the_robot_touches(model):
    """A collision is reported with the geometries in contact: the base driven into the
    table touches the table; a free state touches nothing."""
    inside_table = np.array([-0.5, 0.0, 0.0, 0, 0.0, 0, 0, 0])
    assert not model.free(inside_table)[0]
    c = model.contacts(inside_table)
    assert c and all(x["depth_m"] > 0 for x in c)
    assert any(x["b"] == "table_top" and x["a"].startswith("patrolbot_katana::") for x in c)
    assert [x["depth_m"] for x in c] == sorted((x["depth_m"] for x in c), reverse=True)
    assert model.contacts(np.array([-1.6, 1.0, 0.3, 0, 0.4, -0.3, -0.3, 0])) == []


def test_base_clearance_pads_the_base_alone(kin):
    """planner.base_clearance: the padded model counts the base as colliding within the
    clearance of a chair (Drake's padding on the base link, the certificate's verdicts the
    same as Drake's), not the arm; the floor, lowered by the padding, leaves the base's own
    ground clearance; the true model is unchanged."""
    from nbvs_drake.config import load_scenario
    sc = load_scenario("cluttered_room")
    true, padded = CollisionModel(sc, kin), CollisionModel(sc, kin, base_padding=0.1)
    bare = CollisionModel(sc, kin, base_padding=0.1, certificate=False)
    # chair 0's seat spans x in [1.04, 1.46] on the +x axis; the base (radius 0.25) faces away
    tuck = [0.0, 0.35, -0.35, -0.25, 0.0]
    q = np.array([[1.46 + 0.25 + gap, 0.0, 0.0, *tuck] for gap in (0.05, 0.15)] + [sc.robot.start])
    np.testing.assert_array_equal(true.free(q), [True, True, True])
    np.testing.assert_array_equal(padded.free(q), [False, True, True])
    np.testing.assert_array_equal(bare.free(q), padded.free(q))
    # the base link alone is padded against the environment
    plant = padded.diagram.plant()
    world = plant.world_body().index()
    robot = padded.checker.robot_model_instances()[0]
    pads = {plant.get_body(b).name(): padded.checker.GetPaddingBetween(b, world) for b in plant.GetBodyIndices(robot)}
    assert pads.pop("base_link") == pytest.approx(0.1)
    assert pads and all(v == 0.0 for v in pads.values())


def test_paths_keep_the_base_clear_and_rollouts_meet_the_true_obstacles(kin):
    """PlanningObstacles with planner.base_clearance: each plan's obstacles carry the padded
    model for the positions and the paths (`for_paths`), the true one for the rest."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    sc = load_scenario("cluttered_room", settings=["planner.base_clearance=0.1"])
    obst = PlanningObstacles(sc, kin).for_map(OccupancyMap.for_scenario(sc))
    assert obst.padded is not None and obst.for_paths() is obst.padded
    q = np.array([[1.46 + 0.25 + 0.05, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0]])
    assert obst.free(q)[0] and not obst.for_paths().free(q)[0]
    plain = PlanningObstacles(load_scenario("cluttered_room"), kin).for_map(OccupancyMap.for_scenario(sc))
    assert plain.padded is None and plain.for_paths() is plain
    # with the whole W_box as the obstacle, also beside a W_box model given from outside
    wsc = load_scenario("cluttered_room", settings=["planner.base_clearance=0.1", "planner.map_obstacles=wbox"])
    given = CollisionModel(wsc, kin)
    wobst = PlanningObstacles(wsc, kin, given).for_map(OccupancyMap.for_scenario(wsc))
    assert wobst.collision is given and wobst.padded is not None
    assert wobst.free(q)[0] and not wobst.for_paths().free(q)[0]
