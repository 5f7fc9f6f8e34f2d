"""Planning under motion noise beyond the paper (planning/recovery.py): verified views (a
localisation frame before the sensing scan, correction, re-localisation) in the Localisation
system, the recovery geometry, and the expected utility's arm-only fallback."""

import copy

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from test_registration import _cloud, _first_scan_then_plan, renderer, second_scan_in_view  # noqa: F401

from nbvs_drake.config import VerifiedViews, load_scenario
from nbvs_drake.errors import ScenarioError
from nbvs_drake.perception.registration import KnownSolids, RegistrationConfig, region_mask
from nbvs_drake.planning.recovery import (
    aim_error,
    arm_correction,
    arm_only_candidates,
    camera_error,
    landmark_solids,
    landmarks_in_view,
    look_at_point,
    registration_landmarks,
    relocalisation_scores,
)
from nbvs_drake.world.motion import ControlSequence


def test_a_frame_that_cannot_be_registered_triggers_relocalisation_then_the_next_registers(renderer):  # noqa: F811
    """Verified views: the frame at the end of a noisy plan that misses the object is rejected
    by the registration (too few points); it is neither integrated nor counted, and the belief
    asks for re-localisation. The re-localisation view's frame (the object back in view)
    registers and corrects the belief, which then asks for a correction (it is not yet at
    the planned view); after the exact arm-only correction the frame is the sensing scan,
    with the two localisation frames reported beside it."""
    sc, r, s1 = renderer
    sc = copy.deepcopy(sc)
    sc.localisation.verified_views = VerifiedViews()
    q0, U, states, qt, qb, P2, Xb = second_scan_in_view(sc, r)
    loc, mapper, sim, ctx, pc, status = _first_scan_then_plan(sc, r, q0, U, states, s1.points)
    mctx, lctx = mapper.GetMyContextFromRoot(ctx), loc.GetMyContextFromRoot(ctx)
    tau_port = sim.get_system().GetInputPort("controls")
    m1 = mapper.GetOutputPort("map").Eval(mctx)
    # plan 1 is a view plan: its target is its planned end state
    tau_port.FixValue(ctx, AbstractValue.Make(ControlSequence(1, 0.1, U, states, "view", states[-1])))
    far = P2[~region_mask(sc.scene, P2, RegistrationConfig())][:500]  # nothing of the table or object
    pc.GetMutableData().set_value(_cloud(far))
    status.GetMutableData().set_value(np.array([1.0, len(U), 1.0]))
    sim.AdvanceTo(0.25)
    b = loc.GetOutputPort("belief").Eval(lctx)
    m = mapper.GetOutputPort("map").Eval(mctx)
    assert m.scan_count == 1 and np.array_equal(m.logodds, m1.logodds)  # not integrated, not counted
    assert b.check == "relocalise" and b.scan == 1 and b.frame == 2
    assert b.covariance[2, 2] > 0.01  # the plan's spread kept for the re-localisation view
    # the re-localisation view (here: no motion, the object back in view) registers
    hold = ControlSequence(2, 0.1, np.zeros((0, 7)), qb[None], "relocalise", states[-1])
    tau_port.FixValue(ctx, AbstractValue.Make(hold))
    sim.AdvanceTo(0.35)
    pc.GetMutableData().set_value(_cloud(P2))
    status.GetMutableData().set_value(np.array([2.0, 0.0, 1.0]))
    sim.AdvanceTo(0.45)
    b = loc.GetOutputPort("belief").Eval(lctx)
    assert b.check == "correct" and b.frame == 3 and not np.any(b.covariance)
    assert mapper.GetOutputPort("map").Eval(mctx).scan_count == 1
    from nbvs_drake.world.pose import state_error
    assert state_error(qt, b.state)[1] < 0.5 * state_error(qt, qb)[1]  # the heading error found
    # the exact arm-only correction: its frame is the sensing scan
    fix = ControlSequence(3, 0.1, np.zeros((0, 7)), b.state[None], "correct", states[-1])
    tau_port.FixValue(ctx, AbstractValue.Make(fix))
    sim.AdvanceTo(0.55)
    status.GetMutableData().set_value(np.array([3.0, 0.0, 1.0]))
    sim.AdvanceTo(0.65)
    m = mapper.GetOutputPort("map").Eval(mctx)
    rep = mapper.GetOutputPort("scan_report").Eval(mctx).info
    assert m.scan_count == 2 and rep["integrated"]
    assert [f["check"] for f in rep["frames"]] == ["relocalise", "correct"]
    assert loc.GetOutputPort("belief").Eval(lctx).check == ""


