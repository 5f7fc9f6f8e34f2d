"""`replay.html`: a self-contained Meshcat recording of a run that opens in a browser with no
server (Drake's `Meshcat.StaticHtml`).

The recording shows the robot (MeshcatVisualizer over a MultibodyPlant + SceneGraph of the
robot, the table and the object) moving along the executed (true) paths; after each scan the
map of that scan (unknown voxels of W_box as yellow dots, occupied voxels blue; only the
unknown voxels on the surface of the unknown region are drawn: the others are hidden behind
them), the candidate views the planner kept (camera positions coloured by utility rank,
cyan to magenta, optical axes as short segments), the chosen view (red sphere and axis) and
the planned path (red: base on the floor and camera). The executed base paths stay drawn as
a green trail. A run stopped by a collision ends with the robot moving along the colliding
trajectory's executed part (a dark red trail) to the pose where it collided, marked by a red
cross on the floor. Every overlay is a Meshcat object whose "visible" property is switched in the
recording. Motions are replayed `speedup` times faster than simulated (at most
`max_motion_s` each); the robot waits while a map and a plan are shown.

A script appended to the page opens it paused at a moment: `replay.html#t=12.5`, `#t=end`
(`screenshot_html` uses it). The same drawing helpers serve the live view
(`systems/meshcat_map_view.py`).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from .mapping.occupancy import OCCUPIED, UNKNOWN, OccupancyMap

UNKNOWN_RGBA = (1.0, 0.85, 0.05, 1.0)
OCCUPIED_RGBA = (0.1, 0.3, 1.0, 1.0)
#: unknown voxels are drawn as dots of this share of the voxel size: the occupied voxels and
#: the object show through the gaps
UNKNOWN_POINT_SCALE = 0.4
PLAN_RGBA = (0.9, 0.1, 0.1, 1.0)
TRAIL_RGBA = (0.05, 0.6, 0.2, 1.0)
COLLISION_RGBA = (0.55, 0.0, 0.0, 1.0)
GOAL_RGBA = (0.9, 0.05, 0.05, 1.0)
CANDIDATE_AXIS_RGBA = (0.25, 0.25, 0.3, 1.0)
WBOX_RGBA = (0.3, 0.3, 0.3, 1.0)
ROOT = "/nbvs"

# default viewpoint: behind and above the robot's start side, framing the table and the
# ring the robot drives on
CAMERA_POSITION = (-1.9, -1.6, 1.7)
CAMERA_TARGET = (0.0, 0.0, 0.35)


def _rgba(c):
    from pydrake.geometry import Rgba
    return Rgba(*c)


# ---- map voxels ---------------------------------------------------------------------------

def map_voxel_centres(omap: OccupancyMap, surface_only: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(unknown, occupied) voxel centres (N, 3) of W_box. With `surface_only` the unknown
    voxels are only those with a 6-neighbour outside the unknown region of W_box (the rest
    cannot be seen behind them)."""
    cls = omap.classes()
    inside = omap.in_wbox()
    unk = (cls == UNKNOWN) & inside
    occ = (cls == OCCUPIED) & inside
    if surface_only:
        p = np.pad(unk, 1, constant_values=False)
        interior = (p[2:, 1:-1, 1:-1] & p[:-2, 1:-1, 1:-1] & p[1:-1, 2:, 1:-1] & p[1:-1, :-2, 1:-1]
                    & p[1:-1, 1:-1, 2:] & p[1:-1, 1:-1, :-2])
        unk = unk & ~interior
    res = omap.spec.res
    bmin = np.asarray(omap.spec.bmin, float)

    def centres(mask):
        return bmin + (np.argwhere(mask) + 0.5) * res

    return centres(unk), centres(occ)


