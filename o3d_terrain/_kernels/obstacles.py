"""Kernels for obstacle clustering and the traversability cost map (NumPy in, NumPy out)."""

from __future__ import annotations

import math

import numba
import numpy as np

from . import bspline as _bs


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


@numba.njit(cache=True, inline="always")
def _keep_extremes(best, value, c, k, a, b):
    """Point k at (a, b) replaces the candidates of cell slot c that it beats along x, y,
    x + y and x - y (both signs); ties keep the earlier point."""
    keys = (a, -a, b, -b, a + b, -a - b, a - b, b - a)
    for d in range(8):
        if best[c, d] < 0 or keys[d] > value[c, d]:
            best[c, d] = k
            value[c, d] = keys[d]


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
        _keep_extremes(best, value, c, k, x[k], y[k])
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


@numba.njit(cache=True)
def relabel_points(component, new_id, members, cluster_ids, n_groups):
    """The kept clusters' ids for the obstacle points, in one pass each: ``point_ids`` (M,),
    ``new_id[component[k]]`` or -1 (``component`` -1 = none); ``cluster_ids[members[k]]``
    set to it (in place); and the members grouped by id in point order, ``indices`` with
    ``starts`` (n_groups + 1,), as :func:`group_by` on the ids followed by ``members[order]``.
    """
    m = component.shape[0]
    point_ids = np.empty(m, np.int64)
    starts = np.zeros(n_groups + 1, np.int64)
    for k in range(m):
        c = component[k]
        g = new_id[c] if c >= 0 else -1
        point_ids[k] = g
        if g >= 0:
            cluster_ids[members[k]] = g
            starts[g + 1] += 1
    for g in range(n_groups):
        starts[g + 1] += starts[g]
    fill = starts[:-1].copy()
    indices = np.empty(starts[n_groups], np.int64)
    for k in range(m):
        g = point_ids[k]
        if g >= 0:
            indices[fill[g]] = members[k]
            fill[g] += 1
    return point_ids, indices, starts


@numba.njit(cache=True)
def occupancy_mask(ix, iy, nx, ny):
    """(nx, ny) uint8 mask, 1 at every cell (ix[k], iy[k]) (all inside the grid)."""
    mask = np.zeros((nx, ny), np.uint8)
    for k in range(ix.shape[0]):
        mask[ix[k], iy[k]] = 1
    return mask


@numba.njit(cache=True)
def labels_at(labels, ix, iy, offset):
    """labels[ix[k], iy[k]] + offset for every k, as int64."""
    out = np.empty(ix.shape[0], np.int64)
    for k in range(ix.shape[0]):
        out[k] = labels[ix[k], iy[k]] + offset
    return out


@numba.njit(cache=True)
def fill_boxes(centers, sizes, yaws_deg, x_min, y_min, cell_size, occupied):
    """Mark the cells whose centre lies in an oriented box grown by half a cell.

    Box b: centre ``centers[b]``, (length, width) ``sizes[b]``, yaw ``yaws_deg[b]``. Cells are
    searched over the box's axis-aligned bounds (its corners), as in the cost-map docs.
    """
    nx = occupied.shape[0]
    ny = occupied.shape[1]
    for b in range(centers.shape[0]):
        a = math.radians(yaws_deg[b])
        ca = math.cos(a)
        sa = math.sin(a)
        cx = centers[b, 0]
        cy = centers[b, 1]
        ux = ca * sizes[b, 0] / 2
        uy = sa * sizes[b, 0] / 2
        vx = -sa * sizes[b, 1] / 2
        vy = ca * sizes[b, 1] / 2
        lo_x = min(min(cx + ux + vx, cx - ux + vx), min(cx - ux - vx, cx + ux - vx))
        hi_x = max(max(cx + ux + vx, cx - ux + vx), max(cx - ux - vx, cx + ux - vx))
        lo_y = min(min(cy + uy + vy, cy - uy + vy), min(cy - uy - vy, cy + uy - vy))
        hi_y = max(max(cy + uy + vy, cy - uy + vy), max(cy - uy - vy, cy + uy - vy))
        i0 = max(int(math.floor((lo_x - x_min) / cell_size)), 0)
        i1 = min(int(math.ceil((hi_x - x_min) / cell_size)) + 1, nx)
        j0 = max(int(math.floor((lo_y - y_min) / cell_size)), 0)
        j1 = min(int(math.ceil((hi_y - y_min) / cell_size)) + 1, ny)
        half_u = sizes[b, 0] / 2 + cell_size / 2
        half_v = sizes[b, 1] / 2 + cell_size / 2
        for i in range(i0, i1):
            dx = x_min + (i + 0.5) * cell_size - cx
            for j in range(j0, j1):
                dy = y_min + (j + 0.5) * cell_size - cy
                u = dx * ca + dy * sa
                v = -dx * sa + dy * ca
                if abs(u) <= half_u and abs(v) <= half_v:
                    occupied[i, j] = True


