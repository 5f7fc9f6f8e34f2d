import json

import pytest
from conftest import small_scenario

from nbvs_drake.app.mission import run_mission
from nbvs_drake.config import apply_setting as _set
from nbvs_drake.config import load_scenario


def _small(seed=0, scans=3):
    return small_scenario(seed, scans)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    summary = run_mission(_small(), out, verbose=False)
    return out, summary


def test_short_run_writes_everything(small_run):
    out, s = small_run
    for f in ("summary.json", "iterations.jsonl", "model.ply", "coverage.png", "map.npz", "map.bt"):
        assert (out / f).stat().st_size > 0, f
    disk = json.loads((out / "summary.json").read_text())
    for key in ("coverage", "coverage_5mm", "coverage_by_scan", "scans", "collisions",
                "executed_trajectories", "stop_reason", "wall_s"):
        assert key in disk
    assert disk["scans"] == 3 and disk["stop_reason"] == "max_scans"
    assert disk["executed_trajectories"] == 2 and disk["collisions"] == 0
    cov = disk["coverage_by_scan"]
    assert len(cov) == 3 and all(b >= a - 1e-9 for a, b in zip(cov, cov[1:]))
    assert cov[-1] > cov[0] > 0.1
    lines = (out / "iterations.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in lines] == [1, 2, 3]
    ply = (out / "model.ply").read_bytes()
    assert ply.startswith(b"ply\n") and f"element vertex {disk['object_points']}".encode() in ply
    from nbvs_drake.config.load import with_resolved_sensor  # the sensor preset's values written out
    assert load_scenario(out / "scenario.yaml") == with_resolved_sensor(_small())  # it repeats the run


def test_clearance_script_measures_the_executed_paths(small_run):
    """scripts/clearance.py recomputes, from the run directory alone, the executed motions'
    closest approach to the true world: positive (no collision), one value per trajectory."""
    out, s = small_run
    c = _script("clearance").run_clearance(out)
    assert c["trajectories"] == s["executed_trajectories"] == 2
    assert 0.0 < c["min_clearance_m"] < 1.0 and c["nearest"]
    assert c["min_clearance_m"] == pytest.approx(min(c["per_trajectory_m"]), abs=1e-4)


def _script(name):
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_true_pose_coverage_of_a_noise_free_run_is_the_runs_own(small_run):
    """scripts/true_pose_coverage.py re-renders each scan at the logged true state and
    integrates it as if registration were perfect. Without noise that is what the run did,
    so it finds the run's coverage scan by scan (up to the logged states' 1e-6 rounding)."""
    out, s = small_run
    c = _script("true_pose_coverage").true_pose_coverage(out)
    assert c["scans"] == 3
    assert c["coverage"] == pytest.approx(s["coverage"], abs=1e-6)
    per = c["per_scan"]
    assert per["coverage_true_poses"] == pytest.approx(per["coverage"], abs=2e-3)
    assert per["coverage_true_poses"][0] < per["coverage_true_poses"][-1]


def test_notebook_runs_on_a_results_folder(small_run, tmp_path, monkeypatch):
    """notebooks/coverage_analysis.ipynb, every code cell in order, as Jupyter would run it
    from notebooks/ next to a results/ folder with one run and one experiment folder
    (motion_noise with one finished run; the table marks the others missing)."""
    import shutil
    import sys
    from pathlib import Path

    import matplotlib
    import nbformat

    matplotlib.use("Agg")
    out, s = small_run
    root = Path(__file__).resolve().parents[1]
    shutil.copytree(out, tmp_path / "results" / "small")
    from nbvs_drake.experiments import load_definition, resolve, write_table
    exp = tmp_path / "results" / "experiments" / "motion_noise"
    shutil.copytree(out, exp / "runs" / "teapot-DU-paper_s1")
    write_table(resolve(load_definition("motion_noise"), seeds=[1]), exp)
    (tmp_path / "notebooks").mkdir()
    monkeypatch.chdir(tmp_path / "notebooks")
    monkeypatch.setattr(sys, "path", list(sys.path))  # (the notebook no longer extends it)
    nb = nbformat.read(root / "notebooks" / "coverage_analysis.ipynb", as_version=4)
    nbformat.validate(nb)
    ns: dict = {}
    for cell in nb.cells:
        if cell.cell_type == "code":
            exec(compile(cell.source, "coverage_analysis.ipynb", "exec"), ns)
    assert list(ns["runs"]) == ["small"] and len(ns["runs"]["small"].records) == s["scans"]
    assert ns["runs"]["small"].summary == json.loads((out / "summary.json").read_text())  # RunResult.load
    assert ns["table"].cell("teapot/DU/paper")["metrics"]["coverage"]["mean"] == pytest.approx(100 * s["coverage"])
    # 3 objects x 3 approaches x 9 planners, but the 3 x 4 skipped noise-free DU cells and the
    # 3 x 2 DU and DU-MU cells of each EU-MU-only level (nbvs_tol25, nbvs_replan)
    assert [len(v) for v in ns["exp_runs"].values()] == [1] + [0] * 56


def test_same_seed_same_summary(small_run, tmp_path):
    out, s1 = small_run
    s2 = run_mission(_small(), tmp_path, verbose=False)
    from nbvs_drake.stage_clock import WALL_CLOCK_KEYS
    strip = lambda s: {k: v for k, v in s.items() if k not in WALL_CLOCK_KEYS}  # noqa: E731
    assert strip(s1) == strip(s2)
    a = [json.loads(x) for x in (out / "iterations.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    assert [r["plan"].get("q_goal") for r in a] == [r["plan"].get("q_goal") for r in b]


@pytest.mark.slow
def test_default_teapot_reconstruction(tmp_path):
    """The `make run` job: coverage >= 0.85 within 12 scans, no collision."""
    s = run_mission(load_scenario(), tmp_path, verbose=False)
    assert s["scans"] <= 12 and s["collisions"] == 0
    assert s["coverage"] >= 0.85, s["coverage_by_scan"]


def test_wiring_picture(tmp_path):
    from nbvs_drake.outputs.wiring import write_wiring
    paths = write_wiring(load_scenario(), tmp_path / "w")
    dot = paths[0].read_text()
    for name in ("kinematic_plant", "noisy_velocity_controller", "depth_camera", "octree_mapper",
                 "nbvs_planner", "position_to_geometry_pose", "scene_graph"):
        assert f"name={name}" in dot, name


@pytest.mark.parametrize("strategy, metric, obstacles", [("ort", "fig", "wbox"), ("random_sampling", "rsv", "wbox"),
                                                         ("random_sampling", "seed001", "voxels"),
                                                         ("view_sampling", "seed001", "wbox")])
def test_reconstruct_with_other_planners_and_metrics(tmp_path, strategy, metric, obstacles):
    from nbvs_drake.app.cli import main
    y = tmp_path / "s.yaml"
    y.write_text(f"name: alt\nnoise: {{sigma_v: 0, sigma_w: 0}}\nscene: {{gt_points: 5000}}\n"
                 f"planner: {{strategy: {strategy}, metric: {metric}, ort_vertices: 300, n_candidates: 500, "
                 f"map_obstacles: {obstacles}}}\n"
                 f"mission: {{max_scans: 2}}\n")
    assert main(["reconstruct", "--scenario", str(y), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["planner"] == strategy and s["scans"] >= 1
    recs = [json.loads(x) for x in (tmp_path / "o" / "iterations.jsonl").read_text().splitlines()]
    first = recs[0]["plan"]
    if strategy == "ort":
        assert first["stages"]["vertices"] == 300
    if first["status"] == "ok" and strategy == "ort":
        assert first["factors"]["metric"] == "fig"
    if obstacles == "voxels":
        assert 0 < first["stages"]["obstacle_boxes"] <= 300
    assert len(recs) == s["scans"]


def test_every_scenario_in_diagrams_loads():
    from nbvs_drake.resources import builtin_scenarios
    names = {load_scenario(p).name for p in builtin_scenarios().values()}
    assert {"default", "teapot_du", "teapot_du_mu", "teapot_eu_mu", "cluttered_room"} <= names


@pytest.mark.parametrize("name", ["teapot_eu_mu", "cluttered_room"])
def test_noisy_scenarios_run(tmp_path, name):
    """A small version of each noisy scenario (fewer candidates, rollouts, tree nodes):
    noisy execution, registration, EU, and (cluttered_room) the chairs and RRT."""
    sc = load_scenario(name)
    sc.mission.max_scans = 3
    sc.planner.n_candidates = 1500
    sc = _set(sc, "?planner.utility.samples=40")
    sc = _set(sc, f"?planner.motion_planner.max_nodes={min(sc.planner.rrt_max_nodes(), 400)}")
    sc.scene.gt_points = 5000
    s = run_mission(sc, tmp_path, verbose=False)
    assert s["relocalization"] == "icp" and s["scans"] >= 2, s
    recs = [json.loads(x) for x in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    second = recs[1]
    assert second["scan"]["icp"] is not None and len(second["executed_path"]) > 2
    # the controls were noisy: the true state is not the planned one
    assert second["true_state"] != recs[0]["plan"]["q_goal"]
    assert "eu" in recs[0]["plan"]["factors"]
    for f in ("paths.png", "replay.html", "summary.json"):
        assert (tmp_path / f).stat().st_size > 0


def test_a_collision_stops_the_run_and_keeps_the_colliding_trajectory(tmp_path):
    """Arm noise far beyond Table 4 (sigma 3 rad/s per joint) makes the arm flail into the
    robot or the floor within the first trajectory. The run stops (on_collision: stop), every
    finished iteration is in iterations.jsonl, and the colliding trajectory, which no scan
    ended, is kept in summary.json (up to the collision) and drawn in paths.png and replay.html."""
    import numpy as np
    sc = load_scenario("default")
    sc.mission.max_scans = 3
    sc.mission.on_collision = "stop"
    sc.planner.n_candidates = 1500
    sc.scene.gt_points = 5000
    sc.noise.sigma_v, sc.noise.sigma_w, sc.noise.sigma_arm = 0.5, 2.0, [3.0] * 5
    s = run_mission(sc, tmp_path, verbose=False)
    assert s["stop_reason"] == "collision" and s["collisions"] == 1
    c = s["collision"]
    assert c["trajectory"] == s["executed_trajectories"] >= 1
    assert len(c["executed_path"]) >= 2
    np.testing.assert_allclose(c["executed_path"][-1], c["true_state"], atol=1e-4)  # sampled up to the stop
    # what it hit: a robot geometry against the real world (table, object, ...)
    assert c["contacts"] and all(x["depth_m"] > 0 for x in c["contacts"])
    robot = "patrolbot_katana::"
    assert any(x["a"].startswith(robot) or x["b"].startswith(robot) for x in c["contacts"])
    assert not any("W_box" in (x["a"], x["b"]) for x in c["contacts"])  # the truth has no W_box
    recs = [json.loads(x) for x in (tmp_path / "iterations.jsonl").read_text().splitlines()]
    assert len(recs) == s["scans"] == c["trajectory"]  # the scans before the colliding motion
    assert json.loads((tmp_path / "summary.json").read_text())["collision"] == c
    assert (tmp_path / "paths.png").stat().st_size > 0 and "visual_output_errors" not in s
    from test_replay import _decoded_commands
    decoded = _decoded_commands((tmp_path / "replay.html").read_text())
    assert "/nbvs/collision/trail" in decoded and "/nbvs/collision/cross" in decoded
