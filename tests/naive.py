"""Slow, obvious reference implementations that the fast kernels must match."""

from __future__ import annotations

import math

import numpy as np


def grid_quantize(positions, x_min, y_min, cell_size, nx, ny, min_points=1, fill_empty=True):
    """Eq. 1 of Broggi et al. 2013 cell by cell with plain Python loops.

    Returns (z, count, state, lowest, highest, mean) with state 0 invalid, 1 measured,
    2 filled; lowest/highest/mean are inf/-inf/0 in cells without points.
    """
    cells = [[[] for _ in range(ny)] for _ in range(nx)]
    for x, y, z in positions:
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        with np.errstate(over="ignore"):
            fx = (x - x_min) / cell_size
            fy = (y - y_min) / cell_size
        if not (math.isfinite(fx) and math.isfinite(fy)):
            continue  # a coordinate too large for the grid's scale: skipped as non-finite
        ix, iy = int(math.floor(fx)), int(math.floor(fy))
        if ix == nx and fx <= nx:
            ix = nx - 1
        if iy == ny and fy <= ny:
            iy = ny - 1
        if 0 <= ix < nx and 0 <= iy < ny:
            cells[ix][iy].append(z)
    height = np.zeros((nx, ny))
    count = np.zeros((nx, ny), np.int64)
    state = np.zeros((nx, ny), np.uint8)
    lowest = np.full((nx, ny), np.inf)
    highest = np.full((nx, ny), -np.inf)
    means = np.zeros((nx, ny))
    for ix in range(nx):
        for iy in range(ny):
            zs = cells[ix][iy]
            count[ix, iy] = len(zs)
            if zs:
                lowest[ix, iy] = min(zs)
                highest[ix, iy] = max(zs)
                total = 0.0
                for v in zs:
                    total += v
                means[ix, iy] = total / len(zs)
            if len(zs) >= min_points and zs:
                total = 0.0
                for v in zs:
                    total += v
                mean = total / len(zs)
                squares = 0.0
                for v in zs:
                    squares += (v - mean) * (v - mean)
                sigma = math.sqrt(squares / len(zs))
                height[ix, iy] = max(min(zs), mean - sigma)
                state[ix, iy] = 1
    if fill_empty:
        measured = state == 1
        for ix in range(nx):
            for iy in range(ny):
                if measured[ix, iy]:
                    continue
                values = []
                for dx in (-1, 0, 1):
                    for dy in (-1, 0, 1):
                        jx, jy = ix + dx, iy + dy
                        if (dx or dy) and 0 <= jx < nx and 0 <= jy < ny and measured[jx, jy]:
                            values.append(height[jx, jy])
                if values:
                    acc = 0.0
                    for v in values:
                        acc += v
                    height[ix, iy] = acc / len(values)
                    state[ix, iy] = 2
    return height, count, state, lowest, highest, means


