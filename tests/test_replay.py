"""The visual outputs of a run: paths.png, replay.html (self-contained Meshcat recording,
rendered by headless Chromium when it is installed) and the live Meshcat view."""

import json
import re

import numpy as np
import pytest
from conftest import small_scenario

from nbvs_drake.app.mission import run_mission
from nbvs_drake.outputs import meshcat_draw, replay, screenshot


def _small(scans=3):
    return small_scenario(0, scans, n_candidates=500, gt_points=5000)


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """A short mission shown live in a Meshcat (as `nbvs reconstruct --meshcat`)."""
    from pydrake.geometry import Meshcat, MeshcatParams
    out = tmp_path_factory.mktemp("replay_run")
    meshcat = Meshcat(MeshcatParams(host="localhost"))
    summary = run_mission(_small(), out, verbose=False, meshcat=meshcat)
    return out, summary, meshcat


def test_run_writes_paths_and_replay(live_run):
    out, _, _ = live_run
    assert (out / "paths.png").stat().st_size > 10_000
    size = (out / "replay.html").stat().st_size
    assert 1_000_000 < size < 8_000_000, size
    disk = json.loads((out / "summary.json").read_text())
    assert "visual_output_errors" not in disk
    assert disk["times_s"]["visual_outputs"] > 0


def test_replay_html_is_self_contained(live_run):
    out, _, _ = live_run
    html = (out / "replay.html").read_text()
    # nothing the page loads comes from the network: no script/link/img from http(s), and
    # every fetched command is a data: URL
    assert not re.search(r"""<(script|link|img|iframe)[^>]+(src|href)\s*=\s*["']?(https?:)?//""", html, re.IGNORECASE)
    fetched = re.findall(r"""fetch\(\s*["']([a-z]+):""", html)
    assert fetched and set(fetched) == {"data"}
    # the scene: robot, the maps of the three scans, a recording with visibility switches
    decoded = _decoded_commands(html)
    for path in ("/drake/robot", "/nbvs/map/1/unknown", "/nbvs/map/3/occupied", "/nbvs/plan/1", "/nbvs/wbox",
                 "/nbvs/model_mesh"):  # the reconstructed surface (model_mesh.ply) at the end
        assert path in decoded, path
    assert "set_animation" in decoded and "visible" in decoded
    assert "/nbvs/collision" not in decoded  # nothing collided


def _decoded_commands(html: str) -> str:
    """The page's Meshcat commands (base64 msgpack) decoded to text, roughly (for grepping)."""
    import base64
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return "\n".join(base64.b64decode(b).decode("latin-1") for b in blobs)


def test_live_view_drew_the_scene(live_run):
    _, _, meshcat = live_run
    assert meshcat.HasPath("/drake/robot")  # MeshcatVisualizer
    for path in ("/nbvs/map/unknown", "/nbvs/map/occupied", "/nbvs/wbox", "/nbvs/model_mesh"):  # MeshcatMapView
        assert meshcat.HasPath(path), path


def test_replay_and_paths_tolerate_old_records(live_run, tmp_path):
    """Records without the path fields (older iterations.jsonl) and no maps still give a
    replay (robot jumping between the scan poses) and a top view."""
    from nbvs_drake.outputs.plots import plot_paths
    out, _, _ = live_run
    recs = [json.loads(x) for x in (out / "iterations.jsonl").read_text().splitlines()]
    for r in recs:
        for key in ("executed_path", "corrected_state", "believed_state"):
            r.pop(key, None)
        for key in ("path", "candidates"):
            r["plan"].pop(key, None)
    sc = _small()
    info = replay.write_replay_html(tmp_path / "old.html", sc, recs, None)
    assert info["maps"] == 0 and (tmp_path / "old.html").stat().st_size > 1_000_000
    plot_paths(recs, tmp_path / "old_paths.png", sc.scene)
    assert (tmp_path / "old_paths.png").stat().st_size > 5_000


def test_map_voxel_centres_surface_only(live_run):
    from nbvs_drake.mapping.occupancy import OccupancyMap
    out, _, _ = live_run
    omap = OccupancyMap.load_npz(out / "map.npz")
    unk_all, occ = meshcat_draw.map_voxel_centres(omap, surface_only=False)
    unk, occ2 = meshcat_draw.map_voxel_centres(omap)
    assert 0 < len(unk) < len(unk_all) and len(occ) == len(occ2) > 0
    assert len(unk_all) == int(np.count_nonzero(omap.unknown_mask() & omap.in_wbox()))
    # centres lie in W_box and on the voxel lattice
    assert np.all(unk >= omap.wbox_min - 1e-9) and np.all(unk <= omap.wbox_max + 1e-9)
    k = (unk - omap.spec.bmin) / omap.spec.res - 0.5
    assert np.allclose(k, np.round(k), atol=1e-6)


@pytest.mark.skipif(screenshot.find_chromium() is None, reason="no chromium (Debian: apt-get install chromium)")
def test_replay_renders_in_headless_chromium(live_run, tmp_path):
    """The page renders offline in headless Chromium (software WebGL): the screenshot 2 s into
    the recording (map of scan 1 and its plan) shows the yellow unknown and blue occupied
    voxels among the scene's colours; the one at the end (robot moved, last map) differs."""
    from PIL import Image
    out, _, _ = live_run
    png = screenshot.screenshot_html(out / "replay.html", tmp_path / "replay_2s.png", at_s=2.0)
    c = screenshot.image_colours(png)
    assert c["yellow"] > 0.002 and c["blue"] > 0.0001 and c["distinct_colours"] > 40, c
    png_end = screenshot.screenshot_html(out / "replay.html", tmp_path / "replay_end.png", at_s="end")
    end = screenshot.image_colours(png_end)
    assert end["yellow"] > 0.002 and end["blue"] > 0.0001, end
    a, b = (np.asarray(Image.open(p).convert("RGB")).astype(int) for p in (png, png_end))
    changed = np.mean(np.abs(a - b).sum(axis=-1) > 60)
    assert changed > 0.01, changed


def test_paths_plot_draws_the_chairs_of_the_cluttered_room(tmp_path):
    """The top view shows every known obstacle: cluttered_room's nine chairs (seat and
    backrest each) beside the table, and none in the plain scene."""
    from nbvs_drake.config import load_scenario
    from nbvs_drake.outputs.plots import plot_paths
    room = load_scenario("cluttered_room")
    drawn = plot_paths([], tmp_path / "room.png", room.scene)
    assert sorted(drawn) == sorted([f"chair{k}_{part}" for k in (0, 1, 2, 3, 4, 6, 7, 8, 9)
                                    for part in ("seat", "back")])
    assert (tmp_path / "room.png").stat().st_size > 5_000
    assert plot_paths([], tmp_path / "plain.png", load_scenario("teapot_du").scene) == []
