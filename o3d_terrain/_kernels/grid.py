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
def isolated_low(state, count, z, lowest, mean, gap, spread, min_points):
    """Per cell (arrays of one shape, read flat) whether it is MEASURED, holds at least
    ``min_points`` points and its lowest point lies more than ``gap`` + 3 s below the mean of
    its other points, s <= ``spread`` their standard deviation (from the count, the mean, the
    lowest point and eq. 1's Z = mean - sigma, where Z lies above the lowest point; heights
    relative to the cell's mean)."""
    out = np.zeros(state.size, np.bool_)
    st = state.ravel()
    ct = count.ravel()
    zf = z.ravel()
    lf = lowest.ravel()
    mf = mean.ravel()
    for c in range(st.size):
        n = ct[c]
        if st[c] != MEASURED or n < min_points or n < 2 or not zf[c] > lf[c]:
            continue
        sigma = mf[c] - zf[c]
        low = lf[c] - mf[c]  # < 0
        others = n - 1.0
        rest_mean = -low / others
        rest_var = (n * sigma * sigma - low * low) / others - rest_mean * rest_mean
        rest_sigma = math.sqrt(rest_var) if rest_var > 0.0 else 0.0
        if rest_sigma <= spread and low < rest_mean - gap - 3.0 * rest_sigma:
            out[c] = True
    return out.reshape(state.shape)


@numba.njit(cache=True)
def low_in_cells(z, cells, m, gap, spread, min_points):
    """(N,) bool: the points more than ``gap`` + 3 s below the median height of their cell,
    s = 1.4826 x the cell's median absolute deviation, in the cells (flat indices ``cells``,
    one per point, < 0 for none; ``m`` cells) of at least ``min_points`` points where s is
    at most ``spread``: a thin layer (the ground) with points well below it. The median and
    its deviation ignore up to half the cell's points, so a cell with several such points
    shows them all."""
    n = z.shape[0]
    count = np.zeros(m + 1, np.int64)
    for k in range(n):
        c = cells[k]
        if c >= 0:
            count[c + 1] += 1
    for c in range(m):
        count[c + 1] += count[c]
    start = count[:m].copy()
    order = np.empty(count[m], np.int64)
    for k in range(n):
        c = cells[k]
        if c >= 0:
            order[start[c]] = k
            start[c] += 1
    out = np.zeros(n, np.bool_)
    most = 0
    for c in range(m):
        most = max(most, count[c + 1] - count[c])
    values = np.empty(most)
    for c in range(m):
        first = count[c]
        size = count[c + 1] - first
        if size < min_points or size < 2:
            continue
        for j in range(size):
            values[j] = z[order[first + j]]
        median = np.median(values[:size])
        s = 1.4826 * np.median(np.abs(values[:size] - median))
        if s > spread:
            continue
        limit = median - gap - 3.0 * s
        for j in range(size):
            k = order[first + j]
            if z[k] < limit:
                out[k] = True
    return out


@numba.njit(cache=True)
def cell_indices(x, y, x_min, y_min, cell_size, nx, ny):
    """:func:`_cell` of every point given as separate x and y arrays."""
    out = np.empty(x.shape[0], np.int64)
    for k in range(x.shape[0]):
        out[k] = _cell(x[k], y[k], x_min, y_min, cell_size, nx, ny)
    return out


@numba.njit(cache=True)
def points_outside_cells(positions, x_min, y_min, cell_size, nx, ny, flagged):
    """The rows of the (N, 3) array ``positions`` that do not lie in a cell (:func:`_cell`)
    flagged in the flat bool array ``flagged``, in their order (points outside the grid and
    non-finite ones stay): the first rows of an (N, 3) array."""
    n = positions.shape[0]
    out = np.empty((n, 3))
    j = 0
    for k in range(n):
        c = _cell(positions[k, 0], positions[k, 1], x_min, y_min, cell_size, nx, ny)
        if c < 0 or not flagged[c]:
            out[j, 0] = positions[k, 0]
            out[j, 1] = positions[k, 1]
            out[j, 2] = positions[k, 2]
            j += 1
    return out[:j]


@numba.njit(cache=True)
def refill_around(height, state, nx, ny, emptied):
    """In place on flat (nx * ny) arrays, after the cells ``emptied`` (flat indices) lost their
    points (their state no longer MEASURED): every cell that is not MEASURED within one cell of
    them takes again the mean height of its 8-neighbour MEASURED cells and is FILLED, or
    INVALID with height 0 without one (:func:`_fill_empty`'s values: its sums run over a
    cell's neighbours in increasing flat index, as this loop does)."""
    for e in emptied:
        ex = e // ny
        ey = e - ex * ny
        for ix in range(max(ex - 1, 0), min(ex + 2, nx)):
            for iy in range(max(ey - 1, 0), min(ey + 2, ny)):
                c = ix * ny + iy
                if state[c] == MEASURED:
                    continue
                total = 0.0
                around = 0
                for jx in range(max(ix - 1, 0), min(ix + 2, nx)):
                    for jy in range(max(iy - 1, 0), min(iy + 2, ny)):
                        j = jx * ny + jy
                        if state[j] == MEASURED:
                            total += height[j]
                            around += 1
                if around > 0:
                    height[c] = total / around
                    state[c] = FILLED
                else:
                    height[c] = 0.0
                    state[c] = INVALID


