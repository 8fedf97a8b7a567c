"""Kernels for obstacle clustering and the traversability cost map (NumPy in, NumPy out)."""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def bin_points(x, y, x_min, y_min, cell_size, nx, ny):
    """Cell (ix, iy) of every point as two int64 arrays; -1 for both outside or non-finite."""
    n = x.shape[0]
    ix = np.empty(n, np.int64)
    iy = np.empty(n, np.int64)
    for k in range(n):
        fx = (x[k] - x_min) / cell_size
        fy = (y[k] - y_min) / cell_size
        if not (math.isfinite(fx) and math.isfinite(fy)):
            ix[k] = -1
            iy[k] = -1
            continue
        i = int(math.floor(fx))
        j = int(math.floor(fy))
        if i < 0 or j < 0 or i >= nx or j >= ny:
            ix[k] = -1
            iy[k] = -1
        else:
            ix[k] = i
            iy[k] = j
    return ix, iy


@numba.njit(cache=True)
def cell_statistics(ix, iy, h, use, nx, ny, rough_cap):
    """Per-cell count, highest h, and sum/sum of squares of h over points with h <= rough_cap.

    Only points with ``use[k]`` and a cell (ix >= 0) and a finite h count. Returns
    ``count`` (nx, ny) int32, ``highest`` (nx, ny) float64 (-inf where empty), ``rough_n``,
    ``rough_sum`` and ``rough_sum2`` (nx, ny): the roughness moments.
    """
    count = np.zeros((nx, ny), np.int32)
    highest = np.full((nx, ny), -np.inf)
    rough_n = np.zeros((nx, ny), np.int32)
    rough_sum = np.zeros((nx, ny))
    rough_sum2 = np.zeros((nx, ny))
    for k in range(ix.shape[0]):
        i = ix[k]
        if i < 0 or not use[k]:
            continue
        v = h[k]
        if not math.isfinite(v):
            continue
        j = iy[k]
        count[i, j] += 1
        if v > highest[i, j]:
            highest[i, j] = v
        if v <= rough_cap:
            rough_n[i, j] += 1
            rough_sum[i, j] += v
            rough_sum2[i, j] += v * v
    return count, highest, rough_n, rough_sum, rough_sum2


@numba.njit(cache=True)
def mark_cells(ix, iy, select, nx, ny):
    """(nx, ny) uint8 mask: 1 where a selected point falls."""
    mask = np.zeros((nx, ny), np.uint8)
    for k in range(ix.shape[0]):
        if select[k] and ix[k] >= 0:
            mask[ix[k], iy[k]] = 1
    return mask


@numba.njit(cache=True)
def cluster_moments(point_cluster, x, y, z, h, n_clusters):
    """Per cluster: point count, sums of x, y, z, lowest z, highest z, highest h."""
    count = np.zeros(n_clusters, np.int64)
    sums = np.zeros((n_clusters, 3))
    z_low = np.full(n_clusters, np.inf)
    z_high = np.full(n_clusters, -np.inf)
    h_high = np.full(n_clusters, -np.inf)
    for k in range(point_cluster.shape[0]):
        c = point_cluster[k]
        if c < 0:
            continue
        count[c] += 1
        sums[c, 0] += x[k]
        sums[c, 1] += y[k]
        sums[c, 2] += z[k]
        if z[k] < z_low[c]:
            z_low[c] = z[k]
        if z[k] > z_high[c]:
            z_high[c] = z[k]
        if h[k] > h_high[c]:
            h_high[c] = h[k]
    return count, sums, z_low, z_high, h_high


@numba.njit(cache=True)
def hull_candidates(cell, x, y, n_cells):
    """Per occupied cell, the points extreme along x, y, x + y and x - y (both signs).

    ``cell`` (M,) flat cell index of each point (>= 0). Returns (n_cells, 8) point indices, -1
    for empty cells. The convex hull of any union of cells is, to within a small fraction of a
    cell, the hull of these candidates, so boxes can be fitted on them instead of every point.
    """
    best = np.full((n_cells, 8), -1, np.int64)
    value = np.empty((n_cells, 8))
    for k in range(cell.shape[0]):
        c = cell[k]
        a = x[k]
        b = y[k]
        keys = (a, -a, b, -b, a + b, -a - b, a - b, b - a)
        for d in range(8):
            if best[c, d] < 0 or keys[d] > value[c, d]:
                best[c, d] = k
                value[c, d] = keys[d]
    return best


@numba.njit(cache=True)
def group_by(ids, n_groups):
    """Counting sort: ``order`` of the items with ids 0..n_groups-1 (others left out), grouped
    by id in item order, and ``starts`` (n_groups + 1,): group g is order[starts[g]:starts[g+1]]."""
    starts = np.zeros(n_groups + 1, np.int64)
    for k in range(ids.shape[0]):
        g = ids[k]
        if g >= 0 and g < n_groups:
            starts[g + 1] += 1
    for g in range(n_groups):
        starts[g + 1] += starts[g]
    fill = starts[:-1].copy()
    order = np.empty(starts[n_groups], np.int64)
    for k in range(ids.shape[0]):
        g = ids[k]
        if g >= 0 and g < n_groups:
            order[fill[g]] = k
            fill[g] += 1
    return order, starts
