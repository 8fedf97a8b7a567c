"""Local misfit of the terrain surface, for the automatic obstacle threshold.

The automatic threshold (:func:`o3d_terrain.segment.auto_threshold`) is 3.5 times the robust
spread of the points below the surface over the whole cloud: the sensor's noise where the
surface follows the terrain. Where it cannot (ridges and gullies narrower than the control
spacing on steep, sparse scans; docs/algorithm.md, LAS section) the terrain departs from the
surface by more than that noise, on both sides of it, over areas of about a control spacing.

The ground there is sampled by the mean height above the surface of the points of each
:data:`MISFIT_CELL` cell (points higher than :data:`MISFIT_HIGH` left out). Per block of
:data:`MISFIT_BLOCK` control spacings (at least 7 cells a side, so that the
:data:`MISFIT_MIN_CELLS` cells a block needs fit in its lower half), the misfit scale is
1.4826 times the median depth of the cells whose mean lies *below* the surface (obstacles
never do, so low vegetation or cars covering a block do not raise it; a gully the surface
bridges does). The mean of a cell of pure noise spreads less than its points do, so on
terrain the surface follows the scale stays
below the global one whatever the density (the lowest point of a cell would not: its depth
grows with the number of points in the cell). When that scale gives a
threshold at least :data:`MISFIT_SIGNIFICANT` times the global one (the median of 20 or more
cells is then well beyond its own sampling error), the block's points get that threshold,
at most :data:`MISFIT_HIGH`, on both sides of the surface (terrain the surface undercuts on a
ridge and terrain below it in a gully), and so do its 8 neighbouring blocks: a surface that
bridges a gully also undercuts the ridges beside it, whose cells are all above the surface and
so never measure a misfit themselves. In widened blocks the threshold also grows with the
surface's slope, by half a control spacing x tan(slope) over the global one (at most
:data:`MISFIT_HIGH`): the detail the surface misses lies within about half a spacing of where
the data pin it. Elsewhere the global threshold is unchanged.

The widened threshold does not take the returns of a vertical face: a point more than
:data:`MISFIT_FACE_LOW` above the surface whose x/y column (:data:`MISFIT_FACE_CELL`) holds
points spanning more than :data:`MISFIT_FACE_SPREAD` vertically stays an obstacle
(:func:`face_points`): a car or a person beside rough ground stacks its returns in one column,
a ridge the surface undercuts does not (a column crosses it at the terrain's slope).

In widened blocks the points still above their threshold are then measured against the
terrain around them instead of the surface (:func:`local_plane_terrain`): a point at most the
global threshold above the plane through the terrain points within half a control spacing
that surround it is terrain (repeated while points change): where the surface is known not to
follow the terrain, the terrain points next to a missed ridge pin its ground better than the
surface does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._kernels import local_plane as _lp

__all__ = ["misfit_thresholds", "widened_thresholds", "block_size", "MISFIT_FACTOR",
           "MISFIT_HIGH", "MISFIT_FACE_LOW", "MISFIT_FACE_CELL", "MISFIT_FACE_SPREAD",
           "face_points", "MISFIT_CELL", "MISFIT_BLOCK", "MISFIT_SIGNIFICANT", "MISFIT_MIN_CELLS",
           "MISFIT_REACH", "MISFIT_PLANE_MIN_POINTS", "MISFIT_PLANE_ROUNDS",
           "local_plane_terrain", "misfit_reach", "plane_radius", "PLANE_POINTS", "over_terrain",
           "OVER_RADIUS", "OVER_DEPTH", "OVER_PLANE_POINTS"]

#: threshold = this many robust misfit scales (the factor of the global automatic threshold)
MISFIT_FACTOR = 3.5
#: the widest threshold the misfit can give (m), below a car's or a person's height
MISFIT_HIGH = 1.5
#: side of the cells whose mean height samples the ground (m)
MISFIT_CELL = 1.0
#: the widened threshold does not take a point more than MISFIT_FACE_LOW (m) above the surface
#: whose x/y column of side MISFIT_FACE_CELL (m) spans more than MISFIT_FACE_SPREAD (m)
#: vertically: a wall or an object's side, whose returns stack in one column, not a ridge the
#: surface undercuts, which a column crosses at the terrain's slope (docs/algorithm.md, "Knots
#: where the data are", its paragraph "Vertical faces in widened blocks")
MISFIT_FACE_LOW = 0.5
MISFIT_FACE_CELL = 0.3
MISFIT_FACE_SPREAD = 0.3
#: side of a block, in control spacings (the scale on which the surface's misfit varies)
MISFIT_BLOCK = 2.0
#: a block's threshold replaces the global one only when at least this many times larger
MISFIT_SIGNIFICANT = 2.0
#: fewest cells below the surface that measure a block's misfit; a block is at least
#: ceil(sqrt(2 x MISFIT_MIN_CELLS)) = 7 cells a side whatever the control spacing (about half of
#: its cells lie below a surface that follows the terrain): with the 5 x 5-cell blocks of a
#: 2.5 m spacing no block could ever widen (docs/algorithm.md, "A pit's faces and a raised
#: road's top at the grid's axes")
MISFIT_MIN_CELLS = 20
#: in widened blocks, the threshold grows by this many control spacings x tan(slope): detail
#: the surface cannot follow lies up to half a spacing from where the data pin it
MISFIT_REACH = 0.5
#: in widened blocks, the fewest terrain points (surrounding it) whose local plane can make a
#: point terrain: 3 define a plane, a 4th makes it a fit
MISFIT_PLANE_MIN_POINTS = 4
#: rounds of the local planes at most (a ridge is taken up from its flanks in a few)
MISFIT_PLANE_ROUNDS = 20
#: on a top-down scan (:func:`o3d_terrain.segment.segment_points`), the local planes reach as
#: far as holds this many terrain points at the scan's density (:func:`plane_radius`)
PLANE_POINTS = 16
#: a point the widened threshold or the local planes take above the global threshold is not
#: terrain when a terrain point within OVER_RADIUS (m, x/y) lies more than OVER_DEPTH (m)
#: below the plane through it with the surface's slope (:func:`over_terrain`)
OVER_RADIUS = 0.75
OVER_DEPTH = 0.5
#: ... nor against the plane of the points around it, where they (it included) number at least
#: this many: the points of a face steeper than the surface lie along their own plane
OVER_PLANE_POINTS = 6
#: the local planes (:func:`local_plane_terrain`) and the test of points over the terrain
#: (:func:`over_terrain`) read at most this many points of a neighbour cell (cells as wide as
#: their radius): a denser cell (a lidar's face seen from a few metres holds thousands) lends
#: every k-th of its points, a regular share in which its plane and its lowest points show
#: (docs/algorithm.md, "Points over the terrain on a top-down scan": "A dense cell is read in
#: a regular share")
MOST_CELL_POINTS = 128
#: histogram bin of the depths (m)
_BIN = 0.002


@numba.njit(cache=True)
def _finite_extent(positions, h):
    """(x_min, x_max, y_min, y_max, count) of the points with finite x, y and height."""
    x_min = np.inf
    x_max = -np.inf
    y_min = np.inf
    y_max = -np.inf
    count = 0
    for i in range(h.size):
        x = positions[i, 0]
        y = positions[i, 1]
        if not (math.isfinite(h[i]) and math.isfinite(x) and math.isfinite(y)):
            continue
        count += 1
        x_min = min(x_min, x)
        x_max = max(x_max, x)
        y_min = min(y_min, y)
        y_max = max(y_max, y)
    return x_min, x_max, y_min, y_max, count


@numba.njit(cache=True)
def _block_scales(positions, h, x_min, y_min, cell, nx, ny, per_block, nbx, nby, deepest,
                  bin_size, min_cells, inverse=0.0):
    """Per block, the median depth (m) of the cells whose mean height (over their points at
    most ``deepest`` above the surface, x and y finite) is below it (depths beyond
    ``deepest`` counted as ``deepest``); NaN where fewer than ``min_cells`` cells are below.
    ``positions``: (N, >= 2) x, y rows read in place. ``inverse`` > 0 must be exactly
    1 / cell (a power-of-two cell): the coordinates are then scaled by a multiplication, which
    gives the quotient bit for bit."""
    total_h = np.zeros(nx * ny)
    count = np.zeros(nx * ny, np.int64)
    # consecutive points of a scan mostly share a cell: the cell's running sum and count stay
    # in registers while they do (the same additions in the same order as one per point)
    run = -1
    run_h = 0.0
    run_count = 0
    for i in range(h.size):
        hi = h[i]
        x = positions[i, 0]
        y = positions[i, 1]
        # NaN or an obstacle higher than any threshold, or an undefined position
        if not (hi <= deepest and math.isfinite(x) and math.isfinite(y)):
            continue
        if inverse > 0.0:
            ix = int((x - x_min) * inverse)
            iy = int((y - y_min) * inverse)
        else:
            ix = int((x - x_min) / cell)
            iy = int((y - y_min) / cell)
        if ix < 0 or iy < 0 or ix >= nx or iy >= ny:
            continue
        c = ix * ny + iy
        if c != run:
            if run >= 0:
                total_h[run] = run_h
                count[run] = run_count
            run = c
            run_h = total_h[c]
            run_count = count[c]
        run_h += hi
        run_count += 1
    if run >= 0:
        total_h[run] = run_h
        count[run] = run_count
    low = np.full(nx * ny, np.inf)
    for c in range(nx * ny):
        if count[c] > 0:
            low[c] = total_h[c] / count[c]
    # the depth bins of the cells below the surface, grouped by block (a counting sort)
    nbins = int(deepest / bin_size) + 1
    total = np.zeros(nbx * nby, np.int64)
    for ix in range(nx):
        bx = ix // per_block
        for iy in range(ny):
            if low[ix * ny + iy] <= 0.0:
                total[bx * nby + iy // per_block] += 1
    end = np.empty(nbx * nby, np.int64)  # the end of each block's bins, once they are in
    used = 0
    for b in range(nbx * nby):
        used += total[b]
        end[b] = used - total[b]
    bins = np.empty(used, np.int64)
    for ix in range(nx):
        bx = ix // per_block
        for iy in range(ny):
            v = low[ix * ny + iy]
            if not v <= 0.0:
                continue
            b = bx * nby + iy // per_block
            bins[end[b]] = min(int(-v / bin_size), nbins - 1)
            end[b] += 1
    # per block the bin where the running count of a histogram of its bins reaches half of
    # them: one histogram in cache, cleared again at the bins each block set
    hist = np.zeros(nbins, np.int64)
    out = np.full(nbx * nby, np.nan)
    for b in range(nbx * nby):
        if total[b] < min_cells:
            continue
        for j in range(end[b] - total[b], end[b]):
            hist[bins[j]] += 1
        half = (total[b] + 1) // 2
        acc = 0
        for k in range(nbins):
            acc += hist[k]
            if acc >= half:
                out[b] = (k + 0.5) * bin_size
                break
        for j in range(end[b] - total[b], end[b]):
            hist[bins[j]] = 0
    return out


@numba.njit(cache=True)
def _spread_blocks(out, positions, h, local, x_min, y_min, block_side, nbx, nby):
    """In place: ``out[i]`` = ``local`` of the block of each point with finite x, y and
    height (block indices truncated, then clipped to the grid)."""
    for i in range(h.size):
        x = positions[i, 0]
        y = positions[i, 1]
        if not (math.isfinite(h[i]) and math.isfinite(x) and math.isfinite(y)):
            continue
        bx = min(max(int((x - x_min) / block_side), 0), nbx - 1)
        by = min(max(int((y - y_min) / block_side), 0), nby - 1)
        out[i] = local[bx * nby + by]


def _exact_inverse(cell: float) -> float:
    """1 / cell when it is exact (a power of two, e.g. :data:`MISFIT_CELL`), else 0."""
    c = float(cell)
    if not (math.isfinite(c) and c > 0 and math.frexp(c)[0] == 0.5):
        return 0.0
    inverse = 1.0 / c
    return inverse if math.isfinite(inverse) else 0.0


def _dilate(a: np.ndarray) -> np.ndarray:
    """Maximum over each entry's 3 x 3 neighbourhood (edges replicated)."""
    p = np.pad(a, 1, mode="edge")
    out = a.copy()
    n0, n1 = a.shape
    for i in range(3):
        for j in range(3):
            np.maximum(out, p[i:i + n0, j:j + n1], out=out)
    return out


