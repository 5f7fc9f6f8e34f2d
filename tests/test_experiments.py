"""`nbvs experiment`: definitions as data, the table from the finished runs, the local and the
Ray executors giving the same table, a killed batch keeping its finished runs, failed runs
recorded and retried, the report."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ctrl_c_as_in_a_terminal

from nbvs_drake.app.cli import main
from nbvs_drake.config import load_scenario
from nbvs_drake.experiments import (
    ExperimentError,
    comparable,
    compared_markdown,
    definition_names,
    expand,
    load_definition,
    load_table,
    resolve,
    with_objects,
    write_report,
    write_table,
)

NAMES = ["hrt", "objects", "ig_vs_du", "samples", "motion_noise", "clutter", "ort_size", "ort_vs_rs", "metrics",
         "prediction", "clutter_objects", "clutter_oracle"]

#: a definition small enough to run in seconds: the default scene, 2 scans, few candidates
TINY = """\
name: tiny
title: two short default runs
scenario: default
set: [mission.max_scans=2, planner.n_candidates=600, planner.ray_stride=4, scene.gt_points=3000]
factors:
  - name: h
    levels:
      - {label: "0.3", set: [planner.overlap_h=0.3]}
seeds: [1, 2]
series:
  - {name: coverage, field: coverage, scale: 100}
metrics:
  - {name: coverage, key: coverage, scale: 100, unit: "%"}
"""


def _cli(*args, timeout=900):
    return subprocess.run([sys.executable, "-m", "nbvs_drake.app.cli", "experiment", *args], capture_output=True,
                          text=True, timeout=timeout)


def test_every_experiment_is_listed_with_paper_runs_and_cost(capsys):
    assert main(["experiment", "--list"]) == 0
    out = capsys.readouterr().out
    assert set(NAMES) <= set(definition_names())
    for name in NAMES:
        assert f"\n{name} " in "\n" + out, name
    assert out.count("full:") >= len(NAMES) and out.count("quick:") >= len(NAMES)
    assert "Santos et al. (2020)" in out and "Object Reconstruction Tree" in out and "Table 5" in out
    assert "measured on" in out


@pytest.mark.parametrize("name", NAMES)
def test_definition_expands_to_its_runs(name):
    """Every built-in definition loads, its quick version is smaller, the published values
    name existing factors and levels, and each run's overrides are valid scenario settings."""
    d = load_definition(name)
    full, quick = expand(resolve(d)), expand(resolve(d, quick=True))
    assert 0 < len(quick) < len(full) or (len(quick) == len(full) == 1)
    assert len(quick) <= 12
    assert len({r.run_id for r in full}) == len(full)
    factors = {f["name"]: {str(lv["label"]) for lv in f["levels"]} for f in d.get("factors") or []}
    for pc in (d.get("published") or {}).get("cells") or []:
        assert set(pc["levels"]) <= set(factors), pc
    assert d.get("paper") and d.get("reference")
    assert (d.get("cost") or {}).get("quick_run_s"), "measured cost per quick run"
    for r in {(x.scenario, tuple(x.overrides)): x for x in full + quick}.values():  # validated like `--set`
        load_scenario(r.scenario, seed=r.seed, settings=r.overrides)


def test_full_sizes_follow_the_papers():
    size = {n: len(expand(resolve(load_definition(n)))) for n in NAMES}
    # Table 5: three objects, three approaches, ten runs; with the paper's settings and this
    # project's planner (nbvs, nbvs_refine, nbvs_fine, nbvs_sight, nbvs_face, nbvs_fast), and
    # two on nbvs_fast (nbvs_tol25, nbvs_replan) under EU-MU only; the noise-free DU cells of
    # four rungs skipped
    assert size["motion_noise"] == 3 * 3 * 10 * 7 - 3 * 10 * 4 + 2 * 3 * 10
    assert size["ig_vs_du"] == 2 * 5  # Figs. 9-10: five runs each
    # Table 6: five repetitions with the paper's settings and either motion planner; ten with this project's
    # (nbvs, nbvs_refine, nbvs_fine, nbvs_reach, nbvs_clear, nbvs_sight, nbvs_face, nbvs_fast), and
    # fourteen trials on nbvs_fast (nbvs_tol25, nbvs_k50, nbvs_arcs, nbvs_free, nbvs_free_k1000,
    # nbvs_free_arm3, nbvs_margin, nbvs_free_margin, nbvs_nodist, nbvs_free_margin_tol25,
    # nbvs_free_margin_1cm, nbvs_free_margin_arm3, nbvs_free_margin_replan,
    # nbvs_free_margin_replan_facing) with EU only
    assert size["clutter"] == 2 * 2 * 5 + 2 * 10 * 8 + 14 * 10
    assert size["ort_vs_rs"] == 2 * 10 and size["metrics"] == 4 * 10 and size["ort_size"] == 5 * 10
    # issue 50: seven test objects among the chairs, two maps and the facing matches, 3 seeds
    assert size["clutter_objects"] == 7 * 3 * 3
    # open and chairs, four planners, five seeds (the bunny); the test objects among the chairs, six planners,
    # three seeds, and the cup's oracle in the open
    assert size["clutter_oracle"] == 2 * 4 * 5 + 7 * 6 * 3 + 3
    assert size["hrt"] % 4 == 0  # a = 0..3


