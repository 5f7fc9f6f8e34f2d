"""How good each view the planner picks is, by the greedy oracle's own measure.

    python scripts/oracle_pick_quality.py OBJECT SEED

Runs the `oracle` experiment's nbv cell (its definition's scenario and settings, 12 scans)
for OBJECT (teapot, bunny, dragon) and SEED. After each plan it
ray-casts the chosen view against the true scene (planning/oracle.py's scoring: ground-truth
samples its returns bring within 3 mm that the model does not cover yet) and the best of a
fresh draw of planner.n_candidates candidates (their coarse scores, the best 100 at full
resolution; reachability ignored, so the best is an upper bound), and prints per scan both
gains as shares of the surface, their ratio and the chosen camera's distance to the object's
centre, then the mean ratio and both sums.
"""

from __future__ import annotations

import copy
import sys
import tempfile

import numpy as np

from nbvs_drake.app.mission import run_mission
from nbvs_drake.config import Oracle
from nbvs_drake.experiments.definition import expand, load_definition, resolve
from nbvs_drake.planning import make_planner
from nbvs_drake.planning import random_sampling as rs
from nbvs_drake.planning.candidates import free_candidates
from nbvs_drake.world.robot import RobotKinematics


def main(obj: str, seed: int) -> None:
    runs = expand(resolve(load_definition("oracle"), seeds=[seed]))
    sc = next(r for r in runs if r.levels == {"object": obj, "planner": "nbv"}).resolve()
    kin = RobotKinematics()
    osc = copy.deepcopy(sc)
    osc.planner.strategy = Oracle()
    oracle = make_planner(osc, kin)
    centre = 0.5 * (np.asarray(sc.scene.bbox_min) + np.asarray(sc.scene.bbox_max))
    plan, rows = rs.RandomSamplingPlanner.plan, []

    def measured(self, request):
        res = plan(self, request)
        if res.status != "ok":
            return res
        todo = oracle.uncovered(request.omap.object_points)
        ours = oracle._gain(oracle.truth, np.asarray(res.q_goal)[None], todo)[0]
        cand = free_candidates(oracle.sampler, oracle.obstacles.for_map(request.omap),
                               np.random.default_rng([seed, 99, len(rows)]), request.omap, {}, {})
        coarse = oracle._gain(oracle.coarse, cand, todo)
        best = oracle._gain(oracle.truth, cand[np.argsort(-coarse, kind="stable")[:100]], todo).max()
        cam = kin.camera_poses(np.asarray(res.q_goal)[None])[0][:3, 3]
        n = len(oracle.gt)
        rows.append((ours / n, best / n, ours / max(best, 1), float(np.linalg.norm(cam - centre))))
        g, b, ratio, dist = rows[-1]
        print(f"scan {len(rows) + 1:2d}: ours {100 * g:.2f} %, best of a fresh draw {100 * b:.2f} %, "
              f"ratio {ratio:.2f}, camera {dist:.2f} m from the centre", flush=True)
        return res

    rs.RandomSamplingPlanner.plan = measured
    with tempfile.TemporaryDirectory() as tmp:
        run_mission(sc, tmp, verbose=False)
    r = np.array(rows)
    print(f"mean ratio {r[:, 2].mean():.3f}; summed: ours {100 * r[:, 0].sum():.2f} %, "
          f"best {100 * r[:, 1].sum():.2f} %")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
