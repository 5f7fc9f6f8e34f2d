"""An experiment's table from whatever finished runs exist: per cell (a combination of
levels) the definition's metrics over the seeds (mean, std, min, max, per-seed values, ...),
the per-iteration series (mean and std per iteration), the analysis (Santos et al. 2020's
predicted against revealed unknown volume), the paper's published values beside ours, and the
figures. Wall-clock timings are kept in their own section (`timings`), which `comparable`
leaves out: the same seeds give the same table whichever executor ran them.

Writes DIR/table.json, DIR/table.md and the figures; `load_table(DIR)` reads them back.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import subprocess
from pathlib import Path

import numpy as np

from ..files import write_atomic
from ..perception.evaluation import planning_per_iteration
from .definition import cell_label, cells, expand

#: table.json sections that depend on the machine, the executor or the clock
UNCOMPARED = ("timings", "stamp")
TIMINGS_HEADING = "## Timings"


# --------------------------------------------------------------------------------------
# one run's values
# --------------------------------------------------------------------------------------


def read_run(d: Path) -> dict | None:
    """A finished run's summary, records (iterations.jsonl) and resolved scenario, or None."""
    d = Path(d)
    f = d / "summary.json"
    if not f.is_file():
        return None
    summary = json.loads(f.read_text())
    it = d / "iterations.jsonl"
    records = [json.loads(x) for x in it.read_text().splitlines() if x.strip()] if it.is_file() else []
    sc = d / "scenario.yaml"
    scenario = _scenario_settings(sc.read_text()) if sc.is_file() else {}
    run = json.loads((d / "run.json").read_text()) if (d / "run.json").is_file() else {}
    return {"dir": str(d), "summary": summary, "records": records, "scenario": scenario or {}, "run": run}


def _scenario_settings(text: str) -> dict:
    """A run's scenario.yaml (today's schema or the old flat one) as {dotted name: value}
    (`config.settings_of`); {} when it cannot be read."""
    from ..config import scenario_from_text, settings_of
    from ..errors import NbvsError
    try:
        return settings_of(scenario_from_text(text, "scenario.yaml"))
    except NbvsError:
        return {}


def _get(obj, path: str):
    if isinstance(obj, dict) and path in obj:  # a flat {dotted name: value}
        return obj[path]
    for part in path.split("."):
        if isinstance(obj, dict) and part in obj:
            obj = obj[part]
        else:
            return None
    return obj


def _num(v):
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)) and math.isfinite(v):
        return float(v)
    return None


def derived(run: dict) -> dict:
    """Per-run quantities computed from the summary and the records (usable as metric keys)."""
    s, recs, sc = run["summary"], run["records"], run["scenario"]
    plans = [r["plan"] for r in recs if (r.get("plan") or {}).get("status") == "ok"]
    times = s.get("times_s") or {}
    views = 0
    for p in plans:
        st = p.get("stages") or {}
        views += int(st.get("visibility") or st.get("vertices") or 0)
    rho = [_num((p.get("factors") or {}).get("rho")) for p in plans]
    rho = [x for x in rho if x is not None]
    scans = s.get("scans") or 0
    voxel = _num(_get(sc, "mapper.voxel_size")) or 0.02
    hrt_a = (_num(_get(sc, "planner.evaluator.a")) or 0) if _get(sc, "planner.evaluator") == "Hrt" else 0
    nodes = [p["path_nodes"] for p in plans if p.get("path_nodes")]
    controls = [p["n_controls"] for p in plans if p.get("n_controls") is not None]
    scans_recs = [r.get("scan") or {} for r in recs]
    # the registration and the map update of each sensing scan, and of the localisation frames
    reg_s = sum((sc_.get("register_s") or 0.0) + (sc_.get("update_s") or 0.0)
                + sum(f.get("register_s") or 0.0 for f in sc_.get("frames") or []) for sc_ in scans_recs)
    curve = [c for c in (s.get("coverage_by_scan") or []) if c is not None]
    return {
        # the area under the coverage-against-views curve, normalised: the mean coverage after each scan
        "coverage_auc": float(np.mean(curve)) if curve else None,
        "plans": len(plans),
        "views_evaluated": views,
        # the vertices of each executed path in its search (a steering path: its 2 ends), and its controls
        "nodes_in_path": float(np.mean(nodes)) if nodes else None,
        "controls_in_path": float(np.mean(controls)) if controls else None,
        "stopped_unknown": 1.0 if s.get("stop_reason") == "unknown_below_threshold" else 0.0,
        "registration_s_per_iteration": reg_s / len(scans_recs) if scans_recs else None,
        # the NBV plan, and with the verification and recovery planning that followed it
        **planning_per_iteration(recs),
        "collided": 1.0 if (s.get("collisions") or 0) > 0 else 0.0,
        "distance_per_scan": s["distance"] / scans if scans and s.get("distance") is not None else None,
        "trajectory_length_mean": float(np.mean(rho)) if rho else None,
        "roughest_voxel_m": voxel * 2 ** hrt_a,
        "visibility_s_per_view": times.get("visibility", 0.0) / views if views else None,
        "visibility_s_per_iteration": times.get("visibility", 0.0) / len(plans) if plans else None,
        "motion_planning_s_per_iteration": times.get("motion_planning", 0.0) / len(plans) if plans else None,
        "view_evaluation_s_per_iteration": (times["view_evaluation"] / len(plans)
                                            if plans and "view_evaluation" in times else None),
    }


