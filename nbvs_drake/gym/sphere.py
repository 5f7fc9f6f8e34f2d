"""`nbvs_drake/ViewSphere-v0`: the learned planners' protocol (PC-NBV, SCONE): a free-flying
camera on a sphere of 33 views around the object, one random start view and then next-best
views, scored by the coverage-against-views curve. It shares the scenario's object, ground
truth, sensor (`world.sensor.noisy_depth`: the same noise and faults), map (`OccupancyMap`)
and reward (`perception.evaluation.coverage`, 3 mm) with the robot's mission; the camera
flies, so there are no collisions and no motion noise.

- The views: 33 points of a Fibonacci lattice on the sphere of `radius` about the middle of
  W_box, each camera looking at the middle, its image's up as near the world's up as the
  view allows. The object floats: the map keeps every return in W_box, the underside's too
  (the mission strips a band above its support), while the ground truth is the mission's. The object is
  ray cast alone (Open3D), as the protocol's floating object: no table, no room.
- Action: `Discrete(33)`, the next view (a view taken before gains nothing).
- Observation (`Dict`): `voxels`, `depth` (as Reconstruct-v0), `view` (the current view's
  index), `visited` (MultiBinary(33)) and `view_positions` (33, 3).
- Reward: the ground-truth coverage gained. An episode is the start view and `n_views` more
  (default 9: the 1 + 9 of PC-NBV); its last `info` has `auc` (the mean coverage after each
  of its 1 + n_views scans: the area under the coverage-against-views curve, normalised),
  `coverage`, `ceiling` (the coverage of all 33 views together, noise-free), `distance` (the
  camera's path along the sphere, great-circle arcs, metres) and `collisions` (0).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..world.pose import look_at

N_VIEWS = 33


def sphere_views(n: int = N_VIEWS) -> np.ndarray:
    """n unit directions of a Fibonacci lattice on the sphere (uniform in area; the same every
    time)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def arc_length(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    """The great-circle distance between two unit directions on the sphere of `radius`."""
    return float(radius * np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))


