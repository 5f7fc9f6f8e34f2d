"""Conservative box covers of voxel sets, for Drake collision geometry.

SceneGraph's proximity registration grows super-linearly with the number of geometries
(FACTS.md: a thousand boxes take minutes), so the map's obstacle voxels (unknown and
occupied, Vasquez-Gomez et al. 2017 §3) are merged into at most a few hundred axis-aligned boxes. A cover is
conservative: every obstacle voxel lies in a box. When exact greedy merging needs more boxes
than allowed, the voxels are grouped into 2x2x2 blocks (any obstacle voxel makes the block an
obstacle) and merged again, coarser each time.
"""

from __future__ import annotations

import numpy as np


def greedy_boxes(mask: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Exact cover of the True voxels by boxes [lo, hi) (voxel indices): runs along z, grown
    along y over identical runs, then along x over identical rectangles (greedy meshing)."""
    m = mask.copy()
    nx, ny, nz = m.shape
    out = []
    for i in range(nx):
        for j in range(ny):
            k = 0
            while k < nz:
                if not m[i, j, k]:
                    k += 1
                    continue
                k1 = k
                while k1 < nz and m[i, j, k1]:
                    k1 += 1
                j1 = j + 1
                while j1 < ny and m[i, j1, k:k1].all():
                    j1 += 1
                i1 = i + 1
                while i1 < nx and m[i1, j:j1, k:k1].all():
                    i1 += 1
                m[i:i1, j:j1, k:k1] = False
                out.append((np.array([i, j, k]), np.array([i1, j1, k1])))
                k = k1
    return out


def conservative_boxes(mask: np.ndarray, max_boxes: int) -> tuple[list[tuple[np.ndarray, np.ndarray]], int]:
    """Boxes (voxel index ranges [lo, hi) of the original grid) covering every True voxel, at
    most `max_boxes` of them. Returns (boxes, block size used: 1 = exact)."""
    block = 1
    cur = mask
    while True:
        boxes = greedy_boxes(cur)
        if len(boxes) <= max_boxes or min(cur.shape) <= 1:
            scaled = [(lo * block, np.minimum(hi * block, mask.shape)) for lo, hi in boxes]
            return scaled, block
        pad = [(0, (-s) % 2) for s in cur.shape]
        p = np.pad(cur, pad, constant_values=False)
        cur = p.reshape(p.shape[0] // 2, 2, p.shape[1] // 2, 2, p.shape[2] // 2, 2).any(axis=(1, 3, 5))
        block *= 2
