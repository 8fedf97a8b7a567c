"""Object feet: terrain-level points that share a small vertical column with the low part of an
obstacle (the base of a bush, a wall, a wheel, a post) are relabelled obstacle.

A column (``cell`` x ``cell`` in x/y) is the foot of an object when it holds obstacle points
below ``foot_height`` that stand out of the local noise (higher than ``noise_factor`` times the
noise scale of the points below the surface in their ``noise_cell`` cell), make up at least
``fraction`` of them and the column's terrain points together, and reach more than ``rise``
above the column's lowest point (terrain does not rise that much across a column: where the
surface undercuts steep ground, the ground above the threshold does not take the ground below
it along), and the column or one of its 8 neighbours holds an obstacle point at least
``object_height`` up (an object stands there, not the upper tail of a noisy sensor's ground).
The noise test, the fraction and the object keep a noisy sensor's (a stereo pair's) upper tail
of ground points from marking the columns of the ground they belong to. On a lidar's scan the
foot height may grow with range (``foot_slope``: a sparse lidar's next line up a face lies
higher at range), a column whose lowest mark lies more than ``foot_gap`` (or ``gap_slope`` x
its range) above its terrain is free space under an overhang and no foot, and terrain points
just behind a mark beside an object, as the sensor sees them, go with it (``behind_radius``).
The sensor's scan-line spacing comes from :func:`scan_line_gaps`.

The columns and cells live in open-addressing hash sets of their integer keys, holding only the
ones that candidate points occupy, so the cost does not depend on the cloud's extent (a
kilometre-wide airborne tile at 0.15 m columns would need billions of grid cells).
"""

import math

import numba
import numpy as np

_EMPTY = -1  # a free slot of a hash set (keys are >= 0)
_MIX = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing: 2^64 / golden ratio, odd
_LIMIT = 2147483647.0  # columns per axis a key can hold
#: the noise scale of a cell from the mean depth of its points below the surface (half-normal)
_HALF_NORMAL = math.sqrt(math.pi / 2.0)


@numba.njit(cache=True)
def _key(x, y, x0, y0, inv_cell):
    """The key (ix * 2^32 + iy, >= 0) of the cell holding (x, y), -1 outside [0, _LIMIT)."""
    fx = math.floor((x - x0) * inv_cell)
    fy = math.floor((y - y0) * inv_cell)
    if not (fx >= 0.0 and fy >= 0.0 and fx < _LIMIT and fy < _LIMIT):  # also False for NaN
        return -1
    return np.int64(fx) * np.int64(4294967296) + np.int64(fy)


@numba.njit(cache=True)
def _new_set(count):
    """An empty hash set for ``count`` keys (load factor <= 1/2): (table, shift, mask)."""
    bits = 4
    while (1 << bits) < 2 * count:
        bits += 1
    return np.full(1 << bits, _EMPTY, np.int64), 64 - bits, (1 << bits) - 1


@numba.njit(cache=True)
def _find(table, shift, mask, key, insert):
    """The slot of ``key`` (inserted when ``insert``), or -1 when absent."""
    s = np.int64((np.uint64(key) * _MIX) >> np.uint64(shift))
    while table[s] != _EMPTY:
        if table[s] == key:
            return s
        s = (s + 1) & mask
    if not insert:
        return -1
    table[s] = key
    return s


@numba.njit(cache=True)
def _screen_bit(key):
    """(word, bit mask) of ``key`` in a one-bit-per-hash screen of 1024 uint64 words: the
    top 16 bits of its Fibonacci hash (as :func:`_find` hashes) pick one of 65,536 bits."""
    b = (np.uint64(key) * _MIX) >> np.uint64(48)
    return b >> np.uint64(6), np.uint64(1) << (b & np.uint64(63))


@numba.njit(cache=True)
def _wide_screen_bit(key):
    """(word, bit mask) of ``key`` in a one-bit-per-hash screen of 16,384 uint64 words (128 KB):
    the top 20 bits of its Fibonacci hash."""
    b = (np.uint64(key) * _MIX) >> np.uint64(44)
    return b >> np.uint64(6), np.uint64(1) << (b & np.uint64(63))