def test_object_option_adds_a_mesh_level(tmp_path):
    mesh = tmp_path / "box.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    d = with_objects(load_definition("objects"), [f"box={mesh}"])
    runs = [r for r in expand(resolve(d, quick=True)) if r.levels["object"] == "box"]
    assert runs and any(str(mesh) in o for o in runs[0].overrides)
    with pytest.raises(Exception, match="no object factor"):
        with_objects(load_definition("ort_vs_rs"), [f"box={mesh}"])


def _fake_run(d: Path, seed, coverage, unknown, un_o=None, collisions=0, trajectories=None):
    """A finished run folder with the files the table reads."""
    d.mkdir(parents=True)
    n = len(coverage)
    recs = []
    for k in range(n):
        plan = {"status": "ok", "factors": {"un_o": (un_o or [0] * n)[k], "rho": 1.0 + k}, "plan_s": 1.0} \
            if k < n - 1 else {"status": "stop"}
        recs.append({"iteration": k + 1, "coverage": coverage[k], "remaining_unknown_m3": unknown[k], "plan": plan})
    (d / "iterations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    ex = trajectories if trajectories is not None else n - 1
    (d / "summary.json").write_text(json.dumps({
        "seed": seed, "coverage": coverage[-1], "coverage_by_scan": coverage, "scans": n, "collisions": collisions,
        "executed_trajectories": ex, "collision_rate": collisions / ex if ex else 0, "distance": 2.0 * n,
        "stop_reason": "collision" if collisions else "max_scans", "times_s": {"plan": 1.0 * (n - 1)}, "wall_s": 9.0}))
    (d / "scenario.yaml").write_text("mapper:\n  voxel_size: 0.02\n")


def test_table_from_finished_runs_marks_the_missing_and_keeps_timings_apart(tmp_path):
    """Per cell: metrics over the seeds, a ratio pooled over the runs, the coverage per scan
    with a run that stopped early counting with its last coverage (as mission_table did), a
    missing and a failed run marked; the prediction pairs (un_o x voxel volume against the
    drop of the unknown volume, the first plan left out) and their R²; wall-clock times only
    in the timings section."""
    y = tmp_path / "d.yaml"
    y.write_text(TINY.replace("seeds: [1, 2]", "seeds: [1, 2, 3, 4]") + """\
  - {name: collision_rate, ratio: [collisions, executed_trajectories], scale: 100}
  - {name: collided, key: collided, stats: [nonzero]}
timings:
  - {name: plan_time, key: plan_s_per_iteration, unit: s}
analysis: {kind: prediction, skip_first: 1}
published:
  cells:
    - {levels: {h: "0.3"}, coverage: 90.0}
figures:
  - {file: cov.png, kind: series, series: coverage}
  - {file: pred.png, kind: scatter}
""")
    r = resolve(load_definition(y))
    runs = tmp_path / "e" / "runs"
    v = 0.02 ** 3
    _fake_run(runs / "0.3_s1", 1, [0.3, 0.5, 0.7], [0.30, 0.20, 0.15], un_o=[100, 0.06 / v, 0])
    _fake_run(runs / "0.3_s2", 2, [0.3, 0.4], [0.30, 0.25], collisions=1, trajectories=2)  # stopped early
    (runs / "0.3_s4.failed.json").write_text("{}")
    t = write_table(r, tmp_path / "e", {"command": "test"})
    c = t["cells"][0]
    assert c["finished"] == 2 and c["expected"] == 4 and c["missing_seeds"] == [3, 4] and c["failed_seeds"] == [4]
    assert c["metrics"]["coverage"]["mean"] == pytest.approx(55.0)
    assert c["metrics"]["coverage"]["values"] == {"1": pytest.approx(70.0), "2": pytest.approx(40.0)}
    assert c["metrics"]["collision_rate"]["pooled"] == pytest.approx(100 * 1 / 4)
    assert c["metrics"]["collided"]["nonzero"] == 1
    assert c["series"]["coverage"]["mean"] == pytest.approx([30.0, 45.0, 55.0])  # seed 2 carried at 40
    # only seed 1's second plan is a pair: predicted 0.06 m³, revealed 0.20 - 0.15
    assert c["prediction"]["pairs"] == [[pytest.approx(0.06), pytest.approx(0.05)]]
    assert t["timings"]["cells"][0]["metrics"]["plan_time"]["mean"] == pytest.approx(1.0)
    assert "timings" not in comparable(t) and "stamp" not in comparable(t)
    md = (tmp_path / "e" / "table.md").read_text()
    assert "| 0.3 | 2/4 | 55 ± 21.213 | 90 |" in md
    assert "Missing runs" in md and "0.3 seed 4 (failed)" in md
    assert "plan time" not in compared_markdown(md) and "plan_time" not in compared_markdown(md)
    assert (tmp_path / "e" / "cov.png").stat().st_size > 5000 and (tmp_path / "e" / "pred.png").is_file()
    lt = load_table(tmp_path / "e")
    assert lt.cell("0.3")["finished"] == 2 and lt.markdown == md and len(lt.runs()["0.3"]) == 2
    # the report copies the figures beside itself and links them there
    dest = tmp_path / "docs" / "results.md"
    write_report(tmp_path, dest)
    assert "](figures/experiments/e/cov.png)" in dest.read_text()
    copied = dest.parent / "figures" / "experiments" / "e" / "cov.png"
    assert copied.read_bytes() == (tmp_path / "e" / "cov.png").read_bytes()
    # a results file with the markers: its hand-written text stays, an experiment whose table
    # is not in the output folder keeps its section, one that is there replaces its old section
    hand = dest.parent / "hand.md"
    hand.write_text("# Results\n\nby hand\n\n<!-- nbvs experiment report: begin -->\n"
                    "## e: stale\n\nold numbers\n\n## gone: from another machine\n\n| kept |\n"
                    "### Timings\n\nslow\n<!-- nbvs experiment report: end -->\n\ntail by hand\n")
    write_report(tmp_path, hand)
    text = hand.read_text()
    assert text.startswith("# Results\n\nby hand\n") and text.rstrip().endswith("tail by hand")
    assert "old numbers" not in text and "| 0.3 | 2/4 | 55 ± 21.213 | 90 |" in text
    assert "## gone: from another machine\n\n| kept |\n### Timings\n\nslow" in text
    assert text.count("## e:") == 1 and text.index("## e:") < text.index("## gone:")


def _snapshot(runs: Path) -> dict:
    """Finished run folders (not the temporary ones): summary.json's inode and mtime."""
    return {p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in runs.glob("*/summary.json")
            if ".partial-" not in p.parent.name}


def test_local_and_ray_executors_give_the_same_tables(tmp_path):
    """The quick versions of motion_noise and ort_vs_rs, once in local processes and once as
    tasks on a local Ray cluster: identical tables (the compared part: all but wall-clock
    times and provenance), figures, every run's folder; then the report."""
    pytest.importorskip("ray")
    t0 = time.perf_counter()
    local = _cli("motion_noise", "ort_vs_rs", "--quick", "--jobs", "2", "--out", str(tmp_path / "local"))
    t_local = time.perf_counter() - t0
    assert local.returncode == 0, local.stdout + local.stderr
    t0 = time.perf_counter()
    ray = _cli("motion_noise", "ort_vs_rs", "--quick", "--jobs", "2", "--executor", "ray", "--out",
               str(tmp_path / "ray"))
    t_ray = time.perf_counter() - t0
    assert ray.returncode == 0, ray.stdout + ray.stderr
    print(f"local {t_local:.0f} s, ray {t_ray:.0f} s")
    for name, n_runs in (("motion_noise_quick", 6), ("ort_vs_rs_quick", 4)):
        a, b = load_table(tmp_path / "local" / name), load_table(tmp_path / "ray" / name)
        assert a["runs_finished"] == b["runs_finished"] == a["runs_expected"] == n_runs
        assert comparable(a) == comparable(b)
        assert compared_markdown(a.markdown) == compared_markdown(b.markdown)
        assert a["stamp"]["executor"].startswith("local") and b["stamp"]["executor"].startswith("ray")
        assert a["stamp"]["command"].startswith("nbvs experiment motion_noise ort_vs_rs --quick")
        assert a["stamp"]["git_commit"] and a["stamp"]["date"]
        for f in a["figures"]:
            assert (tmp_path / "ray" / name / f).stat().st_size > 5000
        for rid in a.cells[0]["runs"]:
            for f in ("summary.json", "iterations.jsonl", "model.ply", "map.npz", "scenario.yaml", "replay.html",
                      "run.json"):
                assert (tmp_path / "ray" / name / "runs" / rid / f).is_file(), (rid, f)
            assert (tmp_path / "ray" / name / "logs" / f"{rid}.log").read_text().count("scan ") >= 1
        assert "coverage" in local.stdout and "run" in local.stderr  # per-run lines, the progress bar
    mn = load_table(tmp_path / "local" / "motion_noise_quick")
    assert {c["label"] for c in mn.cells} == {f"teapot/{a}/{p}" for a in ("DU", "DU-MU", "EU-MU")
                                              for p in ("paper", "nbvs")}
    assert all(c["metrics"]["coverage"]["mean"] > 20 for c in mn.cells)
    dest = tmp_path / "docs" / "results.md"
    assert main(["experiment", "report", "--out", str(tmp_path / "local"), "--to", str(dest)]) == 0
    text = dest.read_text()
    assert text.index("## motion_noise") < text.index("## ort_vs_rs")
    assert "Produced by* `nbvs experiment motion_noise ort_vs_rs --quick" in text and "at commit" in text
    # the figures are copied beside the report and linked there, not into the output folder
    assert "](figures/experiments/motion_noise_quick/coverage_per_scan.png)" in text
    fig = tmp_path / "docs" / "figures" / "experiments" / "motion_noise_quick" / "coverage_per_scan.png"
    assert fig.read_bytes() == (tmp_path / "local" / "motion_noise_quick" / "coverage_per_scan.png").read_bytes()


def test_a_killed_batch_keeps_its_finished_runs_and_redoes_only_the_unfinished(tmp_path):
    """SIGKILL of the batch's whole process group while its second run is under way (the first
    finished): the rerun skips the finished run (same summary.json inode and mtime, 'skipped'
    in runner.log), removes the half-written folder, redoes the second run and completes the
    table."""
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY)
    out = tmp_path / "x"
    runs = out / "tiny" / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "nbvs_drake.app.cli", "experiment", str(y), "--jobs", "1",
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    deadline = time.time() + 300
    try:
        while time.time() < deadline:
            partial = list(runs.glob("*.partial-*")) if runs.exists() else []
            if _snapshot(runs) and partial and list(partial[0].glob("iterations.jsonl")):
                break
            assert proc.poll() is None, "the batch ended before it could be killed"
            time.sleep(0.2)
        else:
            raise AssertionError("no finished run and a second one under way within 300 s")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    before = _snapshot(runs)
    assert list(before) == ["0.3_s1"]
    assert list(runs.glob("*.partial-*"))  # the second run was killed half-way
    assert not (out / "tiny" / "table.md").exists()
    again = _cli(str(y), "--jobs", "1", "--out", str(out))
    assert again.returncode == 0, again.stdout + again.stderr
    after = _snapshot(runs)
    assert after["0.3_s1"] == before["0.3_s1"]  # not redone
    assert set(after) == {"0.3_s1", "0.3_s2"} and not list(runs.glob("*.partial-*"))
    log = (out / "tiny" / "runner.log").read_text()
    assert "skipped 0.3_s1 (finished)" in log and "cleaned 0.3_s2.partial-" in log
    assert log.count("start 0.3_s1") == 1 and log.count("start 0.3_s2") == 2
    t = load_table(out / "tiny")
    assert t["runs_finished"] == t["runs_expected"] == 2 and not t.cells[0]["missing_seeds"]
    assert "1 now, 1 skipped" in again.stdout


