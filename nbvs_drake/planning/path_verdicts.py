"""Collision checks in bulk: whole paths and steering edges checked inside one numba call, against
the conservative robot model of the free-space certificate (planning/certificate.py: the robot's
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

from .certificate import (
    COLLIDING,
    EPS,
    FREE,
    UNKNOWN,
    arm_motion_bound,
    classify_state,
    free_margins,
    geometry_reaches,
    margin_size,
    model_reach,
    pair_reaches,
    point_box,
    pose_robot,
    robot_scratch,
    unpack,
    vertical_cylinder_box,
    vertical_cylinder_box_overlap,
)
from .steer_kernels import _wrap, rollout, steer_together

#: states visited in the first, coarse pass over a path: every STRIDE-th (and the last)
STRIDE = 8

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
    classified. A state proved FREE with a margin (`clearance.free_margins`) also proves FREE
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
    """The motion bounds `_walk` takes: (clearance.model_reach, pair_reaches, geometry_reaches's
    per-joint reach), computed once per model."""
    return model_reach(model), pair_reaches(model), geometry_reaches(model)[0]

#: the leapfrog walk (stride 0) probes this share of the last proved state's span ahead of the
#: first state not yet proved, so the probe's own margin, if like the last, reaches back to it
LEAP = 0.4

@nb.njit(cache=True)
def _walk(allq, model, scratch, stride, counter, undecided, start, end, bounds):
    """`_verdict_of_states` with the margins of the first state given (start (3 + P + 2G,):
    m_env, m_self, radius, the P robot pairs' clearances, the G geometries' clearances and
    radii, `clearance.free_margins`; not visited when m_env and m_self are > 0) and the last
    state's returned in end (m_env -1 where it was not visited or has none). A state further
    along is proved by the whole robot's bound against the least clearance, or else by each
    geometry's own motion bound (only the joints before its body, and its own radius for the
    base's turn, `clearance.geometry_reaches`) against its own clearance; likewise each pair's
    relative motion (`clearance.pair_reaches`: only the joints between its two geometries). The
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
        arm[t] = arm[t - 1] + arm_motion_bound(a, b, reach)
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
            mg[0], mg[1], mg[2] = free_margins(allq[i], model, scratch, pc, gc, gr)
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
        v = classify_state(allq[i], model, scratch)
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
    v = _verdict_of_states(allq, model, robot_scratch(model), stride, counter, undecided, _bounds(model))
    return v, allq, np.flatnonzero(undecided)

