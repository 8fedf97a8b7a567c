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
cells go; measured in docs/algorithm.md, "Refit on the terrain points". Where the robust
surface was off (a roadside ditch its layout cannot follow, a sparse scanner's rings), its
labels were too, and the refit moves the surface: it is then made again from its own labels
(:data:`REFINE_REPEAT_MOVE`, :data:`REFINE_REPEATS`; docs/algorithm.md, "The refit made
again").

With an automatic layout the refit may use more control points than the robust fit: the
robust loop solves a dozen times and keeps :data:`o3d_terrain.terrain.AUTO_MAX_CONTROL_POINTS`
per axis, the refit solves once, so it takes the automatic layout up to
:data:`REFINE_MAX_CONTROL_POINTS` (one control point every 2 cells, at least 1 m; never
fewer than the robust fit's), its knots placed as the robust fit's were (adaptive ones from
the terrain cells). A wide frame's surface then follows terrain detail the robust layout's
spacing could not (measured in docs/algorithm.md, "A finer layout for the refit"). On a
vehicle's scan of steep relief (:func:`steep_share` at least :data:`STEEP_SHARE`, or a long
bench face: :data:`o3d_terrain.faces.FACE_RUN`) the caller gives the cap
:data:`STEEP_REFINE_MAX_CONTROL_POINTS` (docs/algorithm.md, "A finer refit on steep relief").

The sample of a cell is eq. 1 with the in-cell slope removed (the height of the least-squares
plane of its terrain points at the cell centre minus their spread about it), at least that
height minus ``noise_floor``: its points are all terrain, so eq. 1's "- sigma" (meant to
discount obstacle points) only has to cover the sensor's noise, and on noisy cells (a stereo
pair at range) the sample stays at the middle of the noise minus the floor instead of a
sigma below it. Cells whose plane is not significant (fewer than 3 points, no tilt) use eq. 1
about the mean the same way.
"""

from __future__ import annotations

import math

import numpy as np

from ._kernels import terrain as _tk
from .grid import MEASURED, HeightGrid, block_sums, quantize_points
from .segment import TerrainLabel, line_spacing_finder, segment_points
from .spline import GridBasis, TerrainSurface, clamped_knots
from .terrain import LAYOUT_MAX_ASPECT, default_control_points, knot_densities
from .threads import one_blas_thread

__all__ = ["refine_surface", "refit_layout", "refit_cap", "steep_share",
           "supported_control_points", "REFINE_MIN_CELLS",
           "REFINE_MAX_CONTROL_POINTS", "REFINE_REPEAT_MOVE", "REFINE_REPEATS",
           "STEEP_REFINE_MAX_CONTROL_POINTS", "STEEP_SHARE", "STEEP_SLOPE_DEG",
           "REFINE_CAP_POINTS", "REFINE_LIMIT_CONTROL_POINTS", "TOP_DOWN_SPAN_CELLS",
           "DENSITY_BLOCK", "density_cap"]

#: fewest grid cells with terrain points for a refit, in multiples of the control points
#: (on a vehicle's scan, of the control points whose support holds terrain points: a forward
#: field of view, a sparse scanner's rings leave most of the region's box unseen, and labels
#: are only wanted where the points are): fewer and the robust surface is kept (the penalty
#: alone would shape the refit; docs/algorithm.md, "Refit on the terrain points")
REFINE_MIN_CELLS = 1.0
#: most control points per axis of the refit's automatic layout: its one banded solve takes
#: 4.3 ms at 40 x 40 on a KITTI frame against 2.2 ms at 32 x 32 (docs/algorithm.md, "A finer
#: layout for the refit", with 48 and 64 measured)
REFINE_MAX_CONTROL_POINTS = 40
#: steep relief: at least STEEP_SHARE of a scan's measured cells lie where the robust
#: surface's normal turns more than STEEP_SLOPE_DEG from its median normal (slopes that change,
#: not a tilt; :func:`steep_share`); on a vehicle's scan of it the refit's automatic layout
#: takes up to STEEP_REFINE_MAX_CONTROL_POINTS per axis (docs/algorithm.md, "A finer refit on
#: steep relief") and the prior's automatic slope limit is
#: :data:`o3d_terrain.terrain.STEEP_MAX_SLOPE_DEG` (the stage RationalBSplineTerrain decides)
STEEP_REFINE_MAX_CONTROL_POINTS = 64
#: ... for up to REFINE_CAP_POINTS terrain points; a denser scan (a terrestrial laser
#: scanner's, a map of many frames) lets those caps grow with the fourth root of its terrain
#: points, up to REFINE_LIMIT_CONTROL_POINTS: the banded solve costs about the fourth power
#: of the control points per axis, the rest of the fit about the points, so the solve keeps
#: the share of the time it has on a frame of REFINE_CAP_POINTS (docs/algorithm.md, "Dense
#: scans: the refit's layout grows with the points")
REFINE_CAP_POINTS = 100_000
REFINE_LIMIT_CONTROL_POINTS = 128
#: a top-down scan's refit (an airborne tile, a photogrammetric cloud) also grows to about one
#: control point per TOP_DOWN_SPAN_CELLS grid cells of terrain points (the spacing
#: sqrt(that many cells' worth of area) over the ground the points cover, never under the
#: automatic layout's 2 cells or 1 m, nor beyond REFINE_LIMIT_CONTROL_POINTS per axis, the
#: limit of the dense scans' growth, unless the loop's own layout has more; twice the
#: :data:`REFINE_MIN_CELLS` a refit needs): the robust loop's layout of such a scan is set for
#: the labels of sparse tiles, and the DTM a survey takes from the surface wants the points'
#: own detail, which the thin-plate penalty keeps from the noise (docs/algorithm.md, "A
#: top-down scan's refit follows its points")
TOP_DOWN_SPAN_CELLS = 2.0
#: ... the ground the points cover measured in blocks of this many metres that hold any
DENSITY_BLOCK = 4.0
STEEP_SLOPE_DEG = 15.0
STEEP_SHARE = 0.2
#: the steep share is measured on at most this many of those cells (evenly picked), and so
#: is a refit's move
STEEP_SAMPLE = 2000
#: a refit that moves the surface by at least this many noise floors at the median terrain
#: cell is made again from its own labels (:func:`refine_surface`) ...
REFINE_REPEAT_MOVE = 0.4
#: ... at most this many more times
REFINE_REPEATS = 2


def refine_surface(surface: TerrainSurface, positions: np.ndarray, *, cell_size: float,
                   smoothing: float, noise_floor: float, sensor_origin=(0.0, 0.0, 0.0),
                   cell_plane: bool = True, max_control_points: int | None = None,
                   repeats: int = REFINE_REPEATS, vehicle: bool = False,
                   top_down: bool = False, line_spacing=None
                   ) -> tuple[TerrainSurface, int, int]:
    """``(surface, cells, refits)``: the surface's layout refitted to the points ``positions``
    that the automatic labelling against ``surface`` calls terrain (module docstring), the
    number of grid cells that held terrain points in the last refit made, and how many refits
    were made; ``(surface, cells, 0)`` unchanged when fewer than :data:`REFINE_MIN_CELLS` times
    the control points did.

    While a refit moves the surface by at least :data:`REFINE_REPEAT_MOVE` times
    ``noise_floor`` at the median terrain cell, the labels it was made from were those of a
    surface that was off by that much, so it is made again from its own labels, up to
    ``repeats`` more times (docs/algorithm.md, "The refit made again").

    cell_size: the grid cell (m) of the samples; smoothing: the thin-plate penalty relative to
    the mean data weight per control point (as the fit's); noise_floor: the largest amount a
    cell's sample sits below its terrain points' plane (m); sensor_origin: the sensor in the
    cloud's coordinates, for the labelling (its range term and its level); cell_plane: False =
    eq. 1 about the cells' means, not their planes (as the fit's option); max_control_points:
    None = the surface's layout and knots (a layout the caller chose), a number = the
    automatic layout up to that many per axis, more on a dense scan (:func:`refit_cap`,
    :func:`refit_layout`; a repeat keeps the first refit's layout and knots); vehicle: the
    points are a vehicle's scan, whose terrain cells :data:`REFINE_MIN_CELLS` weighs against
    the control points under its terrain points only (:func:`supported_control_points`);
    top_down: the points are a top-down scan (an airborne tile), whose automatic layout also
    grows to about one control point per :data:`TOP_DOWN_SPAN_CELLS` cells of terrain points
    (:func:`density_cap`); line_spacing: the
    :func:`~o3d_terrain.segment.scan_line_spacing` of ``positions`` seen from
    ``sensor_origin`` for the labels when the caller has it (a number, or a function that
    finds it when first asked: :func:`~o3d_terrain.segment.line_spacing_finder`); None =
    found once, when a refit's labels first need it."""
    p = np.ascontiguousarray(positions, dtype=np.float64)
    if line_spacing is None:  # the points' scan lines: the same for every refit's labels
        line_spacing = line_spacing_finder(p, sensor_origin)
    refits, cells = 0, 0
    for _ in range(1 + max(0, int(repeats))):
        refined, got, move = _refit(surface, p, cell_size, smoothing, noise_floor,
                                    sensor_origin, cell_plane, max_control_points, vehicle,
                                    top_down, line_spacing)
        if refined is surface:  # too few terrain cells: the surface so far stays
            cells = cells if refits else got
            break
        surface, cells, refits = refined, got, refits + 1
        if move < REFINE_REPEAT_MOVE * noise_floor:
            break
    return surface, cells, refits


def _refit(surface: TerrainSurface, p: np.ndarray, cell_size: float, smoothing: float,
           noise_floor: float, sensor_origin, cell_plane: bool,
           max_control_points: int | None, vehicle: bool = False, top_down: bool = False,
           line_spacing=None) -> tuple[TerrainSurface, int, float]:
    """One refit of :func:`refine_surface`: ``(refined, cells, move)``, move the median of
    |refined - surface| (m) over at most :data:`STEEP_SAMPLE` of the refit's terrain cells
    (evenly picked); ``(surface, cells, 0.0)`` when too few cells held terrain points."""
    # without the feet of objects: they lie within the threshold, and the cell samples (eq. 1
    # about the cells' planes) hardly see them, for 2 ms less per KITTI frame (docs/algorithm.md,
    # "Refit on the terrain points"); without the line-of-sight test, whose points the refit
    # then left to the penalty and which cost a pitched solid-state frame (docs/algorithm.md,
    # "Ground the sensor could not see"); the threshold from the noise below the surface
    # alone, whose precision the refit's points need (docs/algorithm.md, "The threshold on a
    # noisy ground")
    labels, _ = segment_points(surface, p, threshold=None, sensor_origin=sensor_origin,
                               foot_height=0.0, line_of_sight=False, centred_threshold=False,
                               line_spacing=line_spacing)
    terrain = np.compress(labels == TerrainLabel.TERRAIN, p, axis=0)  # ~3x faster than p[mask]
    n0, n1 = surface.control_points.shape
    if len(terrain) == 0:
        return surface, 0, 0.0
    region = surface.region
    grid = quantize_points(terrain, cell_size=cell_size, region=region, fill_empty=False,
                           plane=cell_plane, tilt_spread=noise_floor)
    measured = grid.state == MEASURED
    cells = np.flatnonzero(measured.ravel())
    under = supported_control_points(surface, grid) if vehicle else n0 * n1
    if cells.size < REFINE_MIN_CELLS * under:
        return surface, int(cells.size), 0.0
    # eq. 1 about the cell's plane (about the mean where the plane is not significant: the
    # grid's level and plane_sample are then the mean and eq. 1's sample), at least the
    # plane's height minus the noise floor (at the measured cells only)
    if cell_plane:
        sample = np.maximum(grid.plane_sample.ravel()[cells],
                            grid.level.ravel()[cells] - noise_floor)
    else:
        sample = np.maximum(grid.z.ravel()[cells], grid.mean.ravel()[cells] - noise_floor)
    x0, y0, z0 = surface.origin
    local = (region[0] - x0, region[1] - x0, region[2] - y0, region[3] - y0)
    layout, knots = (n0, n1), (surface.knots_x, surface.knots_y)
    if max_control_points is not None:
        most = refit_cap(max_control_points, len(terrain))
        if top_down:
            most = max(most, min(density_cap(grid, surface.degree),
                                 REFINE_LIMIT_CONTROL_POINTS))
        layout, knots = refit_layout(surface, grid, most, local, top_down)
    basis = GridBasis(grid.x_centers - x0, grid.y_centers - y0, layout, surface.degree, local,
                      knots)
    with one_blas_thread():  # a small banded solve: BLAS threads cost more than they give
        q = basis.solve_cells(cells, sample - z0, np.ones(cells.size), None, smoothing)
    ones = np.ones_like(q)
    refined = TerrainSurface(surface.degree, basis.knots_x, basis.knots_y, q, ones,
                             surface.origin, surface.cell_size)
    # the move, at the cells from the solve's basis: a repeat's surface before has the same
    # knots and R = 1, so the move is the basis at the cells times the control points' change
    picked = cells[::max(1, cells.size // STEEP_SAMPLE)]
    if not surface.is_rational and surface.control_points.shape == q.shape and \
            np.array_equal(surface.knots_x, basis.knots_x) and \
            np.array_equal(surface.knots_y, basis.knots_y):
        move = basis.evaluate_at_cells(q - surface.control_points, ones, picked)
    else:
        ix, iy = np.divmod(picked, grid.state.shape[1])
        move = basis.evaluate_at_cells(q, ones, picked) + z0 - \
            surface(grid.x_centers[ix], grid.y_centers[iy])
    move = np.abs(move[np.isfinite(move)])
    return refined, int(cells.size), float(np.median(move)) if move.size else 0.0


def steep_share(surface: TerrainSurface, grid: HeightGrid,
                slope_deg: float = STEEP_SLOPE_DEG) -> float:
    """The share of ``grid``'s measured cells (at most :data:`STEEP_SAMPLE` of them,
    evenly picked) at whose centre the normal of ``surface`` turns more than ``slope_deg``
    from the median of those normals: ground whose slope changes. A uniform tilt (a sensor
    pitched over a level street) scores 0 however steep it makes the ground in the cloud's
    frame; 0 with no measured cell."""
    cells = np.flatnonzero((grid.state == MEASURED).ravel())
    if cells.size == 0:
        return 0.0
    ix, iy = np.divmod(cells[::max(1, cells.size // STEEP_SAMPLE)], grid.state.shape[1])
    gx, gy = surface.gradient(grid.x_centers[ix], grid.y_centers[iy])
    ok = np.isfinite(gx) & np.isfinite(gy)
    if not ok.any():
        return 0.0
    normals = np.column_stack([-gx[ok], -gy[ok], np.ones(int(ok.sum()))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    median = np.median(normals, axis=0)
    median /= np.linalg.norm(median)
    return float(np.mean(normals @ median < np.cos(np.radians(slope_deg))))


def supported_control_points(surface: TerrainSurface, grid: HeightGrid) -> int:
    """How many of ``surface``'s control points lie under the cells of ``grid`` that hold
    points: the (degree + 1)^2 control points of each knot span a cell's extent reaches (the
    spans of :func:`o3d_terrain._kernels.bspline.find_span`: beyond the knots, the end
    spans). A cell within one span counts that span's control points, as its points would; a
    cell across a knot counts the spans on both sides, which its points may not all reach, so
    the count is never below that of the points themselves. The spans come from one search
    per grid row and column (``np.searchsorted``), not one per point, and the cells' spans
    and their control points from one pass over the grid
    (:func:`o3d_terrain._kernels.terrain.supported_count`): 0.12 ms instead of 3.5 ms for the
    68,000 terrain points of a KITTI frame."""
    x0, y0, _ = surface.origin
    degree = surface.degree
    n0, n1 = surface.control_points.shape
    half = 0.5 * grid.cell_size

    def reach(knots: np.ndarray, centres: np.ndarray, last: int) -> tuple[np.ndarray, np.ndarray]:
        lo = np.searchsorted(knots, centres - half, side="right") - 1
        hi = np.searchsorted(knots, centres + half, side="right") - 1
        return np.clip(lo, degree, last), np.clip(hi, degree, last)

    lo_x, hi_x = reach(surface.knots_x, grid.x_centers - x0, n0 - 1)
    lo_y, hi_y = reach(surface.knots_y, grid.y_centers - y0, n1 - 1)
    return int(_tk.supported_count(np.ascontiguousarray(grid.count), lo_x, hi_x, lo_y, hi_y,
                                   n0, n1, degree))


def refit_cap(most: int, terrain_points: int) -> int:
    """The refit's most control points per axis for a cap ``most`` and ``terrain_points``
    terrain points: ``most`` up to :data:`REFINE_CAP_POINTS` of them, then ``most`` times the
    fourth root of their ratio to it, at most :data:`REFINE_LIMIT_CONTROL_POINTS` (never
    below ``most``)."""
    if terrain_points <= REFINE_CAP_POINTS:
        return int(most)
    grown = int(round(most * (terrain_points / REFINE_CAP_POINTS) ** 0.25))
    return max(int(most), min(grown, REFINE_LIMIT_CONTROL_POINTS))


def density_cap(grid: HeightGrid, degree: int) -> int:
    """Control points per axis (along ``grid``'s longer side) of one every
    sqrt(:data:`TOP_DOWN_SPAN_CELLS` x the area per measured cell) metres, that area the
    blocks of about :data:`DENSITY_BLOCK` metres holding measured cells over their count
    (the grid's own cells would count a sparse tile's gaps between points as no ground)."""
    measured = grid.state == MEASURED
    cells = int(measured.sum())
    if cells == 0:
        return degree + 1
    step = max(1, int(round(DENSITY_BLOCK / grid.cell_size)))
    blocks = block_sums(measured, step) > 0
    area = float(blocks.sum()) * (step * grid.cell_size) ** 2
    spacing = math.sqrt(TOP_DOWN_SPAN_CELLS * area / cells)
    x_min, x_max, y_min, y_max = grid.region
    return int(round(max(x_max - x_min, y_max - y_min) / spacing)) + degree


def refit_layout(surface: TerrainSurface, grid: HeightGrid, most: int,
                 local: tuple[float, float, float, float], top_down: bool = False
                 ) -> tuple[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """``(layout, (knots_x, knots_y))`` of the refit: per axis the automatic layout of
    ``grid`` (:func:`o3d_terrain.terrain.default_control_points`, its axes each on its own on
    a ``top_down`` scan) with at most ``most`` control points, never fewer than ``surface``
    has; the surface's own knots when that is its layout, else knots over ``local`` (the
    region relative to the surface's origin) that are uniform where the surface's are and
    adaptive to the grid's measured cells where they are not
    (:func:`o3d_terrain.terrain.knot_densities`)."""
    n0, n1 = surface.control_points.shape
    degree = surface.degree
    auto = default_control_points(grid, degree, most=most,
                                  max_aspect=None if top_down else LAYOUT_MAX_ASPECT)
    layout = (max(n0, auto[0]), max(n1, auto[1]))
    if layout == (n0, n1):
        return layout, (surface.knots_x, surface.knots_y)
    densities = None
    if not (_uniform(surface.knots_x, n0, degree) and _uniform(surface.knots_y, n1, degree)):
        densities = knot_densities(grid, layout, degree)
    dx, dy = (None, None) if densities is None else densities
    return layout, (clamped_knots(layout[0], degree, local[0], local[1], dx),
                    clamped_knots(layout[1], degree, local[2], local[3], dy))


def _uniform(knots: np.ndarray, n_ctrl: int, degree: int) -> bool:
    """Whether a clamped knot vector's interior spans are equal (to 1e-9 of the domain)."""
    spans = np.diff(knots[degree:n_ctrl + 1])
    return bool(np.ptp(spans) <= 1e-9 * (knots[n_ctrl] - knots[degree]))
