"""Runs an experiment's runs on an executor and keeps every finished one.

Each run is written into a temporary sibling folder (`runs/<run>.partial-<token>/`) and
renamed to `runs/<run>/` only once it is complete (the mission returned and summary.json is
written), so a run's folder appears complete or not at all. A batch that is killed (SIGKILL,
at any moment) and started again keeps and skips every finished run, removes the leftover
temporary folders and redoes the unfinished runs from scratch. A run that fails (an
exception, a worker that dies) is recorded in `runs/<run>.failed.json` (the error and its log)
and does not stop the batch; `retry_failed` reruns those. Each run's stdout and stderr go to
`logs/<run>.log`; the batch's own events (started, skipped, finished, failed, cleaned) to
`runner.log`.

Executors:
- `local`: a pool of `jobs` spawned worker processes (Drake and numba dislike fork), each with
  its share of the cores as numba threads (NUMBA_NUM_THREADS, numba.set_num_threads) and
  reused run after run; a run that kills its worker (a crash in native code) fails alone and
  the worker is replaced.
- `ray`: each run a Ray task, on the cluster at `address` or on a local `ray.init(num_cpus=jobs)`
  started for the batch. The task runs in a temporary folder on its worker and returns the
  run folder as a gzipped tarball with its log; the driver writes them, so workers need no
  shared filesystem (but the package installed, and any `--object` mesh at the same path).
"""

from __future__ import annotations

import datetime as _dt
import io
import json
import os
import shutil
import socket
import sys
import tarfile
import time
import traceback
from pathlib import Path

from ..files import write_atomic
from .definition import ExperimentError, RunSpec, expand, resolve

PARTIAL = ".partial-"


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# --------------------------------------------------------------------------------------
# one run (in a worker)
# --------------------------------------------------------------------------------------


def reconstruct_run(scenario: str, out: Path, seed: int, overrides) -> dict:
    """One `nbvs reconstruct` (nbvs_drake.reconstruct) into the fresh folder `out`; returns
    its summary. `scenario`: a built-in scenario's name (`teapot_eu_mu`) or a YAML path."""
    from ..app.api import reconstruct
    return reconstruct(scenario=str(scenario), out=out, seed=seed, overrides=list(overrides), verbose=True).summary


def execute_run(spec: dict, out: Path, threads: int) -> dict:
    """The worker's side of one run: numba's share of threads, then the mission."""
    os.environ["NUMBA_NUM_THREADS"] = str(threads)  # effective when numba is not yet imported
    import numba
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    t0 = time.perf_counter()
    if spec.get("runner", "mission") == "view_sphere":
        from ..config import load_scenario
        from ..gym.sphere import run_view_sphere
        summary = run_view_sphere(load_scenario(spec["scenario"], seed=spec["seed"], settings=spec["overrides"]), out)
    else:
        summary = reconstruct_run(spec["scenario"], Path(out), spec["seed"], spec["overrides"])
    if not (Path(out) / "summary.json").is_file():
        raise RuntimeError(f"the run returned but wrote no summary.json in {out}")
    from .aggregate import git_commit
    return {"wall_s": time.perf_counter() - t0, "coverage": summary.get("coverage"),
            "scans": summary.get("scans"), "host": socket.gethostname(), "numba_threads": threads,
            "git_commit": git_commit()}


def _die_with_parent():
    """Linux: the run process gets SIGKILL when the batch process dies, so a killed batch
    leaves no orphan writing into a folder the next batch removes."""
    try:
        import ctypes
        import signal
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        if os.getppid() == 1:
            os._exit(1)
    except Exception:  # noqa: BLE001 - best effort
        pass


def _redirect_output(log_path: Path):
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    return saved


def _restore_output(saved):
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(saved[0], 1)
    os.dup2(saved[1], 2)
    os.close(saved[0])
    os.close(saved[1])


def _pool_worker(conn, threads: int):
    """A spawned worker of the local executor: runs one spec after another as the batch
    sends them (each run's output into its own log), replies with the outcome, and stops on
    None or when the batch goes away."""
    _die_with_parent()
    os.environ["NUMBA_NUM_THREADS"] = str(threads)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            break
        if msg is None:
            break
        spec, tmp, log = msg
        saved = _redirect_output(Path(log))
        try:
            reply = {"info": execute_run(spec, Path(tmp), threads)}
        except Exception as e:  # noqa: BLE001 - recorded by the batch
            traceback.print_exc()
            reply = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}
        finally:
            _restore_output(saved)
        conn.send(reply)


