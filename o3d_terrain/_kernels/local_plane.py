"""Terrain from local planes through the terrain points around a point (the misfit's
densification, :func:`o3d_terrain.misfit.local_plane_terrain`).

A candidate point becomes terrain when its height lies at most ``threshold`` above the plane
fitted (least squares in the heights above the surface) through the terrain points within
``radius`` of it, provided at least ``min_points`` of them surround it (some on either side
of it in x and in y: the plane is interpolated, not extrapolated). Rounds repeat until none
changes or ``max_rounds``; each round decides from the terrain of the round before, so the
order of the candidates does not matter, and after the first it looks again only at the
candidates that gained terrain neighbours (the others would decide as before).

The neighbours are found in a grid of cells at least ``radius`` wide over the candidates'
bounding box grown by ``radius`` (its side grows so that it holds at most about 4096 cells per
axis): a point's neighbours within ``radius`` lie in its cell's 3 x 3 block. Only the points
of the candidates' blocks are read, copied once in the order of their cells.

Dense cells are split into split x split sub-cells (:func:`_split`, from the mean number of
points in an occupied cell) that keep the sums of their terrain points (about a corner of
the sub-cell: count, x, y, x^2, xy, y^2, h, xh, yh) and the box of those points. A sub-cell
whose terrain box lies wholly within ``radius`` of the candidate adds its sums, shifted to
the candidate; one wholly beyond it adds nothing; the others are read point by point. The
labels are those of reading every point (the sums differ in rounding only): a face scanned
at ~1,400 points/m2 with a 1.39 m radius reads ~16,000 points per candidate one by one, a
few hundred sub-cells and ~2,000 points this way. A sparse cloud (about 10 points a cell or
fewer) is read point by point, in the order of the points, as without sub-cells.

Only the first round reads each candidate's neighbours this way. Each candidate keeps its
sums (about itself) from round to round, and a later round adds to them the terrain taken in
the round before that lies within ``radius``, each such point tested (they are kept by cell);
a candidate with none of them near decides as before, and one with more of them around than
a read of its sub-cells costs (about a split-th of its block's points) reads them again
instead. The points summed are those of reading every point, in another order: the labels
are equal but for the sums' rounding (a candidate whose height lies within it of
``threshold`` above its plane). On SemanticKITTI 000000 with a 2 m roadside ditch (24,084
candidates, radius 2.7 m, 20 rounds) the kernel read each candidate's sub-cells ~9 times,
~1.0 s; now once, ~0.13 s, ~0.1 s of it the first round. Adding the run of a row's sub-cells
that lies wholly within the circle at once, from sums over the row's first sub-cells, was
measured slower there: the terrain boxes already pass over a sub-cell in a few nanoseconds,
and the ~460 points a candidate reads one by one, which runs do not spare, take as long.
"""

import math

import numba
import numpy as np

from .grid import _eigenvector, _symmetric_eigenvalues, _moment_covariance

#: cells per axis of the neighbour grid at most (the cell grows beyond ``radius`` to keep this)
_MAX_CELLS = 4096.0
#: sub-cells per side of a neighbour cell at most (:func:`_split`)
_MAX_SPLIT = 16
#: a later round reads a candidate's sub-cells anew, rather than testing the terrain points
#: taken in the round before around it, when these are more than this many times a split-th of
#: the points of its 3 x 3 cells: about what a read costs at the split :func:`_split` chooses
#: (9 split^2 sub-cells + 8 P / split points, P a cell's points, is about 12 P / split there)
_FRESH_READ = 1.0


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


@numba.njit(cache=True, inline="always")
def _wanted_cells(positions, candidates, x0, y0, cell, nx, ny):
    """(nx * ny,) bool: the cells of the grid (:func:`_candidate_grid`) in the 3 x 3 block
    around each candidate's cell, whose points a candidate may read."""
    wanted = np.zeros(nx * ny, np.bool_)
    for k in range(candidates.size):
        i = candidates[k]
        gx = min(int((positions[i, 0] - x0) / cell), nx - 1)
        gy = min(int((positions[i, 1] - y0) / cell), ny - 1)
        for jx in range(max(gx - 1, 0), min(gx + 2, nx)):
            for jy in range(max(gy - 1, 0), min(gy + 2, ny)):
                wanted[jx * ny + jy] = True
    return wanted


