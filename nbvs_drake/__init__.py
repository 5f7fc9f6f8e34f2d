"""nbvs_drake: next-best-view/state planning for 3D object reconstruction with a mobile
manipulator (PatrolBot + Katana 6M180, eye-in-hand depth camera), simulated as a Drake
systems diagram."""

from pathlib import Path

__version__ = "0.1.0"

#: Repository folders shipped beside the package (the package is installed in editable mode).
REPO_ROOT = Path(__file__).resolve().parent.parent
MODELS_DIR = REPO_ROOT / "models"
DIAGRAMS_DIR = REPO_ROOT / "diagrams"
DEFAULT_SCENARIO = DIAGRAMS_DIR / "default.yaml"