#: fewest points whose plane eq. 1 uses: a plane takes up to three degrees of freedom from
#: the points, so four leave at least one for the spread about it (fewer: eq. 1)
PLANE_MIN_POINTS = 4

#: a cell's plane is used only where its tilt explains this many times more of the points'
#: spread per degree of freedom than the residuals do (F test, about the 95 % quantile for
#: the degrees of freedom of 5-30 points); elsewhere the cell keeps the mean and eq. 1
PLANE_SIGNIFICANCE = 4.0

#: a cell's plane tilts only along the directions its points span by a standard deviation of
#: at least this many cells (points on one line, a single scan ring through the cell, give a
#: plane tilted along that line and level across it: no extrapolation from noise)
PLANE_SPAN = 0.05


@numba.njit(cache=True, inline="always")
def _cell_plane(n, mean, su, sv, suu, svv, suv, suz, svz, cell_size, max_grade):
    """(gx, gy, level, tilts) of the least-squares plane z = mean + gx (u - mu) + gy (v - mv)
    through a cell's n points from their sums (u, v: offsets from the cell's centre), tilted
    only along the principal directions of the points' (u, v) covariance whose standard
    deviation reaches :data:`PLANE_SPAN` cells, its grade |(gx, gy)| capped at ``max_grade``;
    level = its z at the cell's centre; tilts = the number of directions it tilts along (the
    degrees of freedom its slopes take from the residuals). Fewer than
    :data:`PLANE_MIN_POINTS` points: a level plane at the mean."""
    if n < PLANE_MIN_POINTS:
        return 0.0, 0.0, mean, 0.0
    inv = 1.0 / n
    mu = su * inv
    mv = sv * inv
    a = suu * inv - mu * mu  # covariance [[a, b], [b, d]] of (u, v)
    b = suv * inv - mu * mv
    d = svv * inv - mv * mv
    p = suz * inv - mu * mean  # covariance of (u, v) with z
    q = svz * inv - mv * mean
    span = (PLANE_SPAN * cell_size) ** 2
    half_trace = 0.5 * (a + d)
    gap = math.sqrt(0.25 * (a - d) * (a - d) + b * b)
    large = half_trace + gap
    small = half_trace - gap
    gx = 0.0
    gy = 0.0
    tilts = 0.0
    if small >= span:  # spread over the cell: the full least-squares plane
        det = a * d - b * b
        gx = (d * p - b * q) / det
        gy = (a * q - b * p) / det
        tilts = 2.0
    elif large >= span:  # along one line: tilt along its direction e only
        if abs(b) > 1e-300:
            ex = large - d
            ey = b
        elif a >= d:
            ex = 1.0
            ey = 0.0
        else:
            ex = 0.0
            ey = 1.0
        norm = math.sqrt(ex * ex + ey * ey)
        ex /= norm
        ey /= norm
        slope = (ex * p + ey * q) / large
        gx = slope * ex
        gy = slope * ey
        tilts = 1.0
    grade = math.sqrt(gx * gx + gy * gy)
    if grade > max_grade:
        gx *= max_grade / grade
        gy *= max_grade / grade
    return gx, gy, mean - gx * mu - gy * mv, tilts


@numba.njit(cache=True)
def _plane_candidates(count, squares, min_points, tilt_spread, plane):
    """(slot, candidates, members): per cell its slot among the cells whose plane
    :func:`quantize` must fit (-1 elsewhere), their number and the number of their points.

    A cell needs no plane where the result without one is known: fewer than
    :data:`PLANE_MIN_POINTS` points (level = the mean, sample eq. 1's), or a MEASURED cell
    whose k heights square to less than k tilt_spread^2 about their mean (``squares``, eq. 1's
    sum). Proof of the latter: the plane's tilt spreads the heights by ``explained`` =
    sum_i (g . (p_i - mean p))^2, the squares of its fitted values about their mean; the
    fitted values of a least-squares fit (full, or along one direction of the offsets) are the
    orthogonal projection of the heights onto the span of the constant and those offsets, so
    explained <= sum_i (z_i - mean z)^2 = squares (a projection does not lengthen a vector;
    capping the grade only scales g down). So the tilt_spread test (explained < k
    tilt_spread^2) fails and the cell keeps the mean and eq. 1's sample, as a plane without
    tilt does (level = mean - 0 mu - 0 mv = mean bit for bit: a sum from +0 is never -0). The
    bound is taken with 2 % to spare (candidates: squares >= 0.98 k tilt_spread^2), far above
    the rounding of the sums (of the order of 1e-12 m^2 for heights of 1 km in 0.5 m cells).
    Cells with fewer than ``min_points`` points (not MEASURED) keep their plane's level
    whatever its tilt: candidates. With tilt_spread = 0 every cell of PLANE_MIN_POINTS points
    or more is one. Without ``plane``: none."""
    m = count.shape[0] if plane else 0
    slot = np.full(m, -1, np.int32)
    floor = 0.98 * tilt_spread * tilt_spread
    candidates = 0
    members = 0
    for c in range(m):
        k = count[c]
        if k >= PLANE_MIN_POINTS and (k < min_points or squares[c] >= floor * k):
            slot[c] = candidates
            candidates += 1
            members += k
    return slot, candidates, members