def test_recovery_geometry(kin):
    sc = load_scenario("teapot_eu_mu")
    q = np.array([-1.3, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])  # the start, looking at the table
    assert camera_error(kin, q, q) == pytest.approx((0.0, 0.0), abs=1e-6)
    # a heading error: the arm's first joint turns it back onto the planned look-at point
    point = look_at_point(kin, q, [0.0, 0.0, 0.6])
    off = q.copy()
    off[2] += 0.25
    assert aim_error(kin, off, point)[0] > 0.2
    fixed = arm_correction(kin, off, q, point)
    assert np.array_equal(fixed[:3], off[:3])  # the base stays: the motion is exact
    assert aim_error(kin, fixed, point)[0] < 0.02
    # re-localisation: a view of the table and the object scores higher than one away from it
    marks = registration_landmarks(sc, np.array([[0.0, 0.0, 0.6], [0.05, 0.0, 0.65]]), np.random.default_rng(0))
    away = q.copy()
    away[3] = 2.5  # the arm turned away from the table
    assert landmarks_in_view(kin, sc, q[None], marks)[0] > 0.1
    assert landmarks_in_view(kin, sc, away[None], marks)[0] == 0.0
    cov = np.diag([0.01, 0.01, 0.04])
    s = relocalisation_scores(kin, sc, np.stack([q, away]), cov, marks, np.random.default_rng(1))
    assert s[0] > 0.05 and s[1] == 0.0


def test_a_landmark_whose_surface_faces_away_is_not_in_view(kin):  # noqa: F811
    """mission.landmark_facing: landmarks with normals (L, 6) count only where the surface
    faces the camera. The object's side seen so far (normals towards the start) is in view
    from the start; seen from the far side of the table, the same points are the back of the
    object, and only the landmarks facing that camera count."""
    sc = load_scenario("teapot_eu_mu")
    q = np.array([-1.3, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])  # at -x, looking at the table
    far = q.copy()
    far[0], far[2] = 1.3, np.pi  # at +x, looking back at it
    P = np.array([[-0.05, y, z] for y in (-0.05, 0.0, 0.05) for z in (0.55, 0.6, 0.65)])
    toward_start = np.tile([-1.0, 0.0, 0.0], (len(P), 1))
    obj = np.concatenate([P, toward_start], axis=1)
    plain = landmarks_in_view(kin, sc, np.stack([q, far]), P)
    facing = landmarks_in_view(kin, sc, np.stack([q, far]), obj)
    assert plain[0] == 1.0 and plain[1] == 1.0  # in both fields of view
    assert facing[0] == 1.0 and facing[1] == 0.0  # but their surface faces the start
    # zero normals always face; with the environment, registration_landmarks gives (L, 6)
    assert landmarks_in_view(kin, sc, far[None], np.concatenate([P, 0 * P], axis=1))[0] == 1.0
    marks = registration_landmarks(sc, P, np.random.default_rng(0), object_normals=toward_start)
    assert marks.shape[1] == 6 and np.allclose(np.linalg.norm(marks[:, 3:], axis=1), 1.0)
    # the table top's underside faces down: never in view from above
    under = marks[marks[:, 5] < -0.5]
    assert len(under) and landmarks_in_view(kin, sc, q[None], under)[0] == 0.0
    s = relocalisation_scores(kin, sc, far[None], np.diag([1e-4, 1e-4, 1e-4]), obj, np.random.default_rng(1))
    assert s[0] == 0.0


def _seen_through_reference(solids, origin, P, tol):
    """Slab tests in numpy, box by box: the reference for KnownSolids' kernel."""
    from nbvs_drake.world.pose import rot_z
    out = np.zeros(len(P), bool)
    for c, h, yaw in zip(solids.centers, solids.half, solids.yaw):
        R = rot_z(yaw)
        o = (np.asarray(origin, float) - c) @ R
        d = (P - c) @ R - o
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-h - o) / d, (h - o) / d
        lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
        par = d == 0  # parallel to a slab: inside it always or never
        lo = np.where(par, np.where(np.abs(o) <= h, -np.inf, np.inf), lo)
        hi = np.where(par, np.where(np.abs(o) <= h, np.inf, -np.inf), hi)
        t0, t1_ = np.maximum(lo.max(axis=1), 0.0), np.minimum(hi.min(axis=1), 1.0)
        out |= (t1_ - t0) * np.linalg.norm(d, axis=1) > tol
    return out


