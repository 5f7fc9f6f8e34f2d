"""Meshcat drawing helpers shared by the live view (`systems/meshcat_map_view.py`) and the
recording (`replay.py`): the colours, the map's voxels (unknown voxels of W_box as yellow
dots, only those on the surface of the unknown region, the others being hidden behind them;
occupied voxels blue), a plan's overlays (candidate views coloured by utility rank, cyan to
magenta, with their optical axes; the chosen view as a red sphere and axis; the planned path
in red, base on the floor and camera), W_box as a wireframe and the default viewpoint.
"""

from __future__ import annotations

import numpy as np

from ..mapping.occupancy import OCCUPIED, UNKNOWN, OccupancyMap

UNKNOWN_RGBA = (1.0, 0.85, 0.05, 1.0)
OCCUPIED_RGBA = (0.1, 0.3, 1.0, 1.0)
#: unknown voxels are drawn as dots of this share of the voxel size: the occupied voxels and
#: the object show through the gaps
UNKNOWN_POINT_SCALE = 0.4
PLAN_RGBA = (0.9, 0.1, 0.1, 1.0)
TRAIL_RGBA = (0.05, 0.6, 0.2, 1.0)
COLLISION_RGBA = (0.55, 0.0, 0.0, 1.0)
#: verified views: a scan after a corrected view, after a re-localisation (replay marks)
CORRECT_RGBA = (1.0, 0.55, 0.0, 1.0)
RELOCALISE_RGBA = (0.85, 0.0, 0.85, 1.0)
MODEL_MESH_RGBA = (0.2, 0.75, 0.35, 1.0)  #: the reconstructed surface (TSDF mesh)
GOAL_RGBA = (0.9, 0.05, 0.05, 1.0)
CANDIDATE_AXIS_RGBA = (0.25, 0.25, 0.3, 1.0)
WBOX_RGBA = (0.3, 0.3, 0.3, 1.0)
ROOT = "/nbvs"

# default viewpoint: behind and above the robot's start side, framing the table and the
# ring the robot drives on
CAMERA_POSITION = (-1.9, -1.6, 1.7)
CAMERA_TARGET = (0.0, 0.0, 0.35)


def rgba(c):
    """A Drake Rgba of an (r, g, b, a) tuple."""
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
    meshcat.SetObject(f"{path}/unknown", _cloud(unk), UNKNOWN_POINT_SCALE * size, rgba(UNKNOWN_RGBA))
    meshcat.SetObject(f"{path}/occupied", _cloud(occ), size, rgba(OCCUPIED_RGBA))
    return len(unk), len(occ)


# ---- plan overlays ------------------------------------------------------------------------

def states_array(seq) -> np.ndarray:
    """Robot states (n, 8) of a JSON list of states (None or empty: (0, 8))."""
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
    Q = states_array([c["q"] for c in cands if "q" in c])
    if len(Q):
        g = np.array([float(c.get("g", 0.0)) for c in cands if "q" in c])
        X = kin.camera_poses(Q)
        p = X[:, :3, 3]
        meshcat.SetObject(f"{path}/candidates/cameras", _cloud(p, _utility_colours(g)), 0.045, rgba((1, 1, 1, 1)))
        meshcat.SetLineSegments(f"{path}/candidates/axes", p.T.copy(), (p + 0.15 * X[:, :3, 2]).T.copy(),
                                1.0, rgba(CANDIDATE_AXIS_RGBA))
        drawn["candidates"] = len(Q)
    goal = plan.get("q_goal")
    if goal is not None and plan.get("status", "ok") == "ok":
        X = kin.camera_poses(states_array([goal]))[0]
        meshcat.SetObject(f"{path}/goal/sphere", Sphere(0.03), rgba(GOAL_RGBA))
        meshcat.SetTransform(f"{path}/goal/sphere", RigidTransform(X[:3, 3]))
        meshcat.SetLineSegments(f"{path}/goal/axis", X[:3, 3:4].copy(), (X[:3, 3] + 0.25 * X[:3, 2])[:, None].copy(),
                                3.0, rgba(GOAL_RGBA))
        drawn["goal"] = 1
    states = states_array(plan.get("path"))
    if len(states) >= 2:
        base = np.c_[states[:, :2], np.full(len(states), 0.01)]
        meshcat.SetLine(f"{path}/plan_base", base.T.copy(), 3.0, rgba(PLAN_RGBA))
        cam = kin.camera_poses(states)[:, :3, 3]
        meshcat.SetLine(f"{path}/plan_camera", cam.T.copy(), 2.0, rgba(PLAN_RGBA))
        drawn["plan_states"] = len(states)
    return drawn


def set_wbox(meshcat, path: str, lo, hi):
    """W_box as a wireframe (12 edges)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array([[(hi if (i >> a) & 1 else lo)[a] for a in range(3)] for i in range(8)])
    edges = [(i, i | (1 << a)) for i in range(8) for a in range(3) if not (i >> a) & 1]
    s = np.array([c[i] for i, _ in edges]).T.copy()
    e = np.array([c[j] for _, j in edges]).T.copy()
    meshcat.SetLineSegments(path, s, e, 2.0, rgba(WBOX_RGBA))


def set_default_view(meshcat):
    meshcat.SetProperty("/Axes", "visible", False)
    meshcat.SetCameraPose(np.array(CAMERA_POSITION), np.array(CAMERA_TARGET))