def grid_cell_planes(positions, x_min, y_min, cell_size, nx, ny, max_grade=1.0, span=0.05,
                     min_points=4, significance=4.0, tilt_spread=0.0):
    """Eq. 1 with the in-cell slope removed, cell by cell with numpy: (level, plane_sample).

    Per cell with at least ``min_points`` points: the least-squares plane through its points
    (offsets u, v from the cell centre), tilted only along the eigenvectors of the (u, v)
    covariance whose eigenvalue is at least (span cell)^2, grade capped at ``max_grade``;
    level = the plane at the centre; plane_sample = level + max(lowest residual, -s), s^2 =
    (sum of squared residuals) / (n - 1 - t) (n - 1) / n with t the number of those
    directions, where the tilt's share of the squares per direction is at least
    ``significance`` times the residuals' per degree of freedom and spreads the heights by at
    least ``tilt_spread`` (root mean square). Other cells
    with points: level = the mean, plane_sample = eq. 1 (:func:`grid_quantize`)."""
    z_eq1, _, _, _, _, means = grid_quantize(positions, x_min, y_min, cell_size, nx, ny)
    level = np.zeros((nx, ny))
    sample = z_eq1.copy()
    members = [[[] for _ in range(ny)] for _ in range(nx)]
    for x, y, z in positions:
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        ix, iy = math.floor((x - x_min) / cell_size), math.floor((y - y_min) / cell_size)
        ix, iy = min(ix, nx - 1) if ix == nx else ix, min(iy, ny - 1) if iy == ny else iy
        if 0 <= ix < nx and 0 <= iy < ny:
            members[ix][iy].append((x - x_min - (ix + 0.5) * cell_size,
                                    y - y_min - (iy + 0.5) * cell_size, z))
    for ix in range(nx):
        for iy in range(ny):
            pts = np.array(members[ix][iy]).reshape(-1, 3)
            n = len(pts)
            if n == 0:
                continue
            level[ix, iy] = means[ix, iy]
            if n < min_points:
                continue
            u, v, z = pts[:, 0], pts[:, 1], pts[:, 2]
            c = np.cov(np.stack([u, v]), bias=True)
            b = np.array([np.mean((u - u.mean()) * (z - z.mean())),
                          np.mean((v - v.mean()) * (z - z.mean()))])
            values, vectors = np.linalg.eigh(c)
            g = np.zeros(2)
            hat = 0
            for k in range(2):  # least squares along the principal directions spanned
                if values[k] >= (span * cell_size) ** 2:
                    e = vectors[:, k]
                    g += e * (e @ b) / values[k]
                    hat += 1
            if np.hypot(*g) > max_grade:
                g = g * max_grade / np.hypot(*g)
            lv = z.mean() - g[0] * u.mean() - g[1] * v.mean()
            r = z - lv - g[0] * u - g[1] * v
            explained = np.sum((g[0] * (u - u.mean()) + g[1] * (v - v.mean())) ** 2)
            if (hat == 0 or explained / hat < significance * np.sum(r * r) / (n - 1 - hat)
                    or explained < n * tilt_spread**2):
                continue  # the tilt explains no more than noise, or too little: mean, eq. 1
            s2 = np.sum(r * r) / (n - 1 - hat) * (n - 1) / n
            level[ix, iy] = lv
            sample[ix, iy] = lv + max(r.min(), -math.sqrt(s2))
    return level, sample


def grid_layer_statistics(positions, x_min, y_min, cell_size, nx, ny, layer):
    """The ground-layer statistics of the grid's pass with plain Python loops: per cell the
    number and the sum (in point order) of the z values within [lowest, lowest + layer] and
    the lowest z above lowest + layer (inf where none). Points are binned as in
    :func:`grid_quantize` (non-finite and outside points skipped)."""
    cells = [[[] for _ in range(ny)] for _ in range(nx)]
    for x, y, z in positions:
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        with np.errstate(over="ignore"):
            fx = (x - x_min) / cell_size
            fy = (y - y_min) / cell_size
        if not (math.isfinite(fx) and math.isfinite(fy)):
            continue  # a coordinate too large for the grid's scale: skipped as non-finite
        ix, iy = int(math.floor(fx)), int(math.floor(fy))
        if ix == nx and fx <= nx:
            ix = nx - 1
        if iy == ny and fy <= ny:
            iy = ny - 1
        if 0 <= ix < nx and 0 <= iy < ny:
            cells[ix][iy].append(z)
    count = np.zeros((nx, ny), np.int64)
    total = np.zeros((nx, ny))
    above = np.full((nx, ny), np.inf)
    for ix in range(nx):
        for iy in range(ny):
            zs = cells[ix][iy]
            if not zs:
                continue
            top = min(zs) + layer
            for v in zs:
                if v <= top:
                    count[ix, iy] += 1
                    total[ix, iy] += v
                elif v < above[ix, iy]:
                    above[ix, iy] = v
    return count, total, above


