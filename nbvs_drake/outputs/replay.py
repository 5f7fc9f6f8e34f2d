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
cross on the floor. With verified views (mission.verify_views), a scan taken after
localisation frames gets a vertical mark per frame over the robot: orange for a corrected
view, magenta for a re-localisation (planning/recovery.py). The reconstructed surface
(model_mesh.ply, green) appears after the last scan. Every overlay is a Meshcat object
whose "visible" property is switched in the
recording. Motions are replayed `speedup` times faster than simulated (at most
`max_motion_s` each); the robot waits while a map and a plan are shown.

A script appended to the page opens it paused at a moment: `replay.html#t=12.5`, `#t=end`
(`screenshot.screenshot_html` uses it). The drawing helpers are `meshcat_draw`'s, which the
live view (`systems/meshcat_map_view.py`) shares.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ..files import write_atomic
from ..mapping.occupancy import OccupancyMap
from .meshcat_draw import (
    COLLISION_RGBA,
    CORRECT_RGBA,
    MODEL_MESH_RGBA,
    PLAN_RGBA,
    RELOCALISE_RGBA,
    ROOT,
    TRAIL_RGBA,
    rgba,
    set_default_view,
    set_map_objects,
    set_plan_objects,
    set_wbox,
    states_array,
)


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

    from ..world.robot import add_robot, state_to_positions_index
    from ..world.scene import add_environment

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
                      meshcat=None, collision: dict | None = None, model_mesh=None) -> dict:
    """Writes the recording of a run to `out_path` (replay.html). `records` are the
    iterations.jsonl records; `maps[i]` the map after scan i+1 (None or shorter: the scans
    without a map show no voxels). The fields of the paths are optional: without
    `executed_path` the robot jumps to the next scan's true state. `collision` (summary.json's,
    None when nothing collided): the motion after the last scan that ended in a collision.
    `model_mesh`: (vertices, triangles) of the reconstructed surface (model_mesh.ply), shown
    in green from the last scan on. Returns sizes and times."""
    from pydrake.geometry import Meshcat, MeshcatAnimation, MeshcatParams

    from ..world.robot import RobotKinematics

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
        ex = states_array(rec.get("executed_path"))
        if len(ex) >= 2:
            meshcat.SetLine(f"{ROOT}/trail/{i + 1}", np.c_[ex[:, :2], np.full(len(ex), 0.012)].T.copy(),
                            3.0, rgba(TRAIL_RGBA))
            toggled.append(f"{ROOT}/trail/{i + 1}")

    # verified views (mission.verify_views): a vertical mark over the base where scan k was
    # taken after localisation frames, orange when its view was corrected, magenta when the
    # belief had to be re-localised first (one segment per frame, stacked)
    n_marked = 0
    for i, rec in enumerate(records):
        frames = (rec.get("scan") or {}).get("frames") or []
        if not frames or not rec.get("true_state"):
            continue
        q = states_array([rec["true_state"]])[0]
        for j, f in enumerate(frames):
            z0 = 1.25 + 0.12 * j
            relocalised = f.get("check") == "relocalise"
            meshcat.SetLineSegments(f"{ROOT}/frames/{i + 1}/{j}", np.array([[q[0], q[1], z0]]).T.copy(),
                                    np.array([[q[0], q[1], z0 + 0.09]]).T.copy(), 8.0,
                                    rgba(RELOCALISE_RGBA if relocalised else CORRECT_RGBA))
        toggled.append(f"{ROOT}/frames/{i + 1}")
        n_marked += len(frames)

    mesh_shown = model_mesh is not None and len(model_mesh[1]) > 0
    if mesh_shown:  # the reconstructed surface (TSDF), shown at the end
        mV, mT = model_mesh
        meshcat.SetTriangleMesh(f"{ROOT}/model_mesh", np.asarray(mV, float).T.copy(), np.asarray(mT, np.int32).T.copy(),
                                rgba(MODEL_MESH_RGBA))
        toggled.append(f"{ROOT}/model_mesh")

    hit = states_array((collision or {}).get("executed_path"))
    q_hit = states_array([collision["true_state"]])[0] if (collision or {}).get("true_state") else None
    show_hit = len(hit) >= 2 or q_hit is not None
    if len(hit) >= 2:
        meshcat.SetLine(f"{ROOT}/collision/trail", np.c_[hit[:, :2], np.full(len(hit), 0.014)].T.copy(),
                        4.0, rgba(COLLISION_RGBA))
    if q_hit is not None:  # two diagonals of 0.18 m on the floor
        c = np.r_[q_hit[:2], 0.016]
        arms = 0.09 / np.sqrt(2) * np.array([[1.0, 1.0, 0.0], [1.0, -1.0, 0.0]])
        meshcat.SetLineSegments(f"{ROOT}/collision/cross", (c - arms).T.copy(), (c + arms).T.copy(), 5.0,
                                rgba(PLAN_RGBA))
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
        ex = states_array(rec.get("executed_path"))
        if i > 0 and len(ex) >= 2:  # the motion that ended at scan k
            t = move(ex, t)
        q_true = states_array([rec["true_state"]])[0] if rec.get("true_state") else q_prev
        if q_true is not None:
            pose(q_true, t)
            n_frames += 1
        # scan k: its map replaces the previous one, the previous plan disappears
        show(f"{ROOT}/map/{k}", t, True)
        show(f"{ROOT}/map/{k - 1}", t, False)
        show(f"{ROOT}/plan/{k - 1}", t, False)
        show(f"{ROOT}/trail/{k}", t, True)
        show(f"{ROOT}/frames/{k}", t, True)
        t += hold_s
        show(f"{ROOT}/plan/{k}", t, True)
        t += plan_hold_s
        if q_true is not None:
            pose(q_true, t)  # keyframe: the robot waits until the next motion starts
        q_prev = q_true
    if mesh_shown:
        show(f"{ROOT}/model_mesh", t, True)
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
    write_atomic(out_path, html)
    info = {"bytes": out_path.stat().st_size, "duration_s": round(t, 2), "robot_frames": n_frames,
            "maps": len(n_voxels), "unknown_points": int(sum(u for u, _ in n_voxels)),
            "occupied_points": int(sum(o for _, o in n_voxels)), "collision_shown": show_hit,
            "localisation_frames_shown": n_marked, "model_mesh_shown": mesh_shown,
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
