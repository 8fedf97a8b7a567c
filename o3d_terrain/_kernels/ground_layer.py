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


@numba.njit(cache=True)
def overhung_ground(positions, x_min, y_min, cell_size, z, lowest, highest, above, state,
                    measured, connected, compact, layer, tolerance, clearance, spread, widen):
    """The cells of a connected terrain that are not ``compact`` but whose ground layer is
    their sample: ``connected`` and not ``compact``, the sample ``z`` within the layer
    (z <= lowest + layer), the lowest point at most ``tolerance`` above the lowest point of
    every ``measured`` 8-neighbour (``state`` == ``measured``, finite lowest point: nothing
    lower around it), and no point in (top, top + clearance) with top = lowest + layer (every
    point above the layer, if any, leaves a free gap: a canopy or an overhang; a wall, a
    trunk or a bush returns continuously from its base).

    Returns (overhung, protected = compact | overhung) and sets ``spread`` to ``widen`` on
    the overhung cells (in place). A cell whose ``highest`` point is within the layer, or
    less than ``clearance`` above its top, is decided here; the others by ``above``, the
    lowest z above the top per cell gathered in the grid's pass over the points
    (:func:`o3d_terrain._kernels.grid.quantize` with this ``layer``): h - t rounds
    monotonically in h, so some point h > t has h - t < clearance exactly when the lowest
    one does. With ``above`` empty (0, 0), one pass over the rows (x, y, z) of
    ``positions`` (points outside the grid or with a non-finite coordinate are skipped; the
    cell is computed only for points between the lowest pending top and the highest
    pending top + clearance) looks for a point in the gap instead, if any candidate needs
    it."""
    nx, ny = z.shape
    gathered = above.shape[0] > 0
    m = nx * ny
    top = np.full(m, np.inf)  # finite on undecided candidates
    overhung = np.zeros((nx, ny), np.bool_)
    protected = compact.copy()
    pending = False
    low_top = np.inf  # the pending tops' range: only points within it (+ clearance) matter
    high_top = -np.inf
    for i in range(nx):
        for j in range(ny):
            if not connected[i, j] or compact[i, j] or state[i, j] != measured:
                continue
            lo = lowest[i, j]
            t = lo + layer
            if not z[i, j] <= t:
                continue
            least = np.inf
            for di in range(-1, 2):
                a = i + di
                if a < 0 or a >= nx:
                    continue
                for dj in range(-1, 2):
                    b = j + dj
                    if b < 0 or b >= ny or (di == 0 and dj == 0) or state[a, b] != measured:
                        continue
                    least = min(least, lowest[a, b])
            if not lo <= least + tolerance:
                continue
            hi = highest[i, j]
            if hi <= t:  # every point within the layer
                overhung[i, j] = True
            elif hi - t >= clearance and gathered:  # the lowest point above the layer
                overhung[i, j] = not above[i, j] - t < clearance
            elif hi - t >= clearance:  # points above the gap; one may lie inside it
                overhung[i, j] = True
                top[i * ny + j] = t
                pending = True
                low_top = min(low_top, t)
                high_top = max(high_top, t)
    if pending:
        flat = overhung.reshape(m)
        high_gap = high_top + clearance
        for k in range(positions.shape[0]):
            h = positions[k, 2]
            if not (h > low_top and h < high_gap):  # in no pending cell's gap (or NaN)
                continue
            c = _cell(positions[k, 0], positions[k, 1], x_min, y_min, cell_size, nx, ny)
            if c < 0:
                continue
            t = top[c]  # inf unless pending
            if h > t and h - t < clearance:
                flat[c] = False
                top[c] = np.inf
    for i in range(nx):
        for j in range(ny):
            if overhung[i, j]:
                protected[i, j] = True
                spread[i, j] = widen
    return overhung, protected
