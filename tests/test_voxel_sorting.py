"""Santos et al. 2020's voxel-sorted ray casting, score and unknown-voxel clusters."""
import numpy as np
import pytest

from nbvs_drake.mapping.voxel import FREE, OCCUPIED, UNKNOWN
from nbvs_drake.mapping.voxel_sorting import score, unknown_clusters, unknown_volumes, voxel_sorted_views

R_X = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # camera +z along world +x


def _view(cls, o=(-1.0, 0.55, 0.55), res=0.1):
    # a wide camera (90 x 90 deg) looking along +x at a 12 x 11 x 11 grid at the origin
    return voxel_sorted_views(cls, np.zeros(3), res, np.array([o]), R_X[None], 50.0, 50.0, 49.5, 49.5,
                              100, 100, 0.1, 10.0, 1)[0]


def test_unoccluded_block_is_discovered_entirely():
    cls = np.full((12, 11, 11), FREE, np.int8)
    cls[4:8, 3:8, 3:8] = UNKNOWN  # 4 x 5 x 5 unknown block in free space
    n_first, n_post, rays = _view(cls)
    n_unknown = np.count_nonzero(cls == UNKNOWN)
    assert n_first + n_post == n_unknown  # every unknown voxel in view is intercepted once
    assert 25 <= n_first < n_unknown  # at least the front face is first on its rays
    assert 0 < rays <= n_unknown  # one ray per voxel at most: intercepted voxels are skipped


def test_occluded_voxels_are_never_discovered():
    cls = np.full((12, 11, 11), FREE, np.int8)
    cls[4:8, 3:8, 3:8] = UNKNOWN
    cls[2, :, :] = OCCUPIED  # an occupied wall across the whole view in front of the block
    n_first, n_post, _ = _view(cls)
    assert n_first == 0 and n_post == 0


def test_outside_the_frustum_is_ignored():
    cls = np.full((12, 11, 11), FREE, np.int8)
    cls[4:8, 3:8, 3:8] = UNKNOWN
    n = _view(cls, o=(-1.0, 5.0, 0.55))  # looking past the block
    assert n[0] + n[1] == 0


def test_volumes_and_score():
    u = np.zeros((6, 6, 6), bool)
    u[1:4, 1:4, 1:4] = True  # 27 voxels, one fully enclosed
    outer, inner = unknown_volumes(u, 0.1)
    assert inner == pytest.approx(1e-3) and outer == pytest.approx(26e-3)
    assert score(26, 1, 0.1, outer, inner, w=0.5) == pytest.approx(1.0)
    assert score(13, 0, 0.1, outer, inner, w=0.5) == pytest.approx(13 / 26.5)


def test_clusters_and_centroids():
    u = np.zeros((10, 5, 5), bool)
    u[0:2, 0:2, 0:2] = True
    u[3:5, 0:2, 0:2] = True  # one-voxel gap from the first: same cluster (within 2 voxels)
    u[8:10, 3:5, 3:5] = True  # far away: its own cluster
    res = 0.1
    ax = [(np.arange(n) + 0.5) * res for n in u.shape]
    centers = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1)
    lab, cent, sizes = unknown_clusters(u, centers)
    assert len(sizes) == 2 and sorted(sizes.tolist()) == [8, 16]
    big = int(np.argmax(sizes))
    np.testing.assert_allclose(cent[big], [0.25, 0.1, 0.1])
    np.testing.assert_allclose(cent[1 - big], [0.9, 0.4, 0.4])
    assert np.all((lab > 0) == u)


def _view_near(cls, o, z_near, res=0.1, blinds=False):
    return voxel_sorted_views(cls, np.zeros(3), res, np.array([o]), R_X[None], 50.0, 50.0, 49.5, 49.5,
                              100, 100, z_near, 10.0, 1, blinds)[0]


def test_within_the_minimum_range_a_surface_blinds_the_rays():
    # the camera inside the grid, an unknown block 0.55..0.95 m ahead, minimum range 0.4 m
    o = (0.05, 0.55, 0.55)
    cls = np.full((12, 11, 11), FREE, np.int8)
    cls[6:10, 3:8, 3:8] = UNKNOWN
    n_first, n_post, _ = _view_near(cls, o, 0.4)
    assert n_first >= 25 and n_first + n_post == 4 * 5 * 5  # free space before it: all seen
    wall = cls.copy()
    wall[2, :, :] = OCCUPIED  # a surface 0.15..0.25 m ahead: nearer than the minimum range
    assert tuple(_view_near(wall, o, 0.4)[:2]) == (0, 0)
    assert _view_near(wall, o, 0.1)[0] == 0  # beyond a 0.1 m minimum range it occludes as before
    fog = cls.copy()
    fog[2, :, :] = UNKNOWN  # the conservative rule: unknown space within the minimum range may hold such a surface
    n_first, n_post, _ = _view_near(fog, o, 0.4, blinds=True)
    assert n_first == 0 and n_post == 0
    n_first, n_post, _ = _view_near(fog, o, 0.4)  # the default: it is passed through (most likely air)
    assert n_first >= 25
    n_first, n_post, _ = _view_near(fog, o, 0.1)  # a 0.1 m minimum range: the fog is seen first
    assert n_first > 0
