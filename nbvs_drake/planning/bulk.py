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

from .clearance import COLLIDING, FREE, UNKNOWN, _classify_one, _scratch

#: states visited in the first, coarse pass over a path: every STRIDE-th (and the last)
STRIDE = 8


@nb.njit(cache=True)
def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


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
def _verdict_of_states(allq, model, scratch, stride, counter):
    """The verdict of a sequence of states (see the module docstring); counter[0] += states
    classified."""
    n = allq.shape[0]
    counter[0] += 1
    if _classify_one(allq[0], model, scratch) != FREE:
        return UNKNOWN
    unknown = False
    for phase in range(2):
        for i in range(1, n):
            coarse = (i % stride == 0) or i == n - 1
            if coarse != (phase == 0):
                continue
            counter[0] += 1
            v = _classify_one(allq[i], model, scratch)
            if v == COLLIDING:
                return COLLIDING
            if v == UNKNOWN:
                unknown = True
    return UNKNOWN if unknown else FREE


@nb.njit(cache=True)
def path_verdict(states, model, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of a path's states (m+1, 8), interpolated at max_step."""
    return _verdict_of_states(interpolate(states, max_step), model, _scratch(model), stride, counter)


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
def edge_verdicts(A, B, model, rc, max_step, stride, counter):
    """FREE / COLLIDING / UNKNOWN of the steering edges A[i] -> B[i] (int8 (N,))."""
    out = np.empty(A.shape[0], np.int8)
    scratch = _scratch(model)
    for i in range(A.shape[0]):
        c = steer_together(A[i], B[i], rc[0], rc[1], rc[2], rc[3])
        out[i] = _verdict_of_states(interpolate(rollout(A[i], c, rc[0]), max_step), model, scratch, stride,
                                    counter)
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
def classify(Q, model, counter):
    """FREE / COLLIDING / UNKNOWN of states (N, 8)."""
    out = np.empty(Q.shape[0], np.int8)
    scratch = _scratch(model)
    for i in range(Q.shape[0]):
        out[i] = _classify_one(Q[i], model, scratch)
    counter[0] += Q.shape[0]
    return out


def robot_params(rc) -> np.ndarray:
    """The steering function's parameters of a RobotConfig as the kernels take them."""
    return np.array([rc.control_dt, rc.max_linear_velocity, rc.max_angular_velocity, rc.max_arm_velocity], float)
