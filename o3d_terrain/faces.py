"""Bench faces: long planar faces steeper than the terrain prior's slope limit.

The terrain prior (:mod:`o3d_terrain.terrain`) takes cells as terrain up to its slope limit,
45 degrees by default. The benches of an open pit or a quarry have faces of 55-75 degrees
between flat berms: they are terrain, but the default limit makes them walls, and the relief
rule that raises the limit on a vehicle's scan (:func:`o3d_terrain.refine.steep_share` on the
robust fit's coarse surface) does not see them: the surface the 45-degree prior lets through
stays flat under the faces, and a lidar on the pit floor does not see the berms above it.

The faces are seen in the points themselves. A cell of a face holds points on one plane,
tilted 50-75 degrees from the ground's normal, spread across the cell (not one scan line);
and a face runs on: its cells join into a run tens of metres long. What else stands that
steep is short or not planar: a wall or a car's side is vertical (90 degrees), a windscreen
or a bonnet covers a few cells, a hedge or a bush is rough. Measured in docs/algorithm.md,
"Bench faces" (the recorded SemanticKITTI frames, the synthetic scenes, the ``dem.tif`` sites
and a pit's benches).

:func:`planar_cells` finds the cells, :func:`face_run` measures their longest run against a
ground normal: the stage RationalBSplineTerrain gives the normal of the ground plane around
the sensor (:func:`o3d_terrain.terrain.sensor_ground_plane`, the plane the terrain prior
measures slope against on a tilted sensor), so that a tilted sensor's walls stay walls, and
fits with the limit :func:`face_limit` from the start when the run reaches :data:`FACE_RUN`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._kernels import grid as _grid
from .grid import MEASURED, HeightGrid
from .terrain import STEEP_MAX_SLOPE_DEG

__all__ = ["FaceCells", "planar_cells", "face_run", "face_limit", "FACE_MIN_DEG",
           "FACE_MAX_DEG", "FACE_RUN", "FACE_MARGIN_DEG", "FACE_MAX_LIMIT_DEG"]

#: a face cell's plane is tilted at least FACE_MIN_DEG and at most FACE_MAX_DEG from the
#: ground's normal: steeper than the default limit with a margin, short of a wall
FACE_MIN_DEG = 50.0
FACE_MAX_DEG = 75.0
#: a cell is a candidate when its points span at least FACE_DROP and at most FACE_SPAN metres
#: in height (a 50-75 degree face across a 0.5 m cell; a wall's cell spans more) ...
FACE_DROP = 0.3
FACE_SPAN = 3.0
#: ... it holds at least FACE_MIN_POINTS points, within FACE_RMS metres (root mean square)
#: of their plane and spread at least FACE_WIDTH metres (root mean square) along the plane's
#: second direction: a plane, not one scan line
FACE_MIN_POINTS = 5
FACE_RMS = 0.05
FACE_WIDTH = 0.05
#: the run of face cells (the diagonal of the bounding box of 8-connected face cells, in
#: metres) from which a scan holds a bench face
FACE_RUN = 10.0
#: the slope limit for a scan with a face: FACE_MARGIN_DEG above the faces' median tilt, at
#: most FACE_MAX_LIMIT_DEG (:func:`face_limit`)
FACE_MARGIN_DEG = 5.0
FACE_MAX_LIMIT_DEG = 70.0


@dataclass(frozen=True)
class FaceCells:
    """The planar cells of a grid that may be on a steep face: their flat indices into the
    grid's (nx, ny) cells and the upward unit normals of their points' planes."""

    cells: np.ndarray  # (k,) int64, increasing
    normals: np.ndarray  # (k, 3) float64, normal[:, 2] >= 0
    shape: tuple[int, int]
    cell_size: float


def planar_cells(grid: HeightGrid, positions: np.ndarray) -> FaceCells:
    """The cells of ``grid`` (made from ``positions``) whose points lie on one steep plane:
    MEASURED, spanning FACE_DROP to FACE_SPAN metres in height, at least FACE_MIN_POINTS
    points within FACE_RMS of their total-least-squares plane and spread FACE_WIDTH across
    it; the plane's normal is the points' covariance's least eigenvector
    (:func:`o3d_terrain._kernels.grid.cell_planes`)."""
    shape = (grid.nx, grid.ny)
    empty = FaceCells(np.zeros(0, np.int64), np.zeros((0, 3)), shape, grid.cell_size)
    if grid.lowest is None or grid.highest is None:
        return empty
    with np.errstate(invalid="ignore"):
        span = grid.highest - grid.lowest
    wanted = ((grid.state == MEASURED) & (grid.count >= FACE_MIN_POINTS)
              & (span >= FACE_DROP) & (span <= FACE_SPAN)).ravel()
    cells = np.flatnonzero(wanted)
    if cells.size == 0:
        return empty
    slot = np.full(wanted.size, -1, np.int64)
    slot[cells] = np.arange(cells.size)
    normals, thickness, width = _grid.cell_planes(
        np.ascontiguousarray(positions, dtype=np.float64), grid.x_min, grid.y_min,
        grid.cell_size, grid.nx, grid.ny, slot, cells.size,
        np.ascontiguousarray(grid.lowest, dtype=np.float64).ravel())
    flat = (thickness < FACE_RMS) & (width >= FACE_WIDTH)  # False for NaN
    normals = normals[flat]
    return FaceCells(cells[flat], normals, shape, grid.cell_size)


def face_run(faces: FaceCells, up) -> tuple[float, float]:
    """``(run, tilt)``: the longest run of face cells (m) and their median tilt (deg). Of the
    planar cells whose normal is tilted FACE_MIN_DEG to FACE_MAX_DEG from the unit vector
    ``up`` (the ground's normal), the run is the largest diagonal of the bounding box of
    8-connected ones, the tilt that of the cells of that run; (0, NaN) without any."""
    if faces.cells.size == 0:
        return 0.0, math.nan
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    tilt = np.degrees(np.arccos(np.clip(np.abs(faces.normals @ up), 0.0, 1.0)))
    steep = (tilt >= FACE_MIN_DEG) & (tilt <= FACE_MAX_DEG)
    if not steep.any():
        return 0.0, math.nan
    image = np.zeros(faces.shape[0] * faces.shape[1], bool)
    image[faces.cells[steep]] = True
    labels, count = ndimage.label(image.reshape(faces.shape), structure=np.ones((3, 3), bool))
    boxes = ndimage.find_objects(labels, count)
    runs = [math.hypot(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in boxes]
    longest = int(np.argmax(runs))
    members = labels.ravel()[faces.cells[steep]] == longest + 1
    return runs[longest] * faces.cell_size, float(np.median(tilt[steep][members]))


def face_limit(tilt_deg: float) -> float:
    """The prior's slope limit for faces of median tilt ``tilt_deg``: FACE_MARGIN_DEG above
    it, at least :data:`o3d_terrain.terrain.STEEP_MAX_SLOPE_DEG` and at most
    FACE_MAX_LIMIT_DEG (a truck's side must stay a wall)."""
    return float(min(max(STEEP_MAX_SLOPE_DEG, tilt_deg + FACE_MARGIN_DEG), FACE_MAX_LIMIT_DEG))