def _ray_body(spec: dict, threads: int) -> dict:
    """A Ray task: the run in a temporary folder of the worker; returns the folder as a
    gzipped tarball (bytes) and the log."""
    import tempfile
    with tempfile.TemporaryDirectory(prefix="nbvs_run_") as tmp:
        out, log = Path(tmp) / "run", Path(tmp) / "run.log"
        saved = _redirect_output(log)
        info, error = {}, None
        try:
            info = execute_run(spec, out, threads)
        except Exception as e:  # noqa: BLE001 - the driver records it
            traceback.print_exc()
            error = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}
        finally:
            _restore_output(saved)
        buf = io.BytesIO()
        if error is None:
            with tarfile.open(fileobj=buf, mode="w:gz") as tf:
                tf.add(out, arcname=".")
        return {"info": info, "error": error, "tar": buf.getvalue(), "log": log.read_bytes() if log.exists() else b""}


# --------------------------------------------------------------------------------------
# executors
# --------------------------------------------------------------------------------------


class LocalExecutor:
    name = "local"

    def __init__(self, jobs: int):
        self.jobs = max(1, jobs)
        self.threads = max(1, cpu_count() // self.jobs)
        self._workers = []  # kept from one experiment to the next until close()

    def close(self):
        """Stops the idle workers (asks them to exit, then kills what is left)."""
        for w in self._workers:
            if w.get("dead"):
                continue
            if w["busy"] is None:
                try:
                    w["conn"].send(None)
                except (OSError, ValueError):
                    pass
                w["proc"].join(timeout=10)
            if w["proc"].is_alive():
                w["proc"].kill()
                w["proc"].join()
        self._workers = []

    def describe(self) -> str:
        return f"local, {self.jobs} worker processes x {self.threads} numba threads"

    def _spawn(self, ctx):
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_pool_worker, args=(child, self.threads), name="nbvs-experiment-worker")
        p.start()
        child.close()
        return {"proc": p, "conn": parent, "busy": None}

    def run(self, batch, todo: list[RunSpec]):
        """A pool of `jobs` spawned workers, each reused run after run (the imports and the
        JIT caches are loaded once); a worker that dies fails its run alone and is replaced."""
        import multiprocessing as mp
        from multiprocessing.connection import wait
        ctx = mp.get_context("spawn")
        pending = list(todo)
        self._workers = [w for w in self._workers if not w.get("dead") and w["proc"].is_alive()]
        self._workers += [self._spawn(ctx) for _ in range(min(self.jobs, len(pending)) - len(self._workers))]
        workers = self._workers
        ok = False
        try:
            while True:
                for w in workers:
                    if w["busy"] is None and pending:
                        spec = pending.pop(0)
                        tmp = batch.new_partial(spec)
                        w["conn"].send((spec.to_json(), str(tmp), str(batch.log_path(spec))))
                        w["busy"] = (spec, tmp)
                        batch.event(f"start {spec.run_id} (worker pid {w['proc'].pid})")
                busy = [w for w in workers if w["busy"] is not None]
                if not busy:
                    break
                ready = set(wait([w["conn"] for w in busy] + [w["proc"].sentinel for w in busy], timeout=5.0))
                for i, w in enumerate(workers):
                    if w["busy"] is None or not ({w["conn"], w["proc"].sentinel} & ready):
                        continue
                    spec, tmp = w["busy"]
                    reply = None
                    if w["conn"].poll():
                        try:
                            reply = w["conn"].recv()
                        except (EOFError, OSError):
                            reply = None
                    if reply is None:  # the worker died in the run (a crash in native code, a kill)
                        w["proc"].join(timeout=10)
                        batch.failed(spec, tmp, f"the run's worker process died (exit code {w['proc'].exitcode})",
                                     None, w["proc"].exitcode)
                        w["conn"].close()
                        workers[i] = self._spawn(ctx) if pending else {"proc": w["proc"], "conn": w["conn"],
                                                                        "busy": None, "dead": True}
                        continue
                    w["busy"] = None
                    if "error" not in reply and (tmp / "summary.json").is_file():
                        batch.finished(spec, tmp, reply["info"])
                    else:
                        batch.failed(spec, tmp, reply.get("error") or "the run wrote no summary.json",
                                     reply.get("traceback"), None)
            ok = True
        finally:
            if not ok:  # interrupted: kill the runs in flight
                for w in workers:
                    if not w.get("dead") and w["busy"] is not None and w["proc"].is_alive():
                        w["proc"].kill()
                        w["proc"].join()
                self.close()


