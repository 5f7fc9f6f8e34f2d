"""Next-best-view/state planning. Every strategy implements `Planner.plan(PlanRequest) ->
PlanResult` (planning.interface) by composing shared parts: candidate generation
(planning.candidates, planning.view_sampling), the view evaluator (planning.views), the
per-plan obstacles and the motion planner (planning.motion_planner) and the utility strategy
(planning.utility: deterministic or expected)."""

from __future__ import annotations

from .interface import Planner, PlanRequest, PlanResult  # noqa: F401


def make_planner(sc, kin, wbox_model=None, bulk_checks: bool = True, truth_mesh=None) -> "Planner":
    """The strategy the scenario selects (planner.strategy), with the utility it selects
    (planner.utility). wbox_model: an existing CollisionModel of the known environment with
    W_box (built when None and needed). bulk_checks False: paths are checked as before the bulk
    kernels (`nbvs bench planning`'s baseline). truth_mesh: the true object (world frame) for
    the greedy oracle (planner.strategy "oracle"; built from the scenario when None)."""
    from .candidates import StateSampler
    from .motion_planner import MotionPlanner, PlanningObstacles
    from .utility import make_utility
    from .views import ViewEvaluator

    p = sc.planner
    sampler = StateSampler(sc, kin)
    evaluator = ViewEvaluator(kin, sc)
    obstacles = PlanningObstacles(sc, kin, wbox_model)
    motion = MotionPlanner(sc, kin, sampler, bulk_checks=bulk_checks)
    overlap_h = None if p.strategy_name() == "ViewSampling" else p.overlap_h
    utility = make_utility(sc, evaluator, motion, overlap_h)
    if p.strategy_name() == "Plugin":  # a user's planner (planning/plugins.py)
        from .plugins import PlannerParts, make_plugin
        return make_plugin(p.strategy, PlannerParts(sc, kin, sampler, evaluator, obstacles, motion, utility, overlap_h))
    if p.strategy_name() in ("ViewCircle", "RandomViews"):
        from .baselines import make_baseline
        return make_baseline(sc, kin, sampler, evaluator, obstacles, motion, utility, overlap_h)
    if p.strategy_name() == "Oracle":  # the greedy oracle: it knows the true object (truth_mesh)
        from ..world.objects import build_object
        from .oracle import OraclePlanner
        return OraclePlanner(sc, kin, sampler, obstacles, motion, truth_mesh or build_object(sc))
    if p.strategy_name() == "Ort":
        from .ort import ORTPlanner
        return ORTPlanner(sc, sampler, evaluator, obstacles, motion, utility, overlap_h)
    from .random_sampling import RandomSamplingPlanner
    generator = sampler
    if p.strategy_name() == "ViewSampling":
        from .view_sampling import ClusterViewGenerator
        generator = ClusterViewGenerator(sc, kin, sampler)
    return RandomSamplingPlanner(sc, generator, evaluator, obstacles, motion, utility, overlap_h)


def make_recovery(sc, kin, planner):
    """The verified views' recovery planner (planning/recovery.py) for a planner that has a
    motion planner and per-plan obstacles, with the rollout checks of
    mission.recovery_rollouts; None when the planner has neither."""
    if not (hasattr(planner, "motion") and hasattr(planner, "obstacles")):
        return None
    from .recovery import Recovery
    checker = None
    if sc.localisation.verified_views.recovery_rollouts > 0:
        from .utility import ExpectedUtilityScore
        checker = ExpectedUtilityScore(sc, None, planner.motion, None)
    return Recovery(sc, kin, planner.motion, planner.obstacles, checker)
