"""Bad input gets a one-line error naming the problem (exit code 2), never a traceback."""
import numpy as np
import pytest

from nbvs_drake.app.cli import main
from nbvs_drake.config import Scenario, load_scenario, resolve_sensor, validate
from nbvs_drake.errors import MeshError
from nbvs_drake.world.objects import build_object, tessellate_teapot


def _cli_error(capsys, tmp_path, yaml_text, name="bad.yaml"):
    p = tmp_path / name
    p.write_text(yaml_text)
    rc = main(["reconstruct", "--scenario", str(p), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith("nbvs: error: ")
    return err


@pytest.mark.parametrize("yaml_text, expect", [
    ("planner:\n  n_candidats: 10\n", "n_candidats"),
    ("nosuchsection: 1\n", "nosuchsection"),
    ("noise:\n  sigma_v: -0.1\n", "noise.sigma_v must be >= 0"),
    ("noise:\n  sigma_arm: [0, 0, -1, 0, 0]\n", "noise.sigma_arm"),
    ("planner:\n  overlap_h: 1.5\n", "planner.overlap_h (h) must be in [0, 1]"),
    ("mission:\n  max_scans: 0\n", "mission.max_scans must be >= 1"),
    ("mapper:\n  voxel_size: 0\n", "mapper.voxel_size must be > 0"),
    ("scene:\n  bbox_min: [0, 0, 1]\n  bbox_max: [1, 1, 0.5]\n", "bounding box is empty"),
    ("robot:\n  start: [0, 0, 0]\n", "robot.start must be 8"),
    ("sensor:\n  preset: lidar\n", "sensor.preset"),
    ("scene:\n  object:\n    kind: mesh\n    mesh: nowhere/bunny.ply\n", "object mesh not found"),
    ("scene:\n  object:\n    size: 0.9\n", "does not fit in the bounding box W_box"),
    ("scene: [1, 2\n", "malformed scenario"),
    ("localisation:\n  method: gps\n", "localisation.method must be 'icp' or 'none'"),
    ("mission:\n  relocalization: gps\n", "localisation.method must be 'icp' or 'none'"),  # the old schema, migrated
    ("mission:\n  on_collision: ignore\n", "mission.on_collision must be 'stop' or 'continue'"),
    ("mission:\n  stop_min_surface: 1.5\n", "mission.stop_min_surface must be in [0, 1)"),
    ("mission:\n  stop_unknown_voxels: -3\n", "mission.stop_unknown_voxels must be >= 0"),
    ("localisation:\n  verified_views:\n    recovery_rollouts: -1\n",
     "localisation.verified_views.recovery_rollouts must be >= 0"),
    ("planner:\n  evaluator: !Hrt {a: 2, occluders: true}\n", "occluders"),  # only the exact evaluator's
    ("planner:\n  evaluator: !Hrt {a: 7}\n", "planner.evaluator.a must be in 1..4"),
    ("planner:\n  hrt_a: 9\n", "planner.evaluator.a must be in 1..4"),  # the old schema, migrated
    ("planner:\n  strategy: !Circle {}\n", "Circle"),
    ("planner:\n  utility: !Expected {samples: 0}\n", "planner.utility.samples must be >= 1"),
    ("noise:\n  perturb_zero_commands: true\n", "noise.perturb_zero_commands was removed"),
])
def test_bad_scenarios_get_one_line_errors(capsys, tmp_path, yaml_text, expect):
    err = _cli_error(capsys, tmp_path, yaml_text)
    assert expect in err


def test_settings_override_fields_through_the_typed_schema():
    """`nbvs reconstruct --set section.field=value`: the value is YAML, loaded into the same
    typed dataclasses as the file; the other fields keep the file's values."""
    base = load_scenario("teapot_eu_mu")  # a built-in scenario, by name
    sc = load_scenario("teapot_eu_mu", seed=4,
                       settings=["noise.sigma_w=0.14", "planner.top_k=50", "noise.sigma_arm=[0.01, 0, 0, 0, 0]",
                                 "name=teapot_eu_mu_w014"])
    assert (sc.noise.sigma_w, sc.planner.top_k, sc.noise.sigma_arm[0], sc.name, sc.seed) == \
        (0.14, 50, 0.01, "teapot_eu_mu_w014", 4)
    assert sc.noise.sigma_v == base.noise.sigma_v and sc.planner.utility.samples == base.planner.utility.samples == 500
    assert sc.base_dir == base.base_dir and sc.scene == base.scene


@pytest.mark.parametrize("setting, expect", [
    ("noise.sigma_x=1", "sigma_x"),
    ("noise.sigma_w=abc", "could not convert"),
    ("planner.top_k=1.5", "top_k"),
    ("noise.sigma_w", "expected section.field=value"),
    ("noise.sigma_w=-1", "noise.sigma_w must be >= 0"),
])
def test_bad_settings_get_one_line_errors(capsys, tmp_path, setting, expect):
    rc = main(["reconstruct", "--set", setting, "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("nbvs: error: ")
    assert expect in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_missing_scenario_file(capsys, tmp_path):
    rc = main(["reconstruct", "--scenario", str(tmp_path / "none.yaml")])
    assert rc == 2 and "scenario file not found" in capsys.readouterr().err


def test_scenario_by_builtin_name():
    """`--scenario teapot_eu_mu`: a built-in scenario by name (with or without .yaml), the
    same as its file; its relative paths resolve against the built-in scenarios' folder."""
    from nbvs_drake.resources import diagrams_dir, scenario_path
    sc = load_scenario("teapot_eu_mu")
    assert sc == load_scenario(diagrams_dir() / "teapot_eu_mu.yaml") == load_scenario("teapot_eu_mu.yaml")
    assert sc.name == "teapot_eu_mu" and sc.base_dir == str(diagrams_dir())
    assert scenario_path(None) == scenario_path("default") and load_scenario(None) == load_scenario("default")


def test_unknown_scenario_name_lists_the_builtin_ones(capsys, tmp_path):
    rc = main(["reconstruct", "--scenario", "teapot_eu", "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("nbvs: error: scenario file not found: teapot_eu (neither a file nor a built-in scenario")
    assert err.endswith("built-in: cluttered_room, cluttered_room_nbvs, default, real_robot, real_robot_humanoid, "
                        "real_robot_obstacles, teapot_du, teapot_du_mu, teapot_eu_mu, teapot_eu_mu_nbvs)")
    assert not (tmp_path / "out").exists()


def test_unreadable_mesh(tmp_path, capsys):
    bad = tmp_path / "broken.ply"
    bad.write_text("this is not a mesh\n")
    err = _cli_error(capsys, tmp_path, f"scene:\n  object:\n    kind: mesh\n    mesh: {bad}\n")
    assert "broken.ply" in err and ("unreadable" in err or "cannot read" in err)


def test_defaults_and_presets():
    sc = load_scenario()
    assert sc.name == "default" and sc.mission.max_scans == 12
    s = resolve_sensor(sc.sensor)
    assert (s.width, s.height, s.fov_x_deg, s.fov_y_deg, s.z_near, s.z_far) == (176, 144, 43.6, 34.6, 0.4, 5.0)
    k = Scenario()
    k.sensor.preset = "kinect"
    s = resolve_sensor(k.sensor)
    assert (s.width, s.height, s.noise_a, s.noise_b) == (640, 480, 0.0012, 0.0019)
    assert Scenario().noise.sigma_w == 0.28 and Scenario().noise.sigma_v == 0.00165  # Table 4


def test_mesh_object_from_file(tmp_path):
    # write the teapot as an OBJ and load it back as a "mesh" object, scaled by `size`
    tp = tessellate_teapot(6)
    tp.write_obj(tmp_path / "pot.obj")
    sc = Scenario(base_dir=str(tmp_path))
    sc.scene.object.kind = "mesh"
    sc.scene.object.mesh = "pot.obj"
    sc.scene.object.size = 0.3
    validate(sc)
    mesh = build_object(sc)
    lo, hi = mesh.bounds
    assert max(hi - lo) == pytest.approx(0.3)
    assert lo[2] == pytest.approx(sc.scene.table_height)
    with pytest.raises(MeshError):
        sc.scene.object.mesh = "missing.obj"
        build_object(sc)


def test_teapot_tessellation():
    m = tessellate_teapot(8)
    lo, hi = m.bounds
    np.testing.assert_allclose(hi[2] - lo[2], 3.15, atol=1e-9)  # Newell's height
    assert len(m.triangles) > 32 * 8 * 8 * 1.5


def test_paths_users_take_end_in_one_line(tmp_path, capsys):
    """--out naming an existing file, a --records folder that cannot be written."""
    f = tmp_path / "afile"
    f.write_text("x")
    assert main(["reconstruct", "--out", str(f), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"nbvs: error: output folder {f} is a file, not a folder; choose another --out"
    assert f.read_text() == "x"
    assert main(["experiment", "objects", "--quick", "--records", str(f), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nbvs: error: the records folder {f}/objects_quick cannot be written")


def test_a_verbose_run_prints_its_scans_and_no_library_chatter(tmp_path):
    """`nbvs reconstruct` without --quiet: one line per scan on stdout, and neither Drake's
    INFO lines (one per plan's collision checker) nor numba's threading-layer note."""
    import subprocess
    import sys
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "nbvs_drake.app.cli", "reconstruct", "--out", str(out),
                        "--set", "mission.max_scans=2", "--set", "planner.n_candidates=300",
                        "--set", "scene.gt_points=3000"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert [ln.split()[1] for ln in p.stdout.splitlines() if ln.startswith("scan ")] == ["1", "2"]
    assert "INFO:drake" not in p.stderr and "TBB" not in p.stderr, p.stderr[-2000:]
