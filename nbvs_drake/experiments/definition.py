"""Experiment definitions: YAML data naming a base scenario, the factors varied (each level a
list of `--set` overrides, optionally its own scenario), the seeds, what to aggregate and the
paper's published values. `expand` turns a definition into its runs.

A definition (all keys but `name`, `factors` and `seeds` optional)::

    name: motion_noise
    title: ...
    paper: Vasquez-Gomez, Sucar & Murrieta-Cid (2017)
    reference: Table 5, Fig. 12
    scenario: teapot_du          # base scenario: a name in diagrams/ or a YAML path
    set: [mission.max_scans=12]  # overrides of every run
    factors:                     # the runs are the cross product of the factors' levels
      - name: object
        levels:
          - {label: teapot, set: [scene.object.kind=teapot]}
      - name: approach
        levels:
          - {label: DU-MU, scenario: teapot_du_mu, x: 1}   # x: position in a `versus` figure
          - {label: EU-MU, scenario: teapot_eu_mu, seeds: [1, 2, 3, 4, 5]}  # its own seeds
      - name: planner
        levels:
          - {label: paper}
          - {label: nbvs, set: [planner.metric=coverage]}
          - {label: nbvs_fine, from: nbvs, set: [localisation.fine_stage=true]}  # nbvs's, then its own
    skip:                        # cells not run (a level's label or a list of them per factor)
      - {approach: DU-MU, planner: [nbvs_fine]}
    seeds: [1, 2, 3]
    metrics:   # per-run values (summary.json keys, derived keys; see aggregate.py)
      - {name: coverage, key: coverage, scale: 100, unit: "%", stats: [mean, std, max]}
      - {name: collision_rate, ratio: [collisions, executed_trajectories], scale: 100, unit: "%"}
    series:    # per-iteration values (iterations.jsonl fields), mean and std per iteration
      - {name: coverage, field: coverage, scale: 100, carry: last}
    timings:   # like metrics (or series with `field`), wall-clock: kept apart, never compared
      - {name: plan_time, key: plan_s_per_iteration, unit: s}
    analysis: {kind: prediction, skip_first: 1}
    figures:
      - {file: coverage_per_scan.png, kind: series, series: coverage, panels: object}
    published:
      source: Table 5
      notes: [...]
      cells:
        - {levels: {object: teapot, approach: DU}, coverage.mean: 93.6, collision_rate: 0}
    quick:     # the `--quick` version: fewer seeds and levels, cheaper overrides (applied last)
      seeds: [1, 2]
      levels: {object: [teapot]}          # keep these levels of a factor
      replace_levels: {k: [{label: "300", set: [planner.strategy.vertices=300]}]}  # or other levels
      set: [mission.max_scans=2]
    cost: {...}  # measured seconds per run, and on what machine
"""

from __future__ import annotations

import copy
import dataclasses as dc
import hashlib
import itertools
import json
import re
from pathlib import Path

from ..config import settings_of  # noqa: F401 (re-exported: runner, records)
from ..errors import NbvsError

DEFINITIONS_DIR = Path(__file__).resolve().parent / "definitions"


#: what runs a definition's runs (`runner:`; RunSpec.runner)
RUNNERS = ("mission", "view_sphere")


class ExperimentError(NbvsError):
    """A malformed experiment definition or an impossible request."""


@dc.dataclass
class RunSpec:
    """One run of an experiment: a scenario, a seed and its overrides."""
    run_id: str
    levels: dict  # factor name -> level label
    scenario: str  # scenario name (diagrams/<name>.yaml) or path
    seed: int
    overrides: list
    #: what runs it: "mission" (`nbvs reconstruct`) or "view_sphere" (the view-sphere protocol,
    #: nbvs_drake.gym.sphere.run_view_sphere); a definition's `runner:`
    runner: str = "mission"

    def key(self) -> dict:
        """What makes the run what it is (compared with a finished run's run.json)."""
        k = {"scenario": self.scenario, "seed": self.seed, "overrides": list(self.overrides)}
        if self.runner != "mission":
            k["runner"] = self.runner
        return k

    def to_json(self) -> dict:
        return dc.asdict(self)

    def resolve(self):
        """The scenario this run runs (its scenario with its seed and overrides)."""
        from ..config import load_scenario
        return load_scenario(self.scenario, seed=self.seed, settings=self.overrides)




_LABEL_OK = re.compile(r"[^A-Za-z0-9.+-]+")


def _slug(label: str) -> str:
    return _LABEL_OK.sub("_", str(label)).strip("_") or "x"


def definition_names() -> list[str]:
    """The built-in definitions, in their listing order (`order:` in each file, then name)."""
    found = []
    for p in DEFINITIONS_DIR.glob("*.yaml"):
        d = _read_yaml(p)
        found.append((d.get("order", 100), p.stem))
    return [n for _, n in sorted(found)]


def _read_yaml(path: Path) -> dict:
    import yaml
    try:
        d = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as e:
        raise ExperimentError(f"malformed experiment definition {path}: {' '.join(str(e).split())}") from None
    if not isinstance(d, dict):
        raise ExperimentError(f"experiment definition {path} is not a mapping")
    return d


