"""Screenshots of a page (replay.html) in headless Chromium with software WebGL and no
network, and the colour shares of a screenshot (what the tests and
`scripts/screenshot_replay.py` check a rendered replay by)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

CHROMIUM_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """The path of a Chromium/Chrome executable, or None."""
    import shutil
    for name in CHROMIUM_CANDIDATES:
        p = shutil.which(name)
        if p:
            return p
    return None


def screenshot_html(html_path, png_path, *, at_s: float | str | None = None, size=(1024, 768),
                    chromium: str | None = None, load_ms: int = 4000, timeout_s: float = 240.0) -> Path:
    """Renders `html_path` in headless Chromium (software WebGL: SwiftShader) and writes a PNG.
    `at_s`: the moment of the recording to show (seconds or "end"; the page is opened as
    replay.html#t=...), None: whatever plays after `load_ms` of virtual time. Needs no
    network (every flag that would reach out is off)."""
    import os
    import signal
    import subprocess
    import tempfile
    exe = chromium or find_chromium()
    if exe is None:
        raise FileNotFoundError("no chromium executable found (Debian: apt-get install chromium)")
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    url = html_path.as_uri() + (f"#t={at_s}" if at_s is not None else "")
    with tempfile.TemporaryDirectory(prefix="nbvs_chromium_", ignore_cleanup_errors=True) as profile:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
               "--use-angle=swiftshader", "--disable-quic", "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--disable-extensions", "--disable-dev-shm-usage",
               "--hide-scrollbars", f"--user-data-dir={profile}", f"--screenshot={png_path}",
               f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={int(load_ms)}", url]
        if png_path.exists():
            png_path.unlink()
        # its own process group: on a timeout the renderer and GPU processes go too
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise RuntimeError(f"chromium did not finish the screenshot within {timeout_s:.0f} s") from None
    if not png_path.is_file():
        tail = "\n".join(out.splitlines()[-5:])
        raise RuntimeError(f"chromium wrote no screenshot (exit {proc.returncode}): {tail}")
    return png_path


def image_colours(png_path) -> dict:
    """Pixel shares of a screenshot: yellow (unknown voxels), blue (occupied), and the
    number of distinct colours (coarsely quantised)."""
    from PIL import Image
    a = np.asarray(Image.open(png_path).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    n = r.size
    yellow = (r > 180) & (g > 150) & (b < 110)
    blue = (b > 150) & (r < 110) & (b - g > 40)
    q = (a // 32).reshape(-1, 3)
    distinct = len(np.unique(q[:, 0] * 64 + q[:, 1] * 8 + q[:, 2]))
    return {"yellow": float(yellow.sum() / n), "blue": float(blue.sum() / n), "distinct_colours": distinct}
