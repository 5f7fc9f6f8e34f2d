"""MissionRecorder: writes one JSON line per finished iteration, as it happens."""

from __future__ import annotations

import json
import os
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from ..mapping.occupancy import OccupancyMap
from ..perception.evaluation import coverage, plan_prediction, scan_outcome
from ..stage_clock import EVALUATION, OUTPUTS, stage
from ..world.pose import state_error
from .messages import Belief, ControllerStatus, PlanReport, ScanReport


class IterationLog:
    """Append-only JSON-lines file: each record is one write of one whole line, flushed and
    fsync'ed, so a killed run keeps every finished iteration."""

    def __init__(self, path, echo=None):
        self.path = path
        self.records: list[dict] = []
        self.echo = echo
        open(path, "w").close()

    def append(self, rec: dict):
        line = json.dumps(rec, separators=(",", ":")) + "\n"
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            os.write(fd, line.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        self.records.append(rec)
        if self.echo:
            self.echo(rec)


class MissionRecorder(LeafSystem):
    """A sink: when the planner has answered scan k (a plan or a stop), it evaluates the map
    after scan k (coverage against the ground truth at 3 mm, 5 mm and one voxel; unknown
    voxels) and appends iteration k to the IterationLog with the scan and plan reports, the
    true state at the scan, the believed (dead-reckoned) and the corrected (registered)
    states, and the executed (true) path of the motion that led to scan k; from scan 2 on,
    the prediction of the plan that led to it and the scan's outcome (`evaluation`); when
    that plan was made again after a localisation frame (verified_views.replan), the record
    keeps it as `replanned_plan` and the prediction is its. It keeps
    the map snapshot of every iteration in `maps` (for the replay).

    Input ports:
      - map (abstract OccupancyMap)
      - scan_report (abstract ScanReport)
      - plan_report (abstract PlanReport)
      - true_state (8)
      - collisions (3): [collided trajectories, executed trajectories, in collision now]
      - controller_status (3): `ControllerStatus`; the true state is sampled while a plan
        executes.
      - belief (abstract Belief): the localisation's belief; at each localisation frame
        (mission.verify_views) the true state is read, and each of the iteration's frames
        gets `true_error` [m, rad], the corrected belief's error after that frame.
    Output ports: none (writes files).
    """

    def __init__(self, log: IterationLog, gt_points: np.ndarray, voxel: float, dt: float, dummy_map: OccupancyMap):
        super().__init__()
        self.log = log
        self.gt = gt_points
        self.thresholds = (0.003, 0.005, voxel, 0.01)
        self._map = self.DeclareAbstractInputPort("map", AbstractValue.Make(dummy_map))
        self._scan = self.DeclareAbstractInputPort("scan_report", AbstractValue.Make(ScanReport()))
        self._plan = self.DeclareAbstractInputPort("plan_report", AbstractValue.Make(PlanReport()))
        self._true = self.DeclareVectorInputPort("true_state", 8)
        self._coll = self.DeclareVectorInputPort("collisions", 3)
        self._status = self.DeclareVectorInputPort("controller_status", ControllerStatus.SIZE)
        self._belief = self.DeclareAbstractInputPort("belief", AbstractValue.Make(Belief.exact(np.zeros(8))))
        self.DeclarePeriodicPublishEvent(dt, 0.0, self._publish)
        self._frame_seen = 0
        self._frame_errors: list[list[float]] = []
        self._t_last = time.perf_counter()
        self.maps: list[OccupancyMap] = []
        self._path: list[list[float]] = []

    def _r(self, q) -> list[float]:
        return [round(float(v), 5) for v in q]

    def written(self) -> int:
        return len(self.log.records)

    def unfinished_path(self) -> list[list[float]]:
        """The true states sampled so far of the motion in progress (no scan has ended it yet):
        when a collision stops the run, the colliding trajectory up to the collision."""
        return self._path[::2] + self._path[-1:] if self._path else []

    def _with_frame_errors(self, info: dict) -> dict:
        """The scan report, each of its localisation frames with its `true_error` [m, rad]
        (the frames since the last sensing scan, in order)."""
        out = dict(info)
        frames = info.get("frames")
        if frames:  # (were one missed, the earliest frames go without)
            errs = self._frame_errors[-len(frames):]
            pad = len(frames) - len(errs)
            out["frames"] = list(frames[:pad]) + [dict(f, true_error=e) for f, e in zip(frames[pad:], errs)]
        self._frame_errors = []
        return out

    _replanned: PlanReport | None = None

    @staticmethod
    def _plan_json(report: PlanReport) -> dict:
        skip = ("scan", "believed_state", "corrected_state")
        return {key: v for key, v in report.to_json().items() if key not in skip}

    def _publish(self, context):
        # moving: sample the executed path (a sink's side effect, as the log)
        if not ControllerStatus.of(self._status.Eval(context)).idle:
            self._path.append(self._r(self._true.Eval(context)))
        belief: Belief = self._belief.Eval(context)
        if belief.frame > self._frame_seen:  # a registration ran: a localisation frame's error
            self._frame_seen = belief.frame
            if belief.check:
                err = state_error(self._true.Eval(context), belief.state)
                self._frame_errors.append([round(err[0], 6), round(err[1], 6)])
        report: PlanReport = self._plan.Eval(context)
        k = report.scan
        if k <= self.written():
            if k == self.written() and "replanned_at_frame" in report.result:
                self._replanned = report  # the written plan made again after a frame (verified_views.replan)
            return
        with stage(EVALUATION, "iteration_record"):
            omap: OccupancyMap = self._map.Eval(context)
            scan: ScanReport = self._scan.Eval(context)
            t = time.perf_counter()
            with stage(EVALUATION, "coverage"):
                cov = coverage(self.gt, omap.object_points, self.thresholds)
            t_cov = time.perf_counter() - t
            counts = omap.counts()
            coll = self._coll.Eval(context)
            now = time.perf_counter()
            rec = {
                "iteration": k,
                "t_sim": round(context.get_time(), 3),
                "coverage": cov[0], "coverage_5mm": cov[1], "coverage_voxel": cov[2], "coverage_1cm": cov[3],
                "unknown_voxels": counts["unknown"], "reachable_unknown_voxels": omap.reachable_unknown_count(),
                "occupied_voxels": counts["occupied"],
                "remaining_unknown_m3": counts["unknown"] * omap.voxel_volume(),
                "object_points": int(len(omap.object_points)),
                "scan": self._with_frame_errors(scan.info),
                "plan": self._plan_json(report),
                "true_state": [round(float(v), 6) for v in self._true.Eval(context)],
                "believed_state": report.believed_state,
                "corrected_state": report.corrected_state,
                "executed_path": self.unfinished_path(),
                "collided_trajectories": int(coll[0]), "executed_trajectories": int(coll[1]),
                "coverage_s": t_cov,
                "wall_s": now - self._t_last,
            }
            if self._replanned is not None:  # the plan that led to this scan: the previous one made again
                rec["replanned_plan"] = self._plan_json(self._replanned)
                self._replanned = None
            if self.maps and self.log.records:  # the plan that led to this scan: its prediction, and what came
                prev_plan = rec.get("replanned_plan") or self.log.records[-1]["plan"]
                if prev_plan.get("status") == "ok":
                    rec["prediction"] = plan_prediction(prev_plan.get("factors", {}), omap.voxel_volume())
                rec["outcome"] = scan_outcome(self.maps[-1], omap)
            self._t_last = now
            self._path = []
            self.maps.append(omap)
        with stage(OUTPUTS, "iterations"):
            self.log.append(rec)