def test_a_failed_run_is_recorded_does_not_stop_the_batch_and_is_retried(tmp_path):
    y = tmp_path / "f.yaml"
    y.write_text(TINY.replace('      - {label: "0.3", set: [planner.overlap_h=0.3]}',
                              '      - {label: bad, set: [planner.overlap_h=7]}').replace("[1, 2]", "[1]"))
    out = tmp_path / "o"
    first = _cli(str(y), "--jobs", "1", "--out", str(out))
    assert first.returncode == 1 and "FAILED" in first.stdout and "retry-failed" in first.stderr
    rec = json.loads((out / "tiny" / "runs" / "bad_s1.failed.json").read_text())
    assert "overlap_h" in rec["error"] and Path(rec["log"]).read_text().count("ScenarioError") >= 1
    t = load_table(out / "tiny")
    assert t["runs_finished"] == 0 and t.cells[0]["failed_seeds"] == [1]
    second = _cli(str(y), "--jobs", "1", "--out", str(out))  # not retried without the flag
    assert "skipped bad_s1 (failed before" in (out / "tiny" / "runner.log").read_text()
    assert second.returncode == 1 and "0 to run" in second.stdout
    third = _cli(str(y), "--jobs", "1", "--out", str(out), "--retry-failed")
    assert third.returncode == 1 and "1 to run" in third.stdout
    assert (out / "tiny" / "runner.log").read_text().count("FAILED bad_s1") == 2


