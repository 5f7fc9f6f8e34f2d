import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from nbvs_drake.config import Scenario
from nbvs_drake.mapping import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from nbvs_drake.systems.messages import RegisteredScan
from nbvs_drake.systems.octree_mapper import OctreeMapper


def _wall_scan():
    """A camera at x = -1 looking along +x at a wall of points at x = 0.1 inside W_box."""
    ys, zs = np.meshgrid(np.linspace(-0.2, 0.2, 81), np.linspace(0.5, 0.8, 61))
    pts = np.stack([np.full(ys.size, 0.1), ys.ravel(), zs.ravel()], axis=1)
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # camera z = world x
    X = RigidTransform(R=__import__("pydrake.math", fromlist=["RotationMatrix"]).RotationMatrix(R),
                       p=[-1.0, 0.0, 0.65])
    return pts, X


def test_free_along_rays_occupied_at_hits_unknown_behind():
    sc = Scenario().check()
    m0 = OccupancyMap.for_scenario(sc)
    pts, X = _wall_scan()
    m1, stats = m0.integrate(X.translation(), pts, sc.mapper.table_clearance)
    assert stats["object_points"] == len(pts)
    c = m1.classes()
    spec = m1.spec
    idx = lambda p: tuple(((np.asarray(p) - spec.bmin) // spec.res).astype(int))  # noqa: E731
    assert c[idx([0.11, 0.0, 0.65])] == OCCUPIED  # the wall
    assert c[idx([-0.2, 0.0, 0.65])] == FREE  # in front of it, on the rays
    assert c[idx([0.3, 0.0, 0.65])] == UNKNOWN  # behind it
    assert c[idx([-0.2, 0.3, 0.65])] == UNKNOWN  # beside the frustum of the points
    # probabilities follow OctoMap's sensor model: one hit 0.7, one miss 0.4
    p = m1.probabilities()
    assert abs(p[idx([0.11, 0.0, 0.65])] - 0.7) < 1e-6
    assert abs(p[idx([-0.2, 0.0, 0.65])] - 0.4) < 1e-6
    # the input map is unchanged (immutable snapshots)
    assert m0.unknown_count() == np.prod(spec.dims)
    # a second identical scan: one update per voxel per scan, clamped
    m2, _ = m1.integrate(X.translation(), pts, sc.mapper.table_clearance)
    assert abs(m2.probabilities()[idx([0.11, 0.0, 0.65])] - 0.7 * 0.7 / (0.7 * 0.7 + 0.3 * 0.3)) < 1e-5
    ms = m2
    for _ in range(20):
        ms, _ = ms.integrate(X.translation(), pts, sc.mapper.table_clearance)
    assert abs(ms.probabilities()[idx([0.11, 0.0, 0.65])] - 0.971) < 1e-5
    assert abs(ms.probabilities()[idx([-0.2, 0.0, 0.65])] - 0.1192) < 1e-5


def test_table_points_are_not_object_hits():
    sc = Scenario().check()
    m0 = OccupancyMap.for_scenario(sc)
    pts = np.array([[0.0, 0.0, sc.scene.table_height + 0.001], [0.0, 0.05, 0.6]])
    m1, stats = m0.integrate(np.array([-1.0, 0.0, 0.9]), pts, sc.mapper.table_clearance)
    assert stats["object_points"] == 1
    assert m1.counts()["occupied"] == 1


def test_mapper_system_integrates_each_registered_scan_once():
    sc = Scenario().check()
    mapper = OctreeMapper(sc.scene, sc.mapper, 0.1)
    sim = Simulator(mapper)
    ctx = sim.get_mutable_context()
    pts, X = _wall_scan()
    port = mapper.GetInputPort("registered_scan").FixValue(ctx, AbstractValue.Make(RegisteredScan()))
    sim.AdvanceTo(0.25)
    assert mapper.GetOutputPort("map").Eval(ctx).scan_count == 0  # no scan yet
    scan = RegisteredScan(1, X.translation(), pts, np.zeros((0, 3)), True, {"plan_id": 0})
    port.GetMutableData().set_value(scan)
    sim.AdvanceTo(0.55)
    m = mapper.GetOutputPort("map").Eval(ctx)
    assert m.scan_count == 1
    assert m.counts()["occupied"] > 50
    rep = mapper.GetOutputPort("scan_report").Eval(ctx)
    assert rep.scan_index == 1 and rep.info["points"] == len(pts) and rep.info["plan_id"] == 0
    assert rep.info["integrated"] and rep.info["sensor_origin"] == list(X.translation())
    sim.AdvanceTo(1.0)  # the same scan on the input: integrated once
    assert mapper.GetOutputPort("map").Eval(ctx).scan_count == 1
    # a scan whose registration failed is counted, not integrated
    port.GetMutableData().set_value(RegisteredScan(2, X.translation(), pts + 0.3, np.zeros((0, 3)), False, {}))
    sim.AdvanceTo(1.25)
    m2 = mapper.GetOutputPort("map").Eval(ctx)
    assert m2.scan_count == 2 and np.array_equal(m2.logodds, m.logodds)
    assert not mapper.GetOutputPort("scan_report").Eval(ctx).info["integrated"]


def test_no_return_pixels_clear_free_space():
    from nbvs_drake.world.sensor import no_return_rays, ray_directions
    sc = Scenario().check()
    dirs = ray_directions(sc.sensor, 1)[0]
    depth = np.full((144, 176), np.inf, np.float32)
    depth[0, 0] = np.nan
    depth[0, 1] = 0.0  # too close
    _, X = _wall_scan()
    ends = no_return_rays(depth, X.GetAsMatrix4(), dirs, 5.0)
    assert len(ends) == depth.size - 2
    m, stats = OccupancyMap.for_scenario(sc).integrate(X.translation(), np.zeros((0, 3)), 0.005, ends)
    assert stats["object_points"] == 0
    assert m.counts()["occupied"] == 0 and m.counts()["free"] > 1000


def test_save_load_roundtrip(tmp_path):
    sc = Scenario().check()
    pts, X = _wall_scan()
    m, _ = OccupancyMap.for_scenario(sc).integrate(X.translation(), pts, 0.005)
    m.save_npz(tmp_path / "m.npz")
    m2 = OccupancyMap.load_npz(tmp_path / "m.npz")
    np.testing.assert_array_equal(m.logodds, m2.logodds)
    np.testing.assert_array_equal(m.object_points, m2.object_points)
    assert m2.scan_count == 1 and m2.spec.dims == m.spec.dims
