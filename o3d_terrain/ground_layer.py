"""Terrain samples of cells that hold terrain under an object (a canopy, a wall, a person).

Eq. 1 of the paper, Z = max(min z, mean z - sigma), makes a cell's sample robust to low
outliers, but a cell holding ground returns *and* an object above them (airborne lidar under
a tree canopy, a vehicle lidar cell at the foot of a wall) gets a sample in between, lifted
by up to metres: the fit then bends up under every tree. Such a cell has a *ground layer*: a
group of points within a thin layer above its lowest point. When the layer holds at least two
points and at least ``min_fraction`` of the cell's points, while Z lies above the layer, the
cell's terrain sample becomes the mean height of the layer.

Why the two support conditions: a single low point (multipath, a low outlier) has no layer of
its own (one point), so eq. 1 keeps rejecting it; and in a cell of pure range noise (stereo
at range) the lowest point is the tail of the noise, with only a few per cent of the points
near it, so the sample stays eq. 1 and is not biased low. In simulated Gaussian cells
(layer 0.24 m) no cell is a candidate below σ ≈ 0.15 m; with σ 0.3-0.5 m and 10-20 points,
5-17 % of them still pass (two or three points make 20 %), and their sample drops by about
one σ, inside the robust fit's band below the surface; the synthetic stereo scenes change by
at most 0.001 m RMSE. Measured in docs/algorithm.md.

The layer thickness defaults to the tolerance of the terrain prior: 3 x noise_floor plus the
height spread of a max_slope_deg plane across 0.3 of a cell (0.24 m at 0.5 m cells, 45 deg),
so a cell on steep smooth terrain, whose points spread by the slope, is not split.
"""

from __future__ import annotations

import math

import numpy as np

from ._kernels import ground_layer as _gl
from .errors import InputError
from .grid import MEASURED, HeightGrid

__all__ = ["MIN_LAYER_FRACTION", "OVERHANG_CLEARANCE", "default_layer", "ground_layer_samples",
           "overhung_ground_cells"]

#: the smallest share of a cell's points its ground layer must hold
MIN_LAYER_FRACTION = 0.2

#: the fewest points of a ground layer (one point is an outlier, not a layer)
MIN_LAYER_POINTS = 2

#: free height (m) between a cell's ground layer and the lowest point above it that makes the
#: points above an overhang (a canopy) rather than an object standing in the cell: walls,
#: trunks, bushes and people return continuously from their base (a vehicle lidar's rings are
#: 1 m apart on a wall only beyond about 140 m)
OVERHANG_CLEARANCE = 1.0


def default_layer(cell_size: float, *, noise_floor: float = 0.03,
                  max_slope_deg: float = 45.0) -> float:
    """Ground-layer thickness (m): 3 x noise_floor + 0.3 x cell_size x tan(max_slope_deg)."""
    return 3.0 * noise_floor + 0.3 * cell_size * math.tan(math.radians(max_slope_deg))


