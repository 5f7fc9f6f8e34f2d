"""Planners as plug-ins: a user's class implementing the planner interface, named in the
scenario (`planner: {strategy: !Plugin {entry: "package.module:Class", options: {...}}}`) or
by `nbvs reconstruct --planner package.module:Class`, with no change to this package. An entry
without a colon names an entry point of the group `nbvs_drake.planners` (a package declares
it in its pyproject.toml: `[project.entry-points."nbvs_drake.planners"] mine = "pkg.mod:Class"`).

The class is built as Class(parts, **options): `parts` (PlannerParts) holds the project's
planning parts, so a plug-in can sample states, score views, plan paths and apply the
utility the way the built-in strategies do (docs/examples/nearest_unknown_planner.py)."""

from __future__ import annotations

import dataclasses as dc
import importlib

from ..errors import ScenarioError


@dc.dataclass(frozen=True)
class PlannerParts:
    """What a planner is made of (nbvs_drake.planning.make_planner builds them from the
    scenario): `sc` the scenario; `kin` the robot's kinematics (RobotKinematics); `sampler`
    the state sampler (StateSampler: uniform states whose director ray meets W_box); `evaluator`
    the view evaluator (ViewEvaluator: simulated scans in the map); `obstacles` the per-plan
    obstacles (PlanningObstacles.for_map(omap)); `motion` the motion planner (MotionPlanner:
    connect_many(q_start, goals, obstacles, rng)); `utility` the utility strategy
    (deterministic or expected, utility.select_best); `overlap_h` the registration filter's
    threshold (None: none)."""
    sc: object
    kin: object
    sampler: object
    evaluator: object
    obstacles: object
    motion: object
    utility: object
    overlap_h: float | None


ENTRY_POINT_GROUP = "nbvs_drake.planners"


def load_entry(entry: str):
    """The class an entry names ("package.module:Class", or an entry point's name)."""
    entry = entry.strip()
    what = f"planner.strategy: the plugin {entry!r}"
    if ":" not in entry:
        from importlib.metadata import entry_points
        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == entry]
        if not found:
            raise ScenarioError(f"{what} is neither 'package.module:Class' nor an entry point of the group "
                                f"{ENTRY_POINT_GROUP}")
        try:
            return found[0].load()
        except Exception as e:  # noqa: BLE001 - the user's code: any failure is one line
            raise ScenarioError(f"{what} could not be loaded: {type(e).__name__}: {e}") from None
    module, _, name = entry.partition(":")
    import os
    import sys
    if os.getcwd() not in sys.path:  # a module in the current folder, as `python -m` finds it
        sys.path.append(os.getcwd())
    try:
        obj = importlib.import_module(module)
    except Exception as e:  # noqa: BLE001
        raise ScenarioError(f"{what} could not be imported: {type(e).__name__}: {e}") from None
    for part in name.split("."):
        if not hasattr(obj, part):
            raise ScenarioError(f"{what}: the module {module!r} has no {name!r}")
        obj = getattr(obj, part)
    return obj


def option_values(options: dict) -> dict:
    """The plugin's keyword arguments: each value read as YAML."""
    import yaml
    out = {}
    for k, v in options.items():
        try:
            out[k] = yaml.safe_load(v) if isinstance(v, str) else v
        except yaml.YAMLError:
            raise ScenarioError(f"planner.strategy.options.{k}: {v!r} is not a YAML value") from None
    return out


class PluginPlanner:
    """A user's planner in the mission: its answers checked (a plan "ok" has its goal, its
    controls (m, 7) and its states (m + 1, 8), finite; anything else is one line naming the
    plugin), its path length rho (eq. 8) filled in where it gives none (the run's `distance`
    sums it). It carries the parts' motion planner and obstacles, so verified views and their
    recovery plans work with it as with the built-in strategies."""

    def __init__(self, inner, parts: PlannerParts, entry: str):
        self.inner, self.entry = inner, entry
        self.motion, self.obstacles, self.evaluator = parts.motion, parts.obstacles, parts.evaluator
        self.sc = parts.sc

    def plan(self, request):
        import numpy as np

        from ..world.motion import path_length
        from .interface import PlanResult
        res = self.inner.plan(request)
        bad = f"planner.strategy: the plugin {self.entry!r} returned"
        if not isinstance(res, PlanResult):
            raise ScenarioError(f"{bad} {type(res).__name__}, not a PlanResult")
        if res.status != "ok":
            return res
        try:
            c = np.asarray(res.controls, float)
            s = np.asarray(res.states, float)
            g = np.asarray(res.q_goal, float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{bad} a plan whose goal, controls or states are not arrays") from None
        if c.ndim != 2 or c.shape[1] != 7 or s.shape != (len(c) + 1, 8) or g.shape != (8,):
            raise ScenarioError(f"{bad} a plan with controls {c.shape}, states {s.shape} and goal {g.shape}; "
                                f"a plan has controls (m, 7), states (m + 1, 8) and a goal (8,)")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(s)) and np.all(np.isfinite(g))):
            raise ScenarioError(f"{bad} a plan with non-finite values")
        res.controls, res.states, res.q_goal = c, s, g
        res.factors = dict(res.factors or {})
        res.factors.setdefault("rho", float(path_length(s, self.sc.planner.weights)))
        res.factors.setdefault("info", float(res.utility))
        return res


def make_plugin(strategy, parts: PlannerParts) -> PluginPlanner:
    """The plugin planner of a !Plugin strategy, built from `parts`."""
    cls = load_entry(strategy.entry)
    try:
        planner = cls(parts, **option_values(strategy.options))
    except TypeError as e:
        raise ScenarioError(f"planner.strategy: the plugin {strategy.entry!r} cannot be built with the "
                            f"options {sorted(strategy.options)}: {e}") from None
    if not callable(getattr(planner, "plan", None)):
        raise ScenarioError(f"planner.strategy: the plugin {strategy.entry!r} has no plan(request) method")
    return PluginPlanner(planner, parts, strategy.entry)
