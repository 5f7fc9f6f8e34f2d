"""Keeps numba's on-disk cache of the package's kernels consistent with their sources.

numba (`cache=True`) keys a cached kernel on its own source file only: a kernel in
planning/path_verdicts.py that calls or inlines one in planning/certificate.py keeps its cached machine
code after clearance.py changes (a `git pull` or an edit in a source checkout), and would run
the old callee. `drop_stale` stamps the kernel modules together (each one's size and
modification time, what numba stamps one file with) and, when the stamp differs from the one
the cache was built under, removes the package's cached kernels, so that they compile again.
An installed wheel rewrites every file, so it is consistent anyway; the stamp costs ~1 ms."""

from __future__ import annotations

import hashlib
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
STAMP = "numba_kernels.stamp"


def kernel_sources(root: Path = PACKAGE) -> list[Path]:
    """The package's modules that define numba kernels."""
    return sorted(p for p in root.rglob("*.py")
                  if p.name != "kernel_cache.py" and "njit(" in p.read_text(encoding="utf-8", errors="ignore"))


def sources_stamp(root: Path = PACKAGE) -> str:
    h = hashlib.sha1()
    for p in kernel_sources(root):
        st = p.stat()
        h.update(f"{p.relative_to(root)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def drop_stale(root: Path = PACKAGE) -> bool:
    """Removes the cached kernels (`__pycache__/*.nbi`, `*.nbc` under root) when the kernel
    sources changed since they were cached; True when it removed them. Does nothing where the
    package's folder is not writable (numba then caches elsewhere, per installed file)."""
    marker = root / "__pycache__" / STAMP
    try:
        stamp = sources_stamp(root)
        if marker.is_file() and marker.read_text() == stamp:
            return False
        removed = False
        for cache in root.rglob("__pycache__"):
            for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
                f.unlink(missing_ok=True)
                removed = True
        marker.parent.mkdir(exist_ok=True)
        tmp = marker.with_suffix(".tmp")
        tmp.write_text(stamp)
        tmp.replace(marker)
        return removed
    except OSError:
        return False