@numba.njit(cache=True, inline="always")
def _store_plane_sums(su, sv, suu, svv, suv, suz, svz, s, a_u, a_v, a_uu, a_vv, a_uv, a_uz,
                      a_vz):
    """Write the seven running plane sums of candidate ``s`` (held in registers by
    :func:`_candidate_planes`) back into their arrays."""
    su[s] = a_u
    sv[s] = a_v
    suu[s] = a_uu
    svv[s] = a_vv
    suv[s] = a_uv
    suz[s] = a_uz
    svz[s] = a_vz


@numba.njit(cache=True)
def _candidate_planes(positions, cells, slot, candidates, members, x_min, y_min, cell_size,
                      ny, count, state, mean, max_grade, tilt_spread, level, plane_sample):
    """The planes of the candidate cells of :func:`_plane_candidates` into ``level`` and
    ``plane_sample`` (per cell, the mean and eq. 1's sample already there): their sums in one
    pass over the points (``cells``: each point's cell, < 0 for none) that skips other cells'
    points on their ``slot``, kept in registers while consecutive points stay in one cell;
    :func:`_cell_plane` from the sums; the tilt_spread test from them too; the residuals in
    one pass over the runs of consecutive points in one cell of the cells that pass it (kept
    by the first pass), for the F test, in registers along a run. Sums in point order
    (the values of one per-cell pass over all the points, bit for bit)."""
    # per candidate: sums of the offsets from the cell centre (u, v) and of their products
    # with each other and z, in point order as eq. 1's sums
    su = np.zeros(candidates)
    sv = np.zeros(candidates)
    suu = np.zeros(candidates)
    svv = np.zeros(candidates)
    suv = np.zeros(candidates)
    suz = np.zeros(candidates)
    svz = np.zeros(candidates)
    cell_of = np.empty(candidates, np.int64)
    for c in range(slot.shape[0]):
        if slot[c] >= 0:
            cell_of[slot[c]] = c
    # the candidates' centres (i + 0.5) cell_size along x and y, i the cell's index there (the
    # cell of _scaled_cell: a point on the far edge belongs to the last cell): a point's offset
    # u = x - x_min - centre without a floor per point
    centre_x = np.empty(candidates)
    centre_y = np.empty(candidates)
    for s in range(candidates):
        ix = cell_of[s] // ny
        centre_x[s] = (ix + 0.5) * cell_size
        centre_y[s] = (cell_of[s] - ix * ny + 0.5) * cell_size
    # the candidates' runs of consecutive points in one cell, in point order: points
    # run_start[r] to run_stop[r] - 1 of candidate run_slot[r]
    run_start = np.empty(members, np.int64)
    run_stop = np.empty(members, np.int64)
    run_slot = np.empty(members, np.int64)
    runs = 0
    current = -1  # the candidate whose sums are in the a_ registers (the same additions)
    a_u = a_v = a_uu = a_vv = a_uv = a_uz = a_vz = 0.0
    cx = cy = 0.0
    for k in range(cells.shape[0]):
        c = cells[k]
        if c < 0:
            continue
        s = slot[c]
        if s < 0:
            continue
        if s != current:  # consecutive points mostly share a cell (scan order)
            if current >= 0:
                _store_plane_sums(su, sv, suu, svv, suv, suz, svz, current, a_u, a_v, a_uu,
                                  a_vv, a_uv, a_uz, a_vz)
            current = s
            cx = centre_x[s]
            cy = centre_y[s]
            a_u = su[s]
            a_v = sv[s]
            a_uu = suu[s]
            a_vv = svv[s]
            a_uv = suv[s]
            a_uz = suz[s]
            a_vz = svz[s]
        if runs == 0 or run_slot[runs - 1] != s or run_stop[runs - 1] != k:
            run_start[runs] = k
            run_slot[runs] = s
            runs += 1
        run_stop[runs - 1] = k + 1
        u = positions[k, 0] - x_min - cx
        w = positions[k, 1] - y_min - cy
        v = positions[k, 2]
        a_u += u
        a_v += w
        a_uu += u * u
        a_vv += w * w
        a_uv += u * w
        a_uz += u * v
        a_vz += w * v
    if current >= 0:
        _store_plane_sums(su, sv, suu, svv, suv, suz, svz, current, a_u, a_v, a_uu, a_vv,
                          a_uv, a_uz, a_vz)
    # the planes z = mean + gx (u - mean u) + gy (v - mean v); level = its z at u = v = 0
    grade_x = np.empty(candidates)
    grade_y = np.empty(candidates)
    centre = np.empty(candidates)
    tilts = np.empty(candidates)
    for s in range(candidates):
        c = cell_of[s]
        gx, gy, lv, tl = _cell_plane(count[c], mean[c], su[s], sv[s], suu[s], svv[s], suv[s],
                                     suz[s], svz[s], cell_size, max_grade)
        grade_x[s] = gx
        grade_y[s] = gy
        centre[s] = lv
        tilts[s] = tl
    # the plane's tilt must explain more of the spread than the noise would (an F test of the
    # slopes) and spread the heights by at least tilt_spread: on level or gently sloping ground
    # a tilt fitted to noise or to the relief of grass would only lift the sample, and eq. 1's
    # bias (at most the tilt's spread) stays within the noise the fit allows for; there the
    # plane is the mean and the sample eq. 1's. The spread the tilt explains comes from the
    # sums: only the cells it leaves undecided need the residuals (the F test)
    explained = np.zeros(candidates)
    undecided = np.zeros(candidates, np.bool_)
    for s in range(candidates):
        c = cell_of[s]
        k = count[c]
        if state[c] == MEASURED and tilts[s] > 0:
            inv = 1.0 / k
            mu = su[s] * inv
            mv = sv[s] * inv
            gx = grade_x[s]
            gy = grade_y[s]
            explained[s] = k * (gx * gx * (suu[s] * inv - mu * mu)
                                + 2.0 * gx * gy * (suv[s] * inv - mu * mv)
                                + gy * gy * (svv[s] * inv - mv * mv))
            undecided[s] = not explained[s] < k * tilt_spread * tilt_spread
    least = np.full(candidates, np.inf)  # lowest residual about the plane
    residual_squares = np.zeros(candidates)
    for j in range(runs):
        s = run_slot[j]
        if not undecided[s]:
            continue
        cx = centre_x[s]
        cy = centre_y[s]
        lv = centre[s]
        gx = grade_x[s]
        gy = grade_y[s]
        squares = residual_squares[s]
        lowest = least[s]
        for k in range(run_start[j], run_stop[j]):
            u = positions[k, 0] - x_min - cx
            w = positions[k, 1] - y_min - cy
            r = positions[k, 2] - lv - gx * u - gy * w
            squares += r * r
            lowest = min(lowest, r)
        residual_squares[s] = squares
        least[s] = lowest
    for s in range(candidates):
        c = cell_of[s]
        k = count[c]
        level[c] = centre[s]
        if state[c] == MEASURED and tilts[s] > 0 and (
                not undecided[s] or explained[s] / tilts[s] * (k - 1.0 - tilts[s])
                < PLANE_SIGNIFICANCE * residual_squares[s]):
            tilts[s] = 0.0
            level[c] = mean[c]
        if state[c] == MEASURED and tilts[s] > 0:
            # the residuals' spread with the degrees of freedom the plane took from them (1 for
            # the mean, ``tilts`` for the slopes) given back, in eq. 1's convention (sigma^2 =
            # squares / k, i.e. (k - 1) / k of the unbiased variance): on level ground the
            # same spread as eq. 1's in expectation, on a slope without the rise across it
            spread = residual_squares[s] / (k - 1.0 - tilts[s]) * (k - 1.0) / k
            plane_sample[c] = level[c] + max(least[s], -math.sqrt(spread))


