"""The surface refitted to the terrain points: the last step of the robust terrain fit.

The robust fit (:mod:`o3d_terrain.terrain`) decides on grid cells which samples are terrain,
from one sample per cell and its residual to a surface that is itself still being fitted.
The labelling that follows it (:func:`o3d_terrain.segment.segment_points`) decides per point
and knows more: the misfit's local planes, the thresholds along the normal, the feet of
objects. :func:`refine_surface` labels the points against the robust surface with the
automatic rule (all but the feet of objects), then fits the same spline layout again by
plain least squares to the points labelled terrain alone: per cell of the grid the terrain
points' own sample, weight 1, the thin-plate penalty bridging the cells without terrain
points. The robust surface's wobble between sparse scan lines and its bias under noisy
cells go; measured in docs/algorithm.md, "Refit on the terrain points".

The sample of a cell is eq. 1 with the in-cell slope removed (the height of the least-squares
plane of its terrain points at the cell centre minus their spread about it), at least that
height minus ``noise_floor``: its points are all terrain, so eq. 1's "- sigma" (meant to
discount obstacle points) only has to cover the sensor's noise, and on noisy cells (a stereo
pair at range) the sample stays at the middle of the noise minus the floor instead of a
sigma below it. Cells whose plane is not significant (fewer than 3 points, no tilt) use eq. 1
about the mean the same way.
"""

from __future__ import annotations

import numpy as np

from .grid import MEASURED, quantize_points
from .segment import TerrainLabel, segment_points
from .spline import GridBasis, TerrainSurface
from .threads import one_blas_thread

__all__ = ["refine_surface", "REFINE_MIN_CELLS"]

#: fewest grid cells with terrain points for a refit, in multiples of the control points:
#: fewer and the robust surface is kept (the penalty alone would shape the refit)
REFINE_MIN_CELLS = 1.0


def refine_surface(surface: TerrainSurface, positions: np.ndarray, *, cell_size: float,
                   smoothing: float, noise_floor: float, sensor_origin=(0.0, 0.0, 0.0),
                   cell_plane: bool = True) -> tuple[TerrainSurface, int]:
    """``(surface, cells)``: the surface's layout refitted to the points ``positions`` that
    the automatic labelling against ``surface`` calls terrain (module docstring), and the
    number of grid cells that held terrain points; ``(surface, cells)`` unchanged when fewer
    than :data:`REFINE_MIN_CELLS` times the control points did.

    cell_size: the grid cell (m) of the samples; smoothing: the thin-plate penalty relative to
    the mean data weight per control point (as the fit's); noise_floor: the largest amount a
    cell's sample sits below its terrain points' plane (m); sensor_origin: the sensor in the
    cloud's coordinates, for the labelling (its range term and its level); cell_plane: False =
    eq. 1 about the cells' means, not their planes (as the fit's option)."""
    p = np.ascontiguousarray(positions, dtype=np.float64)
    # without the feet of objects: they lie within the threshold, and the cell samples (eq. 1
    # about the cells' planes) hardly see them, for 2 ms less per KITTI frame (docs/algorithm.md,
    # "Refit on the terrain points"); without the line-of-sight test, whose points the refit
    # then left to the penalty and which cost a pitched solid-state frame (docs/algorithm.md,
    # "Ground the sensor could not see")
    labels, _ = segment_points(surface, p, threshold=None, sensor_origin=sensor_origin,
                               foot_height=0.0, line_of_sight=False)
    terrain = np.compress(labels == TerrainLabel.TERRAIN, p, axis=0)  # ~3x faster than p[mask]
    n0, n1 = surface.control_points.shape
    if len(terrain) == 0:
        return surface, 0
    region = surface.region
    grid = quantize_points(terrain, cell_size=cell_size, region=region, fill_empty=False,
                           plane=cell_plane, tilt_spread=noise_floor)
    measured = grid.state == MEASURED
    cells = np.flatnonzero(measured.ravel())
    if cells.size < REFINE_MIN_CELLS * n0 * n1:
        return surface, int(cells.size)
    # eq. 1 about the cell's plane (about the mean where the plane is not significant: the
    # grid's level and plane_sample are then the mean and eq. 1's sample), at least the
    # plane's height minus the noise floor
    if cell_plane:
        sample = np.maximum(grid.plane_sample, grid.level - noise_floor)
    else:
        sample = np.maximum(grid.z, grid.mean - noise_floor)
    sample = sample.ravel()[cells]
    x0, y0, z0 = surface.origin
    local = (region[0] - x0, region[1] - x0, region[2] - y0, region[3] - y0)
    basis = GridBasis(grid.x_centers - x0, grid.y_centers - y0, (n0, n1), surface.degree, local,
                      (surface.knots_x, surface.knots_y))
    with one_blas_thread():  # a small banded solve: BLAS threads cost more than they give
        q = basis.solve_cells(cells, sample - z0, np.ones(cells.size), None, smoothing)
    refined = TerrainSurface(surface.degree, basis.knots_x, basis.knots_y, q, np.ones_like(q),
                             surface.origin, surface.cell_size)
    return refined, int(cells.size)