@numba.njit(cache=True)
def observed_cells(positions, labels, heights, point_obstacle, tall, x_min, y_min, cell_size,
                   nx, ny, skip_a, skip_b, vehicle_height, rough_cap, occupied):
    """The points of a cloud put into the cost map's cells, in one pass.

    A point's cell is (floor((x - x_min) / cell_size), floor((y - y_min) / cell_size)), as
    :func:`bin_points`. Marks ``occupied`` at the cells of the points of tall obstacles
    (``point_obstacle[k] >= 0`` and ``tall[point_obstacle[k]]``). The points that count for
    step and roughness (label neither ``skip_a`` nor ``skip_b``, height finite and <=
    ``vehicle_height``) give the cells holding points and their moments, stored compactly:
    ``slot`` (nx, ny) int32, the index of the cell's entry or -1, and per entry the point
    count, the highest height, and the count and sum of squares of the heights <=
    ``rough_cap`` (the roughness moments), and its cell (``cell_i``, ``cell_j``). Entries
    are numbered in the order of their first point, and sums run over the points in input
    order. One int32 grid instead of four whole-grid moment arrays (a few percent of the
    cells hold points).
    """
    slot = np.full((nx, ny), -1, np.int32)
    n = positions.shape[0]
    count = np.empty(n, np.int32)
    highest = np.empty(n)
    rough_n = np.empty(n, np.int32)
    rough_sum2 = np.empty(n)
    cell_i = np.empty(n, np.int32)
    cell_j = np.empty(n, np.int32)
    m = 0
    for k in range(n):
        fx = (positions[k, 0] - x_min) / cell_size
        fy = (positions[k, 1] - y_min) / cell_size
        if not (math.isfinite(fx) and math.isfinite(fy)):
            continue
        i = int(math.floor(fx))
        j = int(math.floor(fy))
        if i < 0 or j < 0 or i >= nx or j >= ny:
            continue
        g = point_obstacle[k]
        if g >= 0 and tall[g]:
            occupied[i, j] = True
        if labels[k] == skip_a or labels[k] == skip_b:
            continue
        v = heights[k]
        if not (math.isfinite(v) and v <= vehicle_height):
            continue
        e = slot[i, j]
        if e < 0:
            e = m
            slot[i, j] = m
            cell_i[e] = i
            cell_j[e] = j
            m += 1
            count[e] = 0
            highest[e] = -np.inf
            rough_n[e] = 0
            rough_sum2[e] = 0.0
        count[e] += 1
        highest[e] = max(highest[e], v)  # branch-free updates: the comparisons are
        low = v <= rough_cap  # unpredictable from point to point
        rough_n[e] += low
        rough_sum2[e] += v * v if low else 0.0  # + 0.0 leaves the non-negative sum exact
    return slot, count[:m], highest[:m], rough_n[:m], rough_sum2[:m], cell_i[:m], cell_j[:m]


@numba.njit(cache=True, inline="always")
def _column_sums(rq, weights, by, dby, a, j, sy, p):
    """The y contraction of control row ``a`` at grid column j (span ``sy``, basis values
    ``by[j]`` and derivatives ``dby[j]``): sums over b of N_b R Q, N_b R, N'_b R Q, N'_b R
    (``rq`` = R Q)."""
    va = 0.0
    vd = 0.0
    vay = 0.0
    vdy = 0.0
    for k in range(p + 1):
        b = sy - p + k
        va += by[j, k] * rq[a, b]
        vd += by[j, k] * weights[a, b]
        vay += dby[j, k] * rq[a, b]
        vdy += dby[j, k] * weights[a, b]
    return va, vd, vay, vdy


