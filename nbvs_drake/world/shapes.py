"""The objects of the papers' real-robot experiments (Vasquez-Gomez et al. 2017 §8.4), built
from primitives with the thin parts and hollows of the real things: an office chair (Fig. 3),
a suitcase with its handles (Fig. 19) and a humanoid of NAO's size. Each is z-up with its
lowest point at z = 0 and its footprint centred on the origin, in metres at its nominal size
(the scenario scales it to scene.object.size); each part is convex (ObjectMesh.parts)."""

from __future__ import annotations

import math

import numpy as np

from .primitives import box, cylinder, join, sphere


def office_chair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About 0.6 x 0.6 x 0.9 m, facing +x: five castors on a five-star base, a gas column, a
    seat, two armrests on posts, and a backrest on a bar behind the seat."""
    parts = []
    for k in range(5):
        a = 2 * math.pi * k / 5 + math.pi / 5
        parts.append(sphere((0.29 * math.cos(a), 0.29 * math.sin(a), 0.025), 0.025))  # castor
        parts.append(box((0.03, -0.02, 0.05), (0.31, 0.02, 0.08), yaw=a))  # leg of the star
    parts.append(cylinder((0.0, 0.0), 0.05, 0.09, 0.045))  # hub
    parts.append(cylinder((0.0, 0.0), 0.09, 0.42, 0.025))  # gas column
    parts.append(box((-0.24, -0.24, 0.42), (0.24, 0.24, 0.49)))  # seat
    for s in (-1, 1):
        parts.append(box((-0.03, s * 0.215 - 0.015, 0.49), (0.0, s * 0.215 + 0.015, 0.66)))  # armrest post
        parts.append(box((-0.14, s * 0.215 - 0.025, 0.66), (0.12, s * 0.215 + 0.025, 0.69)))  # armrest
    parts.append(box((-0.275, -0.03, 0.43), (-0.24, 0.03, 0.60)))  # back bar
    parts.append(box((-0.29, -0.22, 0.58), (-0.25, 0.22, 0.90)))  # backrest
    return join(parts)


def suitcase() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About 0.42 (y) x 0.26 (x) x 0.90 m standing on four wheels: the shell, the telescopic
    handle pulled out (two rods and a grip), and a carry handle on top."""
    parts = [box((-0.12, -0.21, 0.04), (0.12, 0.21, 0.62))]  # shell
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(cylinder((sx * 0.09, 0.02), sy * 0.17 - 0.012, sy * 0.17 + 0.012, 0.02, axis="y"))
    for sy in (-1, 1):
        parts.append(box((-0.13, sy * 0.12 - 0.008, 0.62), (-0.114, sy * 0.12 + 0.008, 0.87)))  # rod
        parts.append(box((0.0, sy * 0.07 - 0.01, 0.62), (0.02, sy * 0.07 + 0.01, 0.66)))  # carry post
    parts.append(box((-0.14, -0.14, 0.87), (-0.105, 0.14, 0.90)))  # grip
    parts.append(box((-0.005, -0.08, 0.66), (0.025, 0.08, 0.68)))  # carry handle
    return join(parts)


