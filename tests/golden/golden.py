"""Golden runs: the iteration records and summary of two pinned runs, with wall-clock times
removed, so that a change meant to reorganise the code (not what it computes) is checked to
the last digits (integers and strings exactly, floats to FLOAT_REL_TOL).
`.venv/bin/python tests/golden/golden.py` rewrites the files after a change that is meant to
change the numbers; say so in the commit message.

- default: the default scenario, seed 0, 12 scans (`make run`).
- teapot_eu_mu_4: the teapot_eu_mu scenario, seed 1, mission.max_scans = 4.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: name -> (scenario, seed, overrides)
RUNS = {
    "default": (None, 0, ()),
    "teapot_eu_mu_4": ("teapot_eu_mu", 1, ("mission.max_scans=4",)),
}

#: floats agree when equal to this relative tolerance: numpy's SIMD kernels sum in an order
#: that differs between CPUs (seen: teapot_eu_mu_4's expected utility, a weighted sum of 500
#: rollouts, differed in its last digit, 0.002559765005301889 against ...894, on one machine
#: of this workplace); any change of the planner moves the numbers far more than this
FLOAT_REL_TOL = 1e-9

#: simulated (not wall-clock) durations whose names end in _s
_SIMULATED = {"sim_time_s", "motion_sim_s"}


def is_wall_clock(key: str) -> bool:
    return key in ("times", "times_s") or (key.endswith(("_s", "_s_per_iteration")) and key not in _SIMULATED)


def strip_times(obj):
    """A copy of a JSON value without its wall-clock entries."""
    if isinstance(obj, dict):
        return {k: strip_times(v) for k, v in obj.items() if not is_wall_clock(k)}
    if isinstance(obj, list):
        return [strip_times(v) for v in obj]
    return obj


def load_run(out: Path) -> dict:
    records = [json.loads(line) for line in (out / "iterations.jsonl").read_text().splitlines() if line]
    return strip_times({"summary": json.loads((out / "summary.json").read_text()), "records": records})


def differences(golden, new, path="") -> list[str]:
    """Where `new` differs from `golden`: every key of golden must be in new with an equal
    value (floats: to FLOAT_REL_TOL; new keys are allowed: records may gain fields); lists
    must match element-wise."""
    if isinstance(golden, dict):
        if not isinstance(new, dict):
            return [f"{path}: expected an object"]
        out = []
        for k, v in golden.items():
            if k not in new:
                out.append(f"{path}.{k}: missing")
            else:
                out += differences(v, new[k], f"{path}.{k}")
        return out
    if isinstance(golden, list):
        if not isinstance(new, list) or len(new) != len(golden):
            return [f"{path}: expected a list of {len(golden)}"]
        return [d for i, (a, b) in enumerate(zip(golden, new)) for d in differences(a, b, f"{path}[{i}]")]
    if isinstance(golden, float) and isinstance(new, (int, float)) and not isinstance(new, bool):
        same = math.isclose(golden, new, rel_tol=FLOAT_REL_TOL, abs_tol=0.0)
        return [] if same else [f"{path}: {golden!r} != {new!r}"]
    return [] if golden == new else [f"{path}: {golden!r} != {new!r}"]


#: keys renamed on purpose since the files were written, (parent key, old name) -> new name
#: (e.g. {("factors", "sur"): "info"} while the files predated that rename); none now
RENAMED: dict = {}


def renamed(obj, parent: str = ""):
    """The golden value with the keys of RENAMED given their new names."""
    if isinstance(obj, dict):
        return {RENAMED.get((parent, k), k): renamed(v, k) for k, v in obj.items()}
    if isinstance(obj, list):
        return [renamed(v, parent) for v in obj]
    return obj


def golden_path(name: str) -> Path:
    return HERE / f"{name}.json"


def run(name: str, out: Path) -> dict:
    from nbvs_drake.app.mission import run_mission
    from nbvs_drake.config import load_scenario
    scenario, seed, overrides = RUNS[name]
    from nbvs_drake.resources import scenario_path  # noqa: F401 - built-in names
    sc = load_scenario(scenario_path(scenario) if scenario else None, seed=seed, settings=overrides)
    run_mission(sc, out, verbose=False)
    return load_run(out)


if __name__ == "__main__":
    import sys
    import tempfile
    names = sys.argv[1:] or list(RUNS)
    for n in names:
        with tempfile.TemporaryDirectory() as tmp:
            data = run(n, Path(tmp) / n)
        golden_path(n).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        print("wrote", golden_path(n))
