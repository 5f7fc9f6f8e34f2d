"""Packaged data and the Python API: the models and built-in scenarios found through
`nbvs_drake.resources` (in the repository and in an installed wheel), scenarios by name,
`nbvs_drake.reconstruct` / `RunResult`, and the refusal to write over a finished run."""

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from conftest import small_scenario

import nbvs_drake
from nbvs_drake import resources
from nbvs_drake.app.api import OUTPUTS, RunResult, _prepare_output, reconstruct
from nbvs_drake.app.cli import main
from nbvs_drake.config import load_scenario
from nbvs_drake.errors import NbvsError, RunExistsError, ScenarioError

ROOT = Path(__file__).resolve().parents[1]
#: a two-scan run of the default scene, as `--set` overrides (small_scenario(scans=2, ...))
TINY = ["mission.max_scans=2", "planner.n_candidates=300", "scene.gt_points=3000"]


def _tiny():
    return small_scenario(scans=2, n_candidates=300, gt_points=3000)


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _strip(summary: dict) -> dict:
    from nbvs_drake.stage_clock import WALL_CLOCK_KEYS
    return {k: v for k, v in summary.items() if k not in WALL_CLOCK_KEYS}


# --------------------------------------------------------------------------------------
# resources, in this checkout (an editable install)
# --------------------------------------------------------------------------------------


def test_resources_come_from_the_repository_in_a_checkout():
    assert Path(nbvs_drake.__file__).resolve().parent == ROOT / "nbvs_drake"
    assert resources.source_checkout() == ROOT
    assert resources.models_dir() == ROOT / "models" and resources.diagrams_dir() == ROOT / "diagrams"
    assert resources.model_path("patrolbot_katana.urdf").is_file()
    assert resources.model_path("/abs/x.urdf") == Path("/abs/x.urdf")
    names = resources.builtin_scenarios()
    assert {"default", "teapot_du", "teapot_du_mu", "teapot_eu_mu", "cluttered_room"} <= set(names)
    assert list(names) == sorted(names) and names == {p.stem: p for p in sorted((ROOT / "diagrams").glob("*.yaml"))}
    assert resources.scenario_path(None) == ROOT / "diagrams" / "default.yaml"
    # the old names still answer, from the same place
    assert nbvs_drake.reconstruct is reconstruct and nbvs_drake.RunResult is RunResult


def test_scenario_by_name_path_or_neither(tmp_path, monkeypatch):
    p = resources.scenario_path("teapot_eu_mu")
    assert p == ROOT / "diagrams" / "teapot_eu_mu.yaml" == resources.scenario_path("teapot_eu_mu.yaml")
    assert load_scenario("teapot_eu_mu") == load_scenario(p) and load_scenario("teapot_eu_mu").name == "teapot_eu_mu"
    # a file wins over a built-in of the same name; a relative path is taken from the cwd
    monkeypatch.chdir(tmp_path)
    (tmp_path / "teapot_du").write_text("name: mine\n")
    assert load_scenario("teapot_du").name == "mine" and load_scenario("teapot_du").base_dir == str(tmp_path)
    for bad in ("teapot_eu", "diagrams/teapot_eu_mu.yaml", tmp_path / "none.yaml"):
        with pytest.raises(ScenarioError) as e:
            resources.scenario_path(bad)
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith(f"scenario file not found: {bad}")
        assert "built-in: cluttered_room, cluttered_room_nbvs, default, real_robot, real_robot_humanoid, " \
            "real_robot_obstacles, teapot_du, teapot_du_mu, teapot_eu_mu, teapot_eu_mu_nbvs" in msg


def test_relative_mesh_paths_resolve_against_the_scenario_folder(tmp_path, monkeypatch):
    from nbvs_drake.world.objects import build_object, tessellate_teapot
    (tmp_path / "scn" / "meshes").mkdir(parents=True)
    tessellate_teapot(4).write_obj(tmp_path / "scn" / "meshes" / "pot.obj")
    (tmp_path / "scn" / "pot.yaml").write_text(
        "name: pot\nscene:\n  object: {kind: mesh, mesh: meshes/pot.obj, size: 0.3}\n")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    sc = load_scenario("../scn/pot.yaml")
    assert sc.base_dir == str(tmp_path / "scn")
    lo, hi = build_object(sc).bounds
    assert max(hi - lo) == pytest.approx(0.3)


# --------------------------------------------------------------------------------------
# reconstruct() and RunResult
# --------------------------------------------------------------------------------------


