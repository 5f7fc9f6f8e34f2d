"""The Python entry point: :func:`reconstruct` runs one reconstruction mission, as
`nbvs reconstruct` does (the command calls it), and returns a :class:`RunResult`;
:meth:`RunResult.load` reads a finished run folder back (notebooks, experiment tables).

    import nbvs_drake
    r = nbvs_drake.reconstruct("teapot_eu_mu", out="results/eu", seed=3,
                               overrides=["mission.max_scans=4"])
    r.summary["coverage"], r.paths["replay_html"], len(r.records)
    r = nbvs_drake.RunResult.load("results/eu")
"""

from __future__ import annotations

import copy
import dataclasses as dc
import json
from pathlib import Path

from ..errors import NbvsError, RunExistsError

#: the files of a run folder: RunResult.paths key -> file name (`mission.run_mission` writes them)
OUTPUTS = {
    "scenario": "scenario.yaml",
    "summary": "summary.json",
    "iterations": "iterations.jsonl",
    "model": "model.ply",
    "mesh": "model_mesh.ply",
    "map_npz": "map.npz",
    "map_bt": "map.bt",
    "coverage_png": "coverage.png",
    "paths_png": "paths.png",
    "replay_html": "replay.html",
}


@dc.dataclass(frozen=True)
class RunResult:
    """A finished run.

    - `summary`: the content of summary.json (coverage, scans, collisions, stop_reason, ...).
    - `out`: the run folder.
    - `paths`: name -> path of each output that exists (keys from `OUTPUTS`: scenario,
      summary, iterations, model, mesh (model_mesh.ply), map_npz, map_bt, coverage_png, paths_png, replay_html; the
      last two are missing when writing them failed, see summary["visual_output_errors"]).
    - `records`: the iteration records of iterations.jsonl, one dict per scan.
    """
    summary: dict
    out: Path
    paths: dict
    records: list

    @classmethod
    def load(cls, out_dir: str | Path, partial: bool = False) -> "RunResult":
        """Reads the run folder `out_dir` back. Raises NbvsError when it holds no finished
        run (no summary.json), unless `partial`: then an unfinished run (killed, interrupted,
        or still running) gives its finished iterations, and a summary marked
        {"partial": True} that holds only what they give (scans, coverages, the last
        iteration's unknown voxels); a last line cut mid-write is skipped with a warning."""
        out = Path(out_dir)
        summary_file = out / OUTPUTS["summary"]
        paths = {k: out / name for k, name in OUTPUTS.items() if (out / name).is_file()}
        if not summary_file.is_file():
            if not partial:
                raise NbvsError(f"no finished run in {out} (no {OUTPUTS['summary']})")
            if "iterations" not in paths:
                raise NbvsError(f"no run in {out} (no {OUTPUTS['iterations']})")
            records = _read_iterations(paths["iterations"], tolerate_cut=True)
            return cls(summary=_partial_summary(records), out=out, paths=paths, records=records)
        summary = json.loads(summary_file.read_text())
        records = _read_iterations(paths["iterations"]) if "iterations" in paths else []
        return cls(summary=summary, out=out, paths=paths, records=records)


def _read_iterations(path: Path, tolerate_cut: bool = False) -> list[dict]:
    """The records of an iterations.jsonl; with `tolerate_cut`, a last line that does not parse
    (a kill mid-write) is skipped with a warning."""
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    records = []
    for i, line in enumerate(lines):
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            if not (tolerate_cut and i == len(lines) - 1):
                raise NbvsError(f"{path}: line {i + 1} is not a JSON record") from None
            import warnings
            warnings.warn(f"{path}: the last line is cut (a run stopped mid-write); skipped", stacklevel=3)
    return records


def _partial_summary(records: list[dict]) -> dict:
    """What an unfinished run's iterations give of its summary."""
    last = records[-1] if records else {}
    return {"partial": True, "scans": len(records),
            **{k: last[k] for k in ("coverage", "coverage_5mm", "coverage_voxel", "coverage_1cm", "unknown_voxels",
                                    "reachable_unknown_voxels", "remaining_unknown_m3") if k in last},
            "coverage_by_scan": [r["coverage"] for r in records if "coverage" in r]}


def _resolve_scenario(scenario, seed, overrides):
    from ..config import Scenario, apply_setting, load_scenario, validate
    if isinstance(scenario, Scenario):
        sc = copy.deepcopy(scenario)  # the caller's object is left as it was
        if seed is not None:
            sc.seed = int(seed)
        for setting in overrides:
            sc = apply_setting(sc, setting)
        return validate(sc)
    return load_scenario(scenario, seed=seed, settings=overrides)


