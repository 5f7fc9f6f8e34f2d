"""The picture of a scenario's diagram wiring (Graphviz from Drake's GetGraphvizString)."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from .config import Scenario


def write_wiring(sc: Scenario, out_base: Path) -> list[Path]:
    """Writes OUT.dot, and OUT.svg when Graphviz's `dot` is installed. Returns the paths."""
    from .diagram import build_mission_diagram
    out_base = Path(out_base)
    with tempfile.TemporaryDirectory() as tmp:
        md = build_mission_diagram(sc, Path(tmp), log=None)
        dot = md.diagram.GetGraphvizString(max_depth=1)
    paths = [out_base.with_suffix(".dot")]
    paths[0].write_text(dot)
    if shutil.which("dot"):
        svg = out_base.with_suffix(".svg")
        subprocess.run(["dot", "-Tsvg", str(paths[0]), "-o", str(svg)], check=True)
        paths.append(svg)
    return paths
