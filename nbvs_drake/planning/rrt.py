"""Trees in the robot's state space whose edges are exact control sequences: RRT Ext-Ext
(bidirectional, Vasquez-Gomez et al. 2017 §7.4) from the current state to a candidate, and the growth step
shared with the Object Reconstruction Tree (the ORT paper).

An edge from a to b is the steering function's 'together' controls (turn-drive-turn of the
base with the arm moving alongside), so the controls of a tree path, replayed by the Euler
model without noise, reach the path's end exactly. Distances are the weighted metric of
eq. 8 with the base angle wrapped.
"""

from __future__ import annotations

import dataclasses as dc
import math
from typing import Callable

import numba as nb
import numpy as np

from ..config import RobotConfig
from ..world.motion import rollout, steer_together, wrap_angle

StateSampler = Callable[[np.random.Generator, int], np.ndarray]

#: a tree search gives up after this many iterations (extension attempts) per vertex it may grow
ITERATIONS_PER_VERTEX = 20
PathFree = Callable[[np.ndarray], bool]


def weighted_dist(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """sqrt(sum_j w_j (a_j - b_j)^2) between rows of a (N, 8) and b (8,), angle wrapped."""
    d = np.asarray(a, float) - np.asarray(b, float)
    d[..., 2] = wrap_angle(d[..., 2])
    return np.sqrt(np.sum(w * d * d, axis=-1))


@nb.njit(cache=True, inline="always")
def _sq_within(Q, i, q, w, d, bound, ties):
    """sum_j w_j (Q[i, j] - q_j)^2 with numpy's arithmetic (the same wrapped angle, the same
    pairwise order of the 8 terms, d (8,) scratch), or inf when its first two terms already
    exceed `bound` (reach it, unless ties): the terms are >= 0 and rounding is monotone, so the
    full sum cannot be smaller (the base's x and y carry most of the default weights)."""
    e0 = Q[i, 0] - q[0]
    e1 = Q[i, 1] - q[1]
    d[0] = w[0] * e0 * e0
    d[1] = w[1] * e1 * e1
    if d[0] + d[1] > bound or (not ties and d[0] + d[1] == bound):
        return np.inf
    for j in range(2, 8):
        e = Q[i, j] - q[j]
        if j == 2:
            e = (e + np.pi) % (2 * np.pi) - np.pi
        d[j] = w[j] * e * e
    return ((d[0] + d[1]) + (d[2] + d[3])) + ((d[4] + d[5]) + (d[6] + d[7]))


@nb.njit(cache=True)
def _nearest(Q: np.ndarray, q: np.ndarray, w: np.ndarray) -> int:
    """argmin over the rows of Q of weighted_dist(Q, q, w), with numpy's arithmetic: the
    same wrapped angle and the same (pairwise) order of the 8-term sum, so the same index.
    A row whose first two terms already reach the best sum is skipped (`_sq_within`)."""
    best, best_d, best_sq = 0, np.inf, np.inf
    d = np.empty(8)
    for i in range(Q.shape[0]):
        sq = _sq_within(Q, i, q, w, d, best_sq, False)
        if sq == np.inf:
            continue
        s = math.sqrt(sq)
        if s < best_d:
            best, best_d, best_sq = i, s, sq
    return best


def edge(q0: np.ndarray, q1: np.ndarray, rc: RobotConfig) -> tuple[np.ndarray, np.ndarray]:
    """(controls, states) of the 'together' steering edge from q0 to q1."""
    controls = steer_together(q0, q1, rc)
    return controls, rollout(q0, controls, rc.control_dt)


class Tree:
    """Vertices (states), parent indices and the edge controls from each parent."""

    def __init__(self, root: np.ndarray, capacity: int, rc: RobotConfig | None = None):
        self.q = np.empty((capacity + 1, 8))
        self.q[0] = root
        self.parent = np.full(capacity + 1, -1, dtype=np.int64)
        self.cost = np.zeros(capacity + 1)  # eq. 8 path length from the root
        #: each vertex's edge controls from its parent, or None: steer_together(parent, aim[i])
        #: computed when a path needs it (`add`)
        self.controls: list[np.ndarray | None] = [np.zeros((0, 7))]
        self.aim = np.empty((capacity + 1, 8))
        self.rc = rc
        self.n = 1

    def nearest(self, q: np.ndarray, w: np.ndarray) -> int:
        return int(_nearest(self.q[: self.n], np.asarray(q, float), np.asarray(w, float)))

    def add(self, parent: int, q: np.ndarray, controls: np.ndarray | None, length: float,
            aim: np.ndarray | None = None) -> int:
        """A vertex q reached from `parent` by `controls`; or, with controls None, by the
        'together' steering to `aim` (computed by `controls_to` when a path needs it, as `edge`
        computes it)."""
        i = self.n
        self.q[i] = q
        if aim is not None:
            self.aim[i] = aim
        self.parent[i] = parent
        self.cost[i] = self.cost[parent] + length
        self.controls.append(controls)
        self.n += 1
        return i

    def edge_controls(self, i: int) -> np.ndarray:
        c = self.controls[i]
        if c is None:
            c = steer_together(self.q[self.parent[i]], self.aim[i], self.rc)
            self.controls[i] = c
        return c

    def path_to(self, i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out[::-1]

    def controls_to(self, i: int) -> np.ndarray:
        idx = self.path_to(i)
        parts = [self.edge_controls(j) for j in idx[1:]]
        return np.concatenate(parts) if parts else np.zeros((0, 7))


def _steer_edge(tree: Tree, q_target: np.ndarray, step: float, w: np.ndarray, rc: RobotConfig,
                clip_arm: Callable[[np.ndarray], np.ndarray]):
    """The edge EXTEND would try towards q_target: (nearest vertex, controls, states), or
    None when the target is (at) that vertex or the steering gives no controls."""
    i_near = tree.nearest(q_target, w)
    q_near = tree.q[i_near]
    d = np.asarray(q_target, float) - q_near
    d[2] = wrap_angle(d[2])
    dist = float(np.sqrt(np.sum(w * d * d)))
    if dist < 1e-9:
        return None
    controls, states = edge(q_near, clip_arm(q_near + d * min(1.0, step / dist)), rc)
    return (i_near, controls, states) if len(controls) else None


def extend(tree: Tree, q_target: np.ndarray, step: float, w: np.ndarray, rc: RobotConfig,
           path_free: PathFree, clip_arm: Callable[[np.ndarray], np.ndarray]) -> int | None:
    """EXTEND: from the nearest vertex towards q_target by at most `step` (weighted metric);
    adds the new vertex when its steering edge is collision free. Returns its index or None."""
    from ..world.motion import path_length
    e = _steer_edge(tree, q_target, step, w, rc, clip_arm)
    if e is None or not path_free(e[2]):
        return None
    i_near, controls, states = e
    return tree.add(i_near, states[-1], controls, path_length(states, w))


def extend_batch(tree: Tree, targets: np.ndarray, step: float, w: np.ndarray, rc: RobotConfig,
                 paths_free: Callable[[list[np.ndarray]], np.ndarray],
                 clip_arm: Callable[[np.ndarray], np.ndarray]) -> int:
    """EXTEND towards each of `targets` (B, 8) from the tree as it stands (the nearest
    vertices are found before any of the batch is added), with the B edges checked in one
    call of `paths_free`; the free ones are added in the targets' order, up to the tree's
    capacity. Returns the number of vertices added. B = 1 is `extend`."""
    from ..world.motion import path_length
    cands = [e for e in (_steer_edge(tree, q, step, w, rc, clip_arm) for q in targets) if e is not None]
    if not cands:
        return 0
    free = paths_free([c[2] for c in cands])
    added = 0
    for (i_near, controls, states), ok in zip(cands, free):
        if ok and tree.n < tree.q.shape[0]:
            tree.add(i_near, states[-1], controls, path_length(states, w))
            added += 1
    return added


@dc.dataclass
class RRTResult:
    found: bool
    controls: np.ndarray | None = None
    states: np.ndarray | None = None
    vertices: int = 0
    iterations: int = 0
    path_nodes: int = 0  #: the vertices of the trees the path runs through (its two ends included)


def rrt_ext_ext(q_start: np.ndarray, q_goal: np.ndarray, rc: RobotConfig, w: np.ndarray,
                sample: StateSampler, path_free: PathFree, clip_arm, rng: np.random.Generator,
                max_nodes: int = 10_000, step: float = 1.0, connect_tol: float = 0.3,
                goal_bias: float = 0.1) -> RRTResult:
    """Bidirectional RRT, both trees extended each iteration (Ext-Ext), the second towards the
    first's new vertex. When the two new vertices are within `connect_tol` (weighted metric)
    and the steering edge between them is free, the path start -> ... -> a -> b -> ... -> goal
    is returned with its controls (edges of the goal tree are re-steered in the travel
    direction and re-checked). Gives up after max_nodes vertices or ITERATIONS_PER_VERTEX x
    max_nodes iterations (as the ORT's growth): two trees in pockets that no extension
    leaves would otherwise never stop."""
    ta, tb = Tree(q_start, max_nodes), Tree(q_goal, max_nodes)
    a_is_start = True
    it = 0
    while ta.n + tb.n < max_nodes and it < ITERATIONS_PER_VERTEX * max_nodes:
        it += 1
        target_tree = tb if rng.random() < goal_bias else None
        q_rand = target_tree.q[0] if target_tree is not None else sample(rng, 1)[0]
        ia = extend(ta, q_rand, step, w, rc, path_free, clip_arm)
        if ia is None:
            ta, tb, a_is_start = tb, ta, not a_is_start
            continue
        ib = extend(tb, ta.q[ia], step, w, rc, path_free, clip_arm)
        for i_b in ([ib] if ib is not None else []) + [tb.nearest(ta.q[ia], w)]:
            if weighted_dist(tb.q[i_b][None], ta.q[ia], w)[0] <= connect_tol:
                res = _join(ta, ia, tb, i_b, a_is_start, rc, path_free)
                if res is not None:
                    controls, states, nodes = res
                    return RRTResult(True, controls, states, ta.n + tb.n, it, nodes)
        ta, tb, a_is_start = tb, ta, not a_is_start
    return RRTResult(False, vertices=ta.n + tb.n, iterations=it)


def _join(ta: Tree, ia: int, tb: Tree, ib: int, a_is_start: bool, rc: RobotConfig, path_free: PathFree):
    s_tree, s_i, g_tree, g_i = (ta, ia, tb, ib) if a_is_start else (tb, ib, ta, ia)
    parts = [s_tree.controls_to(s_i)]
    q = s_tree.q[s_i]
    q_start = s_tree.q[0]
    # bridge and then down the goal tree towards its root, steering in the travel direction
    chain = g_tree.path_to(g_i)[::-1]  # g_i ... root(goal)
    for j in chain:
        controls, states = edge(q, g_tree.q[j], rc)
        if len(controls) and not path_free(states):
            return None
        parts.append(controls)
        q = states[-1]
    controls = np.concatenate(parts)
    return controls, rollout(q_start, controls, rc.control_dt), len(s_tree.path_to(s_i)) + len(chain)