@numba.njit(cache=True)
def _candidate(k, positions, heights, labels, obstacle, foot_height, foot_slope, foot_cap,
               sensor_x, sensor_y):
    """Whether point k is a mark candidate: an OBSTACLE point with a finite position less than
    its foot height above the terrain: ``foot_height``, or ``foot_slope`` times its x/y range
    from the sensor where that is higher (at most ``foot_cap``)."""
    h = heights[k]
    if labels[k] != obstacle or not math.isfinite(h):
        return False
    if h >= foot_height:
        # h < min(foot_slope * r, foot_cap), squared (h > 0): most obstacle points stand
        # higher than the cap and need no range
        if not (foot_slope > 0.0 and h < foot_cap):
            return False
        dx = positions[k, 0] - sensor_x
        dy = positions[k, 1] - sensor_y
        if not h * h < foot_slope * foot_slope * (dx * dx + dy * dy):
            return False
    return math.isfinite(positions[k, 0]) and math.isfinite(positions[k, 1])


@numba.njit(cache=True)
def _lattice_origin(low, side):
    """The origin of the keys of cells of ``side`` below ``low`` (the candidates' lowest x or
    y): a multiple of ``side`` one cell below it, so the cells lie on a fixed lattice whatever
    the candidates are (and the candidates' cells all have their 8 neighbours)."""
    return (math.floor(low / side) - 1.0) * side


@numba.njit(cache=True)
def mark_object_feet(positions, heights, labels, cell, foot_height, fraction, rise,
                     object_height, noise_cell, noise_factor, noise_depth, terrain, obstacle,
                     foot_slope=0.0, foot_cap=0.0, sensor_x=0.0, sensor_y=0.0,
                     behind_radius=0.0, behind_margin=0.0, foot_gap=0.0, gap_slope=0.0):
    """In place: the ``terrain`` labels of the foot columns (module docstring) become
    ``obstacle``; returns how many changed. Noise cells take the points with heights in
    (-noise_depth, 0); a noise cell with fewer than 3 of them sets no noise test. Points with
    non-finite coordinates or heights never mark nor match a column. The first pass keeps the
    indices of the candidates and of the tall obstacle points, so the passes for the noise
    cells, the columns and the objects read only those. The columns lie on two lattices, the
    second shifted by half a column along x and y; a terrain point goes with a foot column of
    either (:func:`_foot_columns`, once per lattice on the same labels), so an object's base
    does not depend on where a lattice's column edge falls on its face. On each, the terrain
    points of marked columns are kept as (point, slot) pairs, and the object test runs last
    and only for the columns that pass the others and hold terrain points (with
    ``behind_radius`` > 0, on the first lattice, for every marked column):
    :func:`_object_test`.

    With ``behind_radius`` > 0, then: the TERRAIN points within ``behind_radius`` (x/y) of a
    mark whose column or one of its 8 neighbours holds an obstacle point at least
    ``object_height`` up, and at least ``behind_margin`` farther (x/y range from the sensor)
    than that mark, become ``obstacle`` too: they lie behind the low part of an object as
    seen from the sensor (:func:`_take_behind`).

    With ``foot_gap`` > 0 a column is a foot only when its lowest mark lies at most
    max(``foot_gap``, ``gap_slope`` x that mark's range) above its highest terrain point."""
    n = heights.shape[0]
    # candidates: obstacle points below their foot height (``foot_height``, or
    # ``foot_slope`` times their range up to ``foot_cap`` where higher); the keys' lattices
    # start below their lowest x, y (and the obstacle points at least object_height up, for
    # the object test)
    candidates = np.empty(n, np.int32)  # their indices: the later passes read only them
    tall_points = np.empty(n, np.int32)
    count = 0
    tall = 0
    x0 = math.inf
    y0 = math.inf
    for k in range(n):
        if labels[k] == obstacle and heights[k] >= object_height:
            tall_points[tall] = k
            tall += 1
        if _candidate(k, positions, heights, labels, obstacle, foot_height, foot_slope,
                      foot_cap, sensor_x, sensor_y):
            candidates[count] = k
            count += 1
            x0 = min(x0, positions[k, 0])
            y0 = min(y0, positions[k, 1])
    if count == 0:
        return 0
    nx0 = _lattice_origin(x0, noise_cell)
    ny0 = _lattice_origin(y0, noise_cell)
    inv_noise = 1.0 / noise_cell
    # the noise cells of the candidates, then the depths of the points below the surface there
    cells, cell_shift, cell_mask = _new_set(count)
    cell_slots = np.empty(count, np.int64)
    for c in range(count):
        k = candidates[c]
        key = _key(positions[k, 0], positions[k, 1], nx0, ny0, inv_noise)
        cell_slots[c] = _find(cells, cell_shift, cell_mask, key, True) if key >= 0 else -1
    depth_sum = np.zeros(cells.size)
    depth_count = np.zeros(cells.size, np.int64)
    for k in range(n):
        h = heights[k]
        if h < 0.0 and h > -noise_depth:
            key = _key(positions[k, 0], positions[k, 1], nx0, ny0, inv_noise)
            if key >= 0:
                s = _find(cells, cell_shift, cell_mask, key, False)
                if s >= 0:
                    depth_sum[s] -= h
                    depth_count[s] += 1
    # the marks: the candidates that stand out of their cell's noise
    mark_points = np.empty(count, np.int32)
    n_marks = 0
    for c in range(count):
        k = candidates[c]
        s = cell_slots[c]
        if s >= 0 and depth_count[s] >= 3 and \
                heights[k] <= noise_factor * _HALF_NORMAL * depth_sum[s] / depth_count[s]:
            continue
        mark_points[n_marks] = k
        n_marks += 1
    mark_points = mark_points[:n_marks]
    if n_marks == 0 or tall == 0:
        return 0
    tall_points = tall_points[:tall]
    # the columns on two lattices, the second shifted by half a column along x and y: a
    # column decides for its points on either (an object's face that one lattice's column
    # straddles lies inside a column of the other); the points of foot columns are kept and
    # labelled once both are done
    feet = np.zeros(n, np.bool_)
    behind = behind_radius > 0.0
    beside = np.zeros(0, np.bool_)
    for lattice in range(2):
        cx0 = _lattice_origin(x0, cell) - 0.5 * lattice * cell
        cy0 = _lattice_origin(y0, cell) - 0.5 * lattice * cell
        near_marks = _foot_columns(positions, heights, labels, mark_points, tall_points, cx0,
                                   cy0, cell, fraction, rise, terrain, sensor_x, sensor_y,
                                   foot_gap, gap_slope, feet, behind and lattice == 0)
        if behind and lattice == 0:
            beside = near_marks
    changed = 0
    for k in range(n):
        if feet[k]:
            labels[k] = obstacle
            changed += 1
    if behind:
        changed += _behind_marks(positions, labels, mark_points[beside], behind_radius,
                                 behind_margin, sensor_x, sensor_y, terrain, obstacle)
    return changed


