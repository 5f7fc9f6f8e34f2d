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


#: the lock file of a folder one writer at a time owns (a run folder, an experiment's folder);
#: not an output: no run lists it and no record holds it
LOCK_FILE = ".lock"


class FolderLock:
    """An exclusive OS lock (`fcntl.flock`) on `folder`/.lock, held while the object lives (or
    the `with` block runs): the kernel releases it however the process ends, SIGKILL included,
    so a killed writer never leaves a lock that stops the next. The file holds the owner's pid,
    for the message of whoever finds it taken."""

    def __init__(self, folder, busy: type[Exception], what: str):
        """Takes the lock or raises `busy`("<folder> is in use by <what> (pid N)") at once."""
        import fcntl
        self.path = Path(folder) / LOCK_FILE
        self._f = open(self.path, "a+")
        try:
            fcntl.flock(self._f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._f.seek(0)
            owner = self._f.read().strip()
            self._f.close()
            raise busy(f"{Path(folder)} is in use by {what}" + (f" (pid {owner})" if owner else "")
                       + "; wait for it or choose another output folder") from None
        self._f.seek(0)
        self._f.truncate()
        self._f.write(str(os.getpid()))
        self._f.flush()

    def release(self):
        if not self._f.closed:
            self._f.close()  # closing the descriptor drops the flock

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