def test_prepare_output_refuses_a_finished_run_and_clears_an_unfinished_one(tmp_path):
    done = tmp_path / "done"
    done.mkdir()
    for name in ("summary.json", "iterations.jsonl", "notes.txt"):
        (done / name).write_text("{}\n")
    before = _snapshot(done)
    with pytest.raises(RunExistsError) as e:
        _prepare_output(done, overwrite=False)
    assert str(done) in str(e.value) and "\n" not in str(e.value) and isinstance(e.value, NbvsError)
    assert _snapshot(done) == before
    half = tmp_path / "half"  # a killed run: records, no summary
    half.mkdir()
    for name in ("scenario.yaml", "iterations.jsonl", "replay.html", "notes.txt"):
        (half / name).write_text("x\n")
    _prepare_output(half, overwrite=False)
    assert sorted(p.name for p in half.iterdir()) == ["notes.txt"]  # only the run's own files go
    _prepare_output(done, overwrite=True)
    assert sorted(p.name for p in done.iterdir()) == ["notes.txt"]
    _prepare_output(tmp_path / "new", overwrite=False)  # a folder that is not there yet
    with pytest.raises(NbvsError, match="no finished run"):
        RunResult.load(half)


def test_reconstruct_returns_a_run_result_refuses_a_finished_folder_and_overwrites(tmp_path, capsys):
    out = tmp_path / "run"
    sc = _tiny()
    r = reconstruct(sc, out=out)
    assert sc == _tiny()  # the caller's scenario is not changed
    assert r.out == out and r.summary == json.loads((out / "summary.json").read_text())
    assert r.summary["scans"] == 2 == len(r.records) and [x["iteration"] for x in r.records] == [1, 2]
    assert set(r.paths) == set(OUTPUTS) and all(p.is_file() and p.parent == out for p in r.paths.values())
    assert RunResult.load(out) == r
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.out = tmp_path

    (out / "notes.txt").write_text("mine\n")
    before = _snapshot(out)
    with pytest.raises(RunExistsError, match=str(out)):
        reconstruct(sc, out=out)
    rc = main(["reconstruct", "--out", str(out), "--quiet", *sum((["--set", s] for s in TINY), [])])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("nbvs: error: ") and str(out) in err
    assert "--overwrite" in err
    assert _snapshot(out) == before  # byte for byte, not even touched

    rc = main(["reconstruct", "--out", str(out), "--quiet", "--overwrite", *sum((["--set", s] for s in TINY), [])])
    assert rc == 0
    again = RunResult.load(out)
    assert _strip(again.summary) == _strip(r.summary) and again.summary["wall_s"] != r.summary["wall_s"]
    assert (out / "notes.txt").read_text() == "mine\n"


def test_reconstruct_default_out_is_results_scenario_name(tmp_path, monkeypatch):
    """out=None: results/<scenario name> under the cwd; a finished one there is refused
    before anything runs (the scenario is loaded first: its name gives the folder)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "default").mkdir(parents=True)
    (tmp_path / "results" / "default" / "summary.json").write_text("{}")
    with pytest.raises(RunExistsError, match="results/default"):
        reconstruct(overrides="mission.max_scans=2")
    with pytest.raises(ScenarioError, match="built-in: "):
        reconstruct("no_such_scenario")


# --------------------------------------------------------------------------------------
# the wheel, installed into a fresh virtual environment outside the repository
# --------------------------------------------------------------------------------------


def _data_files(folder: str) -> list[str]:
    base = ROOT / folder
    return sorted(str(p.relative_to(base)) for p in base.rglob("*")
                  if p.is_file() and "__pycache__" not in p.parts and not p.name.startswith("."))


@pytest.fixture(scope="module")
def fresh_venv(tmp_path_factory):
    """Builds the wheel from a copy of the source (so no build/ or egg-info lands in the
    repository) with this venv's setuptools (no build isolation: offline), and installs it
    with --no-deps into a new venv; the heavy dependencies (drake, open3d, numba) come from
    this venv through a .pth file, so the only nbvs_drake there is the wheel's."""
    import setuptools
    if int(setuptools.__version__.split(".")[0]) < 77:
        pytest.skip(f"setuptools {setuptools.__version__} < 77 in this venv (make setup installs a newer one)")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("nbvs_drake", "models", "diagrams"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheels = tmp / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                    "--no-index", "-w", str(wheels), str(src)], check=True, cwd=tmp)
    (wheel,) = wheels.glob("nbvs_drake-*.whl")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    Path(site, "_nbvs_test_deps.pth").write_text("".join(f"{d}\n" for d in sorted(deps)))
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps",
                    "--no-index", str(wheel)], check=True)
    work = tmp / "work"  # the cwd of every command: no repository in sight
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    return {"wheel": wheel, "python": py, "bin": venv / "bin", "site": Path(site), "cwd": work, "env": env}


def _run(v, *cmd, check=True):
    return subprocess.run([str(c) for c in cmd], cwd=v["cwd"], env=v["env"], capture_output=True, text=True,
                          check=check, timeout=600)


