"""A reconstruction killed mid-way keeps every finished iteration in iterations.jsonl, leaves no
lock behind, and its iterations load back (`RunResult.load(partial=True)`); one run writes a
folder at a time."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import ctrl_c_as_in_a_terminal


def test_killed_run_keeps_every_finished_iteration(tmp_path):
    y = tmp_path / "s.yaml"
    y.write_text("name: killed\nscene: {gt_points: 5000}\nplanner: {n_candidates: 500}\nmission: {max_scans: 12}\n")
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "nbvs_drake.app.cli", "reconstruct", "--scenario", str(y),
                             "--out", str(out), "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log = out / "iterations.jsonl"
    deadline = time.time() + 300
    try:
        while time.time() < deadline:
            if log.exists() and log.read_text().count("\n") >= 2:
                break
            assert proc.poll() is None, "the run ended before it could be killed"
            time.sleep(0.2)
        else:
            raise AssertionError("no two iterations within 300 s")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    text = log.read_text()
    assert text.endswith("\n")  # no half-written line
    recs = [json.loads(line) for line in text.splitlines()]
    assert len(recs) >= 2
    assert [r["iteration"] for r in recs] == list(range(1, len(recs) + 1))
    for r in recs:
        assert 0 < r["coverage"] <= 1 and r["true_state"] and r["plan"]
    assert not (out / "summary.json").exists()  # the run never finished
    # the kernel dropped the killed run's lock: the next writer takes it
    from nbvs_drake.errors import RunExistsError
    from nbvs_drake.files import FolderLock
    FolderLock(out, RunExistsError, "another run").release()
    # the API reads what was kept: refused as a finished run, read as a partial one
    from nbvs_drake import RunResult
    from nbvs_drake.errors import NbvsError
    with pytest.raises(NbvsError, match="no finished run"):
        RunResult.load(out)
    part = RunResult.load(out, partial=True)
    assert part.summary["partial"] and part.summary["scans"] == len(recs) == len(part.records)
    assert part.summary["coverage"] == recs[-1]["coverage"] and ".lock" not in [p.name for p in part.paths.values()]
    with log.open("a") as f:  # a kill mid-write leaves a cut last line: skipped, with a warning
        f.write(text.splitlines()[0][:100])
    with pytest.warns(UserWarning, match="last line is cut"):
        cut = RunResult.load(out, partial=True)
    assert [r["iteration"] for r in cut.records] == [r["iteration"] for r in recs]


def test_two_runs_into_one_folder_one_writes_and_the_other_ends_at_once(tmp_path):
    """Two runs started together into one folder: one holds the folder's lock and finishes,
    the other ends at once with one line naming the folder (--overwrite does not break the
    lock), and the folder holds one run."""
    y = tmp_path / "s.yaml"
    y.write_text("name: twice\nscene: {gt_points: 3000}\nplanner: {n_candidates: 300}\nmission: {max_scans: 3}\n")
    out = tmp_path / "same"
    cmd = [sys.executable, "-m", "nbvs_drake.app.cli", "reconstruct", "--scenario", str(y), "--out", str(out)]
    procs = [subprocess.Popen(cmd + extra, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for extra in ([], ["--overwrite"])]
    ends, errs = [], []
    for p in procs:
        errs.append(p.communicate(timeout=600)[1])
        ends.append((p.returncode, time.time()))
    won = [i for i in (0, 1) if ends[i][0] == 0]
    assert len(won) == 1, errs
    lost = 1 - won[0]
    lines = [ln for ln in errs[lost].splitlines() if ln.startswith("nbvs:")]
    # (the holder's pid when it had written it: the two start within the same instant)
    assert len(lines) == 1 and f"{out} is in use by another run" in lines[0], errs[lost]
    assert "Traceback" not in errs[lost]
    recs = [json.loads(line) for line in (out / "iterations.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in recs] == list(range(1, len(recs) + 1))
    assert json.loads((out / "summary.json").read_text())["scans"] == len(recs) == 3


def test_ctrl_c_says_where_the_finished_iterations_are(tmp_path):
    """Ctrl-C (SIGINT) ends a run with one line naming the file that keeps what was finished."""
    y = tmp_path / "s.yaml"
    y.write_text("name: stopped\nscene: {gt_points: 5000}\nplanner: {n_candidates: 500}\nmission: {max_scans: 12}\n")
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "nbvs_drake.app.cli", "reconstruct", "--scenario", str(y),
                             "--out", str(out), "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, preexec_fn=ctrl_c_as_in_a_terminal)
    log = out / "iterations.jsonl"
    deadline = time.time() + 300
    while time.time() < deadline and not (log.exists() and log.read_text().count("\n") >= 1):
        assert proc.poll() is None, "the run ended before it could be interrupted"
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    # 130, or killed by SIGINT itself (-2): CPython re-raises the signal at exit when the
    # Ctrl-C landed in code a compiled module ran through PyRun_* (e.g. during Open3D's import)
    assert proc.returncode in (130, -signal.SIGINT), err
    lines = [ln for ln in err.splitlines() if ln.startswith("nbvs:")]
    assert lines == [f"nbvs: interrupted: the finished iterations are in {log} "
                     f"(the scenario in {out / 'scenario.yaml'}; no summary.json; "
                     f"RunResult.load(folder, partial=True) reads them)"], err
    assert "Traceback" not in err
    assert json.loads(log.read_text().splitlines()[0])["iteration"] == 1