class RayExecutor:
    name = "ray"

    def __init__(self, jobs: int, address: str | None = None):
        self.jobs = max(1, jobs)
        self.address = address
        self.threads = max(1, cpu_count() // self.jobs) if not address else 1
        self._started = False

    def describe(self) -> str:
        where = f"cluster at {self.address}" if self.address else f"local Ray, num_cpus={self.jobs}"
        return f"ray ({where}), {self.threads} numba threads per task"

    def _init(self):
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        try:
            import ray
        except ImportError as e:
            raise ExperimentError(f"--executor ray needs the ray package ({e}); pip install 'ray>=2.9'") from None
        env = {"env_vars": {"NUMBA_NUM_THREADS": str(self.threads), "RAY_USAGE_STATS_ENABLED": "0"}}
        if ray.is_initialized():
            return ray
        # token authentication (Ray >= 2.52): Ray 2.60's local cluster listens on every network
        # interface (its GCS server and raylet bind 0.0.0.0 whatever the node address), so the
        # cluster a batch starts for itself runs with RAY_AUTH_MODE=token (a token is generated
        # at ~/.ray/auth_token when there is none): a client without the token is refused. For
        # --address, token mode is used when a token is at hand (RAY_AUTH_TOKEN,
        # RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token) and the mode is not set, as `--address auto` does.
        if "RAY_AUTH_MODE" not in os.environ and (not self.address or _ray_token_at_hand()):
            os.environ["RAY_AUTH_MODE"] = "token"
            try:  # Ray caches its config at import: refresh it, as Ray's own token setup does
                from ray._raylet import Config
                Config.initialize("")
            except Exception:  # noqa: BLE001 - an older Ray without it reads the variable at init
                pass
        if self.address:
            _probe_ray_address(self.address)
            try:
                # Ray's C++ client writes every refused attempt (a token it does not accept) to
                # stderr for a minute: that goes to a file, the one line below says what happened
                with _stderr_to_file():
                    ray.init(address=self.address, runtime_env=env, log_to_driver=False)
            except Exception as e:  # noqa: BLE001 - ConnectionError, AuthenticationError, RuntimeError
                msg = " ".join(str(e).split())[:300]
                if "uthenticat" in type(e).__name__ + msg or "token" in msg.lower():
                    raise ExperimentError(
                        f"the Ray cluster at {self.address} refused the connection ({type(e).__name__}: {msg}); "
                        "a cluster with token authentication needs its token: RAY_AUTH_TOKEN=... or "
                        "RAY_AUTH_TOKEN_PATH=FILE (or ~/.ray/auth_token, from `ray get-auth-token` on the "
                        "head node)") from None
                hint = ("; if it runs with token authentication, the token given (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH "
                        "or ~/.ray/auth_token) is not its own" if os.environ.get("RAY_AUTH_MODE") == "token" else "")
                raise ExperimentError(f"cannot connect to the Ray cluster at {self.address} "
                                      f"({type(e).__name__}: {msg}){hint}") from None
        else:
            ray.init(num_cpus=self.jobs, include_dashboard=False, runtime_env=env, log_to_driver=False,
                     object_store_memory=200 * 1024 ** 2)
            self._started = True
        return ray

    def run(self, batch, todo: list[RunSpec]):
        ray = self._init()
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_body)
        futures = {}
        try:
            for spec in todo:
                futures[task.remote(spec.to_json(), self.threads)] = spec
                batch.event(f"submit {spec.run_id}")
            while futures:
                ready, _ = ray.wait(list(futures), num_returns=1, timeout=5.0)
                for ref in ready:
                    spec = futures.pop(ref)
                    try:
                        res = ray.get(ref)
                    except Exception as e:  # noqa: BLE001 - a dead worker, a lost task
                        batch.failed(spec, None, f"{type(e).__name__}: {' '.join(str(e).split())[:2000]}", None, None)
                        continue
                    batch.log_path(spec).write_bytes(res.get("log") or b"")
                    if res.get("error"):
                        batch.failed(spec, None, res["error"]["error"], res["error"].get("traceback"), None)
                        continue
                    tmp = batch.new_partial(spec)
                    tmp.mkdir(parents=True)
                    with tarfile.open(fileobj=io.BytesIO(res["tar"]), mode="r:gz") as tf:
                        tf.extractall(tmp, filter="data")
                    batch.finished(spec, tmp, res.get("info") or {})
        finally:
            for ref in list(futures):  # interrupted: cancel what is left
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001
                    pass

    def close(self):
        if self._started:
            import ray
            ray.shutdown()
            self._started = False


