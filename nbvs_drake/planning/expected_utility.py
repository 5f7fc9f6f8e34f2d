"""Expected utility under noisy controls (Vasquez-Gomez et al. 2017 §7.2, Algorithm 1) and the sample-count
bound of §7.3 (eq. 18).

k rollouts of the motion model the NoisyVelocityController executes (Euler integration of
u_t + eps_t, eps truncated Gaussian, zero on the components commanded 0); every
intermediate state of every rollout is checked for
collision with Drake (in batches); any colliding rollout makes the candidate unfeasible (the
conservative rule of Algorithm 1, line 7). With `max_collision_rate` > 0 the candidate is
unfeasible only when more than that share of the k rollouts collide (the "weighted strategy"
§7.2 names as the alternative): a colliding rollout then contributes g = 0, the pos(x) factor
of its final state. Otherwise the utility of each final state is weighted by its
probability, the product of the per-step densities computed in log space (hundreds of
densities underflow) and normalised (weighting "probability", Algorithm 1 lines 10-12; a
rollout of negligible weight is not scored, WEIGHT_FLOOR), or averaged with equal weights
(weighting "mean": the rollouts are already draws from the error distribution, so their
plain average is the Monte Carlo estimate of the expected utility). The products of m
densities spread over ~sqrt(m) in log space, so for the ~100-step plans here the normalised
weights put almost all mass on one rollout: `ess` reports their
effective sample size (sum w)^2 / sum w^2.
"""

from __future__ import annotations

import dataclasses as dc
import math
from typing import Callable

import numpy as np

from ..config import NoiseConfig
from ..world.motion import (
    control_sigmas,
    rollout,
    sample_control_noise,
    sample_truncated_normal,
    truncated_normal_logpdf,
)
from ..world.pose import EXACT_POSE_VAR, apply_corrections

#: the coarse pass over a chunk of rollouts checks every COARSE_STEP-th step (and the last)
COARSE_STEP = 8

#: the rollouts drawn and checked first (`chunk_bounds`)
FIRST_CHUNK = 20

#: with the "probability" weighting, a rollout whose normalised weight is below this share of
#: the largest is not scored: the k rollouts dropped so move E(x) by less than k times this
#: share of the largest utility (5e-7 of it at k = 500), while the weights put almost all mass
#: on a few rollouts (the module docstring), so their views need not all be simulated
WEIGHT_FLOOR = 1e-9


def coarse_to_fine(m: int) -> list[np.ndarray]:
    """The column indices 0..m-1 of m steps in the order the rollouts are checked: the last
    (the view state, near the object), every COARSE_STEP-th, then the rest."""
    if m == 0:
        return []
    coarse = np.zeros(m, bool)
    coarse[COARSE_STEP - 1::COARSE_STEP] = True
    coarse[m - 1] = False
    return [np.array([m - 1]), np.flatnonzero(coarse), np.flatnonzero(~coarse)[:-1]]


def chunk_bounds(k: int, chunk: int) -> list[tuple[int, int]]:
    """The rollouts 0..k-1 in the sets they are drawn, rolled out and checked: FIRST_CHUNK
    first (most candidates that collide are ruled out by a few rollouts), then up to each
    multiple of `chunk`."""
    cuts = sorted({0, k, min(FIRST_CHUNK, k), *range(chunk, k, chunk)})
    return list(zip(cuts[:-1], cuts[1:]))


def sample_count_bound(alpha: float, gamma: float, eta: float = 1 / 0.997) -> int:
    """Smallest k with (1 - eta gamma)^k <= alpha (eq. 18): with k rollouts, a trajectory whose
    error region R meets the obstacles with probability gamma is caught with confidence
    1 - alpha. eta = 1 / P(R) (1 / 0.997 for beta = 3 sigma)."""
    if not (0 < alpha < 1) or not (0 < eta * gamma < 1):
        raise ValueError(f"need 0 < alpha < 1 and 0 < eta*gamma < 1, got alpha={alpha}, eta*gamma={eta * gamma}")
    return int(math.ceil(math.log(alpha) / math.log(1.0 - eta * gamma) - 1e-12))