def cone_fill(height, measured, cell_size, slope):
    """Plain reference of the lower cone envelope min_m (height[m] + slope * d(c, m)), d the
    8-neighbour chamfer distance, by a forward and a backward raster sweep, kept equal to
    ``height`` where ``measured`` (inf = empty; inf stays where no data is reachable)."""
    height = np.asarray(height, dtype=np.float64)
    nx, ny = height.shape
    out = height.copy()
    straight = slope * cell_size
    diagonal = straight * math.sqrt(2.0)
    forward = [(-1, 0, straight), (-1, -1, diagonal), (-1, 1, diagonal), (0, -1, straight)]
    backward = [(1, 0, straight), (1, -1, diagonal), (1, 1, diagonal), (0, 1, straight)]
    for rows, cols, steps in ((range(nx), range(ny), forward),
                              (range(nx - 1, -1, -1), range(ny - 1, -1, -1), backward)):
        for i in rows:
            for j in cols:
                if measured[i, j]:
                    continue
                v = out[i, j]
                for di, dj, step in steps:
                    a, b = i + di, j + dj
                    if 0 <= a < nx and 0 <= b < ny:
                        v = min(v, out[a, b] + step)
                out[i, j] = v
    return out


def above_slope_cone(height, cell_size, slope, tolerance):
    """Plain reference of the wall test: finite cells higher than ``tolerance`` above
    min over the 8 neighbours n of (envelope[n] + slope * d(c, n)), envelope = the lower cone
    envelope of slope ``slope`` with nothing kept fixed (Vosselman's slope-based filter)."""
    height = np.asarray(height, dtype=np.float64)
    nx, ny = height.shape
    envelope = cone_fill(height, np.zeros((nx, ny), bool), cell_size, slope)
    straight = slope * cell_size
    diagonal = straight * math.sqrt(2.0)
    flagged = np.zeros((nx, ny), bool)
    for i in range(nx):
        for j in range(ny):
            if not np.isfinite(height[i, j]):
                continue
            best = math.inf
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    a, b = i + di, j + dj
                    if (di or dj) and 0 <= a < nx and 0 <= b < ny:
                        step = straight if (di == 0 or dj == 0) else diagonal
                        best = min(best, envelope[a, b] + step)
            flagged[i, j] = height[i, j] > best + tolerance
    return flagged