def test_known_solids_block_the_segments_the_see_through_check_flags():
    """KnownSolids.blocked (the numba kernel of mission.landmark_occlusion and of the
    registration's see-through check) agrees with numpy slab tests on random segments in the
    cluttered room, only where asked; a chair's back hides the table from behind it, and a
    camera above the back sees over it."""
    sc = load_scenario("cluttered_room")
    solids = KnownSolids.of(sc.scene)
    rng = np.random.default_rng(0)
    O = rng.uniform([-2.2, -2.2, 0.2], [2.2, 2.2, 1.2], (40, 3))
    P = rng.uniform([-1.6, -1.6, 0.0], [1.6, 1.6, 1.0], (300, 3))
    pairs = rng.random((40, 300)) < 0.7
    B = solids.blocked(O, P, pairs, 0.01)
    ref = np.stack([_seen_through_reference(solids, o, P, 0.01) for o in O]) & pairs
    np.testing.assert_array_equal(B, ref)
    np.testing.assert_array_equal(solids.seen_through(O[0], P, 0.01), _seen_through_reference(solids, O[0], P, 0.01))
    assert 0.1 < B.sum() / pairs.sum() < 0.9
    # chair 0's back stands at x = 1.44 (0.45-0.85 m high); the table top is 0.43 m high
    o = np.array([[2.0, 0.0, 0.7], [2.0, 0.0, 1.1]])
    tgt = np.array([[0.3, 0.0, sc.scene.table_height]])
    np.testing.assert_array_equal(solids.blocked(o, tgt, np.ones((2, 1), bool))[:, 0], [True, False])


def test_landmark_occlusion_picks_a_relocalisation_view_that_sees_the_table(tmp_path):
    """From a base outside the chairs' ring (where nbvs_clear's re-localisation frames found
    nothing to register), the arm-only view ranked first with mission.landmark_occlusion
    returns several times the registration-region points of the one ranked first without
    it, rendered by the real depth camera; the occlusion-aware score knows the blind pick
    sees almost no landmark. Measured: 1274 against 302 points, scores 0.17 and 0.06."""
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.world.robot import RobotKinematics
    sc = load_scenario("cluttered_room", settings=["localisation.verified_views={landmarks: {occlusion: true}}"])
    kin = RobotKinematics(sc.robot.urdf)
    solids = landmark_solids(sc)
    assert solids is not None and landmark_solids(load_scenario("cluttered_room")) is None
    marks = registration_landmarks(sc, np.zeros((0, 3)), np.random.default_rng(0))
    q_now = np.array([1.6, 1.26, -0.55, 0.0, 0.35, -0.35, -0.25, 0.0])
    cand = arm_only_candidates(kin, q_now, 200, np.random.default_rng(3))
    cov = np.diag([0.062, 0.046, 0.039]) ** 2
    blind = relocalisation_scores(kin, sc, cand, cov, marks, np.random.default_rng(1))
    seen = relocalisation_scores(kin, sc, cand, cov, marks, np.random.default_rng(1), solids=solids)
    ia, ib = int(np.argmax(blind)), int(np.argmax(seen))
    assert seen[ia] < 0.1 < seen[ib] and blind[ia] > 0.5
    r = ScanRenderer(sc, tmp_path)
    cfg = RegistrationConfig()
    n = [int(region_mask(sc.scene, r.scan(cand[i]).points, cfg).sum()) for i in (ia, ib)]
    print("region points: blind pick", n[0], "occlusion-aware pick", n[1])
    assert n[1] > 3 * n[0]


def test_an_eu_plan_with_no_feasible_candidate_tries_the_arm_only_fallback(first_scan_map, kin):
    """Noise so large that every rollout of every candidate collides: without the fallback the
    plan is no_feasible; with planner.noise_fallback it tries views from the current base by
    the arm alone (exact under the noise) before it gives up, and finds one."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.interface import PlanRequest
    _, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["planner.n_candidates=400", "planner.eu_samples=20",
                                                 "noise.sigma_v=2.0", "noise.sigma_w=3.0"])
    q0 = np.array(sc.robot.start, float)

    def plan(fallback):
        sc.planner.noise_fallback = fallback
        return make_planner(sc, kin).plan(PlanRequest(omap, q0, np.random.default_rng(3)))
    res = plan(False)
    assert res.status == "no_feasible"
    res = plan(True)
    assert res.status == "ok" and res.factors["fallback"] == "arm_only"
    assert np.array_equal(res.q_goal[:3], q0[:3]) and not np.any(res.controls[:, :2])  # the base stays
    assert res.stages["fallback"]["eu_feasible"] >= 1


@pytest.mark.parametrize("check", ["", "relocalise"])
def test_the_planner_answers_a_localisation_frame(kin, first_scan_map, check):
    """NBVSPlanner (Drake style): a belief whose last frame asks for re-localisation gets an
    arm-only plan with the same target and no new report scan; a plain belief gets nothing new."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.recovery import Recovery
    from nbvs_drake.systems.messages import Belief
    from nbvs_drake.systems.nbvs_planner import NBVSPlanner, PlannerMemory
    sc, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["mission.verify_views=true"])
    q0 = np.array(sc.robot.start, float)
    impl = make_planner(sc, kin)
    sysm = NBVSPlanner.for_scenario(sc, impl, q0, Recovery(sc, kin, impl.motion, impl.obstacles))
    from pydrake.systems.analysis import Simulator
    sim = Simulator(sysm)
    ctx = sim.get_mutable_context()
    target = q0.copy()
    target[2] += 0.3
    mem = PlannerMemory(ControlSequence(4, 0.1, np.zeros((0, 7)), q0[None], "view", target), omap.scan_count,
                        answered_frame=1, target=target)
    ctx.get_mutable_abstract_state(0).set_value(mem)
    sysm.GetInputPort("map").FixValue(ctx, AbstractValue.Make(omap))
    cov = np.diag([0.004, 0.004, 0.02])
    sysm.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(Belief(1, q0, q0, cov, 2, check)))
    sim.AdvanceTo(0.05)  # one update
    new = ctx.get_abstract_state(0).get_value()
    if not check:
        assert new is mem or new.controls.plan_id == 4
        return
    tau = new.controls
    assert tau.plan_id == 5 and tau.purpose == "relocalise" and np.array_equal(tau.target, target)
    assert np.array_equal(tau.states[-1][:3], q0[:3]) and not np.any(tau.controls[:, :2])
    assert new.report.scan == mem.report.scan and new.answered_frame == 2


