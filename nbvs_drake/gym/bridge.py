"""The hand-off between a running mission and an agent: `AgentPlanner` takes the place of the
scenario's planner inside the NBVSPlanner system. After each scan it lets the scenario's own
planner plan as usual (its candidates, their utilities, their paths and the stop criteria),
then hands the decision to the agent and waits for its action: the index of one of the scored
candidates, or a robot state that it reaches with the mission's motion planner.

The mission runs in a process of its own (`worker_main`; the Drake Simulator cannot return in
the middle of an event, and Drake's renderer must live and die in one thread), and the two
sides meet at a pipe: one message each way at a time, so the mission's results do not depend
on the timing of the processes."""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from ..planning.interface import PlanRequest, PlanResult, distance_factor


class Aborted(Exception):
    """The agent left the episode (reset or close) while the mission waited for it."""


@dc.dataclass
class Decision:
    """What the agent decides on after a scan: the plan request (map, believed state), the
    scenario planner's own answer and the candidates to choose from (best first); `unreachable`:
    the last action could not be reached, and this is the same decision asked again."""
    request: PlanRequest
    planned: PlanResult
    candidates: list
    unreachable: bool = False


class Channel:
    """The mission's side of the hand-off over a pipe (a multiprocessing Connection): `ask`
    sends ("decision", observation, info) and waits for the action; ("abort",) back raises
    Aborted, which unwinds the mission. `observe(decision)` makes (observation, info) in the
    mission's process, where its renderer and map live."""

    def __init__(self, conn, observe):
        self.conn, self.observe = conn, observe

    def ask(self, decision: "Decision"):
        obs, info = self.observe(decision)
        self.conn.send(("decision", obs, info))
        msg = self.conn.recv()
        if msg[0] == "abort":
            raise Aborted()
        return msg[1]


#: per candidate: the state (8), then these
CANDIDATE_FEATURES = ("utility", "info", "rho", "duration_s", "feasible")


def observation(d: Decision, n_candidates: int, control_dt: float) -> dict:
    """Reconstruct-v0's observation of a decision, without the depth image: `voxels` (the
    map's classes), `believed_state`, `candidates` (n_candidates, 8 + 5: the state, then
    CANDIDATE_FEATURES) and `candidate_mask`."""
    feats = np.zeros((n_candidates, 8 + len(CANDIDATE_FEATURES)))
    mask = np.zeros(n_candidates, np.int8)
    for i, c in enumerate(d.candidates[:n_candidates]):
        f = c.factors
        eu = f.get("eu")
        feasible = eu.get("feasible", True) if isinstance(eu, dict) else True
        feats[i] = np.r_[c.q_goal, c.utility, f.get("info", 0.0), f.get("rho", 0.0),
                         len(c.controls) * control_dt, float(bool(feasible))]
        mask[i] = 1
    return {"voxels": d.request.omap.classes().astype(np.int8, copy=True),
            "believed_state": np.asarray(d.request.q_start, np.float64).copy(),
            "candidates": feats, "candidate_mask": mask}


def reach(planner, request: PlanRequest, q_goal: np.ndarray) -> PlanResult | None:
    """A plan to a robot state chosen by the agent: the mission's motion planner (the roadmap,
    its steering paths and detours) from the believed state, with the scenario planner's own
    per-plan obstacles; its utility and information term from the planner's view evaluator where
    it has one. None: the state is not free, or no path reaches it."""
    motion, obstacles = getattr(planner, "motion", None), getattr(planner, "obstacles", None)
    if motion is None or obstacles is None:
        raise ValueError(f"{type(planner).__name__} has no motion planner: a robot state cannot be reached")
    sc = motion.sc
    q = np.asarray(q_goal, float).reshape(8)
    if not np.all(np.isfinite(q)):
        return None
    omap = request.omap
    paths = obstacles.for_map(omap).for_paths()
    if not bool(np.asarray(paths.free(q[None])).reshape(-1)[0]):
        return None
    found = motion.connect_many(request.q_start, q[None], paths, request.rng)[0]
    if found is None:
        return None
    evaluator = getattr(planner, "evaluator", None)
    if evaluator is not None:  # the factors random sampling reports, with no registration filter
        from ..planning.baselines import view_result
        res = view_result(sc, evaluator, omap, q, found, max(omap.unknown_count(), 1), None)
    else:
        from ..planning.motion_planner import reached_goal
        from ..world.motion import path_length
        kind, controls, states = found
        rho = path_length(states, sc.planner.weights)
        dist = distance_factor(rho, sc.planner.use_distance)
        res = PlanResult("ok", reached_goal(sc, q, states), controls, states, kind, float(dist),
                         {"pos": 1.0, "reg": 1.0, "info": 1.0, "rho": float(rho), "dist": float(dist),
                          "du": float(dist)}, path_nodes=found.nodes)
    res.factors.update(purpose="view", chosen_by="agent")
    return res


class AgentPlanner:
    """A `Planner` whose decisions an agent takes (nbvs_drake.gym): the scenario's planner
    (`inner`) plans after each scan as it would alone; its answer when it finds nothing (the
    mission's stop) is kept; otherwise the agent is asked through `channel`. An action is an int
    (the index of one of the candidates, best first; at most `n_candidates`) or a robot state
    (8,) reached by `reach`. An action that cannot be taken is answered by the same decision
    again, marked unreachable."""

    def __init__(self, inner, channel: Channel, n_candidates: int):
        self.inner = inner
        self.channel = channel
        self.n_candidates = int(n_candidates)
        # recovery planning (verified views) reads these from the planner
        for name in ("motion", "obstacles", "evaluator", "sc"):
            if hasattr(inner, name):
                setattr(self, name, getattr(inner, name))

    def candidates(self, res: PlanResult) -> list[PlanResult]:
        """The scored feasible candidates, best first (at most n_candidates; the chosen one first)."""
        alts = [r for r in (res.alternatives or [res]) if r.controls is not None]
        if not any(r is res for r in alts):
            alts = [res] + alts
        alts = sorted(alts, key=lambda r: (r is not res, -r.utility))
        return alts[:self.n_candidates]

    def plan(self, request: PlanRequest) -> PlanResult:
        res = self.inner.plan(request)
        if res.status != "ok":
            return res
        decision = Decision(request, res, self.candidates(res))
        while True:
            action = self.channel.ask(decision)
            chosen = self._take(action, decision)
            if chosen is not None:
                chosen.stages, chosen.times = res.stages, res.times
                chosen.candidates = res.candidates
                return chosen
            decision = dc.replace(decision, unreachable=True)

    def _take(self, action, d: Decision) -> PlanResult | None:
        a = np.asarray(action)
        if a.ndim == 0:
            i = int(a)
            return d.candidates[i] if 0 <= i < len(d.candidates) else None
        return reach(self.inner, d.request, a)