def test_definitions_ship_as_package_data():
    """pyproject.toml's package-data takes every definition file into a wheel."""
    import fnmatch
    import tomllib

    from nbvs_drake.experiments import DEFINITIONS_DIR
    root = Path(__file__).resolve().parents[1]
    globs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"][
        "nbvs_drake.experiments"]
    files = [p.relative_to(DEFINITIONS_DIR.parent).as_posix() for p in DEFINITIONS_DIR.glob("*")]
    assert files and all(any(fnmatch.fnmatch(f, g) for g in globs) for f in files)


def test_a_run_whose_worker_dies_fails_alone(tmp_path):
    """A worker process killed in the middle of its run (as a crash in native code would end
    it): that run is recorded as failed, a new worker takes the remaining runs, and
    `--retry-failed` completes the table."""
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY)
    out = tmp_path / "w"
    log = out / "tiny" / "runner.log"
    proc = subprocess.Popen([sys.executable, "-m", "nbvs_drake.app.cli", "experiment", str(y), "--jobs", "1",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not (log.exists() and "start 0.3_s1 (worker pid" in log.read_text()):
        time.sleep(0.1)
    pid = int(log.read_text().split("start 0.3_s1 (worker pid ")[1].split(")")[0])
    os.kill(pid, signal.SIGKILL)
    stdout, _ = proc.communicate(timeout=600)
    assert proc.returncode == 1, stdout
    rec = json.loads((out / "tiny" / "runs" / "0.3_s1.failed.json").read_text())
    assert "worker process died" in rec["error"] and rec["exitcode"] == -signal.SIGKILL
    t = load_table(out / "tiny")
    assert t["runs_finished"] == 1 and t.cells[0]["failed_seeds"] == [1]
    again = _cli(str(y), "--jobs", "1", "--out", str(out), "--retry-failed")
    assert again.returncode == 0, again.stdout + again.stderr
    assert load_table(out / "tiny")["runs_finished"] == 2
    assert not (out / "tiny" / "runs" / "0.3_s1.failed.json").exists()


def test_tables_say_at_which_commits_their_runs_were_made(tmp_path):
    import json

    from nbvs_drake.experiments.aggregate import run_commits
    for i, c in enumerate(["a" * 40, "a" * 40, "b" * 40 + "+dirty", None]):
        d = tmp_path / "runs" / f"r{i}"
        d.mkdir(parents=True)
        (d / "run.json").write_text(json.dumps({"run_id": f"r{i}"} | ({"git_commit": c} if c else {})))
    assert run_commits(tmp_path) == "aaaaaaa x2, bbbbbbb+dirty x1, unrecorded x1"


def test_table_only_writes_the_table_of_the_finished_runs_and_runs_nothing(tmp_path):
    import json

    from nbvs_drake.app.cli import main
    assert main(["experiment", "motion_noise", "--quick", "--table-only", "--out", str(tmp_path)]) == 0
    d = tmp_path / "motion_noise_quick"
    t = json.loads((d / "table.json").read_text())
    assert t["runs_finished"] == 0 and t["runs_expected"] == 2 * 3  # the quick teapot: 2 seeds x 3 approaches
    assert not [p for p in (d / "runs").iterdir() if p.is_dir()]


def test_a_finished_run_whose_scenario_changed_since_is_not_taken_as_finished(tmp_path):
    """A finished run keeps its overrides when diagrams/*.yaml or the defaults change: the
    batch compares its scenario.yaml with what the settings resolve to now, and stops with
    a one-line error naming the fields (a stale run would otherwise enter the table)."""
    from pydrake.common.yaml import yaml_dump_typed

    from nbvs_drake.experiments.runner import scenario_drift
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY.replace("[1, 2]", "[1]"))
    spec = expand(resolve(load_definition(str(y))))[0]
    run = tmp_path / "o" / "tiny" / "runs" / spec.run_id
    run.mkdir(parents=True)
    sc = load_scenario(spec.scenario, seed=spec.seed, settings=spec.overrides)
    (run / "scenario.yaml").write_text(yaml_dump_typed(sc))
    assert scenario_drift(spec, run) == []
    (run / "summary.json").write_text(json.dumps({"coverage": 0.5}))
    (run / "run.json").write_text(json.dumps(spec.to_json()))
    sc.planner.top_k = 7
    sc.mapper.prob_hit = 0.8
    (run / "scenario.yaml").write_text(yaml_dump_typed(sc))
    assert scenario_drift(spec, run) == ["mapper.prob_hit", "planner.top_k"]
    r = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "o"))
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "mapper.prob_hit, planner.top_k" in err[0] and "another --out" in err[0]
    assert (run / "summary.json").is_file()  # nothing removed