def test_legs_end_after_each_drive_that_more_base_motion_follows():
    from nbvs_drake.config import RobotConfig
    from nbvs_drake.world.motion import leg_ends, rollout, steer
    rc = RobotConfig()
    q0 = np.array([-1.3, 0, 0, 0, 0.3, -0.3, -0.2, 0])
    q1 = np.array([0.9, 1.0, 2.0, 0.5, 0.3, -0.3, -0.2, 0])
    kind, c = steer(q0, q1, rc)[0]
    ends = leg_ends(c)
    assert len(ends) == 2 and ends[-1] == len(c)
    s = rollout(q0, c, rc.control_dt)
    # the first leg ends where the drive does: the base stands at the drive's end, the last turn is left
    assert c[ends[0] - 1, 0] != 0 and c[ends[0], 0] == 0 and np.any(c[ends[0]:, 1] != 0)
    assert np.hypot(*(s[ends[0], :2] - q1[:2])) < 1e-9
    # no turn after the drive (the goal faces the way the base drives): one leg
    q2 = q1.copy()
    q2[2] = np.arctan2(q1[1] - q0[1], q1[0] - q0[0])
    assert leg_ends(steer(q0, q2, rc)[0][1]) == [len(steer(q0, q2, rc)[0][1])]
    assert leg_ends(np.zeros((0, 7))) == [0]


