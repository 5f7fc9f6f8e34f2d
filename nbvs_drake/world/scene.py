"""The known environment (floor, table, optional chairs), the object, and the object
bounding box W_box, registered on a MultibodyPlant so that rendering (SceneGraph +
RenderEngineVtk) and collision queries use one model."""

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
    """Floor, table top and legs, and (clutter = chairs) nine chairs around the table."""
    s = scene
    tx, ty = s.table_size
    h = s.table_height
    boxes = [Box("floor", (0.0, 0.0, -0.05), (8.0, 8.0, 0.1), color=(0.8, 0.8, 0.8, 1.0)),
             Box("table_top", (0.0, 0.0, h - TABLE_THICKNESS / 2), (tx, ty, TABLE_THICKNESS))]
    leg_h = h - TABLE_THICKNESS
    for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
        boxes.append(Box(f"table_leg{i}", (sx * (tx / 2 - LEG), sy * (ty / 2 - LEG), leg_h / 2),
                         (LEG, LEG, leg_h)))
    if s.clutter == "chairs":
        boxes += chair_boxes(scene)
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
        if collision:
            plant.RegisterCollisionGeometry(world, RigidTransform(), mesh, "object", friction)
    for n, (c, size) in enumerate(obstacle_boxes or []):
        plant.RegisterCollisionGeometry(world, _pose(c), DBox(*size), f"map_obstacle_{n}", friction)
    if add_wbox_obstacle:
        lo, hi = np.array(sc.scene.bbox_min), np.array(sc.scene.bbox_max)
        plant.RegisterCollisionGeometry(world, _pose(0.5 * (lo + hi)), DBox(*(hi - lo)), "W_box", friction)