def test_a_record_whose_scenario_changed_since_is_refused(tmp_path):
    """A preset or scenario that takes a new value changes what the same overrides resolve to:
    the experiment's own record of the run, made before, is refused (one line naming it), not
    restored as the run asked for (a table rebuilt from it would show what today's code does
    not do)."""
    mine = tmp_path / "mine.yaml"
    mine.write_text("name: mine\nseed: 1\npreset: nbvs\n")
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY.replace("[1, 2]", "[1]").replace("scenario: default", f"scenario: {mine}"))
    rec_root = tmp_path / "records"
    first = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "a"), "--records", str(rec_root))
    assert first.returncode == 0, first.stdout + first.stderr
    same = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "b"), "--records", str(rec_root), "--table-only")
    assert same.returncode == 0 and "1 restored from" in same.stdout, same.stdout + same.stderr
    mine.write_text("name: mine\nseed: 1\npreset: nbvs\nplanner: {top_k: 30}\n")  # the scenario changed
    again = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "c"), "--records", str(rec_root), "--table-only")
    assert again.returncode != 0 and len(again.stderr.strip().splitlines()) == 1, again.stdout + again.stderr
    assert "now resolves to" in again.stderr and "0.3_s1.json.gz" in again.stderr


def test_run_records_continue_a_study_in_another_output_folder(tmp_path):
    """--records: each finished run is recorded (a small gzipped file without the paths); a
    batch with the same records and an empty output folder restores the run instead of
    redoing it and gives the same table; a record made with other settings is refused."""
    import gzip

    from nbvs_drake.experiments.records import read_record
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY.replace("[1, 2]", "[1]"))
    rec_root = tmp_path / "records"
    first = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "a"), "--records", str(rec_root))
    assert first.returncode == 0, first.stdout + first.stderr
    f = rec_root / "tiny" / "0.3_s1.json.gz"
    raw = gzip.decompress(f.read_bytes()).decode()
    assert len(f.read_bytes()) < 20000 and "executed_path" not in raw and '"candidates"' not in raw
    rec = read_record(f)
    assert rec["summary"]["coverage"] > 0 and len(rec["iterations"]) == 2 and rec["run"]["seed"] == 1
    second = _cli(str(y), "--jobs", "1", "--out", str(tmp_path / "b"), "--records", str(rec_root))
    assert second.returncode == 0, second.stdout + second.stderr
    assert "1 restored from" in second.stdout and "0 to run" in second.stdout
    assert "restored 0.3_s1 from" in (tmp_path / "b" / "tiny" / "runner.log").read_text()
    a, b = load_table(tmp_path / "a" / "tiny"), load_table(tmp_path / "b" / "tiny")
    assert comparable(a) == comparable(b) and compared_markdown(a.markdown) == compared_markdown(b.markdown)
    # a record whose settings differ from the definition's
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.replace("[1, 2]", "[1]").replace("overlap_h=0.3", "overlap_h=0.35"))
    third = _cli(str(bad), "--jobs", "1", "--out", str(tmp_path / "c"), "--records", str(rec_root))
    assert third.returncode != 0 and len(third.stderr.strip().splitlines()) == 1
    assert "other settings" in third.stderr and "0.3_s1.json.gz" in third.stderr
    # the same run asked for by another experiment (its own name and label, the settings in
    # another order): restored from tiny's record, and recorded as its own
    other = tmp_path / "other.yaml"
    other.write_text(TINY.replace("name: tiny", "name: other").replace("[1, 2]", "[1]")
                     .replace("set: [mission.max_scans=2, planner.n_candidates=600,",
                              "set: [planner.overlap_h=0.3, planner.n_candidates=600, mission.max_scans=2,")
                     .replace('{label: "0.3", set: [planner.overlap_h=0.3]}', '{label: same, set: []}'))
    fourth = _cli(str(other), "--jobs", "1", "--out", str(tmp_path / "d"), "--records", str(rec_root))
    assert fourth.returncode == 0, fourth.stdout + fourth.stderr
    assert "1 restored from" in fourth.stdout and "0 to run" in fourth.stdout
    run = json.loads((tmp_path / "d" / "other" / "runs" / "same_s1" / "run.json").read_text())
    assert run["shared_from"] == "tiny/0.3_s1.json.gz" and run["run_id"] == "same_s1"
    # the definition now pins a field at the value its scenario gives it anyway (other overrides,
    # the same settings): its own record is restored and recorded again with the new overrides
    pinned = tmp_path / "pinned.yaml"
    pinned.write_text(TINY.replace("[1, 2]", "[1]").replace("scene.gt_points=3000]",
                                                           "scene.gt_points=3000, planner.motion_planner=roadmap]"))
    fifth = _cli(str(pinned), "--jobs", "1", "--out", str(tmp_path / "e"), "--records", str(rec_root))
    assert fifth.returncode == 0, fifth.stdout + fifth.stderr
    assert "1 restored from" in fifth.stdout and "0 to run" in fifth.stdout
    assert "planner.motion_planner=roadmap" in read_record(f)["run"]["overrides"]
    assert read_record(rec_root / "other" / "same_s1.json.gz")["summary"] == rec["summary"]
    # a different run (another seed) is not taken for it
    fifth = _cli(str(other), "--seeds", "2", "--jobs", "1", "--out", str(tmp_path / "d"), "--records", str(rec_root),
                 "--table-only")
    assert fifth.returncode == 0 and "restored" not in fifth.stdout, fifth.stdout + fifth.stderr


