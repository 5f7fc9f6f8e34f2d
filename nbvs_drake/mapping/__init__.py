"""Probabilistic occupancy mapping and view evaluation (numba kernels)."""

from .occupancy import GridSpec, OccupancyMap, SensorModel, grid_for_scenario  # noqa: F401
from .voxel import FREE, OCCUPIED, UNKNOWN, VoxelClass  # noqa: F401
