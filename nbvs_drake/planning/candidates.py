"""Candidate generation: uniform samples of the robot's state space (Vasquez-Gomez et al. 2017,
§7.6 step 1), kept when the camera's director ray meets W_box within the working range. Also
the target stream that grows the Object Reconstruction Tree towards the view space."""

from __future__ import annotations

import math
from typing import Iterator

import numba as nb
import numpy as np

from ..config import Scenario, resolve_sensor
from ..mapping.occupancy import OccupancyMap
from ..world.robot import RobotKinematics
from ..world.state import NQ
from .certificate import body_chain
from .views import director_ray_hits


class StateSampler:
    """Uniform states within the base bounds and the arm's joint limits, and the director-ray
    test of the scenario's W_box within [z_near, min(z_far, planner.max_view_distance)]."""

    def __init__(self, sc: Scenario, kin: RobotKinematics):
        self.sc = sc
        self.kin = kin
        s = resolve_sensor(sc.sensor)
        self.z_near = s.z_near
        self.z_far = min(s.z_far, sc.planner.max_view_distance)
        self._X_PF = np.ascontiguousarray([X for X, _ in kin.joint_fixed], dtype=np.float64)
        self._axes = np.ascontiguousarray([a / np.linalg.norm(a) for _, a in kin.joint_fixed], dtype=np.float64)
        self._X_L5C = np.ascontiguousarray(kin.X_L5C, dtype=np.float64)
        self._plane_offset = _arm_plane_offset(kin.first_joint_vertical(), self._X_PF, self._axes, self._X_L5C)
        #: False: the director-ray test in numpy (`views.director_ray_hits`; the same verdicts,
        #: the baseline of `nbvs bench collision`)
        self.numba_director = True

    def sample_states(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n uniform states: the base in xy_bounds, any heading, the arm within its limits.
        Each draw is numpy's `uniform(low, high)`, low + (high - low) * random(), written
        out: the same numbers (tested), without its broadcasting of array bounds (2x faster)."""
        lo, hi = self.sc.robot.xy_bounds
        alo, ahi = self.kin.arm_lower, self.kin.arm_upper
        q = np.empty((n, NQ))
        q[:, 0:2] = lo + (hi - lo) * rng.random((n, 2))
        q[:, 2] = -np.pi + (np.pi - -np.pi) * rng.random(n)
        q[:, 3:] = alo + (ahi - alo) * rng.random((n, 5))
        return q

    def looks_at_wbox(self, q: np.ndarray) -> np.ndarray:
        """Whether each state's director ray meets W_box within the working range
        (`views.director_ray_hits` of `kin.camera_poses`, in one numba call: ~20x faster; the
        candidate generation and the ORT's targets test ~60 states for each one they keep)."""
        if not self.numba_director:
            bmin, bmax = self.sc.scene.bbox_min, self.sc.scene.bbox_max
            return director_ray_hits(self.kin.camera_poses(q), bmin, bmax, self.z_near, self.z_far)
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=np.float64)
        out = np.empty(len(q), np.bool_)
        _looks_at_box(q, self._X_PF, self._axes, self._X_L5C, np.asarray(self.sc.scene.bbox_min, float),
                      np.asarray(self.sc.scene.bbox_max, float), self.z_near, self.z_far, self._plane_offset,
                      nb.get_num_threads(), out)
        return out

    def generate(self, rng: np.random.Generator, omap: OccupancyMap | None = None) -> tuple[np.ndarray, int]:
        """planner.n_candidates states whose director ray meets W_box (at most
        planner.max_generation_factor times as many raw samples). Returns (states, raw
        samples drawn)."""
        p = self.sc.planner
        kept, raw = [], 0
        need = p.n_candidates
        while need > 0 and raw < p.max_generation_factor * p.n_candidates:
            batch = self.sample_states(rng, max(4 * need, 1024))
            raw += len(batch)
            sel = batch[self.looks_at_wbox(batch)][:need]
            kept.append(sel)
            need -= len(sel)
        q = np.concatenate(kept) if kept else np.zeros((0, NQ))
        return q, raw

    def targets(self, rng: np.random.Generator) -> Iterator[np.ndarray]:
        """An endless stream of random states that look at W_box: the Object Reconstruction
        Tree grows towards them (the ORT paper's proposed bias of the growth to the view
        space)."""
        while True:
            batch = self.sample_states(rng, 4096)
            yield from batch[self.looks_at_wbox(batch)]


def _arm_plane_offset(first_vertical: bool, X_PF: np.ndarray, axes: np.ndarray, X_L5C: np.ndarray) -> float:
    """How far (m) the camera's optical axis can be from the arm's vertical plane (through the
    first joint's axis, at the heading base + first joint), or inf when the arm is not a
    planar arm of that kind: a first joint about the base's vertical with no rotation before
    it, the next joints about parallel horizontal axes or about the link's own x (a roll),
    their offsets along x and z only, and the optical axis along the last link's x (so a roll
    moves it off the plane by the camera's offset from that axis, no more). Lets
    `_looks_at_box` reject a state from the heading alone: the plane must come near W_box."""
    ok = first_vertical  # `RobotKinematics.first_joint_vertical`
    for X, a in zip(X_PF[1:], axes[1:]):
        ok &= np.allclose(X[:3, :3], np.eye(3)) and abs(X[1, 3]) < 1e-12
        ok &= np.allclose(np.abs(a), [0, 1, 0]) or np.allclose(np.abs(a), [1, 0, 0])
    roll = [i for i, a in enumerate(axes) if np.allclose(np.abs(a), [1, 0, 0])]
    ok &= roll in ([], [len(axes) - 1]) and np.allclose(np.abs(X_L5C[:3, 2]), [1, 0, 0])
    return float(np.hypot(X_L5C[1, 3], X_L5C[2, 3])) + 1e-9 if ok else np.inf


@nb.njit(cache=True, parallel=True)
def _looks_at_box(q, X_PF, axes, X_L5C, bmin, bmax, t_near, t_far, plane_offset, threads, out):
    """out[n]: the camera's optical axis (+z of X_WB5 @ X_L5C) at state q[n] enters the box
    [bmin, bmax] before t_far and leaves it after t_near (the slab test of
    `views.director_ray_hits`, NaN slabs ignored as nanmax / nanmin ignore them), with the
    forward kinematics of `certificate.body_chain`. A state whose arm plane (`_arm_plane_offset`:
    the optical axis is within plane_offset of it) misses the box is rejected first, without
    the kinematics (the same verdicts: the ray lies within that slab). The states are split
    into chunks over `threads` numba threads (the same verdicts for any count)."""
    cx, cy = 0.5 * (bmin[0] + bmax[0]), 0.5 * (bmin[1] + bmax[1])
    hx, hy = 0.5 * (bmax[0] - bmin[0]), 0.5 * (bmax[1] - bmin[1])
    ox, oy = X_PF[0, 0, 3], X_PF[0, 1, 3]
    N = q.shape[0]
    n_chunks = max(1, min(N // 1024, 4 * threads))
    for c in nb.prange(n_chunks):  # independent states: chunks of them over the threads
        T = np.empty((6, 4, 4))
        tmp = np.empty((4, 4))
        for n in range(c * N // n_chunks, (c + 1) * N // n_chunks):
            _looks_at_one(q, n, X_PF, axes, X_L5C, bmin, bmax, t_near, t_far, plane_offset, cx, cy, hx, hy,
                          ox, oy, T, tmp, out)
    return out


@nb.njit(cache=True, inline="always")
def _looks_at_one(q, n, X_PF, axes, X_L5C, bmin, bmax, t_near, t_far, plane_offset, cx, cy, hx, hy, ox, oy, T,
                  tmp, out):
    """`_looks_at_box` for state n."""
    if plane_offset < np.inf:
        c, s = math.cos(q[n, 2]), math.sin(q[n, 2])
        mx, my = q[n, 0] + c * ox - s * oy, q[n, 1] + s * ox + c * oy  # the first joint's axis
        a = q[n, 2] + q[n, 3]
        nx, ny = -math.sin(a), math.cos(a)  # the arm plane's normal
        if abs(nx * (cx - mx) + ny * (cy - my)) > plane_offset + abs(nx) * hx + abs(ny) * hy:
            out[n] = False
            return
        if _misses_in_plane(q, n, X_PF, axes, X_L5C, bmin, bmax, t_near, t_far, plane_offset, cx - mx, cy - my,
                            ny, -nx, hx, hy):
            out[n] = False
            return
    body_chain(q[n], X_PF, axes, T, tmp)
    t0, t1 = -np.inf, np.inf
    slabs = False
    for i in range(3):
        o = T[5, i, 0] * X_L5C[0, 3] + T[5, i, 1] * X_L5C[1, 3] + T[5, i, 2] * X_L5C[2, 3] + T[5, i, 3]
        d = T[5, i, 0] * X_L5C[0, 2] + T[5, i, 1] * X_L5C[1, 2] + T[5, i, 2] * X_L5C[2, 2]
        inv = 1.0 / d if d != 0.0 else math.copysign(np.inf, d)
        ta = (bmin[i] - o) * inv
        tb = (bmax[i] - o) * inv
        if not math.isnan(ta) and not math.isnan(tb):  # else numpy's minimum / maximum are NaN
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
            slabs = True
    out[n] = slabs and t0 <= t1 and t1 >= t_near and t0 <= t_far


@nb.njit(cache=True, inline="always")
def _misses_in_plane(q, n, X_PF, axes, X_L5C, bmin, bmax, t_near, t_far, plane_offset, dx, dy, ux, uy, hx, hy):
    """The second pretest of `_looks_at_one` (only for the planar arm `_arm_plane_offset`
    accepts): True when the optical axis surely misses W_box within the range. In the arm's
    vertical plane, in coordinates (r along the heading (ux, uy) from the first joint's axis,
    z up), the joint origins and the link's elevation follow from the pitch joints alone; the
    optical axis runs along the last link, from a point within plane_offset of the one computed
    (the camera's offset turns with the roll). The ray's (r, z) must meet the box's projection,
    [the box centre's r (dx, dy from the axis) -+ its half extents (hx, hy) along the heading] x
    [bmin_z, bmax_z], grown by plane_offset and 1e-6 (rounding against the full kinematics),
    within [t_near, t_far] (widened by 1e-6): if it does not, neither does the ray in 3D, whose
    (r, z) stay inside that projection wherever it is inside the box. NaN slabs: no verdict."""
    r, z, phi = 0.0, X_PF[0, 2, 3], 0.0
    for b in range(1, 5):
        cp, sp = math.cos(phi), math.sin(phi)
        r += X_PF[b, 0, 3] * cp - X_PF[b, 2, 3] * sp
        z += X_PF[b, 0, 3] * sp + X_PF[b, 2, 3] * cp
        phi -= axes[b, 1] * q[n, 3 + b]  # a pitch about +-y lowers / raises the link; a roll about x: 0
    cp, sp = math.cos(phi), math.sin(phi)
    r += X_L5C[0, 3] * cp
    z += X_L5C[0, 3] * sp
    dr, dz = X_L5C[0, 2] * cp, X_L5C[0, 2] * sp  # the optical axis: +-x of the last link
    grow = plane_offset + 1e-6
    cr = dx * ux + dy * uy
    er = abs(ux) * hx + abs(uy) * hy + grow
    t0, t1 = -np.inf, np.inf
    for o, d, lo, hi in ((r, dr, cr - er, cr + er), (z, dz, bmin[2] - grow, bmax[2] + grow)):
        inv = 1.0 / d if d != 0.0 else math.copysign(np.inf, d)
        ta, tb = (lo - o) * inv, (hi - o) * inv
        if math.isnan(ta) or math.isnan(tb):
            return False
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    return not (t0 <= t1 and t1 >= t_near - 1e-6 and t0 <= t_far + 1e-6)


#: planner.free_candidates: at most this many rounds of planner.n_candidates draws per plan
MAX_FREE_ROUNDS = 25


def free_candidates(generator, obstacles, rng: np.random.Generator, omap: OccupancyMap, stages: dict,
                    times: dict, want: int = 0) -> np.ndarray:
    """Candidate generation and the position filter (Vasquez-Gomez et al. 2017 §7.6 steps
    1-2): the generator's states (`generate(rng, omap) -> (states, raw samples)`) that are
    free of the plan's obstacles. want > 0 (planner.free_candidates): further rounds of the
    generator's draws until at least `want` are free (at most MAX_FREE_ROUNDS rounds): among
    obstacles most draws collide, and the free views would otherwise be few. Fills stages
    (sampled, director_ray, position, and rounds when more than one) and times (generate_s,
    position_s)."""
    import time
    kept, raw, drawn, n_free = [], 0, 0, 0
    t_gen = t_pos = 0.0
    while True:
        t = time.perf_counter()
        cand, n_raw = generator.generate(rng, omap)
        t_gen += time.perf_counter() - t
        raw, drawn = raw + n_raw, drawn + len(cand)
        t = time.perf_counter()
        kept.append(cand[obstacles.free(cand)])
        t_pos += time.perf_counter() - t
        n_free += len(kept[-1])
        if n_free >= want or len(kept) >= MAX_FREE_ROUNDS or len(cand) == 0:
            break
    rounds = len(kept)
    cand = np.concatenate(kept) if rounds > 1 else kept[0]
    stages["sampled"] = raw
    stages["director_ray"] = drawn
    stages["position"] = len(cand)
    if rounds > 1:
        stages["rounds"] = rounds
    times["generate_s"] = t_gen
    times["position_s"] = t_pos
    return cand
