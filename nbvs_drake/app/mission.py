"""Runs a reconstruction mission: the Drake Simulator advances the mission diagram until the
planner stops (scan budget spent, no valid candidate, no path); then the results are written:
scenario.yaml (the resolved scenario, written first), summary.json, iterations.jsonl (written
during the run), model.ply, model_mesh.ply (the TSDF surface), map.npz, coverage.png."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..config import Scenario
from ..files import write_atomic
from ..mapping.occupancy import write_ply
from ..perception.evaluation import planning_per_iteration
from ..stage_clock import EVALUATION, MAP, OUTPUTS, SETUP, SIMULATOR, StageClock
from ..systems.mission_recorder import IterationLog
from .diagram import build_mission_diagram


def _print_iteration(rec: dict):
    plan = rec.get("plan", {})
    scan = rec.get("scan", {})
    status = plan.get("status", "")
    if status == "ok":
        what = f"g={plan['utility']:.3g} ({plan['path_kind']}, {plan['n_controls']} controls)"
    else:
        what = f"stop: {plan.get('stop_reason') or status}"
    print(f"scan {rec['iteration']:2d}  coverage {rec['coverage']:.3f} (5 mm {rec['coverage_5mm']:.3f})  "
          f"unknown {rec['unknown_voxels']:6d}  update {scan.get('update_s', 0) * 1e3:5.1f} ms  "
          f"render {scan.get('render_s', 0) * 1e3:5.1f} ms  plan {plan.get('plan_s', 0):5.2f} s  {what}",
          flush=True)


def _write_json(path: Path, obj):
    write_atomic(path, json.dumps(obj, indent=2))


def pose_errors(records: list[dict]) -> dict:
    """Mean planar position (m) and heading (rad) error at the scans after the first, of the
    dead-reckoned belief and of the registration-corrected belief against the true state."""
    from ..world.pose import state_error
    rows = [r for r in records[1:] if r.get("believed_state") and r.get("corrected_state")]
    if not rows:
        return {"scans": 0}
    b = np.array([state_error(r["true_state"], r["believed_state"]) for r in rows])
    c = np.array([state_error(r["true_state"], r["corrected_state"]) for r in rows])
    out = {"scans": len(rows),
           "believed_m": round(float(b[:, 0].mean()), 5), "believed_rad": round(float(b[:, 1].mean()), 5),
           "corrected_m": round(float(c[:, 0].mean()), 5), "corrected_rad": round(float(c[:, 1].mean()), 5),
           "icp_applied": int(sum(1 for r in rows if (r["scan"].get("icp") or {}).get("applied")))}
    # the corrected belief's error after the run's last registration (its last scan whose ICP applied)
    reg = [i for i, r in enumerate(rows) if (r["scan"].get("icp") or {}).get("applied")]
    if reg:
        out["last_registered_m"] = round(float(c[reg[-1], 0]), 5)
        out["last_registered_rad"] = round(float(c[reg[-1], 1]), 5)
    # the localisation frames that registered (mission.verify_views): the corrected belief's
    # error after each, read from the true state at the frame
    fe = np.array([f["true_error"] for r in records for f in r["scan"].get("frames") or []
                   if "true_error" in f and (f.get("icp") or {}).get("applied")]).reshape(-1, 2)
    if len(fe):
        out["frames_registered"] = len(fe)
        out["frames_worst_m"] = round(float(fe[:, 0].max()), 5)
        out["frames_worst_rad"] = round(float(fe[:, 1].max()), 5)
    return out


def summary_cov(records: list[dict], key: str) -> float:
    """The last iteration's coverage `key` (0 before any scan)."""
    return records[-1][key] if records else 0.0


def share_of(value: float, ceiling) -> float | None:
    """value over its ceiling (None without a positive ceiling), rounded as the summary is."""
    return round(value / ceiling, 6) if ceiling else None


def recovery_counts(records: list[dict]) -> dict:
    """mission.verify_views: localisation frames taken before the sensing scans, and of them
    those answered by a correction (`corrections`) and by a re-localisation view (`recoveries`)."""
    frames = [f for r in records for f in r["scan"].get("frames") or []]
    out = {"localisation_frames": len(frames),
           "corrections": sum(1 for f in frames if f.get("check") == "correct" and f.get("purpose") != "leg"),
           "recoveries": sum(1 for f in frames if f.get("check") == "relocalise")}
    legs = sum(1 for f in frames if f.get("purpose") == "leg")
    if legs:  # mission.legs: frames at the end of a leg
        out["leg_frames"] = legs
    return out


