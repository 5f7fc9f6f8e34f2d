"""What a voxel is: its class (the one encoding every module and kernel uses) and its entropy,
both from its log-odds.

Classes follow the occupancy probability: free l < l_free, unknown l_free <= l <= l_occ,
occupied l > l_occ. `FREE`, `UNKNOWN` and `OCCUPIED` are plain ints so that numba kernels
see them as compile-time constants; `VoxelClass` is the same encoding as an IntEnum.
A set of classes (a coarse cell's summary) is a bit set: class c is the bit `1 << c` (`C_*`).
"""

from __future__ import annotations

import enum
import math

import numba as nb
import numpy as np


class VoxelClass(enum.IntEnum):
    FREE = 0
    UNKNOWN = 1
    OCCUPIED = 2


FREE = int(VoxelClass.FREE)
UNKNOWN = int(VoxelClass.UNKNOWN)
OCCUPIED = int(VoxelClass.OCCUPIED)

C_FREE = 1 << FREE  #: bit of the free class in a set of classes
C_UNKNOWN = 1 << UNKNOWN  #: bit of the unknown class
C_OCCUPIED = 1 << OCCUPIED  #: bit of the occupied class


@nb.njit(cache=True, inline="always")
def voxel_class(l, l_free, l_occ):
    """Class of a voxel of log-odds l (compared in float64)."""
    return OCCUPIED if l > l_occ else (UNKNOWN if l >= l_free else FREE)


@nb.njit(cache=True)
def classes_grid(logodds, l_free, l_occ):
    """int8 classes (FREE, UNKNOWN, OCCUPIED) of a C-contiguous log-odds array of any shape."""
    out = np.empty(logodds.shape, np.int8)
    fl = logodds.reshape(-1)
    fo = out.reshape(-1)
    for v in range(fl.shape[0]):
        fo[v] = voxel_class(fl[v], l_free, l_occ)
    return out


@nb.njit(cache=True, inline="always")
def _entropy_from_logodds(l):
    p = 1.0 / (1.0 + math.exp(-l))
    if p <= 0.0 or p >= 1.0:
        return 0.0
    return -p * math.log(p) - (1.0 - p) * math.log(1.0 - p)


@nb.njit(cache=True)
def entropy_grid(logodds):
    """Entropy H(p) of every voxel (float32, same shape)."""
    out = np.empty(logodds.shape, np.float32)
    fl = logodds.reshape(-1)
    fo = out.reshape(-1)
    for v in range(fl.shape[0]):
        fo[v] = _entropy_from_logodds(fl[v])
    return out
