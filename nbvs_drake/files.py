"""Atomic file writes: a file the package writes (a run's JSON, map, cloud, replay, an
experiment's table or record) appears complete or not at all, even when the process is
killed mid-write (SIGKILL), so a reader never sees half a file."""

from __future__ import annotations

import os
from pathlib import Path


def write_atomic(path, data: str | bytes, *, mkdir: bool = False) -> Path:
    """Writes `data` (text as UTF-8, or bytes) to `path` through a temporary file in the same
    folder (named after this process, so two writers never share one), then renames it over
    `path` (os.replace: atomic on POSIX). mkdir: create the missing parent folders. Returns
    `path`. On an error the temporary file is removed and `path` keeps its old content."""
    path = Path(path)
    if mkdir:
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        if isinstance(data, str):
            tmp.write_text(data, encoding="utf-8")
        else:
            tmp.write_bytes(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
