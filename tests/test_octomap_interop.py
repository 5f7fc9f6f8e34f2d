"""Interop with OctoMap: .bt export read by pyoctomap, lossless .npz, and parity of scan
integration with pyoctomap's OcTree on the same scans."""
import numpy as np
import pytest

from nbvs_drake.mapping import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from nbvs_drake.mapping.octomap_io import write_bt

pyoctomap = pytest.importorskip("pyoctomap")


def _tree_classes(tree, omap):
    cen = omap.spec.centers().reshape(-1, 3)
    out = np.empty(len(cen), np.int8)
    for n, c in enumerate(cen):
        node = tree.search(c)
        out[n] = UNKNOWN if node is None else (OCCUPIED if tree.isNodeOccupied(node) else FREE)
    return out.reshape(omap.spec.dims)


@pytest.fixture(scope="module")
def scans(tmp_path_factory, kin):
    from nbvs_drake.config import load_scenario
    from nbvs_drake.perception.scanning import ScanRenderer
    sc = load_scenario()
    r = ScanRenderer(sc, tmp_path_factory.mktemp("scene"), kin)
    q0 = np.array(sc.robot.start)
    q1 = q0.copy()
    q1[:3] = [-0.9, -1.1, 0.9]
    q2 = q0.copy()
    q2[:3] = [0.2, 1.3, -1.75]
    return sc, r, [r.scan(q) for q in (q0, q1, q2)]


def test_bt_export_reads_back_in_pyoctomap(tmp_path, scans):
    sc, r, ss = scans
    m = OccupancyMap.for_scenario(sc)
    for s in ss:
        m = r.integrate(m, s)
    n = write_bt(m, tmp_path / "map.bt")
    tree = pyoctomap.OcTree(0.1)
    assert tree.readBinary(str(tmp_path / "map.bt"))
    assert tree.getResolution() == pytest.approx(sc.mapper.voxel_size) and tree.size() == n
    np.testing.assert_array_equal(_tree_classes(tree, m), m.classes())


def test_same_class_as_octomap_for_99_percent_of_wbox(scans):
    sc, r, ss = scans
    m = OccupancyMap.for_scenario(sc)
    tree = pyoctomap.OcTree(sc.mapper.voxel_size)
    for s in ss:
        m = r.integrate(m, s)
        # OctoMap: full rays, every end point a hit, beams beyond max range truncated (free)
        pts = np.concatenate([s.points, s.free_rays])
        tree.insertPointCloud(pts, s.origin, 4.999)
    ours = m.classes()
    theirs = _tree_classes(tree, m)
    # compare the voxels wholly inside W_box (OctoMap also marks the table top and the floor
    # occupied, which our cloud filter leaves out of the object map by design)
    cen = m.spec.centers()
    h = m.spec.res / 2
    inside = np.all((cen - h >= np.array(sc.scene.bbox_min) - 1e-9) & (cen + h <= np.array(sc.scene.bbox_max) + 1e-9),
                    axis=-1)
    inside &= cen[..., 2] - h >= sc.scene.table_height + 1e-9
    agree = np.mean(ours[inside] == theirs[inside])
    assert inside.sum() > 10000
    assert agree >= 0.99, agree
    assert (ours[inside] == OCCUPIED).sum() > 200  # the comparison covers real surface