def test_the_expected_utility_in_legs_restarts_each_leg_from_its_nominal_start(first_scan_map, kin):
    """With legs, a candidate's rollouts drift over one leg only: at Table 4's noise a long
    plan that is unfeasible as a whole (its rollouts reach the table) can be feasible in legs,
    never the other way round; the value is the last leg's."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.interface import PlanRequest
    _, omap = first_scan_map
    base = ["planner.n_candidates=400", "planner.eu_samples=100", "mission.verify_views=true",
            "planner.motion_planner=roadmap"]
    q0 = np.array(load_scenario("teapot_eu_mu").robot.start, float)
    out = {}
    for legs in (False, True):
        sc = load_scenario("teapot_eu_mu", settings=base + [f"mission.legs={str(legs).lower()}"])
        planner = make_planner(sc, kin)
        assert planner.utility.uses_legs() == legs
        res = planner.plan(PlanRequest(omap, q0, np.random.default_rng(2)))
        out[legs] = res.stages
    assert out[True]["with_path"] == out[False]["with_path"]  # the same candidates and paths
    assert out[True]["eu_feasible"] >= out[False]["eu_feasible"]


def test_the_planner_sends_the_robot_on_to_the_next_legs_end(kin, first_scan_map):
    """mission.legs: a frame at a leg's end (check "correct") is answered by a steering path
    from the corrected belief to the next leg's end (purpose "leg"); when no leg is left, by
    the correction to the view."""
    from pydrake.systems.analysis import Simulator

    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.recovery import Recovery
    from nbvs_drake.systems.messages import Belief
    from nbvs_drake.systems.nbvs_planner import NBVSPlanner, PlannerMemory
    _, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["mission.verify_views=true", "mission.legs=true"])
    q0 = np.array(sc.robot.start, float)
    impl = make_planner(sc, kin)
    target = q0.copy()
    target[:3] = [-1.2, -0.9, 0.9]
    leg_end = q0.copy()
    leg_end[:3] = [-1.4, -0.5, 0.0]
    for legs, purpose in (((leg_end,), "leg"), ((), "view")):
        sysm = NBVSPlanner.for_scenario(sc, impl, q0, Recovery(sc, kin, impl.motion, impl.obstacles))
        sim = Simulator(sysm)
        ctx = sim.get_mutable_context()
        mem = PlannerMemory(ControlSequence(4, 0.1, np.zeros((0, 7)), q0[None], "leg", target), omap.scan_count,
                            answered_frame=1, target=target, legs=legs)
        ctx.get_mutable_abstract_state(0).set_value(mem)
        sysm.GetInputPort("map").FixValue(ctx, AbstractValue.Make(omap))
        sysm.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(Belief(1, q0, q0, np.zeros((3, 3)), 2,
                                                                             "correct")))
        sim.AdvanceTo(0.05)
        new = ctx.get_abstract_state(0).get_value()
        assert new.controls.plan_id == 5 and new.controls.purpose == purpose and new.legs == ()
        np.testing.assert_allclose(new.controls.states[-1], leg_end if legs else target, atol=1e-9)
        assert np.array_equal(new.controls.target, target)


def test_with_leg_turns_a_leg_also_ends_after_a_long_turn_that_a_drive_follows():
    """legs.after_turns: Table 4's heading noise is per control step (sigma_w dt), so a leg
    ends after a turn of at least LegRule.min_turn_steps steps that a drive follows; a
    shorter turn stays in its leg."""
    from nbvs_drake.config import RobotConfig
    from nbvs_drake.world.motion import LegRule, leg_ends, rollout, steer

    def rule(sc):
        return LegRule.of(sc.localisation.verified_views, sc.noise, sc.robot.control_dt)
    rc = RobotConfig()
    sc = load_scenario("cluttered_room", settings=["mission.verify_views=true", "mission.legs=true",
                                                    "mission.leg_turns=true"])
    n = rule(sc).min_turn_steps
    step = sc.noise.sigma_w * sc.robot.control_dt  # 0.028 rad
    # the smallest turn whose spread is more than twice what a frame and one corrective step leave
    assert step * np.sqrt(n) > 2 * np.hypot(0.01, step) >= step * np.sqrt(n - 1)
    assert rule(load_scenario("cluttered_room")).min_turn_steps == 0
    q0 = np.array([-1.3, 0, 0, 0, 0.3, -0.3, -0.2, 0])
    q1 = np.array([0.9, 1.0, 2.0, 0.5, 0.3, -0.3, -0.2, 0])
    c = steer(q0, q1, rc)[0][1]
    ends = rule(sc).ends(c)
    assert len(ends) == 3 and ends[1:] == leg_ends(c)
    # the first leg is the turn alone: the base stands where it started, facing the drive
    s = rollout(q0, c, rc.control_dt)
    assert np.all(c[:ends[0], 0] == 0) and c[ends[0], 0] != 0 and np.all(c[:ends[0], 1] != 0)
    np.testing.assert_allclose(s[ends[0], :2], q0[:2])
    assert leg_ends(c, n, after_drives=False) == [ends[0], len(c)]
    # a turn shorter than n steps before the drive: no leg end there
    short = c[ends[0] - n + 1:]
    assert leg_ends(short, n, after_drives=False) == [len(short)]
    assert rule(load_scenario("cluttered_room")).ends(c) == [len(c)]  # no legs without verified views
    # legs.after_drives false (the preset nbvs_room): the legs end after the long turns only
    assert rule(load_scenario("cluttered_room_nbvs")).ends(c) == leg_ends(c, n, after_drives=False)
    both = load_scenario("cluttered_room_nbvs", settings=["localisation.verified_views.legs.after_drives=true"])
    assert rule(both).ends(c) == ends
    with pytest.raises(ScenarioError, match="legs"):
        load_scenario("teapot_eu_mu_nbvs", settings=["localisation.verified_views.legs.after_drives=false"])


def test_with_leg_turns_each_leg_has_its_own_recovery_budget():
    from nbvs_drake.systems.localisation import _recoveries
    frames = [{"purpose": "leg"}, {"purpose": "relocalise"}, {"purpose": "relocalise"}, {"purpose": "leg"},
              {"purpose": "relocalise"}]
    assert _recoveries(frames, per_leg=False) == 3
    assert _recoveries(frames, per_leg=True) == 1
    assert _recoveries(frames[:4], per_leg=True) == 0
    assert _recoveries([], per_leg=True) == 0


def test_with_leg_turns_a_replanned_leg_turns_first_then_drives(kin, first_scan_map):
    """A frame at a leg's end far off its line (0.4 rad): the answer is the turn back onto the
    line alone, and the leg's end stays ahead of the legs still to go."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.interface import PlanResult
    from nbvs_drake.systems.nbvs_planner import NBVSPlanner
    from nbvs_drake.world.motion import rollout, steer
    _, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["mission.verify_views=true", "mission.legs=true",
                                                  "mission.leg_turns=true"])
    q0 = np.array(sc.robot.start, float)
    impl = make_planner(sc, kin)
    sysm = NBVSPlanner.for_scenario(sc, impl, q0)
    q_end = q0.copy()
    q_end[:3] = [-1.45, -0.9, -np.pi / 2]
    later = (q0.copy(),)
    start = q0.copy()
    start[2] = -np.pi / 2 + 1.2  # the frame found the base 1.2 rad off the leg's heading
    c = steer(start, q_end, sc.robot)[0][1]
    res = PlanResult("ok", q_end, c, rollout(start, c, sc.robot.control_dt), "together")
    first, legs = sysm._first_leg(res, later)
    assert len(legs) == 2 and np.allclose(legs[0], q_end, atol=1e-6)
    assert legs[1] is later[0]
    assert np.all(first.controls[:, 0] == 0) and np.all(first.controls[:, 1] != 0)
    np.testing.assert_allclose(first.states[-1][:2], start[:2])


