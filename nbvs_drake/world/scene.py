"""The known environment (floor, the table or the support box, optional clutter: chairs, a
room, obstacles), the object, and the object bounding box W_box, registered on a MultibodyPlant
so that rendering (SceneGraph + RenderEngineVtk) and collision queries use one model."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from ..config import Scenario, SceneConfig

TABLE_THICKNESS = 0.04
LEG = 0.04


@dc.dataclass
class Box:
    name: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0
    color: tuple[float, float, float, float] = (0.55, 0.4, 0.25, 1.0)


def environment_boxes(scene: SceneConfig) -> list[Box]:
    """The known environment: the floor; the table (support table) or the support box (support
    box, unless it is reconstructed with the object); and the clutter: nine chairs around the
    table (chairs), a room's walls and furniture (room) or obstacles around the object (obstacles)."""
    s = scene
    boxes = [Box("floor", (0.0, 0.0, -0.05), (8.0, 8.0, 0.1), color=(0.8, 0.8, 0.8, 1.0))]
    if s.support == "table":
        tx, ty = s.table_size
        h = s.table_height
        boxes.append(Box("table_top", (0.0, 0.0, h - TABLE_THICKNESS / 2), (tx, ty, TABLE_THICKNESS)))
        leg_h = h - TABLE_THICKNESS
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
            boxes.append(Box(f"table_leg{i}", (sx * (tx / 2 - LEG), sy * (ty / 2 - LEG), leg_h / 2),
                             (LEG, LEG, leg_h)))
    elif s.support == "box" and not s.box_reconstructed:
        bx, by, bz = s.box_size
        boxes.append(Box("support_box", (s.object.xy[0], s.object.xy[1], bz / 2), (bx, by, bz)))
    boxes += {"chairs": chair_boxes, "room": room_boxes, "obstacles": obstacle_boxes}.get(s.clutter, lambda _: [])(s)
    return boxes


def box_arrays(scene: SceneConfig, floor: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The environment's boxes (`environment_boxes`, without the floor when `floor` is
    False) as arrays: centres (M, 3), half sizes (M, 3) and yaws about z (M,)."""
    boxes = [b for b in environment_boxes(scene) if floor or b.name != "floor"]
    return (np.array([b.center for b in boxes], float).reshape(-1, 3),
            0.5 * np.array([b.size for b in boxes], float).reshape(-1, 3),
            np.array([b.yaw for b in boxes], float))


def chair_boxes(scene: SceneConfig) -> list[Box]:
    """Nine chairs on a ring around the table (Vasquez-Gomez et al. 2017 Fig. 13): seat + backrest each, in ten
    slots 36 deg apart with the slot on the -x side (where the robot starts) left open."""
    out = []
    r = 1.25
    for k in (0, 1, 2, 3, 4, 6, 7, 8, 9):
        a = 2 * math.pi * k / 10
        cx, cy = r * math.cos(a), r * math.sin(a)
        yaw = a + math.pi  # facing the table
        out.append(Box(f"chair{k}_seat", (cx, cy, 0.225), (0.42, 0.42, 0.45), yaw, (0.2, 0.3, 0.6, 1)))
        bx, by = cx + 0.19 * math.cos(a), cy + 0.19 * math.sin(a)
        out.append(Box(f"chair{k}_back", (bx, by, 0.65), (0.04, 0.42, 0.4), yaw, (0.2, 0.3, 0.6, 1)))
    return out


ROOM_HALF = 2.4  #: the room's walls stand this far from its centre (m); the base stays within +-1.9
WALL = (0.85, 0.85, 0.8, 1.0)
FURNITURE = (0.5, 0.42, 0.32, 1.0)


def room_boxes(scene: SceneConfig) -> list[Box]:
    """A 4.8 m x 4.8 m room like the lab of Vasquez-Gomez et al. 2017 Fig. 3: four walls 1.8 m
    high, and furniture along them as known obstacles: a desk, a bookcase, a cabinet and a
    second table, leaving the robot's start (-1.7, 0) and the middle of the room free."""
    r, t = ROOM_HALF, 0.1
    walls = [Box("wall_px", (r + t / 2, 0.0, 0.9), (t, 2 * r + 2 * t, 1.8), color=WALL),
             Box("wall_nx", (-r - t / 2, 0.0, 0.9), (t, 2 * r + 2 * t, 1.8), color=WALL),
             Box("wall_py", (0.0, r + t / 2, 0.9), (2 * r, t, 1.8), color=WALL),
             Box("wall_ny", (0.0, -r - t / 2, 0.9), (2 * r, t, 1.8), color=WALL)]
    furniture = [Box("desk", (1.0, 2.05, 0.375), (1.4, 0.7, 0.75), color=FURNITURE),
                 Box("bookcase", (2.2, -0.4, 0.9), (0.4, 1.0, 1.8), color=FURNITURE),
                 Box("cabinet", (-1.2, -2.15, 0.55), (0.8, 0.5, 1.1), color=FURNITURE),
                 Box("side_table", (1.3, -1.9, 0.36), (0.9, 0.6, 0.72), color=FURNITURE)]
    return walls + furniture