def test_a_level_may_run_its_own_seeds():
    d = load_definition("clutter")
    runs = expand(resolve(d))
    seeds = {}
    for r in runs:
        seeds.setdefault(r.levels["planner"], set()).add(r.seed)
    assert seeds["RRT Ext-Ext"] == seeds["roadmap"] == set(range(1, 6))
    assert seeds["nbvs"] == set(range(1, 11))
    # the quick section's seeds (and the caller's) serve every level
    assert {r.seed for r in expand(resolve(d, quick=True))} == set(d["quick"]["seeds"])
    assert {r.seed for r in expand(resolve(d, seeds=[7]))} == {7}


def test_the_local_ray_cluster_refuses_a_client_without_its_token(tmp_path):
    """Ray 2.60 binds its local cluster's GCS server and raylet to every interface, so the
    cluster a batch starts for itself runs with token authentication: a client that does not
    hold the token is refused. And --address with nothing behind it ends in one line, fast."""
    pytest.importorskip("ray")
    from nbvs_drake.experiments.runner import make_executor
    t0 = time.perf_counter()
    with pytest.raises(ExperimentError, match="no Ray cluster answers at 127.0.0.1:1"):
        make_executor("ray", 1, "127.0.0.1:1")._init()
    assert time.perf_counter() - t0 < 30
    ex = make_executor("ray", 1)
    old = os.environ.get("RAY_AUTH_MODE")
    try:
        ray = ex._init()
        assert os.environ["RAY_AUTH_MODE"] == "token"
        gcs = ray.get_runtime_context().gcs_address
        code = ("import ray, sys\n"
                "try:\n    ray.init(address=sys.argv[1], log_to_driver=False)\n"
                "except Exception as e:\n    print('REFUSED', type(e).__name__); sys.exit(3)\n"
                "print('CONNECTED')\n")
        env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN="not-the-token", RAY_USAGE_STATS_ENABLED="0")
        p = subprocess.run([sys.executable, "-c", code, gcs], env=env, capture_output=True, text=True, timeout=120)
        assert p.returncode == 3 and "REFUSED" in p.stdout, p.stdout + p.stderr
        # the runner pointed at it with the wrong token: one line naming the address, no traceback
        p = subprocess.run([sys.executable, "-m", "nbvs_drake.app.cli", "experiment", "objects", "--quick",
                            "--executor", "ray", "--address", gcs, "--out", str(tmp_path / "x")], env=env,
                           capture_output=True, text=True, timeout=180)
        lines = [ln for ln in p.stderr.splitlines() if ln.startswith("nbvs:")]
        assert p.returncode == 2 and len(lines) == 1, p.stderr[-2000:]
        assert f"the Ray cluster at {gcs}" in lines[0] and "token" in lines[0], lines[0]
        assert "Traceback" not in p.stderr and "InvalidAuthToken" not in p.stderr
    finally:
        ex.close()
        if old is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = old


