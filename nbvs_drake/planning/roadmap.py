"""A roadmap that lasts the mission, searched once per plan for all of the plan's goals (a lazy
PRM in the spirit of OMPL's LazyPRM, with the edges of the steering function).

- **Vertices** are free states of the known environment, sampled when the first plan needs them
  (`planner.motion_planner.vertices`): uniform states, states with the arm tucked up (the compact pose
  for driving between the table and the chairs: base-first sampling), and Gaussian pairs near the
  obstacles (the free one of two nearby states of which one is blocked: the narrow passages).
  Each is proved free by the conservative model (planning/path_verdicts.py). The chairs and the table do
  not move, so the vertices and the edges stay for the whole mission.
- **Edges** join each vertex to its `planner.motion_planner.neighbors` nearest in the weighted metric
  of eq. 8; an edge a -> b is the steering function's exact control sequence
  (`motion.steer_together`), weighted by its eq. 8 length, and is checked only when a search
  wants to use it (lazily), in the direction it is travelled, and at most once per obstacle model.
  A plan whose obstacles differ (the map's voxels after a new scan) rechecks the edges it uses:
  an edge through space the map has since found occupied is not used.
- **A plan** adds its start and its goals (and each one's twin with the arm tucked, joined to it
  by an arm-only edge) as temporary vertices, and runs one Dijkstra search from the start for all
  goals at once. The edges on the shortest paths found are checked in bulk (numba; Drake for what
  the model cannot decide); blocked ones are removed and the search is repeated until every
  reachable goal has a checked path. A goal that is not connected costs its own connection edges
  and one bounded growth round (`GROWTH_SAMPLES` states around it), never a full tree search.
- **Paths** are shortened (greedy shortcuts between their vertices, then each intermediate
  vertex turned to face the next and given the goal's arm where that is free and shorter, all
  checked the same way) and rebuilt as one control sequence from the start, which the caller
  checks again with Drake.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from ..world.motion import TUCK_ARM, rollout, steer_together
from . import neighbours, steer_kernels
from .certificate import COLLIDING, FREE, UNKNOWN

UNCHECKED = 2
#: states sampled around a goal the roadmap does not reach, once per plan (its bounded share)
GROWTH_SAMPLES = 24
#: lazy search rounds per query at most (each removes at least one blocked edge)
MAX_ROUNDS = 200


@dc.dataclass
class QueryStats:
    """What one query cost (summed into the plan's stages)."""
    rounds: int = 0
    edges_checked: int = 0
    drake_edges: int = 0
    shortcuts_checked: int = 0
    grown: int = 0
    reached: int = 0
    built: int = 0

    def to_json(self) -> dict:
        return dc.asdict(self)


class Roadmap:
    """The mission's roadmap (see the module docstring). `query` answers one plan."""

    def __init__(self, sc, kin, sampler):
        self.sc = sc
        self.kin = kin
        self.sampler = sampler
        p = sc.planner
        self.w = np.asarray(p.weights, float)
        self.rc = steer_kernels.robot_params(sc.robot)
        self.k = p.motion_planner.neighbors
        self.V = np.zeros((0, 8))
        self.src = np.zeros(0, np.int64)
        self.dst = np.zeros(0, np.int64)
        self.length = np.zeros(0)
        self.state = np.zeros(0, np.int8)
        self._index: dict[tuple[int, int], int] = {}
        self._model = None  # the CollisionModel the edge states were checked against

    # ------------------------------------------------------------------ building
    def _tucked(self, q: np.ndarray) -> np.ndarray:
        t = np.array(q, float, copy=True)
        arm = np.where(np.isnan(TUCK_ARM), t[..., 3:], TUCK_ARM)
        t[..., 3:] = arm
        return self.kin.clip_arm(t)

    def _free(self, q: np.ndarray, collision) -> np.ndarray:
        return collision.bulk_classify(q) == FREE

    def sample(self, rng: np.random.Generator, n: int, collision, around: np.ndarray | None = None,
               sigma: float = 0.3) -> np.ndarray:
        """n free states (fewer when 20 rounds do not find them): a third uniform, a third with
        the arm tucked, a third the free one of a Gaussian pair of which the other is blocked;
        around (8,): centred on that state's base instead (sigma m)."""
        lo, hi = self.sc.robot.xy_bounds
        out, need = [], n
        for _ in range(20):
            if need <= 0:
                break
            m = max(3 * need, 64)
            q = self.sampler.sample_states(rng, m)
            if around is not None:
                q[:, :2] = np.clip(around[:2] + rng.normal(0.0, sigma, (m, 2)), lo, hi)
            q[m // 3: 2 * m // 3] = self._tucked(q[m // 3: 2 * m // 3])
            g = q[2 * m // 3:]
            g2 = g.copy()
            g2[:, :2] = np.clip(g[:, :2] + rng.normal(0.0, 0.1, (len(g), 2)), lo, hi)
            g2[:, 2] += rng.normal(0.0, 0.3, len(g))
            fa, fb = self._free(g, collision), self._free(g2, collision)
            gauss = np.concatenate([g[fa & ~fb], g2[fb & ~fa]])
            plain = q[: 2 * m // 3]
            plain = plain[self._free(plain, collision)]
            take = np.concatenate([plain[: (2 * need) // 3 + 1], gauss[: need // 3 + 1]])[:need]
            out.append(take)
            need -= len(take)
        return np.concatenate(out) if out else np.zeros((0, 8))

    def _add_vertices(self, q: np.ndarray) -> np.ndarray:
        idx = np.arange(len(self.V), len(self.V) + len(q))
        self.V = np.concatenate([self.V, np.asarray(q, float).reshape(-1, 8)])
        return idx

    def _add_edges(self, a: np.ndarray, b: np.ndarray, directed: bool = False):
        """Edges a[i] -> b[i] (and b[i] -> a[i] unless directed) that are not there yet."""
        pairs = [(int(i), int(j)) for i, j in zip(a, b) if i != j and i >= 0 and j >= 0]
        if not directed:
            pairs += [(j, i) for i, j in pairs]
        new = []
        for e in pairs:
            if e not in self._index:
                self._index[e] = len(self.src) + len(new)
                new.append(e)
        if not new:
            return
        e = np.array(new, np.int64)
        self.src = np.concatenate([self.src, e[:, 0]])
        self.dst = np.concatenate([self.dst, e[:, 1]])
        self.length = np.concatenate([self.length, steer_kernels.edge_lengths(self.V[e[:, 0]], self.V[e[:, 1]], self.w,
                                                                     self.rc)])
        self.state = np.concatenate([self.state, np.full(len(e), UNCHECKED, np.int8)])

    def _connect(self, idx: np.ndarray, among: int, k: int, direction: str = "both"):
        """Edges between the vertices idx and their k nearest among the first `among` vertices:
        "both" directions, "out" (idx -> neighbour) or "in" (neighbour -> idx)."""
        if len(idx) == 0 or among == 0:
            return
        nn = neighbours.knn(self.V[:among], self.V[idx], self.w, min(k, among), False)
        a = np.repeat(idx, nn.shape[1])
        b = nn.reshape(-1)
        keep = b >= 0
        a, b = a[keep], b[keep]
        if direction == "in":
            a, b = b, a
        self._add_edges(a, b, directed=direction != "both")

    def build(self, rng: np.random.Generator, collision) -> int:
        q = self.sample(rng, self.sc.planner.motion_planner.vertices, collision)
        idx = self._add_vertices(q)
        self._connect(idx, len(self.V), self.k)
        return len(idx)

    def _truncate(self, n: int):
        """Removes the vertices from n on and their edges (a query's temporary vertices)."""
        keep = (self.src < n) & (self.dst < n)
        if keep.all() and len(self.V) == n:
            return
        self.V = self.V[:n]
        first = int(np.argmin(keep)) if not keep.all() else len(keep)
        if not keep[first:].any():  # the query's edges, added after the roadmap's: drop their keys
            for a, b in zip(self.src[first:].tolist(), self.dst[first:].tolist()):
                del self._index[(a, b)]
            self.src, self.dst, self.length, self.state = (self.src[:first], self.dst[:first], self.length[:first],
                                                           self.state[:first])
            return
        self.src, self.dst, self.length, self.state = (self.src[keep], self.dst[keep], self.length[keep],
                                                       self.state[keep])
        self._index = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(self.src, self.dst))}

    # ------------------------------------------------------------------ checking
    def _check_edges(self, eids: np.ndarray, collision, path_free_py, start: int, st: QueryStats):
        """Sets the state of the edges eids: the bulk verdict, Drake (`collision.path_free`)
        where it is UNKNOWN; edges out of the start go through `path_free_py` (the motion
        planner's check, which lets a believed start in collision leave it)."""
        if len(eids) == 0:
            return
        st.edges_checked += len(eids)
        from_start = self.src[eids] == start
        rest = eids[~from_start]
        if len(rest):
            self.state[rest] = collision.bulk_edges(self.V[self.src[rest]], self.V[self.dst[rest]], self.rc)
        for e in np.concatenate([eids[from_start], rest[self.state[rest] == UNKNOWN]]):
            a, b = self.V[self.src[e]], self.V[self.dst[e]]
            states = rollout(a, steer_together(a, b, self.sc.robot), self.sc.robot.control_dt)
            st.drake_edges += 1
            ok = path_free_py(states) if self.src[e] == start else collision.path_free(states)
            self.state[e] = FREE if ok else COLLIDING

    def _search(self, s: int):
        from scipy.sparse import csr_matrix
        from scipy.sparse.csgraph import dijkstra
        n = len(self.V)
        use = self.state != COLLIDING
        g = csr_matrix((self.length[use] + 1e-9, (self.src[use], self.dst[use])), shape=(n, n))
        dist, pred = dijkstra(g, directed=True, indices=s, return_predecessors=True)
        return dist, pred

    def _chain(self, pred: np.ndarray, s: int, g: int) -> list[int]:
        out = [g]
        while out[-1] != s:
            out.append(int(pred[out[-1]]))
        return out[::-1]

    def _lazy(self, s: int, goals: np.ndarray, collision, path_free_py, st: QueryStats) -> dict[int, list[int]]:
        """Vertex chains from s to each goal vertex reachable through checked-free edges."""
        chains: dict[int, list[int]] = {}
        for _ in range(MAX_ROUNDS):
            st.rounds += 1
            dist, pred = self._search(s)
            pending, chains = [], {}
            for g in goals:
                if not np.isfinite(dist[g]):
                    continue
                ch = self._chain(pred, s, int(g))
                chains[int(g)] = ch
                pending += [self._index[(a, b)] for a, b in zip(ch[:-1], ch[1:])
                            if self.state[self._index[(a, b)]] == UNCHECKED]
            if not pending:
                return chains
            self._check_edges(np.unique(np.array(pending, np.int64)), collision, path_free_py, s, st)
        return {g: ch for g, ch in chains.items()
                if all(self.state[self._index[(a, b)]] == FREE for a, b in zip(ch[:-1], ch[1:]))}

    def _shortcut(self, chain: list[int], collision, cache: dict, st: QueryStats) -> list[int]:
        """Greedy shortcuts: from each kept vertex, the farthest later vertex of the chain that
        a free steering edge reaches (bulk verdict FREE; an undecided one is not taken)."""
        out, i = [chain[0]], 0
        while i < len(chain) - 1:
            nxt = i + 1
            for j in range(len(chain) - 1, i + 1, -1):
                key = (chain[i], chain[j])
                if key not in cache:
                    st.shortcuts_checked += 1
                    cache[key] = collision.bulk_edges(self.V[[chain[i]]], self.V[[chain[j]]], self.rc)[0]
                if cache[key] == FREE:
                    nxt = j
                    break
            out.append(chain[nxt])
            i = nxt
        return out

    # ------------------------------------------------------------------ the query
    def query(self, q_start: np.ndarray, goals: np.ndarray, collision, path_free_py, rng: np.random.Generator):
        """Paths from q_start to each of goals (K, 8): a list of (controls, states, nodes: the
        roadmap vertices it runs through) or None, and the QueryStats. collision: the plan's
        CollisionModel (with its certificate); path_free_py(states) -> bool: the motion planner's
        check of a path from the start."""
        st = QueryStats()
        if self._model is not collision:  # other obstacles: every edge is checked again when used
            self.state[:] = UNCHECKED
            self._model = collision
        if len(self.V) == 0:
            st.built = self.build(rng, collision)
        out: list = [None] * len(goals)
        todo = np.arange(len(goals))
        for growth in range(2):
            if len(todo) == 0:
                break
            if growth:
                grown = [self.sample(rng, GROWTH_SAMPLES, collision, around=goals[i]) for i in todo]
                grown = np.concatenate(grown) if grown else np.zeros((0, 8))
                if len(grown) == 0:
                    break
                idx = self._add_vertices(grown)
                self._connect(idx, len(self.V), self.k)
                st.grown += len(idx)
            n_perm = len(self.V)
            s = self._add_vertices(np.asarray(q_start, float)[None])[0]
            g_idx = self._add_vertices(goals[todo])
            self._connect(np.array([s]), n_perm, 2 * self.k, "out")
            self._connect(g_idx, n_perm, 2 * self.k, "in")
            # twins with the arm tucked: arm-only edges to and from the start and the goals
            ends = np.concatenate([[s], g_idx])
            twins = self._tucked(self.V[ends])
            ok = self._free(twins, collision)
            t_idx, e_ok = self._add_vertices(twins[ok]), ends[ok]
            is_s = e_ok == s
            self._add_edges(e_ok[is_s], t_idx[is_s], directed=True)  # start -> its twin
            self._add_edges(t_idx[~is_s], e_ok[~is_s], directed=True)  # a goal's twin -> the goal
            self._connect(t_idx, n_perm, self.k)
            chains = self._lazy(s, g_idx, collision, path_free_py, st)
            cache: dict = {}
            left = []
            for i, gv in zip(todo, g_idx):
                ch = chains.get(int(gv))
                if ch is None:
                    left.append(i)
                    continue
                ch = self._shortcut(ch, collision, cache, st)
                out[i] = (*self._controls(self._smooth(self.V[ch], collision, st)), len(ch))
            self._truncate(n_perm)
            todo = np.array(left, np.int64)
        st.reached = sum(r is not None for r in out)
        return out, st

    def _smooth(self, Q: np.ndarray, collision, st: QueryStats) -> np.ndarray:
        """The path's intermediate states (rows of Q between the start and the goal) turned to
        face the next one (the base then drives on without turning at them) and given the
        goal's arm (the arm moves once), each change kept when both its edges are proved free
        (bulk verdict FREE) and the path gets shorter (eq. 8)."""
        Q = np.array(Q, float)
        for i in range(1, len(Q) - 1):
            d = Q[i + 1, :2] - Q[i, :2]
            if np.hypot(*d) < 1e-4:
                continue
            best = None
            for arm in (Q[-1, 3:], Q[i, 3:]):
                cand = Q[i].copy()
                cand[2] = np.arctan2(d[1], d[0])
                cand[3:] = arm
                A = np.stack([Q[i - 1], cand])
                B = np.stack([cand, Q[i + 1]])
                st.shortcuts_checked += 2
                old = steer_kernels.edge_lengths(np.stack([Q[i - 1], Q[i]]), np.stack([Q[i], Q[i + 1]]), self.w,
                                                 self.rc).sum()
                new = steer_kernels.edge_lengths(A, B, self.w, self.rc).sum()
                if new < old and np.all(collision.bulk_edges(A, B, self.rc) == FREE):
                    best = cand
                    break
            if best is not None:
                Q[i] = best
        return Q

    def _controls(self, Q: np.ndarray):
        """(controls, states) through the states Q, each edge steered from where the last one
        ended."""
        rcfg = self.sc.robot
        q0 = Q[0]
        q = q0
        parts = []
        for target in Q[1:]:
            c = steer_together(q, target, rcfg)
            parts.append(c)
            q = rollout(q, c, rcfg.control_dt)[-1]
        controls = np.concatenate(parts) if parts else np.zeros((0, 7))
        return controls, rollout(q0, controls, rcfg.control_dt)


__all__ = ["Roadmap", "QueryStats", "UNKNOWN"]
