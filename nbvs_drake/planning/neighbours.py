"""Nearest-neighbour search in the weighted metric of eq. 8: k nearest vertices of a roadmap, and
a grid over the base position for the trees' nearest vertex."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .rrt import _sq_within
from .steer_kernels import weighted_sq


@nb.njit(cache=True)
def knn(V, Q, w, k, skip_self):
    """Indices (len(Q), k) of the k rows of V nearest to each row of Q in the weighted metric of
    eq. 8 (-1 where V has fewer); skip_self: Q is V, a row is not its own neighbour."""
    nq = Q.shape[0]
    out = np.full((nq, k), -1, np.int64)
    best = np.empty(k)
    for i in range(nq):
        best[:] = np.inf
        for v in range(V.shape[0]):
            if skip_self and v == i:
                continue
            d = weighted_sq(V[v], Q[i], w)
            if d < best[k - 1]:
                j = k - 1
                while j > 0 and best[j - 1] > d:
                    best[j] = best[j - 1]
                    out[i, j] = out[i, j - 1]
                    j -= 1
                best[j] = d
                out[i, j] = v
    return out

#: the cell size (m) of the tree's grid over the base's (x, y) (`TreeGrid`)
GRID_CELL = 0.25

class TreeGrid:
    """The tree's vertices bucketed by the base's (x, y) in cells of GRID_CELL, for
    `tree_extensions`' nearest-vertex search: the weighted distance of eq. 8 is at least the
    base's weighted planar distance, so the search visits rings of cells outwards and stops
    when the next ring is farther than the nearest vertex found (the same vertex as the brute
    force, ties to the lower index). A linked list per cell: head (cells,), next (capacity,)."""

    def __init__(self, xy_bounds, capacity: int, cell: float = GRID_CELL):
        lo, hi = float(xy_bounds[0]), float(xy_bounds[1])
        self.n_side = max(1, int(math.ceil((hi - lo) / cell)))
        self.params = np.array([lo, lo, cell], float)
        self.head = np.full(self.n_side * self.n_side, -1, np.int64)
        self.next = np.full(capacity, -1, np.int64)
        self.count = 0

    def insert(self, Q: np.ndarray, n: int):
        """Adds the vertices Q[count:n]."""
        _grid_insert(Q, self.count, n, self.params, self.n_side, self.head, self.next)
        self.count = n

    @property
    def arrays(self):
        return self.params, self.n_side, self.head, self.next

@nb.njit(cache=True, inline="always")
def _grid_cell(v, lo, cell, n_side):
    c = int(math.floor((v - lo) / cell))
    return min(max(c, 0), n_side - 1)

@nb.njit(cache=True)
def _grid_insert(Q, start, end, params, n_side, head, nxt):
    for i in range(start, end):
        c = _grid_cell(Q[i, 0], params[0], params[2], n_side) * n_side + _grid_cell(Q[i, 1], params[1], params[2],
                                                                                    n_side)
        nxt[i] = head[c]
        head[c] = i

@nb.njit(cache=True)
def _nearest_grid(Q, target, w, params, n_side, head, nxt):
    """rrt._nearest over the vertices in the grid (their weighted distances computed with the
    same arithmetic), visiting rings of cells around the target's until the ring's planar
    distance, weighted by the smaller of the x and y weights, reaches the best distance."""
    lo_x, lo_y, cell = params[0], params[1], params[2]
    cx = _grid_cell(target[0], lo_x, cell, n_side)
    cy = _grid_cell(target[1], lo_y, cell, n_side)
    wmin = min(w[0], w[1])
    # the target's distance to its own cell's border (0 outside the grid's bounds)
    border = max(0.0, min(target[0] - (lo_x + cx * cell), lo_x + (cx + 1) * cell - target[0],
                          target[1] - (lo_y + cy * cell), lo_y + (cy + 1) * cell - target[1]))
    best, best_d, best_sq = -1, np.inf, np.inf
    d = np.empty(8)
    for r in range(n_side + 1):
        if r > 0:
            # every vertex in ring r or beyond is at least (r - 1) cells plus that border away
            # in x or in y
            gap = (r - 1) * cell + border
            if wmin * gap * gap > best_sq:
                break
        for i0 in range(cx - r, cx + r + 1):
            if i0 < 0 or i0 >= n_side:
                continue
            for j0 in range(cy - r, cy + r + 1):
                if j0 < 0 or j0 >= n_side:
                    continue
                if max(abs(i0 - cx), abs(j0 - cy)) != r:
                    continue
                i = head[i0 * n_side + j0]
                while i >= 0:
                    sq = _sq_within(Q, i, target, w, d, best_sq, True)
                    if sq < np.inf:
                        sd = math.sqrt(sq)
                        if sd < best_d or (sd == best_d and i < best):
                            best, best_d, best_sq = i, sd, sq
                    i = nxt[i]
    return best
