"""pos(x) against the map: unknown and occupied voxels as merged, conservative boxes."""
import numpy as np
import pytest

from nbvs_drake.mapping import FREE, UNKNOWN
from nbvs_drake.mapping.boxes import conservative_boxes, greedy_boxes
from nbvs_drake.planning.collision import CollisionModel


def _covered(shape, boxes):
    c = np.zeros(shape, bool)
    for lo, hi in boxes:
        c[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    return c


@pytest.mark.parametrize("seed", range(3))
def test_box_covers_are_conservative_and_capped(seed):
    rng = np.random.default_rng(seed)
    mask = rng.random((20, 17, 13)) < 0.3
    exact = greedy_boxes(mask)
    np.testing.assert_array_equal(_covered(mask.shape, exact), mask)  # exact cover
    boxes, block = conservative_boxes(mask, 60)
    assert len(boxes) <= 60 and block > 1
    cov = _covered(mask.shape, boxes)
    assert np.all(cov[mask])  # never hides an obstacle voxel


def test_configurations_against_the_map(kin, first_scan_map):
    sc, omap = first_scan_map
    boxes, _ = omap.obstacle_boxes(300)
    vox = CollisionModel(sc, kin, obstacle_boxes=boxes)
    whole = CollisionModel(sc, kin)
    table = np.array([0.0, 0.0, 0.0, 0, 0.3, 0, 0, 0])  # base inside the table
    # arm stretched from x = -0.95 towards +x, slightly lowered: the camera ends at
    # (-0.12, 0, 0.725), inside W_box, in the space the first scan (from -x) saw free
    seen = np.array([-0.95, 0.0, 0.0, 0.0, -0.05, 0.0, 0.0, 0.0])
    # from the far side, pitched down: the camera ends at (0.32, 0, 0.50), in the shadow
    # behind the teapot, unknown
    unseen = np.array([1.1, 0.0, np.pi, 0.0, -0.13, 0.0, -0.6, 0.0])
    clear = np.array([-1.6, 1.0, 0.3, 0, 0.4, -0.3, -0.3, 0])
    cls = omap.classes()
    vox_of = lambda q: tuple(((kin.camera_poses(q)[0][:3, 3] - omap.spec.bmin) // omap.spec.res).astype(int))  # noqa: E731
    assert cls[vox_of(seen)] == FREE and cls[vox_of(unseen)] == UNKNOWN
    q = np.array([table, seen, unseen, clear])
    np.testing.assert_array_equal(vox.free(q), [False, True, False, True])
    np.testing.assert_array_equal(whole.free(q), [False, False, False, True])  # W_box whole: conservative