def humanoid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A NAO-sized humanoid (about 0.58 m) standing, arms down beside the torso: feet, legs
    apart, hips, torso, shoulders, arms, neck and head."""
    parts = []
    for s in (-1, 1):
        y = s * 0.05
        parts.append(box((-0.04, y - 0.03, 0.0), (0.07, y + 0.03, 0.03)))  # foot
        parts.append(cylinder((0.0, y), 0.03, 0.27, 0.028))  # leg
        parts.append(cylinder((0.0, s * 0.112), 0.27, 0.45, 0.022))  # arm
        parts.append(sphere((0.0, s * 0.112, 0.455), 0.03))  # shoulder
        parts.append(box((0.0, s * 0.112 - 0.02, 0.24), (0.05, s * 0.112 + 0.02, 0.27)))  # hand, forward
    parts.append(box((-0.05, -0.085, 0.27), (0.05, 0.085, 0.31)))  # hips
    parts.append(box((-0.05, -0.08, 0.31), (0.05, 0.08, 0.47)))  # torso
    parts.append(cylinder((0.0, 0.0), 0.47, 0.49, 0.02))  # neck
    parts.append(sphere((0.0, 0.0, 0.535), 0.047))  # head
    return join(parts)


def _ring_wall(radius: float, z0: float, z1: float, thickness: float, staves: int) -> list:
    """A thin round wall of `staves` flat boxes (each convex), tangent to the circle of
    `radius` (its outside), `thickness` thick, from z0 to z1."""
    w = 2 * radius * math.tan(math.pi / staves) * 1.02  # the staves' outsides meet
    parts = []
    for k in range(staves):
        a = 2 * math.pi * k / staves
        parts.append(box((radius - thickness, -w / 2, z0), (radius, w / 2, z1), yaw=a))
    return parts


def cup() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hollow vessel open at the top (issue 50's hollow test object): 0.20 m across, 0.24 m
    tall, a wall of 24 staves 8 mm thick (under half a 2 cm voxel) on a 12 mm bottom; its
    inside, 0.23 m deep, is seen only through its mouth."""
    return join([cylinder((0.0, 0.0), 0.0, 0.012, 0.1, sides=24)] + _ring_wall(0.1, 0.012, 0.24, 0.008, 24))


def crate() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An open box (a hollow with a square mouth): 0.30 x 0.22 x 0.18 m, walls 10 mm thick on a
    10 mm floor, one short side lower (0.12 m) so that its inside is seen from one side as well
    as from above."""
    t = 0.01
    return join([box((-0.15, -0.11, 0.0), (0.15, 0.11, t)),  # floor
                 box((-0.15, -0.11, t), (0.15, -0.11 + t, 0.18)), box((-0.15, 0.11 - t, t), (0.15, 0.11, 0.18)),
                 box((-0.15, -0.11 + t, t), (-0.15 + t, 0.11 - t, 0.18)),
                 box((0.15 - t, -0.11 + t, t), (0.15, 0.11 - t, 0.12))])


def stool() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bar stool of thin parts (issue 50's thin test object): a round seat 0.30 m across and
    25 mm thick on three splayed legs 14 mm thick, with a ring of three rungs 10 mm thick, 0.40 m
    tall; legs and rungs are thinner than a 2 cm voxel."""
    parts = [cylinder((0.0, 0.0), 0.375, 0.40, 0.15, sides=24)]
    feet, tops = [], []
    for k in range(3):
        a = 2 * math.pi * k / 3
        feet.append((0.16 * math.cos(a), 0.16 * math.sin(a)))
        tops.append((0.10 * math.cos(a), 0.10 * math.sin(a)))
    for (fx, fy), (tx, ty) in zip(feet, tops):  # each leg a chain of short vertical boxes
        n = 10
        for i in range(n):
            f0, f1 = i / n, (i + 1) / n
            x, y = fx + (tx - fx) * (f0 + f1) / 2, fy + (ty - fy) * (f0 + f1) / 2
            parts.append(box((x - 0.007, y - 0.007, 0.375 * f0), (x + 0.007, y + 0.007, 0.375 * f1)))
    for k in range(3):  # rungs between the legs at 0.15 m, as boxes along each side
        (ax, ay), (bx, by) = feet[k], feet[(k + 1) % 3]
        f = 0.15 / 0.375
        ax, ay = ax + (tops[k][0] - ax) * f, ay + (tops[k][1] - ay) * f
        bx, by = bx + (tops[(k + 1) % 3][0] - bx) * f, by + (tops[(k + 1) % 3][1] - by) * f
        L = math.hypot(bx - ax, by - ay)
        parts.append(box((-L / 2, -0.005, 0.145), (L / 2, 0.005, 0.155), yaw=math.atan2(by - ay, bx - ax),
                         about=(0.0, 0.0)))
        V, T = parts[-1]
        parts[-1] = (V + np.array([(ax + bx) / 2, (ay + by) / 2, 0.0]), T)
    return join(parts)


