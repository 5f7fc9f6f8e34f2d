"""Evaluation of a reconstruction: coverage against ground-truth surface samples (Vasquez-Gomez et al. 2017
§8, the ORT paper: share of ground-truth points within a threshold of a model point)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def coverage(gt_points: np.ndarray, model_points: np.ndarray, thresholds=(0.003, 0.005)) -> list[float]:
    """Share of ground-truth points within each threshold (m) of a model point."""
    if len(model_points) == 0:
        return [0.0 for _ in thresholds]
    tree = cKDTree(np.asarray(model_points, float))
    d, _ = tree.query(gt_points, k=1, distance_upper_bound=max(thresholds) * 1.0001)
    return [float(np.mean(d <= t)) for t in thresholds]


# --------------------------------------------------------------------------------------
# Predictions checked against outcomes
# --------------------------------------------------------------------------------------

#: a scan that returns fewer object points than this is blind (it shows the planner chose a
#: view that could not see the object)
BLIND_SCAN_POINTS = 100


def scan_outcome(prev, cur) -> dict:
    """What scan `cur.scan_count` gave, from the maps before (`prev`) and after (`cur`) it:
    the unknown voxels it revealed (net, in voxels and m^3), its object points, and the
    overlap measured as the share of those points that landed in voxels already occupied
    before the scan (what the registration filter predicts with its overlap)."""
    from ..mapping.voxel import OCCUPIED
    revealed = prev.unknown_count() - cur.unknown_count()
    new = np.asarray(cur.object_points[len(prev.object_points):], float)
    overlap = 0.0
    if len(new):
        idx = np.clip(prev.spec.voxel_index(new)[0], 0, np.array(prev.spec.dims) - 1)
        cls = prev.classes()[idx[:, 0], idx[:, 1], idx[:, 2]]
        overlap = float(np.mean(cls == OCCUPIED))
    return {"revealed_unknown_voxels": int(revealed), "revealed_m3": revealed * prev.voxel_volume(),
            "object_points": int(len(new)), "overlap": round(overlap, 6)}


def plan_prediction(factors: dict, voxel_volume: float) -> dict:
    """What a plan predicted for its scan: the information term, the unknown voxels its
    simulated scan sees first (un_o) and touches (un_touched: every distinct unknown voxel its
    rays cross before an occupied voxel, with those its returning rays cross within the
    sensor's minimum range, un_near: the volume it expects to reveal), and the overlap with
    known surface it expects."""
    touched = factors.get("un_touched", factors.get("un_o", 0))
    near = factors.get("un_near", 0)
    return {"info": factors.get("info"), "un_o": factors.get("un_o"), "un_touched": touched, "un_near": near,
            "revealed_m3": (touched + near) * voxel_volume, "overlap": factors.get("overlap")}


def prediction_fit(records: list[dict], key: str = "revealed_m3") -> dict:
    """Predicted against revealed unknown volume over the run's plans (every iteration but
    the first carries the prediction of the plan that led to it and the scan's outcome):
    the least-squares line revealed = slope * predicted + b and its R^2 (Santos et al. 2020,
    Fig. 11, report R^2 = 0.954). NaN when fewer than 3 pairs or no spread."""
    pairs = [(r["prediction"][key], r["outcome"][key]) for r in records
             if r.get("prediction") and r.get("outcome") and r["prediction"].get(key) is not None]
    out = {"pairs": len(pairs), "r2": float("nan"), "slope": float("nan")}
    if len(pairs) < 3:
        return out
    x, y = np.array(pairs, float).T
    if np.ptp(x) == 0 or np.ptp(y) == 0:
        return out
    slope, b = np.polyfit(x, y, 1)
    res = y - (slope * x + b)
    out["r2"] = float(1.0 - np.sum(res * res) / np.sum((y - y.mean()) ** 2))
    out["slope"] = float(slope)
    return out


def planning_per_iteration(records: list[dict]) -> dict:
    """The NBV plan per iteration (plan_s_per_iteration) and all planning per iteration
    (planning_all_s_per_iteration: the NBV plans with the verification and recovery planning
    that followed them, `plan.recovery_s`), over the iterations that planned a path; None
    without one. A record from before recovery planning was timed (frames answered, but no plan
    carries recovery_s) has no all-planning time: None, not the plan alone."""
    plans = [r["plan"] for r in records if (r.get("plan") or {}).get("status") == "ok"]
    if not plans:
        return {"plan_s_per_iteration": None, "planning_all_s_per_iteration": None}
    plan = sum(p.get("plan_s") or 0.0 for p in plans)
    recovery = sum((r.get("plan") or {}).get("recovery_s") or 0.0 for r in records)
    untimed = not recovery and any((r.get("scan") or {}).get("frames") for r in records) \
        and not any("recovery_s" in (r.get("plan") or {}) for r in records)
    return {"plan_s_per_iteration": plan / len(plans),
            "planning_all_s_per_iteration": None if untimed else (plan + recovery) / len(plans)}