@numba.njit(cache=True)
def _fill_empty(height, state, nx, ny):
    """In place on flat (nx * ny) arrays: the cells that are not MEASURED take the mean height
    of their 8-neighbour MEASURED cells and become FILLED (those without one stay as they
    are). Each MEASURED cell adds its height to its neighbours (in ``height``, 0 there until
    then) in increasing flat index, which is the order of a neighbour's own (dx, dy) loop
    over them, so the sums are those of that loop bit for bit; then one division per cell."""
    m = nx * ny
    around = np.zeros(m, np.uint8)  # MEASURED neighbours of each cell
    for c in range(m):
        if state[c] != MEASURED:
            continue
        ix = c // ny
        iy = c - ix * ny
        z = height[c]
        for jx in range(max(ix - 1, 0), min(ix + 2, nx)):
            for jy in range(max(iy - 1, 0), min(iy + 2, ny)):
                j = jx * ny + jy
                if state[j] != MEASURED:
                    height[j] += z
                    around[j] += 1
    for c in range(m):
        if around[c] > 0:
            height[c] /= around[c]
            state[c] = FILLED


@numba.njit(cache=True)
def _cells_of(flat, x_min, y_min, cell_size, inverse, nx, ny, cells):
    """Into ``cells``: :func:`_cell` of each point of the flat (3 N) rows ``flat`` (x, y, z of
    point k at 3k, 3k + 1, 3k + 2), -2 also where z is not finite; with ``inverse`` > 0 the
    coordinates scaled by it (:func:`_scaled_cell`). Written without branches, which lets the
    compiler vectorise the loop: a point inside the grid (0 <= f <= n per axis, NaN and
    infinities fail it) is in cell floor(f) (= int(f) there), the far edge f = n in the last;
    the same cells as :func:`_scaled_cell` (tests/test_grid.py)."""
    fnx = float(nx)
    fny = float(ny)
    for k in range(cells.shape[0]):
        if inverse > 0.0:
            fx = (flat[3 * k] - x_min) * inverse
            fy = (flat[3 * k + 1] - y_min) * inverse
        else:
            fx = (flat[3 * k] - x_min) / cell_size
            fy = (flat[3 * k + 1] - y_min) / cell_size
        inside = (fx >= 0.0) & (fx <= fnx) & (fy >= 0.0) & (fy <= fny)
        finite = (abs(fx) < math.inf) & (abs(fy) < math.inf) & (abs(flat[3 * k + 2]) < math.inf)
        ix = min(np.int32(fx if inside else 0.0), nx - 1)
        iy = min(np.int32(fy if inside else 0.0), ny - 1)
        cells[k] = ix * ny + iy if inside & finite else (-1 if finite else -2)


