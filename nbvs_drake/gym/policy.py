"""A gym policy as a planner, and a planner as a gym policy.

- `PolicyPlanner` is a plug-in planner (nbvs_drake.planning.plugins) that takes each decision
  with a policy: a function from Reconstruct-v0's observation (without the depth image) to its
  action (a candidate's index, or a robot state). A policy trained on the environment then runs
  as `nbvs reconstruct --scenario S` with

      planner:
        strategy: !Plugin
          entry: nbvs_drake.gym.policy:PolicyPlanner
          options: {policy: "my_package.agents:act"}

  and is judged by `nbvs experiment` and `nbvs benchmark` like any planner. Its candidates are
  the scenario's random-sampling planner's (the parts' sampler, evaluator, motion planner and
  utility).
- `first_candidate` is a policy that takes the scenario planner's own choice, in either action
  space: the planner as a gym policy (a baseline agent, and the round trip's check).
"""

from __future__ import annotations

import numpy as np

from .bridge import AgentPlanner, Decision, observation


def first_candidate(obs: dict):
    """The scenario planner's own choice: candidate 0 (for a state action space, its state)."""
    return 0


def first_candidate_state(obs: dict) -> np.ndarray:
    """The scenario planner's own choice as a robot state (Reconstruct-v0 with action="state")."""
    return np.asarray(obs["candidates"][0, :8], float)


class _PolicyChannel:
    def __init__(self, policy, n_candidates: int, control_dt: float):
        self.policy, self.n, self.dt = policy, n_candidates, control_dt

    def ask(self, d: Decision):
        if d.unreachable:
            raise RuntimeError("the policy chose a state no path reaches; a policy planner has no second try")
        return self.policy(observation(d, self.n, self.dt))


class PolicyPlanner:
    """A plug-in planner: `policy` (a callable, or "module:function") takes each decision from
    the observation; `n_candidates` as Reconstruct-v0's."""

    def __init__(self, parts, policy="nbvs_drake.gym.policy:first_candidate", n_candidates: int = 16):
        from ..planning.plugins import load_entry
        from ..planning.random_sampling import RandomSamplingPlanner
        fn = load_entry(policy) if isinstance(policy, str) else policy
        inner = RandomSamplingPlanner(parts.sc, parts.sampler, parts.evaluator, parts.obstacles, parts.motion,
                                      parts.utility, parts.overlap_h)
        self.agent = AgentPlanner(inner, _PolicyChannel(fn, int(n_candidates), parts.sc.robot.control_dt),
                                  int(n_candidates))

    def plan(self, request):
        return self.agent.plan(request)
