"""The terrain surface as a raster (a DTM or a slope map) and as a GeoTIFF file.

A digital terrain model is what a survey delivers from a classified tile (PDAL's
``writers.gdal``, lidR's ``rasterize_terrain``): heights of the bare earth on a north-up grid
of square cells, in the tile's coordinate system. :func:`terrain_raster` samples the fitted
surface at the centres of cells aligned to multiples of the cell size; cells farther than
``max_gap`` from every point that supports the surface (the terrain points) hold no data, so
the raster does not claim ground where the cloud never saw any (beyond a forward sensor's
field of view, past the end of a strip). Under a building or a car the surface bridges the
gap, as a DTM's interpolation does. :func:`write_terrain_raster` writes it with
:func:`o3d_terrain.io.write_geotiff`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from scipy import ndimage

from ._kernels import grid as _grid
from .errors import InputError
from .grid import MAX_CELLS
from .io import LasSource, write_geotiff

#: the layers :func:`terrain_raster` makes: the terrain's height (m) and its slope (degrees)
LAYERS = ("height", "slope")
#: default ``max_gap`` (m): a cell farther than this from every supporting point has no data
MAX_GAP = 20.0


def terrain_raster(surface, *, cell_size: float, layer: str = "height", support=None,
                   max_gap: float | None = MAX_GAP) -> tuple[np.ndarray, float, float]:
    """``(values, x_min, y_min)``: ``values[ix, iy]`` of ``layer`` at the centres of square
    cells of ``cell_size`` m covering ``surface``'s region, the cells aligned to multiples of
    ``cell_size`` (a 1 m raster has its corners on whole metres), (``x_min``, ``y_min``) the
    lower-left corner of cell [0, 0]. NaN where the centre lies outside the surface's region
    and, with ``support`` ((N, >= 2) x, y of the points the surface stands on, e.g. its
    terrain points) and ``max_gap`` (m; None = no limit), where no supporting point lies
    within ``max_gap`` of the cell (measured between cells)."""
    if layer not in LAYERS:
        raise InputError(f"layer must be one of {LAYERS}, got {layer!r}")
    if not (isinstance(cell_size, (int, float)) and math.isfinite(cell_size) and cell_size > 0):
        raise InputError(f"cell_size must be a positive number of metres, got {cell_size!r}")
    if max_gap is not None and not (isinstance(max_gap, (int, float)) and math.isfinite(max_gap)
                                    and max_gap >= 0):
        raise InputError(f"max_gap must be a number of metres >= 0 or None, got {max_gap!r}")
    x_lo, x_hi, y_lo, y_hi = surface.region
    x_min = math.floor(x_lo / cell_size) * cell_size
    y_min = math.floor(y_lo / cell_size) * cell_size
    nx = max(1, math.ceil((x_hi - x_min) / cell_size))
    ny = max(1, math.ceil((y_hi - y_min) / cell_size))
    if nx * ny > MAX_CELLS:
        raise InputError(f"a raster of {nx} x {ny} cells of {cell_size} m over the surface's "
                         f"region is over {MAX_CELLS:,} cells; use a larger cell_size")
    xc = x_min + (np.arange(nx) + 0.5) * cell_size
    yc = y_min + (np.arange(ny) + 0.5) * cell_size
    x, y = np.meshgrid(xc, yc, indexing="ij")
    values = surface(x, y) if layer == "height" else surface.slope_deg(x, y)
    values = np.array(values, dtype=np.float64).reshape(nx, ny)
    if support is not None and max_gap is not None:
        p = np.asarray(support, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] < 2:
            raise InputError(f"support must be (N, 2) or (N, 3) points, got shape {p.shape}")
        # the grid's cell of each point (-1 outside, -2 non-finite; HeightGrid.cell_of)
        cells = _grid.cell_indices(np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]),
                                   float(x_min), float(y_min), float(cell_size), nx, ny)
        seen = np.zeros(nx * ny, bool)
        seen[cells[cells >= 0]] = True
        seen = seen.reshape(nx, ny)
        if not seen.any():
            values[:] = np.nan
        else:
            distance = ndimage.distance_transform_edt(~seen) * cell_size
            values[distance > max_gap] = np.nan
    return values, float(x_min), float(y_min)


def write_terrain_raster(path: str | os.PathLike, surface, *, cell_size: float | None = None,
                         layer: str = "height", support=None, max_gap: float | None = MAX_GAP,
                         source: LasSource | str | os.PathLike | None = None,
                         epsg: int | None = None) -> Path:
    """Write ``surface`` as a GeoTIFF raster (:func:`terrain_raster`, then
    :func:`o3d_terrain.io.write_geotiff`): ``layer`` "height" (a DTM, the cloud's height
    units) or "slope" (degrees), cells of ``cell_size`` m (None = the surface's grid cell
    size, else 1 m). ``support``: the points that carry the surface (its terrain points); no
    data farther than ``max_gap`` m from them. ``source``: the LAS/LAZ file the cloud came
    from, whose coordinate system and units the raster takes; ``epsg``: a projected
    coordinate system's code for a cloud without one::

        cloud = o3d_terrain.read_cloud("tile.laz")
        surface, inliers = o3d_terrain.segment_terrain(cloud)
        terrain = cloud.point.positions.numpy()[inliers]
        write_terrain_raster("dtm.tif", surface, cell_size=1.0, support=terrain,
                             source="tile.laz")
    """
    if cell_size is None:
        cell_size = surface.cell_size if surface.cell_size is not None else 1.0
    values, x_min, y_min = terrain_raster(surface, cell_size=cell_size, layer=layer,
                                          support=support, max_gap=max_gap)
    return write_geotiff(path, values, x_min, y_min, cell_size, heights=layer == "height",
                         source=source, epsg=epsg)
