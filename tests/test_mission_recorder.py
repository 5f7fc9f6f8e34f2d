"""MissionRecorder, in Drake's style: the system alone, its inputs fixed, its publish event
run by a Simulator, the iteration log read back."""
import json

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from nbvs_drake.config import load_scenario
from nbvs_drake.mapping.occupancy import OccupancyMap
from nbvs_drake.systems.messages import Belief, ControllerStatus, PlanReport, ScanReport
from nbvs_drake.systems.mission_recorder import IterationLog, MissionRecorder


def test_each_localisation_frame_of_an_iteration_gets_its_true_error(tmp_path):
    """Two localisation frames, then the sensing scan whose plan is answered: the logged
    iteration's frames carry the corrected belief's true error at each frame, in order;
    a registration that is the sensing scan itself (check "") adds none."""
    sc = load_scenario()
    omap = OccupancyMap.for_scenario(sc)
    log = IterationLog(tmp_path / "iterations.jsonl")
    rec = MissionRecorder(log, np.zeros((50, 3)), sc.mapper.voxel_size, 0.1, omap)
    sim = Simulator(rec)
    ctx = sim.get_mutable_context()
    step = iter(np.arange(1, 100) * 0.1)
    publish = lambda: sim.AdvanceTo(next(step))  # noqa: E731  (its periodic publish event)
    q_true = np.array([1.0, -0.5, 0.3, 0, 0, 0, 0, 0])
    fix = lambda name, v: rec.GetInputPort(name).FixValue(ctx, v)  # noqa: E731
    fix("map", AbstractValue.Make(omap))
    fix("scan_report", AbstractValue.Make(ScanReport(0)))
    fix("plan_report", AbstractValue.Make(PlanReport()))
    fix("true_state", q_true)
    fix("collisions", np.zeros(3))
    fix("controller_status", np.array(ControllerStatus(3, 0, True).to_vector()))

    def belief(frame, check, dx, dyaw):
        q = q_true.copy()
        q[0] += dx
        q[2] += dyaw
        return AbstractValue.Make(Belief(1, q_true, q, np.zeros((3, 3)), frame, check))

    fix("belief", belief(1, "relocalise", 0.12, 0.2))   # a frame that did not register
    publish()
    publish()  # the same frame seen again: counted once
    fix("belief", belief(2, "correct", 0.004, -0.003))  # registered, 4 mm / 3 mrad off
    publish()
    fix("belief", belief(3, "", 0.001, 0.0))  # the sensing scan
    publish()
    frames = [{"purpose": "leg", "check": "relocalise", "icp": {"applied": False}},
              {"purpose": "relocalise", "check": "correct", "icp": {"applied": True}}]
    fix("scan_report", AbstractValue.Make(ScanReport(1, frames=frames)))
    fix("plan_report", AbstractValue.Make(PlanReport(scan=1, status="stop", stop_reason="max_scans")))
    publish()

    written = [json.loads(line) for line in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    assert len(written) == 1
    got = [f["true_error"] for f in written[0]["scan"]["frames"]]
    np.testing.assert_allclose(got, [[0.12, 0.2], [0.004, 0.003]], atol=1e-6)
    assert [f["check"] for f in written[0]["scan"]["frames"]] == ["relocalise", "correct"]


def test_pose_errors_summarise_scans_and_registered_frames():
    """summary.json's pose_error: the corrected belief after the last registered scan, and
    the worst of the localisation frames that registered (frames that did not are left out)."""
    from nbvs_drake.app.mission import pose_errors
    q = [0.0] * 8

    def row(k, corrected_dx, applied, frames=()):
        c = list(q)
        c[0] = corrected_dx
        return {"iteration": k, "true_state": q, "believed_state": q, "corrected_state": c,
                "scan": {"icp": {"applied": applied}, "frames": list(frames)}}

    frames = [{"icp": {"applied": False}, "true_error": [0.2, 0.3]},
              {"icp": {"applied": True}, "true_error": [0.016, 0.017]},
              {"icp": {"applied": True}, "true_error": [0.001, 0.002]}]
    out = pose_errors([row(1, 0.0, False), row(2, 0.004, True, frames), row(3, 0.03, False)])
    assert out["scans"] == 2 and out["icp_applied"] == 1
    assert out["last_registered_m"] == 0.004  # scan 3 was not registered
    assert (out["frames_registered"], out["frames_worst_m"], out["frames_worst_rad"]) == (2, 0.016, 0.017)
    assert "frames_registered" not in pose_errors([row(1, 0.0, False), row(2, 0.0, True)])
