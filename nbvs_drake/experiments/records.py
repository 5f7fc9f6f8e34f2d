"""Run records: what a finished run's table cell needs (run.json, summary.json, scenario.yaml
and iterations.jsonl without the planned and executed paths and the candidates), one gzipped
JSON file per run, `RECORDS/<experiment>[_quick]/<run>.json.gz`, small enough to keep in git
(~10 kB for a 25-scan run). `nbvs experiment NAME --records RECORDS` restores the recorded
runs that its output folder lacks before it runs anything (so a study that outgrows one
machine or one session is continued elsewhere, from a checkout, without redoing a run) and
records every finished run, each file written whole (temporary file, then rename).

A restored run's folder holds those four files only (no model, map or replay) and its
run.json says `restored_from`; the table is built from them as from the run's own folder."""

from __future__ import annotations

import gzip
import json
import os
import shutil
from pathlib import Path

from ..files import write_atomic

FORMAT = 1
SUFFIX = ".json.gz"
#: the bulky parts of an iteration record that no table uses (states and candidates)
DROPPED = ("executed_path",)
DROPPED_PLAN = ("path", "candidates")


def _compact(rec: dict) -> dict:
    rec = {k: v for k, v in rec.items() if k not in DROPPED}
    if isinstance(rec.get("plan"), dict):
        rec["plan"] = {k: v for k, v in rec["plan"].items() if k not in DROPPED_PLAN}
    return rec


def record_of(run_dir: Path) -> dict:
    """The record of a finished run folder (summary.json is there)."""
    d = Path(run_dir)
    it = d / "iterations.jsonl"
    sc = d / "scenario.yaml"
    rj = d / "run.json"
    return {"format": FORMAT,
            "run": json.loads(rj.read_text()) if rj.is_file() else {},
            "summary": json.loads((d / "summary.json").read_text()),
            "scenario_yaml": sc.read_text() if sc.is_file() else None,
            "iterations": [_compact(json.loads(x)) for x in it.read_text().splitlines() if x.strip()]
            if it.is_file() else []}


def write_record(run_dir: Path, dest: Path) -> Path:
    """Writes the record of run_dir to dest (gzip without a timestamp: the same run gives the
    same bytes)."""
    raw = json.dumps(record_of(run_dir), separators=(",", ":"), sort_keys=True).encode()
    write_atomic(dest, gzip.compress(raw, compresslevel=9, mtime=0), mkdir=True)
    return Path(dest)


def read_record(path: Path) -> dict:
    from .definition import ExperimentError
    try:
        rec = json.loads(gzip.decompress(Path(path).read_bytes()))
    except (OSError, ValueError, EOFError) as e:
        raise ExperimentError(f"run record {path} is unreadable ({e})") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT or "summary" not in rec:
        raise ExperimentError(f"run record {path} is not a run record of format {FORMAT}")
    return rec


def restore(rec: dict, final: Path, source: Path, tmp: Path) -> Path:
    """Writes a record as the finished run folder `final`: into the temporary folder `tmp`
    (named by the caller, so the runner cleans a leftover with its other partial folders),
    renamed once complete (a run's folder appears complete or not at all)."""
    final, tmp = Path(final), Path(tmp)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    (tmp / "run.json").write_text(json.dumps(dict(rec.get("run") or {}, restored_from=str(source)), indent=1))
    if rec.get("scenario_yaml") is not None:
        (tmp / "scenario.yaml").write_text(rec["scenario_yaml"])
    (tmp / "iterations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rec.get("iterations") or []))
    (tmp / "summary.json").write_text(json.dumps(rec["summary"], indent=1))
    os.rename(tmp, final)
    return final


def settings_key(sc) -> str:
    """A scenario's settings (`definition.settings_of`) as one string, for lookups."""
    from .definition import settings_of
    return json.dumps(settings_of(sc), sort_keys=True, default=str)


def record_scenario(rec: dict):
    """The scenario a record's run was made with (its scenario.yaml, read with today's schema:
    a field added since takes its default), or None when the record has none. Raises the
    loader's ScenarioError when it cannot be read."""
    import tempfile

    from ..config import load_scenario
    text = rec.get("scenario_yaml")
    if text is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "scenario.yaml"
        f.write_text(text)
        return load_scenario(f)


def _index_key(settings: str, runner: str) -> str:
    return settings if runner == "mission" else f"{runner}:{settings}"


class RecordIndex:
    """The records of a records folder by the settings of the runs they hold (`settings_key`
    of each record's scenario.yaml), read once on the first lookup: a run that one experiment
    recorded is found by another whose definition asks for the same run (the ORT paper's
    VUV runs at 20 x 10^3 vertices are a level of ort_vs_rs, metrics and ort_size alike)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._by_key: dict[str, list[Path]] | None = None
        self.unreadable: list[str] = []

    def _build(self) -> dict[str, list[Path]]:
        from ..errors import NbvsError
        out: dict[str, list[Path]] = {}
        for path in sorted(self.root.glob(f"*/*{SUFFIX}")):
            try:
                rec = read_record(path)
                sc = record_scenario(rec)
                if sc is not None:  # a view-sphere run is not the mission of the same scenario
                    runner = (rec.get("run") or {}).get("runner") or "mission"
                    out.setdefault(_index_key(settings_key(sc), runner), []).append(path)
            except NbvsError as e:  # ExperimentError, ScenarioError: not a lookup's business
                self.unreadable.append(f"{path}: {e}")
        return out

    def find(self, sc, exclude: Path | None = None, runner: str = "mission") -> Path | None:
        """A record (not under `exclude`) of a run of `runner` whose settings equal those of
        scenario sc."""
        if self._by_key is None:
            self._by_key = self._build()
        hits = [p for p in self._by_key.get(_index_key(settings_key(sc), runner), [])
                if exclude is None or p.parent != Path(exclude)]
        return hits[0] if hits else None
