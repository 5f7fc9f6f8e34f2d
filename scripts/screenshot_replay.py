#!/usr/bin/env python
"""Screenshots of a run's replay.html in headless Chromium (software WebGL, no network).

    .venv/bin/python scripts/screenshot_replay.py results/default              # 2 s in, and the end
    .venv/bin/python scripts/screenshot_replay.py results/default --at 0 --at 20 --at end --size 1600x1000

Writes replay_<moment>.png next to replay.html (or into --out) and prints, per picture, the
share of yellow (unknown voxels) and blue (occupied voxels) pixels. A moment is seconds into
the recording or "end" (the page is opened as replay.html#t=<moment>, paused there).
Chromium: Debian `apt-get install chromium` (scripts/setup.sh installs it when run as root).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a results folder holding replay.html, or an .html file")
    ap.add_argument("--at", action="append", default=None, help='seconds into the recording, or "end" (repeatable)')
    ap.add_argument("--out", default=None, help="folder for the PNGs (default: next to the html)")
    ap.add_argument("--size", default="1024x768", help="window size WxH")
    args = ap.parse_args(argv)
    from nbvs_drake.outputs.screenshot import find_chromium, image_colours, screenshot_html
    html = Path(args.run)
    if html.is_dir():
        html = html / "replay.html"
    if not html.is_file():
        print(f"screenshot_replay: no such file: {html}", file=sys.stderr)
        return 2
    if find_chromium() is None:
        print("screenshot_replay: no chromium found (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else html.parent
    out.mkdir(parents=True, exist_ok=True)
    w, h = (int(v) for v in args.size.lower().split("x"))
    for at in args.at or ["2", "end"]:
        png = screenshot_html(html, out / f"{html.stem}_{at.replace('.', '_')}.png", at_s=at, size=(w, h))
        print(json.dumps({"png": str(png), "at": at, **image_colours(png)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