class _stderr_to_file:
    """Redirects file descriptor 2 (C++ libraries' stderr too) into a temporary file for the
    `with` block; its content is dropped."""

    def __enter__(self):
        import tempfile
        sys.stderr.flush()
        self._saved = os.dup(2)
        self._file = tempfile.TemporaryFile()
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stderr.flush()
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.close()
        return False


def _ray_token_at_hand() -> bool:
    if os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH"):
        return True
    return (Path.home() / ".ray" / "auth_token").is_file()


def _probe_ray_address(address: str, timeout: float = 5.0):
    """A HOST:PORT address must accept a TCP connection within `timeout` seconds (Ray's own
    connection retries take minutes): else one line naming the address. `auto` and
    `ray://` addresses are left to Ray."""
    import socket
    host, sep, port = address.rpartition(":")
    if address == "auto" or address.startswith("ray://") or not sep or not port.isdigit():
        return
    try:
        with socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=timeout):
            pass
    except OSError as e:
        raise ExperimentError(f"no Ray cluster answers at {address} ({e.strerror or type(e).__name__}); "
                              "start one there (`ray start --head --port PORT`) or leave out --address "
                              "for a local one") from None


def make_executor(name: str, jobs: int | None, address: str | None = None):
    jobs = jobs or cpu_count()
    if name == "local":
        return LocalExecutor(jobs)
    if name == "ray":
        return RayExecutor(jobs, address)
    raise ExperimentError(f"unknown executor {name!r} (local or ray)")


# --------------------------------------------------------------------------------------
# the batch
# --------------------------------------------------------------------------------------


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


