import numpy as np
from conftest import random_states

from nbvs_drake.robot import ARM_JOINTS, RobotKinematics


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