@numba.njit(cache=True)
def _regular_share(cell_of, count, most):
    """(N,) bool: the points that their cells lend (``cell_of[j]`` >= 0 the cell of point j,
    ``count[c]`` the number of such points in cell c): every point of a cell of at most
    ``most``, every k-th in index order of a denser one, k the smallest stride that leaves
    at most ``most`` (a lidar's face seen from a few metres holds thousands a cell; its
    plane and its lowest points show in a regular share of them). ``count`` becomes the
    number each cell lends."""
    stride = np.ones(count.size, np.int64)
    for c in range(count.size):
        if count[c] > most:
            stride[c] = (count[c] + most - 1) // most
            count[c] = (count[c] + stride[c] - 1) // stride[c]
    lends = np.zeros(cell_of.size, np.bool_)
    seen = np.zeros(count.size, np.int64)
    for j in range(cell_of.size):
        c = cell_of[j]
        if c >= 0:
            lends[j] = seen[c] % stride[c] == 0
            seen[c] += 1
    return lends


@numba.njit(cache=True)
def _split(points_per_cell):
    """Sub-cells per side of a neighbour cell for a mean of ``points_per_cell`` points in the
    occupied cells: a candidate then reads about 9 split^2 sub-cells' sums and the points of
    the ~8 split sub-cells the circle of ``radius`` crosses, 9 split^2 + 8 P / split in all,
    least at split = (4 P / 9)^(1/3); 1 (every point read, no sums) up to about 10 points a
    cell, at most :data:`_MAX_SPLIT`."""
    k = round((4.0 * points_per_cell / 9.0) ** (1.0 / 3.0))
    return max(1, min(k, _MAX_SPLIT))


@numba.njit(cache=True, inline="always")
def _sub_range(v, radius, v0, cell, g, split):
    """The sub-cells [lo, hi) along one axis of cell ``g`` (from ``v0``, side ``cell``, split
    ``split`` times) that [v - radius, v + radius] overlaps, one more on each side."""
    lo = math.floor(((v - radius - v0) / cell - g) * split) - 1
    hi = math.floor(((v + radius - v0) / cell - g) * split) + 2
    return max(lo, 0), min(hi, split)


@numba.njit(cache=True, inline="always")
def _add_point(s, q, px, py, ph, agg, ref, box, sums):
    """Add the terrain point ``q`` (of the sorted ``px``, ``py``, ``ph``) to sub-cell ``s``'s
    terrain box ``box[s]`` and, with ``sums``, to its sums ``agg[s]`` about ``ref[s]``."""
    x = px[q]
    y = py[q]
    box[s, 0] = min(box[s, 0], x)
    box[s, 1] = max(box[s, 1], x)
    box[s, 2] = min(box[s, 2], y)
    box[s, 3] = max(box[s, 3], y)
    if sums:
        _add_moments(agg, s, x - ref[s, 0], y - ref[s, 1], ph[q])


@numba.njit(cache=True, inline="always")
def _add_moments(sums, k, u, v, h):
    """Add a point at offset (u, v) with height ``h`` to the row ``sums[k]`` (count, u, v, u^2,
    uv, v^2, h, uh, vh): a sub-cell's sums about its corner, a candidate's about itself."""
    sums[k, 0] += 1.0
    sums[k, 1] += u
    sums[k, 2] += v
    sums[k, 3] += u * u
    sums[k, 4] += u * v
    sums[k, 5] += v * v
    sums[k, 6] += h
    sums[k, 7] += u * h
    sums[k, 8] += v * h


