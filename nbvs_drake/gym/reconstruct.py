"""`nbvs_drake/Reconstruct-v0`: a Gymnasium environment over the real mission. Each episode
is one `nbvs reconstruct` run of the scenario (the same Drake diagram: motion noise,
collisions, registration, map, stop criteria); after every scan the agent takes the decision
the planner would take.

- Actions: `action="candidate"` (default): `Discrete(n_candidates)`, the index of one of the
  scenario planner's scored feasible candidates (best first; `candidate_mask` says which
  exist). `action="state"`: a robot state `Box(8)` (x, y, theta, the five arm joints) that
  the mission's motion planner reaches from the believed state; one that is not free or
  that no path reaches leaves the episode where it was (reward 0, `info["reachable"]`
  False) and the same decision is asked again.
- Observation (`Dict`): `voxels` (the map's voxel classes: 0 free, 1 unknown, 2 occupied, the
  map's whole grid), `depth` (the last scan's depth image at its registered pose, metres, 0
  without a return), `believed_state` (8,), `candidates` (n_candidates, 13: the state, then
  the utility g, the information term, the path length rho (eq. 8), the path's duration (s)
  and 1 for feasible) and `candidate_mask`.
- Reward: the ground-truth coverage (3 mm) gained by the scan the action led to.
- Episodes end (terminated) at the scan budget, a collision (with mission.on_collision
  "stop"), or the planner's stop criterion; `info["summary"]` then holds the run's
  summary.json (coverage, of the ceiling, distance, collisions, F-scores, ...).
- `reset(seed=s)` runs the scenario with seed s: the same seed, the same episode.
"""

from __future__ import annotations

import shutil
import tempfile
import traceback
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .bridge import CANDIDATE_FEATURES, Aborted, AgentPlanner, Channel, Decision, observation


def summary_info(summary: dict) -> dict:
    """The summary's measures an episode's last `info` carries under "summary"."""
    rec = summary.get("reconstruction") or {}
    mesh = rec.get("mesh") or {}
    keep = ("coverage", "coverage_5mm", "coverage_ceiling", "coverage_of_ceiling", "scans", "collisions",
            "collision_rate", "stop_reason", "distance", "remaining_unknown_m3", "prediction_r2", "wall_s")
    out = {k: summary.get(k) for k in keep}
    out["mesh_fscore_5mm"] = (mesh.get("fscore") or {}).get("5mm")
    out["mesh_accuracy_p90_m"] = mesh.get("accuracy_p90_m")
    return out


def _copy(obs: dict) -> dict:
    return {k: np.array(v, copy=True) for k, v in obs.items()}


class _Mission:
    """The mission's process: runs one episode after another as `run_mission` with an
    AgentPlanner attached, and makes the observations there."""

    def __init__(self, sc, n_candidates: int, include_depth: bool, out_dir: Path, keep_runs: bool):
        from ..world.sensor import intrinsics
        self.sc, self.n_candidates, self.include_depth, self.out_dir = sc, n_candidates, include_depth, out_dir
        self.keep_runs = keep_runs
        self.intr = intrinsics(sc.sensor)
        self.md = self.sim = None
        self.coverage = 0.0

    def run(self, seed: int, episode: int, conn) -> dict:
        import copy

        from ..app.mission import run_mission
        sc = copy.deepcopy(self.sc)
        sc.seed = int(seed)
        out = self.out_dir / f"episode_{episode:04d}_seed{seed}"
        if out.exists():
            shutil.rmtree(out)
        if not self.keep_runs:  # only the last episode's run folder is kept
            for old in self.out_dir.glob("episode_*"):
                shutil.rmtree(old, ignore_errors=True)
        self.coverage = 0.0
        channel = Channel(conn, self.observe)

        def attach(md, sim):
            node = md.systems["planner"]
            node.planner = AgentPlanner(node.planner, channel, self.n_candidates)
            self.md, self.sim = md, sim
        try:
            summary = run_mission(sc, out, verbose=False, attach=attach, visual_outputs=False)
        finally:
            self.md = self.sim = None
        return summary

    def last_depth(self) -> np.ndarray:
        from ..perception.reconstruction import depth_from_points
        loc = self.md.systems["localisation"]
        scan = loc.GetOutputPort("registered_scan").Eval(loc.GetMyContextFromRoot(self.sim.get_context()))
        return depth_from_points(np.asarray(scan.points, float), scan.pose, *self.intr).astype(np.float32)

    def observe(self, d: Decision) -> tuple[dict, dict]:
        """(observation, info) of a decision; info's reward: the coverage gained since the last."""
        from ..perception.evaluation import coverage
        scan = int(d.request.omap.scan_count)
        if d.unreachable:
            return None, {"reachable": False, "scan": scan, "reward": 0.0, "coverage": self.coverage}
        obs = observation(d, self.n_candidates, self.sc.robot.control_dt)
        if self.include_depth:
            obs["depth"] = self.last_depth()
        cov = float(coverage(self.md.gt_points, d.request.omap.object_points, (0.003,))[0])
        reward, self.coverage = cov - self.coverage, cov
        return obs, {"reachable": True, "scan": scan, "reward": reward, "coverage": cov}


