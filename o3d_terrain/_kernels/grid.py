"""Grid quantization kernel (Broggi et al. 2013, Sec. IV, eq. 1)."""

from __future__ import annotations

import math

import numba
import numpy as np

INVALID = 0
MEASURED = 1
FILLED = 2


@numba.njit(cache=True, inline="always")
def _scaled_cell(fx, fy, nx, ny):
    """:func:`_cell` from the point's coordinates in cells, fx = (x - x_min) / cell_size and
    fy likewise."""
    if not (math.isfinite(fx) and math.isfinite(fy)):
        return -2
    ix = int(math.floor(fx))
    iy = int(math.floor(fy))
    if ix == nx and fx <= nx:
        ix = nx - 1
    if iy == ny and fy <= ny:
        iy = ny - 1
    if ix < 0 or iy < 0 or ix >= nx or iy >= ny:
        return -1
    return ix * ny + iy


@numba.njit(cache=True, inline="always")
def _cell(x, y, x_min, y_min, cell_size, nx, ny):
    """Flat cell index (ix * ny + iy) of one point; -1 outside the grid, -2 non-finite x or y.

    A point on the far edge of the grid (x == x_min + nx * cell_size) goes to the last cell.
    """
    return _scaled_cell((x - x_min) / cell_size, (y - y_min) / cell_size, nx, ny)


@numba.njit(cache=True)
def cell_indices(x, y, x_min, y_min, cell_size, nx, ny):
    """:func:`_cell` of every point given as separate x and y arrays."""
    out = np.empty(x.shape[0], np.int64)
    for k in range(x.shape[0]):
        out[k] = _cell(x[k], y[k], x_min, y_min, cell_size, nx, ny)
    return out


@numba.njit(cache=True)
def quantize(positions, x_min, y_min, cell_size, nx, ny, min_points, fill_empty, layer=0.0,
             inverse=0.0):
    """Per-cell height Z = max(min z, mean z - sigma) (eq. 1), counts, state, lowest, highest
    and mean z of the rows (x, y, z) of an (N, 3) array (read in place); with ``layer`` > 0
    also the number and the sum of the z values within [lowest, lowest + layer] per cell and
    the lowest z above lowest + layer (inf where none): the ground-layer statistics of
    :mod:`o3d_terrain.ground_layer`, summed in point order, and what its canopy rule needs
    (empty arrays otherwise).

    Each point's cell is :func:`_cell`, found in the first pass over the points and kept for
    the second (no separate pass). ``inverse`` > 0 must be exactly 1 / cell_size (a power of
    two cell size): the coordinates are then scaled by a multiplication, which gives the
    quotient bit for bit. Points with a non-finite x, y or z, or outside the grid, are
    skipped and counted: the result ends with (number non-finite, number outside the grid).
    Cells with fewer than ``min_points`` points are empty. Empty cells take the mean of the
    8-neighbour *measured* cells (state FILLED) when ``fill_empty``; otherwise, or with no
    measured neighbour, they are INVALID with Z = 0. Sums are taken in point order (a plain
    reference implementation reproduces them exactly). Lowest and highest z are inf and -inf,
    the mean 0, in cells without points (whatever ``min_points``).
    """
    m = nx * ny
    n = positions.shape[0]
    cells = np.empty(n, np.int32)  # m <= MAX_CELLS of o3d_terrain.grid, far below 2^31
    count = np.zeros(m, np.int64)
    total = np.zeros(m)
    lowest = np.full(m, np.inf)
    highest = np.full(m, -np.inf)
    nonfinite = 0
    outside = 0
    for k in range(n):
        if inverse > 0.0:
            c = _scaled_cell((positions[k, 0] - x_min) * inverse,
                             (positions[k, 1] - y_min) * inverse, nx, ny)
        else:
            c = _cell(positions[k, 0], positions[k, 1], x_min, y_min, cell_size, nx, ny)
        v = positions[k, 2]
        if c == -2 or not math.isfinite(v):
            nonfinite += 1
            cells[k] = -1
            continue
        cells[k] = c
        if c < 0:
            outside += 1
            continue
        count[c] += 1
        total[c] += v
        lowest[c] = min(lowest[c], v)  # branch-free (cells hold few points: branches mispredict)
        highest[c] = max(highest[c], v)
    mean = np.zeros(m)
    for c in range(m):
        if count[c] > 0:
            mean[c] = total[c] / count[c]
    squares = np.zeros(m)
    use_layer = layer > 0.0
    layer_count = np.zeros(m if use_layer else 0, np.int64)
    layer_sum = np.zeros(m if use_layer else 0)
    layer_above = np.full(m if use_layer else 0, np.inf)
    for k in range(n):
        c = cells[k]
        if c < 0:
            continue
        v = positions[k, 2]
        d = v - mean[c]
        squares[c] += d * d
        if use_layer:
            if v <= lowest[c] + layer:
                layer_count[c] += 1
                layer_sum[c] += v
            else:
                layer_above[c] = min(layer_above[c], v)
    height = np.zeros(m)
    state = np.zeros(m, np.uint8)
    for c in range(m):
        if count[c] >= min_points and count[c] > 0:
            sigma = math.sqrt(squares[c] / count[c])
            height[c] = max(lowest[c], mean[c] - sigma)
            state[c] = MEASURED
    if fill_empty:
        for ix in range(nx):
            for iy in range(ny):
                c = ix * ny + iy
                if state[c] == MEASURED:
                    continue
                acc = 0.0
                n = 0
                for dx in range(-1, 2):
                    for dy in range(-1, 2):
                        jx = ix + dx
                        jy = iy + dy
                        if (dx == 0 and dy == 0) or jx < 0 or jy < 0 or jx >= nx or jy >= ny:
                            continue
                        j = jx * ny + jy
                        if state[j] == MEASURED:
                            acc += height[j]
                            n += 1
                if n > 0:
                    height[c] = acc / n
                    state[c] = FILLED
    return (
        height.reshape(nx, ny),
        count.reshape(nx, ny),
        state.reshape(nx, ny),
        lowest.reshape(nx, ny),
        highest.reshape(nx, ny),
        mean.reshape(nx, ny),
        nonfinite,
        outside,
        layer_count.reshape(nx, ny) if use_layer else layer_count.reshape(0, 0),
        layer_sum.reshape(nx, ny) if use_layer else layer_sum.reshape(0, 0),
        layer_above.reshape(nx, ny) if use_layer else layer_above.reshape(0, 0),
    )


@numba.njit(cache=True)
def finite_bounds(x, y, z):
    """(x_min, x_max, y_min, y_max, number of finite points) over points with finite x, y, z."""
    x_min = np.inf
    x_max = -np.inf
    y_min = np.inf
    y_max = -np.inf
    n = 0
    for k in range(x.shape[0]):
        if math.isfinite(x[k]) and math.isfinite(y[k]) and math.isfinite(z[k]):
            n += 1
            if x[k] < x_min:
                x_min = x[k]
            if x[k] > x_max:
                x_max = x[k]
            if y[k] < y_min:
                y_min = y[k]
            if y[k] > y_max:
                y_max = y[k]
    return x_min, x_max, y_min, y_max, n
