"""Gymnasium environments over the nbvs_drake mission (docs/design.md, "Gymnasium"):

- `nbvs_drake/Reconstruct-v0` (`ReconstructEnv`): the robot's mission, the agent taking each
  next-best-view/state decision;
- `nbvs_drake/ViewSphere-v0` (`ViewSphereEnv`): a free-flying camera on a sphere of 33 views
  around the object (the PC-NBV / SCONE protocol), with the same sensor, map and reward.

`import nbvs_drake.gym` registers both with Gymnasium."""

from __future__ import annotations

import gymnasium as gym

from .reconstruct import ReconstructEnv  # noqa: F401
from .sphere import ViewSphereEnv  # noqa: F401


def _register():
    ids = gym.envs.registry
    if "nbvs_drake/Reconstruct-v0" not in ids:
        gym.register(id="nbvs_drake/Reconstruct-v0", entry_point="nbvs_drake.gym.reconstruct:ReconstructEnv")
    if "nbvs_drake/ViewSphere-v0" not in ids:
        gym.register(id="nbvs_drake/ViewSphere-v0", entry_point="nbvs_drake.gym.sphere:ViewSphereEnv")


_register()