class Batch:
    """One experiment's folder: the lock, the runs' folders, the events, the progress."""

    def __init__(self, r: dict, exp_dir: Path, executor, progress: bool = True):
        self.r, self.dir, self.executor = r, Path(exp_dir), executor
        self.runs_dir = self.dir / "runs"
        self.logs_dir = self.dir / "logs"
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        self.logs_dir.mkdir(exist_ok=True)
        self._n = 0
        self.done = self.fail = 0
        self.bar = None
        self.progress = progress
        self.records: Path | None = None  #: run records' folder (`records.py`), or None

    def record_path(self, spec: RunSpec) -> Path:
        from .records import SUFFIX
        return self.records / f"{spec.run_id}{SUFFIX}"

    def record(self, spec: RunSpec):
        if self.records is not None:
            from .records import write_record
            write_record(self.final(spec), self.record_path(spec))

    # ---- the lock: one batch per experiment folder (released by the kernel on any death)
    def lock(self):
        from ..files import FolderLock
        self._lock = FolderLock(self.dir, ExperimentError, "another `nbvs experiment` batch")

    def event(self, msg: str):
        with open(self.dir / "runner.log", "a") as f:
            f.write(f"{_now()} {msg}\n")

    def log_path(self, spec: RunSpec) -> Path:
        return self.logs_dir / f"{spec.run_id}.log"

    def final(self, spec: RunSpec) -> Path:
        return self.runs_dir / spec.run_id

    def failed_path(self, spec: RunSpec) -> Path:
        return self.runs_dir / f"{spec.run_id}.failed.json"

    def new_partial(self, spec: RunSpec) -> Path:
        self._n += 1
        return self.runs_dir / f"{spec.run_id}{PARTIAL}{os.getpid()}-{self._n}"

    def clean_partials(self):
        for p in sorted(self.runs_dir.glob(f"*{PARTIAL}*")):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
            self.event(f"cleaned {p.name} (left by an unfinished batch)")

    # ---- outcomes
    def finished(self, spec: RunSpec, tmp: Path, info: dict):
        (tmp / "run.json").write_text(json.dumps(dict(spec.to_json(), **info, executor=self.executor.name,
                                                      finished=_now()), indent=1))
        final = self.final(spec)
        if final.exists():  # not a finished run (those are skipped): a stray folder
            shutil.rmtree(final)
        os.rename(tmp, final)
        self.failed_path(spec).unlink(missing_ok=True)
        self.record(spec)
        s = json.loads((final / "summary.json").read_text())
        self.done += 1
        line = (f"{spec.run_id}: coverage {s.get('coverage', 0):.3f} after {s.get('scans')} scans, "
                f"{s.get('stop_reason')}, {info.get('wall_s', s.get('wall_s', 0)):.1f} s")
        self.event(f"done {line}")
        self._say(line)

    def failed(self, spec: RunSpec, tmp: Path | None, error: str, tb: str | None, exitcode):
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        rec = {"run_id": spec.run_id, "spec": spec.to_json(), "error": error, "traceback": tb,
               "exitcode": exitcode, "log": str(self.log_path(spec)), "executor": self.executor.name, "date": _now()}
        write_atomic(self.failed_path(spec), json.dumps(rec, indent=1))
        self.fail += 1
        self.event(f"FAILED {spec.run_id}: {error}")
        self._say(f"{spec.run_id}: FAILED ({error}; log {self.log_path(spec)})")

    def _say(self, line: str):
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(failed=self.fail)
            self.bar.write(line, file=sys.stdout)
        else:
            print(line, flush=True)


def scenario_drift(spec: RunSpec, run_dir: Path) -> list[str]:
    """The scenario fields (dotted names) in which a finished run's scenario.yaml differs from
    the scenario its spec resolves to now; [] when they agree or the run has no scenario.yaml.
    A run keeps its overrides when diagrams/*.yaml or the schema's defaults change, so the
    overrides alone do not tell a stale run. The old file is read with today's schema: a field
    added since takes its default, and flags the run only where the scenario now sets it
    otherwise."""
    from ..config import load_scenario
    from ..errors import NbvsError
    from .definition import settings_of
    f = Path(run_dir) / "scenario.yaml"
    if not f.is_file():
        return []
    try:
        was = load_scenario(f)
    except NbvsError as e:
        return [f"scenario.yaml unreadable: {e}"]
    a, b = settings_of(was), settings_of(spec.resolve())
    return sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))


