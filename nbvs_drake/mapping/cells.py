"""The grid in cells: summaries that let a traversal skip or batch voxels.

- 4 x 4 x 4 cells with one uint64 bit per voxel (bit ((i & 3) * 4 + (j & 3)) * 4 + (k & 3)):
  `cell_masks` (unknown / occupied bitmasks and a shared entropy per cell) and the DDA moves
  that walk them (`cell_step` one voxel, `skip_cell` across an all-free cell at once), for the
  exact view evaluation.
- Level-a pyramid cells of 2^a x 2^a x 2^a voxels: `coarse_summary` (class bit set, entropy
  sum, unknown count), for the hierarchical view evaluation.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .voxel import FREE, OCCUPIED, UNKNOWN, voxel_class

U64_1 = np.uint64(1)


@nb.njit(cache=True, inline="always")
def popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(cache=True)
def cell_masks(cls, H):
    """Per 4x4x4 cell: unknown-voxel bitmask U, occupied-voxel bitmask O (voxels past the grid's
    edge are neither) and the entropy shared by all its unknown voxels (-1 when they differ)."""
    nx, ny, nz = cls.shape
    cx, cy, cz = (nx + 3) >> 2, (ny + 3) >> 2, (nz + 3) >> 2
    U = np.zeros(cx * cy * cz, np.uint64)
    O = np.zeros(cx * cy * cz, np.uint64)
    hc = np.full(cx * cy * cz, -2.0)
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                c = cls[i, j, k]
                if c == FREE:
                    continue
                cf = ((i >> 2) * cy + (j >> 2)) * cz + (k >> 2)
                bit = U64_1 << np.uint64(((i & 3) * 4 + (j & 3)) * 4 + (k & 3))
                if c == OCCUPIED:
                    O[cf] |= bit
                else:
                    U[cf] |= bit
                    h = np.float64(H[i, j, k])
                    if hc[cf] == -2.0:
                        hc[cf] = h
                    elif hc[cf] != h:
                        hc[cf] = -1.0
    return U, O, hc


@nb.njit(cache=True, inline="always")
def bits_entropy(H, cf, cy, cz, m):
    """Sum of the entropies of the voxels of cell cf whose bits are set in m."""
    ci = cf // (cy * cz)
    cj = (cf // cz) % cy
    ck = cf % cz
    s = 0.0
    for b in range(64):
        if (m >> np.uint64(b)) & U64_1:
            s += H[ci * 4 + (b >> 4), cj * 4 + ((b >> 2) & 3), ck * 4 + (b & 3)]
    return s


ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)


@nb.njit(cache=True, inline="always")
def cell_step(i, j, k, ti, tj, tk, b, si, sj, sk, di, dj, dk, bi, bj, bk, wi, wj, wk, t1):
    """One DDA step (Amanatides & Woo, ties: i, then j). Returns the new state and a status:
    0 still in the cell, 1 entered a new 4x4x4 cell, 2 the ray ends (next boundary >= t1)."""
    if ti <= tj and ti <= tk:
        if ti >= t1:
            return i, j, k, ti, tj, tk, b, 2
        i += si
        return i, j, k, ti + di, tj, tk, b + bi, 1 if (i & 3) == wi else 0
    if tj <= tk:
        if tj >= t1:
            return i, j, k, ti, tj, tk, b, 2
        j += sj
        return i, j, k, ti, tj + dj, tk, b + bj, 1 if (j & 3) == wj else 0
    if tk >= t1:
        return i, j, k, ti, tj, tk, b, 2
    k += sk
    return i, j, k, ti, tj, tk + dk, b + bk, 1 if (k & 3) == wk else 0


@nb.njit(cache=True, inline="always")
def _axis_skip(i, t, si, dt, t_exit):
    """Advances one axis of the DDA over its boundaries before t_exit within the 4x4x4 cell."""
    if si == 0 or t >= t_exit:
        return i, t
    n = int(math.ceil((t_exit - t) / dt))
    n = min(n, (3 - (i & 3)) if si > 0 else (i & 3))
    return i + si * n, t + n * dt


@nb.njit(cache=True, inline="always")
def skip_cell(i, j, k, ti, tj, tk, si, sj, sk, di, dj, dk, t1):
    """Moves the DDA across the rest of its 4x4x4 cell at once (the voxels between need no
    visit: the cell is all free). Returns the state in the next cell and status 1, or status 2
    when the ray ends inside the cell."""
    xi = ti + ((3 - (i & 3)) if si > 0 else (i & 3)) * di if si != 0 else np.inf
    xj = tj + ((3 - (j & 3)) if sj > 0 else (j & 3)) * dj if sj != 0 else np.inf
    xk = tk + ((3 - (k & 3)) if sk > 0 else (k & 3)) * dk if sk != 0 else np.inf
    if xi <= xj and xi <= xk:
        if xi >= t1:
            return i, j, k, ti, tj, tk, 2
        j, tj = _axis_skip(j, tj, sj, dj, xi)
        k, tk = _axis_skip(k, tk, sk, dk, xi)
        n = ((3 - (i & 3)) if si > 0 else (i & 3)) + 1
        return i + si * n, j, k, xi + di, tj, tk, 1
    if xj <= xk:
        if xj >= t1:
            return i, j, k, ti, tj, tk, 2
        i, ti = _axis_skip(i, ti, si, di, xj)
        k, tk = _axis_skip(k, tk, sk, dk, xj)
        n = ((3 - (j & 3)) if sj > 0 else (j & 3)) + 1
        return i, j + sj * n, k, ti, xj + dj, tk, 1
    if xk >= t1:
        return i, j, k, ti, tj, tk, 2
    i, ti = _axis_skip(i, ti, si, di, xk)
    j, tj = _axis_skip(j, tj, sj, dj, xk)
    n = ((3 - (k & 3)) if sk > 0 else (k & 3)) + 1
    return i, j, k + sk * n, ti, tj, xk + dk, 1


@nb.njit(cache=True)
def coarse_summary(logodds, H, a, l_free, l_occ):
    """Level-a pyramid cell summaries: class bits (voxel.C_*) of the 2^a x 2^a x 2^a children, the
    entropy sum and the count of their unknown children. Cells past the grid's edge hold
    only the children that exist."""
    s = 1 << a
    nx, ny, nz = logodds.shape
    cx, cy, cz = (nx + s - 1) // s, (ny + s - 1) // s, (nz + s - 1) // s
    bits = np.zeros((cx, cy, cz), np.uint8)
    hsum = np.zeros((cx, cy, cz), np.float64)
    nunk = np.zeros((cx, cy, cz), np.int32)
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                c = voxel_class(logodds[i, j, k], l_free, l_occ)
                ci, cj, ck = i // s, j // s, k // s
                bits[ci, cj, ck] |= 1 << c
                if c == UNKNOWN:
                    hsum[ci, cj, ck] += H[i, j, k]
                    nunk[ci, cj, ck] += 1
    return bits, hsum, nunk
