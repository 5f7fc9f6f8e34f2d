"""Evaluation: coverage, and each plan's prediction checked against its scan's outcome."""

import json

import numpy as np
import pytest

from nbvs_drake.config import Scenario
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.perception.evaluation import coverage, plan_prediction, prediction_fit, scan_outcome


def _wall(x=0.11):  # mid-voxel: each point in one voxel
    ys, zs = np.meshgrid(np.linspace(-0.2, 0.2, 41), np.linspace(0.5, 0.8, 31))
    return np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], axis=1)


def test_scan_outcome_counts_revealed_voxels_points_and_overlap():
    sc = Scenario().check()
    m0 = OccupancyMap.for_scenario(sc)
    o = np.array([-1.0, 0.0, 0.65])
    m1, _ = m0.integrate(o, _wall(), sc.mapper.table_clearance)
    first = scan_outcome(m0, m1)
    assert first["revealed_unknown_voxels"] == m0.unknown_count() - m1.unknown_count() > 0
    assert first["revealed_m3"] == pytest.approx(first["revealed_unknown_voxels"] * 0.02 ** 3)
    assert first["object_points"] == len(_wall()) and first["overlap"] == 0.0  # nothing was known
    m2, _ = m1.integrate(o, _wall(), sc.mapper.table_clearance)  # the same wall again
    again = scan_outcome(m1, m2)
    # the wall's voxels are known (a few edge voxels lost their hit to other rays' misses)
    assert again["overlap"] > 0.9 and again["revealed_unknown_voxels"] == 0


def test_prediction_fit_and_prediction_fields():
    rng = np.random.default_rng(0)
    x = rng.uniform(0.01, 0.05, 12)
    recs = [{"iteration": 1}] + [{"prediction": {"revealed_m3": float(a)},
                                  "outcome": {"revealed_m3": float(1.5 * a + 0.002)}} for a in x]
    fit = prediction_fit(recs)
    assert fit["pairs"] == 12 and fit["r2"] == pytest.approx(1.0) and fit["slope"] == pytest.approx(1.5)
    assert np.isnan(prediction_fit(recs[:3])["r2"])  # two pairs: no fit
    p = plan_prediction({"info": 0.1, "un_o": 10, "un_touched": 30, "overlap": 0.4}, 0.02 ** 3)
    assert p["revealed_m3"] == pytest.approx(30 * 0.02 ** 3) and p["overlap"] == 0.4
    p = plan_prediction({"info": 0.1, "un_o": 10, "un_touched": 30, "un_near": 12, "overlap": 0.4}, 0.02 ** 3)
    assert p["revealed_m3"] == pytest.approx(42 * 0.02 ** 3) and p["un_near"] == 12


def test_a_kinect_view_clears_the_unknown_space_within_its_minimum_range(kin):
    """The Kinect's returning rays cross 0.7 m before any depth counts; the unknown voxels
    there are revealed by the scan, and a plan's prediction counts them
    (`ViewEvaluator.near_range_unknown`): all of the near range's unknown voxels in an
    unknown map, none in a map that knows them free, none behind a surface nearer than the
    minimum range (the ray is blind)."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.mapping.occupancy import OccupancyMap
    from nbvs_drake.planning.views import ViewEvaluator
    from nbvs_drake.world.sensor import resolve_sensor
    sc = load_scenario(settings=["sensor.preset=kinect"])
    ev = ViewEvaluator(kin, sc)
    q = np.array(sc.robot.start, float)
    omap = OccupancyMap.for_scenario(sc)
    n_unknown = ev.near_range_unknown(omap, q)
    z_near = resolve_sensor(sc.sensor).z_near
    X = kin.camera_poses(q[None])[0]
    # the near range's frustum, as far as it lies in the map, is at least a few hundred voxels
    assert n_unknown > 300
    free = OccupancyMap(omap.spec, omap.model, np.full(omap.spec.dims, -5.0, np.float32))  # every voxel free
    assert ev.near_range_unknown(free, q) == 0
    _, inside = omap.spec.voxel_index(X[:3, 3] + 0.3 * X[:3, 2] + np.zeros((1, 3)))
    assert z_near > 0.3 and inside[0]
    depth = (omap.spec.centers() - X[:3, 3]) @ X[:3, 2]
    lo = np.zeros(omap.spec.dims, np.float32)
    lo[(depth > 0.28) & (depth < 0.32)] = 5.0  # a surface 0.3 m in front of the camera: every ray blind
    wall = OccupancyMap(omap.spec, omap.model, lo)
    assert ev.near_range_unknown(wall, q) < 0.05 * n_unknown


def test_a_run_records_predictions_and_outcomes(tmp_path):
    from conftest import small_scenario

    from nbvs_drake.app.mission import run_mission
    s = run_mission(small_scenario(0, 4), tmp_path, verbose=False)
    recs = [json.loads(x) for x in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    assert "prediction" not in recs[0] and "outcome" not in recs[0]
    for prev, r in zip(recs, recs[1:]):
        assert r["prediction"]["un_o"] == prev["plan"]["factors"]["un_o"]
        assert r["outcome"]["revealed_unknown_voxels"] == prev["unknown_voxels"] - r["unknown_voxels"]
        assert r["outcome"]["object_points"] == r["object_points"] - prev["object_points"]
    assert s["prediction_pairs"] == 3 and -1.0 <= s["prediction_r2"] <= 1.0 and s["prediction_slope"] > 0
    assert s["blind_scans"] == 0 and s["blind_scan_list"] == []


def test_coverage_thresholds():
    gt = np.array([[0.0, 0, 0], [0.01, 0, 0]])
    assert coverage(gt, np.array([[0.002, 0, 0]]), (0.003, 0.01)) == [0.5, 1.0]
