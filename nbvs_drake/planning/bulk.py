"""Collision checks in bulk: whole paths and steering edges checked inside one numba call, against
the conservative robot model of the free-space certificate (planning/clearance.py: the robot's
cylinders as exact vertical cylinders or as chains of spheres, one bounding sphere per geometry
tested first, the world's boxes), with early exit.

A path's states (interpolated so that no point of the robot moves more than about `max_step`
between consecutive ones, as `CollisionModel.interpolate`) are visited coarse to fine: every
`stride`-th state along the whole path first, then the rest, so an edge that collides anywhere is
usually rejected after a few states. The verdict of a path is

- FREE when every state is proved free (Drake would find each free: the certificate's proof),
- COLLIDING when its first state is proved free and some state is proved in collision,
- UNKNOWN otherwise: the caller asks Drake (`CollisionModel.path_free`), which stays the
  authority for every state the model cannot decide.

The steering edge of the trees and the roadmap (`motion.steer_together`: turn-drive-turn of the
base with the arm moving alongside, Euler-integrated) is computed here too, so a roadmap checks
thousands of edges without a Python call per edge. The controls of a path the robot executes are
always rebuilt in Python (`motion.steer_together`, `motion.rollout`) and checked again there.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .clearance import (
    COLLIDING,
    EPS,
    FREE,
    UNKNOWN,
    _arm_motion_bound,
    _classify_one,
    _free_margins,
    _geometry_reach,
    _pair_reach,
    _point_box,
    _pose_robot,
    _reach,
    _scratch,
    _vertical_cylinder_box,
    _vertical_cylinder_box_overlap,
    margin_size,
    unpack,
)
from .rrt import _sq_within

#: states visited in the first, coarse pass over a path: every STRIDE-th (and the last)
STRIDE = 8


@nb.njit(cache=True)
def _wrap(a):
    """`motion.wrap_angle` with numpy's floating remainder (fmod, then the divisor's sign), so
    the same bits."""
    b = 2 * np.pi
    m = np.fmod(a + np.pi, b)
    if m != 0.0:
        if m < 0.0:
            m += b
    else:
        m = 0.0
    return m - np.pi


@nb.njit(cache=True)
def interpolate(states, max_step):
    """`CollisionModel.interpolate` in numba (the same arithmetic, so the same states)."""
    n = states.shape[0]
    if n == 1:
        return states.copy()
    subs = np.empty(n - 1, np.int64)
    for i in range(n - 1):
        move = math.hypot(abs(states[i + 1, 0] - states[i, 0]), abs(states[i + 1, 1] - states[i, 1])) \
            + 1.4 * abs(states[i + 1, 2] - states[i, 2])
        s = 0.0
        for j in range(3, 8):
            s += abs(states[i + 1, j] - states[i, j])
        move += 0.7 * s
        subs[i] = max(1, int(math.ceil(move / max_step)))
    out = np.empty((1 + subs.sum(), 8))
    out[0] = states[0]
    r = 1
    for i in range(n - 1):
        for k in range(subs[i]):
            f = (k + 1) / subs[i]
            for j in range(8):
                out[r, j] = states[i, j] + f * (states[i + 1, j] - states[i, j])
            r += 1
    return out


@nb.njit(cache=True)
def _verdict_of_states(allq, model, scratch, stride, counter, undecided, bounds):
    """The verdict of a sequence of states (see the module docstring); counter[0] += states
    classified. A state proved FREE with a margin (`clearance._free_margins`) also proves FREE
    every state of the sequence that no point of the robot can reach from it by moving less than
    the margin (a bound of the motion summed along the sequence): those are not visited,
    and the verdict is the one of visiting every state. `undecided` (bool (n,), or empty: not
    wanted): set True at the states found UNKNOWN (all of them when the verdict is UNKNOWN
    and the first state is FREE). stride > 0: the first state, the last, every stride-th, then
    the rest; stride 0: `_walk`'s leapfrog order. bounds: `_bounds(model)`."""
    none = np.full(margin_size(model), -1.0)
    return _walk(allq, model, scratch, stride, counter, undecided, none, np.empty(none.shape[0]), bounds)