@numba.njit(cache=True, inline="always")
def _gather(k, xi, yi, cx, cy, nx, ny, slot, x0, y0, cell, split, radius, first, px, py, ph,
            pt, agg, ref, box, sums, sides):
    """Into ``sums[k]`` (count, x, y, x^2, xy, y^2, h, xh, yh of the offsets from (xi, yi))
    and ``sides[k]`` (east, west, north, south: some point lies beyond (xi, yi) that way):
    the terrain points within ``radius`` of (xi, yi) in the 3 x 3 cells about cell (cx, cy),
    read from the sub-cells (module docstring)."""
    kk = split * split
    r2 = radius * radius
    m = 0.0
    sx = sy = sxx = sxy = syy = sh = sxh = syh = 0.0
    east = west = north = south = False
    for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
        for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
            c = slot[gx * ny + gy]
            if c < 0:
                continue
            # the sub-cells the circle's box overlaps (one more each side: a point's
            # sub-cell comes from its own rounding)
            a0, a1 = _sub_range(xi, radius, x0, cell, gx, split)
            b0, b1 = _sub_range(yi, radius, y0, cell, gy, split)
            for a in range(a0, a1):
                for s in range(c * kk + a * split + b0, c * kk + a * split + b1):
                    # the terrain box's nearest and farthest offsets: every terrain point
                    # of the sub-cell lies within the radius, or none does, or it is read
                    # point by point (exact: |x_j - x_i| is monotone in x_j in floating
                    # point too)
                    ex = box[s, 1] - xi
                    wx = box[s, 0] - xi
                    ey = box[s, 3] - yi
                    wy = box[s, 2] - yi
                    if not ex >= wx:
                        continue  # no terrain point
                    nearx = wx if wx > 0.0 else (-ex if ex < 0.0 else 0.0)
                    neary = wy if wy > 0.0 else (-ey if ey < 0.0 else 0.0)
                    if nearx * nearx + neary * neary > r2:
                        continue
                    farx = max(-wx, ex)
                    fary = max(-wy, ey)
                    if split > 1 and farx * farx + fary * fary <= r2:
                        ax = ref[s, 0] - xi
                        ay = ref[s, 1] - yi
                        ms = agg[s, 0]
                        su = agg[s, 1]
                        sv = agg[s, 2]
                        sw = agg[s, 6]
                        m += ms
                        sx += su + ms * ax
                        sy += sv + ms * ay
                        sxx += agg[s, 3] + 2.0 * ax * su + ms * ax * ax
                        sxy += agg[s, 4] + ax * sv + ay * su + ms * ax * ay
                        syy += agg[s, 5] + 2.0 * ay * sv + ms * ay * ay
                        sh += sw
                        sxh += agg[s, 7] + ax * sw
                        syh += agg[s, 8] + ay * sw
                        east = east or ex > 0.0
                        west = west or wx < 0.0
                        north = north or ey > 0.0
                        south = south or wy < 0.0
                        continue
                    for q in range(first[s], first[s + 1]):
                        if not pt[q]:
                            continue
                        dx = px[q] - xi
                        dy = py[q] - yi
                        if dx * dx + dy * dy > r2:
                            continue
                        hj = ph[q]
                        m += 1.0
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
    sums[k, 0] = m
    sums[k, 1] = sx
    sums[k, 2] = sy
    sums[k, 3] = sxx
    sums[k, 4] = sxy
    sums[k, 5] = syy
    sums[k, 6] = sh
    sums[k, 7] = sxh
    sums[k, 8] = syh
    sides[k, 0] = east
    sides[k, 1] = west
    sides[k, 2] = north
    sides[k, 3] = south


