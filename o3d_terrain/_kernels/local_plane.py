"""Terrain from local planes through the terrain points around a point (the misfit's
densification, :func:`o3d_terrain.misfit.local_plane_terrain`).

A candidate point becomes terrain when its height lies at most ``threshold`` above the plane
fitted (least squares in the heights above the surface) through the terrain points within
``radius`` of it, provided at least ``min_points`` of them surround it (some on either side
of it in x and in y: the plane is interpolated, not extrapolated). Rounds repeat until none
changes or ``max_rounds``; each round decides from the terrain of the round before, so the
order of the candidates does not matter, and after the first it looks again only at the
candidates with new terrain in their 3 x 3 cells (the others would decide as before).

The neighbours are found in a grid of cells at least ``radius`` wide over the candidates'
bounding box grown by ``radius`` (its side grows so that it holds at most about 4096 cells per
axis): a point's neighbours within ``radius`` lie in its cell's 3 x 3 block.
"""

import math

import numba
import numpy as np

#: cells per axis of the neighbour grid at most (the cell grows beyond ``radius`` to keep this)
_MAX_CELLS = 4096.0


@numba.njit(cache=True, inline="always")
def _candidate_grid(positions, candidates, margin, cell):
    """(x0, x1, y0, y1, side, nx, ny): the candidates' x/y bounding box grown by ``margin``,
    tiled from (x0, y0) by square cells at least ``cell`` wide (wider when the box would
    need more than :data:`_MAX_CELLS` per axis), nx x ny of them."""
    x0 = np.inf
    x1 = -np.inf
    y0 = np.inf
    y1 = -np.inf
    for k in range(candidates.size):
        i = candidates[k]
        x0 = min(x0, positions[i, 0])
        x1 = max(x1, positions[i, 0])
        y0 = min(y0, positions[i, 1])
        y1 = max(y1, positions[i, 1])
    x0 -= margin
    y0 -= margin
    x1 += margin
    y1 += margin
    side = max(cell, (x1 - x0) / _MAX_CELLS, (y1 - y0) / _MAX_CELLS)
    return x0, x1, y0, y1, side, int((x1 - x0) / side) + 1, int((y1 - y0) / side) + 1