@nb.njit(cache=True)
def _bounds(model):
    """The motion bounds `_walk` takes: (clearance._reach, _pair_reach, _geometry_reach's
    per-joint reach), computed once per model."""
    return _reach(model), _pair_reach(model), _geometry_reach(model)[0]


#: the leapfrog walk (stride 0) probes this share of the last proved state's span ahead of the
#: first state not yet proved, so the probe's own margin, if like the last, reaches back to it
LEAP = 0.4


@nb.njit(cache=True)
def _walk(allq, model, scratch, stride, counter, undecided, start, end, bounds):
    """`_verdict_of_states` with the margins of the first state given (start (3 + P + 2G,):
    m_env, m_self, radius, the P robot pairs' clearances, the G geometries' clearances and
    radii, `clearance._free_margins`; not visited when m_env and m_self are > 0) and the last
    state's returned in end (m_env -1 where it was not visited or has none). A state further
    along is proved by the whole robot's bound against the least clearance, or else by each
    geometry's own motion bound (only the joints before its body, and its own radius for the
    base's turn, `clearance._geometry_reach`) against its own clearance; likewise each pair's
    relative motion (`clearance._pair_reach`: only the joints between its two geometries). The
    order of the visits changes only how many states are visited: every state is visited or
    proved by a visited state's margins, and a COLLIDING or UNKNOWN state is always visited,
    so the verdict and the undecided states are the same in every order. stride 0 (leapfrog):
    after the first and the last state, the state LEAP x (the span the last visited state
    proved) beyond the first state not yet proved, or that state itself when the last visit
    proved nothing. bounds: `_bounds(model)`."""
    n = allq.shape[0]
    reach, W, GW = bounds
    P, G = W.shape[0], GW.shape[0]
    end[0] = -1.0
    end[1] = -1.0
    # cumulative along the sequence (state 0 to state t): the base's travel, its turn, the arm's
    # motion bound (any point relative to the base), the turn weighted by the arm's motion
    # bound at the end (af) and at the start (ab) of each step, and each joint's travel (cq)
    xy, th, arm, af, ab = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    cq = np.zeros((n, 5))
    for t in range(1, n):
        a, b = allq[t - 1], allq[t]
        dth = abs(b[2] - a[2])
        xy[t] = xy[t - 1] + math.hypot(b[0] - a[0], b[1] - a[1])
        th[t] = th[t - 1] + dth
        arm[t] = arm[t - 1] + _arm_motion_bound(a, b, reach)
        af[t] = af[t - 1] + arm[t] * dth
        ab[t] = ab[t - 1] + arm[t - 1] * dth
        for k in range(5):
            cq[t, k] = cq[t - 1, k] + abs(b[3 + k] - a[3 + k])
    mg = np.empty(start.shape[0])  # the last visited state's margins
    pc, gc, gr = mg[3:3 + P], mg[3 + P:3 + P + G], mg[3 + P + G:]
    done = np.zeros(n, np.bool_)
    unknown = False
    span = 0
    u = 0  # every state before u is done
    k = -1
    while True:
        k += 1
        if k == 0:
            i = 0
        elif k == 1:
            i = n - 1  # most blocked extensions end in an obstacle
        elif stride > 0:
            i = (k - 2) * stride  # every stride-th, then the rest
            if i >= n:
                i = k - 2 - (n - 1) // stride - 1
                if i >= n:
                    break
        else:
            while u < n and done[u]:
                u += 1
            if u >= n:
                break
            i = min(n - 1, u + int(LEAP * span))
            while i > u and done[i]:
                i -= 1
        if done[i]:
            continue
        if i == 0 and start[0] > 0.0 and start[1] > 0.0:
            mg[:] = start
        else:
            counter[0] += 1
            mg[0], mg[1], mg[2] = _free_margins(allq[i], model, scratch, pc, gc, gr)
        m, ms, r = mg[0], mg[1], mg[2]
        if m > 0.0 and ms > 0.0:
            if i == n - 1:
                end[:] = mg
            # how far a point can get from where it is at state i: the base's travel, its
            # turn times the point's distance from the base's axis (at most r at state i,
            # plus the arm's motion since), and the arm's motion; per geometry, and each
            # pair's relative motion
            done[i] = True
            j = i + 1
            while j < n:
                turn = (af[j] - af[i]) - arm[i] * (th[j] - th[i])  # the turn times the arm's motion since
                if not ((xy[j] - xy[i]) + r * (th[j] - th[i]) + turn + (arm[j] - arm[i]) < m
                        or _geometries_clear(GW, cq, i, j, (xy[j] - xy[i]) + turn, th[j] - th[i], gc, gr)):
                    break
                if not (arm[j] - arm[i] < ms or _pairs_clear(W, cq, i, j, pc)):
                    break
                done[j] = True
                j += 1
            hi = j
            j = i - 1
            while j >= 0:
                turn = arm[i] * (th[i] - th[j]) - (ab[i] - ab[j])
                if not ((xy[i] - xy[j]) + r * (th[i] - th[j]) + turn + (arm[i] - arm[j]) < m
                        or _geometries_clear(GW, cq, j, i, (xy[i] - xy[j]) + turn, th[i] - th[j], gc, gr)):
                    break
                if not (arm[i] - arm[j] < ms or _pairs_clear(W, cq, j, i, pc)):
                    break
                done[j] = True
                j -= 1
            span = hi - j - 1
            continue
        span = 0
        v = _classify_one(allq[i], model, scratch)
        done[i] = True
        if v == FREE:
            continue
        if i == 0:
            return UNKNOWN
        if v == COLLIDING:
            return COLLIDING
        unknown = True
        if undecided.shape[0]:
            undecided[i] = True
    return UNKNOWN if unknown else FREE