@numba.njit(cache=True, inline="always")
def _add_fresh(k, xi, yi, cx, cy, nx, ny, slot, radius, fresh_first, fresh, sums, sides):
    """Add to ``sums[k]`` and ``sides[k]`` (:func:`_gather`) the terrain points of the round
    before (``fresh``: x, y, height, by cell from ``fresh_first``) within ``radius`` of
    (xi, yi) in the 3 x 3 cells about cell (cx, cy). Returns whether any was. (A few points a
    candidate: added into the arrays, where :func:`_gather`'s hot loop sums in registers.)"""
    r2 = radius * radius
    grew = False
    for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
        for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
            c = slot[gx * ny + gy]
            if c < 0:
                continue
            for t in range(fresh_first[c], fresh_first[c + 1]):
                dx = fresh[t, 0] - xi
                dy = fresh[t, 1] - yi
                if dx * dx + dy * dy > r2:
                    continue
                grew = True
                _add_moments(sums, k, dx, dy, fresh[t, 2])
                sides[k, 0] = sides[k, 0] or dx > 0.0
                sides[k, 1] = sides[k, 1] or dx < 0.0
                sides[k, 2] = sides[k, 2] or dy > 0.0
                sides[k, 3] = sides[k, 3] or dy < 0.0
    return grew


@numba.njit(cache=True, inline="always")
def _on_plane(k, h, threshold, min_points, sums, sides):
    """Whether a point at height ``h`` lies at most ``threshold`` above the least-squares plane
    of the neighbours summed in ``sums[k]`` and ``sides[k]`` (:func:`_gather`): at least
    ``min_points`` of them, some on each side, not all on a line."""
    m = sums[k, 0]
    if m < min_points or not (sides[k, 0] and sides[k, 1] and sides[k, 2] and sides[k, 3]):
        return False
    sx = sums[k, 1]
    sy = sums[k, 2]
    sxx = sums[k, 3]
    sxy = sums[k, 4]
    syy = sums[k, 5]
    sh = sums[k, 6]
    sxh = sums[k, 7]
    syh = sums[k, 8]
    # intercept of the least-squares plane h = a + b dx + c dy (Cramer's rule)
    det = (m * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy)
           + sy * (sx * sxy - sxx * sy))
    if not abs(det) > 1e-9 * m * max(sxx * syy, 1e-300):
        return False  # the neighbours lie on a line
    num = (sh * (sxx * syy - sxy * sxy) - sx * (sxh * syy - sxy * syh)
           + sy * (sxh * sxy - sxx * syh))
    return h - num / det <= threshold