def _min_block_cells(min_cells: int) -> int:
    """The fewest cells along a block's side: about half of a block's cells lie below a
    surface that follows the terrain, so a block of at least 2 x ``min_cells`` cells can hold
    the ``min_cells`` cells below it that measure its misfit (7 for the default 20)."""
    return math.ceil(math.sqrt(2 * max(int(min_cells), 0)))


def block_size(surface) -> float:
    """:data:`MISFIT_BLOCK` control spacings of a TerrainSurface (m, the larger axis)."""
    spacing = 0.0
    for knots in (surface.knots_x, surface.knots_y):
        spans = max(1, knots.size - 2 * surface.degree - 1)
        spacing = max(spacing, float(knots[-1] - knots[0]) / spans)
    return MISFIT_BLOCK * spacing


def misfit_reach(block: float) -> float:
    """How far (m) terrain detail the surface misses lies from where the data pin it, for
    blocks of side ``block``: :data:`MISFIT_REACH` control spacings (the slope term's reach and
    the local planes' radius)."""
    return MISFIT_REACH * block / MISFIT_BLOCK


def misfit_thresholds(positions: np.ndarray, heights: np.ndarray, threshold: float, *,
                      block: float, factor: float = MISFIT_FACTOR, high: float = MISFIT_HIGH,
                      cell: float = MISFIT_CELL, significant: float = MISFIT_SIGNIFICANT,
                      min_cells: int = MISFIT_MIN_CELLS, grade=None,
                      reach: float | None = None) -> np.ndarray:
    """Per-point thresholds (N,), the global ``threshold`` widened by the local misfit.

    Per block of side ``block`` (m; at least ceil(sqrt(2 x ``min_cells``)) cells, so that the
    ``min_cells`` cells fit in the half of a block below the surface): s = 1.4826 x the median
    depth of the ``cell`` x ``cell`` cells whose mean height (``heights`` are z - S; points
    higher than ``high`` left out) is below the surface, t = factor x s; where t >= significant
    x threshold and at least ``min_cells`` cells count, the points of the block and of its 8
    neighbours get min(t, high) (the largest such), elsewhere ``threshold``.

    grade: optional callable (x, y) -> |grad S| (the surface's tangent of slope) at the points
        (:func:`o3d_terrain.segment.segment_points` measures it from the ground under the
        sensor, so that a sensor's tilt does not count as slope);
    with it, the points of widened blocks get at least min(threshold + ``reach`` x |grad S|,
    ``high``): terrain detail the surface cannot follow lies up to ``reach`` (default half a
    control spacing, :func:`misfit_reach` of the block) away from where the
    data pin the surface, so on a slope it departs from the surface by up to reach x
    tan(slope). Points of blocks that were not widened keep ``threshold``."""
    p = np.asarray(positions, dtype=np.float64)
    out = widened_thresholds(p, heights, threshold, block=block, factor=factor, high=high,
                             cell=cell, significant=significant, min_cells=min_cells,
                             grade=grade, reach=reach)
    return np.full(len(p), float(threshold)) if out is None else out


