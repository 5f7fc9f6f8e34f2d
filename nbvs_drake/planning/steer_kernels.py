"""The steering function and its rollout in numba (copies of `world.motion.steer_together` and
`world.motion.rollout`, Euler-integrated alike), the eq. 8 path length and weighted distances:
what the bulk checks of paths, trees and the roadmap integrate without a Python call per edge.
The controls of a path the robot executes are always rebuilt in Python and checked again."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


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
def weighted_sq(a, b, w):
    acc = 0.0
    for j in range(8):
        e = a[j] - b[j]
        if j == 2:
            e = _wrap(e)
        acc += w[j] * e * e
    return acc

def robot_params(rc) -> np.ndarray:
    """The steering function's parameters of a RobotConfig as the kernels take them."""
    return np.array([rc.control_dt, rc.max_linear_velocity, rc.max_angular_velocity, rc.max_arm_velocity], float)

@nb.njit(cache=True)
def _sum8(d):
    """sum of 8 terms in numpy's pairwise order (as rrt._nearest and weighted_dist)."""
    return ((d[0] + d[1]) + (d[2] + d[3])) + ((d[4] + d[5]) + (d[6] + d[7]))
