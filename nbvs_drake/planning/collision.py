"""pos(x) on Drake: the planner's collision model (robot + known environment + W_box as the
obstacle of the unknown region) checked with `pydrake.planning.SceneGraphCollisionChecker`,
behind a numba certificate (`clearance.FreeCertificate`) that proves most free states free,
and many colliding ones in collision, from conservative models of the same geometry: Drake
decides every other state, so the verdicts are Drake's."""

from __future__ import annotations

import contextlib
import time

import numpy as np

from ..config import Scenario
from ..world.robot import RobotKinematics, add_robot
from ..world.scene import add_environment
from . import path_verdicts
from .certificate import FREE, UNKNOWN, FreeCertificate, Unsupported

#: the robot's base link (the PatrolBot's body), which planner.obstacles.base_clearance pads
BASE_BODY = "base_link"


class CollisionModel:
    """Batched configuration checks in the robot state layout q = [x, y, theta, q1..q5].

    object_obj: the true object (for detecting real collisions of the executed motion)
    instead of the planner's conservative W_box obstacle.
    obstacle_boxes: (centre, size) boxes standing for the unknown and occupied space of the
    map (Vasquez-Gomez et al. 2017 §3: O = W_obj u W_unk u O_env) instead of the whole W_box.
    base_padding: the base link (BASE_BODY) counts as colliding within this distance of the
    environment (Drake's padding; planner.obstacles.base_clearance).
    """

    def __init__(self, sc: Scenario, kin: RobotKinematics, *, object_obj: str | None = None,
                 padding: float = 0.0, obstacle_boxes=None, certificate: bool = True, base_padding: float = 0.0):
        from pydrake.planning import RobotDiagramBuilder, SceneGraphCollisionChecker
        rdb = RobotDiagramBuilder(time_step=0.0)
        plant = rdb.plant()
        robot = add_robot(plant, sc.robot.urdf)
        add_environment(plant, sc, object_obj=object_obj, visual=False, obstacle_boxes=obstacle_boxes,
                        add_wbox_obstacle=object_obj is None and obstacle_boxes is None,
                        floor_drop=padding + base_padding)
        plant.Finalize()
        self.diagram = rdb.Build()
        self.kin = kin
        self.checker = SceneGraphCollisionChecker(
            model=self.diagram, robot_model_instances=[robot], edge_step_size=0.02,
            env_collision_padding=padding, self_collision_padding=0.0)
        if base_padding > 0:  # the base alone keeps this far from the environment (planner.obstacles.base_clearance)
            base = plant.GetBodyByName(BASE_BODY, robot).index()
            self.checker.SetPaddingOneRobotBodyAllEnvironmentPairs(base, padding + base_padding)
        #: the free-space certificate (None: Drake checks every state; also when the world has
        #: geometry the certificate does not model)
        self.certificate = None
        #: what the checks cost: states classified by the conservative model (certificate and
        #: bulk kernels), states Drake was asked about, seconds spent (`check_stats`)
        self.counter = np.zeros(1, np.int64)
        self.drake_queries = 0
        self.check_s = 0.0
        if certificate:
            try:
                self.certificate = FreeCertificate(self.diagram, self.checker, kin)
            except Unsupported:
                pass

    def check_stats(self) -> dict:
        return {"collision_checks": int(self.counter[0]) + self.drake_queries, "drake_queries": self.drake_queries,
                "collision_check_s": self.check_s}

    @contextlib.contextmanager
    def timed(self):
        """Adds the time spent inside to check_s (the bulk kernels' callers use it too)."""
        t = time.perf_counter()
        try:
            yield
        finally:
            self.check_s += time.perf_counter() - t

    def bulk_classify(self, q: np.ndarray) -> np.ndarray:
        """FREE / COLLIDING / UNKNOWN of states (N, 8) by the conservative model alone (needs
        the certificate)."""
        with self.timed():
            q = np.ascontiguousarray(np.atleast_2d(q), float)
            return path_verdicts.classify(q, *self.certificate.model, self.counter)

    def bulk_path(self, states: np.ndarray, max_step: float = 0.02) -> int:
        """FREE / COLLIDING / UNKNOWN of a path by the conservative model alone (path_verdicts.path_verdict)."""
        with self.timed():
            states = np.ascontiguousarray(states, float)
            return int(path_verdicts.path_verdict(states, *self.certificate.model, max_step,
                                                  path_verdicts.STRIDE, self.counter))

    def bulk_path_undecided(self, states: np.ndarray, max_step: float = 0.02):
        """(verdict, interpolated states, indices of those the model cannot decide) of a path
        (path_verdicts.path_undecided)."""
        with self.timed():
            return path_verdicts.path_undecided(np.ascontiguousarray(states, float), *self.certificate.model, max_step,
                                       path_verdicts.STRIDE, self.counter)

    def bulk_edges(self, A: np.ndarray, B: np.ndarray, rc: np.ndarray, max_step: float = 0.02) -> np.ndarray:
        """FREE / COLLIDING / UNKNOWN of the steering edges A[i] -> B[i] (path_verdicts.edge_verdicts)."""
        with self.timed():
            return path_verdicts.edge_verdicts(np.ascontiguousarray(A, float), np.ascontiguousarray(B, float),
                                      *self.certificate.model, rc, max_step, path_verdicts.STRIDE, self.counter)

    def free(self, q: np.ndarray, parallelize: bool = True) -> np.ndarray:
        """Boolean (N,) collision-free flags for states (N, 8)."""
        with self.timed():
            return self._free(q, parallelize)

    def _free(self, q: np.ndarray, parallelize: bool) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        if len(q) == 0:
            return np.zeros(0, bool)
        if self.certificate is None:
            out, todo = np.zeros(len(q), bool), np.arange(len(q))
        else:
            verdict = self.certificate.classify(q)
            self.counter[0] += len(q)
            out, todo = verdict == FREE, np.flatnonzero(verdict == UNKNOWN)
        if len(todo) == 0:
            return out
        pos = self.kin.to_positions(q[todo])
        self.drake_queries += len(todo)
        if len(todo) == 1:
            out[todo[0]] = self.checker.CheckConfigCollisionFree(pos[0])
        else:  # thread dispatch costs more than it saves on small batches
            out[todo] = self.checker.CheckConfigsCollisionFree(list(pos), parallelize=parallelize and len(todo) >= 64)
        return out

    def contacts(self, q: np.ndarray) -> list[dict]:
        """What touches what at the state q (8,): every pair of geometries in penetration
        (Drake's point-pair query), as {"a", "b", "depth_m"}, deepest first. Names are the
        geometries' (e.g. `patrolbot_katana::link5` and `chair6_back`, `table_top`, `object`);
        descriptive only: `free` (the collision checker, with its filters) is the verdict."""
        plant, sg = self.diagram.plant(), self.diagram.scene_graph()
        if self._contact_context is None:
            self._contact_context = self.diagram.CreateDefaultContext()
        ctx = self._contact_context
        plant.SetPositions(plant.GetMyMutableContextFromRoot(ctx), self.kin.to_positions(np.atleast_2d(q))[0])
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx))
        names = query.inspector().GetName
        out = [{"a": names(p.id_A), "b": names(p.id_B), "depth_m": round(float(p.depth), 4)}
               for p in query.ComputePointPairPenetration()]
        return sorted(out, key=lambda c: -c["depth_m"])

    _contact_context = None

    @staticmethod
    def interpolate(states: np.ndarray, max_step: float = 0.02) -> np.ndarray:
        """The states of a path and interpolated states in between (linear in q, so that no
        point of the robot moves more than about `max_step` between consecutive states)."""
        states = np.asarray(states, float)
        if len(states) == 1:
            return states
        d = np.abs(np.diff(states, axis=0))
        # reach of the arm: base translation + rotation x 1.4 m lever, joints x 0.7 m
        move = np.hypot(d[:, 0], d[:, 1]) + 1.4 * d[:, 2] + 0.7 * d[:, 3:].sum(axis=1)
        subs = np.maximum(1, np.ceil(move / max_step)).astype(int)
        seg = np.repeat(np.arange(len(subs)), subs)  # segment of each interpolated state
        frac = (np.arange(len(seg)) - np.repeat(np.cumsum(subs) - subs, subs) + 1) / np.repeat(subs, subs)
        return np.concatenate([states[:1], states[seg] + frac[:, None] * (states[seg + 1] - states[seg])])

    @staticmethod
    def _coarse(n: int, coarse_stride: int) -> np.ndarray:
        coarse = np.zeros(n, bool)
        coarse[::coarse_stride] = True
        coarse[-1] = True
        return coarse

    def path_free(self, states: np.ndarray, max_step: float = 0.02, coarse_stride: int = 8) -> bool:
        """Checks the states of a path and interpolated states in between (`interpolate`).
        Every coarse_stride-th of those states is checked first: most paths that collide are
        caught there, at a fraction of the checks, and a free path costs the same checks in
        two batches. The verdict does not depend on it (coarse_stride 0: one pass)."""
        allq = self.interpolate(states, max_step)
        if len(allq) == 1:
            return bool(self.free(allq)[0])
        if coarse_stride <= 0 or len(allq) <= 2 * coarse_stride:
            return bool(np.all(self.free(allq)))
        coarse = self._coarse(len(allq), coarse_stride)
        return bool(np.all(self.free(allq[coarse])) and np.all(self.free(allq[~coarse])))

    def paths_free(self, paths: list[np.ndarray], max_step: float = 0.02, coarse_stride: int = 8) -> np.ndarray:
        """`path_free` of many paths, (N,) bool, with the checks of all paths in two Drake
        batches (the coarse states of every path, then the rest of those that passed): the
        same verdicts, far fewer calls, and the batch spread over Drake's threads."""
        if not paths:
            return np.zeros(0, bool)
        allq = [self.interpolate(s, max_step) for s in paths]
        lens = np.array([len(a) for a in allq])
        coarse = [self._coarse(n, coarse_stride) if coarse_stride > 0 and n > 2 * coarse_stride
                  else np.ones(n, bool) for n in lens]
        ok = np.ones(len(paths), bool)
        for first in (True, False):
            idx = [i for i in range(len(paths)) if ok[i] and (first or not coarse[i].all())]
            if not idx:
                break
            parts = [allq[i][coarse[i] if first else ~coarse[i]] for i in idx]
            free = self.free(np.concatenate(parts))
            owner = np.repeat(np.arange(len(idx)), [len(x) for x in parts])
            bad = np.zeros(len(idx), bool)
            np.logical_or.at(bad, owner, ~free)
            ok[np.asarray(idx)[bad]] = False
        return ok
