"""Motion model of Vasquez-Gomez et al. 2017 §6: velocity controls u = [v, w_b, w_1..w_5] held for dt, Euler
integration of the non-holonomic base, truncated Gaussian control noise; the steering
function that turns a start/goal pair into controls; the weighted path length (eq. 8)."""

from __future__ import annotations

import dataclasses as dc
import math
from typing import Optional

import numpy as np
from scipy.special import ndtr, ndtri

from ..config import REGISTERED_SIGMA, NoiseConfig, RobotConfig  # noqa: F401 (REGISTERED_SIGMA: re-exported)
from .state import NQ, NU


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def wrap_scalar(a: float) -> float:
    """`wrap_angle` of one angle, as a float (the same value: Python's float % is numpy's)."""
    return (float(a) + math.pi) % (2 * math.pi) - math.pi


@dc.dataclass(frozen=True)
class ControlSequence:
    """tau = {u_1..u_m}: each row [v, w_b, w_1..w_5] is held for dt. plan_id identifies the
    plan (0 = no motion, the initial state). `states` are the m+1 planned states. `purpose`:
    "view" (to a planned view), "correct" (an exact re-aim back to it) or "relocalise" (a
    re-localisation view), and `target`, the state whose view a verified view checks the frame
    at the plan's end against (mission.verify_views; planning/recovery.py)."""
    plan_id: int
    dt: float
    controls: np.ndarray
    states: np.ndarray
    purpose: str = "view"
    target: np.ndarray | None = None

    def __deepcopy__(self, memo):  # immutable value
        return self

    @property
    def m(self) -> int:
        return len(self.controls)

    @staticmethod
    def empty(q: np.ndarray, dt: float = 0.1, plan_id: int = 0) -> "ControlSequence":
        return ControlSequence(plan_id, dt, np.zeros((0, NU)), np.asarray(q, float)[None].copy())