def prediction_summary(records: list[dict]) -> dict:
    """Predicted against revealed unknown volume over the run's plans (prediction_r2,
    prediction_slope, prediction_pairs; NaN written as null) and the scans that returned
    fewer than evaluation.BLIND_SCAN_POINTS object points (blind_scans: how many;
    blind_scan_list: which)."""
    from ..perception.evaluation import BLIND_SCAN_POINTS, prediction_fit
    fit = prediction_fit(records)
    clean = lambda v: None if v != v else round(v, 6)  # noqa: E731 - NaN -> null
    blind = [r["iteration"] for r in records if r["scan"].get("object_points", BLIND_SCAN_POINTS) < BLIND_SCAN_POINTS]
    return {"prediction_r2": clean(fit["r2"]), "prediction_slope": clean(fit["slope"]),
            "prediction_pairs": fit["pairs"], "blind_scans": len(blind), "blind_scan_list": blind}


def _finish_clock(summary: dict, clock: StageClock):
    """wall_s (from the clock's start to now) and its disjoint stages (stages_s, with
    `unattributed`), each stage's parts below it (stage_parts_s)."""
    summary["wall_s"] = time.perf_counter() - clock.t0
    summary["stages_s"], summary["stage_parts_s"] = clock.report(summary["wall_s"])


def run_mission(sc: Scenario, out_dir: str | Path, verbose: bool = True, meshcat=None,
                clock: StageClock | None = None, attach=None, visual_outputs: bool = True) -> dict:
    """`meshcat`: a pydrake Meshcat that shows the run live (robot, map, plans), or None.
    `clock`: the run's stage clock, started where its time begins (`reconstruct`'s entry);
    None: one started here. summary.json's `wall_s` runs from the clock's start to the final
    summary.json, and `stages_s` splits it into the clock's disjoint stages (stage_clock.py).
    `attach(md, simulator)`: called once the diagram and its Simulator exist, before it is
    initialised (nbvs_drake.gym hands the planner's decisions to an agent there).
    `visual_outputs` False: no paths.png or replay.html (the rest is written)."""
    clock = clock or StageClock()
    with clock.running():
        return _run_mission(sc, Path(out_dir), verbose, meshcat, clock, attach, visual_outputs)