def load_definition(name_or_path) -> dict:
    """A built-in definition by name (`motion_noise`) or a definition YAML file, checked."""
    p = Path(str(name_or_path))
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ExperimentError(f"experiment definition not found: {p}")
        d = _read_yaml(p)
        d.setdefault("name", p.stem)
        d["_path"] = str(p.resolve())
    else:
        f = DEFINITIONS_DIR / f"{name_or_path}.yaml"
        if not f.is_file():
            raise ExperimentError(f"unknown experiment {name_or_path!r}; known: {', '.join(definition_names())}")
        d = _read_yaml(f)
        d["_path"] = str(f)
    check_definition(d)
    return d


def check_definition(d: dict) -> dict:
    name = d.get("name")
    if not name or not isinstance(name, str) or _slug(name) != name:
        raise ExperimentError(f"experiment name must be a plain word (letters, digits, _ . + -), got {name!r}")

    def need(cond, msg):
        if not cond:
            raise ExperimentError(f"experiment {name}: {msg}")
    need(d.get("runner", "mission") in RUNNERS, f"runner must be one of {', '.join(RUNNERS)}, not {d.get('runner')!r}")
    factors = d.get("factors") or []
    need(isinstance(factors, list), "factors must be a list")
    seen = set()
    for f in factors:
        need(isinstance(f, dict) and f.get("name") and isinstance(f.get("levels"), list) and f["levels"],
             f"each factor needs a name and a non-empty list of levels, got {f!r}")
        need(f["name"] not in seen, f"factor {f['name']!r} appears twice")
        seen.add(f["name"])
        labels = [str(lv.get("label", "")) for lv in f["levels"]]
        need(all(labels) and len(set(labels)) == len(labels), f"factor {f['name']}: levels need distinct labels")
        for i, lv in enumerate(f["levels"]):
            need(isinstance(lv.get("set", []), list), f"factor {f['name']} level {lv['label']}: set must be a list")
            if lv.get("from") is not None:
                need(str(lv["from"]) in labels[:i],
                     f"factor {f['name']} level {lv['label']}: from {lv['from']!r} names no earlier level")
            ls = lv.get("seeds")
            need(ls is None or (isinstance(ls, list) and ls and all(isinstance(x, int) for x in ls)),
                 f"factor {f['name']} level {lv['label']}: seeds must be a non-empty list of integers")
    for sk in d.get("skip") or []:
        need(isinstance(sk, dict) and sk, f"each skip entry maps factors to levels, got {sk!r}")
        for fname, want in sk.items():
            f = next((f for f in factors if f["name"] == fname), None)
            need(f is not None, f"skip names no factor {fname!r}")
            want = want if isinstance(want, list) else [want]
            unknown = sorted(set(map(str, want)) - {str(lv["label"]) for lv in f["levels"]})
            need(not unknown, f"skip: factor {fname} has no levels {unknown}")
    seeds = d.get("seeds")
    need(isinstance(seeds, list) and seeds and all(isinstance(s, int) for s in seeds),
         "seeds must be a list of integers")
    for sec in ("metrics", "timings", "series"):
        for m in d.get(sec) or []:
            need(isinstance(m, dict) and m.get("name"), f"each entry of {sec} needs a name, got {m!r}")
            if sec == "series":
                need(m.get("field") or m.get("summary"), f"series {m['name']}: needs field or summary")
            elif not m.get("field"):
                need(m.get("key") or m.get("ratio"), f"{sec} {m['name']}: needs key, ratio or field")
    q = d.get("quick") or {}
    for fname, levels in (q.get("replace_levels") or {}).items():
        need(any(f["name"] == fname for f in factors), f"quick.replace_levels names no factor {fname!r}")
        need(isinstance(levels, list) and levels and all(isinstance(lv, dict) and lv.get("label") for lv in levels),
             f"quick.replace_levels.{fname}: a non-empty list of levels with labels")
    for fname, labels in (q.get("levels") or {}).items():
        f = next((f for f in factors if f["name"] == fname), None)
        need(f is not None, f"quick.levels names no factor {fname!r}")
        known = {str(lv["label"]) for lv in f["levels"]}
        unknown = sorted(set(map(str, labels)) - known)
        need(not unknown, f"quick.levels.{fname}: unknown levels {unknown}")
    return d


def with_objects(d: dict, objects: list[str]) -> dict:
    """`--object NAME=PATH`: a copy of the definition with one more level of its `object`
    factor per mesh (kind mesh, the path made absolute); also kept by --quick."""
    if not objects:
        return d
    d = copy.deepcopy(d)
    f = next((f for f in d.get("factors") or [] if f["name"] == "object"), None)
    if f is None:
        raise ExperimentError(f"experiment {d['name']} has no object factor: --object does not apply")
    for spec in objects:
        label, sep, path = spec.partition("=")
        if not sep or not label or not path:
            raise ExperimentError(f"--object {spec!r}: expected NAME=PATH (an OBJ/PLY/STL/OFF/GLB mesh)")
        p = Path(path).expanduser().resolve()
        if not p.is_file():
            raise ExperimentError(f"--object {spec!r}: no such file {p}")
        if any(str(lv["label"]) == label for lv in f["levels"]):
            raise ExperimentError(f"--object {spec!r}: the object factor already has a level {label!r}")
        f["levels"].append({"label": label, "set": ["scene.object.kind=mesh", f"scene.object.mesh={json.dumps(str(p))}",
                                                   "scene.object.size=0.40"]})
        q = d.get("quick") or {}
        if "object" in (q.get("levels") or {}):
            q["levels"]["object"] = list(q["levels"]["object"]) + [label]
    return d