class ViewSphereEnv(gym.Env):
    """See the module's docstring. `scenario`, `settings`: as Reconstruct-v0 (the object, the
    sensor and the map come from it); `radius`: the sphere's (m; None: 2.5 times the object's
    bounding radius, at least the sensor's minimum range plus that radius plus 0.1 m)."""

    metadata = {"render_modes": []}

    def __init__(self, scenario="default", settings=(), n_views: int = 9, radius: float | None = None,
                 include_depth: bool = True):
        import open3d as o3d

        from ..app.api import _resolve_scenario
        from ..config import resolve_sensor
        from ..errors import ScenarioError
        from ..mapping.occupancy import OccupancyMap
        from ..world.objects import build_object, ground_truth_points
        from ..world.sensor import intrinsics, ray_directions
        if not 1 <= int(n_views) <= N_VIEWS - 1:
            raise ScenarioError(f"n_views must be 1 to {N_VIEWS - 1}, not {n_views}")
        self.sc = _resolve_scenario(scenario, None, tuple(settings))
        self.n_views, self.include_depth = int(n_views), include_depth
        self.mesh = build_object(self.sc)
        self.gt = ground_truth_points(self.mesh, self.sc, np.random.default_rng([0, 41]))
        V = np.asarray(self.mesh.vertices, float)
        self.center = 0.5 * (np.asarray(self.sc.scene.bbox_min, float) + np.asarray(self.sc.scene.bbox_max, float))
        r_obj = float(np.max(np.linalg.norm(V - self.center, axis=1)))
        s = resolve_sensor(self.sc.sensor)
        if radius is None:
            radius = max(2.5 * r_obj, s.z_near + r_obj + 0.1)
        if not (np.isfinite(radius) and radius - r_obj >= s.z_near and radius + r_obj <= s.z_far):
            raise ScenarioError(f"radius {radius} m puts the object outside the sensor's range "
                                f"{s.z_near}-{s.z_far} m (its bounding radius is {r_obj:.3f} m)")
        self.radius = float(radius)
        self.dirs = sphere_views()
        self.positions = self.center + self.radius * self.dirs
        self.poses = [look_at(p, self.center) for p in self.positions]
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)),
                                  o3d.core.Tensor(np.asarray(self.mesh.triangles, np.uint32)))
        self._rays, _, _ = ray_directions(self.sc.sensor, 1)
        self._intr = intrinsics(self.sc.sensor)
        self._z_range = (s.z_near, s.z_far)
        self._empty = OccupancyMap.for_scenario(self.sc)
        dims = tuple(int(d) for d in self._empty.spec.dims)
        w, h = self._intr[0], self._intr[1]
        obs = {"voxels": spaces.Box(0, 2, dims, np.int8), "view": spaces.Discrete(N_VIEWS),
               "visited": spaces.MultiBinary(N_VIEWS),
               "view_positions": spaces.Box(-np.inf, np.inf, (N_VIEWS, 3), np.float64)}
        if include_depth:
            obs["depth"] = spaces.Box(0.0, np.inf, (h, w), np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_space = spaces.Discrete(N_VIEWS)
        self._ceiling = None
        self._seed = 0

    # ---- the sensor and the map ------------------------------------------------------------
    def exact_depth(self, view: int) -> np.ndarray:
        """The noise-free depth image (h, w) of a view: z of the first hit, +inf without one."""
        import open3d as o3d
        X = self.poses[view]
        D = self._rays @ X[:3, :3].T
        O = np.broadcast_to(X[:3, 3], D.shape)
        t = self._scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(np.c_[O, D], np.float32)))["t_hit"].numpy()
        z = t * self._rays[:, 2]
        z = np.where((z >= self._z_range[0]) & (z <= self._z_range[1]), z, np.inf)
        w, h = self._intr[0], self._intr[1]
        return z.reshape(h, w)

    def _scan(self, view: int, step: int):
        """Scans view `view` (the sensor's noise and faults seeded by the episode's seed and the
        scan's number) into the map; returns the depth image."""
        from ..world.sensor import noisy_depth
        z = noisy_depth(self.exact_depth(view), self.sc.sensor, self._seed, step)
        X = self.poses[view]
        flat = z.ravel()
        back = self._rays / self._rays[:, 2:3]  # camera-frame points per unit depth
        hit = np.isfinite(flat) & (flat > 0)
        miss = np.isinf(flat)
        P = (back[hit] * flat[hit, None]) @ X[:3, :3].T + X[:3, 3]
        F = (self._rays[miss] * self._z_range[1]) @ X[:3, :3].T + X[:3, 3]
        # the object floats: no support's returns to strip above W_box's floor (the mission's
        # table_clearance), so every return in W_box marks the map, its underside's too
        self.omap, _ = self.omap.integrate(X[:3, 3], P, 0.0, free_rays=F)
        return np.where(np.isfinite(z), z, 0.0).astype(np.float32)

    def _coverage(self, points: np.ndarray) -> float:
        from ..perception.evaluation import coverage
        return float(coverage(self.gt, points, (0.003,))[0])

    def exact_points(self, view: int) -> np.ndarray:
        """The noise-free returns (N, 3) of a view, world frame."""
        z = self.exact_depth(view).ravel()
        ok = np.isfinite(z)
        X = self.poses[view]
        return (self._rays[ok] / self._rays[ok, 2:3] * z[ok, None]) @ X[:3, :3].T + X[:3, 3]

    def ceiling(self) -> float:
        """The coverage of all 33 views together, noise-free (computed once)."""
        if self._ceiling is None:
            self._ceiling = self._coverage(np.concatenate([self.exact_points(v) for v in range(N_VIEWS)]))
        return self._ceiling

    # ---- the Gymnasium API ------------------------------------------------------------------
    def _obs(self, depth) -> dict:
        obs = {"voxels": self.omap.classes().astype(np.int8, copy=False), "view": int(self.view),
               "visited": self.visited.copy(), "view_positions": self.positions.copy()}
        if self.include_depth:
            obs["depth"] = depth
        return obs

    def _take(self, view: int) -> tuple[dict, float]:
        depth = self._scan(view, len(self.curve))
        cov = self._coverage(self.omap.object_points)
        reward = cov - (self.curve[-1] if self.curve else 0.0)
        if self.curve:
            self.distance += arc_length(self.dirs[self.view], self.dirs[view], self.radius)
        self.view = view
        self.visited[view] = 1
        self.curve.append(cov)
        return self._obs(depth), reward

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        self.omap = self._empty
        self.visited = np.zeros(N_VIEWS, np.int8)
        self.curve: list[float] = []
        self.distance = 0.0
        self.view = int(np.random.default_rng([self._seed, 43]).integers(N_VIEWS))
        obs, _ = self._take(self.view)
        return obs, {"coverage": self.curve[-1], "view": self.view, "seed": self._seed}

    def step(self, action):
        if len(self.curve) > self.n_views:
            raise RuntimeError("the episode is over: call reset()")
        view = int(action)
        if not 0 <= view < N_VIEWS:
            raise ValueError(f"a view is 0 to {N_VIEWS - 1}, not {action}")
        obs, reward = self._take(view)
        done = len(self.curve) > self.n_views
        info = {"coverage": self.curve[-1], "view": view, "distance": self.distance}
        if done:
            info.update(auc=float(np.mean(self.curve)), ceiling=self.ceiling(), collisions=0,
                        curve=list(self.curve))
        return obs, float(reward), done, False, info


# ---- the view-sphere protocol's planners (nbvs benchmark view_sphere) ----------------------