def ground_layer_samples(grid: HeightGrid, positions: np.ndarray, *,
                         layer: float | None = None,
                         min_fraction: float = MIN_LAYER_FRACTION
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(samples, replaced): the grid's samples Z with the cells that hold a ground layer under
    an object set to the mean height of that layer, and the (nx, ny) bool mask of those cells.

    positions: the (N, 3) points the grid was made from (same coordinates); not read when
        the grid carries the statistics for this ``layer`` (``quantize_points(layer=...)``).
    layer: thickness above each cell's lowest point (m); None = :func:`default_layer`.
    min_fraction: share of the cell's points the layer must hold.
    """
    if grid.lowest is None:
        raise InputError("ground_layer_samples needs a grid with per-cell lowest points "
                         "(made by quantize_points)")
    if layer is None:
        layer = default_layer(grid.cell_size)
    if not (math.isfinite(layer) and layer > 0):
        raise InputError(f"layer must be a positive number of metres, got {layer!r}")
    if not (0.0 <= min_fraction <= 1.0):
        raise InputError(f"min_fraction must be in [0, 1], got {min_fraction!r}")
    if grid.layer_count is not None and grid.layer == layer:  # gathered by the grid's pass
        return _gl.ground_layer_from_sums(
            grid.z, grid.lowest, grid.count, grid.state == MEASURED, grid.layer_count,
            grid.layer_sum, float(layer), MIN_LAYER_POINTS, float(min_fraction))
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 3:
        raise InputError(f"positions must be (N, 3), got {p.shape}")
    return _gl.ground_layer_samples(
        np.ascontiguousarray(p), grid.x_min, grid.y_min, grid.cell_size,
        np.ascontiguousarray(grid.z, dtype=np.float64),
        np.ascontiguousarray(grid.lowest, dtype=np.float64),
        np.ascontiguousarray(grid.count), grid.state == MEASURED, float(layer),
        MIN_LAYER_POINTS, float(min_fraction))


def overhung_ground_cells(grid: HeightGrid, positions: np.ndarray, connected: np.ndarray,
                          compact: np.ndarray, samples: np.ndarray, *, layer: float,
                          tolerance: float, clearance: float = OVERHANG_CLEARANCE,
                          spread: np.ndarray | None = None, widen: float = 0.0
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(overhung, protected): the (nx, ny) bool cells of the terrain prior's ``connected``
    cells, not ``compact``, whose sample is their ground: the sample (``samples``, e.g. from
    :func:`ground_layer_samples`) lies within ``layer`` of the lowest point, that lowest point
    is at most ``tolerance`` above the lowest point of every measured 8-neighbour (nothing
    lower around it), and every point of the cell above the layer (if any) lies at least
    ``clearance`` above the layer's top (a canopy or an overhang over the ground, not an
    object standing on it); and ``compact | overhung``. Such a cell is ground, bare or under
    a canopy: its points need not all be terrain, or may be too few for the terrain prior's
    compact test, but its sample is its ground.

    positions: the (N, 3) points the grid was made from (same coordinates); read only when a
        candidate holds points at least ``clearance`` above its layer and the grid does not
        carry the statistics for this ``layer`` (``quantize_points(layer=...)``).
    spread: optional (nx, ny) float64 array set to ``widen`` on the overhung cells (in place).
    """
    if grid.lowest is None or grid.highest is None:
        raise InputError("overhung_ground_cells needs a grid with per-cell lowest and highest "
                         "points (made by quantize_points)")
    for name, value in (("layer", layer), ("tolerance", tolerance), ("clearance", clearance)):
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a finite number of metres >= 0, got {value!r}")
    shape = grid.z.shape
    if grid.layer_above is not None and grid.layer == layer:  # gathered by the grid's pass
        p = np.zeros((0, 3))
        above = np.ascontiguousarray(grid.layer_above, dtype=np.float64)
    else:
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] < 3:
            raise InputError(f"positions must be (N, 3), got {p.shape}")
        above = np.zeros((0, 0))
    for name, mask in (("connected", connected), ("compact", compact), ("samples", samples)):
        if np.shape(mask) != shape:
            raise InputError(f"{name} must have the grid's shape {shape}, got {np.shape(mask)}")
    if spread is None:
        spread = np.zeros(shape)
    elif spread.shape != shape or spread.dtype != np.float64 or not spread.flags.c_contiguous:
        raise InputError(f"spread must be a C-contiguous float64 array of shape {shape}")
    return _gl.overhung_ground(
        np.ascontiguousarray(p), grid.x_min, grid.y_min, grid.cell_size,
        np.ascontiguousarray(samples, dtype=np.float64),
        np.ascontiguousarray(grid.lowest, dtype=np.float64),
        np.ascontiguousarray(grid.highest, dtype=np.float64), above, grid.state, MEASURED,
        np.ascontiguousarray(connected, dtype=bool), np.ascontiguousarray(compact, dtype=bool),
        float(layer), float(tolerance), float(clearance), spread, float(widen))
