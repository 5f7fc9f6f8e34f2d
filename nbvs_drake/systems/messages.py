"""The typed values that travel on the mission diagram's ports between systems.

- `ControllerStatus`: the NoisyVelocityController's `status` vector (3), read through
  `ControllerStatus.of(port.Eval(context))` instead of by index.
- `Belief`: the Localisation system's belief after the last scan (abstract port).
- `RegisteredScan`: a scan as Localisation hands it to the OctreeMapper (abstract port).
- `ScanReport`: the OctreeMapper's record of the last integrated scan (abstract port).
- `PlanReport`: the NBVSPlanner's record of the last plan or stop (abstract port), with
  `to_json()` for the iteration records.

Every value is immutable: a context copy shares it (`__deepcopy__` returns self).
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from ..world.state import NQ


class _Immutable:
    def __deepcopy__(self, memo):
        return self


@dc.dataclass(frozen=True)
class ControllerStatus(_Immutable):
    """[plan_id being executed, steps done, idle (1 when the plan is finished)]."""
    plan_id: int = 0
    steps_done: int = 0
    idle: bool = True

    SIZE = 3

    @staticmethod
    def of(vector) -> "ControllerStatus":
        v = np.asarray(vector, float)
        return ControllerStatus(int(round(v[0])), int(round(v[1])), bool(v[2] >= 0.5))

    def to_vector(self) -> list[float]:
        return [float(self.plan_id), float(self.steps_done), 1.0 if self.idle else 0.0]


@dc.dataclass(frozen=True)
class Belief(_Immutable):
    """Where the robot believes it is after scan `scan` (0: before any scan): `dead_reckoned`,
    the state the executed plans predict; `state`, the same corrected by the scan's
    registration; `covariance` (3, 3), the planar pose error (dx, dy, dyaw) that no
    registration has removed yet (zero after a registered scan). With mission.verify_views,
    `frame` counts every frame registered (sensing scans and localisation frames) and `check`
    says what the last one asks for when it was a localisation frame: "correct" (registered,
    but the camera is off the planned view) or "relocalise" (not registered); "" otherwise."""
    scan: int
    dead_reckoned: np.ndarray
    state: np.ndarray
    covariance: np.ndarray
    frame: int = 0
    check: str = ""

    @staticmethod
    def exact(q) -> "Belief":
        q = np.asarray(q, float)
        return Belief(0, q, q, np.zeros((3, 3)))


@dc.dataclass(frozen=True)
class RegisteredScan(_Immutable):
    """Scan `index` (1-based; 0: none yet) at its registered (corrected) pose: the sensor
    origin (3,), the returns (N, 3) and the maximum-range end points of the no-return pixels
    (M, 3), world frame; `integrate`: False when the registration failed and
    localisation.skip_unregistered_scans holds it back; `info`: plan_id, t_sim, render_s,
    register_s, icp (the registration's summary) for the scan report; `pose`: the camera's
    registered pose X_WC (4, 4)."""
    index: int = 0
    origin: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    points: np.ndarray = dc.field(default_factory=lambda: np.zeros((0, 3)))
    free_rays: np.ndarray = dc.field(default_factory=lambda: np.zeros((0, 3)))
    integrate: bool = True
    info: dict = dc.field(default_factory=dict)
    pose: np.ndarray = dc.field(default_factory=lambda: np.eye(4))  #: X_WC at the registered pose


class ScanReport(_Immutable):
    """Immutable record of the last integrated scan."""

    def __init__(self, scan_index: int = 0, **info):
        self.scan_index = scan_index
        self.info = info


@dc.dataclass(frozen=True)
class PlanReport(_Immutable):
    """The planner's answer to scan `scan`: status "ok" (a plan), "stop" (a stop criterion
    before planning) or the planner's failure ("no_candidate", "no_path", "no_feasible");
    stop_reason names why the mission ends ("" while it goes on). `result` is the
    PlanResult's JSON (utility, factors, stages, times, path_kind, q_goal, n_controls, path,
    candidates); the belief the plan started from (believed_state: dead-reckoned,
    corrected_state: registered, start_sigma: its spread); plan_id and motion_sim_s of the
    emitted plan; recovery_s: the recovery planning since the previous scan. `status` "" and
    scan 0: no scan answered yet."""
    scan: int = 0
    status: str = ""
    stop_reason: str = ""
    result: dict = dc.field(default_factory=dict)
    plan_s: float | None = None
    believed_state: list | None = None
    corrected_state: list | None = None
    start_sigma: list | None = None
    plan_id: int | None = None
    motion_sim_s: float | None = None
    #: seconds the planner spent on the localisation frames between the previous scan and this
    #: one (the verification and recovery planning that followed the previous plan)
    recovery_s: float | None = None

    def to_json(self) -> dict:
        """The flat record of the iteration log ("plan" of iterations.jsonl, with scan and the
        two belief states)."""
        d = {"scan": self.scan, **self.result}
        if self.status:
            d["status"] = self.status
        for k in ("plan_s", "believed_state", "corrected_state", "start_sigma", "plan_id", "motion_sim_s",
                  "recovery_s"):
            v = getattr(self, k)
            if v is not None:
                d[k] = v
        d["stop_reason"] = self.stop_reason
        return d


def rounded_state(q) -> list[float]:
    """A state as the reports write it (6 decimals)."""
    q = np.asarray(q, float)
    assert q.shape == (NQ,)
    return [round(float(v), 6) for v in q]
