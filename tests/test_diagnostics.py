"""diagnostics.candidate_gains (`nbvs bench prediction`): a plan's candidates rendered with the
real camera and measured against their predicted covered-area gain."""
import numpy as np

from nbvs_drake.config import load_scenario
from nbvs_drake.outputs.diagnostics import candidate_gains


def test_candidates_are_rendered_and_measured_against_their_prediction():
    sc = load_scenario(None, seed=2, settings=["planner.n_candidates=300", "scene.gt_points=4000"])
    r = candidate_gains(sc, n_best=4, n_random=4)
    n = r["rendered"]
    assert 8 <= n <= 12 and n == len(r["gain"]) == len(r["predicted_m2"]) == len(r["uniform_predicted_m2"])
    assert 0.1 < r["coverage_before"] < 0.6 and r["candidates"] > 100
    p, g = np.array(r["predicted_m2"]), np.array(r["gain"])
    assert np.all(p >= 0) and np.all(g >= 0) and g.max() == r["best_gain"] > 0.01
    # the four predicted best come first
    assert p[:4].min() >= p[n - 4:].max()
    for tag in ("", "uniform_"):
        assert -1.0 <= r[tag + "spearman"] <= 1.0
        assert r[tag + "gain_of_predicted_best"] == g[np.argmax(r[tag + "predicted_m2"])]