@numba.njit(cache=True)
def local_plane_terrain(positions, heights, terrain, candidates, radius, threshold,
                        min_points, max_rounds):
    """In place: ``terrain[i]`` (bool, (N,)) set for the ``candidates`` (int64 indices) that
    lie at most ``threshold`` above the local plane of the terrain points around them (module
    docstring). ``positions`` (N, >= 2), ``heights`` (N,) above the surface. Returns how many
    candidates became terrain."""
    if candidates.size == 0 or not radius > 0.0:
        return 0
    x0, x1, y0, y1, cell, nx, ny = _candidate_grid(positions, candidates, radius, radius)
    n = heights.size
    cell_of = np.full(n, -1, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        x = positions[i, 0]
        y = positions[i, 1]
        if not (math.isfinite(heights[i]) and x >= x0 and x <= x1 and y >= y0 and y <= y1):
            continue
        c = min(int((x - x0) / cell), nx - 1) * ny + min(int((y - y0) / cell), ny - 1)
        cell_of[i] = c
        start[c + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    order = np.empty(start[nx * ny], np.int64)
    fill = start[:-1].copy()
    for i in range(n):
        c = cell_of[i]
        if c >= 0:
            order[fill[c]] = i
            fill[c] += 1
    r2 = radius * radius
    accepted = 0
    new = np.empty(candidates.size, np.int64)
    # a candidate's decision changes only when terrain was added within its 3 x 3 cells
    dirty = np.ones(nx * ny, np.bool_)
    for _ in range(max_rounds):
        count = 0
        for k in range(candidates.size):
            i = candidates[k]
            if terrain[i] or cell_of[i] < 0:
                continue
            cx = cell_of[i] // ny
            cy = cell_of[i] % ny
            seen = False
            for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                    seen = seen or dirty[gx * ny + gy]
            if not seen:
                continue
            xi = positions[i, 0]
            yi = positions[i, 1]
            m = 0
            sx = sy = sxx = sxy = syy = sh = sxh = syh = 0.0
            east = west = north = south = False
            for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                    c = gx * ny + gy
                    for q in range(start[c], start[c + 1]):
                        j = order[q]
                        if not terrain[j]:
                            continue
                        dx = positions[j, 0] - xi
                        dy = positions[j, 1] - yi
                        if dx * dx + dy * dy > r2:
                            continue
                        hj = heights[j]
                        m += 1
                        sx += dx
                        sy += dy
                        sxx += dx * dx
                        sxy += dx * dy
                        syy += dy * dy
                        sh += hj
                        sxh += dx * hj
                        syh += dy * hj
                        east = east or dx > 0.0
                        west = west or dx < 0.0
                        north = north or dy > 0.0
                        south = south or dy < 0.0
            if m < min_points or not (east and west and north and south):
                continue
            # intercept of the least-squares plane h = a + b dx + c dy (Cramer's rule)
            det = (m * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy)
                   + sy * (sx * sxy - sxx * sy))
            if not abs(det) > 1e-9 * m * max(sxx * syy, 1e-300):
                continue  # the neighbours lie on a line
            num = (sh * (sxx * syy - sxy * sxy) - sx * (sxh * syy - sxy * syh)
                   + sy * (sxh * sxy - sxx * syh))
            if heights[i] - num / det <= threshold:
                new[count] = i
                count += 1
        if count == 0:
            break
        dirty[:] = False
        for k in range(count):
            terrain[new[k]] = True
            dirty[cell_of[new[k]]] = True
        accepted += count
    return accepted


@numba.njit(cache=True)
def count_within(positions, x, y, radius, stop):
    """How many of the points ``positions`` (N, >= 2) lie within ``radius`` (x/y) of (x, y),
    counting up to ``stop`` (the answer is then ``stop``: no need to read on)."""
    r2 = radius * radius
    count = 0
    for i in range(positions.shape[0]):
        dx = positions[i, 0] - x
        dy = positions[i, 1] - y
        if dx * dx + dy * dy <= r2:
            count += 1
            if count >= stop:
                break
    return count


@numba.njit(cache=True)
def points_per_square_metre(positions, selected):
    """The ``selected`` (N,) bool points per occupied 1 m x 1 m cell of their bounding box
    (0 when none is selected): their density where they lie."""
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    count = 0
    for i in range(positions.shape[0]):
        if selected[i] and math.isfinite(positions[i, 0]) and math.isfinite(positions[i, 1]):
            x0 = min(x0, positions[i, 0])
            x1 = max(x1, positions[i, 0])
            y0 = min(y0, positions[i, 1])
            y1 = max(y1, positions[i, 1])
            count += 1
    if count == 0:
        return 0.0
    # at most about 4096 x 4096 cells: a wider cloud's cells grow (the density counts per m2)
    cell = max(1.0, (x1 - x0) / _MAX_CELLS, (y1 - y0) / _MAX_CELLS)
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
    seen = np.zeros(nx * ny, np.bool_)
    occupied = 0
    for i in range(positions.shape[0]):
        if selected[i] and math.isfinite(positions[i, 0]) and math.isfinite(positions[i, 1]):
            c = int((positions[i, 0] - x0) / cell) * ny + int((positions[i, 1] - y0) / cell)
            if not seen[c]:
                seen[c] = True
                occupied += 1
    return count / (occupied * cell * cell)


@numba.njit(cache=True)
def column_spread(positions, heights, high, candidates, cell):
    """For each candidate point, the vertical extent (highest minus lowest z) of the points in
    its x/y column of side ``cell``: the points with a finite height of magnitude below
    ``high`` count (a canopy far above does not). The columns tile the candidates' bounding
    box from its lower corner (:func:`_candidate_grid`: at most about 4096 per axis, a wider
    box gets wider columns). 0 where a column holds one point."""
    m = candidates.shape[0]
    out = np.zeros(m)
    if m == 0:
        return out
    x_min, _, y_min, _, side, nx, ny = _candidate_grid(positions, candidates, 0.0, cell)
    wanted = np.zeros(nx * ny, np.bool_)
    for i in range(m):
        k = candidates[i]
        wanted[int((positions[k, 0] - x_min) / side) * ny
               + int((positions[k, 1] - y_min) / side)] = True
    low = np.full(nx * ny, math.inf)
    top = np.full(nx * ny, -math.inf)
    for k in range(positions.shape[0]):
        h = heights[k]
        if not (abs(h) < high):  # also skips NaN heights (non-finite or outside the surface)
            continue
        fx = (positions[k, 0] - x_min) / side
        fy = (positions[k, 1] - y_min) / side
        if not (fx >= 0.0 and fx < nx and fy >= 0.0 and fy < ny):
            continue
        c = int(fx) * ny + int(fy)
        if wanted[c]:
            z = positions[k, 2]
            low[c] = min(low[c], z)
            top[c] = max(top[c], z)
    for i in range(m):
        k = candidates[i]
        c = int((positions[k, 0] - x_min) / side) * ny + int((positions[k, 1] - y_min) / side)
        out[i] = top[c] - low[c] if top[c] >= low[c] else 0.0
    return out
