"""OctoMap interoperability: writes the map as an OctoMap binary tree (`.bt`, readable by
octovis and pyoctomap's `OcTree.readBinary`).

The dense grid lies on OctoMap's lattice (voxel (i, j, k) has key (i, j, k) + key_offset), so
each known voxel becomes a depth-16 leaf: free (binary maximum-likelihood value) or occupied;
unknown voxels are absent nodes, as in OctoMap. Nodes whose eight children are leaves of one
class are pruned into a leaf, as OctoMap's prune() does.
"""

from __future__ import annotations

import numpy as np

from ..files import write_atomic
from .occupancy import OccupancyMap
from .voxel import FREE, OCCUPIED

TREE_DEPTH = 16
_FREE_BITS, _OCC_BITS, _INNER_BITS = 0b01, 0b10, 0b11  # child i: free sets bit 2i, occupied bit 2i+1


def _serialize(classes: np.ndarray, off: np.ndarray):
    """Pre-order binary node stream of the tree over `classes` (voxel.FREE, UNKNOWN, OCCUPIED)
    whose voxel (0, 0, 0) has key `off`. Returns (bytes, number of nodes). (Plain Python ints
    in the recursion: numpy's per-call overhead on 3-element arrays was most of its time.)"""
    dims = classes.shape
    lo = tuple(int(v) for v in off)
    hi = tuple(lo[a] + int(dims[a]) for a in range(3))  # [lo, hi) per axis
    cls = classes.tolist()
    free_c, occ_c = int(FREE), int(OCCUPIED)
    bits_of = {"free": _FREE_BITS, "occ": _OCC_BITS, "inner": _INNER_BITS}
    n_nodes = [0]
    # summed-area tables of the free and occupied voxels: a node's counts in 8 lookups, so that
    # a node all unknown, all free or all occupied (a pruned leaf) ends without its children
    sat = []
    for c in (free_c, occ_c):
        t = np.zeros(tuple(d + 1 for d in dims), np.int64)
        t[1:, 1:, 1:] = (classes == c).cumsum(0).cumsum(1).cumsum(2)
        sat.append(t.tolist())

    def count(t, x0, y0, z0, x1, y1, z1):
        return (t[x1][y1][z1] - t[x0][y1][z1] - t[x1][y0][z1] - t[x1][y1][z0]
                + t[x0][y0][z1] + t[x0][y1][z0] + t[x1][y0][z0] - t[x0][y0][z0])

    def node(depth, bx, by, bz):
        """Returns ('unknown' | 'free' | 'occ' | 'inner', payload bytes)."""
        size = 1 << (TREE_DEPTH - depth)
        if (bx + size <= lo[0] or by + size <= lo[1] or bz + size <= lo[2]
                or bx >= hi[0] or by >= hi[1] or bz >= hi[2]):
            return "unknown", b""
        if size == 1:
            c = cls[bx - lo[0]][by - lo[1]][bz - lo[2]]
            return ("free" if c == free_c else "occ" if c == occ_c else "unknown"), b""
        # the node's part of the grid: no known voxel -> unknown; a node wholly inside the grid
        # all of one known class -> that leaf (what the recursion's pruning would return)
        x0, y0, z0 = max(bx - lo[0], 0), max(by - lo[1], 0), max(bz - lo[2], 0)
        x1, y1, z1 = min(bx + size, hi[0]) - lo[0], min(by + size, hi[1]) - lo[1], min(bz + size, hi[2]) - lo[2]
        nf = count(sat[0], x0, y0, z0, x1, y1, z1)
        no = count(sat[1], x0, y0, z0, x1, y1, z1)
        if nf == 0 and no == 0:
            return "unknown", b""
        inside = bx >= lo[0] and by >= lo[1] and bz >= lo[2] and bx + size <= hi[0] and by + size <= hi[1] \
            and bz + size <= hi[2]
        if inside and (nf == size ** 3 or no == size ** 3):
            return ("free" if nf else "occ"), b""
        half = size >> 1
        kids = [node(depth + 1, bx + half * (pos & 1), by + half * ((pos >> 1) & 1), bz + half * ((pos >> 2) & 1))
                for pos in range(8)]
        first = kids[0][0]
        if first != "inner" and all(k == first for k, _ in kids):
            return first, b""
        lo_byte = hi_byte = 0
        payload = bytearray()
        for i, (kind, data) in enumerate(kids):
            bits = bits_of.get(kind, 0)
            if i < 4:
                lo_byte |= bits << (2 * i)
            else:
                hi_byte |= bits << (2 * (i - 4))
            if kind != "unknown":
                n_nodes[0] += 1
            if kind == "inner":
                payload += data
        return "inner", bytes([lo_byte, hi_byte]) + bytes(payload)

    out = bytearray()
    kind, data = node(0, 0, 0, 0)
    if kind == "inner":
        out += data
        n_nodes[0] += 1  # the root
    elif kind in ("free", "occ"):  # a single leaf root (whole key space known): not for maps here
        raise ValueError("degenerate map: the root is a leaf")
    return bytes(out), n_nodes[0]


def write_bt(omap: OccupancyMap, path) -> int:
    """Writes `path` (.bt) atomically; returns the number of tree nodes."""
    data, n = _serialize(omap.classes(), omap.spec.key_offset())
    header = ("# Octomap OcTree binary file\n"
              "# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
              f"id OcTree\nsize {n}\nres {omap.spec.res:g}\ndata\n").encode()
    write_atomic(path, header + data)
    return n
