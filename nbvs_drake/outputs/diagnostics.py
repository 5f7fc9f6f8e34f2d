"""What the planner predicts against what the scans give, candidate by candidate: render the
scan of each of a plan's candidates (the real RgbdSensor, `scanning.ScanRenderer`), integrate
it into the plan's map and measure the coverage it adds, beside the covered-area gain the
view evaluation predicted (`view_metrics.M_COVER_GAIN`). The instrument behind the coverage
gain's model of unknown space (docs/decisions.md); `nbvs bench prediction` prints it."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from ..config import Scenario


def _ranks(a: np.ndarray) -> np.ndarray:
    return np.argsort(np.argsort(a, kind="stable"), kind="stable").astype(float)


def candidate_gains(sc: Scenario, views=(), n_best: int = 60, n_random: int = 60, seed: int = 123) -> dict:
    """After the scan from the start state and the scans from the robot states `views`, the
    planner's candidates (generation and position filter of planner.n_candidates states) are
    scored by the view evaluation, with the coverage gain's model of unknown space
    (`views.near_surface`) and with the first model, every unknown voxel alike (keys
    prefixed `uniform_`); the `n_best` predicted best by each and `n_random` others drawn at
    random are rendered. Returns the predicted gains (m^2), the measured gains (share of the
    ground truth newly within 3 mm), their rank correlation (Spearman), and what the view
    predicted best gave against the best measured."""
    from ..mapping import view_metrics as K
    from ..mapping.occupancy import OccupancyMap
    from ..perception.evaluation import coverage
    from ..perception.scanning import ScanRenderer
    from ..planning.candidates import StateSampler
    from ..planning.motion_planner import PlanningObstacles
    from ..planning.views import ViewEvaluator
    from ..world.objects import build_object, ground_truth_points
    from ..world.robot import RobotKinematics

    kin = RobotKinematics(sc.robot.urdf)
    with tempfile.TemporaryDirectory() as tmp:
        rend = ScanRenderer(sc, Path(tmp), kin)
        gt = ground_truth_points(build_object(sc), sc)
        omap = OccupancyMap.for_scenario(sc)
        for q in [sc.robot.start, *views]:
            omap = rend.integrate(omap, rend.scan(np.asarray(q, float)))
        c0 = coverage(gt, omap.object_points)[0]
        rng = np.random.default_rng(seed)
        obst = PlanningObstacles(sc, kin).for_map(omap)
        cand, _ = StateSampler(sc, kin).generate(rng, omap)
        cand = cand[obst.free(cand)]
        preds = {}
        for model in (True, False):
            ev = ViewEvaluator(kin, sc)
            ev.near_surface_model = model
            if ev.coverage_radius <= 0:
                ev.coverage_radius = sc.planner.coverage.radius
            preds[model] = ev.evaluate(omap, cand)[:, K.M_COVER_GAIN]
        # the n_best of each model, then n_random of the others
        best = list(dict.fromkeys(np.concatenate([np.argsort(-preds[m], kind="stable")[:n_best]
                                                  for m in (True, False)]).tolist()))
        rest = np.setdiff1d(np.arange(len(cand)), best)
        pick = np.concatenate([best, rng.choice(rest, min(n_random, len(rest)), replace=False)]).astype(int)
        gain = np.array([coverage(gt, rend.integrate(omap, rend.scan(cand[i])).object_points)[0] - c0
                         for i in pick])
    out = {"coverage_before": c0, "candidates": int(len(cand)), "rendered": int(len(pick)),
           "best_gain": float(gain.max())}
    for m, tag in ((True, ""), (False, "uniform_")):
        p = preds[m][pick]
        top = np.argsort(-p, kind="stable")
        out |= {f"{tag}spearman": float(np.corrcoef(_ranks(p), _ranks(gain))[0, 1]),
                f"{tag}gain_of_predicted_best": float(gain[top[0]]),
                f"{tag}mean_gain_of_predicted_top5": float(gain[top[:5]].mean()), f"{tag}predicted_m2": p.tolist()}
    return out | {"gain": gain.tolist(), "states": cand[pick].tolist()}