@nb.njit(cache=True)
def path_verdict(states, F, I, H, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of a path's states (m+1, 8), interpolated at max_step."""
    model = unpack(F, I, H)
    return _verdict_of_states(interpolate(states, max_step), model, robot_scratch(model), stride, counter,
                              np.zeros(0, np.bool_), _bounds(model))

@nb.njit(cache=True)
def edge_verdicts(A, B, F, I, H, rc, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of the steering edges A[i] -> B[i] (int8 (N,))."""
    model = unpack(F, I, H)
    out = np.empty(A.shape[0], np.int8)
    scratch = robot_scratch(model)
    none = np.zeros(0, np.bool_)
    bounds = _bounds(model)
    for i in range(A.shape[0]):
        c = steer_together(A[i], B[i], rc[0], rc[1], rc[2], rc[3])
        out[i] = _verdict_of_states(interpolate(rollout(A[i], c, rc[0]), max_step), model, scratch, stride,
                                    counter, none, bounds)
    return out

@nb.njit(cache=True)
def classify(Q, F, I, H, counter):
    """FREE / COLLIDING / UNKNOWN of states (N, 8)."""
    model = unpack(F, I, H)
    out = np.empty(Q.shape[0], np.int8)
    scratch = robot_scratch(model)
    for i in range(Q.shape[0]):
        out[i] = classify_state(Q[i], model, scratch)
    counter[0] += Q.shape[0]
    return out

#: `rollout_verdicts` skips a box whose clearance from a part exceeds the part's motion bound
#: by more than this (m): far above the rounding of either, so the verdicts are those of
#: testing every box
NEAR_MARGIN = 1e-9


@nb.njit(cache=True)
def states_free(Q, F, I, H):
    """Whether each of the states (N, 8) is proved FREE by `classify_state` (bool (N,); not
    counted: `rollout_verdicts`' nominal states)."""
    model = unpack(F, I, H)
    scratch = robot_scratch(model)
    out = np.empty(Q.shape[0], np.bool_)
    for i in range(Q.shape[0]):
        out[i] = classify_state(Q[i], model, scratch) == FREE
    return out

@nb.njit(cache=True, parallel=True)
def rollout_verdicts(states, steps, nominal, nom_free, c, r, slack, F, I, H, counter):
    """FREE / COLLIDING / UNKNOWN (int8 (k, L)) of rollout states (k, L, 8) at the plan's steps
    `steps` (L,: rows of the others) against the plan's nominal states (n, 8), whether each is
    proved free (nom_free (n,): `states_free`) and their part clearances (c, r (n, parts),
    slack (n, parts, boxes): `Certificate.part_box_clearances`; rows not in `steps` are not
    read). A state whose arm equals the nominal's, at a step whose nominal state is proved free,
    differs from it by a planar rigid motion of the whole robot: its self-distances are the
    nominal's, and each part j of the robot with hypot(dx, dy) + r_j |dtheta| < c_j stays clear
    of the environment; only the other parts are tested (as `classify_state` tests them: a ball
    inside them reaching into a box proves a collision, a part beyond every box's padding is
    free), each only against the boxes whose clearance from it the motion may use up (slack
    within NEAR_MARGIN of its bound: the others' tests cannot fire, so the verdicts are those of
    testing every box). Other states get `classify_state`. The rollouts run on numba's threads,
    each with its own scratch (the same verdicts)."""
    model = unpack(F, I, H)
    (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h, e_zal,
     e_exact, pairs, pair_pad) = model
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
    out = np.empty((k_, L), np.int8)
    counter[0] += k_ * L
    for i in nb.prange(k_):  # the rollouts on numba's threads, each with its own scratch
        scratch_i = robot_scratch(model)
        fail = np.empty(P, np.bool_)
        for tt in range(L):
            q = states[i, tt]
            t = steps[tt]
            same = nom_free[t]
            for a in range(3, 8):
                if q[a] != nominal[t, a]:
                    same = False
                    break
            if not same:
                out[i, tt] = classify_state(q, model, scratch_i)
                continue
            dxy = math.hypot(q[0] - nominal[t, 0], q[1] - nominal[t, 1])
            dth = abs(_wrap(q[2] - nominal[t, 2]))
            n_fail = 0
            for j in range(P):
                fail[j] = dxy + r[t, j] * dth >= c[t, j]
                n_fail += fail[j]
            if n_fail == 0:
                out[i, tt] = FREE
                continue
            pose_robot(q, model, scratch_i)
            gp, sw = scratch_i[1], scratch_i[2]
            v = FREE
            for j in range(P):
                if not fail[j]:
                    continue
                g, kk = part_g[j], part_s[j]
                pad = g_pad[g]
                reach = dxy + r[t, j] * dth + NEAR_MARGIN
                for m in range(M):
                    if slack[t, j, m] > reach:  # out of the part's reach
                        continue
                    if kk < 0:  # a vertical cylinder
                        if pad >= 0.0 and e_exact[m] and e_zal[m] and vertical_cylinder_box_overlap(
                                gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m, EPS):
                            v = COLLIDING
                            break
                        if e_zal[m]:
                            d = vertical_cylinder_box(gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m)
                        else:
                            d = point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m) - g_bound[g]
                        if d <= pad + EPS:
                            v = UNKNOWN
                    else:
                        d = point_box(sw[kk, 0], sw[kk, 1], sw[kk, 2], e_R, e_p, e_h, m)
                        if pad >= 0.0 and e_exact[m] and d < s_in[kk] - EPS:
                            v = COLLIDING
                            break
                        if d <= s_rho[kk] + pad + EPS:
                            v = UNKNOWN
                if v == COLLIDING:
                    break
            out[i, tt] = v
    return out
