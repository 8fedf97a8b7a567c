"""Ground-layer samples: the points within a thin layer above a cell's lowest point
(see :mod:`o3d_terrain.ground_layer`).

Arrays are ``[ix, iy]`` like the height grid. NumPy in, NumPy out.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .grid import _cell


@numba.njit(cache=True)
def ground_layer_samples(positions, x_min, y_min, cell_size, z, lowest, count, measured,
                         layer, min_points, min_fraction):
    """(samples, replaced) over the (nx, ny) grid: ``z`` where kept; the mean height of the
    points with lowest <= z_point <= lowest + layer where the cell is ``measured``, its
    sample is above that layer, and the layer holds at least ``min_points`` points and
    ``min_fraction`` of the cell's ``count``.

    A pass over the cells finds the candidates (sample above the layer); only if there are
    any, one pass over the rows (x, y, z) of ``positions`` (points outside the grid or with
    a non-finite coordinate are skipped) for the layer's counts and sums; then the rule of
    :func:`ground_layer_from_sums`."""
    nx, ny = z.shape
    m = nx * ny
    flat_z = z.reshape(m)
    flat_lowest = lowest.reshape(m)
    flat_measured = measured.reshape(m)
    # candidate cells: sample above the layer (few: most cells are compact)
    top = np.full(m, -np.inf)
    any_candidate = False
    for c in range(m):
        if flat_measured[c] and flat_z[c] > flat_lowest[c] + layer:
            top[c] = flat_lowest[c] + layer
            any_candidate = True
    near = np.zeros(m, np.int64)
    total = np.zeros(m)
    if any_candidate:
        for k in range(positions.shape[0]):
            c = _cell(positions[k, 0], positions[k, 1], x_min, y_min, cell_size, nx, ny)
            if c < 0:
                continue
            h = positions[k, 2]
            if h <= top[c] and math.isfinite(h):
                near[c] += 1
                total[c] += h
    return ground_layer_from_sums(z, lowest, count, measured, near.reshape(nx, ny),
                                  total.reshape(nx, ny), layer, min_points, min_fraction)


@numba.njit(cache=True)
def ground_layer_from_sums(z, lowest, count, measured, layer_count, layer_sum, layer,
                           min_points, min_fraction):
    """:func:`ground_layer_samples` from per-cell statistics gathered in the grid's point
    pass (``layer_count`` and ``layer_sum`` of the z values within [lowest, lowest + layer],
    :func:`o3d_terrain._kernels.grid.quantize`): the same candidates, counts and sums (in
    point order), so the same samples, without a pass over the points."""
    nx, ny = z.shape
    samples = z.copy()
    replaced = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            if not (measured[i, j] and z[i, j] > lowest[i, j] + layer):
                continue
            n = layer_count[i, j]
            if n >= min_points and n >= min_fraction * count[i, j]:
                samples[i, j] = layer_sum[i, j] / n
                replaced[i, j] = True
    return samples, replaced
