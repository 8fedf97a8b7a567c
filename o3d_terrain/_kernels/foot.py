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
of ground points from marking the columns of the ground they belong to.

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
                     foot_slope=0.0, foot_cap=0.0, sensor_x=0.0, sensor_y=0.0):
    """In place: the ``terrain`` labels of the foot columns (module docstring) become
    ``obstacle``; returns how many changed. Noise cells take the points with heights in
    (-noise_depth, 0); a noise cell with fewer than 3 of them sets no noise test. Points with
    non-finite coordinates or heights never mark nor match a column. The first pass keeps the
    indices of the candidates and of the tall obstacle points, so the passes for the noise
    cells, the columns and the objects read only those (the candidates' noise-cell slots
    kept from the first of them); the terrain points of marked columns are kept as
    (point, slot) pairs for the last pass. The object test runs last and only for the
    columns that pass the others and hold terrain points (no other column changes a label):
    the tall points are looked up in the small set of those columns' 3 x 3 neighbourhoods
    instead of all being inserted into a set of their own."""
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
    cx0 = _lattice_origin(x0, cell)
    cy0 = _lattice_origin(y0, cell)
    nx0 = _lattice_origin(x0, noise_cell)
    ny0 = _lattice_origin(y0, noise_cell)
    inv_cell = 1.0 / cell
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
    # the columns of the candidates that stand out of their cell's noise
    columns, shift, mask = _new_set(count)
    marks = np.zeros(columns.size, np.int64)
    level = np.zeros(columns.size, np.int64)
    top = np.full(columns.size, -np.inf)  # the highest mark of a column
    bottom = np.full(columns.size, np.inf)  # the lowest of its marks and terrain points
    # a one-bit-per-hash screen of the marked columns (8 KB, in cache): most terrain points
    # are in no marked column and need no look-up in the set
    screen = np.zeros(1024, np.uint64)
    for c in range(count):
        k = candidates[c]
        s = cell_slots[c]
        if s >= 0 and depth_count[s] >= 3 and \
                heights[k] <= noise_factor * _HALF_NORMAL * depth_sum[s] / depth_count[s]:
            continue
        key = _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell)
        if key >= 0:
            s = _find(columns, shift, mask, key, True)
            word, bit = _screen_bit(key)
            screen[word] |= bit
            marks[s] += 1
            top[s] = max(top[s], heights[k])
            bottom[s] = min(bottom[s], heights[k])
    # the terrain points in marked columns (their slots kept)
    hit_points = candidates  # reused: (point, slot) of the terrain points in marked columns
    hit_slots = np.empty(n, np.int32)
    hits = 0
    for k in range(n):
        if labels[k] == terrain:
            key = _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell)
            if key >= 0:
                word, bit = _screen_bit(key)
                if screen[word] & bit == 0:
                    continue
                s = _find(columns, shift, mask, key, False)
                if s >= 0:
                    level[s] += 1
                    hit_points[hits] = k
                    hit_slots[hits] = s
                    hits += 1
                    if math.isfinite(heights[k]):
                        bottom[s] = min(bottom[s], heights[k])
    # the columns where the marks are enough of the points and rise enough (the ones with
    # terrain points: only those change labels); then the object test for them alone: the
    # columns of their 3 x 3 neighbourhoods that hold an obstacle point at least
    # object_height up (a small set, so the ~48,000 tall KITTI points are lookups in cache)
    enough = np.zeros(columns.size, np.bool_)
    qualified = 0
    for s in range(columns.size):
        if columns[s] != _EMPTY and level[s] > 0 and \
                marks[s] >= fraction * (marks[s] + level[s]) and top[s] - bottom[s] > rise:
            enough[s] = True
            qualified += 1
    if qualified == 0 or tall == 0:
        return 0
    around, around_shift, around_mask = _new_set(9 * qualified)
    for s in range(columns.size):
        if not enough[s]:
            continue
        ix = columns[s] >> 32
        iy = columns[s] & 4294967295
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if ix + dx >= 0 and iy + dy >= 0:  # tall points' keys are never negative
                    _find(around, around_shift, around_mask,
                          (ix + dx) * 4294967296 + iy + dy, True)
    standing = np.zeros(around.size, np.bool_)  # a tall point's column
    for c in range(tall):
        k = tall_points[c]
        key = _key(positions[k, 0], positions[k, 1], cx0, cy0, inv_cell)
        if key >= 0:
            s = _find(around, around_shift, around_mask, key, False)
            if s >= 0:
                standing[s] = True
    for s in range(columns.size):
        if not enough[s]:
            continue
        ix = columns[s] >> 32
        iy = columns[s] & 4294967295
        near = False
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if ix + dx >= 0 and iy + dy >= 0:
                    a = _find(around, around_shift, around_mask,
                              (ix + dx) * 4294967296 + iy + dy, False)
                    near = near or standing[a]
        enough[s] = near
    changed = 0
    for c in range(hits):
        if enough[hit_slots[c]]:
            labels[hit_points[c]] = obstacle
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
    ``step``-th point in 8 narrow wedges around it (:func:`_wedge`) at x/y ranges in [r_min, r_max];
    gaps of at most ``min_gap`` (points of one scan line, whose elevation is its beam's) are
    left out. A rotating lidar's points of one azimuth lie on its beams, so the gaps are
    multiples of the angle between neighbouring scan lines; a camera's are a pixel's."""
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