def worker_main(conn, sc, n_candidates: int, include_depth: bool, out_dir: str, keep_runs: bool):
    """The mission process's loop: ("reset", seed, episode) runs an episode, answering with
    ("decision", observation, info) at each decision and ("done", summary, info) at its end
    (("error", text) if it fails); ("abort",) during an episode ends it (("aborted",));
    ("close",) ends the process."""
    mission = _Mission(sc, n_candidates, include_depth, Path(out_dir), keep_runs)
    while True:
        try:
            msg = conn.recv()
        except EOFError:  # the environment's process is gone
            break
        if msg[0] == "close":
            break
        if msg[0] != "reset":
            continue
        try:
            summary = mission.run(msg[1], msg[2], conn)
        except Aborted:
            conn.send(("aborted",))
            continue
        except Exception as e:  # noqa: BLE001 - handed to the agent's process
            conn.send(("error", f"{type(e).__name__}: {e}\n{traceback.format_exc()}"))
            continue
        cov = float(summary.get("coverage", mission.coverage))
        conn.send(("done", summary_info(summary), {"reward": cov - mission.coverage, "coverage": cov,
                                                    "scan": summary.get("scans"),
                                                    "stop_reason": summary.get("stop_reason")}))
    conn.close()


def worker_entry(fd: int):
    """The mission process's entry (`_start_worker`): its first message is ("init", scenario,
    n_candidates, include_depth, out_dir)."""
    from multiprocessing.connection import Connection
    conn = Connection(fd)
    msg = conn.recv()
    worker_main(conn, *msg[1:])


def _start_worker():
    """The mission's process and a Connection to it (a socket pair). A plain subprocess, not
    multiprocessing's: the environment may itself run in a daemonic process (gymnasium's
    AsyncVectorEnv), which multiprocessing forbids to have children."""
    import os
    import socket
    import subprocess
    import sys
    from multiprocessing.connection import Connection
    ours, theirs = socket.socketpair()
    fd = theirs.fileno()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    proc = subprocess.Popen([sys.executable, "-c", f"from nbvs_drake.gym.reconstruct import worker_entry; "
                             f"worker_entry({fd})"], pass_fds=(fd,), env=env)
    theirs.close()
    return Connection(ours.detach()), proc