@numba.njit(cache=True)
def _run_count(cells):
    """The number of runs of consecutive equal entries of ``cells`` (branch-free: the
    compiler vectorises the loop)."""
    runs = min(cells.shape[0], 1)
    for k in range(1, cells.shape[0]):
        runs += cells[k] != cells[k - 1]
    return runs


@numba.njit(cache=True)
def _cell_sums(flat, cells, m):
    """Per cell of ``cells`` (one per point, -1 outside, -2 non-finite) of the flat rows
    ``flat``: the number of points, the mean, the lowest and the highest of their z (the sum
    taken in point order, then divided by the number; 0, inf and -inf in cells without
    points), then the numbers of non-finite and of outside points. A run of consecutive
    points in one cell (the usual case in a scan's or an image's order) is summed in
    registers and stored once at its end: the same additions in the same order, without a
    store and a reload per point (which chain one point's update to the next one's). The
    sums go straight into the arrays returned (the sum into ``mean``, divided in place), so
    no per-cell array is filled twice; where the points come one to a run (random order:
    each point would touch four arrays' cache lines), :func:`_cell_sums_side_by_side`.
    The same values either way, bit for bit (tests/test_grid.py)."""
    if 2 * _run_count(cells) > cells.shape[0]:  # fewer than 2 points a run
        return _cell_sums_side_by_side(flat, cells, m)
    count = np.zeros(m, np.int64)
    mean = np.zeros(m)  # the sum of z until the division at the end
    lowest = np.full(m, math.inf)
    highest = np.full(m, -math.inf)
    nonfinite = 0
    outside = 0
    current = -1
    k_n = 0
    k_t = k_lo = k_hi = 0.0  # the sums of the current run's cell
    for k in range(cells.shape[0]):
        c = cells[k]
        if c < 0:
            nonfinite += c == -2
            outside += c == -1
            continue
        if c != current:
            if current >= 0:
                count[current] = k_n
                mean[current] = k_t
                lowest[current] = k_lo
                highest[current] = k_hi
            current = c
            k_n = count[c]
            k_t = mean[c]
            k_lo = lowest[c]
            k_hi = highest[c]
        v = flat[3 * k + 2]
        k_n += 1
        k_t += v
        k_lo = min(k_lo, v)  # branch-free (cells hold few points: branches mispredict)
        k_hi = max(k_hi, v)
    if current >= 0:
        count[current] = k_n
        mean[current] = k_t
        lowest[current] = k_lo
        highest[current] = k_hi
    for c in range(m):
        if count[c] > 0:
            mean[c] /= count[c]
    return count, mean, lowest, highest, nonfinite, outside