def run_value(run: dict, key: str):
    """`key` in the summary (dotted: `times_s.plan`), then the derived quantities, then
    `scenario.<section>.<field>`."""
    v = _get(run["summary"], key)
    if v is None:
        v = derived(run).get(key)
    if v is None and key.startswith("scenario."):
        v = _get(run["scenario"], key[len("scenario."):])
    return v


def _efficiency(recs: list[dict]) -> list:
    """The ORT paper's reconstruction efficiency per iteration: coverage increment over the
    observation cost t_plan + t_mov + t_update (the plan that led to the scan, its simulated
    motion time, and the scan's render, registration and map update), % per second."""
    out = [None]
    for a, b in zip(recs, recs[1:]):
        plan, scan = a.get("plan") or {}, b.get("scan") or {}
        cost = (plan.get("plan_s") or 0.0) + (plan.get("motion_sim_s") or 0.0) + \
            sum(scan.get(k) or 0.0 for k in ("render_s", "register_s", "update_s"))
        out.append(100 * (b["coverage"] - a["coverage"]) / cost if cost > 0 else None)
    return out


def run_series(run: dict, spec: dict) -> list:
    if spec.get("summary"):
        return list(run["summary"].get(spec["summary"]) or [])
    field = spec["field"]
    if field == "efficiency":
        return _efficiency(run["records"])
    return [_get(r, field) for r in run["records"]]


# --------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------


def _clean(x):
    """JSON-safe: NaN and inf become None, numpy scalars plain numbers."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def metric_stats(spec: dict, runs: dict[int, dict]) -> dict:
    """One metric over a cell's finished runs (seed -> run)."""
    scale = float(spec.get("scale", 1.0))
    out = {}
    if spec.get("ratio"):
        num_k, den_k = spec["ratio"]
        nums = {s: _num(run_value(r, num_k)) for s, r in runs.items()}
        dens = {s: _num(run_value(r, den_k)) for s, r in runs.items()}
        tn = sum(v for v in nums.values() if v is not None)
        td = sum(v for v in dens.values() if v is not None)
        out["pooled"] = scale * tn / td if td else (0.0 if runs else None)
        vals = {s: (scale * nums[s] / dens[s] if dens[s] else 0.0) for s in runs
                if nums[s] is not None and dens[s] is not None}
    else:
        vals = {}
        for s, r in runs.items():
            v = _num(run_value(r, spec["key"]))
            if v is not None:
                vals[s] = scale * v
    a = np.array(list(vals.values()), float)
    out["n"] = int(a.size)
    out["values"] = {str(s): v for s, v in sorted(vals.items())}
    if a.size:
        out.update(mean=float(a.mean()), std=float(a.std(ddof=1)) if a.size > 1 else 0.0,
                   min=float(a.min()), max=float(a.max()), sum=float(a.sum()), nonzero=int(np.count_nonzero(a)))
    else:
        out.update(mean=None, std=None, min=None, max=None, sum=None, nonzero=0)
    return out