@numba.njit(cache=True, parallel=True, error_model="numpy")
def gradient_norm_grid(x, y, knots_x, knots_y, degree, control, weights, tol):
    """|grad S| of the rational surface at every node (x[i], y[j]) (local coordinates), float64;
    NaN where x[i] or y[j] lies outside the knot range widened by ``tol`` (inside it,
    clamped to the range), as :func:`~o3d_terrain._kernels.bspline.rational_surface_grid`.

    The tensor product is contracted along y once for all columns (4 tables (n0, len(y)):
    sums over b of N_b(y_j) R Q, N_b R and the same with N'_b), then each grid row is
    degree + 1 scaled additions of table rows per sum, contiguous along y, and the quotient
    rule S_x = (A_x - S D_x) / D, S_y = (A_y - S D_y) / D. Rows are split over threads.
    """
    nx = x.shape[0]
    ny = y.shape[0]
    p = degree
    n0 = control.shape[0]
    n1 = control.shape[1]
    span_y, by, dby = _bs.basis_first_derivative_table(y, n1, p, knots_y, tol)
    rq = weights * control
    t_a = np.empty((n0, ny))
    t_d = np.empty((n0, ny))
    t_ay = np.empty((n0, ny))
    t_dy = np.empty((n0, ny))
    for a in numba.prange(n0):
        for j in range(ny):
            sy = span_y[j]
            if sy < 0:  # NaN propagates to every node of the column
                t_a[a, j] = np.nan
                t_d[a, j] = np.nan
                t_ay[a, j] = np.nan
                t_dy[a, j] = np.nan
                continue
            t_a[a, j], t_d[a, j], t_ay[a, j], t_dy[a, j] = _column_sums(rq, weights, by, dby,
                                                                         a, j, sy, p)
    out = np.empty((nx, ny))
    for i in numba.prange(nx):
        bx = np.empty(p + 1)
        dbx = np.empty(p + 1)
        lft = np.empty(p + 1)
        rgt = np.empty(p + 1)
        sx = _bs.clamped_basis_first_derivative(x[i], n0, p, knots_x, tol, bx, dbx, lft, rgt)
        if sx < 0:
            for j in range(ny):
                out[i, j] = np.nan
            continue
        s_a = np.zeros(ny)
        s_d = np.zeros(ny)
        s_ax = np.zeros(ny)
        s_dx = np.zeros(ny)
        s_ay = np.zeros(ny)
        s_dy = np.zeros(ny)
        for k in range(p + 1):
            a = sx - p + k
            u = bx[k]
            du = dbx[k]
            for j in range(ny):
                s_a[j] += u * t_a[a, j]
                s_d[j] += u * t_d[a, j]
                s_ax[j] += du * t_a[a, j]
                s_dx[j] += du * t_d[a, j]
                s_ay[j] += u * t_ay[a, j]
                s_dy[j] += u * t_dy[a, j]
        for j in range(ny):
            _, gx, gy = _bs.quotient_rule(s_a[j], s_d[j], s_ax[j], s_dx[j], s_ay[j], s_dy[j])
            out[i, j] = math.sqrt(gx * gx + gy * gy)
    return out


@numba.njit(cache=True, error_model="numpy")
def slope_at_cells(x, y, cell_i, cell_j, knots_x, knots_y, degree, control, weights, tol):
    """atan |grad S| (radians) of the rational surface at the nodes (x[cell_i[e]],
    y[cell_j[e]]) (local coordinates) for every entry e (:func:`observed_cells`); NaN outside
    the knot range widened by ``tol``.

    The same sums in the same order as :func:`gradient_norm_grid` (the y contraction tabulated
    once for the columns asked for, then degree + 1 scaled terms per node, the x basis once
    per row), so |grad S| is identical where both compute it; the work is proportional to the
    nodes asked for, not the grid.
    """
    nx = x.shape[0]
    ny = y.shape[0]
    p = degree
    n0 = control.shape[0]
    n1 = control.shape[1]
    m = cell_i.shape[0]
    out = np.full(m, np.nan)
    columns = np.zeros(ny, np.bool_)
    row_start = np.zeros(nx + 1, np.int64)  # the entries grouped by row (counting sort)
    for e in range(m):
        columns[cell_j[e]] = True
        row_start[cell_i[e] + 1] += 1
    for i in range(nx):
        row_start[i + 1] += row_start[i]
    fill = row_start[:-1].copy()
    by_row = np.empty(m, np.int64)
    for e in range(m):
        by_row[fill[cell_i[e]]] = e
        fill[cell_i[e]] += 1
    span_y, by, dby = _bs.basis_first_derivative_table(y, n1, p, knots_y, tol)
    rq = weights * control
    t_a = np.empty((n0, ny))
    t_d = np.empty((n0, ny))
    t_ay = np.empty((n0, ny))
    t_dy = np.empty((n0, ny))
    for a in range(n0):
        for j in range(ny):
            sy = span_y[j]
            if not columns[j] or sy < 0:
                continue
            t_a[a, j], t_d[a, j], t_ay[a, j], t_dy[a, j] = _column_sums(rq, weights, by, dby,
                                                                         a, j, sy, p)
    bx = np.empty(p + 1)
    dbx = np.empty(p + 1)
    lft = np.empty(p + 1)
    rgt = np.empty(p + 1)
    for i in range(nx):
        if row_start[i] == row_start[i + 1]:
            continue
        sx = _bs.clamped_basis_first_derivative(x[i], n0, p, knots_x, tol, bx, dbx, lft, rgt)
        if sx < 0:
            continue
        for t in range(row_start[i], row_start[i + 1]):
            e = by_row[t]
            j = cell_j[e]
            if span_y[j] < 0:
                continue
            s_a = 0.0
            s_d = 0.0
            s_ax = 0.0
            s_dx = 0.0
            s_ay = 0.0
            s_dy = 0.0
            for k in range(p + 1):
                a = sx - p + k
                u = bx[k]
                du = dbx[k]
                s_a += u * t_a[a, j]
                s_d += u * t_d[a, j]
                s_ax += du * t_a[a, j]
                s_dx += du * t_d[a, j]
                s_ay += u * t_ay[a, j]
                s_dy += u * t_dy[a, j]
            _, gx, gy = _bs.quotient_rule(s_a, s_d, s_ax, s_dx, s_ay, s_dy)
            out[e] = math.atan(math.sqrt(gx * gx + gy * gy))
    return out


