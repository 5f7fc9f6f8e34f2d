"""Benchmarks (`nbvs bench visibility --json`): view evaluation and scan integration on the
default scene after its first scan, with the OctoMap peer (pyoctomap) measured in the same run."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from .config import load_scenario
from .mapping import kernels as K
from .mapping.occupancy import OccupancyMap
from .planning.collision import CollisionModel
from .planning.random_sampling import RandomSamplingPlanner
from .robot import RobotKinematics
from .scanning import ScanRenderer
from .sensor import ray_directions


def _best_of(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def bench_visibility(n_views: int = 400, trials: int = 20, per_trial: int = 200, seed: int = 0) -> dict:
    import numba
    sc = load_scenario()
    kin = RobotKinematics(sc.robot.urdf)
    with tempfile.TemporaryDirectory() as tmp:
        r = ScanRenderer(sc, Path(tmp), kin)
        scan = r.scan(np.array(sc.robot.start))
    m0 = OccupancyMap.for_scenario(sc)
    omap = r.integrate(m0, scan)

    # candidate views: states whose director ray meets W_box (seed 000 §7.6 step 1)
    sc.planner.n_candidates = max(n_views, trials * per_trial)
    planner = RandomSamplingPlanner(sc, kin, CollisionModel(sc, kin))
    states, _ = planner.generate(np.random.default_rng(seed))
    X = kin.camera_poses(states)
    pos, rot = np.ascontiguousarray(X[:, :3, 3]), np.ascontiguousarray(X[:, :3, :3])
    dirs, tn, tf = ray_directions(sc.sensor, 1)
    lo = np.ascontiguousarray(omap.logodds, dtype=np.float32)
    bmin, res, m = omap.spec.bmin.astype(np.float64), omap.spec.res, omap.model
    threads = numba.get_num_threads()

    def uni(p, R, chunks):
        return K.evaluate_views(lo, bmin, res, p, R, dirs, tn, tf, m.l_free, m.l_occ, chunks)

    def hrt(p, R, chunks, a=2):
        return K.evaluate_views_hrt(lo, a, bmin, res, p, R, dirs, tn, tf, m.l_free, m.l_occ, chunks)

    uni(pos[:2], rot[:2], 1), hrt(pos[:2], rot[:2], 1)  # compile / load the cache
    sub = slice(0, n_views)
    numba.set_num_threads(1)
    try:
        t1 = _best_of(lambda: uni(pos[:100], rot[:100], 1), 2) / 100
    finally:
        numba.set_num_threads(threads)
    t_all = _best_of(lambda: uni(pos[sub], rot[sub], threads), 2) / n_views
    t_hrt = _best_of(lambda: hrt(pos[sub], rot[sub], threads), 2) / n_views

    agree = 0
    for k in range(trials):
        s = slice(k * per_trial, (k + 1) * per_trial)
        f0 = uni(pos[s], rot[s], threads)[:, K.M_FIG]
        f2 = hrt(pos[s], rot[s], threads)[:, K.M_FIG]
        agree += int(np.argmax(f0) == np.argmax(f2))

    t_int = _best_of(lambda: r.integrate(m0, scan), 5)
    out = {
        "scene": "default (teapot) after the first scan",
        "rays_per_view": int(len(dirs)),
        "voxel_m": res,
        "grid": list(omap.spec.dims),
        "threads": threads,
        "ms_per_view_1core_full_res": 1e3 * t1,
        "views_per_s_full_res": 1.0 / t_all,
        "views_per_s_hrt_a2": 1.0 / t_hrt,
        "hrt_a2_speedup": t_all / t_hrt,
        "hrt_a2_best_view_agreement": agree / trials,
        "scan_integration_ms": 1e3 * t_int,
        "scan_points": int(len(scan.points)),
        "scan_no_return_rays": int(len(scan.free_rays)),
    }
    out.update(_octomap_peer(scan, res, omap, dirs, X[0]))
    return out


def _octomap_peer(scan, res, omap, dirs, X_view) -> dict:
    try:
        import pyoctomap
    except ImportError:
        return {"octomap": "pyoctomap not installed"}
    pts = np.ascontiguousarray(np.concatenate([scan.points, scan.free_rays]), dtype=np.float64)

    def insert():
        tree = pyoctomap.OcTree(res)
        tree.insertPointCloud(pts, scan.origin, 4.999)
        return tree

    t_ins = _best_of(insert, 3)
    tree = insert()
    o = np.ascontiguousarray(X_view[:3, 3], dtype=np.float64)
    world_dirs = dirs @ X_view[:3, :3].T
    end = np.zeros(3)
    t = time.perf_counter()
    for d in world_dirs:
        tree.castRay(o, np.ascontiguousarray(d), end, True, 5.0)
    t_cast = time.perf_counter() - t
    return {"octomap_insert_ms": 1e3 * t_ins, "octomap_castray_ms_per_view": 1e3 * t_cast,
            "octomap_version": getattr(pyoctomap, "__version__", "")}


def main(args) -> int:
    if args.what == "visibility":
        res = bench_visibility(n_views=args.views)
    else:
        raise SystemExit(f"unknown benchmark {args.what!r}")
    print(json.dumps(res, indent=None if args.json else 2))
    return 0