def euler_step(q: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """x_t = x + v cos(theta) dt, y_t = y + v sin(theta) dt, theta_t = theta + w_b dt,
    q_i,t = q_i + w_i dt (Vasquez-Gomez et al. 2017 §6.2). Broadcasts over leading dimensions."""
    q = np.asarray(q, float)
    u = np.asarray(u, float)
    out = np.array(q, copy=True)
    th = q[..., 2]
    out[..., 0] = q[..., 0] + u[..., 0] * np.cos(th) * dt
    out[..., 1] = q[..., 1] + u[..., 0] * np.sin(th) * dt
    out[..., 2] = th + u[..., 1] * dt
    out[..., 3:] = q[..., 3:] + u[..., 2:] * dt
    return out


def rollout(q0: np.ndarray, controls: np.ndarray, dt: float) -> np.ndarray:
    """States (m+1, 8) (or (..., m+1, 8) when controls have leading dims) of the Euler model.

    Vectorised over time: the heading and the joints are running sums of w dt, and x, y the
    running sums of v cos(theta) dt, v sin(theta) dt at the previous heading. np.cumsum adds
    sequentially, so the states are bit for bit those of applying `euler_step` m times
    (tests/test_kinematic_plant.py checks it), 30-40x faster for one plan's controls."""
    controls = np.asarray(controls, float)
    lead = controls.shape[:-2]
    inc = np.zeros(lead + (controls.shape[-2] + 1, NQ))
    inc[..., 0, :] = np.asarray(q0, float)
    inc[..., 1:, 2] = controls[..., 1] * dt
    inc[..., 1:, 3:] = controls[..., 2:] * dt
    th = np.cumsum(inc[..., 2], axis=-1)[..., :-1]  # heading before each step
    inc[..., 1:, 0] = controls[..., 0] * np.cos(th) * dt
    inc[..., 1:, 1] = controls[..., 0] * np.sin(th) * dt
    return np.cumsum(inc, axis=-2)


def path_length(states: np.ndarray, weights) -> float:
    """rho = sum_i sqrt(sum_j w_j (x_i(a_j) - x_{i-1}(a_j))^2), eq. 8 (base angle wrapped)."""
    s = np.asarray(states, float)
    d = s[1:] - s[:-1]
    d[:, 2] = wrap_angle(d[:, 2])
    return float(np.sqrt((np.asarray(weights, float) * d * d).sum(axis=1)).sum())


# --------------------------------------------------------------------------------------
# Noise
# --------------------------------------------------------------------------------------


def noise_sigmas(noise: NoiseConfig) -> np.ndarray:
    return np.array([noise.sigma_v, noise.sigma_w] + list(noise.sigma_arm), float)


def control_sigmas(noise: NoiseConfig, controls: np.ndarray) -> np.ndarray:
    """Per-step standard deviations (m, NU) of the noise on `controls` (m, NU): Table 4's
    sigmas on every component, except where the command is exactly 0, which is executed
    exactly."""
    controls = np.asarray(controls, float)
    sig = np.broadcast_to(noise_sigmas(noise), controls.shape)
    return np.where(controls != 0.0, sig, 0.0)


def sample_control_noise(rng: np.random.Generator, noise: NoiseConfig, controls: np.ndarray,
                         n: int | None = None) -> np.ndarray:
    """Noise for executing `controls` (m, NU): (m, NU), or (n, m, NU) for n rollouts; truncated
    at +-beta sigma per component, zero where `control_sigmas` is zero. The same generator
    draws give the same noise on the commanded components whatever the zero-command rule."""
    controls = np.asarray(controls, float)
    shape = (len(controls),) if n is None else (n, len(controls))
    # sample_truncated_normal's draws, its inverse CDF taken only where the noise acts (the
    # same numbers there, zero elsewhere: Table 4 leaves the arm and the uncommanded exact)
    sigma = noise_sigmas(noise)
    u = _truncated_uniform(rng, noise.beta, shape + (len(sigma),))
    sig = np.broadcast_to(sigma, controls.shape).ravel()
    act = np.flatnonzero(control_sigmas(noise, controls).ravel() > 0)  # (step, component) pairs
    flat = u.reshape(-1, max(controls.size, 1))
    eps = np.zeros(flat.shape)
    eps[:, act] = ndtri(flat[:, act]) * sig[act]
    return eps.reshape(u.shape)


def sample_truncated_normal(rng: np.random.Generator, sigma: np.ndarray, beta: float, shape) -> np.ndarray:
    """Zero-mean normal samples with standard deviations `sigma` (broadcast over the last
    axis), truncated to [-beta sigma, beta sigma] by inverse-CDF sampling."""
    return ndtri(_truncated_uniform(rng, beta, tuple(shape) + (len(sigma),))) * sigma


def _truncated_uniform(rng: np.random.Generator, beta: float, shape) -> np.ndarray:
    """The uniform draws of sample_truncated_normal: their inverse normal CDF is the sample."""
    lo = ndtr(-beta)
    return rng.uniform(lo, 1.0 - lo, size=shape)


def truncated_normal_logpdf(eps: np.ndarray, sigma: np.ndarray, beta: float) -> np.ndarray:
    """Log density of the truncated normal per component; components with sigma = 0 are
    deterministic and contribute 0. Summed over the last axis."""
    sigma = np.asarray(sigma, float)
    active = sigma > 0
    s = np.where(active, sigma, 1.0)
    z = eps / s
    norm = np.log(ndtr(beta) - ndtr(-beta))
    lp = -0.5 * z * z - np.log(s) - 0.5 * math.log(2 * math.pi) - norm
    return np.sum(np.where(active, lp, 0.0), axis=-1)



@dc.dataclass(frozen=True)
class TurnDrift:
    """legs.turn_drift: a turn in place too short to be a long one still ends a leg when the
    drive after it would carry the heading spread a frame there removes more than `limit`
    sideways: 3 (step sqrt(n) - floor) d > limit for a turn of n steps and a drive of d m,
    where step = sigma_w dt is one step's heading spread and floor what a frame and one
    corrective step leave (`LegRule.of`)."""
    step: float  #: rad, sigma_w dt
    floor: float  #: rad
    limit: float  #: m
    dt: float  #: s, the control period (a drive's length is sum |v| dt)

    def ends_leg(self, turn_steps: int, drive_m: float) -> bool:
        return 3.0 * (self.step * math.sqrt(turn_steps) - self.floor) * drive_m > self.limit


@dc.dataclass(frozen=True)
class LegRule:
    """Where a plan's legs end (localisation.verified_views.legs): `on` when plans run in legs
    (verified views with legs, under motion noise); `min_turn_steps` > 0 (legs.after_turns):
    a leg also ends after a turn in place of at least that many steps that a drive follows;
    `drift` (legs.turn_drift > 0, with after_turns): also after a shorter turn whose heading
    spread the drive after it would carry too far sideways (`TurnDrift`)."""
    on: bool
    min_turn_steps: int
    after_drives: bool = True  #: legs.after_drives
    drift: Optional[TurnDrift] = None

    @staticmethod
    def of(verified_views, noise: NoiseConfig, control_dt: float) -> "LegRule":
        """The rule of the localisation section's verified views, the noise and the control period."""
        vv = verified_views
        legs = vv.legs if vv is not None else None
        on = bool(legs is not None and np.any(noise_sigmas(noise) > 0))
        steps, drift = 0, None
        step = noise.sigma_w * control_dt
        if legs is not None and legs.after_turns and step > 0:
            # the first turn whose heading spread, sigma_w dt sqrt(n), is more than twice what a
            # frame leaves (the registration's heading error and one step of corrective turn)
            floor = math.hypot(REGISTERED_SIGMA[2], step)
            steps = int(math.floor((2.0 * floor / step) ** 2)) + 1
            if legs.turn_drift > 0:
                drift = TurnDrift(step, floor, float(legs.turn_drift), float(control_dt))
        return LegRule(on, steps, bool(legs is None or legs.after_drives), drift)

    def ends(self, controls: np.ndarray) -> list[int]:
        """Where a plan's legs end: `leg_ends` when plans run in legs, else [m]."""
        if not self.on:
            return [len(np.asarray(controls).reshape(-1, NU))]
        return leg_ends(controls, self.min_turn_steps, self.after_drives, self.drift)

    def turn_ends(self, controls: np.ndarray) -> list[int]:
        """Where a re-planned leg (turn, drive, turn) ends after its turns alone (the leg's own
        drive is its end), as `ends` with after_drives off; [m] without after_turns."""
        if not self.min_turn_steps:
            return [len(np.asarray(controls).reshape(-1, NU))]
        return leg_ends(controls, self.min_turn_steps, False, self.drift)


def _drive_after(c: np.ndarray, drive: np.ndarray, dt: float) -> np.ndarray:
    """For each step i, the length (m) of the drive that starts at step i + 1 (0 if none)."""
    m = len(c)
    out = np.zeros(m)
    run = 0.0
    for i in range(m - 1, 0, -1):  # run: the drive starting at step i
        run = run + abs(c[i, 0]) * dt if drive[i] else 0.0
        out[i - 1] = run
    return out


def leg_ends(controls: np.ndarray, min_turn_steps: int = 0, after_drives: bool = True,
             drift: Optional[TurnDrift] = None) -> list[int]:
    """The legs of a plan (verified views' legs): the end index (exclusive, into the controls) of
    each, one after every drive phase (v != 0) that more base motion follows, and the last
    at m. A plan with one drive, or none, is one leg unless a turn follows its drive.
    min_turn_steps > 0 (legs.after_turns): a leg also ends after every turn in place
    (omega != 0, v = 0) of at least that many steps that a drive follows, so the frame there
    fixes the heading before the drive; with `drift` (legs.turn_drift), also after a shorter
    turn that the drive after it would carry too far sideways (`TurnDrift.ends_leg`).
    after_drives=False (legs.after_drives): only ends after turns, and then after the turning
    steps since the last end add up to min_turn_steps (one long turn or several shorter ones),
    or to a turn `drift` ends, before the drive that follows them."""
    c = np.asarray(controls, float).reshape(-1, NU)
    m = len(c)
    drive = c[:, 0] != 0.0
    turn = (c[:, 1] != 0.0) & ~drive
    ahead = _drive_after(c, drive, drift.dt) if drift is not None and m else np.zeros(m)

    def long_turn(i: int, n: int) -> bool:
        return min_turn_steps > 0 and (n >= min_turn_steps or (drift is not None and drift.ends_leg(n, ahead[i])))
    if after_drives:
        later = np.zeros(m, bool)  # base motion after step i
        run = np.zeros(m, int)  # steps of the turn that ends at step i
        if m:
            later[:-1] = np.cumsum((drive | turn)[::-1])[::-1][1:] > 0
        for i in range(m):
            run[i] = (run[i - 1] + 1 if i else 1) if turn[i] else 0
        ends = [i + 1 for i in range(m - 1) if (drive[i] and not drive[i + 1] and later[i])
                or (turn[i] and drive[i + 1] and long_turn(i, int(run[i])))]
        return ends + [m]
    # after turns only: the heading's spread grows with every turning step since the last
    # frame, so a leg ends before the drive that follows min_turn_steps of them in all (one
    # long turn, or several shorter ones between drives)
    ends, acc = [], 0
    for i in range(m - 1):
        acc += int(turn[i])
        if turn[i] and drive[i + 1] and long_turn(i, acc):
            ends.append(i + 1)
            acc = 0
    return ends + [m]




# --------------------------------------------------------------------------------------
# Steering
# --------------------------------------------------------------------------------------


def _base_phases(q0, q1):
    """Turn-drive-turn for the in-place turning base, as (d_theta1, d_drive, d_theta2),
    choosing forward or backward driving by the smaller total rotation."""
    dx, dy = q1[0] - q0[0], q1[1] - q0[1]
    d = math.hypot(dx, dy)
    if d < 1e-4:
        return [(wrap_scalar(q1[2] - q0[2]), 0.0, 0.0)]
    phi = math.atan2(dy, dx)
    fwd = (wrap_scalar(phi - q0[2]), d, wrap_scalar(q1[2] - phi))
    back = (wrap_scalar(phi + math.pi - q0[2]), -d, wrap_scalar(q1[2] - phi - math.pi))
    cost = lambda p: abs(p[0]) + abs(p[2])  # noqa: E731
    return [fwd, back] if cost(fwd) <= cost(back) else [back, fwd]


def _base_controls(ph, rc: RobotConfig) -> np.ndarray:
    """The base's phases (turn, drive, turn) as constant-velocity controls: each phase in the
    fewest steps that keep its one moving component (v or w_b) within its limit, covering
    the phase exactly."""
    dt = rc.control_dt
    rows = []
    for k, val in enumerate(ph):
        c, vmax = (0, rc.max_linear_velocity) if k == 1 else (1, rc.max_angular_velocity)
        if val == 0:
            continue
        n = int(math.ceil(abs(val) / (vmax * dt) - 1e-9))
        if n:
            r = np.zeros((n, NU))
            r[:, c] = val / (n * dt)
            rows.append(r)
    return np.concatenate(rows) if rows else np.zeros((0, NU))


def _arm_controls(dq: np.ndarray, rc: RobotConfig, n_min: int = 0) -> np.ndarray:
    """Arm velocities moving by dq in max(n_min, needed) steps at constant velocity."""
    dt = rc.control_dt
    need = int(math.ceil(np.max(np.abs(dq)) / (rc.max_arm_velocity * dt) - 1e-9)) if np.any(dq != 0) else 0
    n = max(need, n_min)
    out = np.zeros((n, NU))
    if n:
        out[:, 2:] = dq / (n * dt)
    return out


#: arm pointing straight up (J2 = 90 deg): the compact pose for driving among obstacles
TUCK_ARM = np.array([np.nan, math.pi / 2, 0.0, 0.0, np.nan])


def _together(base: np.ndarray, dq: np.ndarray, rc: RobotConfig) -> np.ndarray:
    """The arm moving by dq during the base's controls `base`."""
    tog = _arm_controls(dq, rc, n_min=len(base))
    tog[: len(base), :2] = base[:, :2]
    return tog


def steer_together(q0: np.ndarray, q1: np.ndarray, rc: RobotConfig) -> np.ndarray:
    """The first (shortest) of `steer`'s sequences alone, the trees' edge: 'together' with
    the driving direction of the smaller total rotation."""
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    return _together(_base_controls(_base_phases(q0, q1)[0], rc), q1[3:] - q0[3:], rc)


#: the largest angle (rad) between an arc's chord and its tangents that `_arc_base` uses
ARC_MAX_ANGLE = 1.2


def _arc_base(q0: np.ndarray, q1: np.ndarray, rc: RobotConfig) -> np.ndarray | None:
    """Turn-arc-turn base controls from q0 to q1 (x, y, theta): where turn-drive-turn would
    turn the same way before and after driving (the base circling), the smaller of the two
    turns is driven as a circular arc instead (v and w_b together), the remaining turn in
    place. Shorter in eq. 8 when the arc is gentle (the turn's cost adds in quadrature to the
    drive's), longer when the arc's extra length outweighs that (a sharp turn over a short
    drive): the planner takes the shorter (`steer`). Exact
    under the noise-free Euler model: n steps of constant (v, w_b) displace the base along
    the direction heading + (n-1) w_b dt / 2 by |v| dt sin(n w_b dt / 2) / sin(w_b dt / 2),
    so w_b is chosen to aim at q1 and v to reach it. None where the turns have opposite
    signs (turn-drive-turn is as short), the base does not move, or the arc would be too
    curved (chord angle above ARC_MAX_ANGLE). Forward or backward driving, whichever turns
    less, as `_base_phases`."""
    dx, dy = q1[0] - q0[0], q1[1] - q0[1]
    d = math.hypot(dx, dy)
    if d < 1e-4:
        return None
    dt = rc.control_dt
    phi = math.atan2(dy, dx)  # the chord's direction
    best, best_turn = None, np.inf
    for sign in (1.0, -1.0):  # forward, backward: the direction of travel is heading (+ pi)
        h0 = q0[2] + (0.0 if sign > 0 else math.pi)
        f0, f2 = wrap_scalar(phi - h0), wrap_scalar(q1[2] + (0.0 if sign > 0 else math.pi) - phi)
        if f0 * f2 <= 0.0:
            continue
        alpha = f0 if abs(f0) <= abs(f2) else f2  # the arc's chord angle: the smaller turn
        if abs(alpha) > ARC_MAX_ANGLE:
            continue
        pre = f0 - alpha  # turn in place before the arc (0 when the first turn is the smaller)
        length = d * alpha / math.sin(alpha)
        n = max(2, int(math.ceil(length / (rc.max_linear_velocity * dt) - 1e-9)),
                int(math.ceil(2.0 * abs(alpha) / (rc.max_angular_velocity * dt) - 1e-9)) + 1)
        for _ in range(50):
            delta = 2.0 * alpha / (n - 1)  # heading change per step
            v = d * math.sin(delta / 2.0) / (dt * math.sin(n * delta / 2.0))
            if v <= rc.max_linear_velocity + 1e-12 and abs(delta) / dt <= rc.max_angular_velocity + 1e-12:
                break
            n += 1
        else:
            continue
        post = wrap_scalar(q1[2] - (q0[2] + pre + n * delta))
        turn = abs(pre) + abs(post)
        if turn < best_turn:
            arc = np.zeros((n, NU))
            arc[:, 0], arc[:, 1] = sign * v, delta / dt
            best_turn = turn
            best = np.concatenate([_base_controls((pre, 0.0, 0.0), rc), arc, _base_controls((post, 0.0, 0.0), rc)])
    return best


def steer_arc(q0: np.ndarray, q1: np.ndarray, rc: RobotConfig) -> np.ndarray | None:
    """'arc': `_arc_base` with the arm moving during the base motion (as 'together'), or None."""
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    base = _arc_base(q0, q1, rc)
    return None if base is None else _together(base, q1[3:] - q0[3:], rc)


def steer(q0: np.ndarray, q1: np.ndarray, rc: RobotConfig, weights=None) -> list[tuple[str, np.ndarray]]:
    """Candidate control sequences from q0 to q1, shortest first. Each is exact under the
    noise-free Euler model (turns and drives are separate phases; the arm moves at constant
    velocity): 'together' (arm during the base motion), 'arm_first', 'base_first', and 'tuck'
    (arm up, drive, arm down), each with forward and backward driving. With eq. 8's weights
    (planner.steering.arcs) also 'arc' (`steer_arc`) where it applies: first when it is
    shorter than 'together', else after it."""
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    dq = q1[3:] - q0[3:]
    out = []
    arc = steer_arc(q0, q1, rc) if weights is not None else None
    for ph in _base_phases(q0, q1):
        base = _base_controls(ph, rc)
        out.append(("together", _together(base, dq, rc)))
        if arc is not None:
            dt = rc.control_dt
            shorter = path_length(rollout(q0, arc, dt), weights) < path_length(rollout(q0, out[-1][1], dt), weights)
            out.insert(len(out) - 1 if shorter else len(out), ("arc", arc))
            arc = None
        out.append(("arm_first", np.concatenate([_arm_controls(dq, rc), base])))
        out.append(("base_first", np.concatenate([base, _arm_controls(dq, rc)])))
        tuck = np.where(np.isnan(TUCK_ARM), q0[3:], TUCK_ARM)
        out.append(("tuck", np.concatenate([_arm_controls(tuck - q0[3:], rc), base,
                                            _arm_controls(q1[3:] - tuck, rc)])))
    return out


#: perpendicular offsets (fractions of the start-goal distance) of the waypoints `detour_waypoints` gives
DETOUR_OFFSETS = (0.5, 0.75, 0.35)


def detour_waypoints(q0: np.ndarray, q1: np.ndarray, xy_bounds) -> list[np.ndarray]:
    """Base positions (x, y) beside the straight line from q0 to q1, for a path that drives
    around what stands between them (the table between two sides of the object): the
    midpoint moved perpendicular to the line by each of DETOUR_OFFSETS times the distance, on
    either side, kept within xy_bounds; in that order (the connection takes the first free
    path, not the shortest)."""
    p0, p1 = np.asarray(q0[:2], float), np.asarray(q1[:2], float)
    d = p1 - p0
    L = float(np.hypot(*d))
    if L < 1e-3:
        return []
    n = np.array([-d[1], d[0]]) / L
    mid = 0.5 * (p0 + p1)
    lo, hi = xy_bounds
    out = []
    for f in DETOUR_OFFSETS:
        for s in (1.0, -1.0):
            out.append(np.clip(mid + s * f * L * n, lo, hi))
    return out


def steer_via(q0: np.ndarray, q1: np.ndarray, w: np.ndarray, rc: RobotConfig) -> list[tuple[str, np.ndarray]]:
    """Control sequences from q0 to q1 whose base drives through the waypoint w (x, y):
    turn-drive-turn to w, facing q1, then turn-drive-turn to q1 (each leg driving forward or
    backward, whichever turns less, as `steer`'s), with the arm moving during the
    whole base motion ('detour') or tucked for it ('detour_tuck'). Exact under the noise-free
    Euler model, as `steer`'s."""
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    heading = math.atan2(q1[1] - w[1], q1[0] - w[0])  # the second leg's driving direction
    qw = np.concatenate([w, [heading], q0[3:]])
    base = np.concatenate([_base_controls(_base_phases(q0, qw)[0], rc), _base_controls(_base_phases(qw, q1)[0], rc)])
    tuck = np.where(np.isnan(TUCK_ARM), q0[3:], TUCK_ARM)
    return [("detour", _together(base, q1[3:] - q0[3:], rc)),
            ("detour_tuck", np.concatenate([_arm_controls(tuck - q0[3:], rc), base, _arm_controls(q1[3:] - tuck, rc)]))]