def test_recovery_rollouts_reject_a_path_that_the_belief_s_spread_drives_into_the_table(kin, first_scan_map):
    """mission.recovery_rollouts: a drive towards the table that stops 6 cm short of contact
    is free, also shifted by the +-2 cm margins; with the belief 5 cm unsure along the drive
    its rollouts reach the table and the path is refused, with the registration's 1 cm
    spread it is kept."""
    from nbvs_drake.planning import make_planner, make_recovery
    from nbvs_drake.planning.recovery import Recovery
    _, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["mission.verify_views=true", "mission.recovery_rollouts=200"])
    impl = make_planner(sc, kin)
    rec = make_recovery(sc, kin, impl)
    obs = impl.obstacles.for_map(omap)
    q0 = np.array(sc.robot.start, float)
    line = np.repeat(q0[None], 400, axis=0)
    line[:, 0] = q0[0] + np.linspace(0.0, 1.2, 400)
    contact = line[np.argmin(obs.free(line)), 0]  # the first x where the robot meets the table
    assert contact > q0[0] + 0.2
    goal = q0.copy()
    goal[0] = contact - 0.06
    assert rec._direct(q0, goal, obs) is not None  # no rollouts: free with its margins
    assert rec._direct(q0, goal, obs, np.zeros((3, 3))) is not None  # the registration's spread
    assert rec._direct(q0, goal, obs, np.diag([0.05 ** 2, 0.0, 0.0])) is None
    assert Recovery(load_scenario("teapot_eu_mu", settings=["mission.verify_views=true"]), kin, impl.motion,
                    impl.obstacles)._direct(q0, goal, obs, np.diag([0.05 ** 2, 0.0, 0.0])) is not None


@pytest.mark.parametrize("refine", [False, True])
def test_the_scan_after_a_correction_is_registered_again_with_refine_scan(renderer, refine):  # noqa: F811
    """localisation.verified_views.refine_scan: the sensing scan that ends a correction path is
    registered too, from the frame's pose with the registration's own spread as its prior,
    and the belief takes that registration's correction; without it the scan is taken at
    the belief (the frame before it registered, the correction path is exact)."""
    from nbvs_drake.world.motion import REGISTERED_SIGMA
    loc, mapper, ctx, b, scan, _ = _a_frame_then_its_correction(renderer, refine_scan=refine)
    mctx, lctx = mapper.GetMyContextFromRoot(ctx), loc.GetMyContextFromRoot(ctx)
    scan()
    rep = mapper.GetOutputPort("scan_report").Eval(mctx).info
    after = loc.GetOutputPort("belief").Eval(lctx)
    assert mapper.GetOutputPort("map").Eval(mctx).scan_count == 2 and rep["integrated"]
    assert [f["check"] for f in rep["frames"]] == ["correct"]
    if refine:
        assert rep["icp"] is not None and rep["icp"]["applied"]
        np.testing.assert_allclose(rep["icp"]["prior_sigma"], REGISTERED_SIGMA, rtol=1e-3)
        from nbvs_drake.world.pose import Correction
        np.testing.assert_allclose(after.state, Correction(*rep["icp"]["correction"]).apply_state(b.state),
                                   atol=1e-5)
    else:
        assert rep["icp"] is None
        np.testing.assert_array_equal(after.state, b.state)


def test_a_registered_frame_joins_the_registration_model(renderer):  # noqa: F811
    """A localisation frame that registers corrects the belief and joins the registration
    model (the points later scans register against), as the sensing scan does."""
    loc, mapper, ctx, b, scan, before = _a_frame_then_its_correction(renderer)
    lctx = loc.GetMyContextFromRoot(ctx)
    assert not np.array_equal(b.state, b.dead_reckoned)  # registered, corrected
    after_frame = len(loc._mem_of(lctx).model.points)
    assert after_frame > before
    scan()
    assert loc.GetOutputPort("belief").Eval(lctx).check == ""  # the sensing scan
    assert len(loc._mem_of(lctx).model.points) > after_frame