def widened_thresholds(positions: np.ndarray, heights: np.ndarray, threshold: float, *,
                       block: float, factor: float = MISFIT_FACTOR, high: float = MISFIT_HIGH,
                       cell: float = MISFIT_CELL, significant: float = MISFIT_SIGNIFICANT,
                       min_cells: int = MISFIT_MIN_CELLS, grade=None,
                       reach: float | None = None) -> np.ndarray | None:
    """:func:`misfit_thresholds`, or None when no block is widened (every point keeps
    ``threshold``; the usual case where the surface follows the terrain): no per-point array
    is made then."""
    p = np.asarray(positions, dtype=np.float64)
    h = np.ascontiguousarray(heights, dtype=np.float64)
    if high <= threshold or not block > 0:
        return None
    x_min, x_max, y_min, y_max, n_finite = _finite_extent(p, h)
    if n_finite == 0:
        return None
    per_block = max(1, int(round(block / cell)), _min_block_cells(min_cells))
    nx = int((x_max - x_min) / cell) + 1
    ny = int((y_max - y_min) / cell) + 1
    nbx = (nx + per_block - 1) // per_block
    nby = (ny + per_block - 1) // per_block
    scales = _block_scales(p, h, x_min, y_min, float(cell), nx, ny, per_block, nbx, nby,
                           float(high), _BIN, int(min_cells), _exact_inverse(cell))
    local = factor * 1.4826 * scales
    local = np.where(local >= significant * threshold, np.minimum(local, high), threshold)
    if not (local > threshold).any():  # the usual case where the surface follows the terrain
        return None
    # a surface that bridges a gully undercuts the ridges beside it: the neighbouring blocks
    # (within one block, i.e. two control spacings) get the widened threshold too
    local = _dilate(local.reshape(nbx, nby)).ravel()
    out = np.full(len(p), float(threshold))
    _spread_blocks(out, p, h, local, x_min, y_min, cell * per_block, nbx, nby)
    if grade is not None:
        if reach is None:
            reach = misfit_reach(block)
        wide = np.flatnonzero(out > threshold)
        if wide.size:
            g = np.asarray(grade(p[wide, 0], p[wide, 1]), dtype=np.float64)
            g = np.where(np.isfinite(g), g, 0.0)
            out[wide] = np.maximum(out[wide], np.minimum(threshold + reach * g, high))
    return out


