"""Evaluation of a reconstruction: coverage against ground-truth surface samples (seed 000
§8, seed 003: share of ground-truth points within a threshold of a model point)."""

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