class NoiseDraws:
    """The control noise of k rollouts, `sample_control_noise(rng, noise, controls, k)`, drawn
    one set of rollouts at a time (`rows`): the generator is advanced past all k at once, as
    that call leaves it, so a candidate that its first rollouts rule out does not draw the
    others' noise, and every later draw is the same. (A PCG64 generator, which numpy's
    default_rng is, draws one 64-bit output per uniform; another generator draws all k.)"""

    def __init__(self, rng: np.random.Generator, noise: NoiseConfig, controls: np.ndarray, k: int):
        self.noise, self.controls = noise, controls
        self.per = controls.size  # uniforms per rollout
        bg = rng.bit_generator
        self._all = None
        if isinstance(bg, np.random.PCG64):
            self._state = bg.state
            bg.advance(k * self.per)
        else:
            self._all = sample_control_noise(rng, noise, controls, k)

    def rows(self, idx: np.ndarray) -> np.ndarray:
        """The noise (len(idx), m, NU) of the rollouts idx (increasing)."""
        idx = np.asarray(idx, np.int64)
        if self._all is not None:
            return self._all[idx]
        if len(idx) == 0:
            return np.zeros((0,) + self.controls.shape)
        g = np.random.Generator(np.random.PCG64())
        g.bit_generator.state = self._state
        g.bit_generator.advance(int(idx[0]) * self.per)
        span = sample_control_noise(g, self.noise, self.controls, int(idx[-1] - idx[0]) + 1)
        return span[idx - idx[0]]


@dc.dataclass
class ExpectedUtility:
    feasible: bool
    value: float  #: E(x); 0 when unfeasible
    rollouts: int  #: k
    rollouts_checked: int  #: rollouts whose states were collision-checked (stops at the first collision)
    collided_rollouts: int  #: among those checked
    final_states: np.ndarray | None = None
    utilities: np.ndarray | None = None
    weights: np.ndarray | None = None
    ess: float = 0.0  #: effective sample size of the weights (k for "mean")
    #: the weighted standard deviation of the rollouts' utilities about E(x) (with the
    #: "probability" weighting over the rollouts scored: see WEIGHT_FLOOR)
    spread: float = 0.0
    mask: np.ndarray | None = None  #: the rollouts whose final state was scored (k,)

    @property
    def scored(self) -> int:
        """How many rollouts' final states were scored."""
        return 0 if self.mask is None else int(np.count_nonzero(self.mask))

    def to_json(self) -> dict:
        return {"feasible": self.feasible, "eu": self.value, "k": self.rollouts,
                "rollouts_checked": self.rollouts_checked, "collided_rollouts": self.collided_rollouts,
                "ess": self.ess, "g_std": self.spread, "scored": self.scored}