@numba.njit(cache=True)
def _foot_columns(positions, heights, labels, mark_points, tall_points, cx0, cy0, cell,
                  fraction, rise, terrain, sensor_x, sensor_y, foot_gap, gap_slope, feet,
                  want_near):
    """The feet rule on the lattice of columns of side ``cell`` from (cx0, cy0): ``feet`` is
    set for the ``terrain`` points of the columns that are a foot (marks enough of the
    column's points, rising enough, no free space under them, an object in or beside the
    column). Returns, with ``want_near``, whether each mark's column is beside an object
    (the object test then runs for every marked column), else an empty array."""
    m = mark_points.shape[0]
    inv_cell = 1.0 / cell
    columns, shift, mask = _new_set(m)
    marks = np.zeros(columns.size, np.int64)
    level = np.zeros(columns.size, np.int64)
    top = np.full(columns.size, -np.inf)  # the highest mark of a column
    bottom = np.full(columns.size, np.inf)  # the lowest of its marks and terrain points
    lowest_mark = np.full(columns.size, np.inf)  # and its lowest mark, that mark's range
    lowest_range = np.zeros(columns.size)
    highest_terrain = np.full(columns.size, -np.inf)  # its highest terrain point
    # a one-bit-per-hash screen of the marked columns (8 KB, in cache): most terrain points
    # are in no marked column and need no look-up in the set
    screen = np.zeros(1024, np.uint64)
    mark_slots = np.full(m, -1, np.int64)
    for i in range(m):
        k = mark_points[i]
        key = _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell)
        if key < 0:
            continue
        s = _find(columns, shift, mask, key, True)
        mark_slots[i] = s
        word, bit = _screen_bit(key)
        screen[word] |= bit
        marks[s] += 1
        top[s] = max(top[s], heights[k])
        bottom[s] = min(bottom[s], heights[k])
        if heights[k] < lowest_mark[s]:
            lowest_mark[s] = heights[k]
            lowest_range[s] = math.hypot(positions[k, 0] - sensor_x,
                                         positions[k, 1] - sensor_y)
    # the terrain points in marked columns, with their slots
    hit_points = _screened(positions, labels, terrain, cx0, cy0, inv_cell, screen, False)
    hit_slots = np.empty(hit_points.shape[0], np.int32)
    hits = 0
    for i in range(hit_points.shape[0]):
        k = hit_points[i]
        s = _find(columns, shift, mask,
                  _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell), False)
        if s >= 0:
            level[s] += 1
            hit_points[hits] = k
            hit_slots[hits] = s
            hits += 1
            if math.isfinite(heights[k]):
                bottom[s] = min(bottom[s], heights[k])
                highest_terrain[s] = max(highest_terrain[s], heights[k])
    # the columns where the marks are enough of the points, rise enough and leave no free
    # space under them (the ones with terrain points: only those change labels); then the
    # object test for them (with ``want_near`` for every marked column)
    enough = np.zeros(columns.size, np.bool_)
    tested = np.zeros(columns.size, np.bool_)
    for s in range(columns.size):
        if columns[s] != _EMPTY and level[s] > 0 and \
                marks[s] >= fraction * (marks[s] + level[s]) and top[s] - bottom[s] > rise and \
                (foot_gap <= 0.0 or lowest_mark[s] - highest_terrain[s]
                 <= max(foot_gap, gap_slope * lowest_range[s])):
            enough[s] = True
        tested[s] = enough[s] or (want_near and columns[s] != _EMPTY)
    near = _object_test(positions, columns, tested, tall_points, cx0, cy0, inv_cell)
    for c in range(hits):
        if enough[hit_slots[c]] and near[hit_slots[c]]:
            feet[hit_points[c]] = True
    if not want_near:
        return np.zeros(0, np.bool_)
    near_marks = np.zeros(m, np.bool_)
    for i in range(m):
        near_marks[i] = mark_slots[i] >= 0 and near[mark_slots[i]]
    return near_marks