def run_experiment(defn: dict, out_root, *, quick: bool = False, seeds=None, jobs: int | None = None,
                   executor="local", address: str | None = None, retry_failed: bool = False,
                   command: str = "", progress: bool = True, table_only: bool = False, records=None,
                   only: dict | None = None) -> dict:
    """Runs what is missing of one experiment into out_root/<name>[_quick]/ and writes its
    table (`table_only`: runs nothing, the table of the runs finished so far, e.g. of a batch
    that was stopped). `executor`: "local", "ray" or an executor from `make_executor` (left open, for
    several experiments on one Ray session). `records`: a run records' folder (`records.py`):
    the runs recorded in records/<name>[_quick]/ that the output folder lacks are restored
    first, and every finished run is recorded there. `only` {factor: [level labels]}: run only
    the runs of those levels (the table still covers every run finished). Returns {"table", "dir", "ran",
    "skipped", "restored", "failed" (the run ids that failed, now or before)}."""
    if isinstance(executor, str):
        ex = make_executor(executor, jobs, address)
        try:
            return run_experiment(defn, out_root, quick=quick, seeds=seeds, executor=ex, retry_failed=retry_failed,
                                  command=command, progress=progress, table_only=table_only, records=records,
                                  only=only)
        finally:
            ex.close()
    from .aggregate import write_table
    r = resolve(defn, quick=quick, seeds=seeds)
    exp_dir = Path(out_root) / (r["name"] + ("_quick" if quick else ""))
    ex = executor
    batch = Batch(r, exp_dir, ex, progress)
    batch.lock()
    batch.clean_partials()
    specs = expand(r)
    restored = _restore_records(batch, specs, records, exp_dir.name)
    todo, skipped, failed_before = [], [], []
    for spec in specs:
        final = batch.final(spec)
        if (final / "summary.json").is_file():
            rj = final / "run.json"
            if rj.is_file():
                have_key = _run_key(json.loads(rj.read_text()))
                if have_key != spec.key():
                    raise ExperimentError(
                        f"{final} was run with other settings ({have_key}) than this definition asks "
                        f"({spec.key()}); remove it or use another --out")
            drift = [] if table_only else scenario_drift(spec, final)
            if drift:
                more = f" and {len(drift) - 3} more" if len(drift) > 3 else ""
                raise ExperimentError(
                    f"{final} was run with a scenario that differs from what its settings give now "
                    f"({', '.join(drift[:3])}{more}: the scenario files or the defaults changed since); "
                    f"remove it or use another --out")
            skipped.append(spec)
            batch.event(f"skipped {spec.run_id} (finished)")
            if batch.records is not None and not batch.record_path(spec).is_file():
                batch.record(spec)
        elif batch.failed_path(spec).is_file() and not retry_failed:
            failed_before.append(spec)
            batch.event(f"skipped {spec.run_id} (failed before; --retry-failed reruns it)")
        else:
            todo.append(spec)
    if table_only:
        todo = []
    if only:
        factors = {f["name"]: {str(lv["label"]) for lv in f["levels"]} for f in r.get("factors") or []}
        for fname, labels in only.items():
            unknown = set(labels) - factors.get(fname, set())
            if fname not in factors or unknown:
                raise ExperimentError(f"--only {fname}={','.join(labels)}: {r['name']} has no "
                                      + (f"factor {fname!r}" if fname not in factors else
                                         f"level {', '.join(sorted(unknown))} of {fname}"))
        todo = [sp for sp in todo if all(sp.levels.get(f) in labels for f, labels in only.items())]
    import yaml
    (exp_dir / "definition.yaml").write_text(yaml.safe_dump({k: v for k, v in r.items() if not k.startswith("_")},
                                                            sort_keys=False, allow_unicode=True))
    head = (f"{r['name']}{' (quick)' if quick else ''}: {len(specs)} runs, {len(skipped)} finished before"
            f"{f' ({restored} restored from {batch.records})' if restored else ''}, "
            f"{len(failed_before)} failed before, {len(todo)} to run on {ex.describe()} -> {exp_dir}")
    batch.event(f"batch: {head}; command: {command}")
    print(head, flush=True)
    if todo:
        if progress:
            from tqdm import tqdm
            batch.bar = tqdm(total=len(specs), initial=len(skipped) + len(failed_before), unit="run",
                             desc=r["name"], file=sys.stderr, dynamic_ncols=True, smoothing=0)
            batch.bar.set_postfix(failed=len(failed_before))
        from ..errors import Interrupted, InterruptGuard
        guard = InterruptGuard()
        try:
            with guard:
                ex.run(batch, todo)
        except BaseException as e:
            if not guard.was_interrupt(e):
                raise
            n = sum(1 for sp in specs if (batch.final(sp) / "summary.json").is_file())
            raise Interrupted(f"interrupted: {n} of {len(specs)} runs of {r['name']} are finished in "
                              f"{exp_dir / 'runs'}" + (f" and recorded in {batch.records}" if batch.records else "")
                              + "; the same command goes on from there (`--table-only` writes their table)") from None
        finally:
            if batch.bar is not None:
                batch.bar.close()
    stamp = {"command": command, "executor": ex.describe(), "host": socket.gethostname()}
    table = write_table(r, exp_dir, stamp)
    batch.event(f"table: {table['runs_finished']} of {table['runs_expected']} runs -> {exp_dir / 'table.md'}")
    failed_now = [s.run_id for s in specs if batch.failed_path(s).is_file()]
    print(f"{r['name']}: {table['runs_finished']} of {table['runs_expected']} runs finished "
          f"({batch.done} now, {len(skipped)} skipped), {len(failed_now)} failed -> {exp_dir / 'table.md'}",
          flush=True)
    return {"table": table, "dir": exp_dir, "ran": batch.done, "skipped": len(skipped), "restored": restored,
            "failed": failed_now}