class SpherePlanner:
    """A next-best view among the sphere's unvisited views, chosen as the scenario's planner
    chooses: planner.strategy Oracle: the view whose true returns cover the most uncovered
    ground-truth samples (3 mm); RandomViews: a random one; the others: the view evaluator's
    information term of planner.metric (this project's "coverage", the papers' "sur") on the
    map, the best one (the first among equals)."""

    def __init__(self, env: ViewSphereEnv):
        from ..config import variant_name
        self.env, self.sc = env, env.sc
        self.kind = {"Oracle": "oracle", "RandomViews": "random"}.get(variant_name(self.sc.planner.strategy), "metric")
        if variant_name(self.sc.planner.strategy) == "Plugin":
            from ..errors import ScenarioError
            raise ScenarioError("the view sphere runs the built-in planners (a plug-in plans robot states): "
                                "use nbvs_drake/ViewSphere-v0 with the plug-in's own policy")
        if self.kind == "metric":
            from ..planning.views import ViewEvaluator
            from ..world.robot import RobotKinematics
            self.evaluator = ViewEvaluator(RobotKinematics(self.sc.robot.urdf), self.sc)

    def choose(self, seed: int, step: int) -> int:
        env = self.env
        todo = np.flatnonzero(env.visited == 0)
        if self.kind == "random":
            return int(np.random.default_rng([seed, 47, step]).choice(todo))
        if self.kind == "oracle":
            from ..planning.oracle import newly_covered, uncovered
            todo_gt = uncovered(env.gt, env.omap.object_points)
            gains = [len(newly_covered(env.exact_points(v), env.gt, todo_gt)) for v in todo]
            return int(todo[int(np.argmax(gains))])
        omap = env.omap
        met = self.evaluator.evaluate_poses(omap, np.stack([env.poses[v] for v in todo]))
        info = self.evaluator.information(omap, None, met, self.sc.planner.metric, max(omap.unknown_count(), 1))
        return int(todo[int(np.argmax(info))])


def run_view_sphere(sc, out, n_views: int = 9) -> dict:
    """One episode of the view-sphere protocol with the scenario's planner (`SpherePlanner`),
    seeded by the scenario's seed, written as a run: scenario.yaml, iterations.jsonl (one line
    per view) and summary.json (coverage and its curve, coverage_auc, the ceiling over the 33
    views, distance along the sphere, no collisions, the point model's metrics)."""
    import json
    import time
    from pathlib import Path

    from pydrake.common.yaml import yaml_dump_typed

    from ..config.load import with_resolved_sensor
    from ..files import write_atomic
    from ..perception.reconstruction import point_metrics
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.yaml").write_text(yaml_dump_typed(with_resolved_sensor(sc)))
    env = ViewSphereEnv(sc, n_views=n_views, include_depth=False)
    planner = SpherePlanner(env)
    _, info = env.reset(seed=sc.seed)
    rows = [{"iteration": 1, "view": info["view"], "coverage": info["coverage"], "plan": {"plan_s": 0.0}}]
    done = False
    plan_s = []
    while not done:
        t = time.perf_counter()
        view = planner.choose(sc.seed, len(rows))
        plan_s.append(time.perf_counter() - t)
        _, _, done, _, info = env.step(view)
        rows.append({"iteration": len(rows) + 1, "view": view, "coverage": info["coverage"],
                     "plan": {"status": "ok", "plan_s": plan_s[-1], "factors": {"rho": arc_length(
                         env.dirs[rows[-1]["view"]], env.dirs[view], env.radius)}}})
    (out / "iterations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    from ..perception.evaluation import coverage
    cov5 = coverage(env.gt, env.omap.object_points, (0.005,))[0]
    ceiling = info["ceiling"]
    summary = {
        "scenario": sc.name, "seed": sc.seed, "planner": sc.planner.strategy_word() if planner.kind != "metric"
        else f"{sc.planner.strategy_word()}:{sc.planner.metric}", "protocol": "view_sphere",
        "coverage": info["coverage"], "coverage_5mm": cov5, "coverage_by_scan": info["curve"],
        "coverage_auc": info["auc"], "coverage_ceiling": ceiling,
        "coverage_of_ceiling": round(info["coverage"] / ceiling, 6) if ceiling else None,
        "scans": len(rows), "collisions": 0, "executed_trajectories": len(rows) - 1, "collision_rate": 0.0,
        "stop_reason": "max_scans", "distance": info["distance"], "sphere_radius_m": env.radius,
        "reconstruction": {"points": point_metrics(env.omap.object_points, env.mesh.vertices, env.mesh.triangles,
                                                   env.gt, sc.mapper.voxel_size)},
        "plan_s_per_iteration": float(np.mean(plan_s)) if plan_s else 0.0,
        "wall_s": time.perf_counter() - t0,
    }
    env.close()
    write_atomic(out / "summary.json", json.dumps(summary, indent=2))
    return summary