@numba.njit(cache=True, error_model="numpy")
def cost_cells(cell_i, cell_j, entry_slope, count, highest, rough_n, rough_sum2, occupied,
               max_slope_deg, lethal_step, max_roughness, w_slope, w_step, w_rough,
               unknown_cost, free_state, unknown_state, lethal_state, slope_of_unknown,
               slope_grid):
    """The cost formula of docs/obstacles.md on every cell, before inflation.

    The entries ``cell_i``, ``cell_j``, ``count``, ``highest``, ``rough_n``, ``rough_sum2``
    are the cells holding points (:func:`observed_cells`); ``entry_slope`` their atan |grad S|
    in radians (:func:`slope_at_cells`; NaN outside the surface); step = max(0, highest),
    roughness = RMS. Returns float32 ``slope``, ``step``, ``rough``, ``cost`` (NaN where
    undefined), bool ``lethal`` (slope over the limit, step over the lethal step, or occupied:
    ``occupied`` itself, updated in place) and uint8 ``state``.

    A cell without a point costs ``unknown_cost``, has NaN slope and is ``unknown_state``, or
    ``lethal_state`` at cost 1 when occupied; with ``slope_of_unknown`` (a slope-only map) it
    takes its slope from ``slope_grid`` (radians, the whole grid), costs max(slope term,
    ``unknown_cost``) and is lethal over the slope limit too. A cell holding points is
    ``free_state``, or ``lethal_state`` at cost 1 when lethal. The cost of the cells that
    are not lethal is capped at float32(0.99), as :func:`inflate` leaves it away from lethal
    cells, so inflation only visits the cells near lethal ones. Every cell is first filled as
    a cell without a point (one pass over the grid with no per-cell lookup of the entry), then
    the entries are written over it (a few percent of the cells: 14k of 253k on KITTI 000000;
    0.68 -> 0.29 ms, minima, against one pass testing every cell's slot); decisions are taken
    in float64. Serial: a fork-join over threads gains ~0.3 ms
    on an idle second core and loses tens of milliseconds when the cores are shared (threads
    waiting for one another), see docs/performance.md.
    """
    nx = occupied.shape[0]
    ny = occupied.shape[1]
    slope = np.empty((nx, ny), np.float32)
    step = np.empty((nx, ny), np.float32)
    rough = np.empty((nx, ny), np.float32)
    cost = np.empty((nx, ny), np.float32)
    state = np.empty((nx, ny), np.uint8)
    total = w_slope + w_step + w_rough
    to_deg = 180.0 / math.pi
    cap = np.float32(0.99)
    unknown32 = np.float32(min(unknown_cost, 0.99))
    one = np.float32(1.0)
    nan32 = np.float32(np.nan)
    lethal_u8 = np.uint8(lethal_state)
    unknown_u8 = np.uint8(unknown_state)
    if slope_of_unknown:
        for i in range(nx):
            for j in range(ny):
                sl = slope_grid[i, j] * to_deg
                if math.isnan(sl):
                    slope_term = 1.0
                    is_lethal = False
                else:
                    slope_term = (sl / max_slope_deg) ** 2
                    is_lethal = sl > max_slope_deg
                slope[i, j] = sl
                step[i, j] = nan32
                rough[i, j] = nan32
                c = np.float32(max(w_slope * slope_term / total, unknown_cost))
                occ = occupied[i, j] or is_lethal
                occupied[i, j] = occ
                cost[i, j] = one if occ else min(c, cap)
                state[i, j] = lethal_u8 if occ else unknown_u8
    else:
        for i in range(nx):
            for j in range(ny):
                occ = occupied[i, j]
                slope[i, j] = nan32
                step[i, j] = nan32
                rough[i, j] = nan32
                cost[i, j] = one if occ else unknown32
                state[i, j] = lethal_u8 if occ else unknown_u8
    for e in range(cell_i.shape[0]):
        i = cell_i[e]
        j = cell_j[e]
        sl = entry_slope[e] * to_deg
        if math.isnan(sl):
            slope_term = 1.0
            is_lethal = False
        else:
            slope_term = (sl / max_slope_deg) ** 2
            is_lethal = sl > max_slope_deg
        slope[i, j] = sl
        st = max(highest[e], 0.0)
        step[i, j] = st
        step_term = (st / lethal_step) ** 2
        is_lethal = is_lethal or st > lethal_step
        if rough_n[e] > 0:
            ro = math.sqrt(rough_sum2[e] / rough_n[e])
            rough[i, j] = ro
            rough_term = min(ro / max_roughness, 1.0) ** 2
        else:
            rough[i, j] = np.nan
            rough_term = 0.0
        if is_lethal or occupied[i, j]:
            occupied[i, j] = True
            state[i, j] = lethal_state
            cost[i, j] = 1.0
        else:
            state[i, j] = free_state
            c = np.float32((w_slope * slope_term + w_step * step_term + w_rough * rough_term)
                           / total)
            cost[i, j] = min(c, cap)
    return slope, step, rough, cost, occupied, state


