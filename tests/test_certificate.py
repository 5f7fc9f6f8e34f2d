"""The free-space certificate in front of Drake's collision checks (planning/certificate.py):
its forward kinematics is Drake's, it never calls a state free that Drake finds in collision
or in collision that Drake finds free
(random states and states within ~1e-6 of a contact, in every kind of world the planner and
the executed-motion checks build), and it does prove most free states free."""

import numpy as np
import pytest
from conftest import drake_free, near_contacts, random_states

from nbvs_drake.config import load_scenario
from nbvs_drake.planning.certificate import COLLIDING, FREE, ROBOT_BODIES
from nbvs_drake.planning.collision import CollisionModel
from nbvs_drake.world.objects import build_object


def test_forward_kinematics_is_drakes(kin):
    model = CollisionModel(load_scenario(), kin)
    plant = model.diagram.plant()
    ctx = plant.CreateDefaultContext()
    for q in random_states(kin, 12, seed=3):
        plant.SetPositions(ctx, kin.to_positions(q[None])[0])
        T = model.certificate.body_poses(q)
        for k, name in enumerate(ROBOT_BODIES):
            X = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName(name)).GetAsMatrix4()
            np.testing.assert_allclose(T[k], X, atol=1e-12)


def _worlds(kin, tmp_path, first_scan_map):
    sc = load_scenario()
    yield "W_box", CollisionModel(sc, kin)
    yield "cluttered room", CollisionModel(load_scenario("cluttered_room"), kin)
    yield "true object (mesh), padded", CollisionModel(
        sc, kin, object_obj=str(build_object(sc).write_obj(tmp_path / "object.obj")), padding=0.01)
    sc1, omap = first_scan_map
    yield "map boxes", CollisionModel(sc1, kin, obstacle_boxes=omap.obstacle_boxes(300)[0])


def test_the_certificate_never_frees_a_state_drake_finds_in_collision(kin, tmp_path, first_scan_map):
    for name, model in _worlds(kin, tmp_path, first_scan_map):
        assert model.certificate is not None, name
        q = random_states(kin, 4000, seed=11)
        free = drake_free(model, q)
        edge = near_contacts(model, q, free)
        q_all = np.concatenate([q, edge, near_contacts(model, q[::-1], free[::-1])])
        drake = drake_free(model, q_all)
        verdict = model.certificate.classify(q_all)
        cert, hit = verdict == FREE, verdict == COLLIDING
        assert not np.any(cert & ~drake), f"{name}: {int(np.sum(cert & ~drake))} states certified but in collision"
        assert not np.any(hit & drake), f"{name}: {int(np.sum(hit & drake))} states proved colliding but free"
        np.testing.assert_array_equal(model.free(q_all), drake, err_msg=name)
        # and it is worth having: most free random states are proved free without Drake
        assert cert[: len(q)].sum() >= 0.7 * free.sum(), f"{name}: {cert[:len(q)].sum()} of {free.sum()}"
        assert hit[: len(q)].sum() >= 0.3 * (~free).sum(), f"{name}: {hit[:len(q)].sum()} of {(~free).sum()}"
        assert 0.1 < free.mean() < 0.95, name  # the worlds have both free and colliding states


@pytest.mark.parametrize("q_case", ["folded arm", "table", "clear"])
def test_known_states_keep_their_verdicts(kin, q_case):
    """The collision tests' hand-made states (tests/test_collision.py), with and without the
    certificate."""
    q = {"folded arm": [-1.6, 1.0, 0.0, 0.0, 0.5, -2.2, -2.0, 0.0],
         "table": [-0.5, 0.0, 0.0, 0, 0.0, 0, 0, 0],
         "clear": [-1.6, 1.0, 0.3, 0, 0.4, -0.3, -0.3, 0]}[q_case]
    sc = load_scenario()
    with_cert, without = CollisionModel(sc, kin), CollisionModel(sc, kin, certificate=False)
    assert without.certificate is None
    assert with_cert.free(np.array(q))[0] == without.free(np.array(q))[0] == (q_case == "clear")


def test_self_collisions_are_proved_from_the_robot_pairs(kin):
    """States where the robot touches only itself (the arm's last link folded onto its first
    link or the base): the certificate proves most of them colliding from balls inside the
    robot's own geometries, and none that Drake finds free, on both sides of the contacts."""
    model = CollisionModel(load_scenario(), kin)
    q = random_states(kin, 3000, seed=5)
    q[:, :2] = [-1.6, 1.0]  # far from the table and W_box: every collision is the robot's own
    free = drake_free(model, q)
    assert 0.05 < (~free).mean() < 0.9
    q_all = np.concatenate([q, near_contacts(model, q, free, both=True)])
    drake = drake_free(model, q_all)
    hit = model.certificate.classify(q_all) == COLLIDING
    assert not np.any(hit & drake), f"{int(np.sum(hit & drake))} states proved colliding but free"
    assert hit[: len(q)].sum() >= 0.7 * (~free).sum(), f"{hit[:len(q)].sum()} of {(~free).sum()}"
    np.testing.assert_array_equal(model.free(q_all), drake)