def test_ctrl_c_stops_a_batch_and_says_where_the_finished_runs_are(tmp_path):
    """SIGINT to the batch's process group (Ctrl-C in a terminal) while its second run is under
    way: one line naming the folder with the finished run, no traceback, exit code 130; the
    finished run stays."""
    y = tmp_path / "tiny.yaml"
    y.write_text(TINY)
    out = tmp_path / "x"
    runs = out / "tiny" / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "nbvs_drake.app.cli", "experiment", str(y), "--jobs", "1",
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=ctrl_c_as_in_a_terminal)
    deadline = time.time() + 300
    while time.time() < deadline:
        partial = list(runs.glob("*.partial-*")) if runs.exists() else []
        if _snapshot(runs) and partial:
            break
        assert proc.poll() is None, "the batch ended before it could be interrupted"
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = [ln for ln in err.splitlines() if ln.startswith("nbvs:")]
    assert lines == [f"nbvs: interrupted: 1 of 2 runs of tiny are finished in {runs}; the same command goes on "
                     "from there (`--table-only` writes their table)"], err
    assert "Traceback" not in err
    assert list(_snapshot(runs)) == ["0.3_s1"]


@pytest.mark.parametrize("experiment, scenario, levels, extra", [
    ("motion_noise", "teapot_eu_mu_nbvs", {"object": "teapot", "approach": "EU-MU", "planner": "nbvs_replan"}, []),
    ("clutter", "cluttered_room_nbvs", {"utility": "EU", "planner": "nbvs_free_margin_replan"},
     ["scene.object.kind=bunny", "scene.object.size=-1"]),
])
def test_the_builtin_nbvs_scenarios_are_the_experiments_levels(experiment, scenario, levels, extra):
    """`nbvs reconstruct --scenario teapot_eu_mu_nbvs` (or cluttered_room_nbvs) runs this
    project's planner under noise with the settings the experiments measured: the resolved
    scenario equals the level's run of the same seed, field by field."""
    run = next(r for r in expand(resolve(load_definition(experiment)))
               if r.seed == 3 and all(r.levels[k] == v for k, v in levels.items()))
    measured = load_scenario(run.scenario, seed=run.seed, settings=run.overrides)
    builtin = load_scenario(scenario, seed=3, settings=extra)
    measured.name, measured.preset = builtin.name, builtin.preset
    assert measured == builtin
    vv = builtin.localisation.verified_views
    assert vv is not None and vv.landmarks.occlusion and vv.landmarks.facing
    assert builtin.localisation.search is not None


