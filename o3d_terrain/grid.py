"""The 2.5-D height grid (Broggi et al. 2013, Sec. IV): value object and quantization.

Arrays are indexed ``[ix, iy]`` (x first, shape ``(nx, ny)``), like the spline's control points
``Q[i0, i1]``. Cell ``(ix, iy)`` covers ``[x_min + ix*c, x_min + (ix+1)*c)`` and likewise in y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ._files import open_npz, output_path
from ._kernels import free_space as _free_space
from ._kernels import grid as _grid
from .errors import InputError

INVALID = _grid.INVALID
MEASURED = _grid.MEASURED
FILLED = _grid.FILLED

#: the most cells a grid may have (a typo'd cell size should fail, not exhaust memory)
MAX_CELLS = 50_000_000
#: a region wider than this (m) in the too-many-cells error gets a hint about millimetres
UNIT_HINT_SPAN = 20_000.0
#: an isolated low point: in a cell of at least LOW_MIN_POINTS points whose heights form a
#: layer of spread at most LOW_SPREAD (m), a point more than LOW_GAP (m) plus three of those
#: spreads below it (:func:`isolated_low_cells`: the lowest point against the others' mean and
#: standard deviation; :func:`isolated_low_points`: every point against the median and the
#: median absolute deviation): a return from below the ground (multipath off a wet road,
#: glass), not ground; on a cell of ground the layer is the ground
LOW_GAP = 0.3
LOW_SPREAD = 0.1
LOW_MIN_POINTS = 4
#: :func:`without_low_returns` acts when at least this share of the measured cells have an
#: isolated low point: a clean SemanticKITTI frame has 0.3-0.4 %, the synthetic scenes at most
#: 1.0 %; the fit itself copes with up to about 0.5 % of the points low (about 4 % of the
#: cells), and from 1 % fails (docs/algorithm.md, "Returns from below the ground")
LOW_MIN_SHARE = 0.02
#: a top-down scan's fit wants cells that hold about this many points where most of its points
#: lie, so that a cell under vegetation also holds a return from the ground (grown_cell;
#: docs/algorithm.md, "Cells for a sparse top-down scan")
CELL_POINTS = 3.0
#: side (m) of the blocks whose point counts give the density most points lie in
#: (typical_density; not refine.DENSITY_BLOCK, the area a top-down scan's points cover)
TYPICAL_DENSITY_BLOCK = 5.0
#: the largest cell (m) a sparse top-down scan's fit grows to
MAX_GROWN_CELL = 3.0
#: grown cells are a multiple of this side (m)
GROWN_CELL_STEP = 0.25


@dataclass(frozen=True, eq=False)
class HeightGrid:
    """Per-cell terrain height samples Z with counts and a measured/filled/invalid state."""

    x_min: float
    y_min: float
    cell_size: float
    z: np.ndarray  # (nx, ny) float64; 0 where INVALID
    count: np.ndarray  # (nx, ny) int64 points per cell
    state: np.ndarray  # (nx, ny) uint8: INVALID 0, MEASURED 1, FILLED 2
    lowest: np.ndarray | None = None  # (nx, ny) lowest z per cell (inf where empty)
    highest: np.ndarray | None = None  # (nx, ny) highest z per cell (-inf where empty)
    mean: np.ndarray | None = None  # (nx, ny) mean z per cell (0 where empty)
    skipped_nonfinite: int = 0  # points skipped for a NaN or infinite coordinate
    skipped_outside: int = 0  # finite points outside the grid's region
    # ground-layer statistics (o3d_terrain.ground_layer) for the thickness ``layer`` (m):
    # number and sum of the z values within [lowest, lowest + layer] per cell, and the lowest
    # z above lowest + layer (inf where none: the canopy rule's gap above the layer)
    layer: float = 0.0
    layer_count: np.ndarray | None = None
    layer_sum: np.ndarray | None = None
    layer_above: np.ndarray | None = None
    # eq. 1 with the in-cell slope removed (quantize_points(plane=True)): the height at the
    # cell's centre of the least-squares plane through its points, and that height plus
    # max(lowest residual, -sigma of the residuals about the plane) on MEASURED cells of 4 or
    # more points whose plane's tilt is significant (elsewhere the mean and z)
    level: np.ndarray | None = None
    plane_sample: np.ndarray | None = None
    tilt_spread: float | None = None  # the tilt_spread the planes were made with (m)
    # quantize_points' options, so that the same grid can be made again from fewer points
    # (requantize)
    min_points: int = 1
    fill_empty: bool = True

    def __repr__(self) -> str:
        r = tuple(round(float(v), 3) for v in self.region)
        measured = int(np.count_nonzero(self.state == MEASURED))
        filled = int(np.count_nonzero(self.state == FILLED))
        return (f"HeightGrid(cells={self.shape}, cell_size={self.cell_size}, region={r}, "
                f"measured={measured}, filled={filled}, points={int(self.count.sum())})")

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.z.shape)  # type: ignore[return-value]

    @property
    def nx(self) -> int:
        return int(self.z.shape[0])

    @property
    def ny(self) -> int:
        return int(self.z.shape[1])

    @property
    def region(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) covered by the cells."""
        c = self.cell_size
        return (self.x_min, self.x_min + self.nx * c, self.y_min, self.y_min + self.ny * c)

    @property
    def x_centers(self) -> np.ndarray:
        return self.x_min + (np.arange(self.nx) + 0.5) * self.cell_size

    @property
    def y_centers(self) -> np.ndarray:
        return self.y_min + (np.arange(self.ny) + 0.5) * self.cell_size

    @property
    def valid(self) -> np.ndarray:
        return self.state != INVALID

    def cell_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat cell index (ix * ny + iy) of each point; -1 outside the grid, -2 non-finite."""
        return _grid.cell_indices(
            np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(y, dtype=np.float64),
            self.x_min, self.y_min, self.cell_size, self.nx, self.ny,
        )

    def save(self, path: str | Path) -> None:
        extremes = {k: v for k, v in (("lowest", self.lowest), ("highest", self.highest),
                                      ("mean", self.mean)) if v is not None}
        np.savez_compressed(
            output_path(path), kind="HeightGrid", x_min=self.x_min, y_min=self.y_min,
            cell_size=self.cell_size, z=self.z, count=self.count, state=self.state, **extremes,
        )

    @classmethod
    def load(cls, path: str | Path) -> "HeightGrid":
        """The grid :meth:`save` wrote (``path`` with or without its ``.npz``)."""
        with open_npz(path, "HeightGrid") as data:
            extremes = [data[k] if k in data.files else None
                        for k in ("lowest", "highest", "mean")]
            return cls(float(data["x_min"]), float(data["y_min"]), float(data["cell_size"]),
                       data["z"], data["count"], data["state"], *extremes)


def grid_shape(region: tuple[float, float, float, float], cell_size: float) -> tuple[int, int]:
    """Cells needed to cover a region (at least one per axis)."""
    x_min, x_max, y_min, y_max = region
    nx = max(1, int(np.ceil((x_max - x_min) / cell_size - 1e-9)))
    ny = max(1, int(np.ceil((y_max - y_min) / cell_size - 1e-9)))
    return nx, ny


def region_of(positions: np.ndarray) -> tuple[float, float, float, float]:
    """The x/y bounding box of the finite points."""
    positions = np.asarray(positions, dtype=np.float64)
    x_min, x_max, y_min, y_max, n = _grid.finite_bounds(
        positions[:, 0], positions[:, 1], positions[:, 2])
    if n == 0:
        raise InputError("the cloud has no finite point; give a cloud with at least one point")
    return (float(x_min), float(x_max), float(y_min), float(y_max))


def _exact_inverse(cell_size: float) -> float:
    """1 / cell_size when it is exact (a power of two: 0.25, 0.5, 1, 2 m), so that multiplying
    by it equals dividing by the cell size bit for bit; 0 otherwise."""
    c = float(cell_size)
    if not (math.isfinite(c) and c > 0 and math.frexp(c)[0] == 0.5):
        return 0.0
    inverse = 1.0 / c
    return inverse if math.isfinite(inverse) else 0.0


#: at most this share of a cloud's points may be stray returns far from the others for the
#: grid's error to point them out (:func:`_stray_points`)
STRAY_SHARE = 0.01


def quantize_points(
    positions: np.ndarray,
    *,
    cell_size: float,
    region: tuple[float, float, float, float] | None = None,
    min_points: int = 1,
    fill_empty: bool = True,
    layer: float = 0.0,
    plane: bool = False,
    tilt_spread: float = 0.0,
) -> HeightGrid:
    """Quantize points into a :class:`HeightGrid` (eq. 1). Non-finite points are skipped.
    ``layer`` > 0: also the ground-layer statistics for that thickness (m) in the same pass
    (used by :func:`o3d_terrain.ground_layer.ground_layer_samples` and
    :func:`~o3d_terrain.ground_layer.overhung_ground_cells` instead of their own).
    ``plane``: also eq. 1 with the in-cell slope removed (``level`` and ``plane_sample``,
    from each cell's least-squares plane, grade at most 1, where its tilt is significant and
    spreads the points' heights by at least ``tilt_spread`` m, root mean square;
    :func:`o3d_terrain._kernels.grid.quantize`), summed only over the cells whose plane can
    pass those tests."""
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"positions must be (N, 3), got {positions.shape}")
    if len(positions) == 0:
        raise InputError("the cloud is empty; give a cloud with points")
    positions = np.ascontiguousarray(positions)
    x = positions[:, 0]
    y = positions[:, 1]
    z = positions[:, 2]  # strided views: the kernels read the rows in place
    if region is None:
        x_min, x_max, y_min, y_max, n = _grid.finite_bounds(x, y, z)
        if n == 0:
            raise InputError("the cloud has no finite point; give a cloud with at least one point")
        region = (float(x_min), float(x_max), float(y_min), float(y_max))
    x_min, x_max, y_min, y_max = region
    if not (x_max >= x_min and y_max >= y_min):
        raise InputError(f"region {tuple(region)} is degenerate: x_max must be >= x_min and y_max >= y_min")
    nx, ny = grid_shape(region, cell_size)
    if nx * ny > MAX_CELLS:
        span = max(x_max - x_min, y_max - y_min)
        stray = _stray_points(x, y, cell_size)
        raise InputError(
            f"region {tuple(round(v, 3) for v in region)} at cell_size {cell_size} m needs "
            f"{nx}×{ny} cells (over {MAX_CELLS:,}); use a larger cell_size or a smaller region"
            + (stray if stray else
               f" (the region spans {span / 1000:,.0f} km: if the coordinates are millimetres, "
               "scale the cloud to metres, e.g. positions / 1000)" if span > UNIT_HINT_SPAN
               else "")
        )
    if not (isinstance(layer, (int, float, np.integer, np.floating)) and math.isfinite(layer)
            and layer >= 0):
        raise InputError(f"layer must be a finite number of metres >= 0, got {layer!r}")
    layer = float(layer)
    (height, count, state, lowest, highest, mean, nonfinite, outside, layer_count, layer_sum,
     layer_above, level, plane_sample) = _grid.quantize(
        positions, x_min, y_min, cell_size, nx, ny, min_points, fill_empty, layer,
        _exact_inverse(cell_size), bool(plane), 1.0, float(tilt_spread))
    return HeightGrid(float(x_min), float(y_min), float(cell_size), height, count, state, lowest,
                      highest, mean, int(nonfinite), int(outside), layer,
                      layer_count if layer else None, layer_sum if layer else None,
                      layer_above if layer else None, level if plane else None,
                      plane_sample if plane else None,
                      float(tilt_spread) if plane else None, int(min_points), bool(fill_empty))


def isolated_low_cells(grid: HeightGrid, *, gap: float = LOW_GAP, spread: float = LOW_SPREAD,
                       min_points: int = LOW_MIN_POINTS) -> np.ndarray:
    """(nx, ny) bool: the MEASURED cells of at least ``min_points`` points whose lowest point
    lies more than ``gap`` + 3 s below the mean of the cell's other points, s (at most
    ``spread``) their standard deviation: the cell's other points are a thin layer (the
    ground) and its lowest point lies well below it. From the grid's own per-cell sums (the
    count, the mean, the lowest point and eq. 1's Z = mean - sigma where that lies above the
    lowest point), so no pass over the points
    (:func:`o3d_terrain._kernels.grid.isolated_low`)."""
    if grid.lowest is None or grid.mean is None:
        return np.zeros(grid.shape, bool)
    return _grid.isolated_low(
        np.ascontiguousarray(grid.state), np.ascontiguousarray(grid.count),
        np.ascontiguousarray(grid.z, dtype=np.float64),
        np.ascontiguousarray(grid.lowest, dtype=np.float64),
        np.ascontiguousarray(grid.mean, dtype=np.float64), float(gap), float(spread),
        int(min_points))


def isolated_low_points(grid: HeightGrid, positions: np.ndarray, *, gap: float = LOW_GAP,
                        spread: float = LOW_SPREAD, min_points: int = LOW_MIN_POINTS
                        ) -> np.ndarray:
    """(N,) bool: among ``positions``, the points the grid was made from, those more than
    ``gap`` + 3 s below the median height of their cell, s (at most ``spread``) 1.4826 times
    the cell's median absolute deviation, in cells of at least ``min_points`` points: a thin
    layer and returns well below it; the median ignores up to half a cell's points, so a cell
    with several such returns gives them all (:func:`isolated_low_cells`, from the cells'
    sums, sees a cell's lowest point only; :func:`o3d_terrain._kernels.grid.low_in_cells`:
    one pass to sort the points by cell, then each cell's median)."""
    p = np.asarray(positions, dtype=np.float64)
    cells = grid.cell_of(p[:, 0], p[:, 1])
    z = np.ascontiguousarray(p[:, 2])
    cells = np.where(np.isfinite(z), cells, -1)
    return _grid.low_in_cells(z, cells, grid.nx * grid.ny, float(gap), float(spread),
                              int(min_points))


def requantize(grid: HeightGrid, positions: np.ndarray, *, cell_size: float | None = None,
               layer: float | None = None) -> HeightGrid:
    """``grid`` made again from ``positions`` (e.g. the points it was made from without some):
    the same cells, options, ground-layer thickness and cells' planes; with ``cell_size``
    cells of that side over the grid's region instead (``layer``: their ground-layer
    thickness, None = the grid's)."""
    return quantize_points(positions, cell_size=grid.cell_size if cell_size is None else cell_size,
                           region=grid.region, min_points=grid.min_points,
                           fill_empty=grid.fill_empty,
                           layer=grid.layer if layer is None else layer,
                           plane=grid.plane_sample is not None,
                           tilt_spread=grid.tilt_spread or 0.0)


def block_sums(values: np.ndarray, step: int) -> np.ndarray:
    """Sums of an (nx, ny) array over blocks of ``step`` x ``step`` cells (the last row and
    column of blocks padded with zeros): (ceil(nx / step), ceil(ny / step)); booleans are
    counted."""
    nx, ny = values.shape
    dtype = np.int64 if values.dtype == bool else values.dtype
    padded = np.zeros((-(-nx // step) * step, -(-ny // step) * step), dtype)
    padded[:nx, :ny] = values
    return padded.reshape(padded.shape[0] // step, step, -1, step).sum(axis=(1, 3))


def typical_density(grid: HeightGrid, block: float = TYPICAL_DENSITY_BLOCK) -> float:
    """Points per square metre where most of the grid's points lie: the median over the
    points of the density of the block of about ``block`` m (whole cells) each lies in. A
    tile's gaps (water, shadows) and its sparse margins do not lower it, and a tile dense in
    one part and sparse elsewhere gets the density most of its points see."""
    step = max(1, int(round(block / grid.cell_size)))
    counts = block_sums(grid.count, step).ravel()
    counts = np.sort(counts[counts > 0])
    if counts.size == 0:
        return 0.0
    total = np.cumsum(counts)
    median = counts[int(np.searchsorted(total, 0.5 * total[-1]))]
    return float(median) / (step * grid.cell_size) ** 2


def grown_cell(grid: HeightGrid, *, points: float = CELL_POINTS,
               largest: float = MAX_GROWN_CELL) -> float:
    """The cell side (m) at which a cell holds about ``points`` points where most of the
    grid's points lie (:func:`typical_density`), in steps of :data:`GROWN_CELL_STEP`, at most
    ``largest``; the grid's own cell when that is under twice its side (its cells hold 3/4
    of ``points`` or more)."""
    density = typical_density(grid)
    if density <= 0:
        return grid.cell_size
    side = math.sqrt(points / density)
    if side < 2.0 * grid.cell_size:
        return grid.cell_size
    return min(math.ceil(side / GROWN_CELL_STEP - 1e-9) * GROWN_CELL_STEP, largest)


def without_low_returns(grid: HeightGrid, positions: np.ndarray, *,
                        min_share: float = LOW_MIN_SHARE
                        ) -> tuple[HeightGrid, np.ndarray, int]:
    """``(grid, positions, dropped)``: when at least ``min_share`` of the grid's MEASURED cells
    are :func:`isolated_low_cells` (from the cells' sums: a cheap test that the scan has many),
    the grid made again (:func:`requantize`) from the points without the isolated low ones
    (:func:`isolated_low_points`), those points and how many were left out; else the inputs
    and 0."""
    cells = isolated_low_cells(grid)
    found = int(cells.sum())
    if found == 0 or found < min_share * int(np.count_nonzero(grid.state == MEASURED)):
        return grid, positions, 0
    low = isolated_low_points(grid, positions)
    if not low.any():
        return grid, positions, 0
    kept = np.ascontiguousarray(np.asarray(positions, dtype=np.float64)[~low])
    return requantize(grid, kept), kept, int(low.sum())


#: :func:`without_overhead`: azimuth sectors of the rays around the sensor ...
OVERHEAD_SECTORS = 720
#: ... range bins (m) ...
OVERHEAD_BIN = 0.5
#: ... the bound from the rank-th lowest ray over a place ...
OVERHEAD_RANK = 3
#: ... and how far (m) above it a cell's lowest point lies, plus a 45 degree rise across its
#: sector's width at its range, to be overhead ...
OVERHEAD_CLEARANCE = 0.5
#: ... with range bins out to this distance (m; farther rays share the last bin) ...
OVERHEAD_REACH = 400.0
#: ... from a sensor at least this high (m) over the median lowest point of the cells ...
OVERHEAD_SENSOR_HEIGHT = 0.3
#: ... this far from it (m, x/y)
OVERHEAD_GROUND_RING = (2.0, 10.0)


def overhead_cells(grid: HeightGrid, sensor_origin) -> np.ndarray:
    """(nx, ny) bool: the cells of ``grid`` whose lowest point lies above where rays of the
    scan from ``sensor_origin`` pass on their way to farther returns
    (:func:`o3d_terrain._kernels.free_space.overhead_cells`: by more than
    :data:`OVERHEAD_CLEARANCE` plus a 45 degree rise across the azimuth sector's width at the
    cell's range): the underside of a ceiling, a roof or a canopy that the sensor sees rays
    pass under, with no point lower in the cell. No ground can be there: the ground under a
    ray that went on lies below it."""
    ox, oy, oz = (float(v) for v in sensor_origin)
    x_min, x_max, y_min, y_max = grid.region
    farthest = math.hypot(max(abs(x_min - ox), abs(x_max - ox)),
                          max(abs(y_min - oy), abs(y_max - oy)))
    bins = int(min(farthest, OVERHEAD_REACH) / OVERHEAD_BIN) + 1
    return _free_space.overhead_cells(
        np.ascontiguousarray(grid.lowest, dtype=np.float64), grid.x_min, grid.y_min,
        grid.cell_size, ox, oy, oz, OVERHEAD_SECTORS, OVERHEAD_BIN, bins, OVERHEAD_RANK,
        OVERHEAD_CLEARANCE, 8.0 / OVERHEAD_SECTORS)


def cells_around(grid: HeightGrid, sensor_origin, radius: float):
    """(block, dx, dy): the slice of the grid's cells within ``radius`` of the sensor along x
    and y, and their centres' offsets from it as a column and a row; None when no cell lies
    there."""
    dx = grid.x_centers - float(sensor_origin[0])
    dy = grid.y_centers - float(sensor_origin[1])
    i = np.flatnonzero(np.abs(dx) <= radius)
    j = np.flatnonzero(np.abs(dy) <= radius)
    if i.size == 0 or j.size == 0:
        return None
    block = np.s_[i[0]:i[-1] + 1, j[0]:j[-1] + 1]
    return block, dx[block[0]][:, None], dy[block[1]][None, :]


def sensor_above_ground(grid: HeightGrid, sensor_origin) -> bool:
    """Whether ``sensor_origin`` lies at least :data:`OVERHEAD_SENSOR_HEIGHT` above the median
    lowest point of the grid's cells whose centres lie :data:`OVERHEAD_GROUND_RING` m from it
    (x/y): a place rays of the scan were cast from, not the ground beneath the sensor (a
    stereo rig's cloud in a vehicle frame has the origin there, a sensor found from a scan in
    a map frame is put there) nor a place without ground around it."""
    if grid.lowest is None:
        return False
    near, far = OVERHEAD_GROUND_RING
    around = cells_around(grid, sensor_origin, far)
    if around is None:
        return False
    block, dx, dy = around
    lowest = grid.lowest[block]
    reach = np.hypot(dx, dy)
    ring = np.isfinite(lowest) & (reach >= near) & (reach <= far)
    return bool(ring.any()) and \
        float(np.median(lowest[ring])) <= float(sensor_origin[2]) - OVERHEAD_SENSOR_HEIGHT


def without_overhead(grid: HeightGrid, positions: np.ndarray, sensor_origin
                     ) -> tuple[HeightGrid, np.ndarray, int]:
    """``(grid, positions, dropped)``: the grid without its :func:`overhead_cells` seen from
    ``sensor_origin`` (:func:`without_cells`: as made again from the points without theirs),
    the points without theirs and how many were left out; the inputs and 0 when there are
    none. A cell with a point below the bound keeps every point: ground under a canopy and
    the canopy over it are what the ground-layer samples and the terrain prior's canopy rule
    read. Only where the sensor stands over the ground around it
    (:func:`sensor_above_ground`); the grid's lowest points are needed (the inputs and 0
    otherwise)."""
    if not sensor_above_ground(grid, sensor_origin):
        return grid, positions, 0
    over = overhead_cells(grid, sensor_origin)
    if not over.any():
        return grid, positions, 0
    p = np.asarray(positions, dtype=np.float64)
    kept = _grid.points_outside_cells(p, grid.x_min, grid.y_min, grid.cell_size, grid.nx,
                                      grid.ny, over.reshape(-1))
    return without_cells(grid, over), kept, len(p) - len(kept)


def without_cells(grid: HeightGrid, cells: np.ndarray) -> HeightGrid:
    """``grid`` with the cells ``cells`` ((nx, ny) bool) emptied of their points: the grid
    :func:`requantize` makes from the points without theirs, array for array, with no pass
    over the points (a cell's sums hold its own points only; the cells that are not MEASURED
    are filled again from their MEASURED neighbours when the grid fills empty cells)."""
    where = np.flatnonzero(cells)

    def emptied(values, value):
        if values is None:
            return None
        values = values.copy()
        values.reshape(-1)[where] = value
        return values

    state = emptied(grid.state, INVALID)
    z = emptied(grid.z, 0.0)
    if grid.fill_empty:
        _grid.refill_around(z.reshape(-1), state.reshape(-1), grid.nx, grid.ny, where)
    plane_sample = None
    if grid.plane_sample is not None:  # eq. 1's sample wherever a cell is not MEASURED
        plane_sample = np.where(state == MEASURED, grid.plane_sample, z)
    return replace(grid, z=z, count=emptied(grid.count, 0), state=state,
                   lowest=emptied(grid.lowest, math.inf),
                   highest=emptied(grid.highest, -math.inf), mean=emptied(grid.mean, 0.0),
                   layer_count=emptied(grid.layer_count, 0),
                   layer_sum=emptied(grid.layer_sum, 0.0),
                   layer_above=emptied(grid.layer_above, math.inf),
                   level=emptied(grid.level, 0.0), plane_sample=plane_sample)


def _stray_points(x: np.ndarray, y: np.ndarray, cell_size: float) -> str | None:
    """For the error of a region from the cloud with too many cells: when at most
    :data:`STRAY_SHARE` of the finite points lie far outside the box of the others (their 1st
    to 99th percentiles, widened by half their span), and that box needs few enough cells,
    the text that says so and gives the box as a region; None otherwise."""
    finite = np.isfinite(x) & np.isfinite(y)
    xs, ys = x[finite], y[finite]
    if xs.size == 0:
        return None
    (x_lo, x_hi), (y_lo, y_hi) = np.percentile(xs, [1, 99]), np.percentile(ys, [1, 99])
    pad_x, pad_y = 0.5 * (x_hi - x_lo) + cell_size, 0.5 * (y_hi - y_lo) + cell_size
    box = (float(x_lo - pad_x), float(x_hi + pad_x), float(y_lo - pad_y), float(y_hi + pad_y))
    stray = np.count_nonzero((xs < box[0]) | (xs > box[1]) | (ys < box[2]) | (ys > box[3]))
    nx, ny = grid_shape(box, cell_size)
    if stray == 0 or stray > STRAY_SHARE * xs.size or nx * ny > MAX_CELLS:
        return None
    verb = "lies" if stray == 1 else "lie"
    return (f": {stray:,} of the {xs.size:,} points {verb} far outside the others, which fit in "
            f"region={tuple(round(v, 1) for v in box)}; if they are stray returns, drop them "
            f"or give that region (points outside it are left unlabelled)")


def with_cell_planes(grid: HeightGrid, positions: np.ndarray | None, *,
                     tilt_spread: float = 0.0) -> HeightGrid:
    """``grid`` with the cells' planes (``level``, ``plane_sample``; ``tilt_spread`` as in
    :func:`quantize_points`) of ``positions``, the points it was made from, gathered by a
    second quantization over its cells (its ``plane_sample`` is eq. 1's ``z`` wherever the
    grid's own cell is not MEASURED); ``grid`` itself when it already carries planes made
    with this ``tilt_spread``."""
    if (grid.plane_sample is not None and grid.level is not None
            and grid.tilt_spread == tilt_spread):
        return grid
    if positions is None:
        raise InputError("the cells' planes (cell_plane) need the points the grid was made "
                         "from; give the positions, or set cell_plane to false")
    x_min, x_max, y_min, y_max = grid.region
    planes = quantize_points(positions, cell_size=grid.cell_size,
                             region=(x_min, x_max, y_min, y_max), plane=True,
                             tilt_spread=tilt_spread)
    if planes.shape != grid.shape:
        raise InputError(f"the points give a {planes.shape} grid over the grid's region "
                         f"{grid.shape}")
    usable = (grid.state == MEASURED) & (planes.state == MEASURED)
    return replace(grid, level=np.where(usable, planes.level, grid.mean if grid.mean is not
                                        None else grid.z),
                   plane_sample=np.where(usable, planes.plane_sample, grid.z),
                   tilt_spread=float(tilt_spread))