@numba.njit(cache=True)
def inflate(cost, state, lethal, cell_size, inscribed_radius, circumscribed_radius,
            inflation_scale, inscribed_state):
    """Inflation by the footprint, in place, after :func:`cost_cells` (which set the lethal
    cells LETHAL at cost 1 and capped the other costs at 0.99): cells within
    ``inscribed_radius`` (m) of a lethal cell become INSCRIBED at cost 1, out to
    ``circumscribed_radius`` the cost is at least 0.99 exp(-(d - r_in) / inflation_scale).

    d is the exact Euclidean distance between cell centres, as float32(sqrt(d²)) *
    float32(cell_size) (OpenCV's exact ``distanceTransform`` scaled by the cell size gives the
    same to within one float32 unit), computed only out to ``reach`` = the circumscribed
    radius plus one cell, by the separable exact distance transform (Meijster et al. 2000;
    Felzenszwalb & Huttenlocher 2012) cut off at ``reach``: per row, the squared distance
    along the row to its nearest lethal cell, over the row's window (its first lethal column
    - ``reach`` to its last + ``reach``; beyond it the distance exceeds ``reach``); then d² is
    the least a² + that over the rows at most ``reach`` away (|a| <= reach) with a lethal
    cell. A lethal cell within ``reach`` of a cell lies within ``reach`` rows and columns of
    it, so d² is exact up to ``reach``²; larger values are only upper bounds and count as
    beyond the circumscribed radius. Row i visits only the union of the windows of the rows
    within reach (the other cells are farther than ``reach`` from every lethal cell and keep
    their capped cost), one contiguous run of SIMD minima per row within reach: on KITTI
    000000 117k of the 253k cells, 2.9M minima instead of 6.3M over whole rows (per-row
    windows, 1.9M minima in 15.6k short runs, were slower: 0.9 against 0.76 ms). d² takes at
    most ``reach``² + 1 values, so the least cost of each is tabulated once. Serial, as
    :func:`cost_cells`.
    """
    nx = cost.shape[0]
    ny = cost.shape[1]
    reach = int(math.ceil(circumscribed_radius / cell_size)) + 1
    far = reach * reach + 1
    # the least cost for each d² (-1 = inscribed, 0 = beyond the circumscribed radius)
    least = np.zeros(far + 1)
    step = np.float32(cell_size)
    for k in range(far):
        d = float(np.float32(np.float32(math.sqrt(k)) * step))
        if d <= inscribed_radius:
            least[k] = -1.0
        elif d <= circumscribed_radius:
            least[k] = 0.99 * math.exp(-(d - inscribed_radius) / inflation_scale)
    # per row with a lethal cell: the window [w0, w1) of columns within reach of its lethal
    # cells (empty: none), over it the squared distance along the row to the nearest lethal
    # cell, ``far`` elsewhere
    w0 = np.zeros(nx, np.int64)
    w1 = np.zeros(nx, np.int64)
    along = np.empty((nx, ny), np.int32)
    for i in range(nx):
        lo = -1
        for j in range(ny):
            if lethal[i, j]:
                lo = j
                break
        if lo < 0:
            continue
        hi = lo
        for j in range(ny - 1, lo, -1):
            if lethal[i, j]:
                hi = j
                break
        a0 = max(lo - reach, 0)
        a1 = min(hi + reach + 1, ny)
        w0[i] = a0
        w1[i] = a1
        along_row = along[i]
        along_row[:] = far  # the row is read over the other rows' windows too
        last = -(reach + 1)
        for j in range(a0, a1):
            if lethal[i, j]:
                last = j
            along[i, j] = j - last
        last = ny + reach + 1
        for j in range(a1 - 1, a0 - 1, -1):
            if lethal[i, j]:
                last = j
            b = min(along[i, j], last - j)
            along[i, j] = b * b if b <= reach else far
    d2 = np.empty(ny, np.int32)
    for i in range(nx):
        r0 = max(i - reach, 0)
        r1 = min(i + reach, nx - 1)
        lo = ny
        hi = 0
        for r in range(r0, r1 + 1):
            if w1[r] > w0[r]:
                lo = min(lo, w0[r])
                hi = max(hi, w1[r])
        if lo >= hi:  # no lethal cell within reach: costs already capped
            continue
        # views indexed from 0: the loops vectorise (no negative-index wraparound to check)
        window = d2[lo:hi]
        window[:] = far
        for r in range(r0, r1 + 1):
            if w1[r] > w0[r]:
                a2 = np.int32((r - i) * (r - i))
                row = along[r, lo:hi]
                for t in range(window.shape[0]):
                    window[t] = min(window[t], a2 + row[t])
        lethal_row = lethal[i, lo:hi]
        cost_row = cost[i, lo:hi]
        state_row = state[i, lo:hi]
        for t in range(window.shape[0]):
            if lethal_row[t]:
                continue
            floor = least[min(window[t], far)]
            if floor < 0:
                state_row[t] = inscribed_state
                cost_row[t] = 1.0
            elif floor > 0:
                cost_row[t] = min(max(float(cost_row[t]), floor), 0.99)