def test_a_series_figure_draws_only_the_levels_it_names(tmp_path, monkeypatch):
    """A `series` figure with `levels` draws only the cells at those levels (clutter draws its
    rungs and presets, not every trial)."""
    from nbvs_drake.experiments import figures

    def cell(planner, v):
        return {"levels": {"utility": "EU", "planner": planner},
                "series": {"coverage": {"mean": [v, v + 10], "std": [1.0, 1.0], "n": [2, 2]}}}
    table = {"cells": [cell("nbvs", 30.0), cell("trial", 40.0), cell("preset", 50.0)]}
    drawn = []
    real = figures.plt.Axes.legend

    def legend(ax, *a, **kw):
        drawn.append([t for t in ax.get_legend_handles_labels()[1]])
        return real(ax, *a, **kw)
    monkeypatch.setattr(figures.plt.Axes, "legend", legend)
    spec = {"file": "c.png", "kind": "series", "series": "coverage", "panels": "utility",
            "levels": {"planner": ["nbvs", "preset"]}}
    figures.draw_series({"series": [{"name": "coverage", "unit": "%"}]}, table, spec, tmp_path / "c.png")
    assert drawn == [["nbvs (2 runs)", "preset (2 runs)"]] and (tmp_path / "c.png").stat().st_size > 0
    drawn.clear()
    figures.draw_series({}, table, {**spec, "levels": None}, tmp_path / "d.png")
    assert drawn == [["nbvs (2 runs)", "trial (2 runs)", "preset (2 runs)"]]
