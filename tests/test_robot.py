import numpy as np
from conftest import random_states

from nbvs_drake.world.robot import ARM_JOINTS, RobotKinematics


def test_urdf_has_8_dof_and_katana_limits(kin: RobotKinematics):
    plant = kin.plant
    assert plant.num_positions() == 8
    assert plant.GetJointByName("base").type_name() == "planar"
    deg = np.degrees
    np.testing.assert_allclose(deg(kin.arm_lower), [-173.4, -7.7, -127.3, -116.5, -171.5], atol=1e-6)
    np.testing.assert_allclose(deg(kin.arm_upper), [165.7, 124.3, 117.7, 107.5, 164.5], atol=1e-6)
    np.testing.assert_allclose(kin.arm_velocity_limits, [2.21, 1.19, 1.19, 2.21, 2.21])
    assert [plant.GetJointByName(j).type_name() for j in ARM_JOINTS] == ["revolute"] * 5


def test_camera_pose_at_zero_configuration(kin):
    # arm horizontal along +x: mount (0.20, 0, 0.50) + shoulder 0.2015 up, links 0.19+0.139+0.1473
    # along x, camera 0.1505 further and 0.055 above the wrist axis, looking along +x.
    X = kin.camera_poses(np.zeros(8))[0]
    np.testing.assert_allclose(X[:3, 3], [0.20 + 0.19 + 0.139 + 0.1473 + 0.1505, 0, 0.50 + 0.2015 + 0.055], atol=1e-9)
    np.testing.assert_allclose(X[:3, 2], [1, 0, 0], atol=1e-12)  # optical axis +x
    np.testing.assert_allclose(X[:3, 1], [0, 0, -1], atol=1e-12)  # image down = world down


def test_camera_pose_base_and_shoulder(kin):
    # base at (1, 2) turned 90 deg (forward = world +y), J2 = 90 deg: arm straight up above
    # the mount; the housing offset (link +z) now points to the base's -x = world -y.
    q = np.array([1.0, 2.0, np.pi / 2, 0, np.pi / 2, 0, 0, 0])
    X = kin.camera_poses(q)[0]
    up = 0.19 + 0.139 + 0.1473 + 0.1505
    np.testing.assert_allclose(X[:3, 3], [1.0, 2.0 + 0.20 - 0.055, 0.50 + 0.2015 + up], atol=1e-9)
    np.testing.assert_allclose(X[:3, 2], [0, 0, 1], atol=1e-12)


def test_vectorised_fk_matches_drake(kin):
    for q in random_states(kin, 20, seed=3):
        np.testing.assert_allclose(kin.camera_poses(q)[0], kin.camera_pose_drake(q), atol=1e-12)


def test_turned_about_the_mount_keeps_the_camera_pose(kin):
    """The base turned about the arm's first joint and the joint turned back: the same camera
    pose (so the same view) for every heading whose joint angle stays within its limits."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = np.concatenate([rng.uniform(-1.5, 1.5, 2), rng.uniform(-np.pi, np.pi, 1),
                            rng.uniform(kin.arm_lower, kin.arm_upper)])
        turned = kin.turned_about_mount(q, np.linspace(-np.pi, np.pi, 25))
        ok = ~np.isnan(turned[:, 0])
        assert ok.sum() >= 20  # the first joint turns through ~5.9 of the 2 pi rad
        np.testing.assert_array_equal(np.isnan(turned).any(axis=1), ~ok)
        assert np.all(kin.arm_within_limits(turned[ok]))
        np.testing.assert_array_equal(turned[ok][:, 4:], np.tile(q[4:], (ok.sum(), 1)))
        X = kin.camera_poses(np.vstack([q[None], turned[ok]]))
        np.testing.assert_allclose(X[1:], np.broadcast_to(X[0], X[1:].shape), atol=1e-12)
    # the joint's range leaves a gap of ~0.37 rad: a heading whose joint angle falls in it,
    # either way round, is NaN; the joint may turn the long way round to reach another
    q = np.zeros(8)
    q[3] = 2.8
    assert np.isnan(kin.turned_about_mount(q, [-0.2])[0, 0])  # 3.0 or 3.0 - 2 pi
    t = kin.turned_about_mount(q, [-0.5])[0]  # 3.3 - 2 pi
    np.testing.assert_allclose(t[3], 3.3 - 2 * np.pi)


def test_scalar_wrap_and_path_length_are_bit_for_bit_the_array_ones():
    """The motion planner's scalar angle wrap and its eq. 8 length give the same floats as the
    array forms they replace (a steering path's length decides which option is tried first)."""
    import math

    from nbvs_drake.world.motion import path_length, wrap_angle, wrap_scalar
    rs = np.random.default_rng(0)
    for v in [*rs.normal(size=20000) * 10, 0.0, -0.0, math.pi, -math.pi, 2 * math.pi, 3 * math.pi, 1e-300]:
        a = float(wrap_angle(v))
        assert wrap_scalar(v) == a and math.copysign(1.0, wrap_scalar(v)) == math.copysign(1.0, a)
    for _ in range(300):
        s = rs.normal(size=(int(rs.integers(2, 200)), 8)) * rs.uniform(0.01, 10)
        w = rs.uniform(0, 10, 8)
        d = np.diff(s, axis=0)
        d[:, 2] = wrap_angle(d[:, 2])
        assert path_length(s, list(w)) == float(np.sum(np.sqrt(np.sum(w * d * d, axis=1))))
