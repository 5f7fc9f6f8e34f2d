"""Planners as plug-ins (nbvs_drake.planning.plugins), and a gym policy as a planner."""

import json
from pathlib import Path

import pytest

from nbvs_drake.errors import ScenarioError

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"
QUICK = ["mission.max_scans=3", "scene.gt_points=4000", "mission.coverage_ceiling=false"]
EXAMPLE = 'planner.strategy=!Plugin {entry: "nearest_unknown_planner:NearestUnknownPlanner", options: {samples: "300"}}'


def test_the_documented_example_plugin_runs_and_its_record_re_runs(tmp_path, monkeypatch):
    from nbvs_drake.app.api import reconstruct
    monkeypatch.syspath_prepend(str(EXAMPLES))
    run = reconstruct(None, tmp_path / "a", seed=2, overrides=QUICK + [EXAMPLE])
    s = run.summary
    assert s["planner"] == "plugin:nearest_unknown_planner:NearestUnknownPlanner"
    assert s["scans"] == 3 and s["coverage"] > 0.4 and s["distance"] > 0
    # its scenario.yaml names the plugin and its options: the run repeats from it
    again = reconstruct(str(tmp_path / "a" / "scenario.yaml"), tmp_path / "b")
    assert again.summary["coverage"] == s["coverage"] and again.summary["distance"] == s["distance"]


def test_the_cli_takes_a_plugin_by_its_entry(tmp_path):
    import subprocess
    import sys
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "nbvs_drake.app.cli", "reconstruct", "--planner",
                        "nearest_unknown_planner:NearestUnknownPlanner", "--out", str(out), "--quiet",
                        *[a for q in QUICK[:1] + ["mission.max_scans=2"] for a in ("--set", q)]],
                       cwd=EXAMPLES, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((out / "summary.json").read_text())["planner"].startswith("plugin:nearest_unknown")


def test_a_policy_wrapped_as_a_planner_and_the_planner_as_a_policy_give_the_planners_run(tmp_path):
    """The round trip: PolicyPlanner asking first_candidate (the scenario planner's own
    choice) runs exactly the mission of the built-in planner."""
    from nbvs_drake.app.api import reconstruct
    plain = reconstruct(None, tmp_path / "plain", seed=3, overrides=QUICK).summary
    wrapped = reconstruct(None, tmp_path / "wrapped", seed=3, overrides=QUICK + [
        'planner.strategy=!Plugin {entry: "nbvs_drake.gym.policy:PolicyPlanner", '
        'options: {policy: "nbvs_drake.gym.policy:first_candidate"}}']).summary
    assert wrapped["coverage"] == plain["coverage"] and wrapped["distance"] == plain["distance"]


BAD = '''
import numpy as np
from nbvs_drake.planning import PlanResult

class NoPlan:
    def __init__(self, parts):
        pass

class Garbage:
    def __init__(self, parts, width=1):
        self.width = width
    def plan(self, request):
        return PlanResult("ok", np.zeros(8), np.zeros((3, self.width)), np.zeros((4, 8)))
'''


@pytest.mark.parametrize("entry, options, message", [
    ("nosuch_module:Planner", "", "could not be imported: ModuleNotFoundError"),
    ("bad_plugins:Missing", "", "has no 'Missing'"),
    ("bad_plugins:NoPlan", "", "has no plan(request) method"),
    ("bad_plugins:Garbage", ", options: {height: '2'}", "cannot be built with the options ['height']"),
    ("bad_plugins:Garbage", "", "a plan has controls (m, 7)"),
    ("no_such_entry_point", "", "nor an entry point of the group nbvs_drake.planners"),
])
def test_a_broken_plugin_is_one_line_naming_it(tmp_path, monkeypatch, entry, options, message):
    from nbvs_drake.app.api import reconstruct
    (tmp_path / "bad_plugins.py").write_text(BAD)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ScenarioError) as e:
        reconstruct(None, tmp_path / "run",
                    overrides=QUICK + [f'planner.strategy=!Plugin {{entry: "{entry}"{options}}}'])
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_plugin_needs_its_entry():
    from nbvs_drake.config import load_scenario
    with pytest.raises(ScenarioError, match="needs its entry"):
        load_scenario(None, settings=["planner.strategy=!Plugin {}"])