def series_stats(spec: dict, runs: dict[int, dict]) -> dict:
    """Mean and std per iteration. carry: last (default for coverage-like series) keeps a run
    that stopped early at its last value, as its final model does; carry: none averages each
    iteration over the runs that reached it."""
    scale = float(spec.get("scale", 1.0))
    per = {}
    for s, r in runs.items():
        v = [(_num(x) * scale if _num(x) is not None else math.nan) for x in run_series(r, spec)]
        if v:
            per[s] = v
    if not per:
        return {"mean": [], "std": [], "n": [], "values": {}}
    longest = max(len(v) for v in per.values())
    a = np.full((len(per), longest), math.nan)
    for i, v in enumerate(per.values()):
        a[i, : len(v)] = v
        if spec.get("carry", "last") == "last":
            last = [x for x in v if not math.isnan(x)]
            a[i, len(v):] = last[-1] if last else math.nan
    n = np.sum(~np.isnan(a), axis=0)
    with np.errstate(invalid="ignore"), __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(a, axis=0)
        std = np.nanstd(a, axis=0)
    return {"mean": _clean(mean.tolist()), "std": _clean(std.tolist()), "n": n.tolist(),
            "values": {str(s): _clean(v) for s, v in sorted(per.items())}}


def prediction_pairs(run: dict, skip_first: int = 0) -> list[tuple[float, float]]:
    """Santos et al. 2020 Fig. 11's pairs from one run, one per plan k (made after scan k,
    k = 1, 2, ...; the first scan has no plan before it): the unknown volume the plan
    predicted to reveal against the unknown volume scan k + 1 revealed. Read from the records'
    `prediction.revealed_m3` and `outcome.revealed_m3` (iterations.jsonl, from scan 2 on);
    records without them (runs made before those fields) fall back to the plan's un_o (the
    unknown voxels its rays reach first) x the voxel volume against the drop of the map's
    unknown volume in W_box. The first `skip_first` plans are left out."""
    recs = run["records"]
    voxel = _num(_get(run["scenario"], "mapper.voxel_size")) or 0.02
    pairs = []
    for k, (a, b) in enumerate(zip(recs, recs[1:])):
        if k < skip_first:
            continue
        pred, out = _num(_get(b, "prediction.revealed_m3")), _num(_get(b, "outcome.revealed_m3"))
        if pred is None or out is None:
            plan = a.get("plan") or {}
            un_o = _num((plan.get("factors") or {}).get("un_o"))
            ua, ub = _num(a.get("remaining_unknown_m3")), _num(b.get("remaining_unknown_m3"))
            if plan.get("status") != "ok" or un_o is None or ua is None or ub is None:
                continue
            pred, out = un_o * voxel ** 3, ua - ub
        pairs.append((pred, out))
    return pairs


