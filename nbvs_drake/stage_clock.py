"""Where a mission's seconds go: a clock of named, disjoint stages.

`run_mission` makes a `StageClock` the active one for the run (`StageClock.running`); each
system wraps its work in `stage(name, part)`, and the mission wraps what lies outside the
simulator (building the diagram, the evaluation, the outputs) and the simulator's
`AdvanceTo` itself. Time is exclusive: while a stage runs inside another (a render inside a
registration, every system inside `simulator`), the inner one gets those seconds and the
outer one gets only its own. The top-level stages therefore never overlap, and `simulator`
keeps only Drake's stepping and the light systems' work. What no stage covers (between
`reconstruct`'s entry and the clock's start, between stages) is `unattributed`.

Without an active clock (a system built in a test, a plan called from a notebook) `stage`
does nothing.
"""

from __future__ import annotations

import contextlib
import time

#: the top-level stages of a mission, in the order summary.json lists them
SETUP = "setup"  #: imports, the scenario, the diagram and the simulator's initialisation
SIMULATOR = "simulator"  #: the simulator's stepping: Drake's events, the controller, plant and monitor
NBV_PLAN = "nbv_plan"  #: the NBV plans: candidates, view evaluation, motion planning, expected utility
#: the localisation frames' registration, the re-localisation views and the recovery paths
VERIFICATION = "verification_recovery"
SCANS = "scans"  #: rendering every depth image (the localisation frames' too) and its faults
REGISTRATION = "registration"  #: the sensing scans' registration and the registration model's merge
MAP = "map"  #: the octree's update and the surface fusion's per-scan depth maps
EVALUATION = "evaluation"  #: coverage per scan, the reconstruction's metrics, the coverage ceiling
OUTPUTS = "outputs"  #: iterations.jsonl, the model, mesh, maps, plots, replay and summary files
UNATTRIBUTED = "unattributed"
STAGES = (SETUP, SIMULATOR, NBV_PLAN, VERIFICATION, SCANS, REGISTRATION, MAP, EVALUATION, OUTPUTS)

#: summary.json's wall-clock entries: what differs between two runs of the same seed
WALL_CLOCK_KEYS = ("wall_s", "times_s", "stages_s", "stage_parts_s", "plan_s_per_iteration",
                   "planning_all_s_per_iteration")

_active: "StageClock | None" = None


class _Frame:
    __slots__ = ("name", "part", "own", "mark")

    def __init__(self, name: str, part: str, now: float):
        self.name, self.part, self.own, self.mark = name, part, 0.0, now


class StageClock:
    """Exclusive wall time per (stage, part) since `t0` (perf_counter seconds, when it was made)."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.parts: dict[str, dict[str, float]] = {}  #: stage -> part -> seconds
        self._stack: list[_Frame] = []

    @property
    def totals(self) -> dict[str, float]:
        """stage -> seconds (its parts together)."""
        return {k: sum(v.values()) for k, v in self.parts.items()}

    @contextlib.contextmanager
    def stage(self, name: str, part: str = "other"):
        """Counts the block's own seconds (less those of stages inside it) to `name`, under
        `part`. The yielded frame's `name` and `part` may be changed inside the block (the work
        is known only at its end: a registration that turns out a localisation frame)."""
        now = time.perf_counter()
        if self._stack:
            top = self._stack[-1]
            top.own += now - top.mark
        f = _Frame(name, part, now)
        self._stack.append(f)
        try:
            yield f
        finally:
            now = time.perf_counter()
            self._stack.pop()
            self.add(f.name, f.part, f.own + now - f.mark)
            if self._stack:
                self._stack[-1].mark = now

    def add(self, name: str, part: str, seconds: float):
        parts = self.parts.setdefault(name, {})
        parts[part] = parts.get(part, 0.0) + seconds

    @contextlib.contextmanager
    def running(self):
        """Makes this the clock `stage` counts on for the block."""
        global _active
        prev, _active = _active, self
        try:
            yield self
        finally:
            _active = prev

    def report(self, wall_s: float, digits: int = 3) -> tuple[dict, dict]:
        """({stage: seconds} over STAGES and `unattributed` (wall_s less the stages), adding
        up to wall_s; {stage: {part: seconds}})."""
        totals = self.totals
        stages = {k: round(totals.get(k, 0.0), digits) for k in STAGES}
        for k, v in totals.items():
            if k not in stages:
                stages[k] = round(v, digits)
        stages[UNATTRIBUTED] = round(max(wall_s - sum(totals.values()), 0.0), digits)
        parts = {k: {p: round(s, digits) for p, s in sorted(v.items(), key=lambda kv: -kv[1])}
                 for k, v in self.parts.items()}
        return stages, parts


def stage(name: str, part: str = "other"):
    """`StageClock.stage` on the active clock; a no-op block when none is active."""
    if _active is None:
        return contextlib.nullcontext(_Frame(name, part, 0.0))
    return _active.stage(name, part)