@numba.njit(cache=True)
def _behind_marks(positions, labels, marks, radius, margin, sensor_x, sensor_y, terrain,
                  obstacle):
    """In place: the ``terrain`` points within ``radius`` (x/y) of one of the ``marks`` and at
    least ``margin`` farther from the sensor (x/y range) than it become ``obstacle``; returns
    how many. The marks' index (:func:`_behind_index`) screens the points before the
    look-ups (:func:`_take_behind`)."""
    if marks.shape[0] == 0:
        return 0
    (cells, shift, mask, start, xs, ys, rs, x0, y0, screen,
     occupied) = _behind_index(positions, marks, radius, sensor_x, sensor_y)
    points = _screened(positions, labels, terrain, x0, y0, 1.0 / radius, screen, True)
    return _take_behind(positions, labels, points, cells, shift, mask, start, xs, ys, rs, x0,
                        y0, occupied, radius, margin, sensor_x, sensor_y, terrain, obstacle)


@numba.njit(cache=True)
def _screened(positions, labels, terrain, x0, y0, inv_side, screen, wide):
    """The ``terrain`` points whose cell (side 1 / ``inv_side`` from (x0, y0)) has its bit set
    in ``screen`` (:func:`_wide_screen_bit` with ``wide``, else :func:`_screen_bit`), in
    point order: the few a hash set then looks up."""
    n = positions.shape[0]
    points = np.empty(n, np.int32)
    count = 0
    for k in range(n):
        if labels[k] != terrain:
            continue
        key = _key(positions[k, 0], positions[k, 1], x0, y0, inv_side)
        if key < 0:
            continue
        word, bit = _wide_screen_bit(key) if wide else _screen_bit(key)
        if screen[word] & bit != 0:
            points[count] = k
            count += 1
    return points[:count]