def face_points(positions: np.ndarray, heights: np.ndarray, candidates: np.ndarray, *,
                low: float = MISFIT_FACE_LOW, cell: float = MISFIT_FACE_CELL,
                spread: float = MISFIT_FACE_SPREAD, high: float = 2.0 * MISFIT_HIGH
                ) -> np.ndarray:
    """The ``candidates`` (indices) more than ``low`` above the surface whose x/y column of
    side ``cell`` holds points (heights below ``high`` in magnitude) spanning more than
    ``spread`` vertically: the returns of a vertical face."""
    idx = np.ascontiguousarray(candidates, dtype=np.int64)
    h = np.ascontiguousarray(heights, dtype=np.float64)
    idx = idx[h[idx] > low]
    if idx.size == 0:
        return idx
    extent = _lp.column_spread(np.asarray(positions, dtype=np.float64), h, float(high), idx,
                               float(cell))
    return idx[extent > spread]


def over_terrain(positions: np.ndarray, candidates: np.ndarray, terrain: np.ndarray,
                 gradient, *, radius: float = OVER_RADIUS, depth: float = OVER_DEPTH,
                 plane_points: int = OVER_PLANE_POINTS,
                 cell_points: int = MOST_CELL_POINTS) -> np.ndarray:
    """The ``candidates`` (indices) that stand over terrain: some ``terrain`` (N,) bool point
    within ``radius`` (x/y) lies more than ``depth`` below the plane through the candidate
    with the surface's slope there (``gradient(x, y) -> (gx, gy)``) and, where the candidate
    and the terrain points within ``radius`` number at least ``plane_points``, also below the
    plane through it with the slope of their own plane. Ground is one height at each place: a
    point with terrain that far beneath it, beyond what the slope explains, is vegetation or
    an object over the ground (docs/algorithm.md, "Points over the terrain on a top-down
    scan"), while a ridge the surface undercuts has its flanks along its slope, and a face
    steeper than the surface along its own plane. A neighbour cell lends at most
    ``cell_points`` of its terrain points (:data:`MOST_CELL_POINTS`)."""
    p = np.asarray(positions, dtype=np.float64)
    idx = np.ascontiguousarray(candidates, dtype=np.int64)
    if idx.size == 0:
        return idx
    gx, gy = gradient(p[idx, 0], p[idx, 1])
    gx = np.where(np.isfinite(gx), gx, 0.0)
    gy = np.where(np.isfinite(gy), gy, 0.0)
    least = _lp.depth_below_slope(p, np.ascontiguousarray(terrain, dtype=np.bool_), idx,
                                  np.ascontiguousarray(gx, dtype=np.float64),
                                  np.ascontiguousarray(gy, dtype=np.float64), float(radius),
                                  int(plane_points), int(cell_points))
    return idx[least < -depth]


