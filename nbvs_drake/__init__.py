"""nbvs_drake: next-best-view/state planning for 3D object reconstruction with a mobile
manipulator (PatrolBot + Katana 6M180, eye-in-hand depth camera), simulated as a Drake
systems diagram.

    import nbvs_drake
    result = nbvs_drake.reconstruct("teapot_eu_mu", out="results/eu")   # a RunResult
    result = nbvs_drake.RunResult.load("results/eu")                     # read a run back

The models and built-in scenarios are package data: see `nbvs_drake.resources`."""

from .api import RunResult, reconstruct

__version__ = "0.1.0"

__all__ = ["RunResult", "reconstruct", "__version__"]

#: old names of the data folders (before `nbvs_drake.resources`), kept for code that still
#: imports them; new code calls resources.models_dir(), diagrams_dir(), scenario_path()
_OLD_NAMES = {"MODELS_DIR": "models_dir", "DIAGRAMS_DIR": "diagrams_dir", "DEFAULT_SCENARIO": "default_scenario_path"}


def __getattr__(name):
    if name in _OLD_NAMES:
        from . import resources
        return getattr(resources, _OLD_NAMES[name])()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