def _run_mission(sc: Scenario, out: Path, verbose: bool, meshcat, clock: StageClock, attach=None,
                 visual_outputs: bool = True) -> dict:
    with clock.stage(SETUP, "diagram"):
        # Open3D (registration, surface fusion) before the first scan: a Ctrl-C that lands in its
        # import mid-run leaves it half initialised, and it then exits with status 1 at shutdown
        import open3d  # noqa: F401
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import EventStatus

        out.mkdir(parents=True, exist_ok=True)
        # the resolved scenario (seed, defaults and the sensor preset's values filled in):
        # `nbvs reconstruct --scenario OUT/scenario.yaml` repeats the run
        from pydrake.common.yaml import yaml_dump_typed

        from ..config.load import with_resolved_sensor
        (out / "scenario.yaml").write_text(yaml_dump_typed(with_resolved_sensor(sc)))
        log = IterationLog(out / "iterations.jsonl", echo=_print_iteration if verbose else None)
        md = build_mission_diagram(sc, out / "scene", log, meshcat=meshcat)
        if verbose:
            print(f"nbvs: scenario {sc.name!r}, seed {sc.seed}, object {sc.scene.object.kind}, "
                  f"planner {sc.planner.strategy_word()}, writing to {out}", flush=True)
        sim = Simulator(md.diagram)
        ctx = sim.get_mutable_context()
        planner = md.systems["planner"]
        rec = md.systems["recorder"]
        monitor_sys = md.systems["monitor"]
        halted = {}

        def monitor(root_context):
            pctx = planner.GetMyContextFromRoot(root_context)
            stopped = planner.GetOutputPort("stopped").Eval(pctx)[0] > 0.5
            if stopped and rec.written() >= planner.GetOutputPort("report").Eval(pctx).scan:
                return EventStatus.ReachedTermination(planner, "mission finished")
            if sc.mission.on_collision == "stop":
                counts = monitor_sys.GetOutputPort("counts").Eval(monitor_sys.GetMyContextFromRoot(root_context))
                if counts[0] > 0:
                    halted["t"] = root_context.get_time()
                    return EventStatus.ReachedTermination(monitor_sys, "collision")
            return EventStatus.Succeeded()

        sim.set_monitor(monitor)
        if attach is not None:
            attach(md, sim)
        sim.Initialize()
    with clock.stage(SIMULATOR):
        sim.AdvanceTo(sc.mission.max_sim_time)
        pctx = planner.GetMyContextFromRoot(ctx)
        report = planner.GetOutputPort("report").Eval(pctx)
        stop_reason = "collision" if halted else (report.stop_reason or "max_sim_time")
        mapper = md.systems["mapper"]
        omap = mapper.GetOutputPort("map").Eval(mapper.GetMyContextFromRoot(ctx))
        counts = monitor_sys.GetOutputPort("counts").Eval(monitor_sys.GetMyContextFromRoot(ctx))

    from ..perception.reconstruction import mesh_metrics, owned_by, point_metrics, write_mesh_ply
    with clock.stage(MAP, "surface_fusion"):  # the TSDF mesh of the registered scans that agree
        fusion = md.systems["surface_fusion"]
        fctx = fusion.GetMyContextFromRoot(ctx)
        mesh_V, mesh_T = fusion.GetOutputPort("mesh").Eval(fctx)
        # the point model without the returns of the scans the mesh leaves out (misplaced)
        left_out = fusion.GetOutputPort("left_out").Eval(fctx)
        model_points = omap.object_points
        if left_out:
            scans = fusion.GetOutputPort("scans").Eval(fctx)
            from ..world.sensor import intrinsics
            model_points = model_points[~owned_by(model_points, [scans[i] for i in left_out], intrinsics(sc.sensor))]
    with clock.stage(OUTPUTS, "model"):
        write_ply(out / "model.ply", model_points)
        write_mesh_ply(out / "model_mesh.ply", mesh_V, mesh_T)
    t_rec = time.perf_counter()
    with clock.stage(EVALUATION, "reconstruction"):
        gt_V, gt_T, vox = md.mesh.vertices, md.mesh.triangles, sc.mapper.voxel_size
        reconstruction = {
            "points": point_metrics(model_points, gt_V, gt_T, md.gt_points, vox),
            "mesh": mesh_metrics(mesh_V, mesh_T, gt_V, gt_T, md.gt_points, vox, np.random.default_rng([sc.seed, 23])),
            "mesh_vertices": int(len(mesh_V)), "mesh_triangles": int(len(mesh_T)),
            # the scans the model leaves out: {number among the integrated scans: conflict share}
            "scans_left_out": {str(k): round(float(v), 4) for k, v in sorted(left_out.items())},
            "points_left_out": int(len(omap.object_points) - len(model_points)),
        }
    t_rec = time.perf_counter() - t_rec
    ceiling = None
    if sc.mission.coverage_ceiling:
        from ..planning.oracle import coverage_ceiling
        with clock.stage(EVALUATION, "coverage_ceiling"):
            ceiling = coverage_ceiling(sc, md.kin, md.mesh, str(out / "scene" / "object.obj"))
    records = log.records
    with clock.stage(OUTPUTS, "map"):
        omap.save_npz(out / "map.npz")
        from ..mapping.octomap_io import write_bt
        write_bt(omap, out / "map.bt")
    with clock.stage(OUTPUTS, "coverage_png"):
        from ..outputs.plots import plot_coverage
        plot_coverage(records, out / "coverage.png", title=f"{sc.name} (seed {sc.seed})")
    with clock.stage(OUTPUTS, "summary"):
        collided, executed = int(counts[0]), int(counts[1])
        plans = [r["plan"] for r in records if r["plan"].get("status") == "ok"]

        def stage_total(key):
            return float(sum(r["plan"].get("times", {}).get(key, 0.0) for r in records))

        collision = None
        if halted:  # the trajectory that collided never reached a scan: keep it here
            kplant = md.systems["kinematic_plant"]
            q_stop = kplant.GetOutputPort("state").Eval(kplant.GetMyContextFromRoot(ctx))
            # the state the monitor found in contact (the plant has moved one control step on since)
            q_hit = monitor_sys.GetOutputPort("collision_state").Eval(monitor_sys.GetMyContextFromRoot(ctx))
            collision = {"trajectory": executed, "t_sim": round(halted["t"], 3),
                         "true_state": [round(float(v), 6) for v in q_stop],
                         "contact_state": [round(float(v), 6) for v in q_hit],
                         "executed_path": rec.unfinished_path(),
                         "contacts": monitor_sys.truth.contacts(q_hit)}
        summary = {
            "scenario": sc.name,
            "seed": sc.seed,
            "planner": sc.planner.strategy_word(),
            "coverage": summary_cov(records, "coverage"),
            "coverage_5mm": summary_cov(records, "coverage_5mm"),
            "coverage_voxel": summary_cov(records, "coverage_voxel"),
            "coverage_1cm": summary_cov(records, "coverage_1cm"),
            "coverage_by_scan": [r["coverage"] for r in records],
            # the share of the surface any reachable pose can see (planning/oracle.py), and ours of it
            "coverage_ceiling": ceiling["ceiling"] if ceiling else None,
            "coverage_of_ceiling": share_of(summary_cov(records, "coverage"), ceiling and ceiling["ceiling"]),
            # at 1 cm (a map of 3 cm voxels): the ceiling and ours of it
            "coverage_ceiling_1cm": ceiling["ceiling_1cm"] if ceiling else None,
            "coverage_of_ceiling_1cm": share_of(summary_cov(records, "coverage_1cm"),
                                                ceiling and ceiling["ceiling_1cm"]),
            "scans": int(omap.scan_count),
            "collisions": collided,
            "executed_trajectories": executed,
            "collision_rate": collided / executed if executed else 0.0,
            "stop_reason": stop_reason,
            "collision": collision,
            "distance": float(sum(p["factors"]["rho"] for p in plans)),
            # accuracy, completeness, Chamfer, precision / recall / F-score at 3 mm, 5 mm and one voxel
            # (reconstruction.py), of the point model and of the TSDF mesh (model_mesh.ply)
            "reconstruction": reconstruction,
            "remaining_unknown_m3": records[-1]["remaining_unknown_m3"] if records else None,
            "unknown_voxels": records[-1]["unknown_voxels"] if records else None,
            "reachable_unknown_voxels": records[-1].get("reachable_unknown_voxels") if records else None,
            "object_points": int(len(omap.object_points)),
            "relocalization": sc.localisation.method,
            "pose_error": pose_errors(records),
            **(recovery_counts(records) if sc.localisation.verified_views is not None else {}),
            **prediction_summary(records),
            "sim_time_s": round(ctx.get_time(), 3),
            "times_s": {
                "plan": float(sum(p.get("plan_s", 0.0) for p in plans)),
                "generate": stage_total("generate_s"),
                "position_filter": stage_total("position_s"),
                "visibility": stage_total("visibility_s"),
                # the path search and every collision check (the expected utility's rollouts' included)
                "motion_planning": stage_total("motion_planning_s"),
                # candidate views (and the expected utility's rollouts' final views) scored
                "view_evaluation": stage_total("view_evaluation_s"),
                "map_update": float(sum(r["scan"].get("update_s", 0.0) for r in records)),
                "registration": float(sum(r["scan"].get("register_s", 0.0) for r in records)),
                "render": float(sum(r["scan"].get("render_s", 0.0) for r in records)),
                "coverage_eval": float(sum(r["coverage_s"] for r in records)),
                "reconstruction": t_rec,
                "coverage_ceiling": ceiling["seconds"] if ceiling and not ceiling.get("cached") else 0.0,
            },
            **{k: None if v is None else round(v, 4) for k, v in planning_per_iteration(records).items()},
        }
        _finish_clock(summary, clock)
        _write_json(out / "summary.json", summary)
    if not visual_outputs:
        return summary
    # paths.png and replay.html after summary.json: a failure there cannot lose the results
    with clock.stage(OUTPUTS, "visual_outputs"):
        from ..outputs.visual_outputs import write_visual_outputs
        vis = write_visual_outputs(out, sc, records, getattr(rec, "maps", None), out / "scene" / "object.obj",
                                   verbose=verbose, collision=collision, model_mesh=(mesh_V, mesh_T))
    with clock.stage(OUTPUTS, "summary"):
        summary["times_s"]["visual_outputs"] = vis["seconds"]
        if vis["errors"]:
            summary["visual_output_errors"] = vis["errors"]
        _finish_clock(summary, clock)
        _write_json(out / "summary.json", summary)
    if verbose:
        print(f"done: coverage {summary['coverage']:.3f} after {summary['scans']} scans, "
              f"{collided} collisions in {executed} trajectories, stop: {stop_reason}, "
              f"{summary['wall_s']:.1f} s  -> {out}/summary.json", flush=True)
    return summary
