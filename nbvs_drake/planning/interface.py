"""The planner interface: every strategy (random sampling, ORT, view sampling, the baselines)
implements `Planner.plan(request) -> PlanResult`. A request carries what the planner may know:
the map, the belief (state and planar covariance) and the plan's random generator; the
result carries the chosen state, its control sequence, its utility and the factors, with one
name per factor across strategies (FACTOR_NAMES)."""

from __future__ import annotations

import dataclasses as dc
from typing import Protocol

import numpy as np

from ..mapping.occupancy import OccupancyMap

#: the utility's factors as every strategy reports them: g = pos * reg * info * dist
#: (Vasquez-Gomez et al. 2017 eq. 4; `info` is the information term of the scenario's
#: planner.metric, named in `metric`); rho: the path's length (eq. 8); du: the deterministic
#: utility; eu: the expected utility's summary (utility "eu"); un_o, un_touched, oc_o, overlap,
#: un_total: the simulated scan's unknown voxels seen first and touched, its occupied voxels,
#: its registration overlap and the map's unknown voxels; un_near: the chosen view's unknown
#: voxels within the sensor's minimum range that its returning rays clear
#: (`ViewEvaluator.near_range_unknown`, for the plan's prediction)
FACTOR_NAMES = ("pos", "reg", "info", "metric", "dist", "rho", "du", "eu", "un_o", "un_touched", "oc_o", "overlap",
                "un_total", "un_near")


@dc.dataclass(frozen=True)
class PlanRequest:
    """What a plan starts from: the map after the last scan, the believed state q (8,), the
    belief's planar pose covariance (3, 3) (zero after a registered scan; None: exact) and the
    generator every random choice of this plan draws from."""
    omap: OccupancyMap
    q_start: np.ndarray
    rng: np.random.Generator
    start_cov: np.ndarray | None = None


@dc.dataclass
class PlanResult:
    #: "ok", "no_candidate" (nothing passed the filters), "no_path" (none reachable) or
    #: "no_feasible" (reachable, but every one unfeasible under the expected utility)
    status: str
    q_goal: np.ndarray | None = None
    controls: np.ndarray | None = None  #: (m, 7)
    states: np.ndarray | None = None  #: (m+1, 8) planned states
    path_kind: str = ""
    utility: float = 0.0
    factors: dict = dc.field(default_factory=dict)
    stages: dict = dc.field(default_factory=dict)  #: candidates surviving each filter
    times: dict = dc.field(default_factory=dict)  #: seconds per stage
    #: the candidates that reached motion planning with a path: (state, utility) each
    candidates: list = dc.field(default_factory=list)
    #: the path's vertices in the search that found it (motion_planner.FoundPath.nodes; 0: none)
    path_nodes: int = 0
    #: the scored feasible candidates `candidates` lists, as PlanResults with their paths (this
    #: one among them): what an agent chooses from (nbvs_drake.gym); not written to records
    alternatives: list = dc.field(default_factory=list, repr=False)

    def to_json(self) -> dict:
        d = {"status": self.status, "utility": self.utility, "factors": self.factors,
             "stages": self.stages, "times": self.times, "path_kind": self.path_kind}
        if self.q_goal is not None:
            d["q_goal"] = [round(float(v), 6) for v in self.q_goal]
            d["n_controls"] = int(len(self.controls))
            if self.path_nodes:
                d["path_nodes"] = int(self.path_nodes)
            step = max(1, len(self.states) // 60)
            path = np.concatenate([self.states[::step], self.states[-1:]])
            d["path"] = [[round(float(v), 4) for v in s] for s in path]
        if self.candidates:
            d["candidates"] = [{"q": [round(float(v), 4) for v in q], "g": round(float(g), 6)}
                               for q, g in self.candidates]
        return d


class Planner(Protocol):
    """A next-best-view/state strategy."""

    def plan(self, request: PlanRequest) -> PlanResult:
        ...


def distance_factor(rho, use_distance: bool = True):
    """The utility's travel factor dist(x) = 1 / (1 + rho) of a path of length rho (eq. 8),
    a number or an array (Vasquez-Gomez et al. 2017 eq. 4); 1 with planner.use_distance false."""
    if use_distance:
        return 1.0 / (1.0 + rho)
    return np.ones_like(rho, dtype=float) if np.ndim(rho) else 1.0
