"""Tree growth in numba: a batch of RRT extensions (the ORT's), each from the tree as it stood
before the batch, its edge checked by the path verdicts in the leapfrog order of `_walk`."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .certificate import COLLIDING, UNKNOWN, robot_scratch, unpack
from .neighbours import _nearest_grid
from .path_verdicts import _bounds, _walk, interpolate
from .steer_kernels import _sum8, _wrap, rollout, steer_together


@nb.njit(cache=True, parallel=True)
def tree_extensions(Q, margins, targets, w, step, rc, arm_lo, arm_hi, F, I, H, max_step, counter,
                    grid_params, n_side, head, nxt, n_chunks):
    """The extensions of `rrt.extend_batch` towards each of targets (B, 8) from the tree's
    vertices in the grid (`TreeGrid`, the rows of Q inserted so far) as they stand, computed
    and checked in one call with the same arithmetic as rrt._steer_edge and
    MotionPlanner.path_free: per target the nearest vertex,
    the clipped steering target, the new vertex (the end of the edge's rollout), the verdict
    FREE / COLLIDING / UNKNOWN, or -2 where the target is at the vertex or the steering gives
    no controls (COLLIDING includes an edge that leaves the arm's limits), and the edge's eq. 8
    length (its steps summed in order: equal to `motion.path_length`'s to ~1e-15 relative).
    The extensions are independent: they are spread over n_chunks chunks of targets
    (numba threads; each chunk its own scratch; a few chunks per thread even out their
    costs), the same outputs for any count. For the
    UNKNOWN edges, what to ask Drake: first (B,) bool (the edge's first state is undecided:
    ask about the whole edge), and the interpolated states of edge b that the model cannot
    decide, states[offsets[b]:offsets[b + 1]] (the edge is free iff Drake finds them all
    free); those few edges are walked again, in order, to collect them. The edges are walked
    in `_walk`'s leapfrog order from their vertex's margins (margins (capacity,
    `clearance.margin_size`), the rows of Q so far; m_env -1 where not known), and end (B,
    margin_size) returns the margins of each edge's last state (the vertex it adds) where the
    walk computed them."""
    B = targets.shape[0]
    near = np.empty(B, np.int64)
    length = np.zeros(B)
    aim = np.empty((B, 8))
    new = np.empty((B, 8))
    verdict = np.empty(B, np.int8)
    counts = np.zeros(B, np.int64)
    end = np.full((B, margins.shape[1]), -1.0)
    model = unpack(F, I, H)
    bounds = _bounds(model)
    n_chunks = max(1, min(n_chunks, B))
    for c in nb.prange(n_chunks):
        scratch = robot_scratch(model)
        none = np.zeros(0, np.bool_)
        for b in range(c * B // n_chunks, (c + 1) * B // n_chunks):
            i = _nearest_grid(Q, targets[b], w, grid_params, n_side, head, nxt)
            states = _extension_states(Q, i, targets[b], w, step, rc, arm_lo, arm_hi, b, near, aim, length)
            if states.shape[0] == 0:
                verdict[b] = -2
                continue
            new[b] = states[-1]
            if not _within_arm_limits(states, arm_lo, arm_hi):
                verdict[b] = COLLIDING
                continue
            verdict[b] = _walk(interpolate(states, max_step), model, scratch, 0, counts[b:b + 1], none,
                               margins[i], end[b], bounds)
    counter[0] += counts.sum()
    # the undecided states of the UNKNOWN edges (the same walk, with the states marked)
    first = np.zeros(B, np.bool_)
    offsets = np.zeros(B + 1, np.int64)
    parts = []
    scratch = robot_scratch(model)
    for b in range(B):
        offsets[b + 1] = offsets[b]
        if verdict[b] != UNKNOWN:
            continue
        allq = interpolate(_extension_states(Q, near[b], targets[b], w, step, rc, arm_lo, arm_hi, b, near, aim,
                                             length), max_step)
        und = np.zeros(allq.shape[0], np.bool_)
        _walk(allq, model, scratch, 0, counts[b:b + 1], und, margins[near[b]], np.empty(margins.shape[1]),
              bounds)
        idx = np.flatnonzero(und)
        first[b] = idx.shape[0] == 0
        parts.append(allq[idx])
        offsets[b + 1] = offsets[b] + idx.shape[0]
    out = np.empty((offsets[B], 8))
    k = 0
    for b in range(B):
        if verdict[b] == UNKNOWN:
            out[offsets[b]:offsets[b + 1]] = parts[k]
            k += 1
    return near, aim, new, verdict, length, first, offsets, out, end

@nb.njit(cache=True)
def _within_arm_limits(states, arm_lo, arm_hi):
    for t in range(states.shape[0]):
        for j in range(5):
            if states[t, 3 + j] < arm_lo[j] - 1e-9 or states[t, 3 + j] > arm_hi[j] + 1e-9:
                return False
    return True

@nb.njit(cache=True)
def _extension_states(Q, i, target, w, step, rc, arm_lo, arm_hi, b, near, aim, length):
    """The rollout states of the extension from vertex i towards `target` (near[b], aim[b]
    and length[b] filled in); an empty array where the target is at the vertex or the
    steering gives no controls."""
    d = np.empty(8)
    sq = np.empty(8)
    near[b] = i
    for j in range(8):
        d[j] = target[j] - Q[i, j]
    d[2] = _wrap(d[2])
    for j in range(8):
        sq[j] = w[j] * d[j] * d[j]
    dist = math.sqrt(_sum8(sq))
    if dist < 1e-9:
        return np.empty((0, 8))
    f = min(1.0, step / dist)
    for j in range(8):
        aim[b, j] = Q[i, j] + d[j] * f
    for j in range(5):
        aim[b, 3 + j] = min(max(aim[b, 3 + j], arm_lo[j]), arm_hi[j])
    c = steer_together(Q[i], aim[b], rc[0], rc[1], rc[2], rc[3])
    if c.shape[0] == 0:
        return np.empty((0, 8))
    states = rollout(Q[i], c, rc[0])
    length[b] = 0.0
    for t in range(states.shape[0] - 1):  # eq. 8, each step's terms in numpy's order
        for j in range(8):
            e = states[t + 1, j] - states[t, j]
            if j == 2:
                e = _wrap(e)
            sq[j] = w[j] * e * e
        length[b] += math.sqrt(_sum8(sq))
    return states