def _cloud(points: np.ndarray, rgb: np.ndarray | None = None):
    from pydrake.perception import BaseField, Fields, PointCloud
    fields = BaseField.kXYZs | (BaseField.kRGBs if rgb is not None else 0)
    pc = PointCloud(len(points), Fields(fields))
    if len(points):
        pc.mutable_xyzs()[:] = np.asarray(points, np.float32).T
        if rgb is not None:
            pc.mutable_rgbs()[:] = np.asarray(rgb, np.uint8).T
    return pc


def set_map_objects(meshcat, path: str, omap: OccupancyMap):
    """Unknown (yellow) and occupied (blue) voxels of `omap` as point clouds at path/unknown
    and path/occupied (points of one voxel size). Returns (n_unknown drawn, n_occupied)."""
    unk, occ = map_voxel_centres(omap)
    size = float(omap.spec.res)
    meshcat.SetObject(f"{path}/unknown", _cloud(unk), UNKNOWN_POINT_SCALE * size, _rgba(UNKNOWN_RGBA))
    meshcat.SetObject(f"{path}/occupied", _cloud(occ), size, _rgba(OCCUPIED_RGBA))
    return len(unk), len(occ)


# ---- plan overlays ------------------------------------------------------------------------

def _states(seq) -> np.ndarray:
    a = np.asarray(seq if seq is not None else [], float)
    return a.reshape(-1, 8) if a.size else np.zeros((0, 8))


def _utility_colours(g: np.ndarray) -> np.ndarray:
    """uint8 RGB from a cyan-to-magenta ramp of the utilities' ranks."""
    import matplotlib
    if len(g) == 0:
        return np.zeros((0, 3), np.uint8)
    order = np.argsort(np.argsort(g))
    t = order / max(len(g) - 1, 1)
    rgb = matplotlib.colormaps["cool"](t)[:, :3]
    return (255 * rgb).astype(np.uint8)


def set_plan_objects(meshcat, path: str, plan: dict, kin) -> dict:
    """The candidates (path/candidates: camera positions coloured by utility and their optical
    axes), the chosen view (path/goal) and the planned path (path/plan_base on the floor,
    path/plan_camera) of one plan report. Returns what was drawn."""
    from pydrake.geometry import Sphere
    from pydrake.math import RigidTransform
    drawn = {}
    cands = plan.get("candidates") or []
    Q = _states([c["q"] for c in cands if "q" in c])
    if len(Q):
        g = np.array([float(c.get("g", 0.0)) for c in cands if "q" in c])
        X = kin.camera_poses(Q)
        p = X[:, :3, 3]
        meshcat.SetObject(f"{path}/candidates/cameras", _cloud(p, _utility_colours(g)), 0.045, _rgba((1, 1, 1, 1)))
        meshcat.SetLineSegments(f"{path}/candidates/axes", p.T.copy(), (p + 0.15 * X[:, :3, 2]).T.copy(),
                                1.0, _rgba(CANDIDATE_AXIS_RGBA))
        drawn["candidates"] = len(Q)
    goal = plan.get("q_goal")
    if goal is not None and plan.get("status", "ok") == "ok":
        X = kin.camera_poses(_states([goal]))[0]
        meshcat.SetObject(f"{path}/goal/sphere", Sphere(0.03), _rgba(GOAL_RGBA))
        meshcat.SetTransform(f"{path}/goal/sphere", RigidTransform(X[:3, 3]))
        meshcat.SetLineSegments(f"{path}/goal/axis", X[:3, 3:4].copy(), (X[:3, 3] + 0.25 * X[:3, 2])[:, None].copy(),
                                3.0, _rgba(GOAL_RGBA))
        drawn["goal"] = 1
    states = _states(plan.get("path"))
    if len(states) >= 2:
        base = np.c_[states[:, :2], np.full(len(states), 0.01)]
        meshcat.SetLine(f"{path}/plan_base", base.T.copy(), 3.0, _rgba(PLAN_RGBA))
        cam = kin.camera_poses(states)[:, :3, 3]
        meshcat.SetLine(f"{path}/plan_camera", cam.T.copy(), 2.0, _rgba(PLAN_RGBA))
        drawn["plan_states"] = len(states)
    return drawn


