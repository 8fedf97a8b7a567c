"""Free space along a scan's rays: how high the ground can be under the path of each ray.

A return at p seen from the sensor at o means the straight path from o to p is free: the
ground under every point of it lies lower. The path's height over a horizontal range r from
the sensor is o_z + r * s, s = (p_z - o_z) / R the ray's slope (R its horizontal range), so
over range r in one azimuth sector the ground lies below o_z + r * s for every ray of the
sector that reaches farther than r: below o_z + r * min(s), the lowest of those slopes.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _diamond(dx, dy):
    """A monotone stand-in for the azimuth of (dx, dy) != (0, 0), in [0, 4): 0 along +x, 1
    along +y, 2 along -x, 3 along -y (the position along the unit diamond |x| + |y| = 1).
    Equal steps of it are at most 4 / pi times an equal step of the azimuth wide (at the
    diagonals)."""
    if dy >= 0.0:
        return dy / (dx + dy) if dx >= 0.0 else 1.0 - dx / (dy - dx)
    return 2.0 - dy / (-dx - dy) if dx < 0.0 else 3.0 + dx / (dx - dy)


@numba.njit(cache=True)
def overhead_cells(lowest, x_min, y_min, cell_size, ox, oy, oz, sectors, bin_width, bins, rank,
                   clearance, rise):
    """(nx, ny) bool: the cells of a grid (``lowest``: each cell's lowest point, inf where
    empty; the cell at (x_min, y_min) first, sides ``cell_size``) whose lowest point lies more
    than ``clearance`` + ``rise`` * R above o_z + R * s, with R the horizontal range of the
    cell's centre from the sensor (ox, oy, oz) and s the ``rank``-th lowest slope among the
    rays to the lowest points of the cells of its azimuth sector that lie in a range bin
    (``bin_width`` m, ``bins`` of them, the last holding every farther cell) beyond its own:
    the cells over which rays went on to farther returns, where no ground can be. A cell's
    lowest point stands for its rays (the lowest slope of a cell is its lowest point's, the
    one the bound takes), at the cell's centre. The rank-th lowest instead of the lowest: a
    ray or two that end below the ground (multipath, a reflection) do not lower the bound.
    The ``sectors`` sectors are equal steps of :func:`_diamond`, at most 8 / ``sectors``
    radians wide (``rise`` * R is the caller's allowance for the ground's rise across that
    width)."""
    nx, ny = lowest.shape
    step = sectors / 4.0
    inverse_bin = 1.0 / bin_width
    last_sector = sectors - 1
    # the rank lowest slopes of the rays ending in each (bin, sector), ascending
    low = np.full((bins * sectors, rank), math.inf)
    m = nx * ny
    key = np.full(m, -1, np.int64)  # the cells' bin * sectors + sector, -1 for empty cells
    slope = np.empty(m)
    reach = np.empty(m)
    for ix in range(nx):
        dx = x_min + (ix + 0.5) * cell_size - ox
        for iy in range(ny):
            z = lowest[ix, iy]
            if not math.isfinite(z):
                continue
            dy = y_min + (iy + 0.5) * cell_size - oy
            r = math.sqrt(dx * dx + dy * dy)
            if not r > 0.0:
                continue
            c = ix * ny + iy
            k = min(int(r * inverse_bin), bins - 1) * sectors \
                + min(int(_diamond(dx, dy) * step), last_sector)
            v = (z - oz) / r
            key[c] = k
            slope[c] = v
            reach[c] = r
            if v < low[k, rank - 1]:
                j = rank - 1
                while j > 0 and low[k, j - 1] > v:
                    low[k, j] = low[k, j - 1]
                    j -= 1
                low[k, j] = v
    # low[b * sectors + s] becomes the rank lowest slopes of the rays ending in the bins after
    # b: merged from the farthest bin inwards, every sector's in turn
    carry = np.full((sectors, rank), math.inf)
    merged = np.empty(rank)
    for b in range(bins - 1, -1, -1):
        for s in range(sectors):
            k = b * sectors + s
            if low[k, 0] == math.inf:
                continue  # no cell ends here: none needs its slot, and carry stays as it is
            i = 0
            j = 0
            for t in range(rank):  # i + j = t < rank: both stay in range
                if carry[s, i] <= low[k, j]:
                    merged[t] = carry[s, i]
                    i += 1
                else:
                    merged[t] = low[k, j]
                    j += 1
            for t in range(rank):
                low[k, t] = carry[s, t]
                carry[s, t] = merged[t]
    out = np.zeros((nx, ny), np.bool_)
    flat = out.reshape(m)
    for c in range(m):
        k = key[c]
        if k >= 0:
            r = reach[c]
            flat[c] = (slope[c] - low[k, rank - 1]) * r > clearance + rise * r
    return out