@nb.njit(cache=True, inline="always")
def _geometries_clear(GW, cq, a, b, base, dth, gc, gr):
    """Every robot geometry g stays clear of the environment from state a to state b (a < b):
    the base's travel and the turn weighted by the arm's motion (base), plus its own radius
    times the turn dth, plus its own arm motion bound sum_k GW[g, k] (the joints' travel from
    a to b), is below its clearance gc[g]."""
    for g in range(GW.shape[0]):
        d = base + gr[g] * dth
        for k in range(5):
            d += GW[g, k] * (cq[b, k] - cq[a, k])
        if d >= gc[g]:
            return False
    return True


@nb.njit(cache=True, inline="always")
def _pairs_clear(W, cq, a, b, pc):
    """Every robot pair j stays clear from state a to state b (a < b): its relative motion
    bound sum_k W[j, k] (the joints' travel from a to b) is below its clearance pc[j]."""
    for j in range(W.shape[0]):
        d = 0.0
        for k in range(5):
            d += W[j, k] * (cq[b, k] - cq[a, k])
        if d >= pc[j]:
            return False
    return True


@nb.njit(cache=True)
def path_undecided(states, F, I, H, max_step, stride, counter):
    """(verdict, interpolated states, the indices of those the model cannot decide) of a path
    (`path_verdict`); with verdict UNKNOWN and no index, the first state is undecided."""
    model = unpack(F, I, H)
    allq = interpolate(states, max_step)
    undecided = np.zeros(allq.shape[0], np.bool_)
    v = _verdict_of_states(allq, model, _scratch(model), stride, counter, undecided, _bounds(model))
    return v, allq, np.flatnonzero(undecided)