def set_wbox(meshcat, path: str, lo, hi):
    """W_box as a wireframe (12 edges)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array([[(hi if (i >> a) & 1 else lo)[a] for a in range(3)] for i in range(8)])
    edges = [(i, i | (1 << a)) for i in range(8) for a in range(3) if not (i >> a) & 1]
    s = np.array([c[i] for i, _ in edges]).T.copy()
    e = np.array([c[j] for _, j in edges]).T.copy()
    meshcat.SetLineSegments(path, s, e, 2.0, _rgba(WBOX_RGBA))


def set_default_view(meshcat):
    meshcat.SetProperty("/Axes", "visible", False)
    meshcat.SetCameraPose(np.array(CAMERA_POSITION), np.array(CAMERA_TARGET))


# ---- the recording ------------------------------------------------------------------------

def _resample(states: np.ndarray, n: int) -> np.ndarray:
    """n states evenly spaced in index along a path (theta unwrapped first)."""
    s = states.copy()
    s[:, 2] = np.unwrap(s[:, 2])
    if len(s) == 1:
        return np.repeat(s, n, axis=0)
    u = np.linspace(0, len(s) - 1, n)
    return np.stack([np.interp(u, np.arange(len(s)), s[:, j]) for j in range(s.shape[1])], axis=1)


def compact_obj(src, dst) -> Path:
    """A smaller copy of an OBJ for the page: vertices at 0.01 mm, faces without normals
    (three.js computes them), nothing else. Returns `dst`."""
    verts, faces = [], []
    with open(src) as f:
        for line in f:
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                idx = [w.split("/")[0] for w in line.split()[1:]]
                faces.extend(f"f {idx[0]} {idx[j]} {idx[j + 1]}" for j in range(1, len(idx) - 1))
    V = np.asarray(verts, float)
    with open(dst, "w") as f:
        f.write("\n".join(f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in V))
        f.write("\n" + "\n".join(faces) + "\n")
    return Path(dst)


def _robot_visualizer(sc, meshcat, obj_mesh_path):
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from .robot import add_robot, state_to_positions_index
    from .scene import add_environment

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    add_robot(plant, sc.robot.urdf)
    add_environment(plant, sc, object_obj=str(obj_mesh_path) if obj_mesh_path else None, collision=False)
    plant.Finalize()
    MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                   MeshcatVisualizerParams(role=Role.kIllustration, prefix="robot"))
    diagram = builder.Build()
    return diagram, plant, state_to_positions_index(plant)


def write_replay_html(out_path, sc, records: list[dict], maps: list[OccupancyMap] | None,
                      obj_mesh_path=None, *, fps: float = 12.0, hold_s: float = 1.0,
                      plan_hold_s: float = 1.2, max_motion_s: float = 4.0, speedup: float = 2.5,
                      meshcat=None, collision: dict | None = None) -> dict:
    """Writes the recording of a run to `out_path` (replay.html). `records` are the
    iterations.jsonl records; `maps[i]` the map after scan i+1 (None or shorter: the scans
    without a map show no voxels). The fields of the paths are optional: without
    `executed_path` the robot jumps to the next scan's true state. `collision` (summary.json's,
    None when nothing collided): the motion after the last scan that ended in a collision.
    Returns sizes and times."""
    from pydrake.geometry import Meshcat, MeshcatAnimation, MeshcatParams

    from .robot import RobotKinematics

    t0 = time.perf_counter()
    own = meshcat is None
    if own:
        meshcat = Meshcat(MeshcatParams(host="localhost"))
    kin = RobotKinematics(sc.robot.urdf)
    tmpdir = tempfile.TemporaryDirectory(prefix="nbvs_replay_")
    if obj_mesh_path is not None:
        try:
            obj_mesh_path = compact_obj(obj_mesh_path, Path(tmpdir.name) / "object.obj")
        except (OSError, ValueError):
            pass  # the original file then
    diagram, plant, q_index = _robot_visualizer(sc, meshcat, obj_mesh_path)
    ctx = diagram.CreateDefaultContext()
    pctx = plant.GetMyMutableContextFromRoot(ctx)
    maps = list(maps or [])

    def pose(q, t):
        x = np.zeros(plant.num_positions())
        x[q_index] = q
        plant.SetPositions(pctx, x)
        ctx.SetTime(t)
        diagram.ForcedPublish(ctx)

    set_default_view(meshcat)
    set_wbox(meshcat, f"{ROOT}/wbox", sc.scene.bbox_min, sc.scene.bbox_max)

    # objects first (scene tree), all hidden until the recording shows them
    toggled = []  # paths whose visibility the recording switches
    n_voxels = []
    for i, rec in enumerate(records):
        if i < len(maps) and maps[i] is not None:
            n_voxels.append(set_map_objects(meshcat, f"{ROOT}/map/{i + 1}", maps[i]))
            toggled.append(f"{ROOT}/map/{i + 1}")
        if set_plan_objects(meshcat, f"{ROOT}/plan/{i + 1}", rec.get("plan", {}), kin):
            toggled.append(f"{ROOT}/plan/{i + 1}")
        ex = _states(rec.get("executed_path"))
        if len(ex) >= 2:
            meshcat.SetLine(f"{ROOT}/trail/{i + 1}", np.c_[ex[:, :2], np.full(len(ex), 0.012)].T.copy(),
                            3.0, _rgba(TRAIL_RGBA))
            toggled.append(f"{ROOT}/trail/{i + 1}")

    hit = _states((collision or {}).get("executed_path"))
    q_hit = _states([collision["true_state"]])[0] if (collision or {}).get("true_state") else None
    show_hit = len(hit) >= 2 or q_hit is not None
    if len(hit) >= 2:
        meshcat.SetLine(f"{ROOT}/collision/trail", np.c_[hit[:, :2], np.full(len(hit), 0.014)].T.copy(),
                        4.0, _rgba(COLLISION_RGBA))
    if q_hit is not None:  # two diagonals of 0.18 m on the floor
        c = np.r_[q_hit[:2], 0.016]
        arms = 0.09 / np.sqrt(2) * np.array([[1.0, 1.0, 0.0], [1.0, -1.0, 0.0]])
        meshcat.SetLineSegments(f"{ROOT}/collision/cross", (c - arms).T.copy(), (c + arms).T.copy(), 5.0,
                                _rgba(PLAN_RGBA))
    if show_hit:
        toggled.append(f"{ROOT}/collision")

    meshcat.StartRecording(frames_per_second=fps, set_visualizations_while_recording=False)
    dt_frame = 1.0 / fps
    shown: dict[str, list] = {p: [] for p in toggled}  # path -> [(time, visible)]

    def show(path, t, v):
        if path in shown:
            shown[path].append((t, v))

    t = 0.0
    q_prev = None
    dt_ctrl = float(sc.robot.control_dt)
    n_frames = 0

    def move(path, t):
        """The robot along an executed path from time t; returns the time it arrives."""
        nonlocal n_frames
        dur = float(np.clip(len(path) * dt_ctrl / speedup, 1.0, max_motion_s))
        n = max(round(dur * fps), 2)
        for j, q in enumerate(_resample(path, n)):
            pose(q, t + j * dt_frame)
        n_frames += n
        return t + n * dt_frame

    for i, rec in enumerate(records):
        k = i + 1
        ex = _states(rec.get("executed_path"))
        if i > 0 and len(ex) >= 2:  # the motion that ended at scan k
            t = move(ex, t)
        q_true = _states([rec["true_state"]])[0] if rec.get("true_state") else q_prev
        if q_true is not None:
            pose(q_true, t)
            n_frames += 1
        # scan k: its map replaces the previous one, the previous plan disappears
        show(f"{ROOT}/map/{k}", t, True)
        show(f"{ROOT}/map/{k - 1}", t, False)
        show(f"{ROOT}/plan/{k - 1}", t, False)
        show(f"{ROOT}/trail/{k}", t, True)
        t += hold_s
        show(f"{ROOT}/plan/{k}", t, True)
        t += plan_hold_s
        if q_true is not None:
            pose(q_true, t)  # keyframe: the robot waits until the next motion starts
        q_prev = q_true
    if show_hit:  # the colliding motion, then the robot stays where it hit
        if len(hit) >= 2:
            t = move(hit, t)
        q_prev = q_hit if q_hit is not None else hit[-1]
        pose(q_prev, t)
        n_frames += 1
        show(f"{ROOT}/collision", t, True)
    t += hold_s
    if q_prev is not None:
        pose(q_prev, t)
    # every toggled object: hidden at frame 0 unless shown then, switched at its times
    for p, events in shown.items():
        if not events or events[0][0] > 0:
            meshcat.SetProperty(p, "visible", False, 0.0)
        for tv, v in events:
            meshcat.SetProperty(p, "visible", v, tv)
    meshcat.StopRecording()
    rec_anim = meshcat.get_mutable_recording()
    rec_anim.set_loop_mode(MeshcatAnimation.LoopMode.kLoopOnce)
    rec_anim.set_clamp_when_finished(True)
    rec_anim.set_autoplay(True)
    # the scene without the animation (e.g. paused at the end) shows the final state
    for p, events in shown.items():
        final = events[-1][1] if events else False
        meshcat.SetProperty(p, "visible", bool(final))
    if q_prev is not None:
        pose(q_prev, t)
    meshcat.PublishRecording()
    html = _with_seek_script(meshcat.StaticHtml())
    out_path = Path(out_path)
    tmp = out_path.with_suffix(out_path.suffix + ".tmp")
    tmp.write_text(html)
    tmp.replace(out_path)
    info = {"bytes": out_path.stat().st_size, "duration_s": round(t, 2), "robot_frames": n_frames,
            "maps": len(n_voxels), "unknown_points": int(sum(u for u, _ in n_voxels)),
            "occupied_points": int(sum(o for _, o in n_voxels)), "collision_shown": show_hit,
            "seconds": time.perf_counter() - t0}
    tmpdir.cleanup()
    if own:
        meshcat.Delete()
        del meshcat
    return info


# ---- opening at a given moment ----------------------------------------------------------

#: appended to the page: `replay.html#t=12.5` (or `#t=end`) opens paused at that moment of the
#: recording (Meshcat's animator: pause, seek); without it the recording plays once from 0
SEEK_SCRIPT = """<script>
// nbvs_drake: replay.html#t=SECONDS (or #t=end) opens the recording paused at that moment
(function () {
  var m = /(?:^#|&)t=([0-9.]+|end)/.exec(window.location.hash);
  if (!m) return;
  var tries = 0;
  var timer = setInterval(function () {
    var a = (typeof viewer !== "undefined") ? viewer.animator : null;
    if (a && a.actions && a.actions.length > 0) {
      clearInterval(timer);
      a.pause();
      var t = m[1] === "end" ? a.duration : Math.min(parseFloat(m[1]), a.duration);
      a.seek(t);
      a.display_progress(t);
    } else if (++tries > 1200) {
      clearInterval(timer);
    }
  }, 50);
})();
</script>
"""


def _with_seek_script(html: str) -> str:
    i = html.rfind("</body>")
    return html[:i] + SEEK_SCRIPT + html[i:] if i >= 0 else html + SEEK_SCRIPT


# ---- headless screenshots -----------------------------------------------------------------

CHROMIUM_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """The path of a Chromium/Chrome executable, or None."""
    import shutil
    for name in CHROMIUM_CANDIDATES:
        p = shutil.which(name)
        if p:
            return p
    return None


def screenshot_html(html_path, png_path, *, at_s: float | str | None = None, size=(1024, 768),
                    chromium: str | None = None, load_ms: int = 4000, timeout_s: float = 240.0) -> Path:
    """Renders `html_path` in headless Chromium (software WebGL: SwiftShader) and writes a PNG.
    `at_s`: the moment of the recording to show (seconds or "end"; the page is opened as
    replay.html#t=...), None: whatever plays after `load_ms` of virtual time. Needs no
    network (every flag that would reach out is off)."""
    import os
    import signal
    import subprocess
    import tempfile
    exe = chromium or find_chromium()
    if exe is None:
        raise FileNotFoundError("no chromium executable found (Debian: apt-get install chromium)")
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    url = html_path.as_uri() + (f"#t={at_s}" if at_s is not None else "")
    with tempfile.TemporaryDirectory(prefix="nbvs_chromium_", ignore_cleanup_errors=True) as profile:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
               "--use-angle=swiftshader", "--disable-quic", "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--disable-extensions", "--disable-dev-shm-usage",
               "--hide-scrollbars", f"--user-data-dir={profile}", f"--screenshot={png_path}",
               f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={int(load_ms)}", url]
        if png_path.exists():
            png_path.unlink()
        # its own process group: on a timeout the renderer and GPU processes go too
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise RuntimeError(f"chromium did not finish the screenshot within {timeout_s:.0f} s") from None
    if not png_path.is_file():
        tail = "\n".join(out.splitlines()[-5:])
        raise RuntimeError(f"chromium wrote no screenshot (exit {proc.returncode}): {tail}")
    return png_path


def image_colours(png_path) -> dict:
    """Pixel shares of a screenshot: yellow (unknown voxels), blue (occupied), and the
    number of distinct colours (coarsely quantised)."""
    from PIL import Image
    a = np.asarray(Image.open(png_path).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    n = r.size
    yellow = (r > 180) & (g > 150) & (b < 110)
    blue = (b > 150) & (r < 110) & (b - g > 40)
    q = (a // 32).reshape(-1, 3)
    distinct = len(np.unique(q[:, 0] * 64 + q[:, 1] * 8 + q[:, 2]))
    return {"yellow": float(yellow.sum() / n), "blue": float(blue.sum() / n), "distinct_colours": distinct}


# ---- the visual outputs of a run ----------------------------------------------------------

def write_visual_outputs(out_dir, sc, records: list[dict], maps=None, obj_mesh_path=None,
                         verbose: bool = False, collision: dict | None = None) -> dict:
    """paths.png (top view of planned vs executed paths) and replay.html in `out_dir`. Each
    is written on its own: a failure is reported (returned under "errors" and printed), never
    raised, so that it cannot cost the run its other results. Returns
    {"seconds": ..., "errors": [...], "replay": info of write_replay_html or None}."""
    import traceback

    from .plots import plot_paths
    out = Path(out_dir)
    t0 = time.perf_counter()
    errors, info = [], None
    try:
        plot_paths(records, out / "paths.png", sc.scene, title=f"{sc.name} (seed {sc.seed}): paths, top view",
                   collision=collision)
    except Exception as e:  # noqa: BLE001 - a plot must not lose the run
        errors.append(f"paths.png: {type(e).__name__}: {e}")
        if verbose:
            traceback.print_exc()
    if obj_mesh_path is not None and not Path(obj_mesh_path).is_file():
        obj_mesh_path = None
    try:
        info = write_replay_html(out / "replay.html", sc, records, maps, obj_mesh_path, collision=collision)
    except Exception as e:  # noqa: BLE001
        errors.append(f"replay.html: {type(e).__name__}: {e}")
        if verbose:
            traceback.print_exc()
    for e in errors:
        print(f"nbvs: warning: could not write {e}", flush=True)
    return {"seconds": time.perf_counter() - t0, "errors": errors, "replay": info}