@numba.njit(cache=True)
def _cell_sums_side_by_side(flat, cells, m):
    """:func:`_cell_sums` for points in short runs (random order): the four per-cell values
    are summed side by side in one (m, 4) array, so that a point touches one cache line, and
    copied out at the end (the same values bit for bit)."""
    sums = np.zeros((m, 4))  # count, total, lowest, highest
    for c in range(m):
        sums[c, 2] = math.inf
        sums[c, 3] = -math.inf
    nonfinite = 0
    outside = 0
    current = -1
    k_n = k_t = k_lo = k_hi = 0.0  # the sums of the current run's cell
    for k in range(cells.shape[0]):
        c = cells[k]
        if c < 0:
            nonfinite += c == -2
            outside += c == -1
            continue
        if c != current:
            if current >= 0:
                sums[current, 0] = k_n
                sums[current, 1] = k_t
                sums[current, 2] = k_lo
                sums[current, 3] = k_hi
            current = c
            k_n = sums[c, 0]
            k_t = sums[c, 1]
            k_lo = sums[c, 2]
            k_hi = sums[c, 3]
        v = flat[3 * k + 2]
        k_n += 1.0
        k_t += v
        k_lo = min(k_lo, v)  # branch-free (cells hold few points: branches mispredict)
        k_hi = max(k_hi, v)
    if current >= 0:
        sums[current, 0] = k_n
        sums[current, 1] = k_t
        sums[current, 2] = k_lo
        sums[current, 3] = k_hi
    count = np.empty(m, np.int64)
    mean = np.zeros(m)
    lowest = np.empty(m)
    highest = np.empty(m)
    for c in range(m):
        count[c] = np.int64(sums[c, 0])  # exact: counts stay far below 2^53
        if count[c] > 0:
            mean[c] = sums[c, 1] / count[c]
        lowest[c] = sums[c, 2]
        highest[c] = sums[c, 3]
    return count, mean, lowest, highest, nonfinite, outside


@numba.njit(cache=True)
def _cell_spreads(flat, cells, mean, lowest, layer, use_layer):
    """Per cell: the sum of the squared deviations of its points' z from ``mean``; with
    ``use_layer`` also the number and the sum of the z within [lowest, lowest + layer] and
    the lowest z above that (inf where none; empty arrays otherwise). Runs of consecutive
    points in one cell in registers, as :func:`_cell_sums`."""
    m = mean.shape[0]
    ml = m if use_layer else 0
    squares = np.zeros(m)
    layer_count = np.zeros(ml, np.int64)
    layer_sum = np.zeros(ml)
    layer_above = np.full(ml, math.inf)
    current = -1
    k_sq = k_ls = 0.0
    k_lc = 0
    k_la = math.inf
    k_mean = k_top = 0.0  # the current cell's mean and lowest + layer
    for k in range(cells.shape[0]):
        c = cells[k]
        if c < 0:
            continue
        if c != current:
            if current >= 0:
                squares[current] = k_sq
                if use_layer:
                    layer_count[current] = k_lc
                    layer_sum[current] = k_ls
                    layer_above[current] = k_la
            current = c
            k_sq = squares[c]
            k_mean = mean[c]
            if use_layer:
                k_lc = layer_count[c]
                k_ls = layer_sum[c]
                k_la = layer_above[c]
                k_top = lowest[c] + layer
        v = flat[3 * k + 2]
        d = v - k_mean
        k_sq += d * d
        if use_layer:
            if v <= k_top:
                k_lc += 1
                k_ls += v
            else:
                k_la = min(k_la, v)
    if current >= 0:
        squares[current] = k_sq
        if use_layer:
            layer_count[current] = k_lc
            layer_sum[current] = k_ls
            layer_above[current] = k_la
    return squares, layer_count, layer_sum, layer_above