@numba.njit(cache=True)
def grid_box_candidates(cluster, ix, iy, cell_labels, x, y, n_clusters):
    """The points extreme along x, y, x + y and x - y (both signs) in their cell
    (:func:`hull_candidates`), over the points with ``cluster >= 0``, for clusterings where
    every cell belongs to one cluster (the grid clustering).

    The connected-components label image (``cell_labels`` (nx, ny) int32, > 0 at occupied
    cells) serves as the per-cell slot table: it is overwritten (the cells of kept clusters
    get -1 - slot) instead of filling a fresh whole-grid table. Slots are numbered in point
    order and ties go to the first point. Returns the candidates' x, y grouped by cluster, in
    point order within a cluster, and ``starts`` (n_clusters + 1,).

    Each point's slot is kept from the numbering pass (an int32 per point), so the extremes
    pass reads it instead of the label image again, and the candidates are counted per cluster
    as they are marked (one pass over the points fewer): 1.06-1.23 -> 0.89-1.06 ms on KITTI
    000000 (52k points, medians).
    """
    m = cluster.shape[0]
    n_slots = 0
    slot = np.empty(m, np.int32)
    for k in range(m):
        if cluster[k] < 0:
            slot[k] = -1
            continue
        v = cell_labels[ix[k], iy[k]]
        if v > 0:
            v = -1 - n_slots
            cell_labels[ix[k], iy[k]] = v
            n_slots += 1
        slot[k] = -1 - v
    best = np.full((n_slots, 8), -1, np.int64)
    value = np.empty((n_slots, 8))
    for k in range(m):
        c = slot[k]
        if c < 0:
            continue
        _keep_extremes(best, value, c, k, x[k], y[k])
    mark = np.zeros(m, np.bool_)
    starts = np.zeros(n_clusters + 1, np.int64)
    for c in range(n_slots):
        for d in range(8):
            k = best[c, d]
            if not mark[k]:
                mark[k] = True
                starts[cluster[k] + 1] += 1
    for g in range(n_clusters):
        starts[g + 1] += starts[g]
    fill = starts[:-1].copy()
    cx = np.empty(starts[n_clusters])
    cy = np.empty(starts[n_clusters])
    for k in range(m):
        if mark[k]:
            g = cluster[k]
            cx[fill[g]] = x[k]
            cy[fill[g]] = y[k]
            fill[g] += 1
    return cx, cy, starts


