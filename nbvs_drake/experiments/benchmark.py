"""`nbvs benchmark`: any planner judged the same way. A protocol is an experiment definition
(nbvs_drake/experiments/protocols/): `robot` (this project's: the robot, 12 scans, ten objects,
the open scene, Table 4's noise and the cluttered room) and `view_sphere` (the learned
planners': 33 views on a sphere, 1 + 9). It runs through the experiment runner (the local pool
or Ray, records, `--quick`) and prints one table: per condition and planner, the AUC of
coverage against views, the final coverage, the share of the ceiling, the share of the greedy
oracle (per object, the planner's mean coverage over the oracle's in the same condition, then
the mean over the objects), Chamfer and F-score at 5 mm (the point model), distance (eq. 8; on
the sphere, metres along it), the runs that collided and the time per decision."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .definition import ExperimentError, check_definition

PROTOCOLS_DIR = Path(__file__).resolve().parent / "protocols"

#: the table's columns: (name, heading, digits, scale)
COLUMNS = (("auc", "AUC", 1, 100), ("coverage", "coverage", 1, 100), ("of_ceiling", "of ceiling", 1, 100),
           ("of_oracle", "of oracle", 1, 100), ("chamfer_mm", "Chamfer (mm)", 2, 1), ("fscore_5mm", "F 5 mm", 1, 100),
           ("distance", "distance", 2, 1), ("collided", "collided", 0, 1), ("decision_s", "s / decision", 3, 1))


def protocol_names() -> list[str]:
    return sorted(p.stem for p in PROTOCOLS_DIR.glob("*.yaml"))


def load_protocol(name: str) -> dict:
    """A protocol by name, checked as an experiment definition."""
    from .definition import load_definition
    f = PROTOCOLS_DIR / f"{name}.yaml"
    if not f.is_file():
        raise ExperimentError(f"unknown benchmark protocol {name!r}; known: {', '.join(protocol_names())}")
    return load_definition(f)


def with_plugins(d: dict, planners: list[str]) -> dict:
    """The protocol with one more planner level per "LABEL=MODULE:CLASS" (a plug-in planner,
    run in every condition)."""
    import copy
    d = copy.deepcopy(d)
    factor = next((f for f in d["factors"] if f["name"] == "planner"), None)
    for spec in planners:
        label, sep, entry = spec.partition("=")
        if not sep or not label.strip() or not entry.strip():
            raise ExperimentError(f"--planner {spec!r}: expected LABEL=MODULE:CLASS, e.g. mine=my_planner:Planner")
        if any(str(lv["label"]) == label.strip() for lv in factor["levels"]):
            raise ExperimentError(f"--planner {spec!r}: the protocol already has a planner {label.strip()!r}")
        factor["levels"].append({"label": label.strip(),
                                 "set": ["planner.strategy=!Plugin {entry: %s}" % json.dumps(entry.strip())]})
    check_definition(d)
    return d


def _runs(exp_dir: Path) -> list[dict]:
    """The finished runs of a protocol's folder: their levels and summaries."""
    out = []
    for rj in sorted((exp_dir / "runs").glob("*/run.json")):
        sj = rj.parent / "summary.json"
        if sj.is_file():
            out.append({"levels": json.loads(rj.read_text())["levels"], "summary": json.loads(sj.read_text())})
    return out


def _num(v):
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def _mean(vals):
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def table_rows(runs: list[dict]) -> list[dict]:
    """One row per (condition, planner): the columns' means over objects and seeds, and `runs`."""
    def cond(r):
        return r["levels"].get("condition", "")

    def values(s):
        curve = [c for c in s.get("coverage_by_scan") or [] if c is not None]
        rec = (s.get("reconstruction") or {}).get("points") or {}
        return {"auc": _num(s.get("coverage_auc")) if s.get("coverage_auc") is not None else _mean(curve),
                "coverage": _num(s.get("coverage")), "of_ceiling": _num(s.get("coverage_of_ceiling")),
                "chamfer_mm": None if _num(rec.get("chamfer_m")) is None else 1000 * rec["chamfer_m"],
                "fscore_5mm": _num((rec.get("fscore") or {}).get("5mm")), "distance": _num(s.get("distance")),
                "collided": 1.0 if (s.get("collisions") or 0) > 0 else 0.0,
                "decision_s": _num(s.get("plan_s_per_iteration"))}
    # the oracle's mean coverage per (condition, object)
    oracle = {}
    for r in runs:
        if r["levels"].get("planner") == "oracle":
            oracle.setdefault((cond(r), r["levels"].get("object")), []).append(_num(r["summary"].get("coverage")))
    oracle = {k: _mean(v) for k, v in oracle.items()}
    cells = {}
    for r in runs:
        cells.setdefault((cond(r), r["levels"].get("planner")), []).append(r)
    rows = []
    for (c, p), rs in cells.items():
        vals = [values(r["summary"]) for r in rs]
        row = {"condition": c, "planner": p, "runs": len(rs)}
        for name, *_ in COLUMNS:
            if name == "of_oracle":
                continue
            if name == "collided":
                row[name] = int(sum(v[name] for v in vals))
            else:
                row[name] = _mean([v[name] for v in vals])
        per_object = {}
        for r in rs:
            per_object.setdefault(r["levels"].get("object"), []).append(_num(r["summary"].get("coverage")))
        shares = [_mean(v) / oracle[(c, o)] for o, v in per_object.items()
                  if oracle.get((c, o)) and _mean(v) is not None]
        row["of_oracle"] = _mean(shares)
        rows.append(row)
    order = {"open": 0, "noise": 1, "room": 2, "": 0}
    return sorted(rows, key=lambda r: (order.get(r["condition"], 9), r["planner"] == "oracle", r["planner"]))


def table_markdown(name: str, rows: list[dict]) -> str:
    cond = any(r["condition"] for r in rows)
    head = (["condition"] if cond else []) + ["planner", "runs"] + [h for _, h, _, _ in COLUMNS]
    lines = [f"nbvs benchmark {name}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = ([r["condition"]] if cond else []) + [r["planner"], str(r["runs"])]
        for key, _, digits, scale in COLUMNS:
            v = r.get(key)
            cells.append("–" if v is None else (str(v) if key == "collided" else f"{v * scale:.{digits}f}"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_benchmark_table(name: str, exp_dir: Path) -> str:
    """benchmark.md and benchmark.json in the protocol's folder; returns the markdown."""
    rows = table_rows(_runs(exp_dir))
    md = table_markdown(name, rows)
    (exp_dir / "benchmark.md").write_text(md + "\n")
    (exp_dir / "benchmark.json").write_text(json.dumps({"protocol": name, "rows": rows}, indent=1))
    return md