def test_wheel_ships_every_model_and_scenario_and_finds_them_outside_the_repository(fresh_venv):
    import zipfile
    v = fresh_venv
    names = zipfile.ZipFile(v["wheel"]).namelist()
    for folder in ("models", "diagrams"):
        shipped = sorted(n[len(f"nbvs_drake/{folder}/"):] for n in names if n.startswith(f"nbvs_drake/{folder}/"))
        assert shipped == _data_files(folder), folder
    pkgs = {str(p.parent.relative_to(ROOT)).replace("/", ".") for p in (ROOT / "nbvs_drake").rglob("*.py")
            if "__pycache__" not in p.parts}
    assert pkgs <= {n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith(".py")}
    probe = """
import json, nbvs_drake
from nbvs_drake import resources
from nbvs_drake.config import load_scenario
from nbvs_drake.world.objects import build_object
from nbvs_drake.world.robot import RobotKinematics
sc = load_scenario("teapot_eu_mu")
RobotKinematics()  # parses the shipped URDF
print(json.dumps({"file": nbvs_drake.__file__, "models": str(resources.models_dir()),
                  "checkout": resources.source_checkout() is not None, "names": list(resources.builtin_scenarios()),
                  "base_dir": sc.base_dir, "object_points": len(build_object(sc).vertices)}))
"""
    got = json.loads(_run(v, v["python"], "-c", probe).stdout)
    assert Path(got["file"]).parent == v["site"] / "nbvs_drake"
    assert got["models"] == str(v["site"] / "nbvs_drake" / "models") and not got["checkout"]
    assert got["names"] == list(resources.builtin_scenarios())
    assert got["base_dir"] == str(v["site"] / "nbvs_drake" / "diagrams") and got["object_points"] > 100
    bad = _run(v, v["bin"] / "nbvs", "reconstruct", "--scenario", "teapot_eu", check=False)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1
    assert "built-in: cluttered_room, cluttered_room_nbvs, default" in bad.stderr
    assert not (v["cwd"] / "results").exists()


@pytest.mark.slow
def test_wheel_reconstructs_by_name_with_the_cli_and_the_api(fresh_venv):
    """Two-scan runs from the installed wheel (cwd outside the repository): the CLI by
    scenario name, into the default results/<name>; and the Python API, whose numbers are the
    repository's. 60-90 s (slow: the first run there compiles the numba kernels afresh, their
    cache sitting beside the installed modules); the test above is its quick variant."""
    v = fresh_venv
    sets = [a for s in TINY for a in ("--set", s)]
    _run(v, v["bin"] / "nbvs", "reconstruct", "--scenario", "teapot_du", "--quiet", *sets)
    cli = json.loads((v["cwd"] / "results" / "teapot_du" / "summary.json").read_text())
    assert cli["scenario"] == "teapot_du" and cli["scans"] == 2
    api = f"""
import json, nbvs_drake
r = nbvs_drake.reconstruct("default", out="api_run", overrides={TINY!r})
print(json.dumps({{"summary": r.summary, "paths": sorted(r.paths), "records": len(r.records)}}))
"""
    got = json.loads(_run(v, v["python"], "-c", api).stdout.splitlines()[-1])
    assert got["paths"] == sorted(OUTPUTS) and got["records"] == 2
    # the same numbers as the same run from the repository
    here = reconstruct(_tiny(), out=v["cwd"].parent / "here")
    assert _strip(got["summary"]) == _strip(here.summary)


def test_a_changed_kernel_source_drops_the_cached_kernels(tmp_path):
    """numba keys a cached kernel on its own file only; kernel_cache.drop_stale removes every
    cached kernel when any kernel module changed (a caller in one module inlines a callee in
    another), and keeps them while the kernel modules stand."""
    from nbvs_drake.kernel_cache import drop_stale
    root = tmp_path / "pkg"
    cache = root / "sub" / "__pycache__"
    cache.mkdir(parents=True)
    kernel, plain = root / "sub" / "k.py", root / "plain.py"
    kernel.write_text("@nb.njit(cache=True)\ndef f():\n    return 1\n")
    plain.write_text("x = 1\n")
    cached = [cache / "k.f-2.py311.nbi", cache / "k.f-2.py311.1.nbc"]

    def fill():
        for f in cached:
            f.write_text("")

    fill()
    assert drop_stale(root) and not any(f.exists() for f in cached)  # no stamp yet
    fill()
    assert not drop_stale(root) and all(f.exists() for f in cached)  # the same sources
    plain.write_text("x = 22\n")
    assert not drop_stale(root) and all(f.exists() for f in cached)  # not a kernel module
    kernel.write_text("@nb.njit(cache=True)\ndef f():\n    return 22\n")
    assert drop_stale(root) and not any(f.exists() for f in cached)
