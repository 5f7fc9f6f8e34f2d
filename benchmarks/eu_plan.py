"""The default scene's expected-utility plan (`nbvs bench planning`'s `eu_plan_s_k500`: after the
first scan, 10,000 candidates, k = 500, Table 4 noise), repeated in one process, at this
checkout or at an older one (issue #49 compared 79445c7's with today's):

    PYTHONPATH=<checkout> .venv/bin/python benchmarks/eu_plan.py [plans]

Prints one JSON line: each plan's seconds (the first of a process includes numba's
compilation or warm-up), the chosen goal, its E(x) and the last plan's stage times."""
import copy
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

try:  # the package's layout since the structure issue
    from nbvs_drake.config import Expected, load_scenario
    from nbvs_drake.perception.scanning import ScanRenderer
    from nbvs_drake.world.robot import RobotKinematics
    NEW = True
except ImportError:  # 79445c7 and before
    from nbvs_drake.config import load_scenario
    from nbvs_drake.robot import RobotKinematics
    from nbvs_drake.scanning import ScanRenderer
    NEW = False
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.planning import PlanRequest, make_planner
from nbvs_drake.planning.collision import CollisionModel


def main(plans: int) -> dict:
    # the 2 cm map at every checkout (the default's before issue 50, bench.MAP_2CM)
    sc = load_scenario(settings=["mapper.voxel_size=0.02"])
    kin = RobotKinematics(sc.robot.urdf)
    with tempfile.TemporaryDirectory() as tmp:
        r = ScanRenderer(sc, Path(tmp), kin)
        omap = r.integrate(OccupancyMap.for_scenario(sc), r.scan(np.array(sc.robot.start)))
    q0 = np.array(sc.robot.start)
    du = copy.deepcopy(sc)
    du.planner.n_candidates = 10_000
    cm = CollisionModel(du, kin)
    eu = copy.deepcopy(du)
    if NEW:
        eu.planner.utility = Expected(samples=500)
    else:
        eu.planner.utility, eu.planner.eu_samples = "eu", 500
    eu.noise.sigma_v, eu.noise.sigma_w = 0.00165, 0.28  # Table 4
    out: dict = {"eu_plan_s_k500": []}
    for _ in range(plans):
        planner = make_planner(eu, kin, cm)
        t = time.perf_counter()
        res = planner.plan(PlanRequest(omap, q0, np.random.default_rng(0)))
        out["eu_plan_s_k500"].append(round(time.perf_counter() - t, 3))
    out.update(q_goal=[round(float(v), 6) for v in res.q_goal], eu_value=res.utility, times=res.times)
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)))
