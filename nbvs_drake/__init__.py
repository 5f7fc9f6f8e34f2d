"""nbvs_drake: next-best-view/state planning for 3D object reconstruction with a mobile
manipulator (PatrolBot + Katana 6M180, eye-in-hand depth camera), simulated as a Drake
systems diagram.

    import nbvs_drake
    result = nbvs_drake.reconstruct("teapot_eu_mu", out="results/eu")   # a RunResult
    result = nbvs_drake.RunResult.load("results/eu")                     # read a run back

The models and built-in scenarios are package data: see `nbvs_drake.resources`."""

from .kernel_cache import drop_stale

drop_stale()  # before any kernel loads from numba's cache (kernel_cache.py says why)

from .app.api import RunResult, reconstruct  # noqa: E402
from .config.schema import set_wbox_rule  # noqa: E402
from .world.objects import automatic_wbox  # noqa: E402

set_wbox_rule(automatic_wbox)  # the configuration's automatic W_box, from the object model

__version__ = "0.1.0"

__all__ = ["RunResult", "reconstruct", "__version__"]
