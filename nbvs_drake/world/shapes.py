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


#: kind -> builder
SHAPES = {"chair": office_chair, "suitcase": suitcase, "humanoid": humanoid}
