"""Probabilistic occupancy mapping and view evaluation (numba kernels)."""

from .occupancy import OccupancyMap, GridSpec, SensorModel, grid_for_scenario, UNKNOWN, FREE, OCCUPIED  # noqa: F401