def _run_key(run: dict) -> dict:
    """What identifies the run in a run.json, as RunSpec.key()."""
    k = {"scenario": run.get("scenario"), "seed": run.get("seed"), "overrides": run.get("overrides")}
    if run.get("runner", "mission") != "mission":
        k["runner"] = run["runner"]
    return k


def _same_settings(rec: dict, spec: RunSpec) -> bool:
    """Whether a run record's scenario has the settings the spec resolves to now."""
    from ..errors import NbvsError
    from .records import record_scenario, settings_key
    try:
        was = record_scenario(rec)
    except NbvsError:
        return False
    return was is not None and settings_key(was) == settings_key(spec.resolve())


def _check_writable(folder: Path):
    """One line, before any run, when the records folder cannot be created or written."""
    import tempfile
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-check-"):
            pass
    except OSError as e:
        raise ExperimentError(f"the records folder {folder} cannot be written ({e.strerror or e}); "
                              "choose another --records") from None


def _restore_records(batch: Batch, specs, records, folder: str) -> int:
    """Restores the recorded runs that batch's folder lacks, and sets batch.records: each
    run's own record (records/<folder>/<run>.json.gz), or else the record of the same run made
    by another experiment or under another run name (equal settings, `records.RecordIndex`),
    which is then also recorded under this run's name. A record of its own made with other
    overrides than its spec asks is restored when its scenario has the same settings (and
    recorded again with the spec's overrides), and refused otherwise, as a run folder is; so is
    one of its own made with the same overrides whose scenario they no longer resolve to (a
    preset changed since). Returns the number restored."""
    if records is None:
        return 0
    from .records import RecordIndex, read_record, restore
    batch.records = Path(records) / folder
    _check_writable(batch.records)
    index = RecordIndex(Path(records))
    n = 0
    for spec in specs:
        src = batch.record_path(spec)
        if (batch.final(spec) / "summary.json").is_file():
            continue
        shared = not src.is_file()
        if shared:
            # another experiment's record, or this one's under an older run name (a factor
            # added since renames the runs: the clutter runs before planner.motion_planner)
            src = index.find(spec.resolve(), runner=spec.runner)
            if src is None:
                continue
        rec = read_record(src)
        if shared:  # the run this spec asks for, made under another experiment's name
            rec["run"] = dict(rec.get("run") or {}, **spec.to_json(), shared_from=f"{src.parent.name}/{src.name}")
        key = _run_key(rec.get("run") or {})
        if key != spec.key():
            if not _same_settings(rec, spec):
                raise ExperimentError(f"run record {src} was made with other settings ({key}) than this definition "
                                      f"asks ({spec.key()}); remove it or use other --records")
            # its overrides differ, its scenario does not: a definition that now pins what its
            # scenario file used to leave to the default (e.g. planner.motion_planner)
            rec["run"] = dict(rec.get("run") or {}, **spec.to_json(), recorded_as=key)
            shared = True  # recorded again under the definition's overrides
        elif not shared and not _same_settings(rec, spec):
            # its own record, asked with the same overrides, but the scenario they resolve to
            # has changed since (a preset or a built-in scenario took a new value): not this run
            raise ExperimentError(f"run record {src} was made with other settings than this definition now "
                                  f"resolves to (a preset or scenario changed since it was made); pin what it "
                                  f"was made with in the definition, remove it, or use other --records")
        final = batch.final(spec)
        if final.exists():
            shutil.rmtree(final)
        restore(rec, final, src, final.with_name(f"{final.name}{PARTIAL}restore-{os.getpid()}"))
        batch.failed_path(spec).unlink(missing_ok=True)
        if shared:
            batch.record(spec)
        batch.event(f"restored {spec.run_id} from {src}")
        n += 1
    for line in index.unreadable:
        batch.event(f"record not used: {line}")
    return n
