"""The visual outputs of a run, each written on its own so that a failure cannot cost the
run its other results: paths.png (`plots.plot_paths`) and replay.html
(`replay.write_replay_html`)."""

from __future__ import annotations

import time
from pathlib import Path

from .replay import write_replay_html


def write_visual_outputs(out_dir, sc, records: list[dict], maps=None, obj_mesh_path=None,
                         verbose: bool = False, collision: dict | None = None, model_mesh=None) -> dict:
    """paths.png (top view of planned vs executed paths) and replay.html in `out_dir`. Each
    is written on its own: a failure is reported (returned under "errors" and printed), never
    raised, so that it cannot cost the run its other results. Returns
    {"seconds": ..., "errors": [...], "replay": info of write_replay_html or None}."""
    import traceback

    from .plots import plot_paths
    out = Path(out_dir)
    t0 = time.perf_counter()
    errors, info = [], None
    try:
        plot_paths(records, out / "paths.png", sc.scene, title=f"{sc.name} (seed {sc.seed}): paths, top view",
                   collision=collision)
    except Exception as e:  # noqa: BLE001 - a plot must not lose the run
        errors.append(f"paths.png: {type(e).__name__}: {e}")
        if verbose:
            traceback.print_exc()
    if obj_mesh_path is not None and not Path(obj_mesh_path).is_file():
        obj_mesh_path = None
    try:
        info = write_replay_html(out / "replay.html", sc, records, maps, obj_mesh_path, collision=collision,
                                 model_mesh=model_mesh)
    except Exception as e:  # noqa: BLE001
        errors.append(f"replay.html: {type(e).__name__}: {e}")
        if verbose:
            traceback.print_exc()
    for e in errors:
        print(f"nbvs: warning: could not write {e}", flush=True)
    return {"seconds": time.perf_counter() - t0, "errors": errors, "replay": info}
