"""Warms the caches of a fresh install, so that its first run waits for nothing (`make setup`
runs `python -m nbvs_drake.warmup`): the motion planner's numba kernels
(`planning.warmup.warm_kernels`), then everything else a mission calls (scan integration,
view evaluation, coverage) by a two-scan run of the default scenario, which also puts the
default object's coverage ceiling into its cache (planning/oracle.py)."""

from __future__ import annotations

import time

from .planning.warmup import warm_kernels


def warm_run() -> float:
    """A two-scan run of the default scenario into a temporary folder; returns its seconds."""
    import tempfile

    from .config import load_scenario
    from .mission import run_mission
    t = time.perf_counter()
    sc = load_scenario(settings=["mission.max_scans=2", "planner.n_candidates=300"])
    with tempfile.TemporaryDirectory() as tmp:
        run_mission(sc, tmp, verbose=False)
    return time.perf_counter() - t


if __name__ == "__main__":
    from .errors import quiet_library_logs
    quiet_library_logs()
    print(f"warmup: the motion planner's numba kernels compiled in {warm_kernels():.1f} s", flush=True)
    print(f"warmup: a two-scan run (the other kernels, the default object's ceiling) in {warm_run():.1f} s")
