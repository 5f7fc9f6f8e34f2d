"""Closed triangle meshes of boxes, cylinders and spheres, and their union as one mesh whose
parts stay apart (each part convex, so a collision model can take them one by one). The
objects built from primitives (world.shapes) are made of these."""

from __future__ import annotations

import math

import numpy as np


def box(lo, hi, yaw: float = 0.0, about=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (8, 3), triangles (12, 3)) of the axis-aligned box lo..hi, turned by `yaw`
    (rad) about the vertical through `about` (x, y); triangles wound counter-clockwise seen
    from outside."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
    T = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6],  # bottom, top
                  [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],  # -y, +y
                  [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # -x, +x
    return _turn(V, yaw, about), T


def cylinder(center_xy, z0: float, z1: float, radius: float, sides: int = 16,
             axis: str = "z") -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder of `sides` faces. axis z: vertical, through `center_xy` from z0 to z1.
    axis x or y: horizontal along that axis from z0 to z1 (its coordinate on the axis), through
    `center_xy` = the other two coordinates ((y, z) for x, (x, z) for y)."""
    a = 2 * math.pi * np.arange(sides) / sides
    c, s = radius * np.cos(a), radius * np.sin(a)
    ring = np.stack([c, s], axis=1)
    V = np.concatenate([np.c_[ring, np.full(sides, z0)], np.c_[ring, np.full(sides, z1)],
                        [[0.0, 0.0, z0], [0.0, 0.0, z1]]])
    i = np.arange(sides)
    j = (i + 1) % sides
    T = np.concatenate([np.stack([i, j, i + sides], 1), np.stack([j, j + sides, i + sides], 1),
                        np.stack([np.full(sides, 2 * sides), j, i], 1),
                        np.stack([np.full(sides, 2 * sides + 1), i + sides, j + sides], 1)])
    p, q = center_xy
    if axis == "z":
        V[:, :2] += (p, q)
    elif axis == "x":  # (ring x, ring y, along) -> (along, p + ring x, q + ring y)
        V = np.stack([V[:, 2], p + V[:, 0], q + V[:, 1]], axis=1)
    elif axis == "y":  # (ring x, ring y, along) -> (p + ring y, along, q + ring x): keeps the winding
        V = np.stack([p + V[:, 1], V[:, 2], q + V[:, 0]], axis=1)
    else:
        raise ValueError(f"cylinder axis must be x, y or z, got {axis!r}")
    return V, T.astype(np.int32)


def sphere(center, radius: float, rings: int = 8, sectors: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere (poles shared)."""
    th = math.pi * np.arange(1, rings) / rings
    ph = 2 * math.pi * np.arange(sectors) / sectors
    t, p = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    V = np.concatenate([[[0, 0, 1.0]], V, [[0, 0, -1.0]]]) * radius + np.asarray(center, float)
    tris = []
    s = sectors
    for k in range(s):
        tris.append([0, 1 + k, 1 + (k + 1) % s])
    for r in range(rings - 2):
        for k in range(s):
            a, b = 1 + r * s + k, 1 + r * s + (k + 1) % s
            tris += [[a, a + s, b], [b, a + s, b + s]]
    last = len(V) - 1
    base = 1 + (rings - 2) * s
    for k in range(s):
        tris.append([last, base + (k + 1) % s, base + k])
    return V, np.array(tris, np.int32)


def join(parts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, triangles, part of each triangle) of the parts [(V, T), ...] as one mesh."""
    V, T, P, n = [], [], [], 0
    for k, (v, t) in enumerate(parts):
        V.append(v)
        T.append(np.asarray(t) + n)
        P.append(np.full(len(t), k, np.int32))
        n += len(v)
    return np.concatenate(V), np.concatenate(T).astype(np.int32), np.concatenate(P)


def _turn(V: np.ndarray, yaw: float, about) -> np.ndarray:
    if not yaw:
        return V
    c, s = math.cos(yaw), math.sin(yaw)
    out = V.copy()
    x, y = V[:, 0] - about[0], V[:, 1] - about[1]
    out[:, 0], out[:, 1] = about[0] + c * x - s * y, about[1] + s * x + c * y
    return out
