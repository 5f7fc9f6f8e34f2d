"""The picture of a scenario's diagram wiring (Graphviz from Drake's GetGraphvizString)."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from ..config import Scenario


def write_wiring(sc: Scenario, out_base: Path) -> list[Path]:
    """Writes OUT.dot, and OUT.svg and OUT.png when Graphviz's `dot` is installed. Returns
    the paths written."""
    from ..app.diagram import build_mission_diagram
    out_base = Path(out_base)
    with tempfile.TemporaryDirectory() as tmp:
        md = build_mission_diagram(sc, Path(tmp), log=None)
        dot = md.diagram.GetGraphvizString(max_depth=1)
    paths = [out_base.with_suffix(".dot")]
    paths[0].write_text(dot)
    if shutil.which("dot"):
        for fmt, extra in (("svg", []), ("png", ["-Gdpi=80"])):
            p = out_base.with_suffix("." + fmt)
            subprocess.run(["dot", f"-T{fmt}", *extra, str(paths[0]), "-o", str(p)], check=True)
            paths.append(p)
    return paths