class ReconstructEnv(gym.Env):
    """See the module's docstring. `scenario`: a built-in scenario's name, a YAML path or a
    Scenario; `settings`: "section.field=value" strings as `nbvs reconstruct --set`;
    `out_dir`: where each episode's run is written (None: a temporary folder, removed at
    close; `keep_runs` False: only the last episode's folder is kept there); `include_depth`
    False leaves the depth image out of the observation. The mission
    runs in a process of its own, started with the environment (its imports take a few seconds)."""

    metadata = {"render_modes": []}

    def __init__(self, scenario="default", settings=(), action: str = "candidate", n_candidates: int = 16,
                 out_dir=None, include_depth: bool = True, keep_runs: bool = False):
        from ..app.api import _resolve_scenario
        from ..errors import ScenarioError
        from ..mapping.occupancy import OccupancyMap
        from ..world.sensor import intrinsics
        if action not in ("candidate", "state"):
            raise ScenarioError(f"action must be 'candidate' or 'state', not {action!r}")
        if int(n_candidates) < 1:
            raise ScenarioError(f"n_candidates must be at least 1, not {n_candidates}")
        self.sc = _resolve_scenario(scenario, None, tuple(settings))
        self.action_kind, self.n_candidates, self.include_depth = action, int(n_candidates), include_depth
        self._own_dir = out_dir is None
        self.out_dir = Path(tempfile.mkdtemp(prefix="nbvs_gym_")) if out_dir is None else Path(out_dir)
        w, h = intrinsics(self.sc.sensor)[:2]
        dims = tuple(int(d) for d in OccupancyMap.for_scenario(self.sc).spec.dims)
        lo, hi = self._state_bounds()
        obs = {"voxels": spaces.Box(0, 2, dims, np.int8),
               "believed_state": spaces.Box(-np.inf, np.inf, (8,), np.float64),
               "candidates": spaces.Box(-np.inf, np.inf, (self.n_candidates, 8 + len(CANDIDATE_FEATURES)), np.float64),
               "candidate_mask": spaces.MultiBinary(self.n_candidates)}
        if include_depth:
            obs["depth"] = spaces.Box(0.0, np.inf, (h, w), np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_space = (spaces.Discrete(self.n_candidates) if action == "candidate"
                             else spaces.Box(lo, hi, (8,), np.float64))
        self._conn, self._proc = _start_worker()
        self._conn.send(("init", self.sc, self.n_candidates, include_depth, str(self.out_dir), keep_runs))
        self._running = False
        self._last_obs = None
        self._episode = 0

    def _state_bounds(self):
        from ..world.robot import RobotKinematics
        kin = RobotKinematics(self.sc.robot.urdf)
        b = self.sc.robot.xy_bounds
        lo = np.r_[b[0], b[0], -np.pi, kin.arm_lower]
        hi = np.r_[b[1], b[1], np.pi, kin.arm_upper]
        return lo.astype(np.float64), hi.astype(np.float64)

    def _empty_obs(self) -> dict:
        return {k: np.zeros(s.shape, s.dtype) for k, s in self.observation_space.spaces.items()}

    def _receive(self) -> tuple:
        """(observation, reward, terminated, info) of the mission's next message."""
        try:
            msg = self._conn.recv()
        except EOFError:
            self._running = False
            raise RuntimeError("the mission's process ended unexpectedly") from None
        if msg[0] == "error":
            self._running = False
            raise RuntimeError(f"the mission failed: {msg[1]}")
        if msg[0] == "done":
            self._running = False
            info = dict(msg[2], summary=msg[1])
            return _copy(self._last_obs), info.pop("reward"), True, info
        obs, info = msg[1], dict(msg[2])
        if obs is not None:
            self._last_obs = obs
        return _copy(self._last_obs), info.pop("reward"), False, info

    # ---- the Gymnasium API ------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._stop_episode()
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        self._episode += 1
        self._last_obs = self._empty_obs()
        self._conn.send(("reset", int(seed), self._episode))
        self._running = True
        obs, _, _, info = self._receive()
        return obs, dict(info, seed=int(seed))

    def step(self, action):
        if not self._running:
            raise RuntimeError("the episode is over: call reset()")
        a = np.asarray(action)
        self._conn.send(("action", int(a) if a.ndim == 0 else a.astype(np.float64)))
        obs, reward, terminated, info = self._receive()
        return obs, float(reward), bool(terminated), False, info

    def _stop_episode(self):
        if self._running:
            self._conn.send(("abort",))
            while self._conn.recv()[0] not in ("aborted", "done", "error"):
                pass
            self._running = False

    def close(self):
        if getattr(self, "_proc", None) is not None:
            if self._proc.poll() is None:
                try:
                    self._stop_episode()
                    self._conn.send(("close",))
                except (BrokenPipeError, EOFError, OSError):
                    pass
                try:
                    self._proc.wait(timeout=30)
                except Exception:  # noqa: BLE001 - a mission that does not end is ended
                    self._proc.kill()
                    self._proc.wait()
            self._conn.close()
        self._proc = None
        if self._own_dir and self.out_dir.exists():
            shutil.rmtree(self.out_dir, ignore_errors=True)
        super().close()