@numba.njit(cache=True)
def obstacle_points(labels, positions, heights, obstacle_label, max_height, cell_size):
    """The obstacle points of a cloud and their clustering cells: one pass over the cloud,
    one over the selected points.

    Selects the points labelled ``obstacle_label`` with finite x, y, z and height, and height
    <= ``max_height`` (use inf for no limit). Returns ``members`` (their indices, increasing),
    ``points`` (M, 3) copies, their heights ``member_heights`` (M,) (gathered here instead of a
    NumPy fancy index afterwards: ~0.07 ms for 52k points), and the cells ``ix``, ``iy`` of
    side ``cell_size`` counted from
    the lowest x and y of the selected points (floor((x - x_low) / cell_size)). The first
    pass writes the indices and copies into arrays sized for the whole cloud (only the first
    M rows are touched) and returns views of them, so the cloud is read once.
    """
    n = labels.shape[0]
    members = np.empty(n, np.int64)
    points = np.empty((n, 3))
    member_heights = np.empty(n)
    m = 0
    x_low = np.inf
    y_low = np.inf
    for k in range(n):
        if labels[k] != obstacle_label:
            continue
        x = positions[k, 0]
        y = positions[k, 1]
        z = positions[k, 2]
        h = heights[k]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
                and math.isfinite(h)) or h > max_height:
            continue
        members[m] = k
        points[m, 0] = x
        points[m, 1] = y
        points[m, 2] = z
        member_heights[m] = h
        m += 1
        if x < x_low:
            x_low = x
        if y < y_low:
            y_low = y
    ix = np.empty(m, np.int64)
    iy = np.empty(m, np.int64)
    for t in range(m):
        ix[t] = int(math.floor((points[t, 0] - x_low) / cell_size))
        iy[t] = int(math.floor((points[t, 1] - y_low) / cell_size))
    return members[:m], points[:m], member_heights[:m], ix, iy


@numba.njit(cache=True)
def _convex_hull(px, py, hull):
    """Andrew's monotone chain (Andrew 1979): the convex hull of the points (px, py) into
    ``hull`` (indices, counter-clockwise, no collinear vertices); returns the vertex count
    (1 when all points coincide, 2 when they are collinear)."""
    n = px.shape[0]
    order = np.argsort(px, kind="mergesort")
    start = 0  # equal x: sort the run by y (runs are short: insertion sort)
    while start < n:
        stop = start + 1
        while stop < n and px[order[stop]] == px[order[start]]:
            stop += 1
        for a in range(start + 1, stop):
            v = order[a]
            b = a - 1
            while b >= start and py[order[b]] > py[v]:
                order[b + 1] = order[b]
                b -= 1
            order[b + 1] = v
        start = stop
    m = 0
    for t in range(n):  # lower chain
        k = order[t]
        while m >= 2 and ((px[hull[m - 1]] - px[hull[m - 2]]) * (py[k] - py[hull[m - 2]])
                          - (py[hull[m - 1]] - py[hull[m - 2]]) * (px[k] - px[hull[m - 2]])) <= 0:
            m -= 1
        hull[m] = k
        m += 1
    lower = m + 1
    for t in range(n - 2, -1, -1):  # upper chain
        k = order[t]
        while m >= lower and ((px[hull[m - 1]] - px[hull[m - 2]]) * (py[k] - py[hull[m - 2]])
                              - (py[hull[m - 1]] - py[hull[m - 2]])
                              * (px[k] - px[hull[m - 2]])) <= 0:
            m -= 1
        hull[m] = k
        m += 1
    m -= 1  # the last point repeats the first
    if m < 1:
        m = 1
    if m == 2 and px[hull[0]] == px[hull[1]] and py[hull[0]] == py[hull[1]]:
        m = 1
    return m


@numba.njit(cache=True)
def _outside_octagon(x, y, s0, s1, ox, oy, bx, by):
    """Akl & Toussaint (1978) pre-filter: the points of ``x[s0:s1]``, ``y[s0:s1]`` (shifted by
    -ox, -oy) not strictly inside the polygon of the extreme points along x, x + y, y, y - x,
    -x, -x - y, -y, x - y, written to ``bx``, ``by``; returns their count. Hull vertices are
    never strictly inside it, so the hull of the kept points is the hull of all."""
    best = np.empty(8, np.int64)
    value = np.full(8, -np.inf)
    for k in range(s0, s1):
        a = x[k] - ox
        b = y[k] - oy
        keys = (a, a + b, b, b - a, -a, -a - b, -b, a - b)
        for d in range(8):
            if keys[d] > value[d]:
                value[d] = keys[d]
                best[d] = k
    # the octagon's vertices in counter-clockwise order (repeats allowed)
    qx = np.empty(8)
    qy = np.empty(8)
    for d in range(8):
        qx[d] = x[best[d]] - ox
        qy[d] = y[best[d]] - oy
    n = 0
    for k in range(s0, s1):
        a = x[k] - ox
        b = y[k] - oy
        inside = value[0] + value[4] > 0.0  # an octagon of one point holds nothing
        for d in range(8):
            e = (d + 1) % 8
            ex = qx[e] - qx[d]
            ey = qy[e] - qy[d]
            if ex == 0.0 and ey == 0.0:
                continue
            if ex * (b - qy[d]) - ey * (a - qx[d]) <= 0.0:
                inside = False
                break
        if not inside:
            bx[n] = a
            by[n] = b
            n += 1
    return n