def obstacle_boxes(scene: SceneConfig) -> list[Box]:
    """Obstacles around the object as in Vasquez-Gomez et al. 2017 Fig. 19 (boxes, a bin, a
    crate, a cabinet) 0.8-1.3 m from it, leaving the robot's start (-1.7, 0) a way in."""
    x, y = scene.object.xy
    spec = [("crate", (0.9, 0.85), (0.45, 0.45, 0.5), 0.3),
            ("cabinet", (-0.15, 1.25), (0.6, 0.35, 0.9), 0.0),
            ("bin", (0.75, -1.0), (0.35, 0.35, 0.6), 0.0),
            ("boxes", (-0.95, -1.0), (0.5, 0.4, 0.4), -0.4),
            ("stand", (1.35, -0.1), (0.3, 0.5, 1.0), 0.0)]
    return [Box(n, (x + cx, y + cy, sz / 2), (sx, sy, sz), yaw, FURNITURE) for n, (cx, cy), (sx, sy, sz), yaw in spec]


def _pose(center, yaw=0.0):
    from pydrake.math import RigidTransform, RollPitchYaw
    return RigidTransform(RollPitchYaw(0, 0, yaw), np.asarray(center, float))


def add_environment(plant, sc: Scenario, *, object_obj: str | None = None,
                    add_wbox_obstacle: bool = False, collision: bool = True, visual: bool = True,
                    obstacle_boxes=None, floor_drop: float = 0.0):
    """Registers the environment on the world body of `plant` (before Finalize).

    object_obj: path of the object's OBJ (world-frame vertices) to add as visual (rendered)
        and collision (convex hull) geometry; None leaves the object out (the planner's
        model: the object is unknown to it).
    add_wbox_obstacle: add W_box as a collision-only box (O = W_obj u W_unk u O_env is
        inside W_box u O_env, so this is the conservative obstacle of the unknown region).
    obstacle_boxes: (centre, size) pairs added as collision-only boxes (the map's unknown
        and occupied voxels, merged).
    floor_drop: the floor's collision box this much lower (m): a model whose base link is
        padded by that much against the environment (planner.obstacles.base_clearance) keeps the base's
        own ground clearance.
    """
    from pydrake.geometry import Box as DBox
    from pydrake.geometry import Mesh
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import CoulombFriction

    world = plant.world_body()
    friction = CoulombFriction(0.5, 0.5)
    for b in environment_boxes(sc.scene):
        X = _pose(b.center, b.yaw)
        if b.name == "floor" and floor_drop:
            X = _pose((b.center[0], b.center[1], b.center[2] - floor_drop), b.yaw)
        shape = DBox(*b.size)
        if visual:
            plant.RegisterVisualGeometry(world, X, shape, b.name, np.array(b.color))
        if collision:
            plant.RegisterCollisionGeometry(world, X, shape, b.name, friction)
    if object_obj is not None:
        mesh = Mesh(str(object_obj), 1.0)
        if visual:
            plant.RegisterVisualGeometry(world, RigidTransform(), mesh, "object",
                                         np.array([0.85, 0.85, 0.9, 1.0]))
        if collision:  # Drake collides a mesh as its convex hull: an object of parts, part by part
            from .objects import ObjectMesh
            parts = ObjectMesh.part_files(object_obj) or [object_obj]
            for k, p in enumerate(parts):
                plant.RegisterCollisionGeometry(world, RigidTransform(), Mesh(str(p), 1.0),
                                                "object" if len(parts) == 1 else f"object_part{k}", friction)
    for n, (c, size) in enumerate(obstacle_boxes or []):
        plant.RegisterCollisionGeometry(world, _pose(c), DBox(*size), f"map_obstacle_{n}", friction)
    if add_wbox_obstacle:
        lo, hi = np.array(sc.scene.bbox_min), np.array(sc.scene.bbox_max)
        plant.RegisterCollisionGeometry(world, _pose(0.5 * (lo + hi)), DBox(*(hi - lo)), "W_box", friction)