def lamp() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A desk lamp (a test object held out of development, issue 50): a round base 0.16 m
    across, a slanted arm 12 mm thick, and a round shade open at both ends (0.14 m across,
    6 mm walls) hanging over the base; 0.36 m tall."""
    parts = [cylinder((0.0, 0.0), 0.0, 0.02, 0.08, sides=20)]
    a0, a1 = np.array([-0.04, 0.0, 0.02]), np.array([0.02, 0.0, 0.33])  # the arm, in short boxes
    n = 12
    for i in range(n):
        p0, p1 = a0 + (a1 - a0) * i / n, a0 + (a1 - a0) * (i + 1) / n
        c = 0.5 * (p0 + p1)
        parts.append(box((c[0] - 0.006, -0.006, p0[2]), (c[0] + 0.006, 0.006, p1[2])))
    parts.append(box((0.0, -0.006, 0.33), (0.07, 0.006, 0.342)))  # the arm's top, out to the shade
    parts += [(V + np.array([0.07, 0.0, 0.0]), T) for V, T in _ring_wall(0.07, 0.24, 0.36, 0.006, 20)]
    return join(parts)


def mug() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mug (a benchmark object, nbvs benchmark): a hollow like the cup, 0.18 m across and
    0.22 m tall with 8 mm walls, and a loop handle 16 mm thick whose hole is seen through from
    the side."""
    parts = [cylinder((0.0, 0.0), 0.0, 0.012, 0.09, sides=24)] + _ring_wall(0.09, 0.012, 0.22, 0.008, 24)
    for z0, z1 in ((0.05, 0.066), (0.164, 0.18)):  # the handle's arms, out from the wall
        parts.append(box((0.085, -0.008, z0), (0.15, 0.008, z1)))
    parts.append(box((0.134, -0.008, 0.066), (0.15, 0.008, 0.164)))  # its upright
    return join(parts)


def stack() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A stack of primitives (a benchmark object): a box 0.20 x 0.14 x 0.12 m, a ball 0.14 m
    across resting on it, and a rod 50 mm thick leaning against them (self-occlusion and a
    slanted thin part)."""
    parts = [box((-0.10, -0.07, 0.0), (0.10, 0.07, 0.12)), sphere((0.03, 0.0, 0.19), 0.07, rings=10, sectors=20)]
    a0, a1 = np.array([-0.16, 0.0, 0.0]), np.array([-0.02, 0.0, 0.30])  # the rod, in short boxes
    n = 10
    for i in range(n):
        p0, p1 = a0 + (a1 - a0) * i / n, a0 + (a1 - a0) * (i + 1) / n
        c = 0.5 * (p0 + p1)
        parts.append(box((c[0] - 0.025, -0.025, p0[2]), (c[0] + 0.025, 0.025, p1[2])))
    return join(parts)


def arch() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An arch (a benchmark object): two pillars 20 mm thick, 0.26 m apart and 0.30 m tall,
    under a lintel 0.36 m long, with a thin plate 6 mm thick standing on the lintel (thin
    parts, and a gap seen through)."""
    return join([box((-0.15, -0.03, 0.0), (-0.13, 0.03, 0.30)), box((0.13, -0.03, 0.0), (0.15, 0.03, 0.30)),
                 box((-0.18, -0.04, 0.30), (0.18, 0.04, 0.33)), box((-0.08, -0.003, 0.33), (0.08, 0.003, 0.40))])


#: kind -> builder
SHAPES = {"chair": office_chair, "suitcase": suitcase, "humanoid": humanoid, "cup": cup, "crate": crate,
          "stool": stool, "lamp": lamp, "mug": mug, "stack": stack, "arch": arch}