def _a_frame_then_its_correction(renderer, **verified):  # noqa: F811
    """Verified views with the `mission` settings: the view plan's frame registers (the object
    in view) and asks for a correction (its target is beside where the plan ended). Returns
    (localisation, mapper, root context, the belief after the frame, scan(), the registration
    model's size before the frame), where scan() runs the exact arm-only correction and its
    sensing scan."""
    sc, r, s1 = renderer
    sc = copy.deepcopy(sc)
    sc.localisation.verified_views = VerifiedViews()
    for k, v in verified.items():
        setattr(sc.localisation.verified_views, k, v)
    q0, U, states, qt, qb, P2, Xb = second_scan_in_view(sc, r)
    loc, mapper, sim, ctx, pc, status = _first_scan_then_plan(sc, r, q0, U, states, s1.points)
    lctx = loc.GetMyContextFromRoot(ctx)
    before = len(loc._mem_of(lctx).model.points)
    tau_port = sim.get_system().GetInputPort("controls")
    target = states[-1].copy()
    target[0] += 0.2
    tau_port.FixValue(ctx, AbstractValue.Make(ControlSequence(1, 0.1, U, states, "view", target)))
    pc.GetMutableData().set_value(_cloud(P2))
    status.GetMutableData().set_value(np.array([1.0, len(U), 1.0]))
    sim.AdvanceTo(0.25)
    b = loc.GetOutputPort("belief").Eval(lctx)
    assert b.check == "correct"

    def scan():
        tau_port.FixValue(ctx, AbstractValue.Make(ControlSequence(2, 0.1, np.zeros((0, 7)), b.state[None], "correct",
                                                                  target)))
        sim.AdvanceTo(0.35)
        status.GetMutableData().set_value(np.array([2.0, 0.0, 1.0]))
        sim.AdvanceTo(0.45)
    return loc, mapper, ctx, b, scan, before



def test_legs_after_turns_only_end_once_the_turning_since_the_last_end_adds_up():
    """legs.after_drives false: short turns between drives add up; the leg ends before the
    drive that follows min_turn_steps turning steps in all (a long turn alone does it)."""
    from nbvs_drake.world.motion import leg_ends
    n = 10

    def seq(*parts):  # ("t", steps) turn in place, ("d", steps) drive
        c = np.concatenate([np.tile([[0.0, 0.5, 0, 0, 0, 0, 0]] if k == "t" else [[0.3, 0, 0, 0, 0, 0, 0]], (s, 1))
                            for k, s in parts])
        return c
    c = seq(("t", 4), ("d", 5), ("t", 4), ("d", 5), ("t", 4), ("d", 5), ("t", 12), ("d", 5))
    # 4 + 4 + 4 turning steps reach 10 before the third drive; then the long turn alone
    assert leg_ends(c, n, after_drives=False) == [22, 39, len(c)]
    # each turn on its own (legs that also end after drives): only the long one
    assert [e for e in leg_ends(c, n) if c[e - 1, 1] != 0] == [39]
    assert leg_ends(seq(("t", 12), ("d", 5)), n, after_drives=False) == [12, 17]


def test_a_short_turn_ends_a_leg_when_the_drive_after_it_would_carry_its_heading_spread_far():
    """legs.turn_drift: the suitcase's seed 1 collided after a 3-step turn (0.18 rad) that a
    1.45 m drive followed; 3 (sigma_w dt sqrt(3) - floor) 1.45 m = 8 cm sideways a frame would
    have removed. Such a turn now ends a leg; the same turn before a short drive, and a one-step
    turn (whose spread a frame cannot lower) before any drive, do not."""
    from nbvs_drake.world.motion import LegRule, TurnDrift, leg_ends

    def seq(*parts):  # ("t", steps) turn in place at 0.6 rad/s, ("d", steps) drive at 0.3 m/s
        return np.concatenate([np.tile([[0.0, 0.6, 0, 0, 0, 0, 0]] if k == "t" else [[0.3, 0, 0, 0, 0, 0, 0]], (s, 1))
                               for k, s in parts])
    sc = load_scenario("real_robot_obstacles")
    rule = LegRule.of(sc.localisation.verified_views, sc.noise, sc.robot.control_dt)
    assert rule.drift is not None and rule.drift.limit == pytest.approx(0.03) and rule.min_turn_steps == 5
    far, near = seq(("t", 3), ("d", 49)), seq(("t", 3), ("d", 8))  # 1.47 m and 0.24 m
    assert rule.ends(far) == [3, len(far)] and rule.turn_ends(far) == [3, len(far)]
    assert rule.ends(near) == [len(near)]
    assert rule.ends(seq(("t", 1), ("d", 60))) == [61]
    # the limit: 3 steps end a leg from about half a metre of drive on
    d = TurnDrift(0.028, np.hypot(0.01, 0.028), 0.03, 0.1)
    assert d.ends_leg(3, 0.6) and not d.ends_leg(3, 0.45) and not d.ends_leg(1, 10.0)
    # without turn_drift (the room's preset among the chairs) the short turn stays in its leg
    assert leg_ends(far, rule.min_turn_steps) == [len(far)]