@numba.njit(cache=True)
def local_plane_terrain(positions, heights, terrain, candidates, radius, threshold,
                        min_points, max_rounds, cell_points):
    """In place: ``terrain[i]`` (bool, (N,)) set for the ``candidates`` (int64 indices) that
    lie at most ``threshold`` above the local plane of the terrain points around them (module
    docstring). ``positions`` (N, >= 2), ``heights`` (N,) above the surface. A neighbour cell
    of more than ``cell_points`` points (terrain or not) lends the planes a regular share of
    them (:func:`_regular_share`). Returns how many candidates became terrain."""
    if candidates.size == 0 or not radius > 0.0:
        return 0
    x0, x1, y0, y1, cell, nx, ny = _candidate_grid(positions, candidates, radius, radius)
    n = heights.size
    # the cells whose points can be read: a candidate's 3 x 3 cells
    wanted = _wanted_cells(positions, candidates, x0, y0, cell, nx, ny)
    # the points in them (listed in index order), each with its cell and its fraction of it
    cell_of = np.full(n, -1, np.int64)
    listed = np.empty(n, np.int64)
    frac = np.empty((n, 2))
    count = np.zeros(nx * ny, np.int64)
    inside = 0
    for i in range(n):
        x = positions[i, 0]
        y = positions[i, 1]
        if not (math.isfinite(heights[i]) and x >= x0 and x <= x1 and y >= y0 and y <= y1):
            continue
        fx = (x - x0) / cell
        fy = (y - y0) / cell
        gx = min(int(fx), nx - 1)
        gy = min(int(fy), ny - 1)
        c = gx * ny + gy
        if not wanted[c]:
            continue
        cell_of[i] = c
        listed[inside] = i
        frac[inside, 0] = fx - gx
        frac[inside, 1] = fy - gy
        count[c] += 1
        inside += 1
    # the points a dense cell lends the planes (the others are still labelled, as candidates
    # or terrain); count becomes the number each cell lends
    lends = _regular_share(cell_of, count, cell_points)
    # the points in the candidates' own cells, on average: what a candidate reads
    read = 0.0
    placed = 0
    for k in range(candidates.size):
        c = cell_of[candidates[k]]
        if c >= 0:
            read += count[c]
            placed += 1
    # the occupied cells, numbered (in place of their counts; -1 for the others)
    slot = count
    occupied = 0
    for c in range(nx * ny):
        if slot[c] > 0:
            slot[c] = occupied
            occupied += 1
        else:
            slot[c] = -1
    split = _split(read / max(placed, 1))
    kk = split * split
    # sub-cell s = slot * kk + a * split + b (a, b of split x split in the cell, from the
    # cell's own fraction so that the sub-cells partition the cells exactly); the points
    # sorted by it, then by index (a stable counting sort): sub-cell s holds
    # order[first[s]:first[s + 1]]
    sub_of = np.empty(inside, np.int64)
    first = np.zeros(occupied * kk + 1, np.int64)
    for t in range(inside):
        a = min(max(int(frac[t, 0] * split), 0), split - 1)
        b = min(max(int(frac[t, 1] * split), 0), split - 1)
        sub = slot[cell_of[listed[t]]] * kk + a * split + b
        sub_of[t] = sub
        first[sub + 1] += 1
    for s in range(occupied * kk):
        first[s + 1] += first[s]
    fill = first[:-1].copy()
    order = np.empty(inside, np.int64)
    at = np.full(n, -1, np.int64)  # each point's place in ``order``
    sub_at = np.empty(inside, np.int64)  # the sub-cell of the point at each place
    for t in range(inside):
        q = fill[sub_of[t]]
        i = listed[t]
        order[q] = i
        at[i] = q
        sub_at[q] = sub_of[t]
        fill[sub_of[t]] += 1
    # the points in that order: x, y, height, terrain
    px = np.empty(inside)
    py = np.empty(inside)
    ph = np.empty(inside)
    pt = np.empty(inside, np.bool_)
    for q in range(inside):
        j = order[q]
        px[q] = positions[j, 0]
        py[q] = positions[j, 1]
        ph[q] = heights[j]
        pt[q] = terrain[j] and lends[j]
    # per sub-cell: the sums of its terrain points about its reference corner (count, u, v,
    # uu, uv, vv, h, uh, vh), the corner, and the terrain points' box (x min, x max, y min,
    # y max); only read when split > 1
    subs = occupied * kk if split > 1 else 0
    agg = np.zeros((subs, 9))
    ref = np.empty((subs, 2))
    box = np.empty((occupied * kk, 4))
    box[:, 0] = np.inf
    box[:, 1] = -np.inf
    box[:, 2] = np.inf
    box[:, 3] = -np.inf
    for c in range(nx * ny):
        if slot[c] < 0 or split == 1:
            continue
        gx = c // ny
        gy = c - gx * ny
        for t in range(kk):
            a = t // split
            ref[slot[c] * kk + t, 0] = x0 + (gx + a / split) * cell
            ref[slot[c] * kk + t, 1] = y0 + (gy + (t - a * split) / split) * cell
    for s in range(occupied * kk):
        for q in range(first[s], first[s + 1]):
            if pt[q]:
                _add_point(s, q, px, py, ph, agg, ref, box, split > 1)
    # each candidate's neighbour sums (:func:`_gather`), kept from round to round: a later
    # round adds the terrain taken in the round before, at a few nanoseconds a point, where
    # reading the sub-cells again costs a few microseconds (module docstring)
    sums = np.zeros((candidates.size, 9))
    sides = np.zeros((candidates.size, 4), np.bool_)
    # the terrain taken in the round before (x, y, height), by occupied cell: that of cell c
    # is fresh[fresh_first[c]:fresh_first[c + 1]]
    fresh_first = np.zeros(occupied + 1, np.int64)
    fresh = np.empty((candidates.size, 3))
    fresh_fill = np.empty(occupied, np.int64)
    # the occupied cells with such terrain in their 3 x 3 cells: the candidates of the others
    # gained no neighbour
    touched = np.zeros(occupied, np.bool_)
    accepted = 0
    new = np.empty(candidates.size, np.int64)
    for round_ in range(max_rounds):
        added = 0
        for k in range(candidates.size):
            i = candidates[k]
            if terrain[i] or cell_of[i] < 0 or (round_ > 0 and not touched[slot[cell_of[i]]]):
                continue
            cx = cell_of[i] // ny
            cy = cell_of[i] % ny
            xi = positions[i, 0]
            yi = positions[i, 1]
            read = round_ == 0
            if not read:
                n_fresh = 0
                n_near = 0
                for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                    for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                        c = slot[gx * ny + gy]
                        if c >= 0:
                            n_fresh += fresh_first[c + 1] - fresh_first[c]
                            n_near += first[(c + 1) * kk] - first[c * kk]
                if n_fresh == 0:
                    continue
                # much terrain taken around: reading the sub-cells again costs less
                read = n_fresh * split > _FRESH_READ * n_near
                if not read and not _add_fresh(k, xi, yi, cx, cy, nx, ny, slot, radius,
                                               fresh_first, fresh, sums, sides):
                    continue  # no new neighbour: it decides as before
            if read:
                _gather(k, xi, yi, cx, cy, nx, ny, slot, x0, y0, cell, split, radius, first,
                        px, py, ph, pt, agg, ref, box, sums, sides)
            if _on_plane(k, heights[i], threshold, min_points, sums, sides):
                new[added] = i
                added += 1
        if added == 0:
            break
        fresh_first[:] = 0
        touched[:] = False
        for k in range(added):
            j = new[k]
            terrain[j] = True
            cx = cell_of[j] // ny
            cy = cell_of[j] % ny
            for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                    if slot[gx * ny + gy] >= 0:
                        touched[slot[gx * ny + gy]] = True
            if not lends[j]:
                continue
            # the sub-cells too, for the candidates that read them again
            q = at[j]
            pt[q] = True
            _add_point(sub_at[q], q, px, py, ph, agg, ref, box, split > 1)
            fresh_first[slot[cell_of[j]] + 1] += 1
        for c in range(occupied):
            fresh_first[c + 1] += fresh_first[c]
        fresh_fill[:] = fresh_first[:-1]
        for k in range(added):
            j = new[k]
            if not lends[j]:
                continue
            c = slot[cell_of[j]]
            fresh[fresh_fill[c], 0] = positions[j, 0]
            fresh[fresh_fill[c], 1] = positions[j, 1]
            fresh[fresh_fill[c], 2] = heights[j]
            fresh_fill[c] += 1
        accepted += added
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


