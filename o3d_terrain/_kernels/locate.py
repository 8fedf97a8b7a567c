"""Passes over the points for :func:`o3d_terrain.locate.locate_sensor`: the x/y counts of a
grid, and the points within a radius of a spot."""

import math

import numba
import numpy as np


@numba.njit(cache=True)
def cell_counts(positions, x0, y0, cell, nx, ny):
    """(nx, ny) int64 counts of the points with finite x, y, z in cells of side ``cell`` from
    (x0, y0) (points beyond the last cell counted in it)."""
    counts = np.zeros((nx, ny), np.int64)
    for k in range(positions.shape[0]):
        x = positions[k, 0]
        y = positions[k, 1]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(positions[k, 2])):
            continue
        i = min(max(int((x - x0) / cell), 0), nx - 1)
        j = min(max(int((y - y0) / cell), 0), ny - 1)
        counts[i, j] += 1
    return counts


@numba.njit(cache=True)
def points_within(positions, x, y, radius):
    """(M, 3) copy of the points with finite x, y, z within ``radius`` (x/y) of (x, y)."""
    r2 = radius * radius
    keep = np.zeros(positions.shape[0], np.bool_)
    m = 0
    for k in range(positions.shape[0]):
        dx = positions[k, 0] - x
        dy = positions[k, 1] - y
        if dx * dx + dy * dy <= r2 and math.isfinite(positions[k, 2]):
            keep[k] = True
            m += 1
    out = np.empty((m, 3))
    m = 0
    for k in range(positions.shape[0]):
        if keep[k]:
            out[m, 0] = positions[k, 0]
            out[m, 1] = positions[k, 1]
            out[m, 2] = positions[k, 2]
            m += 1
    return out