def _claim_output(out: Path):
    """Creates the run folder and takes its lock (`files.FolderLock`): one run writes a folder
    at a time; a second run aimed at it ends at once with a RunExistsError naming it, whatever
    its `overwrite`. Returns the lock, held until released (the kernel drops it when the
    process dies)."""
    from ..files import FolderLock
    _make_folder(out)
    return FolderLock(out, RunExistsError, "another run")


def _make_folder(out: Path):
    if out.exists() and not out.is_dir():
        raise RunExistsError(f"output folder {out} is a file, not a folder; choose another --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunExistsError(f"cannot create the output folder {out}: {e.strerror}") from None


def _refuse_finished(out: Path, overwrite: bool):
    if (out / OUTPUTS["summary"]).exists() and not overwrite:
        raise RunExistsError(f"{out} holds a finished run ({OUTPUTS['summary']}); "
                             "pass --overwrite (overwrite=True) to replace it, or choose another output folder")


def _prepare_output(out: Path, overwrite: bool):
    """Refuses a folder holding a finished run unless `overwrite`; otherwise removes the
    outputs of an earlier run there (summary.json first, so that a run stopped halfway never
    leaves an old summary beside new records). Other files in the folder are left alone.
    `reconstruct` calls it holding the folder's lock (`_claim_output`)."""
    _make_folder(out)
    _refuse_finished(out, overwrite)
    for name in OUTPUTS.values():
        f = out / name
        if f.is_file() or f.is_symlink():
            f.unlink()


def reconstruct(scenario=None, out=None, seed=None, overrides=(), *, overwrite=False, verbose=False,
                meshcat=None) -> RunResult:
    """Runs one reconstruction mission and returns its :class:`RunResult`.

    - `scenario`: None (the default scenario), a YAML path, a built-in scenario's name
      (`"teapot_eu_mu"`; see `nbvs_drake.resources.builtin_scenarios()`), or a
      :class:`nbvs_drake.config.Scenario` (copied; not changed). Relative mesh paths in a
      scenario file resolve against the file's folder (a Scenario object: its `base_dir`).
    - `out`: the output folder; None: `results/<scenario name>` under the current directory.
    - `seed`: replaces the scenario's seed.
    - `overrides`: "section.field=value" strings, as `nbvs reconstruct --set` (the value is
      YAML; applied in order, checked by the same typed schema).
    - `overwrite`: a folder that holds a finished run (summary.json) is refused with a
      RunExistsError, leaving it untouched, unless this is True. A folder with an unfinished
      run (iterations.jsonl but no summary.json, e.g. a killed run) is written over without
      asking. Either way only the run's own files (`OUTPUTS`, and `scene/`) are replaced.
    - `verbose`: print one line per scan; `meshcat`: a pydrake Meshcat to show the run live.

    Bad input raises an NbvsError subclass (ScenarioError, MeshError, RunExistsError) with a
    one-line message; the mission's results are the same as `nbvs reconstruct` gives.
    """
    from ..stage_clock import SETUP, StageClock
    clock = StageClock()  # the run's wall_s starts here
    if isinstance(overrides, str):
        overrides = (overrides,)
    with clock.running():
        with clock.stage(SETUP, "scenario"):
            sc = _resolve_scenario(scenario, seed, tuple(overrides))
        out = Path(out) if out is not None else Path("results") / sc.name
        if out.is_dir():
            _refuse_finished(out, overwrite)  # before anything is written there, the lock included
        with _claim_output(out):
            with clock.stage(SETUP, "output_folder"):
                _prepare_output(out, overwrite)  # again, under the lock: another run may have finished
            with clock.stage(SETUP, "imports"):  # the mission's modules: Drake, Open3D, numba
                from ..errors import Interrupted, InterruptGuard
                from .mission import run_mission
            guard = InterruptGuard()
            try:
                with guard:
                    run_mission(sc, out, verbose=verbose, meshcat=meshcat, clock=clock)
            except BaseException as e:
                if not guard.was_interrupt(e):
                    raise
                raise Interrupted(f"interrupted: the finished iterations are in {out / 'iterations.jsonl'} "
                                  f"(the scenario in {out / 'scenario.yaml'}; no summary.json; "
                                  f"RunResult.load(folder, partial=True) reads them)") from None
    return RunResult.load(out)
