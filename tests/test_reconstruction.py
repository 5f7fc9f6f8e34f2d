"""Reconstruction metrics (accuracy, completeness, Chamfer, precision / recall / F-score)
against hand-computed cases, and the SurfaceFusion system's TSDF mesh (Drake style)."""

import numpy as np
import pytest
import trimesh
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from nbvs_drake.config import Scenario
from nbvs_drake.perception.reconstruction import depth_from_points, mesh_metrics, point_metrics
from nbvs_drake.systems.messages import RegisteredScan
from nbvs_drake.systems.surface_fusion import SurfaceFusion
from nbvs_drake.world.objects import ObjectMesh, sample_surface
from nbvs_drake.world.pose import look_at
from nbvs_drake.world.sensor import intrinsics

R = 0.1  #: the test sphere's radius (m)


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=6, radius=R)  # faceting error ~0.01 mm
    V, T = np.asarray(m.vertices, float), np.asarray(m.faces, np.int32)
    gt = sample_surface(ObjectMesh(V, T), 20000, np.random.default_rng(1))
    return V, T, gt


def test_a_surface_offset_by_a_known_distance_has_that_accuracy(sphere):
    V, T, gt = sphere
    for off in (0.002, 0.004):
        model = sample_surface(ObjectMesh(V, T), 20000, np.random.default_rng(2)) * (1 + off / R)
        m = point_metrics(model, V, T, gt, 0.02)
        assert m["accuracy_m"] == pytest.approx(off, abs=5e-5)
        assert m["accuracy_p90_m"] == pytest.approx(off, abs=5e-5)
        assert m["precision"]["3mm"] == (1.0 if off < 0.003 else 0.0)
        assert m["precision"]["5mm"] == 1.0 and m["precision"]["voxel"] == 1.0
        # completeness: the nearest model point of a ground-truth sample, at least the offset
        assert off <= m["completeness_m"] < off + 0.002
        assert m["chamfer_m"] == pytest.approx(0.5 * (m["accuracy_m"] + m["completeness_m"]), abs=1e-6)


def test_half_a_sphere_has_a_recall_of_one_half(sphere):
    V, T, gt = sphere
    model = sample_surface(ObjectMesh(V, T), 40000, np.random.default_rng(3))
    model = model[model[:, 2] > 0]  # the upper half
    m = point_metrics(model, V, T, gt, 0.02)
    # the ground truth within 3 mm of the half: the half and a 3 mm band below its rim
    band = 0.003 / (np.pi * R)
    assert 0.5 <= m["recall"]["3mm"] <= 0.5 + band + 0.01
    assert m["precision"]["3mm"] == 1.0 and m["accuracy_m"] < 1e-4
    p, r = m["precision"]["3mm"], m["recall"]["3mm"]
    assert m["fscore"]["3mm"] == pytest.approx(2 * p * r / (p + r), abs=1e-6)
    assert m["fscore"]["3mm"] == pytest.approx(2 / 3, abs=0.02)
    # the mesh of that half: the same recall, measured to its triangles
    keep = np.all(V[T][:, :, 2] > 0, axis=1)
    mm = mesh_metrics(V, T[keep], V, T, gt, 0.02, np.random.default_rng(4))
    assert 0.5 - 0.01 <= mm["recall"]["3mm"] <= 0.5 + band + 0.01 and mm["precision"]["3mm"] == 1.0


def test_an_empty_model_scores_zero():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    T = np.array([[0, 1, 2]], np.int32)
    gt = np.array([[0.1, 0.1, 0.0]])
    m = point_metrics(np.zeros((0, 3)), V, T, gt, 0.02)
    assert m["fscore"]["5mm"] == 0.0 and m["accuracy_m"] is None and m["completeness_m"] is None
    assert mesh_metrics(V, np.zeros((0, 3), np.int32), V, T, gt, 0.02, np.random.default_rng(0))["recall"]["3mm"] == 0