def resolve(d: dict, quick: bool = False, seeds=None) -> dict:
    """The definition as it will run: the quick section applied (seeds, levels, overrides
    appended after every level's), `seeds` (a list) replacing the seeds."""
    r = copy.deepcopy(d)
    for f in r.get("factors") or []:  # each level's `from` resolved, so that filtering keeps its settings
        f["levels"] = [resolved_level(f, lv) for lv in f["levels"]]
    r["quick"] = bool(quick)
    q = d.get("quick") or {}
    r["extra_set"] = list(q.get("set") or []) if quick else []
    if quick:
        if q.get("seeds"):
            r["seeds"] = list(q["seeds"])
        for f in r.get("factors") or []:
            if f["name"] in (q.get("replace_levels") or {}):
                f["levels"] = copy.deepcopy(q["replace_levels"][f["name"]])
                continue
            keep = (q.get("levels") or {}).get(f["name"])
            if keep is not None:
                keep = [str(k) for k in keep]
                f["levels"] = [lv for lv in f["levels"] if str(lv["label"]) in keep]
    if seeds:
        r["seeds"] = [int(s) for s in seeds]
    if quick or seeds:  # the quick section's or the caller's seeds serve every level
        for f in r.get("factors") or []:
            for lv in f["levels"]:
                lv.pop("seeds", None)
    return r


def resolved_level(factor: dict, level: dict) -> dict:
    """A level with its `from` resolved: the overrides of the level it starts from
    (recursively) before its own, and that level's scenario and seeds unless it names its own."""
    out = {k: v for k, v in level.items() if k != "from"}
    out["set"] = list(level.get("set") or [])
    if level.get("from") is not None:
        parent = resolved_level(factor, next(lv for lv in factor["levels"] if str(lv["label"]) == str(level["from"])))
        for k in ("scenario", "seeds"):
            if k not in out and parent.get(k) is not None:
                out[k] = parent[k]
        out["set"] = parent["set"] + out["set"]
    return out


def _skipped(r: dict, labels: dict) -> bool:
    for sk in r.get("skip") or []:
        if all(str(labels.get(f)) in {str(x) for x in (w if isinstance(w, list) else [w])} for f, w in sk.items()):
            return True
    return False


def cells(r: dict) -> list[dict]:
    """Every combination of levels of a resolved definition (`resolve`: each level's `from`
    resolved) but the skipped ones, in definition order: [{factor: level dict}]."""
    factors = r.get("factors") or []
    if not factors:
        return [{}]
    out = []
    for combo in itertools.product(*[f["levels"] for f in factors]):
        combo = dict(zip([f["name"] for f in factors], combo))
        if not _skipped(r, _labels(combo)):
            out.append(combo)
    return out


def cell_label(levels: dict) -> str:
    """'teapot/DU' (level labels joined in factor order) or 'all' for no factor."""
    return "/".join(str(v) for v in levels.values()) or "all"


def cell_id(levels: dict) -> str:
    return "-".join(_slug(v) for v in levels.values()) or "run"


def expand(r: dict) -> list[RunSpec]:
    """The runs of a resolved definition (cell by cell, seed by seed)."""
    runs = []
    for combo in cells(r):
        scenario = r.get("scenario")
        overrides = list(r.get("set") or [])
        for lv in combo.values():
            scenario = lv.get("scenario") or scenario
        for lv in combo.values():
            overrides += list(lv.get("set") or [])
        overrides += list(r.get("extra_set") or [])
        if not scenario:
            raise ExperimentError(f"experiment {r['name']}: no scenario for {cell_label(_labels(combo))}")
        # a level may run its own seeds (`seeds:` in the level; the first such level's count)
        level_seeds = next((lv["seeds"] for lv in combo.values() if lv.get("seeds")), None)
        for seed in level_seeds or r["seeds"]:
            runs.append(RunSpec(f"{cell_id(_labels(combo))}_s{seed}", _labels(combo), str(scenario), int(seed),
                                overrides, r.get("runner") or "mission"))
    ids = [x.run_id for x in runs]
    if len(set(ids)) != len(ids):
        raise ExperimentError(f"experiment {r['name']}: two runs share a folder name; make the level labels distinct")
    return runs


def _labels(combo: dict) -> dict:
    return {f: str(lv["label"]) for f, lv in combo.items()}


def fingerprint(r: dict) -> str:
    """A short hash of what the runs are (for the record, not for skipping)."""
    return hashlib.sha1(json.dumps([x.key() for x in expand(r)], sort_keys=True).encode()).hexdigest()[:12]
