"""Slope-limited terrain connectivity on a height grid (a "lowest plausible surface" prior).

Terrain is continuous: between two neighbouring cells its height changes by at most
distance * tan(max terrain slope). Obstacles (vehicles, people, buildings, trunks) stand on it
with near-vertical walls: somewhere along their outline the height jumps by more than that.
So the cells reachable from low seed cells by steps that never climb faster than the slope limit
are terrain candidates, however steep or narrow the terrain feature (a berm, a ditch wall, a
mountain slope), and however wide the obstacle (a building's roof is never reached: its walls
are a jump). Descending is always allowed (terrain can fall away behind a crest).

Cells without data are crossed with the height of the lowest cone through the data,
``E(c) = min_m z(m) + tan(gap slope) * d(c, m)`` (a chamfer distance transform), so occlusion
shadows do not split the terrain, while a shadow cannot raise the carried height faster than
the gap slope.

Arrays are ``[ix, iy]`` like the height grid. NumPy in, NumPy out.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_SQRT2 = 1.4142135623730951


@numba.njit(cache=True, inline="always")
def _least_neighbour(envelope, i, j, straight, diagonal):
    """min over the 8 neighbours n of cell (i, j) of envelope[n] + the step to n (``straight``
    along an axis, ``diagonal`` across): the lowest the slope cone of a neighbour allows."""
    nx, ny = envelope.shape
    best = np.inf
    for di in range(-1, 2):
        a = i + di
        if a < 0 or a >= nx:
            continue
        for dj in range(-1, 2):
            b = j + dj
            if b < 0 or b >= ny or (di == 0 and dj == 0):
                continue
            v = envelope[a, b] + (straight if (di == 0 or dj == 0) else diagonal)
            if v < best:
                best = v
    return best


@numba.njit(cache=True)
def _window_min_axis0(values, radius):
    """Minimum over [i - radius, i + radius] (clipped) along axis 0 of every column: van Herk /
    Gil-Werman block prefix and suffix minima over blocks of w = 2 radius + 1 rows; the window
    [lo, hi] of row i spans the suffix of lo's block and the prefix of hi's, or, within one
    block (a window clipped at a border), starts at the block's start or ends at the array's
    end. Every step processes whole rows (contiguous, vectorised)."""
    nx, ny = values.shape
    w = 2 * radius + 1
    prefix = np.empty((nx, ny))
    suffix = np.empty((nx, ny))
    for start in range(0, nx, w):
        stop = min(start + w, nx)
        for j in range(ny):
            prefix[start, j] = values[start, j]
            suffix[stop - 1, j] = values[stop - 1, j]
        for k in range(start + 1, stop):
            for j in range(ny):
                prefix[k, j] = min(prefix[k - 1, j], values[k, j])
        for k in range(stop - 2, start - 1, -1):
            for j in range(ny):
                suffix[k, j] = min(suffix[k + 1, j], values[k, j])
    out = np.empty((nx, ny))
    for i in range(nx):
        lo = max(i - radius, 0)
        hi = min(i + radius, nx - 1)
        if lo // w != hi // w:
            for j in range(ny):
                out[i, j] = min(suffix[lo, j], prefix[hi, j])
        elif lo % w == 0:
            for j in range(ny):
                out[i, j] = prefix[hi, j]
        else:
            for j in range(ny):
                out[i, j] = suffix[lo, j]
    return out


@numba.njit(cache=True)
def window_min(values, radius):
    """Minimum over the (2 radius + 1)^2 square window around every cell (clipped at the
    borders). Separable (:func:`_window_min_axis0` along x, then along y on the transposed
    array, whose rows are contiguous): O(cells) whatever the radius. A minimum is exact in
    any order, so this is the plain window minimum."""
    along_x = _window_min_axis0(values, radius)
    return np.ascontiguousarray(
        _window_min_axis0(np.ascontiguousarray(along_x.T), radius).T)


@numba.njit(cache=True)
def connected_terrain(height, seeds, cell_size, step_slope, tolerance):
    """Cells reachable from ``seeds`` by 8-neighbour steps that climb at most
    step_slope * distance + tolerance (descending is free). ``height`` must be finite where it
    can be crossed (e.g. the gap envelope of :func:`prior_seeds`); inf cells are never entered.
    Returns a bool mask over all cells (measured and crossed empty cells).

    A breadth-first search over the grid padded with a ring of inf cells (never entered), so
    the 8 neighbours of a cell are its flat index plus fixed offsets without bounds tests. The
    reachable set does not depend on the order cells are visited in."""
    nx, ny = height.shape
    w = ny + 2
    padded = np.full((nx + 2) * w, np.inf)
    accepted = np.zeros((nx + 2) * w, np.bool_)
    queue = np.empty(nx * ny, np.int64)
    tail = 0
    for i in range(nx):
        for j in range(ny):
            q = (i + 1) * w + j + 1
            h = height[i, j]
            padded[q] = h
            if seeds[i, j] and np.isfinite(h):
                accepted[q] = True
                queue[tail] = q
                tail += 1
    straight = step_slope * cell_size + tolerance
    diagonal = step_slope * cell_size * _SQRT2 + tolerance
    head = 0
    while head < tail:
        q = queue[head]
        head += 1
        hs = padded[q] + straight
        hd = padded[q] + diagonal
        for o in (-w - 1, -w + 1, w - 1, w + 1):
            r = q + o
            if not accepted[r] and padded[r] <= hd:
                accepted[r] = True
                queue[tail] = r
                tail += 1
        for o in (-w, -1, 1, w):
            r = q + o
            if not accepted[r] and padded[r] <= hs:
                accepted[r] = True
                queue[tail] = r
                tail += 1
    out = np.empty((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            out[i, j] = accepted[(i + 1) * w + j + 1]
    return out


@numba.njit(cache=True)
def neighbour_rise(height, cell_size, max_slope):
    """Per cell, the terrain's rise across it (m) from the lowest points of its 8-neighbours.

    A plane of gradient (gx, gy) rises cell_size * (|gx| + |gy|) from one corner of a cell to
    the opposite one, whatever its direction to the grid. Each axis gives the rises to its
    two neighbours, equal on a plane: the steeper one along either axis is the larger
    component (the face's, at the foot or the top of a face, where one neighbour is level),
    the gentler one along either axis the smaller (what noise least inflates: along a face,
    its cells' lowest points differ by their noise only). The two, as slopes, are capped
    together at ``max_slope`` in magnitude, then summed over the cell. Where an axis has no
    finite neighbour, a diagonal neighbour's rise (the sum, on a plane) counts when larger,
    at most cell_size * max_slope * sqrt(2). 0 for a cell without finite neighbours, and for
    inf (empty) cells. On a plane along an axis the rise is cell_size times its slope, as
    the steepest slope to a neighbour gave it before; across the axes up to sqrt(2) times
    more, which that missed (docs/algorithm.md, "Bench faces at an angle to the grid"): a
    65-degree face at 20 degrees to the grid's axes spans 1.37 m in a 0.5 m cell, the
    steepest neighbour slope gave 1.0 m, and its cells were no terrain."""
    nx, ny = height.shape
    out = np.zeros((nx, ny))
    for i in range(nx):
        for j in range(ny):
            h = height[i, j]
            if not np.isfinite(h):
                continue
            # per axis: the larger and the smaller rise to its neighbours (-1: none)
            x_max = y_max = -1.0
            x_min = y_min = np.inf
            across = 0.0
            for di in range(-1, 2):
                a = i + di
                if a < 0 or a >= nx:
                    continue
                for dj in range(-1, 2):
                    b = j + dj
                    if b < 0 or b >= ny or (di == 0 and dj == 0):
                        continue
                    hn = height[a, b]
                    if not np.isfinite(hn):
                        continue
                    d = abs(hn - h)
                    if dj == 0:
                        x_max = max(x_max, d)
                        x_min = min(x_min, d)
                    elif di == 0:
                        y_max = max(y_max, d)
                        y_min = min(y_min, d)
                    else:
                        across = max(across, d)
            both = x_max >= 0.0 and y_max >= 0.0
            large = max(x_max, y_max, 0.0) / cell_size
            small = min(x_min, y_min) / cell_size if both else 0.0
            slope = math.sqrt(large * large + small * small)
            if slope > max_slope:
                large *= max_slope / slope
                small *= max_slope / slope
            rise = cell_size * (large + small)
            if not both:
                rise = max(rise, min(across, cell_size * max_slope * _SQRT2))
            out[i, j] = rise
    return out


@numba.njit(cache=True)
def below_compact_neighbours(height, candidate, compact, tolerance, min_neighbours):
    """Candidate cells whose height is at most tolerance above the highest of their compact
    8-neighbours, with at least ``min_neighbours`` such neighbours: cells that lie within the
    terrain their compact neighbours span (a sparse cell on a slope between a crest and a foot)
    and not above it (the step of a wall or a bush face)."""
    nx, ny = height.shape
    out = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            if not candidate[i, j]:
                continue
            top = -np.inf
            n = 0
            for di in range(-1, 2):
                a = i + di
                if a < 0 or a >= nx:
                    continue
                for dj in range(-1, 2):
                    b = j + dj
                    if b < 0 or b >= ny or (di == 0 and dj == 0) or not compact[a, b]:
                        continue
                    n += 1
                    if height[a, b] > top:
                        top = height[a, b]
            out[i, j] = n >= min_neighbours and height[i, j] <= top + tolerance
    return out


@numba.njit(cache=True)
def compact_cells(low, sample, highest, count, connected, cell_size, max_rise_slope,
                  tolerance, min_points, support, use_highest):
    """The compact cells of a connected terrain and the terrain's rise across each cell
    (o3d_terrain.terrain.terrain_prior_mask), in two passes over the grid.

    rise = :func:`neighbour_rise` of ``low`` (capped at ``max_rise_slope``).
    Dense compact: connected, count >= min_points, sample - low <= tolerance + rise / 2 and
    (with ``use_highest``) highest - low <= tolerance + rise. Sparse compact: connected,
    count < min_points, the same extent test, and :func:`below_compact_neighbours` of the
    dense compact cells with ``support``. Returns (compact, rise)."""
    nx, ny = low.shape
    rise = neighbour_rise(low, cell_size, max_rise_slope)
    dense = np.zeros((nx, ny), np.bool_)
    sparse = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            r = rise[i, j]
            if not connected[i, j]:
                continue
            extent_ok = (not use_highest) or highest[i, j] - low[i, j] <= tolerance + r
            if count[i, j] >= min_points:
                dense[i, j] = extent_ok and sample[i, j] - low[i, j] <= tolerance + 0.5 * r
            else:
                sparse[i, j] = extent_ok
    compact = below_compact_neighbours(low, sparse, dense, tolerance, support)
    for i in range(nx):
        for j in range(ny):
            if dense[i, j]:
                compact[i, j] = True
    return compact, rise


@numba.njit(cache=True)
def compact_rise(low, compact, cell_size, max_rise_slope):
    """The terrain's rise across each compact cell measured between terrain cells only:
    :func:`neighbour_rise` from the cell's lowest point to its compact 8-neighbours' (capped
    at ``max_rise_slope``); 0 on cells that are not compact or have no compact neighbour.

    This is the widening of a compact cell above the surface (half of it: detail a control
    grid of about two cells' spacing cannot follow). :func:`compact_cells` measures the rise
    to any measured neighbour, which is right for its own test (a cell next to a wall may
    hold points up to the wall's foot) but not for the widening: a neighbour that is not
    compact (a wall, a bush face, a car side) is no evidence that the terrain climbs. On a
    sparse scan the cell where one ring grazes the base of a bush or a wall is compact (a
    flat line of points) and its steepest neighbour is the face above it, so it got the
    widest threshold of the grid and lifted the surface onto the bush (SemanticKITTI at 16
    scan lines: F1 +0.7 / +0.5 / +0.3 with this rise; docs/algorithm.md, "Sparse scanners").
    On steep terrain the neighbours are compact themselves and the rise is unchanged."""
    # :func:`neighbour_rise` skips empty (inf) cells and neighbours: hide the cells
    # that are not compact
    return neighbour_rise(np.where(compact, low, np.inf), cell_size, max_rise_slope)


@numba.njit(cache=True)
def _cone_sweep(gap, env, measured, g1, g2, s1, s2, forward):
    """One raster pass of :func:`prior_seeds`, in place: each cell takes the least of its
    value and its already swept neighbours' (the previous row's three, the previous cell in
    its row) plus the step (``g1``/``g2`` straight/diagonal for ``gap``, whose measured cells
    stay fixed; ``s1``/``s2`` for ``env``). Forward: rows and cells in increasing order;
    backward: decreasing. Per row, the previous row's terms first (independent of each other),
    then the chain along the row carried in registers: a minimum is exact in any order, so
    this is the plain sweep."""
    nx, ny = gap.shape
    tg = np.empty(ny)
    te = np.empty(ny)
    for step in range(nx):
        i = step if forward else nx - 1 - step
        p = i - 1 if forward else i + 1
        has_prev = p >= 0 and p < nx
        for j in range(ny):
            v = gap[i, j]
            e = env[i, j]
            if has_prev:
                v = min(v, gap[p, j] + g1)
                e = min(e, env[p, j] + s1)
                if j > 0:
                    v = min(v, gap[p, j - 1] + g2)
                    e = min(e, env[p, j - 1] + s2)
                if j < ny - 1:
                    v = min(v, gap[p, j + 1] + g2)
                    e = min(e, env[p, j + 1] + s2)
            tg[j] = v
            te[j] = e
        first = 0 if forward else ny - 1
        if not measured[i, first]:
            gap[i, first] = tg[first]
        env[i, first] = te[first]
        vp = gap[i, first]
        ep = env[i, first]
        for k in range(1, ny):
            j = k if forward else ny - 1 - k
            ep = min(te[j], ep + s1)
            env[i, j] = ep
            if measured[i, j]:
                vp = gap[i, j]
            else:
                vp = min(tg[j], vp + g1)
                gap[i, j] = vp


@numba.njit(cache=True)
def _near_measured(measured):
    """(nx, ny) bool: whether cell (i, j) or one of its 8 neighbours is measured (for a cell
    that is not: whether a neighbour is). A 3 x 3 maximum, separable: along each row, then
    across the rows (two passes of whole rows instead of a 3 x 3 search per cell, which
    finds nothing in most cells of a sparse grid)."""
    nx, ny = measured.shape
    along = np.zeros((nx, ny), np.bool_)  # (i, j - 1 .. j + 1)
    for i in range(nx):
        for j in range(ny):
            along[i, j] = measured[i, j] | ((j > 0) and measured[i, j - 1]) | \
                ((j + 1 < ny) and measured[i, j + 1])
    near = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            near[i, j] = along[i, j] | ((i > 0) and along[i - 1, j]) | \
                ((i + 1 < nx) and along[i + 1, j])
    return near


@numba.njit(cache=True)
def prior_seeds(low, measured, cell_size, gap_slope, slope, tolerance, radius):
    """The inputs of :func:`connected_terrain` for the terrain prior: (crossed, seeds).

    Two lower cone envelopes min_m (low[m] + slope * d(c, m)) (d the 8-neighbour chamfer
    distance), swept together by two raster passes: ``gap`` with the measured cells kept fixed
    and the gap slope (how empty cells are crossed), ``env`` with nothing fixed and ``slope``;
    empty cells next to a measured cell take ``env`` (the points' spacing, not a gap).
    Walls: cells higher than ``tolerance`` above the least neighbour value of ``env``
    (Vosselman's slope-based filter); crossed = gap, inf on walls. Seeds: measured cells, not
    walls, with low <= :func:`window_min` (low, radius). Plain references of both envelopes
    and of the wall test: tests/naive.py (cone_fill, above_slope_cone)."""
    nx, ny = low.shape
    gap = low.copy()  # measured cells fixed, gap slope
    env = low.copy()  # nothing fixed, slope
    g1 = gap_slope * cell_size
    g2 = g1 * _SQRT2
    s1 = slope * cell_size
    s2 = s1 * _SQRT2
    _cone_sweep(gap, env, measured, g1, g2, s1, s2, True)
    _cone_sweep(gap, env, measured, g1, g2, s1, s2, False)
    # an empty cell next to a measured one is no gap in the data but the spacing of the points
    # (a sparse airborne tile's one point per two or three cells): it takes the slope cone,
    # so steep terrain stays connected across it; the gap slope holds from the second cell on
    near = _near_measured(measured)
    for i in range(nx):
        for j in range(ny):
            if measured[i, j] or not near[i, j]:
                continue
            gap[i, j] = env[i, j]
    lowest_around = window_min(low, radius)
    seeds = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            h = low[i, j]
            if not np.isfinite(h):
                continue
            # above the slope cone of a neighbour: a wall's top
            if h > _least_neighbour(env, i, j, s1, s2) + tolerance:
                gap[i, j] = np.inf
            else:
                seeds[i, j] = measured[i, j] and h <= lowest_around[i, j]
    return gap, seeds


@numba.njit(cache=True)
def _difference(low, measured, i, j, di, dj, step):
    """dz per metre of ``low`` at cell (i, j) along (di, dj): central where both neighbours
    are measured, else one-sided; NaN where neither is."""
    nx, ny = low.shape
    a = i - di >= 0 and j - dj >= 0 and measured[i - di, j - dj]
    b = i + di < nx and j + dj < ny and measured[i + di, j + dj]
    if a and b:
        return (low[i + di, j + dj] - low[i - di, j - dj]) / (2.0 * step)
    if b:
        return (low[i + di, j + dj] - low[i, j]) / step
    if a:
        return (low[i, j] - low[i - di, j - dj]) / step
    return np.nan


@numba.njit(cache=True)
def _within_tilt(sx, sy, gx, gy, min_cos):
    """Whether the slope (sx, sy) of a cell lies within the angle of cosine ``min_cos`` of the
    plane of gradient (gx, gy); a NaN component counts as the plane's own."""
    if not math.isfinite(sx):
        sx = gx
    if not math.isfinite(sy):
        sy = gy
    dot = sx * gx + sy * gy + 1.0
    return dot >= min_cos * math.sqrt((sx * sx + sy * sy + 1.0) * (gx * gx + gy * gy + 1.0))


@numba.njit(cache=True)
def ground_plane(low, measured, x_centers, y_centers, sx, sy, radius, min_cos, min_cells,
                 rounds):
    """(gx, gy, c) of a least-squares plane z = gx (x - sx) + gy (y - sy) + c through ``low`` of
    the ``measured`` cells whose centre lies within ``radius`` of (sx, sy); ``low`` must be
    finite on every measured cell.

    A cell whose own slope (:func:`_difference` with its neighbours along x and y) lies
    further from the plane than the angle of cosine ``min_cos`` is left out: a face or an
    object's side, not the ground (the first fit measures it from level, each next one from
    the plane before). ``rounds`` fits in all, each after the first also without the cells
    more than twice the robust spread (1.4826 median absolute residual, plus 0.05) above the
    plane before (objects). (0, 0, NaN) when fewer than ``min_cells`` cells lie there or the
    cells lie on one line. The cell block searched is the radius' bounding box, not the whole
    grid."""
    c = x_centers[1] - x_centers[0] if x_centers.shape[0] > 1 else 1.0
    i0 = max(0, int(math.floor((sx - radius - x_centers[0]) / c)))
    i1 = min(x_centers.shape[0], int(math.ceil((sx + radius - x_centers[0]) / c)) + 1)
    cy = y_centers[1] - y_centers[0] if y_centers.shape[0] > 1 else 1.0
    j0 = max(0, int(math.floor((sy - radius - y_centers[0]) / cy)))
    j1 = min(y_centers.shape[0], int(math.ceil((sy + radius - y_centers[0]) / cy)) + 1)
    size = max(0, i1 - i0) * max(0, j1 - j0)
    x = np.empty(size)
    y = np.empty(size)
    z = np.empty(size)
    slope = np.empty((size, 2))  # each cell's own (dz/dx, dz/dy) from its neighbours
    n = 0
    r2 = radius * radius
    for i in range(i0, i1):
        dx = x_centers[i] - sx
        for j in range(j0, j1):
            dy = y_centers[j] - sy
            if measured[i, j] and dx * dx + dy * dy <= r2:
                x[n] = dx
                y[n] = dy
                z[n] = low[i, j]
                slope[n, 0] = _difference(low, measured, i, j, 1, 0, c)
                slope[n, 1] = _difference(low, measured, i, j, 0, 1, cy)
                n += 1
    if n < min_cells:
        return 0.0, 0.0, np.nan
    keep = np.empty(n, np.bool_)
    kept = 0
    for k in range(n):
        keep[k] = _within_tilt(slope[k, 0], slope[k, 1], 0.0, 0.0, min_cos)
        kept += keep[k]
    if kept < min_cells:
        return 0.0, 0.0, np.nan
    residual = np.empty(n)
    gx = 0.0
    gy = 0.0
    height = np.nan
    for _ in range(rounds):
        sxx = sxy = sx1 = syy = sy1 = s1 = sxz = syz = sz = 0.0
        for k in range(n):
            if keep[k]:
                sxx += x[k] * x[k]
                sxy += x[k] * y[k]
                sx1 += x[k]
                syy += y[k] * y[k]
                sy1 += y[k]
                s1 += 1.0
                sxz += x[k] * z[k]
                syz += y[k] * z[k]
                sz += z[k]
        a = np.array([[sxx, sxy, sx1], [sxy, syy, sy1], [sx1, sy1, s1]])
        if abs(np.linalg.det(a)) < 1e-9 * max(sxx * syy * s1, 1e-300):
            return 0.0, 0.0, np.nan
        g = np.linalg.solve(a, np.array([sxz, syz, sz]))
        gx = g[0]
        gy = g[1]
        height = g[2]
        for k in range(n):
            residual[k] = z[k] - (gx * x[k] + gy * y[k] + g[2])
        spread = 1.4826 * np.median(np.abs(residual[keep])) + 0.05
        kept = 0
        for k in range(n):
            keep[k] = (residual[k] < 2.0 * spread
                       and _within_tilt(slope[k, 0], slope[k, 1], gx, gy, min_cos))
            kept += keep[k]
        if kept < min_cells:
            break
    return gx, gy, height