def test_surface_fusion_meshes_the_registered_scans(sphere):
    """SurfaceFusion: two scans of a sphere on the table, from the front and from the back,
    FixValue'd as registered scans; its mesh lies on the sphere (within a voxel) and covers
    both sides; a scan not integrated is left out; the table is cropped away."""
    V, T, _ = sphere
    sc = Scenario().check()
    c = np.array([0.0, 0.0, sc.scene.table_height + R + 0.05])
    fusion = SurfaceFusion(sc.scene, sc.mapper, sc.sensor, 0.1)
    sim = Simulator(fusion)
    ctx = sim.get_mutable_context()
    port = fusion.GetInputPort("registered_scan")
    intr = intrinsics(sc.sensor)
    rays = _camera_rays(intr)

    def scan(k, eye, integrate=True):
        X = look_at(eye, c)
        P = _ray_sphere(X, rays, c, R)
        assert len(P) > 500
        np.testing.assert_array_less(np.abs(depth_from_points(P, X, *intr)[depth_from_points(P, X, *intr) > 0]), 5)
        port.FixValue(ctx, AbstractValue.Make(RegisteredScan(k, X[:3, 3], P, np.zeros((0, 3)), integrate, {}, X)))
        sim.AdvanceTo(0.1 * k)

    scan(1, c + [-0.8, 0.0, 0.3])
    Vm, Tm = fusion.GetOutputPort("mesh").Eval(ctx)
    assert len(Tm) > 200
    d = np.abs(np.linalg.norm(Vm - c, axis=1) - R)
    assert np.percentile(d, 95) < 0.003
    assert Vm[:, 0].max() < c[0] + 0.03  # one side only
    scan(2, c + [0.8, 0.1, 0.3], integrate=False)  # not integrated: left out
    assert len(fusion.GetOutputPort("mesh").Eval(ctx)[1]) == len(Tm)
    scan(3, c + [0.8, 0.1, 0.3])
    Vm, Tm = fusion.GetOutputPort("mesh").Eval(ctx)
    assert Vm[:, 0].max() > c[0] + 0.08 and Vm[:, 0].min() < c[0] - 0.08  # both sides now
    assert np.percentile(np.abs(np.linalg.norm(Vm - c, axis=1) - R), 95) < 0.003
    assert Vm[:, 2].min() >= sc.scene.table_height + sc.mapper.table_clearance - 1e-9


def _camera_rays(intr):
    w, h, fx, fy, cx, cy = intr
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    d = np.stack([(u.ravel() - cx) / fx, (v.ravel() - cy) / fy, np.ones(u.size)], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _ray_sphere(X, rays, c, r):
    """The first hits of the camera's rays on the sphere, world frame."""
    o = X[:3, 3]
    d = rays @ X[:3, :3].T
    oc = o - c
    b = d @ oc
    disc = b * b - (oc @ oc - r * r)
    ok = disc > 0
    t = -b[ok] - np.sqrt(disc[ok])
    return o + t[:, None] * d[ok]


def test_surface_fusion_leaves_out_a_scan_its_registration_misplaced(sphere):
    """Five scans of the sphere from around it, FixValue'd as registered scans; the fourth's
    registration put it 6 cm off (its points and pose moved together, as a registration
    error moves them). SurfaceFusion's mesh leaves it out (`left_out` names it, its conflict
    share above mapper.scan_conflict) and lies on the sphere; with the fourth registered
    right, every scan stays; with mapper.scan_conflict 1 the misplaced one stays, and the
    mesh carries its surface off the sphere."""
    from nbvs_drake.perception.reconstruction import consistent_scans, owned_by
    V, T, _ = sphere
    c = np.array([0.0, 0.0, Scenario().check().scene.table_height + R + 0.05])
    E = np.eye(4)
    E[:3, 3] = [0.04, -0.045, 0.0]

    def run(misplaced: bool, scan_conflict: float = 0.05):
        sc = Scenario().check()
        sc.mapper.scan_conflict = scan_conflict
        fusion = SurfaceFusion(sc.scene, sc.mapper, sc.sensor, 0.1)
        sim = Simulator(fusion)
        ctx = sim.get_mutable_context()
        intr = intrinsics(sc.sensor)
        rays = _camera_rays(intr)
        for k in range(5):
            a = 2 * np.pi * k / 5
            X = look_at(c + [0.8 * np.cos(a), 0.8 * np.sin(a), 0.3], c)
            P = _ray_sphere(X, rays, c, R)
            if misplaced and k == 3:
                X, P = E @ X, P + E[:3, 3]
            fusion.GetInputPort("registered_scan").FixValue(
                ctx, AbstractValue.Make(RegisteredScan(k + 1, X[:3, 3], P, np.zeros((0, 3)), True, {}, X)))
            sim.AdvanceTo(0.1 * (k + 1))
        Vm, _ = fusion.GetOutputPort("mesh").Eval(ctx)
        d = np.abs(np.linalg.norm(Vm - c, axis=1) - R)
        return fusion.GetOutputPort("left_out").Eval(ctx), d, fusion.GetOutputPort("scans").Eval(ctx), intr

    left_out, d, scans, intr = run(misplaced=True)
    assert list(left_out) == [3] and left_out[3] > 0.05, left_out
    assert np.percentile(d, 95) < 0.003
    assert consistent_scans(scans, intr)[0] == [0, 1, 2, 4]
    # the point model's cleaning: the misplaced scan's returns are its own, the others' are not
    P3 = _ray_sphere(look_at(c + [0.8 * np.cos(6 * np.pi / 5), 0.8 * np.sin(6 * np.pi / 5), 0.3], c),
                     _camera_rays(intr), c, R) + E[:3, 3]
    P0 = _ray_sphere(look_at(c + [0.8, 0.0, 0.3], c), _camera_rays(intr), c, R)
    assert owned_by(P3, [scans[3]], intr).mean() > 0.95 and owned_by(P0, [scans[3]], intr).mean() < 0.02
    left_out, d, _, _ = run(misplaced=False)
    assert left_out == {} and np.percentile(d, 95) < 0.003
    left_out, d, _, _ = run(misplaced=True, scan_conflict=1.0)
    assert left_out == {} and np.percentile(d, 99) > 0.01