def local_plane_terrain(positions: np.ndarray, heights: np.ndarray, terrain: np.ndarray,
                        candidates: np.ndarray, *, radius: float, threshold: float,
                        min_points: int = MISFIT_PLANE_MIN_POINTS,
                        rounds: int = MISFIT_PLANE_ROUNDS,
                        cell_points: int = MOST_CELL_POINTS) -> int:
    """In place: ``terrain`` (N,) bool set at the ``candidates`` (indices) whose height above
    the surface lies at most ``threshold`` above the least-squares plane (of the heights)
    through the terrain points within ``radius`` (m) of them, when at least ``min_points``
    such points surround the candidate (some on either side in x and in y); repeated, each
    round from the terrain of the one before, until none changes or ``rounds``. Returns how
    many candidates became terrain.

    :func:`o3d_terrain.segment.segment_points` gives it the points of widened blocks still
    labelled obstacle, with ``radius`` half a control spacing (:data:`MISFIT_REACH`): there
    the surface is known not to follow the terrain (a ridge it undercuts by metres), while the
    terrain points on the ridge's flanks, within the reach of detail the surface misses, do;
    a bush or a tree stands above the plane through the ground around it, a ridge point does
    not. A neighbour cell lends the planes at most ``cell_points`` of its points
    (:data:`MOST_CELL_POINTS`); every candidate is still decided."""
    p = np.asarray(positions, dtype=np.float64)
    idx = np.ascontiguousarray(candidates, dtype=np.int64)
    if idx.size == 0:
        return 0
    if terrain.dtype != np.bool_ or not terrain.flags.writeable or terrain.shape != (len(p),):
        raise ValueError("local_plane_terrain: terrain must be a writeable (N,) bool array")
    return int(_lp.local_plane_terrain(p, np.ascontiguousarray(heights, dtype=np.float64),
                                       terrain, idx, float(radius), float(threshold),
                                       int(min_points), int(rounds), int(cell_points)))


def plane_radius(positions: np.ndarray, terrain: np.ndarray, *, most: float,
                 points: int = PLANE_POINTS) -> float:
    """The radius (m) of a disc that holds ``points`` of the ``terrain`` (N,) bool points on
    average, from their density per occupied square metre; at most ``most`` (0 when none is
    terrain). A scan of 2 points/m2 gives 1.6 m, one of 40 points/m2 0.36 m: the local plane
    is as local as the density allows."""
    density = _lp.points_per_square_metre(np.asarray(positions, dtype=np.float64),
                                          np.ascontiguousarray(terrain, dtype=np.bool_))
    if density <= 0.0:
        return 0.0
    return min(math.sqrt(points / (math.pi * density)), float(most))