def misfit_thresholds(positions, heights, threshold, *, block, factor=3.5, high=1.5, cell=1.0,
                      significant=2.0, min_cells=20, bin_size=0.002):
    """o3d_terrain.misfit.misfit_thresholds with numpy and plain loops: cells of ``cell`` m
    from the finite points' lower-left corner, the mean height per cell of the points at most
    ``high`` above the surface, per block the median depth of the cells below the surface (a
    histogram of ``bin_size`` bins), the widened blocks dilated by one block, spread to the
    points."""
    p = np.asarray(positions, dtype=np.float64)
    h = np.asarray(heights, dtype=np.float64)
    out = np.full(len(p), float(threshold))
    finite = np.isfinite(h) & np.isfinite(p[:, 0]) & np.isfinite(p[:, 1])
    if not finite.any() or high <= threshold or not block > 0:
        return out
    x, y = p[:, 0], p[:, 1]
    x_min, x_max = x[finite].min(), x[finite].max()
    y_min, y_max = y[finite].min(), y[finite].max()
    # a block is at least sqrt(2 min_cells) cells a side: its lower half holds min_cells
    per_block = max(1, int(round(block / cell)), int(np.ceil(np.sqrt(2 * min_cells))))
    nx = int((x_max - x_min) / cell) + 1
    ny = int((y_max - y_min) / cell) + 1
    nbx = (nx + per_block - 1) // per_block
    nby = (ny + per_block - 1) // per_block
    total = np.zeros((nx, ny))
    count = np.zeros((nx, ny), np.int64)
    for i in np.flatnonzero(finite & (h <= high)):
        ix = int((x[i] - x_min) / cell)
        iy = int((y[i] - y_min) / cell)
        if 0 <= ix < nx and 0 <= iy < ny:
            total[ix, iy] += h[i]
            count[ix, iy] += 1
    nbins = int(high / bin_size) + 1
    depths = [[[] for _ in range(nby)] for _ in range(nbx)]
    for ix in range(nx):
        for iy in range(ny):
            if count[ix, iy] and total[ix, iy] / count[ix, iy] <= 0.0:
                mean = total[ix, iy] / count[ix, iy]
                depths[ix // per_block][iy // per_block].append(
                    min(int(-mean / bin_size), nbins - 1))
    local = np.full((nbx, nby), float(threshold))
    for bx in range(nbx):
        for by in range(nby):
            bins = sorted(depths[bx][by])
            if len(bins) < min_cells:
                continue
            scale = (bins[(len(bins) + 1) // 2 - 1] + 0.5) * bin_size
            t = factor * 1.4826 * scale
            if t >= significant * threshold:
                local[bx, by] = min(t, high)
    if not (local > threshold).any():
        return out
    padded = np.pad(local, 1, mode="edge")
    dilated = np.max([padded[i:i + nbx, j:j + nby] for i in range(3) for j in range(3)], axis=0)
    side = cell * per_block
    for i in np.flatnonzero(finite):
        bx = min(max(int((x[i] - x_min) / side), 0), nbx - 1)
        by = min(max(int((y[i] - y_min) / side), 0), nby - 1)
        out[i] = dilated[bx, by]
    return out



def mark_object_feet(labels, heights, positions, foot_height, cell, fraction, rise,
                     object_height, noise_cell, noise_factor, noise_depth, terrain=1,
                     obstacle=2, foot_slope=0.0, foot_cap=0.0, sensor=(0.0, 0.0),
                     behind_radius=0.0, behind_margin=0.0, foot_gap=0.0):
    """Object feet with dicts of cells: candidates are OBSTACLE points below their foot
    height, ``foot_height`` or min(foot_slope * r, foot_cap) where higher (r: x/y range from
    ``sensor``); keys floor((x - x0) / side), floor((y - y0) / side) with x0/y0 the multiple
    of ``side`` one cell below the floor of the candidates' lowest coordinates (a lattice per
    side). A candidate marks its column when its noise cell has fewer than 3 points with
    heights in (-noise_depth, 0) or it is higher than noise_factor * sqrt(pi / 2) * their mean
    depth; a marked column's TERRAIN points become OBSTACLE when marks >= fraction * (marks +
    its TERRAIN points), its highest mark is more than ``rise`` above the lowest of its marks
    and TERRAIN points, and it or one of its 8 neighbours holds an OBSTACLE point at least
    ``object_height`` up, and (``foot_gap`` > 0) its lowest mark lies at most
    max(foot_gap, foot_slope * that mark's range) above its highest TERRAIN point. Then, with
    ``behind_radius`` > 0, the TERRAIN points within
    ``behind_radius`` (x/y) of a mark whose column or one of its 8 neighbours holds such an
    obstacle point, and at least ``behind_margin`` farther from ``sensor`` (x/y range),
    become OBSTACLE. The columns lie on two lattices, the second shifted by half a column
    along x and y (its origin half a column lower); a TERRAIN point goes with a foot column
    of either, both judged on the same labels; the rule behind the marks uses the first
    lattice's object test. Returns the new labels and how many changed."""
    labels = labels.copy()

    def finite_xy(k):
        return math.isfinite(positions[k, 0]) and math.isfinite(positions[k, 1])

    def limit(k):
        if foot_slope > 0 and heights[k] >= foot_height:
            reach = foot_slope * math.hypot(positions[k, 0] - sensor[0],
                                            positions[k, 1] - sensor[1])
            return max(foot_height, min(reach, foot_cap))
        return foot_height

    candidates = [k for k in range(len(labels))
                  if labels[k] == obstacle and math.isfinite(heights[k])
                  and heights[k] < limit(k) and finite_xy(k)]
    if not candidates:
        return labels, 0
    low_x = min(positions[k, 0] for k in candidates)
    low_y = min(positions[k, 1] for k in candidates)

    def key(k, side, shift=0.0):
        x0 = (math.floor(low_x / side) - 1.0) * side - shift * side
        y0 = (math.floor(low_y / side) - 1.0) * side - shift * side
        return (math.floor((positions[k, 0] - x0) * (1.0 / side)),
                math.floor((positions[k, 1] - y0) * (1.0 / side)))

    depths: dict = {}
    for k in range(len(labels)):
        if -noise_depth < heights[k] < 0 and finite_xy(k):
            depths.setdefault(key(k, noise_cell), []).append(-heights[k])
    mark_points = []
    for k in candidates:
        d = depths.get(key(k, noise_cell), [])
        if len(d) >= 3 and heights[k] <= noise_factor * math.sqrt(math.pi / 2) * np.mean(d):
            continue
        mark_points.append(k)

    def feet_on(shift):
        """The TERRAIN points of foot columns on the lattice shifted by ``shift`` columns,
        and the object test of each column."""
        def col(k):
            return key(k, cell, shift)
        marks: dict = {}
        column_heights: dict = {}  # each marked column's marks and TERRAIN points
        for k in mark_points:
            marks[col(k)] = marks.get(col(k), 0) + 1
            column_heights.setdefault(col(k), {"marks": [], "all": []})
            column_heights[col(k)]["marks"].append(heights[k])
            column_heights[col(k)]["all"].append(heights[k])
        objects = {col(k) for k in range(len(labels))
                   if labels[k] == obstacle and heights[k] >= object_height and finite_xy(k)}
        level: dict = {}
        terrain_top: dict = {}
        for k in range(len(labels)):
            if labels[k] == terrain and finite_xy(k):
                level[col(k)] = level.get(col(k), 0) + 1
                if col(k) in column_heights and math.isfinite(heights[k]):
                    column_heights[col(k)]["all"].append(heights[k])
                    terrain_top[col(k)] = max(terrain_top.get(col(k), -math.inf), heights[k])

        def no_gap(c):
            if foot_gap <= 0:
                return True
            low = min((k for k in mark_points if col(k) == c), key=lambda k: heights[k])
            reach = foot_slope * math.hypot(positions[low, 0] - sensor[0],
                                            positions[low, 1] - sensor[1])
            return heights[low] - terrain_top.get(c, -math.inf) <= max(foot_gap, reach)

        def near_object(k):
            ix, iy = col(k)
            return any((ix + dx, iy + dy) in objects for dx in (-1, 0, 1) for dy in (-1, 0, 1))
        feet = set()
        for k in range(len(labels)):
            if labels[k] != terrain or not finite_xy(k):
                continue
            m = marks.get(col(k), 0)
            if m > 0 and near_object(k) and m >= fraction * (m + level[col(k)]) and \
                    max(column_heights[col(k)]["marks"]) \
                    - min(column_heights[col(k)]["all"]) > rise and no_gap(col(k)):
                feet.add(k)
        return feet, near_object

    # two lattices, the second shifted by half a column: a point goes with a foot of either
    feet, near_first = feet_on(0.0)
    feet |= feet_on(0.5)[0]
    for k in feet:
        labels[k] = obstacle
    changed = len(feet)
    if behind_radius > 0:
        def rng(k):
            return math.hypot(positions[k, 0] - sensor[0], positions[k, 1] - sensor[1])

        shown = [j for j in mark_points if near_first(j)]
        for k in range(len(labels)):
            if labels[k] != terrain or not finite_xy(k):
                continue
            if any(math.hypot(positions[j, 0] - positions[k, 0],
                              positions[j, 1] - positions[k, 1]) <= behind_radius
                   and rng(j) <= rng(k) - behind_margin for j in shown):
                labels[k] = obstacle
                changed += 1
    return labels, changed


def relabel_along_normal(labels, heights, positions, surface, threshold, below_threshold,
                         range_coefficient=0.0, sensor_origin=(0.0, 0.0, 0.0), cap=2.0,
                         terrain=1, obstacle=2, below=3):
    """Thresholds along the normal with numpy masks: OBSTACLE points with h <= t(r) f and
    BELOW_TERRAIN points with h >= -below_threshold f become TERRAIN, f = min(sqrt(1 +
    |grad S|^2), cap) (1 where it is not finite), the gradient from ``surface.gradient`` (the
    B-spline sums). Returns the new labels."""
    labels = labels.copy()
    r2 = (positions[:, 0] - sensor_origin[0]) ** 2 + (positions[:, 1] - sensor_origin[1]) ** 2
    t = threshold + range_coefficient * r2 if range_coefficient else np.full(len(labels),
                                                                             threshold)
    gx, gy = surface.gradient(positions[:, 0], positions[:, 1])
    factor = np.sqrt(1.0 + gx * gx + gy * gy)
    factor = np.where(np.isfinite(factor), np.minimum(factor, cap), 1.0)
    up = (labels == obstacle) & (heights <= t * factor)
    down = (labels == below) & (heights >= -below_threshold * factor)
    labels[up | down] = terrain
    return labels