@numba.njit(cache=True)
def _object_test(positions, columns, tested, tall_points, cx0, cy0, inv_cell):
    """Per slot of the columns' set: whether the column (for the ``tested`` slots) or one of
    its 8 neighbours holds one of the ``tall_points``. Their 3 x 3 neighbourhoods go into a
    small set (9 entries per tested column), so the tall points (~48,000 on a KITTI frame)
    are look-ups in it, behind a screen of it: most tall points (walls, canopies) stand in
    none of them."""
    count = 0
    for s in range(columns.size):
        count += tested[s]
    around, around_shift, around_mask = _new_set(9 * max(count, 1))
    wide = np.zeros(16384, np.uint64)
    for s in range(columns.size):
        if not tested[s]:
            continue
        ix = columns[s] >> 32
        iy = columns[s] & 4294967295
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if ix + dx >= 0 and iy + dy >= 0:  # tall points' keys are never negative
                    key = (ix + dx) * 4294967296 + iy + dy
                    _find(around, around_shift, around_mask, key, True)
                    word, bit = _wide_screen_bit(key)
                    wide[word] |= bit
    standing = np.zeros(around.size, np.bool_)  # a tall point's column
    for c in range(tall_points.shape[0]):
        k = tall_points[c]
        key = _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell)
        if key >= 0:
            word, bit = _wide_screen_bit(key)
            if wide[word] & bit == 0:
                continue
            s = _find(around, around_shift, around_mask, key, False)
            if s >= 0:
                standing[s] = True
    near = np.zeros(columns.size, np.bool_)
    for s in range(columns.size):
        if not tested[s]:
            continue
        ix = columns[s] >> 32
        iy = columns[s] & 4294967295
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if ix + dx >= 0 and iy + dy >= 0:
                    a = _find(around, around_shift, around_mask,
                              (ix + dx) * 4294967296 + iy + dy, False)
                    near[s] = near[s] or standing[a]
    return near


@numba.njit(cache=True)
def _behind_index(positions, mark_points, radius, sensor_x, sensor_y):
    """The marks (at least one) grouped by cells of side ``radius`` (a hash set on a lattice of
    multiples of the side, so a point's marks within ``radius`` lie in its cell's 3 x 3
    neighbourhood): (cells, shift, mask, start, x, y, range, x0, y0, screen, occupied). The
    marks of the cell in slot s are start[s] .. start[s + 1] - 1 of the per-mark arrays x, y
    and range (from the sensor), by increasing range; the 128 KB screens hold the cells
    within reach of a mark and the cells that hold one."""
    m = mark_points.shape[0]
    x_low = math.inf
    y_low = math.inf
    for i in range(m):
        x_low = min(x_low, positions[mark_points[i], 0])
        y_low = min(y_low, positions[mark_points[i], 1])
    inv = 1.0 / radius
    # two cells below the marks: the 3 x 3 neighbourhoods of their cells keep keys >= 0
    x0 = _lattice_origin(x_low, radius) - radius
    y0 = _lattice_origin(y_low, radius) - radius
    cells, shift, mask = _new_set(m)
    slot_of = np.empty(m, np.int64)
    start = np.zeros(cells.size + 1, np.int64)
    for i in range(m):
        k = mark_points[i]
        s = _find(cells, shift, mask, _key(positions[k, 0], positions[k, 1], x0, y0, inv), True)
        slot_of[i] = s
        start[s + 1] += 1
    for s in range(cells.size):
        start[s + 1] += start[s]
    xs = np.empty(m)
    ys = np.empty(m)
    rs = np.empty(m)
    filled = start[:cells.size].copy()
    for i in range(m):
        g = filled[slot_of[i]]
        k = mark_points[i]
        xs[g] = positions[k, 0]
        ys[g] = positions[k, 1]
        rs[g] = math.hypot(positions[k, 0] - sensor_x, positions[k, 1] - sensor_y)
        filled[slot_of[i]] += 1
    for s in range(cells.size):  # each cell's marks by range (insertion sort: a few each)
        for g in range(start[s] + 1, start[s + 1]):
            j = g
            while j > start[s] and rs[j - 1] > rs[j]:
                xs[j - 1], xs[j] = xs[j], xs[j - 1]
                ys[j - 1], ys[j] = ys[j], ys[j - 1]
                rs[j - 1], rs[j] = rs[j], rs[j - 1]
                j -= 1
    screen = np.zeros(16384, np.uint64)
    occupied = np.zeros(16384, np.uint64)
    for s in range(cells.size):
        if cells[s] == _EMPTY:
            continue
        word, bit = _wide_screen_bit(cells[s])
        occupied[word] |= bit
        ix = cells[s] >> 32
        iy = cells[s] & 4294967295
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                word, bit = _wide_screen_bit((ix + dx) * 4294967296 + iy + dy)
                screen[word] |= bit
    return cells, shift, mask, start, xs, ys, rs, x0, y0, screen, occupied


