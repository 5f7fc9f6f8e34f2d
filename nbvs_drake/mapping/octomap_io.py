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
    whose voxel (0, 0, 0) has key `off`. Returns (bytes, number of nodes)."""
    dims = np.array(classes.shape)
    lo_key, hi_key = off, off + dims  # [lo, hi) per axis
    out = bytearray()
    n_nodes = [0]

    def node(depth, base):
        """Returns ('unknown' | 'free' | 'occ' | 'inner', payload bytes)."""
        size = 1 << (TREE_DEPTH - depth)
        if np.any(base + size <= lo_key) or np.any(base >= hi_key):
            return "unknown", b""
        if size == 1:
            c = classes[tuple(base - off)]
            return ("free" if c == FREE else "occ" if c == OCCUPIED else "unknown"), b""
        half = size >> 1
        kids = []
        for pos in range(8):
            child_base = base + half * np.array([pos & 1, (pos >> 1) & 1, (pos >> 2) & 1])
            kids.append(node(depth + 1, child_base))
        kinds = [k for k, _ in kids]
        if all(k == "free" for k in kinds):
            return "free", b""
        if all(k == "occ" for k in kinds):
            return "occ", b""
        if all(k == "unknown" for k in kinds):
            return "unknown", b""
        lo_byte = hi_byte = 0
        payload = bytearray()
        for i, (kind, data) in enumerate(kids):
            bits = {"free": _FREE_BITS, "occ": _OCC_BITS, "inner": _INNER_BITS}.get(kind, 0)
            if i < 4:
                lo_byte |= bits << (2 * i)
            else:
                hi_byte |= bits << (2 * (i - 4))
            if kind != "unknown":
                n_nodes[0] += 1
            if kind == "inner":
                payload += data
        return "inner", bytes([lo_byte, hi_byte]) + bytes(payload)

    kind, data = node(0, np.zeros(3, np.int64))
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
