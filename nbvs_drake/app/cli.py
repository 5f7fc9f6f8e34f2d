"""Command line: `nbvs reconstruct`, `nbvs diagram`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..errors import NbvsError


def _only(specs: list[str]) -> dict:
    """--only FACTOR=LABEL[,LABEL] options as {factor: [labels]}."""
    from ..experiments import ExperimentError
    out = {}
    for spec in specs:
        f, sep, labels = spec.partition("=")
        if not sep or not f or not labels:
            raise ExperimentError(f"--only {spec!r}: expected FACTOR=LABEL[,LABEL], e.g. planner=nbvs")
        out.setdefault(f.strip(), []).extend(x.strip() for x in labels.split(",") if x.strip())
    return out


def _cmd_reconstruct(args):
    from ..errors import quiet_library_logs
    from .api import reconstruct
    quiet_library_logs()
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat, MeshcatParams
        meshcat = Meshcat(MeshcatParams(host="localhost", port=args.meshcat_port))
        print(f"nbvs: live view (Meshcat) at {meshcat.web_url()}", flush=True)
    overrides = list(args.set)
    if args.planner:  # a plug-in planner: the scenario's strategy (its records re-run it the same way)
        overrides.append("planner.strategy=!Plugin {entry: %s}" % json.dumps(args.planner))
    reconstruct(args.scenario, out=args.out, seed=args.seed, overrides=overrides, overwrite=args.overwrite,
                verbose=not args.quiet, meshcat=meshcat)
    if meshcat is not None and sys.stdin.isatty():
        try:
            input(f"nbvs: the live view stays at {meshcat.web_url()}; press Enter to close it ")
        except EOFError:
            pass


def _cmd_diagram(args):
    from ..config import load_scenario
    from ..outputs.wiring import write_wiring
    from ..resources import builtin_scenarios, diagrams_dir, source_checkout
    # beside the built-in scenarios in a source checkout (the repository's diagrams/); a
    # wheel install does not write into its own package: ./diagrams instead
    folder = diagrams_dir() if source_checkout() else Path("diagrams")
    paths = list(builtin_scenarios().values()) if args.all else [args.scenario]
    for p in paths:
        sc = load_scenario(p)
        out = Path(args.out) if (args.out and not args.all) else folder / f"{sc.name}_wiring"
        for f in write_wiring(sc, out):
            print(f)


def _cmd_experiment(args):
    import shlex

    from ..experiments import ExperimentError, listing, load_definition, run_experiment, with_objects, write_report
    from ..experiments.runner import make_executor
    out = args.out or "results/experiments"
    if args.list:
        print(listing())
        return
    if not args.names:
        raise ExperimentError("name an experiment (`nbvs experiment --list` lists them) or `report`")
    if args.names == ["report"]:
        dest, names = write_report(out, args.to or "docs/results.md", args.figures)
        print(f"{dest}: {len(names)} tables ({', '.join(names)})")
        return
    defs = [with_objects(load_definition(n), args.object) if args.object else load_definition(n)
            for n in args.names]
    command = shlex.join(["nbvs", "experiment", *args.names]
                         + (["--quick"] if args.quick else [])
                         + (["--seeds", *map(str, args.seeds)] if args.seeds else [])
                         + [a for o in args.only for a in ("--only", o)]
                         + (["--jobs", str(args.jobs)] if args.jobs else []) + ["--executor", args.executor]
                         + (["--address", args.address] if args.address else []) + ["--out", out]
                         + (["--retry-failed"] if args.retry_failed else [])
                         + (["--table-only"] if args.table_only else [])
                         + (["--records", args.records] if args.records else [])
                         + [a for o in args.object for a in ("--object", o)])
    ex = make_executor("local" if args.table_only else args.executor, args.jobs, args.address)
    failed = []
    try:
        for d in defs:
            failed += run_experiment(d, out, quick=args.quick, seeds=args.seeds, executor=ex,
                                     retry_failed=args.retry_failed, command=command,
                                     table_only=args.table_only, records=args.records,
                                     only=_only(args.only))["failed"]
    finally:
        ex.close()
    if failed:
        print(f"nbvs: {len(failed)} runs failed ({', '.join(failed)}); their errors are in runs/<run>.failed.json, "
              "`--retry-failed` reruns them", file=sys.stderr)
        raise SystemExit(1)


def _cmd_benchmark(args):
    import shlex

    from ..experiments import ExperimentError, listing, run_experiment
    from ..experiments.benchmark import load_protocol, protocol_names, with_plugins, write_benchmark_table
    from ..experiments.runner import make_executor
    out = args.out or "results/benchmarks"
    if args.list:
        print(listing([load_protocol(n) for n in protocol_names()]))
        return
    if not args.protocol:
        raise ExperimentError(f"name a protocol: {', '.join(protocol_names())} (`nbvs benchmark --list`)")
    d = load_protocol(args.protocol)
    if args.planner:
        d = with_plugins(d, args.planner)
    command = shlex.join(["nbvs", "benchmark", args.protocol] + (["--quick"] if args.quick else [])
                         + (["--seeds", *map(str, args.seeds)] if args.seeds else [])
                         + [a for o in args.only for a in ("--only", o)]
                         + [a for p in args.planner for a in ("--planner", p)]
                         + (["--jobs", str(args.jobs)] if args.jobs else []) + ["--executor", args.executor]
                         + ["--out", out] + (["--records", args.records] if args.records else []))
    ex = make_executor("local" if args.table_only else args.executor, args.jobs, args.address)
    try:
        res = run_experiment(d, out, quick=args.quick, seeds=args.seeds, executor=ex, retry_failed=args.retry_failed,
                             command=command, table_only=args.table_only, records=args.records,
                             only=_only(args.only))
    finally:
        ex.close()
    print(write_benchmark_table(args.protocol, Path(res["dir"])))
    if res["failed"]:
        print(f"nbvs: {len(res['failed'])} runs failed ({', '.join(res['failed'])}); their errors are in "
              "runs/<run>.failed.json, `--retry-failed` reruns them", file=sys.stderr)
        raise SystemExit(1)


def _cmd_config_reference(args) -> None:
    from ..config.reference import write_reference
    print(write_reference(Path(args.out)))


def main(argv=None) -> int:
    from ..resources import builtin_scenarios
    ap = argparse.ArgumentParser(prog="nbvs", description="Next-best-view/state planning on a Drake diagram")
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("reconstruct", help="reconstruct the scenario's object; write model, metrics and plots")
    r.add_argument("--scenario", default=None,
                   help="scenario YAML or a built-in scenario's name (default: default); built-in: "
                        + ", ".join(builtin_scenarios()))
    r.add_argument("--out", default=None, help="output folder (default: results/<scenario name>)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace a finished run in the output folder (without it such a folder is refused)")
    r.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one scenario field, e.g. --set noise.sigma_w=0.14 --set planner.top_k=50 "
                        "(YAML value; repeatable; recorded in the run's scenario.yaml)")
    r.add_argument("--planner", default=None, metavar="MODULE:CLASS",
                   help="a plug-in planner (a class implementing the planner interface; a module in the current "
                        "folder or on PYTHONPATH, or an entry point of the group nbvs_drake.planners): "
                        "sets planner.strategy to !Plugin {entry: MODULE:CLASS}")
    r.add_argument("--quiet", action="store_true")
    r.add_argument("--meshcat", action="store_true",
                   help="show the run live in Meshcat (robot, map voxels, candidates, plan); prints the URL")
    r.add_argument("--meshcat-port", type=int, default=None,
                   help="Meshcat's port (default: the first free one from 7000)")
    r.set_defaults(func=_cmd_reconstruct)
    d = sub.add_parser("diagram", help="write the Graphviz wiring of a scenario's diagram")
    d.add_argument("--scenario", default=None, help="scenario YAML or built-in name (default: default)")
    d.add_argument("--out", default=None, help="output path without extension")
    d.add_argument("--all", action="store_true",
                   help="every built-in scenario (written into the repository's diagrams/ in a source checkout)")
    d.set_defaults(func=_cmd_diagram)
    b = sub.add_parser("bench", help="benchmarks, printing JSON")
    b.add_argument("what", choices=["visibility", "planning", "motion", "collision", "prediction", "oracle",
                                    "registration", "mission"])
    b.add_argument("--json", action="store_true", help="one line of JSON")
    b.add_argument("--views", type=int, default=400, help="views per timing batch")
    b.add_argument("--sensor", default="sr4000", choices=["sr4000", "kinect"],
                   help="visibility: the sensor (kinect: its planner model against every pixel)")
    b.add_argument("--max-scans", type=int, default=None,
                   help="mission: shorter missions (a quick look; the benchmark is the full ones)")
    b.set_defaults(func=lambda a: __import__("nbvs_drake.app.bench", fromlist=["main"]).main(a))
    e = sub.add_parser("experiment", help="run a paper's experiment (many runs) and write its table and figures",
                       description="nbvs experiment NAME... runs what is missing of each experiment into "
                                   "OUT/NAME/ (OUT/NAME_quick/ with --quick): runs/<run>/ per run, table.md, "
                                   "table.json and figures; finished runs are kept and skipped. "
                                   "`nbvs experiment --list` lists them; `nbvs experiment report` assembles "
                                   "docs/results.md from the tables.")
    e.add_argument("names", nargs="*", metavar="NAME",
                   help="experiment name(s) (see --list) or definition YAML files; or `report`")
    e.add_argument("--list", action="store_true", help="list the experiments: paper, table/figure, runs, cost")
    e.add_argument("--seeds", nargs="+", type=int, default=None, help="replace the definition's seeds")
    e.add_argument("--only", action="append", default=[], metavar="FACTOR=LABEL[,LABEL]",
                   help="run only the runs of these levels of a factor (repeatable; the table covers "
                        "every finished run), e.g. --only planner=nbvs --only approach=DU,EU-MU")
    e.add_argument("--quick", action="store_true", help="the definition's small version (minutes)")
    e.add_argument("--jobs", type=int, default=None, help="runs at a time (default: the number of cores)")
    e.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local processes (default) or Ray tasks")
    e.add_argument("--address", default=None, help="--executor ray: a running Ray cluster (default: a local one)")
    e.add_argument("--out", default=None, help="experiments folder (default: results/experiments)")
    e.add_argument("--retry-failed", action="store_true", help="rerun the runs that failed before")
    e.add_argument("--object", action="append", default=[], metavar="NAME=PATH",
                   help="one more object level (an OBJ/PLY/STL/OFF/GLB mesh) for experiments with an object factor")
    e.add_argument("--to", default=None, help="report: the markdown file (default: docs/results.md)")
    e.add_argument("--figures", default=None, metavar="DIR",
                   help="report: where the tables' figures are copied to and linked from "
                        "(default: the report's folder/figures/experiments)")
    e.add_argument("--table-only", action="store_true",
                   help="run nothing: write the table of the runs finished so far (e.g. of a stopped batch)")
    e.add_argument("--records", default=None, metavar="DIR",
                   help="run records (small files to keep in git): restore the runs recorded in "
                        "DIR/NAME/ that OUT lacks before running, record every finished run there")
    e.set_defaults(func=_cmd_experiment)
    k = sub.add_parser("benchmark", help="judge planners by a protocol (the robot, the view sphere) in one table",
                       description="nbvs benchmark PROTOCOL runs a protocol's planners, objects and seeds (as "
                                   "nbvs experiment runs an experiment: the local pool or Ray, records, --quick) "
                                   "into OUT/PROTOCOL/ and prints one table: AUC, coverage, of the ceiling, of "
                                   "the greedy oracle, Chamfer, F-score at 5 mm, distance, collisions, time per "
                                   "decision (OUT/PROTOCOL/benchmark.md and .json).")
    k.add_argument("protocol", nargs="?", metavar="PROTOCOL", help="robot or view_sphere (see --list)")
    k.add_argument("--list", action="store_true", help="list the protocols: runs and cost")
    k.add_argument("--planner", action="append", default=[], metavar="LABEL=MODULE:CLASS",
                   help="one more planner: a plug-in (repeatable), e.g. --planner mine=my_planner:Planner")
    k.add_argument("--quick", action="store_true", help="the protocol's small version (minutes)")
    k.add_argument("--seeds", nargs="+", type=int, default=None, help="replace the protocol's seeds")
    k.add_argument("--only", action="append", default=[], metavar="FACTOR=LABEL[,LABEL]",
                   help="run only these levels (the table covers every finished run), e.g. --only condition=open")
    k.add_argument("--jobs", type=int, default=None, help="runs at a time (default: the number of cores)")
    k.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local processes (default) or Ray tasks (a cluster with --address)")
    k.add_argument("--address", default=None, help="--executor ray: a running Ray cluster (default: a local one)")
    k.add_argument("--out", default=None, help="benchmarks folder (default: results/benchmarks)")
    k.add_argument("--retry-failed", action="store_true", help="rerun the runs that failed before")
    k.add_argument("--table-only", action="store_true", help="run nothing: the table of the runs finished so far")
    k.add_argument("--records", default=None, metavar="DIR",
                   help="run records: restore DIR/PROTOCOL/ first, record every finished run there")
    k.set_defaults(func=_cmd_benchmark)
    c = sub.add_parser("config-reference", help="write the configuration reference (docs/configuration.md)")
    c.add_argument("--out", default="docs/configuration.md", help="the markdown file (default: docs/configuration.md)")
    c.set_defaults(func=_cmd_config_reference)
    args = ap.parse_args(argv)
    try:
        args.func(args)
    except NbvsError as e:
        print(f"nbvs: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(f"nbvs: {e}" if str(e) else "nbvs: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