@numba.njit(cache=True)
def _take_behind(positions, labels, points, cells, shift, mask, start, xs, ys, rs, x0, y0,
                 occupied, radius, margin, sensor_x, sensor_y, terrain, obstacle):
    """In place: the ``points`` still ``terrain`` within ``radius`` (x/y) of a mark and at
    least ``margin`` farther from the sensor (x/y range) than it become ``obstacle`` (the
    marks as :func:`_behind_index` groups them); returns how many."""
    inv = 1.0 / radius
    radius2 = radius * radius
    changed = 0
    for i in range(points.shape[0]):
        k = points[i]
        if labels[k] != terrain:
            continue
        x = positions[k, 0]
        y = positions[k, 1]
        key = _key(x, y, x0, y0, inv)
        ix = key >> 32
        iy = key & 4294967295
        r = math.hypot(x - sensor_x, y - sensor_y)
        found = False
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if found or ix + dx < 0 or iy + dy < 0:
                    continue
                near_key = (ix + dx) * 4294967296 + iy + dy
                word, bit = _wide_screen_bit(near_key)
                if occupied[word] & bit == 0:  # no mark there: no look-up
                    continue
                s = _find(cells, shift, mask, near_key, False)
                if s < 0:
                    continue
                for g in range(start[s], start[s + 1]):
                    if rs[g] > r - margin:  # the cell's marks by range: none nearer
                        break
                    ddx = xs[g] - x
                    ddy = ys[g] - y
                    if ddx * ddx + ddy * ddy <= radius2:
                        found = True
                        break
        if found:
            labels[k] = obstacle
            changed += 1
    return changed


@numba.njit(cache=True)
def _wedge(dx, dy, tan_wedge):
    """Which of 8 narrow wedges around the sensor holds the x/y offset (dx, dy): 0-3 along
    +x, -x, +y, -y, 4-7 along the diagonals (+x+y, -x-y, +x-y, -x+y); -1 for none. A wedge is
    the offsets within atan(tan_wedge) of its direction."""
    ax = abs(dx)
    ay = abs(dy)
    if ay < tan_wedge * ax:
        return 0 if dx > 0.0 else 1
    if ax < tan_wedge * ay:
        return 2 if dy > 0.0 else 3
    u = dx + dy  # the diagonals, scaled by sqrt(2) (the ratio is what counts)
    v = dx - dy
    if abs(v) < tan_wedge * abs(u):
        return 4 if u > 0.0 else 5
    if abs(u) < tan_wedge * abs(v):
        return 6 if v > 0.0 else 7
    return -1


@numba.njit(cache=True)
def scan_line_gaps(positions, sensor_x, sensor_y, sensor_z, tan_wedge, r_min, r_max,
                   min_gap, step):
    """The gaps (rad) between neighbouring elevation angles, seen from the sensor, of every
    ``step``-th point in 8 narrow wedges around it (:func:`_wedge`) at x/y ranges in
    [r_min, r_max]; gaps of at most ``min_gap`` (points of one scan line, whose elevation is
    its beam's) are left out. A rotating lidar's points of one azimuth lie on its beams, so
    the gaps are multiples of the angle between neighbouring scan lines; a camera's are a
    pixel's."""
    n = positions.shape[0]
    chosen = np.empty(n, np.int32)  # the points in a wedge, and their wedges
    wedge_of = np.empty(n, np.int8)
    counts = np.zeros(9, np.int64)
    m = 0
    low2 = r_min * r_min
    high2 = r_max * r_max
    for k in range(0, n, step):
        dx = positions[k, 0] - sensor_x
        dy = positions[k, 1] - sensor_y
        w = _wedge(dx, dy, tan_wedge)  # -1 for NaN: no wedge
        if w < 0:
            continue
        r2 = dx * dx + dy * dy
        if r2 < low2 or r2 > high2 or not math.isfinite(positions[k, 2]):
            continue
        chosen[m] = k
        wedge_of[m] = w
        counts[w + 1] += 1
        m += 1
    for w in range(8):
        counts[w + 1] += counts[w]
    elevation = np.empty(m)
    filled = counts[:8].copy()
    for i in range(m):
        k = chosen[i]
        w = wedge_of[i]
        elevation[filled[w]] = math.atan2(positions[k, 2] - sensor_z,
                                          math.hypot(positions[k, 0] - sensor_x,
                                                     positions[k, 1] - sensor_y))
        filled[w] += 1
    gaps = np.empty(max(m, 1))
    g = 0
    for w in range(8):
        angles = np.sort(elevation[counts[w]:counts[w + 1]])
        for i in range(1, angles.shape[0]):
            d = angles[i] - angles[i - 1]
            if d > min_gap:
                gaps[g] = d
                g += 1
    return gaps[:g]