def fit(pairs) -> dict:
    """Least-squares line revealed = slope * predicted + intercept and its R²."""
    if len(pairs) < 2:
        return {"n": len(pairs), "r2": None, "slope": None, "intercept": None}
    x, y = np.array(pairs, float).T
    if np.ptp(x) == 0:
        return {"n": len(pairs), "r2": None, "slope": None, "intercept": None}
    slope, intercept = np.polyfit(x, y, 1)
    ss_res = float(np.sum((y - (slope * x + intercept)) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {"n": len(pairs), "r2": 1 - ss_res / ss_tot if ss_tot > 0 else None, "slope": float(slope),
            "intercept": float(intercept)}


# --------------------------------------------------------------------------------------
# the table
# --------------------------------------------------------------------------------------


def _matches(pub_levels: dict, levels: dict) -> bool:
    return all(str(levels.get(k)) == str(v) for k, v in pub_levels.items())


def _published_for(r: dict, levels: dict) -> dict:
    out = {}
    for pc in (r.get("published") or {}).get("cells") or []:
        if _matches(pc.get("levels") or {}, levels):
            out.update({k: v for k, v in pc.items() if k != "levels"})
    return out


def git_commit(root: Path | None = None) -> str:
    """HEAD of the package's source checkout (+dirty with uncommitted changes to tracked
    files), or "unknown" (an installed wheel, no git)."""
    root = root or Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return "unknown"
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (head or "unknown") + ("+dirty" if dirty and head else "")


def build_table(r: dict, exp_dir: Path, stamp: dict | None = None) -> dict:
    """table.json's content from the finished runs in exp_dir/runs/."""
    exp_dir = Path(exp_dir)
    specs = expand(r)
    by_cell: dict[str, list] = {}
    for sp in specs:
        by_cell.setdefault(cell_label(sp.levels), []).append(sp)
    out_cells, timing_cells, analysis = [], [], {}
    for combo in cells(r):
        levels = {f: str(lv["label"]) for f, lv in combo.items()}
        label = cell_label(levels)
        finished, missing, failed = {}, [], []
        for sp in by_cell.get(label, []):
            run = read_run(exp_dir / "runs" / sp.run_id)
            if run is not None:
                finished[sp.seed] = run
            else:
                missing.append(sp.seed)
                if (exp_dir / "runs" / f"{sp.run_id}.failed.json").is_file():
                    failed.append(sp.seed)
        cell = {"label": label, "levels": levels, "expected": len(by_cell.get(label, [])),
                "seeds": [sp.seed for sp in by_cell.get(label, [])],
                "finished": len(finished), "missing_seeds": missing, "failed_seeds": failed,
                "runs": [sp.run_id for sp in by_cell.get(label, [])],
                "x": next((lv.get("x") for lv in combo.values() if lv.get("x") is not None), None),
                "metrics": {m["name"]: metric_stats(m, finished) for m in r.get("metrics") or []},
                "series": {s["name"]: series_stats(s, finished) for s in r.get("series") or []},
                "stop_reasons": {str(s): run["summary"].get("stop_reason") for s, run in sorted(finished.items())},
                "published": {k: v for k, v in _published_for(r, levels).items()
                              if k.split(".")[0] not in {t["name"] for t in r.get("timings") or []}}}
        tcell = {"label": label, "levels": levels, "metrics": {}, "series": {},
                 "published": {k: v for k, v in _published_for(r, levels).items()
                               if k.split(".")[0] in {t["name"] for t in r.get("timings") or []}},
                 "wall_s": {str(s): run["summary"].get("wall_s") for s, run in sorted(finished.items())}}
        for t in r.get("timings") or []:
            if t.get("field"):
                tcell["series"][t["name"]] = series_stats(t, finished)
            else:
                tcell["metrics"][t["name"]] = metric_stats(t, finished)
        an = r.get("analysis") or {}
        if an.get("kind") == "prediction":
            pairs = []
            for _, run in sorted(finished.items()):
                pairs += prediction_pairs(run, int(an.get("skip_first", 0)))
            cell["prediction"] = dict(fit(pairs), pairs=[[float(a), float(b)] for a, b in pairs])
        out_cells.append(cell)
        timing_cells.append(tcell)
    an = r.get("analysis") or {}
    if an.get("kind") == "prediction":
        allp = [tuple(p) for c in out_cells for p in c["prediction"]["pairs"]]
        analysis["prediction"] = fit(allp)
    table = {
        "experiment": r["name"], "title": r.get("title", ""), "paper": r.get("paper", ""),
        "reference": r.get("reference", ""), "quick": bool(r.get("quick")),
        "seeds": list(r["seeds"]), "factors": [f["name"] for f in r.get("factors") or []],
        "runs_expected": len(specs), "runs_finished": sum(c["finished"] for c in out_cells),
        "cells": out_cells, "analysis": analysis,
        "timings": {"cells": timing_cells},
        "stamp": stamp or {},
    }
    return _clean(table)


def comparable(table: dict) -> dict:
    """table.json without the wall-clock and provenance sections."""
    return {k: v for k, v in table.items() if k not in UNCOMPARED}


def compared_markdown(md: str) -> str:
    """table.md up to its timings section."""
    return md.split("\n" + TIMINGS_HEADING, 1)[0]


# --------------------------------------------------------------------------------------
# markdown
# --------------------------------------------------------------------------------------


def _fmt(v, digits=3):
    if v is None:
        return "–"
    if isinstance(v, float):
        if v != 0 and (abs(v) < 10 ** -digits or abs(v) >= 1e5):
            return f"{v:.{digits}g}"
        return f"{v:.{digits}f}".rstrip("0").rstrip(".") if "." in f"{v:.{digits}f}" else f"{v:.{digits}f}"
    return str(v)


def _columns(specs: list[dict]) -> list[tuple[str, str, str]]:
    """(column key, title, how) per shown statistic of each metric."""
    cols = []
    for m in specs:
        title = m.get("label", m["name"].replace("_", " "))
        unit = f" ({m['unit']})" if m.get("unit") else ""
        stats = m.get("stats") or (["pooled"] if m.get("ratio") else ["mean", "std"])
        if "mean" in stats and "std" in stats:
            cols.append((f"{m['name']}.mean", f"{title}{unit} mean ± std", "mean±std"))
            stats = [s for s in stats if s not in ("mean", "std")]
        for st in stats:
            name = {"pooled": "", "nonzero": "", "values": " per seed"}.get(st, f" {st}")
            cols.append((f"{m['name']}.{st}", f"{title}{unit}{name}".strip(), st))
    return cols


def _cell_value(stats: dict, how: str, digits: int):
    if not stats:
        return "–"
    if how == "mean±std":
        if stats.get("mean") is None:
            return "–"
        return f"{_fmt(stats['mean'], digits)} ± {_fmt(stats['std'], digits)}"
    if how == "values":
        return ", ".join(_fmt(v, digits) for v in stats.get("values", {}).values()) or "–"
    if how == "nonzero":
        return f"{stats.get('nonzero', 0)} of {stats.get('n', 0)}"
    return _fmt(stats.get(how), digits)


def _pub_value(pub: dict, key: str):
    name, st = key.split(".", 1)
    if key in pub:
        return pub[key]
    if st in ("mean", "pooled") and name in pub:
        return pub[name]
    return None


def _md_table(factor_names, rows, specs, digits, with_runs=True) -> list[str]:
    cols = _columns(specs)
    col_digits = [next(int(m.get("digits", digits)) for m in specs if m["name"] == k.split(".", 1)[0])
                  for k, _, _ in cols]
    shown_pub = {k for k, _, _ in cols if any(_pub_value(c.get("published") or {}, k) is not None for c in rows)}
    head = list(factor_names) + (["runs"] if with_runs else [])
    for k, title, _ in cols:
        head.append(title)
        if k in shown_pub:
            head.append("paper")
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for c in rows:
        row = [c["levels"].get(f, "") for f in factor_names]
        if with_runs:
            row.append(f"{c['finished']}/{c['expected']}")
        for (k, _, how), dg in zip(cols, col_digits):
            name = k.split(".", 1)[0]
            row.append(_cell_value(c["metrics"].get(name), how, dg))
            if k in shown_pub:
                row.append(_fmt(_pub_value(c.get("published") or {}, k), dg))
        lines.append("| " + " | ".join(str(x) for x in row) + " |")
    return lines


def _unmatched_published(r: dict, table: dict) -> list[str]:
    out = []
    labels = [c["levels"] for c in table["cells"]]
    for pc in (r.get("published") or {}).get("cells") or []:
        lv = pc.get("levels") or {}
        if not any(_matches(lv, x) for x in labels):
            vals = ", ".join(f"{k} {v}" for k, v in pc.items() if k != "levels")
            out.append(f"{'/'.join(str(v) for v in lv.values())}: {vals}")
    return out


def markdown(r: dict, table: dict, figures: list[str]) -> str:
    digits = int(r.get("digits", 3))
    fn = table["factors"] or ["cell"]
    rows = table["cells"]
    L = [f"### {r['name']}: {r.get('title', '')}".rstrip(": "), ""]
    ref = ", ".join(x for x in (r.get("paper"), r.get("reference")) if x)
    if ref:
        L += [f"{ref}.", ""]
    if r.get("description"):
        L += [" ".join(str(r["description"]).split()), ""]
    size = (f"{table['runs_finished']} of {table['runs_expected']} runs finished; "
            f"seeds {', '.join(map(str, table['seeds']))}")
    if table["quick"]:
        size += "; **quick version** (`--quick`: " + ", ".join(f"`{s}`" for s in r.get("extra_set") or []) + ")"
    L += [size + ".", ""]
    L += _md_table(fn, [dict(c, levels=c["levels"] or {"cell": "all"}) for c in rows], r.get("metrics") or [], digits)
    pub = r.get("published") or {}
    if pub.get("source"):
        cond = f" ({pub['conditions']})" if pub.get("conditions") else ""
        L += ["", f"*paper*: {r.get('paper', '')}, {pub['source']}{cond}."]
    extra = _unmatched_published(r, table)
    if extra:
        L += ["", "Published rows without a counterpart here: " + "; ".join(extra) + "."]
    for n in pub.get("notes") or []:
        L += ["", f"*paper*: {' '.join(str(n).split())}"]
    an = table.get("analysis", {}).get("prediction")
    if an is not None:
        skip = int((r.get("analysis") or {}).get("skip_first", 0))
        L += ["", "Predicted against revealed unknown volume, one pair per plan (the scan after it), "
              + (f"the first {skip} plans of each run left out:" if skip else "every plan of each run:"), "",
              "| cell | pairs | R² | slope | intercept (m³) |", "| --- | --- | --- | --- | --- |"]
        for c in rows:
            p = c["prediction"]
            L.append(f"| {c['label']} | {p['n']} | {_fmt(p['r2'])} | {_fmt(p['slope'])} | {_fmt(p['intercept'], 4)} |")
        L.append(f"| all | {an['n']} | {_fmt(an['r2'])} | {_fmt(an['slope'])} | {_fmt(an['intercept'], 4)} |")
        pa = (r.get("published") or {}).get("analysis") or {}
        if pa:
            L.append(f"| *paper* | {_fmt(pa.get('n'))} | {_fmt(pa.get('r2'), 4)} | {_fmt(pa.get('slope'))} | "
                     f"{_fmt(pa.get('intercept'), 4)} |")
        if (r.get("analysis") or {}).get("note"):
            L += ["", " ".join(str(r["analysis"]["note"]).split())]
    # per-seed values and stop reasons
    L += ["", "<details><summary>per seed</summary>", "", "| cell | seed | " +
          " | ".join(m["name"] for m in r.get("metrics") or []) + " | stop reason |",
          "|" + " --- |" * (3 + len(r.get("metrics") or []))]
    for c in rows:
        for s in c.get("seeds", table["seeds"]):
            vals = [_fmt(c["metrics"][m["name"]]["values"].get(str(s)), int(m.get("digits", digits)))
                    for m in r.get("metrics") or []]
            stop = c["stop_reasons"].get(str(s))
            if stop is None:
                stop = "failed" if s in c["failed_seeds"] else "missing"
            L.append(f"| {c['label']} | {s} | " + " | ".join(vals) + f" | {stop} |")
    L += ["", "</details>"]
    missing = [f"{c['label']} seed {s}" + (" (failed)" if s in c["failed_seeds"] else "")
               for c in rows for s in c["missing_seeds"]]
    if missing:
        L += ["", "**Missing runs**: " + ", ".join(missing) + "."]
    if figures:
        L += [""] + [f"![{Path(f).stem.replace('_', ' ')}]({f})" for f in figures]
    # ------------------------------------------------------------- not compared
    L += ["", f"{TIMINGS_HEADING} (wall-clock; not compared between executors or machines)", ""]
    tspecs = [t for t in r.get("timings") or [] if not t.get("field")]
    trows = [dict(tc, finished=c["finished"], expected=c["expected"], levels=c["levels"] or {"cell": "all"})
             for tc, c in zip(table["timings"]["cells"], rows)]
    L += _md_table(fn, [dict(t, metrics=dict(t["metrics"], wall_s=_wall_stats(t["wall_s"]))) for t in trows],
                   tspecs + [{"name": "wall_s", "label": "run wall time", "unit": "s"}], digits, with_runs=False)
    st = table.get("stamp") or {}
    if st:
        L += ["", "Provenance: " + "; ".join(f"{k} `{v}`" for k, v in st.items() if v not in (None, ""))]
    return "\n".join(L) + "\n"


def _wall_stats(wall: dict) -> dict:
    vals = {s: float(v) for s, v in wall.items() if v is not None}
    a = np.array(list(vals.values()), float)
    if not a.size:
        return {"mean": None, "std": None, "n": 0, "values": {}}
    return {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if a.size > 1 else 0.0, "n": int(a.size),
            "values": vals}


def run_commits(exp_dir) -> str:
    """The commits the finished runs were made at (each run's run.json), short, with how many
    runs each: "a34f294 x20, 232f94c x10"; runs from before commits were recorded count as
    "unrecorded"."""
    counts: dict[str, int] = {}
    for rj in sorted((Path(exp_dir) / "runs").glob("*/run.json")):
        try:
            c = json.loads(rj.read_text()).get("git_commit") or "unrecorded"
        except (OSError, ValueError):
            continue
        c = c if c in ("unrecorded", "unknown") else c[:7] + ("+dirty" if c.endswith("+dirty") else "")
        counts[c] = counts.get(c, 0) + 1
    return ", ".join(f"{c} x{n}" for c, n in sorted(counts.items(), key=lambda kv: -kv[1]))


# --------------------------------------------------------------------------------------
# writing and reading
# --------------------------------------------------------------------------------------


def write_table(r: dict, exp_dir, stamp: dict | None = None) -> dict:
    """Builds the table from exp_dir/runs/, draws the figures, writes table.json and
    table.md (each file replaced whole). Returns the table dict."""
    from .figures import draw_figures
    exp_dir = Path(exp_dir)
    exp_dir.mkdir(parents=True, exist_ok=True)
    stamp = dict(stamp or {})
    stamp.setdefault("date", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"))
    stamp.setdefault("git_commit", git_commit())
    stamp.setdefault("run_commits", run_commits(exp_dir))
    table = build_table(r, exp_dir, stamp)
    figures = draw_figures(r, table, exp_dir)
    table["figures"] = figures
    md = markdown(r, table, figures)
    write_atomic(exp_dir / "table.json", json.dumps(table, indent=1, allow_nan=False))
    write_atomic(exp_dir / "table.md", md)
    return table




class Table(dict):
    """An experiment's table.json (a dict) with its markdown and helpers."""

    dir: Path
    markdown: str

    @property
    def cells(self) -> list[dict]:
        return self["cells"]

    def cell(self, label: str) -> dict:
        """The cell 'teapot/DU' (level labels joined by /)."""
        for c in self["cells"]:
            if c["label"] == label:
                return c
        raise KeyError(f"{label!r}; cells: {[c['label'] for c in self['cells']]}")

    def runs(self) -> dict[str, list[dict]]:
        """Per cell label, the finished runs' summaries (in seed order)."""
        out = {}
        for c in self["cells"]:
            out[c["label"]] = [json.loads((self.dir / "runs" / rid / "summary.json").read_text())
                               for rid in c["runs"] if (self.dir / "runs" / rid / "summary.json").is_file()]
        return out


def load_table(exp_dir) -> Table:
    """An experiment folder's table (table.json and table.md, as `nbvs experiment` wrote
    them), e.g. `load_table('results/experiments/motion_noise').cell('teapot/EU-MU')`."""
    d = Path(exp_dir)
    f = d / "table.json"
    if not f.is_file():
        from .definition import ExperimentError
        raise ExperimentError(f"no experiment table in {d} (table.json); run `nbvs experiment NAME --out ...` first")
    t = Table(json.loads(f.read_text()))
    t.dir = d
    t.markdown = (d / "table.md").read_text() if (d / "table.md").is_file() else ""
    return t
