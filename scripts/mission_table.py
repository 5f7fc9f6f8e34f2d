"""Runs scenarios x seeds and prints the comparison table of seed 000's experiments
(coverage, collisions, collision rate, distance, scans, stop reasons, pose errors).

    .venv/bin/python scripts/mission_table.py --scenarios teapot_du teapot_du_mu teapot_eu_mu \\
        --seeds 1 2 3 4 5 --out results/table [--jobs 2]
    .venv/bin/python scripts/mission_table.py --collect results/table   # table of finished runs
    .venv/bin/python scripts/mission_table.py --scenarios teapot_du_mu teapot_eu_mu \
        --set noise.sigma_w=0.14 --label w014 --out results/noise_sweep     # one setting changed

Each run is `nbvs reconstruct --scenario diagrams/<name>.yaml --seed <s> --out <out>/<name>_s<s>`
(with `--label L`: `--set name=<name>_L`, folders <name>_L_s<s>; every `--set` is passed on);
the table (markdown) and one JSON object per scenario are printed from the runs' summary.json,
and <out>/coverage_by_scan.png plots each scenario's mean coverage per scan (seed 000 Fig. 12;
a run stopped early counts with its last coverage).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from nbvs_drake.plots import carry_forward, plot_coverage_by_scenario  # noqa: E402


def run_one(name: str, seed: int, out: Path, settings=(), label: str = "") -> Path:
    run_name = f"{name}_{label}" if label else name
    d = out / f"{run_name}_s{seed}"
    if (d / "summary.json").exists():
        return d
    d.mkdir(parents=True, exist_ok=True)
    extra = [a for kv in list(settings) + ([f"name={run_name}"] if label else []) for a in ("--set", kv)]
    with open(d.with_suffix(".log"), "w") as log:
        subprocess.run([sys.executable, "-m", "nbvs_drake.cli", "reconstruct", "--scenario",
                        str(ROOT / "diagrams" / f"{name}.yaml"), "--seed", str(seed), "--out", str(d), *extra],
                       stdout=log, stderr=subprocess.STDOUT, check=False)
    return d


def collect(out: Path) -> dict[str, list[dict]]:
    rows: dict[str, list[dict]] = {}
    for f in sorted(out.glob("*_s*/summary.json")):
        s = json.loads(f.read_text())
        rows.setdefault(s["scenario"], []).append(s)
    return rows


def table(rows: dict[str, list[dict]]) -> tuple[str, list[dict]]:
    lines = ["| scenario | runs | coverage (3 mm) mean | per seed | collisions | collision rate | distance (eq. 8) | scans | stop reasons | base error believed → corrected (m) | heading (rad) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    out = []
    for name, ss in rows.items():
        ss = sorted(ss, key=lambda s: s["seed"])
        n = len(ss)
        cov = [s["coverage"] for s in ss]
        coll = sum(s["collisions"] for s in ss)
        ex = sum(s["executed_trajectories"] for s in ss)
        pe = [s.get("pose_error", {}) for s in ss if s.get("pose_error", {}).get("scans")]

        def mean(xs):
            return sum(xs) / len(xs) if xs else float("nan")
        agg = {"scenario": name, "seeds": [s["seed"] for s in ss], "coverage": cov,
               "coverage_mean": mean(cov), "collisions": [s["collisions"] for s in ss],
               "collision_rate": coll / ex if ex else 0.0, "distance_mean": mean([s["distance"] for s in ss]),
               "scans": [s["scans"] for s in ss], "stop_reasons": [s["stop_reason"] for s in ss],
               "believed_m": mean([p["believed_m"] for p in pe]), "corrected_m": mean([p["corrected_m"] for p in pe]),
               "believed_rad": mean([p["believed_rad"] for p in pe]),
               "corrected_rad": mean([p["corrected_rad"] for p in pe]),
               "wall_s_mean": mean([s["wall_s"] for s in ss]),
               "coverage_by_scan_mean": [round(float(c), 6) for c in
                                         carry_forward([s["coverage_by_scan"] for s in ss]).mean(0)]}
        out.append(agg)
        lines.append(
            f"| {name} | {n} | {agg['coverage_mean']:.3f} | {', '.join(f'{c:.3f}' for c in cov)} | "
            f"{coll} ({sum(1 for s in ss if s['collisions'])} runs) | {agg['collision_rate']:.3f} | "
            f"{agg['distance_mean']:.2f} | {', '.join(str(s) for s in agg['scans'])} | "
            f"{', '.join(agg['stop_reasons'])} | {agg['believed_m']:.3f} → {agg['corrected_m']:.3f} | "
            f"{agg['believed_rad']:.3f} → {agg['corrected_rad']:.3f} |")
    return "\n".join(lines), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="*", default=["teapot_du", "teapot_du_mu", "teapot_eu_mu"])
    ap.add_argument("--seeds", nargs="*", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--out", default="results/table")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--collect", default=None, help="only tabulate the finished runs in this folder")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scenario override passed to every run (as `nbvs reconstruct --set`)")
    ap.add_argument("--label", default="", help="suffix of the runs' scenario names and folders")
    a = ap.parse_args(argv)
    out = Path(a.collect or a.out)
    if not a.collect:
        jobs = [(n, s) for n in a.scenarios for s in a.seeds]
        with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as ex:
            list(ex.map(lambda j: run_one(j[0], j[1], out, a.set, a.label), jobs))
    rows = collect(out)
    md, agg = table(rows)
    plot_coverage_by_scenario({n: [s["coverage_by_scan"] for s in sorted(ss, key=lambda s: s["seed"])]
                               for n, ss in rows.items()}, out / "coverage_by_scan.png",
                              "mean coverage per scan")
    print(md)
    for row in agg:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