def expected_utility(q0: np.ndarray, controls: np.ndarray, dt: float, k: int, noise: NoiseConfig,
                     rng: np.random.Generator, state_free: Callable[[np.ndarray], np.ndarray],
                     utility: Callable[[np.ndarray], np.ndarray], chunk: int = 100,
                     weighting: str = "probability", max_collision_rate: float = 0.0,
                     start_cov: np.ndarray | None = None, block_free=None,
                     start_free: Callable[[np.ndarray], np.ndarray] | None = None) -> ExpectedUtility:
    """Algorithm 1. state_free(states (N, 8)) -> bool (N,); utility(final states (k, 8)) -> (k,);
    weighting "mean" or "probability" (see the module docstring); max_collision_rate: the
    share of colliding rollouts a feasible candidate may have (0: none, Algorithm 1);
    start_cov: covariance (3, 3) of the believed start pose's planar error (dx, dy, dyaw), as
    `registration.motion_prior` gives it: each rollout then starts from the belief moved by a
    draw of that error (truncated at beta sigma like the control noise), so a belief that no
    scan has corrected since the last plan spreads the rollouts' final states accordingly.
    None or zero: Algorithm 1's exactly known start x_c.
    block_free(states (c, L, 8), steps (L,)) -> bool (c, L), optional: the same check given the
    states of c rollouts at the steps `steps` (1..m) of the plan; with it each set of rollouts
    (`chunk_bounds`) is checked coarse to fine (their final states, every COARSE_STEP-th
    step, the rest), a rollout no further than its first collision, and checking stops once
    more than the allowed share collide: the verdict is the same as checking every state,
    `collided_rollouts` then counts the colliding rollouts found before it stopped.
    start_free(states (k, 8)) -> bool (k,), optional, with a start_cov: the rollouts whose
    start (a draw of the belief's spread) collides are dropped, since the robot stands free
    (the belief conditioned on no collision); the candidate is unfeasible when every start
    collides, and `rollouts` counts those kept."""
    if weighting not in ("mean", "probability"):
        raise ValueError(f"weighting must be 'mean' or 'probability', got {weighting!r}")
    if not 0.0 <= max_collision_rate < 1.0:
        raise ValueError(f"max_collision_rate must be in [0, 1), got {max_collision_rate}")
    controls = np.asarray(controls, float)
    sigma = control_sigmas(noise, controls)  # (m, NU): 0 where the command is exact
    draws = NoiseDraws(rng, noise, controls, k)
    rows = np.arange(k)  # the rollouts kept (all but those whose start collides)
    z = None
    if start_cov is not None and np.any(np.diag(np.asarray(start_cov, float)) > EXACT_POSE_VAR):
        L = np.linalg.cholesky(np.asarray(start_cov, float) + EXACT_POSE_VAR * np.eye(3))
        z = sample_truncated_normal(rng, np.ones(3), noise.beta, (k,))  # (k, 3) standard draws
        q0 = apply_corrections(q0, z @ L.T)
        if start_free is not None:  # only the starts where the robot can stand
            keep = np.asarray(start_free(q0), bool)
            if not keep.any():
                return ExpectedUtility(False, 0.0, 0, 0, 0)
            q0, z, rows, k = q0[keep], z[keep], rows[keep], int(keep.sum())
    q0 = np.broadcast_to(np.asarray(q0, float), (k, 8))
    allowed = int(math.floor(max_collision_rate * k + 1e-9))  # colliding rollouts tolerated
    ok = np.ones(k, bool)
    finals = np.zeros((k, 8))
    checked = collided = 0
    eps = []
    for start, stop in chunk_bounds(k, chunk):
        # this chunk's rollouts (each row its own: the same states as all k at once), so that
        # a candidate ruled out by its first rollouts does not draw or roll out the others
        eps.append(draws.rows(rows[start:stop]))
        states = rollout(q0[start:stop], controls[None] + eps[-1], dt)
        finals[start:stop] = states[:, -1]
        block = states[:, 1:]  # intermediate and final states
        checked += len(block)
        if block_free is not None:
            # coarse to fine, each rollout until its first collision; the rollouts' verdicts
            # are those of checking every state, and checking stops once too many collide
            bad = np.zeros(len(block), bool)
            for cols in coarse_to_fine(block.shape[1]):
                live = np.flatnonzero(~bad)
                bad[live] = ~block_free(block[live][:, cols], cols + 1).all(axis=1)
                if collided + np.count_nonzero(bad) > allowed:
                    break
            ok[start:stop] = ~bad
        else:
            free = state_free(block.reshape(-1, 8)).reshape(block.shape[:2])
            ok[start:stop] = free.all(axis=1)
        collided = int(np.count_nonzero(~ok[:stop]))
        if collided > allowed:
            return ExpectedUtility(False, 0.0, k, checked, collided)
    if weighting == "probability":
        eps = np.concatenate(eps) if eps else np.zeros((0,) + controls.shape)
        logp = truncated_normal_logpdf(eps, sigma, noise.beta).sum(axis=1)  # log prod_t p_t
        if z is not None:  # times the start's density
            logp = logp + truncated_normal_logpdf(z, np.ones(3), noise.beta)
        w = np.exp(logp - logp.max())
        w /= w.sum()
    else:
        w = np.full(k, 1.0 / k)
    # pos(x) = 0 at a colliding rollout's end; rollouts of negligible weight are not scored
    score = ok & (w >= WEIGHT_FLOOR * w.max()) if weighting == "probability" else ok
    ess = float(1.0 / np.sum(w * w))
    return rescored(ExpectedUtility(True, 0.0, k, checked, collided, finals, None, w, ess, mask=score), utility)


def rescored(eu: ExpectedUtility, utility: Callable[[np.ndarray], np.ndarray]) -> ExpectedUtility:
    """The rollouts of `eu` (their weights, which are scored: `mask`) with their final states
    scored by `utility` (g = 0 elsewhere): E(x), the utilities and their spread. Algorithm 1's
    last step, and the coarse-to-fine expected utility's finer scoring of the same rollouts
    (`utility.ExpectedUtilityScore`)."""
    g = np.zeros(eu.rollouts)
    g[eu.mask] = np.asarray(utility(eu.final_states[eu.mask]), float)
    value = float(np.dot(eu.weights, g))
    spread = float(np.sqrt(max(np.dot(eu.weights, (g - value) ** 2), 0.0)))
    return dc.replace(eu, value=value, utilities=g, spread=spread)