@numba.njit(cache=True)
def depth_below_slope(positions, terrain, candidates, gx, gy, radius, min_plane, cell_points):
    """For each candidate point i, how far the lowest ``terrain`` (N,) bool point j != i
    within ``radius`` (x/y) of it lies below the plane through it with the slope (gx_i, gy_i):
    min over j of (z_j - z_i) - (gx_i (x_j - x_i) + gy_i (y_j - y_i)) (negative: below), or
    +inf where no terrain point lies within ``radius``. Where the candidate and those points
    number at least ``min_plane``, the same is also measured with the slope of their own
    plane (the least eigenvector of their covariance; a plane steeper than about 84 degrees
    gives 0) and the larger of the two is kept: points on a face steeper than the slope the
    caller gives lie along their own plane, not below it.

    The neighbours are found in cells at least ``radius`` wide over the candidates' bounding
    box grown by ``radius`` (:func:`_candidate_grid`), the terrain points of the candidates'
    3 x 3 blocks only, gathered once in the order of their cells. A cell holding more than
    ``cell_points`` terrain points gives a regular share of them (:func:`_regular_share`)."""
    m = candidates.shape[0]
    out = np.full(m, np.inf)
    if m == 0:
        return out
    x0, _, y0, _, side, nx, ny = _candidate_grid(positions, candidates, radius, radius)
    wanted = _wanted_cells(positions, candidates, x0, y0, side, nx, ny)
    # the terrain points of the wanted cells, each with its cell, then those their cells lend
    # sorted by cell (a counting sort): cell c holds order[start[c]:start[c + 1]]
    n = positions.shape[0]
    cell_of = np.full(n, -1, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for j in range(n):
        if not terrain[j]:
            continue
        fx = (positions[j, 0] - x0) / side
        fy = (positions[j, 1] - y0) / side
        if fx >= 0.0 and fx < nx and fy >= 0.0 and fy < ny:
            c = int(fx) * ny + int(fy)
            if wanted[c]:
                cell_of[j] = c
                start[c + 1] += 1
    lends = _regular_share(cell_of, start[1:], cell_points)  # start[c + 1]: cell c's count
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(start[-1], np.int64)
    for j in range(n):
        c = cell_of[j]
        if c >= 0 and lends[j]:
            order[fill[c]] = j
            fill[c] += 1
    r2 = radius * radius
    cov = np.empty((3, 3))
    normal = np.empty(3)
    near = np.empty(start[-1], np.int64)
    for k in range(m):
        i = candidates[k]
        xi = positions[i, 0]
        yi = positions[i, 1]
        zi = positions[i, 2]
        cx = int((xi - x0) / side)
        cy = int((yi - y0) / side)
        count = 0
        least = np.inf
        for a in range(max(cx - 1, 0), min(cx + 2, nx)):
            for b in range(max(cy - 1, 0), min(cy + 2, ny)):
                c = a * ny + b
                for s in range(start[c], start[c + 1]):
                    j = order[s]
                    dx = positions[j, 0] - xi
                    dy = positions[j, 1] - yi
                    if j == i or dx * dx + dy * dy > r2:
                        continue
                    near[count] = j
                    count += 1
                    e = positions[j, 2] - zi - (gx[k] * dx + gy[k] * dy)
                    least = min(least, e)
        if count + 1 >= min_plane and least < 0.0:
            # the neighbourhood's own plane (the candidate included), about the candidate
            sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
            for t in range(count):
                j = near[t]
                u = positions[j, 0] - xi
                v = positions[j, 1] - yi
                w = positions[j, 2] - zi
                sx += u
                sy += v
                sz += w
                sxx += u * u
                sxy += u * v
                sxz += u * w
                syy += v * v
                syz += v * w
                szz += w * w
            _moment_covariance(cov, count + 1.0, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz)
            lowest, _ = _symmetric_eigenvalues(cov)
            if _eigenvector(cov, lowest, normal):
                if abs(normal[2]) < 0.1:  # a near-vertical plane: a face
                    least = max(least, 0.0)
                else:
                    px = -normal[0] / normal[2]
                    py = -normal[1] / normal[2]
                    own = np.inf
                    for t in range(count):
                        j = near[t]
                        e = positions[j, 2] - zi - (px * (positions[j, 0] - xi)
                                                    + py * (positions[j, 1] - yi))
                        own = min(own, e)
                    least = max(least, own)
        out[k] = least
    return out


@numba.njit(cache=True)
def range_histogram(positions, x, y, step, width, bins):
    """Counts of every ``step``-th point by horizontal distance from (x, y), in ``bins`` bins
    of ``width`` (m) from 0; farther points are not counted."""
    counts = np.zeros(bins, np.int64)
    reach = width * bins
    for i in range(0, positions.shape[0], step):
        dx = positions[i, 0] - x
        dy = positions[i, 1] - y
        r2 = dx * dx + dy * dy
        if r2 < reach * reach:
            counts[int(math.sqrt(r2) / width)] += 1
    return counts