def test_the_arm_only_fallback_keeps_the_base_where_the_noise_left_it(first_scan_map, kin):
    """Among the chairs the paths keep the base 0.15 m clear (planner.obstacles.base_clearance),
    but the noise can leave it nearer. The arm-only views keep the base where it stands: their
    positions meet the true obstacles, not the padded ones, which refuse every arm
    configuration there (clutter's seed 6 at 1 cm stopped after two scans so)."""
    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.candidates import StateSampler
    from nbvs_drake.planning.interface import PlanRequest
    from nbvs_drake.planning.motion_planner import PlanningObstacles
    from nbvs_drake.planning.random_sampling import _ArmOnly
    _, omap = first_scan_map
    sc = load_scenario("cluttered_room_nbvs", settings=["planner.n_candidates=1500", "planner.utility.samples=20"])
    obstacles = PlanningObstacles(sc, kin).for_map(omap)
    q = StateSampler(sc, kin).sample_states(np.random.default_rng(2), 3000)
    near = q[obstacles.free(q) & ~obstacles.for_paths().free(q)]  # free, within the base's clearance
    assert len(near)
    x = near[np.argmin(np.linalg.norm(near[:, :2], axis=1))]  # the nearest the table (at the origin)
    cand, _ = _ArmOnly(sc, kin, x).generate(np.random.default_rng(4), omap)
    assert len(cand) and not obstacles.for_paths().free(cand).any() and obstacles.free(cand).any()
    planner = make_planner(sc, kin)
    # as the plan reaches it when nothing was feasible: after the plan made again without the
    # rollouts' margin (planner.utility.clearance)
    res = planner._plan(PlanRequest(omap, x, np.random.default_rng(5), None), _ArmOnly(sc, kin, x), margin=False)
    assert res.stages["position"] > 0
    assert res.status == "ok" and np.array_equal(res.q_goal[:3], x[:3])


@pytest.mark.parametrize("replan", [False, True])
def test_a_frame_no_path_answers_gets_a_fresh_plan_not_a_blind_scan(kin, first_scan_map, replan):
    """localisation.verified_views.replan: a frame asks for a correction back to a view that no
    path reaches (its base stands in the table). Without replan the robot stays (an empty plan:
    the next frame is the scan, taken where it stands); with it the next view is planned afresh
    from the belief, emitted as a scan's plan is, with a new target, once per scan."""
    from pydrake.systems.analysis import Simulator

    from nbvs_drake.planning import make_planner
    from nbvs_drake.planning.recovery import Recovery
    from nbvs_drake.systems.messages import Belief
    from nbvs_drake.systems.nbvs_planner import NBVSPlanner, PlannerMemory
    _, omap = first_scan_map
    sc = load_scenario("teapot_eu_mu", settings=["mission.verify_views=true",
                                                  f"localisation.verified_views.replan={str(replan).lower()}"])
    q0 = np.array(sc.robot.start, float)
    impl = make_planner(sc, kin)
    target = q0.copy()
    target[:3] = [0.0, 0.0, 0.0]  # the base in the table: no path
    sysm = NBVSPlanner.for_scenario(sc, impl, q0, Recovery(sc, kin, impl.motion, impl.obstacles))
    sim = Simulator(sysm)
    ctx = sim.get_mutable_context()
    mem = PlannerMemory(ControlSequence(4, 0.1, np.zeros((0, 7)), q0[None], "relocalise", target), omap.scan_count,
                        answered_frame=1, target=target)
    ctx.get_mutable_abstract_state(0).set_value(mem)
    sysm.GetInputPort("map").FixValue(ctx, AbstractValue.Make(omap))
    sysm.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(Belief(1, q0, q0, np.zeros((3, 3)), 2, "correct")))
    sim.AdvanceTo(0.05)
    new = ctx.get_abstract_state(0).get_value()
    assert new.controls.plan_id == 5 and new.answered_frame == 2 and new.report.scan == mem.report.scan
    if not replan:
        assert new.controls.purpose == "relocalise" and len(new.controls.controls) == 0 and not new.replanned
        return
    assert new.replanned and new.controls.purpose in ("leg", "view") and len(new.controls.controls) > 0
    assert not np.array_equal(new.controls.target, target)
    assert new.report.result["replanned_at_frame"] == 2 and new.report.result["status"] == "ok"
    np.testing.assert_allclose(new.report.result["q_goal"], new.controls.target, atol=1e-5)
    # a second frame no path answers before the scan: the robot stays, as without replan
    stuck = PlannerMemory(new.controls, new.planned_for_scan, new.report, 2, target, replanned=True)
    ctx.get_mutable_abstract_state(0).set_value(stuck)
    sysm.GetInputPort("belief").FixValue(ctx, AbstractValue.Make(Belief(1, q0, q0, np.zeros((3, 3)), 3, "correct")))
    sim.AdvanceTo(0.15)
    again = ctx.get_abstract_state(0).get_value()
    assert again.controls.purpose == "relocalise" and len(again.controls.controls) == 0