@numba.njit(cache=True)
def quantize(positions, x_min, y_min, cell_size, nx, ny, min_points, fill_empty, layer=0.0,
             inverse=0.0, plane=False, max_grade=1.0, tilt_spread=0.0):
    """Per-cell height Z = max(min z, mean z - sigma) (eq. 1), counts, state, lowest, highest
    and mean z of the rows (x, y, z) of an (N, 3) array (read in place); with ``layer`` > 0
    also the number and the sum of the z values within [lowest, lowest + layer] per cell and
    the lowest z above lowest + layer (inf where none): the ground-layer statistics of
    :mod:`o3d_terrain.ground_layer`, summed in point order, and what its canopy rule needs
    (empty arrays otherwise). With ``plane`` also eq. 1 with the in-cell slope removed
    (:func:`_cell_plane`): per cell the height at the cell's centre of the least-squares
    plane through its points (``level``) and the sample level + max(lowest residual, -s)
    (``plane_sample``), s the residuals' spread with the plane's degrees of freedom given
    back; the cell's mean and Z where it has fewer than :data:`PLANE_MIN_POINTS` points, the
    tilt fails the F test of :data:`PLANE_SIGNIFICANCE` or it spreads the points' heights by
    less than ``tilt_spread`` (m, root mean square over the points). The planes' sums are
    gathered only for the cells that can pass those tests (:func:`_plane_candidates`), in a
    third pass over the points, and the residuals for the F test only for the cells whose
    tilt passes the tilt_spread test, in a fourth over their points (:func:`_candidate_planes`;
    empty arrays without ``plane``).

    Each point's cell is :func:`_cell`, found in a loop of its own before the first pass over
    the points and kept for the later passes. Empty cells are filled by :func:`_fill_empty`.
    ``inverse`` > 0 must be exactly 1 / cell_size (a power of
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
    # the rows as one flat (3 N) array: x, y, z of point k at 3k, 3k + 1, 3k + 2 (indexing
    # the 2-D array goes through its run-time strides, which keeps these loops scalar)
    flat = positions.reshape(3 * n)
    # the cells first, in a loop of their own (branch-free: the compiler vectorises it)
    _cells_of(flat, x_min, y_min, cell_size, inverse, nx, ny, cells)
    count, mean, lowest, highest, nonfinite, outside = _cell_sums(flat, cells, m)
    use_layer = layer > 0.0
    squares, layer_count, layer_sum, layer_above = _cell_spreads(flat, cells, mean, lowest,
                                                                 layer, use_layer)
    height = np.zeros(m)
    state = np.zeros(m, np.uint8)
    for c in range(m):
        if count[c] >= min_points and count[c] > 0:
            sigma = math.sqrt(squares[c] / count[c])
            height[c] = max(lowest[c], mean[c] - sigma)
            state[c] = MEASURED
    if fill_empty:
        _fill_empty(height, state, nx, ny)
    # the cells whose plane can pass its tests, each with a slot in compact per-candidate
    # arrays (the other cells' results need no plane: _plane_candidates)
    slot, candidates, members = _plane_candidates(count, squares, min_points,
                                                  tilt_spread, plane)
    mp = m if plane else 0
    # cells without a candidate plane: the mean (0 without points) and eq. 1's sample
    level = mean[:mp].copy()
    plane_sample = height[:mp].copy()
    if candidates > 0:
        _candidate_planes(positions, cells, slot, candidates, members, x_min, y_min,
                          cell_size, ny, count, state, mean, max_grade, tilt_spread, level,
                          plane_sample)
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
        level.reshape(nx, ny) if plane else level.reshape(0, 0),
        plane_sample.reshape(nx, ny) if plane else plane_sample.reshape(0, 0),
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


@numba.njit(cache=True, inline="always")
def _store_moment_sums(sums, s, r_n, r_x, r_y, r_z, r_xx, r_xy, r_xz, r_yy, r_yz, r_zz):
    """Write the ten running sums of slot ``s`` (held in registers by :func:`cell_planes`)
    back into ``sums``."""
    sums[s, 0] = r_n
    sums[s, 1] = r_x
    sums[s, 2] = r_y
    sums[s, 3] = r_z
    sums[s, 4] = r_xx
    sums[s, 5] = r_xy
    sums[s, 6] = r_xz
    sums[s, 7] = r_yy
    sums[s, 8] = r_yz
    sums[s, 9] = r_zz


@numba.njit(cache=True)
def cell_planes(positions, x_min, y_min, cell_size, nx, ny, slot, count, base):
    """Per slot (``slot``: flat cell index -> slot, -1 for cells not wanted; ``count`` slots)
    the total-least-squares plane of the cell's points: its upward unit normal (count, 3) and
    the root mean square of the points about it along the normal and along the plane's second
    direction (the covariance's least and middle eigenvalues, square-rooted), (count,) each;
    NaN for slots with fewer than 3 points. One pass over the points, the sums taken about
    the cell's centre and ``base[c]`` (a height in the cell, e.g. its lowest) so that they
    stay small; non-finite points and points outside the grid are skipped. The points' cells
    come first, in a loop of their own (:func:`_cells_of`, as :func:`quantize` finds them:
    vectorised, -2 also for a non-finite z); a run of consecutive points in one cell is
    summed in registers and stored once at its end (the same additions in the same order as
    one store per point, :func:`_cell_sums`)."""
    n = positions.shape[0]
    cells = np.empty(n, np.int32)
    _cells_of(positions.reshape(3 * n), x_min, y_min, cell_size, 0.0, nx, ny, cells)
    sums = np.zeros((count, 10))  # n, x, y, z, xx, xy, xz, yy, yz, zz
    current = -1  # the cell whose sums are in the registers below
    s = 0
    centre_x = centre_y = low = 0.0
    r_n = r_x = r_y = r_z = r_xx = r_xy = r_xz = r_yy = r_yz = r_zz = 0.0
    for k in range(n):
        c = cells[k]
        if c < 0 or slot[c] < 0:
            continue
        if c != current:
            if current >= 0:
                _store_moment_sums(sums, s, r_n, r_x, r_y, r_z, r_xx, r_xy, r_xz, r_yy, r_yz,
                                   r_zz)
            current = c
            s = slot[c]
            centre_x = x_min + (c // ny + 0.5) * cell_size
            centre_y = y_min + (c % ny + 0.5) * cell_size
            low = base[c]
            r_n = sums[s, 0]
            r_x = sums[s, 1]
            r_y = sums[s, 2]
            r_z = sums[s, 3]
            r_xx = sums[s, 4]
            r_xy = sums[s, 5]
            r_xz = sums[s, 6]
            r_yy = sums[s, 7]
            r_yz = sums[s, 8]
            r_zz = sums[s, 9]
        dx = positions[k, 0] - centre_x
        dy = positions[k, 1] - centre_y
        dz = positions[k, 2] - low
        r_n += 1.0
        r_x += dx
        r_y += dy
        r_z += dz
        r_xx += dx * dx
        r_xy += dx * dy
        r_xz += dx * dz
        r_yy += dy * dy
        r_yz += dy * dz
        r_zz += dz * dz
    if current >= 0:
        _store_moment_sums(sums, s, r_n, r_x, r_y, r_z, r_xx, r_xy, r_xz, r_yy, r_yz, r_zz)
    normal = np.full((count, 3), np.nan)
    thickness = np.full(count, np.nan)
    width = np.full(count, np.nan)
    a = np.empty((3, 3))
    for s in range(count):
        n = sums[s, 0]
        if n < 3:
            continue
        _moment_covariance(a, n, sums[s, 1], sums[s, 2], sums[s, 3], sums[s, 4], sums[s, 5],
                          sums[s, 6], sums[s, 7], sums[s, 8], sums[s, 9])
        least, middle = _symmetric_eigenvalues(a)
        if not _eigenvector(a, least, normal[s]):
            continue
        if normal[s, 2] < 0:
            for i in range(3):
                normal[s, i] = -normal[s, i]
        thickness[s] = math.sqrt(max(least, 0.0))
        width[s] = math.sqrt(max(middle, 0.0))
    return normal, thickness, width


@numba.njit(cache=True)
def _moment_covariance(a, n, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz):
    """Fill the 3 x 3 ``a`` with the covariance of ``n`` points from their sums: sx = sum
    of x, sxy = sum of x y, and so on (the means' products taken off the second moments)."""
    mx, my, mz = sx / n, sy / n, sz / n
    a[0, 0] = sxx / n - mx * mx
    a[0, 1] = a[1, 0] = sxy / n - mx * my
    a[0, 2] = a[2, 0] = sxz / n - mx * mz
    a[1, 1] = syy / n - my * my
    a[1, 2] = a[2, 1] = syz / n - my * mz
    a[2, 2] = szz / n - mz * mz


@numba.njit(cache=True)
def _symmetric_eigenvalues(a):
    """The least and the middle eigenvalue of a symmetric 3 x 3 matrix, in closed form (the
    trigonometric solution of the characteristic cubic): a LAPACK call per cell costs more
    than the cell's sums."""
    p1 = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
    q = (a[0, 0] + a[1, 1] + a[2, 2]) / 3.0
    p2 = (a[0, 0] - q) ** 2 + (a[1, 1] - q) ** 2 + (a[2, 2] - q) ** 2 + 2.0 * p1
    if p2 <= 0.0:  # a multiple of the identity
        return q, q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (a[0, 0] - q) / p, (a[1, 1] - q) / p, (a[2, 2] - q) / p
    b01, b02, b12 = a[0, 1] / p, a[0, 2] / p, a[1, 2] / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
               + b02 * (b01 * b12 - b11 * b02))
    phi = math.acos(min(max(r, -1.0), 1.0)) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    least = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return least, 3.0 * q - largest - least


@numba.njit(cache=True)
def _eigenvector(a, value, out):
    """Unit eigenvector of the symmetric 3 x 3 matrix ``a`` for its least eigenvalue
    ``value`` into ``out``: the largest cross product of two rows of a - value I; False when
    every cross product vanishes (a repeated least eigenvalue: no single direction)."""
    m = a.copy()
    for i in range(3):
        m[i, i] -= value
    best = 0.0
    for i, j in ((0, 1), (0, 2), (1, 2)):
        cx = m[i, 1] * m[j, 2] - m[i, 2] * m[j, 1]
        cy = m[i, 2] * m[j, 0] - m[i, 0] * m[j, 2]
        cz = m[i, 0] * m[j, 1] - m[i, 1] * m[j, 0]
        norm = cx * cx + cy * cy + cz * cz
        if norm > best:
            best = norm
            out[0], out[1], out[2] = cx, cy, cz
    if not best > 0.0:
        return False
    scale = 1.0 / math.sqrt(best)
    for i in range(3):
        out[i] *= scale
    return True
