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
    def load(cls, out_dir: str | Path) -> "RunResult":
        """Reads the run folder `out_dir` back. Raises NbvsError when it holds no finished
        run (no summary.json)."""
        out = Path(out_dir)
        summary_file = out / OUTPUTS["summary"]
        if not summary_file.is_file():
            raise NbvsError(f"no finished run in {out} (no {OUTPUTS['summary']})")
        summary = json.loads(summary_file.read_text())
        paths = {k: out / name for k, name in OUTPUTS.items() if (out / name).is_file()}
        records = []
        if "iterations" in paths:
            records = [json.loads(line) for line in paths["iterations"].read_text().splitlines() if line.strip()]
        return cls(summary=summary, out=out, paths=paths, records=records)


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


def _prepare_output(out: Path, overwrite: bool):
    """Refuses a folder holding a finished run unless `overwrite`; otherwise removes the
    outputs of an earlier run there (summary.json first, so that a run stopped halfway never
    leaves an old summary beside new records). Other files in the folder are left alone."""
    if out.exists() and not out.is_dir():
        raise RunExistsError(f"output folder {out} is a file, not a folder; choose another --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunExistsError(f"cannot create the output folder {out}: {e.strerror}") from None
    if (out / OUTPUTS["summary"]).exists() and not overwrite:
        raise RunExistsError(f"{out} holds a finished run ({OUTPUTS['summary']}); "
                             "pass --overwrite (overwrite=True) to replace it, or choose another output folder")
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
    if isinstance(overrides, str):
        overrides = (overrides,)
    sc = _resolve_scenario(scenario, seed, tuple(overrides))
    out = Path(out) if out is not None else Path("results") / sc.name
    _prepare_output(out, overwrite)
    from ..errors import Interrupted, InterruptGuard
    from .mission import run_mission
    guard = InterruptGuard()
    try:
        with guard:
            run_mission(sc, out, verbose=verbose, meshcat=meshcat)
    except BaseException as e:
        if not guard.was_interrupt(e):
            raise
        raise Interrupted(f"interrupted: the finished iterations are in {out / 'iterations.jsonl'} "
                          f"(the scenario in {out / 'scenario.yaml'}; no summary.json)") from None
    return RunResult.load(out)