@numba.njit(cache=True)
def min_area_boxes(x, y, starts):
    """The minimum-area rectangle of each group of points ``x[starts[g]:starts[g + 1]]``,
    ``y[...]`` (Freeman & Shapira 1975: one side of the least-area enclosing rectangle lies
    along a convex hull edge; every hull edge is tried).

    Areas within a relative 1e-9 of each other count as equal, and of equal areas the
    smallest perimeter wins (then the first edge): several edges can give the same area (all
    three edges of an acute triangle give twice its area), and without a rule the choice
    would follow rounding. ``cv2.minAreaRect`` (float32) picks among such ties by rounding,
    so it can return another of the equal-area rectangles.

    Computed in float64 on coordinates relative to each group's first point. Returns
    ``centers`` (G, 2), ``sizes`` (G, 2) as (length, width) with length >= width, and
    ``yaws`` (G,) in degrees, the direction of the length in (-90, 90] (for length == width,
    the direction of the side along the chosen hull edge). A group of coincident points gives
    size (0, 0) and yaw 90; collinear points give width 0 and the line's direction.
    """
    g_count = starts.shape[0] - 1
    centers = np.empty((g_count, 2))
    sizes = np.empty((g_count, 2))
    yaws = np.empty(g_count)
    largest = 0
    for g in range(g_count):
        largest = max(largest, starts[g + 1] - starts[g])
    hull = np.empty(largest + 1, np.int64)
    bx = np.empty(largest)
    by = np.empty(largest)
    to_deg = 180.0 / math.pi
    for g in range(g_count):
        s0 = starts[g]
        s1 = starts[g + 1]
        ox = x[s0]
        oy = y[s0]
        n = _outside_octagon(x, y, s0, s1, ox, oy, bx, by)
        px = bx[:n]
        py = by[:n]
        m = _convex_hull(px, py, hull)
        if m == 1:
            centers[g, 0] = ox + px[hull[0]]
            centers[g, 1] = oy + py[hull[0]]
            sizes[g, 0] = 0.0
            sizes[g, 1] = 0.0
            yaws[g] = 90.0  # as cv2.minAreaRect
            continue
        best = np.inf
        best_perimeter = np.inf
        bu0 = bu1 = bv0 = bv1 = ux_best = uy_best = 0.0
        edges = m if m > 2 else 1
        for e in range(edges):
            a = hull[e]
            b = hull[(e + 1) % m]
            ex = px[b] - px[a]
            ey = py[b] - py[a]
            length = math.sqrt(ex * ex + ey * ey)
            ux = ex / length
            uy = ey / length
            u0 = np.inf
            u1 = -np.inf
            v0 = np.inf
            v1 = -np.inf
            for t in range(m):
                k = hull[t]
                u = px[k] * ux + py[k] * uy
                v = -px[k] * uy + py[k] * ux
                u0 = min(u0, u)
                u1 = max(u1, u)
                v0 = min(v0, v)
                v1 = max(v1, v)
            area = (u1 - u0) * (v1 - v0)
            perimeter = (u1 - u0) + (v1 - v0)
            if area < best * (1.0 - 1e-9) or (area <= best * (1.0 + 1e-9)
                                               and perimeter < best_perimeter):
                best = area
                best_perimeter = perimeter
                bu0, bu1, bv0, bv1, ux_best, uy_best = u0, u1, v0, v1, ux, uy
        cu = 0.5 * (bu0 + bu1)
        cv = 0.5 * (bv0 + bv1)
        centers[g, 0] = ox + cu * ux_best - cv * uy_best
        centers[g, 1] = oy + cu * uy_best + cv * ux_best
        along = bu1 - bu0
        across = bv1 - bv0
        if along >= across:
            sizes[g, 0] = along
            sizes[g, 1] = across
            yaw = math.atan2(uy_best, ux_best) * to_deg
        else:
            sizes[g, 0] = across
            sizes[g, 1] = along
            yaw = math.atan2(ux_best, -uy_best) * to_deg
        while yaw > 90.0:
            yaw -= 180.0
        while yaw <= -90.0:
            yaw += 180.0
        yaws[g] = yaw
    return centers, sizes, yaws