@nb.njit(cache=True)
def path_verdict(states, F, I, H, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of a path's states (m+1, 8), interpolated at max_step."""
    model = unpack(F, I, H)
    return _verdict_of_states(interpolate(states, max_step), model, _scratch(model), stride, counter,
                              np.zeros(0, np.bool_), _bounds(model))


@nb.njit(cache=True)
def steer_together(q0, q1, dt, v_max, w_max, a_max):
    """`motion.steer_together` in numba: controls (n, 7)."""
    dx, dy = q1[0] - q0[0], q1[1] - q0[1]
    d = math.hypot(dx, dy)
    ph = np.zeros(3)
    if d < 1e-4:
        ph[0] = _wrap(q1[2] - q0[2])
    else:
        phi = math.atan2(dy, dx)
        f0, f2 = _wrap(phi - q0[2]), _wrap(q1[2] - phi)
        b0, b2 = _wrap(phi + np.pi - q0[2]), _wrap(q1[2] - phi - np.pi)
        if abs(f0) + abs(f2) <= abs(b0) + abs(b2):
            ph[0], ph[1], ph[2] = f0, d, f2
        else:
            ph[0], ph[1], ph[2] = b0, -d, b2
    counts = np.zeros(3, np.int64)
    for k in range(3):
        vmax = v_max if k == 1 else w_max
        if ph[k] != 0:
            counts[k] = int(math.ceil(abs(ph[k]) / (vmax * dt) - 1e-9))
    nb_ = counts.sum()
    dq = q1[3:] - q0[3:]
    need = 0
    amax = 0.0
    for j in range(5):
        amax = max(amax, abs(dq[j]))
    if amax > 0:
        need = int(math.ceil(amax / (a_max * dt) - 1e-9))
    n = max(need, nb_)
    out = np.zeros((n, 7))
    if n:
        for j in range(5):
            out[:, 2 + j] = dq[j] / (n * dt)
    r = 0
    for k in range(3):
        c = 0 if k == 1 else 1
        for _ in range(counts[k]):
            out[r, 0] = 0.0
            out[r, 1] = 0.0
            out[r, c] = ph[k] / (counts[k] * dt)
            r += 1
    return out


@nb.njit(cache=True)
def rollout(q0, controls, dt):
    """`motion.rollout` of one control sequence in numba (sequential sums, as np.cumsum)."""
    m = controls.shape[0]
    out = np.empty((m + 1, 8))
    out[0] = q0
    th = q0[2]
    for t in range(m):
        out[t + 1, 0] = out[t, 0] + controls[t, 0] * math.cos(th) * dt
        out[t + 1, 1] = out[t, 1] + controls[t, 0] * math.sin(th) * dt
        out[t + 1, 2] = out[t, 2] + controls[t, 1] * dt
        for j in range(5):
            out[t + 1, 3 + j] = out[t, 3 + j] + controls[t, 2 + j] * dt
        th = out[t + 1, 2]
    return out


@nb.njit(cache=True)
def path_length(states, w):
    """Eq. 8 of a path (m+1, 8), the base angle wrapped."""
    s = 0.0
    for t in range(states.shape[0] - 1):
        acc = 0.0
        for j in range(8):
            e = states[t + 1, j] - states[t, j]
            if j == 2:
                e = _wrap(e)
            acc += w[j] * e * e
        s += math.sqrt(acc)
    return s


@nb.njit(cache=True)
def edge_lengths(A, B, w, rc):
    """Eq. 8 lengths of the steering edges A[i] -> B[i] (rc: dt, v_max, w_max, a_max)."""
    out = np.empty(A.shape[0])
    for i in range(A.shape[0]):
        c = steer_together(A[i], B[i], rc[0], rc[1], rc[2], rc[3])
        out[i] = path_length(rollout(A[i], c, rc[0]), w)
    return out


@nb.njit(cache=True)
def edge_verdicts(A, B, F, I, H, rc, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of the steering edges A[i] -> B[i] (int8 (N,))."""
    model = unpack(F, I, H)
    out = np.empty(A.shape[0], np.int8)
    scratch = _scratch(model)
    none = np.zeros(0, np.bool_)
    bounds = _bounds(model)
    for i in range(A.shape[0]):
        c = steer_together(A[i], B[i], rc[0], rc[1], rc[2], rc[3])
        out[i] = _verdict_of_states(interpolate(rollout(A[i], c, rc[0]), max_step), model, scratch, stride,
                                    counter, none, bounds)
    return out


@nb.njit(cache=True)
def weighted_sq(a, b, w):
    acc = 0.0
    for j in range(8):
        e = a[j] - b[j]
        if j == 2:
            e = _wrap(e)
        acc += w[j] * e * e
    return acc


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


@nb.njit(cache=True)
def classify(Q, F, I, H, counter):
    """FREE / COLLIDING / UNKNOWN of states (N, 8)."""
    model = unpack(F, I, H)
    out = np.empty(Q.shape[0], np.int8)
    scratch = _scratch(model)
    for i in range(Q.shape[0]):
        out[i] = _classify_one(Q[i], model, scratch)
    counter[0] += Q.shape[0]
    return out


def robot_params(rc) -> np.ndarray:
    """The steering function's parameters of a RobotConfig as the kernels take them."""
    return np.array([rc.control_dt, rc.max_linear_velocity, rc.max_angular_velocity, rc.max_arm_velocity], float)


@nb.njit(cache=True)
def rollout_verdicts(states, nominal, c, r, F, I, H, counter):
    """FREE / COLLIDING / UNKNOWN (int8 (k, L)) of rollout states (k, L, 8) against the nominal
    states of the same steps (L, 8) and their part clearances (c, r (L, parts):
    `clearance._part_clearances`). A state whose arm equals the nominal's, at a step whose
    nominal state is proved free, differs from it by a planar rigid motion of the whole robot:
    its self-distances are the nominal's, and each part j of the robot with
    hypot(dx, dy) + r_j |dtheta| < c_j stays clear of the environment; only the other parts are
    tested (as `_classify_one` tests them: a ball inside them reaching into a box proves a
    collision, a part beyond every box's padding is free). Other states get `_classify_one`."""
    model = unpack(F, I, H)
    (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h, e_zal,
     e_exact, pairs, pair_pad) = model
    scratch = _scratch(model)
    G, M = g_body.shape[0], e_p.shape[0]
    P = c.shape[1]
    part_g = np.empty(P, np.int64)
    part_s = np.empty(P, np.int64)  # the sphere, or -1 for a vertical cylinder
    j = 0
    for g in range(G):
        if g_vert[g]:
            part_g[j], part_s[j] = g, -1
            j += 1
        else:
            for k in range(s0[g], s0[g + 1]):
                part_g[j], part_s[j] = g, k
                j += 1
    k_, L = states.shape[0], states.shape[1]
    nom_free = np.empty(L, np.bool_)
    for t in range(L):
        nom_free[t] = _classify_one(nominal[t], model, scratch) == FREE
    out = np.empty((k_, L), np.int8)
    fail = np.empty(P, np.bool_)
    for i in range(k_):
        for t in range(L):
            q = states[i, t]
            counter[0] += 1
            same = nom_free[t]
            for a in range(3, 8):
                if q[a] != nominal[t, a]:
                    same = False
                    break
            if not same:
                out[i, t] = _classify_one(q, model, scratch)
                continue
            dxy = math.hypot(q[0] - nominal[t, 0], q[1] - nominal[t, 1])
            dth = abs(_wrap(q[2] - nominal[t, 2]))
            n_fail = 0
            for j in range(P):
                fail[j] = dxy + r[t, j] * dth >= c[t, j]
                n_fail += fail[j]
            if n_fail == 0:
                out[i, t] = FREE
                continue
            _pose_robot(q, model, scratch)
            gp, sw = scratch[1], scratch[2]
            v = FREE
            for j in range(P):
                if not fail[j]:
                    continue
                g, kk = part_g[j], part_s[j]
                pad = g_pad[g]
                for m in range(M):
                    if kk < 0:  # a vertical cylinder
                        if pad >= 0.0 and e_exact[m] and e_zal[m] and _vertical_cylinder_box_overlap(
                                gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m, EPS):
                            v = COLLIDING
                            break
                        if e_zal[m]:
                            d = _vertical_cylinder_box(gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m)
                        else:
                            d = _point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m) - g_bound[g]
                        if d <= pad + EPS:
                            v = UNKNOWN
                    else:
                        d = _point_box(sw[kk, 0], sw[kk, 1], sw[kk, 2], e_R, e_p, e_h, m)
                        if pad >= 0.0 and e_exact[m] and d < s_in[kk] - EPS:
                            v = COLLIDING
                            break
                        if d <= s_rho[kk] + pad + EPS:
                            v = UNKNOWN
                if v == COLLIDING:
                    break
            out[i, t] = v
    return out


@nb.njit(cache=True)
def _sum8(d):
    """sum of 8 terms in numpy's pairwise order (as rrt._nearest and weighted_dist)."""
    return ((d[0] + d[1]) + (d[2] + d[3])) + ((d[4] + d[5]) + (d[6] + d[7]))


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
        scratch = _scratch(model)
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
    scratch = _scratch(model)
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
