"""The terrain fit: iterative re-weighted rational B-spline fitting of a height grid.

Broggi et al. 2013, Algorithm V-B.1: start with few control points, fit, weigh samples by their
distance to the surface (eq. 3), derive control-point weights R from the sample weights W,
equalize samples that lie above the surface, add control points, repeat. Two methods:

- ``method="paper"``: the algorithm as printed, with the resolutions of docs/algorithm.md
  (denominator of eq. 2 without Q, equalization Z - dz / W, loop while samples still move).
  Kept so the measurements in docs/algorithm.md are reproducible.
- ``method="robust"`` (default): the same loop made robust where the printed method fails:
  bounded asymmetric weights (a monotone transform of eq. 3), a robust noise scale, equalization
  that clips outliers onto a band above the surface (no low bias), a rational fit consistent with
  R, coarse-to-fine growth of the control grid, and a thin-plate penalty so that control points
  without data under them continue the surface smoothly instead of running away; by default
  also a slope-limited terrain prior (:func:`terrain_prior_mask`) so that steep narrow terrain
  is not rejected as an obstacle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .errors import InputError
from ._kernels import ground as _ground
from ._kernels import terrain as _tk
from .grid import FILLED, MEASURED, HeightGrid, cells_around
from .ground_layer import default_layer, ground_layer_samples, overhung_ground_cells
from .noise import GridNoise, RangeNoise
from .spline import GridBasis, TerrainSurface, clamped_knots
from .threads import one_blas_thread

__all__ = ["fit_grid", "fit_grid_detailed", "TerrainFit", "IterationRecord",
           "default_control_points", "terrain_prior_mask", "sensor_ground_plane", "METHODS",
           "MAX_SLOPE_DEG", "STEEP_MAX_SLOPE_DEG", "STEEP_LIMIT_SHARE", "NOISE_FLOOR",
           "TOP_DOWN_MAX_CONTROL_POINTS", "LAYOUT_MAX_ASPECT", "KNOT_PLACEMENTS",
           "knot_densities"]

METHODS = ("robust", "paper")

#: the terrain prior's slope limit (deg): steeper faces are walls (a vehicle's, a building's)
#: and not terrain; raising it lets bench faces of pits and cuttings be terrain but connects
#: the walls of cars and buildings to the ground (docs/algorithm.md, "Steep faces")
MAX_SLOPE_DEG = 45.0
#: the slope limit the automatic choice takes on a vehicle's scan of strong relief: at least
#: STEEP_LIMIT_SHARE of its measured cells where the surface of the robust fit's last coarse
#: layout turns its normal more than 15 degrees from the median normal
#: (:func:`o3d_terrain.refine.steep_share`; the fit then starts again): a vehicle tilted by the
#: slope it stands on sees the slopes ahead of it steeper than they are (docs/algorithm.md,
#: "A steeper slope limit on strong relief")
STEEP_MAX_SLOPE_DEG = 60.0
STEEP_LIMIT_SHARE = 0.35

#: smallest noise threshold of the robust weights (m); also the least height spread a cell's
#: plane must give its points to replace eq. 1 (``cell_plane``)
NOISE_FLOOR = 0.03

#: most control points per axis chosen automatically (keeps the banded solve in milliseconds)
AUTO_MAX_CONTROL_POINTS = 32
#: ... on a top-down scan (an airborne tile: no points near the sensor), which is not fitted
#: at a vehicle's frame rate: a layout of one control point every 2 cells then follows terrain
#: up to about 45 m across (docs/algorithm.md, "Local planes and a finer layout on a top-down
#: scan")
TOP_DOWN_MAX_CONTROL_POINTS = 48

#: the automatic layout keeps the spacing of its control points along one axis at least
#: 1 / LAYOUT_MAX_ASPECT of that along the other (on a vehicle's scan): the per-axis cap
#: would otherwise make a narrow extent's spacing far finer across it than along it (a
#: forward field of view 76 x 33 m: 2.4 m along, 1.0 m across), and the surface then climbs
#: the hedges and walls along its sides; a 360 degree street frame (156 x 101 m, 5.4 and
#: 3.5 m apart) loses one control point across (docs/algorithm.md, "The layout's aspect on a
#: narrow scan")
LAYOUT_MAX_ASPECT = 1.5

#: knot placements of the robust fit: uniform spans, or narrower where there are more data
KNOT_PLACEMENTS = ("uniform", "adaptive")
#: share of an adaptive layout's knot density that follows the measured cells (the rest is
#: uniform, so no span grows beyond 1 / (1 - share) times the uniform spacing)
ADAPTIVE_KNOT_SHARE = 0.4

#: beyond AUTO_MAX_CONTROL_POINTS (extents over ~170 m: airborne tiles), the automatic layout
#: keeps control points at most this far apart (m), up to AUTO_LIMIT_CONTROL_POINTS per axis
#: (6 m apart up to ~1.13 km: a 1 km survey tile keeps the spacing of a 350 m one;
#: docs/algorithm.md, "Layout of wide tiles")
AUTO_MAX_SPACING = 6.0
AUTO_LIMIT_CONTROL_POINTS = 192

#: fewest points for which eq. 1 can tell a compact cell from one holding a vertical face
#: (with one or two points Z equals the lowest point whatever the points are)
MIN_COMPACT_POINTS = 3

#: compact neighbours a cell with fewer points needs to be called compact
SPARSE_SUPPORT = 2

#: a connected run of compact cells the coarse layouts dropped (weight under half their base)
#: that spans at least this far (m) is terrain the coarse layouts could not follow (a berm, a
#: ditch, an embankment seen from a high mount), not an object: the finest layout starts them
#: at their base weight again. Compact objects a vehicle meets (car and truck roofs, bushes)
#: span less (docs/algorithm.md, "Long terrain the coarse layouts dropped")
LONG_TERRAIN_SPAN = 10.0

#: a sensor tilted more than this (deg) against the ground around it has the terrain prior's
#: connectivity measure slope against that ground's plane: pitch or roll adds to every slope
#: the prior sees in the sensor's frame (docs/algorithm.md, "Held-out mountings"); below it,
#: none
PRIOR_LEVEL_MIN_TILT_DEG = 5.0

#: the ground plane under the sensor for PRIOR_LEVEL_MIN_TILT_DEG: from the lowest points of
#: the measured cells within this radius (m) of the sensor, at least this many cells
PRIOR_LEVEL_RADIUS = 15.0
PRIOR_LEVEL_MIN_CELLS = 50
#: ... leaving out the cells whose own slope lies more than this (deg) from the plane: a face
#: or an object's side in the radius, not the ground under the sensor (a bench face 4 m
#: ahead of a vehicle on a berm tilted the plane by 17 degrees; docs/algorithm.md, "Bench
#: faces")
PRIOR_LEVEL_MAX_SLOPE_DEG = 50.0
PRIOR_LEVEL_ROUNDS = 3
#: compact cells at the level of the ground the sensor stands on (anywhere in the grid) keep
#: their weight up to this much (m) further above the surface: where the surface rounds an
#: edge the sensor cannot see (the top of a raised road, a berm's lip) they would otherwise
#: become outliers and let it sag further (docs/algorithm.md, "A vehicle on a berm")
LEVEL_WIDEN = 0.1


@dataclass(frozen=True)
class IterationRecord:
    """One pass of the loop: layout, mean |error|, noise threshold, samples moved."""

    control_points: tuple[int, int]
    mean_error: float
    threshold: float
    moved: int


@dataclass(frozen=True, eq=False)
class TerrainFit:
    """The fitted surface plus what the fit did (for diagnostics and docs figures)."""

    surface: TerrainSurface
    iterations: list[IterationRecord] = field(default_factory=list)
    sample_weights: np.ndarray | None = None  # (m0, m1) final weights W (0 = unused)
    samples: np.ndarray | None = None  # (m0, m1) final samples after equalization (world z)
    equalized: np.ndarray | None = None  # (m0, m1) bool: sample was moved by equalization
    outliers: np.ndarray | None = None  # (m0, m1) bool: valid sample judged off the terrain
    noise: float = float("nan")  # robust noise scale of the samples at the end (m)
    # the robust loop's surface when ``surface`` is its refit to the terrain points
    # (RationalBSplineTerrain's refine, o3d_terrain.refine); None = surface is the loop's own
    robust_surface: TerrainSurface | None = None
    # the terrain prior's slope limit the fit used (deg; None without the prior)
    max_slope_deg: float | None = None
    # RationalBSplineTerrain: the share of the grid's measured cells on relief
    # (o3d_terrain.refine.steep_share) that chose the slope limit and the refit's layout: of
    # the robust fit's surface when the refit's automatic layout needed it and the share did
    # not raise the limit (a bench face may have), else of its last coarse layout's; None when
    # the stage needed neither (a top-down scan; a limit given and no automatic refit layout)
    relief_share: float | None = None
    # RationalBSplineTerrain: the longest run of bench-face cells (m, o3d_terrain.faces.face_run)
    # measured against the ground plane around the sensor before the fit; None when it was not
    # asked for (a limit given, no prior, a top-down scan)
    face_run: float | None = None
    # RationalBSplineTerrain's refine: how many refits made ``surface`` (o3d_terrain.refine:
    # one, more while a refit still moved the surface; 0 when too few cells held terrain
    # points); None without a refit
    refits: int | None = None
    # RationalBSplineTerrain on a vehicle's scan: how many isolated low returns the fit left
    # out (o3d_terrain.grid.without_low_returns; 0 when too few cells had one); None when it
    # did not look (a top-down scan, low_returns off, no points)
    low_returns: int | None = None
    # RationalBSplineTerrain on a vehicle's scan: how many points the fit left out in the cells
    # over where rays went on (o3d_terrain.grid.without_overhead); None when it did not look (a
    # top-down scan, free_space off, no points)
    overhead: int | None = None


def default_control_points(grid: HeightGrid, degree: int = 3,
                           spacing: float | None = None,
                           most: int = AUTO_MAX_CONTROL_POINTS,
                           max_aspect: float | None = LAYOUT_MAX_ASPECT) -> tuple[int, int]:
    """A control-point layout from the grid's extent: about one control point every
    ``spacing`` metres (default: 2 cells, at least 1 m), at most ``most`` per axis
    (default :data:`AUTO_MAX_CONTROL_POINTS`; :data:`TOP_DOWN_MAX_CONTROL_POINTS` for a
    top-down scan) unless that leaves them more than :data:`AUTO_MAX_SPACING` apart (then one
    every AUTO_MAX_SPACING metres, at most :data:`AUTO_LIMIT_CONTROL_POINTS`), and at least
    ``degree + 1``. With ``max_aspect`` (default :data:`LAYOUT_MAX_ASPECT`; None = each axis
    on its own, as on a top-down scan) an axis whose spacing that leaves finer than the other
    axis's over ``max_aspect`` takes fewer control points, spaced the other's over
    ``max_aspect``."""
    if spacing is None:
        spacing = max(2.0 * grid.cell_size, 1.0)
    x_min, x_max, y_min, y_max = grid.region
    extents = (x_max - x_min, y_max - y_min)
    out = []
    for extent, cells in zip(extents, (grid.nx, grid.ny)):
        n = int(round(extent / spacing)) + degree
        most_here = max(int(most), int(math.ceil(extent / AUTO_MAX_SPACING)) + degree)
        n = min(n, most_here, AUTO_LIMIT_CONTROL_POINTS, cells + degree - 1)
        out.append(max(n, degree + 1))
    if max_aspect is not None:
        widest = max(extent / (n - degree) for extent, n in zip(extents, out))
        finest = widest / float(max_aspect)
        out = [min(n, max(int(round(extent / finest)) + degree, degree + 1))
               for extent, n in zip(extents, out)]
    return out[0], out[1]


def fit_grid(grid: HeightGrid, **options) -> TerrainSurface:
    """Fit the terrain surface to a height grid; see :func:`fit_grid_detailed` for options."""
    return fit_grid_detailed(grid, **options).surface


def fit_grid_detailed(
    grid: HeightGrid,
    *,
    control_points: Sequence[int] | int | None = None,
    degree: int = 3,
    method: str = "robust",
    smoothing: float = 0.05,
    noise_floor: float = NOISE_FLOOR,
    filled_weight: float = 0.3,
    rational: bool = True,
    max_iterations: int = 30,
    terrain_prior: bool = True,
    max_slope_deg: float = MAX_SLOPE_DEG,
    gap_slope_deg: float = 20.0,
    max_obstacle_width: float = 40.0,
    positions: np.ndarray | None = None,
    ground_layer: bool = True,
    range_noise: RangeNoise | None = None,
    cell_plane: bool = False,
    sensor_origin: Sequence[float] | None = None,
    knots: str = "uniform",
    stop_after_coarse: Callable[[TerrainSurface], bool] | None = None,
) -> TerrainFit | None:
    """Fit a rational B-spline terrain surface to a :class:`HeightGrid`.

    control_points: (n0 + 1, n1 + 1) per axis at the end of the growth (one int: both axes);
        None = from the grid's extent (:func:`default_control_points`).
    degree: polynomial degree of the B-spline basis (the paper's "order 3" is degree 3).
    method: "robust" (default) or "paper" (Algorithm V-B.1 as printed, see module docstring).
    smoothing: thin-plate penalty relative to the mean data weight per control point (robust).
    noise_floor: smallest noise threshold in metres, so noise-free data still converges (robust).
    filled_weight: weight of FILLED cells relative to MEASURED ones (robust; paper uses 1).
    rational: derive control-point weights R from the sample weights (the paper's rational
        surface); False gives a plain B-spline.
    max_iterations: cap on loop passes.
    terrain_prior: (robust) slope-limited connectivity to the lowest cells
        (:func:`terrain_prior_mask`): connected compact cells (enough points, no vertical
        extent beyond the terrain's rise across the cell) above the surface get a noise
        threshold widened by half the rise to their compact neighbours
        (:func:`o3d_terrain._kernels.ground.compact_rise`), and are not equalized, so steep
        narrow terrain such as a berm is not rejected as an obstacle; their sample is
        max(eq. 1, mean z - noise_floor) (all their points are terrain) when the grid carries
        the mean (docs/algorithm.md). With ``positions`` and ``ground_layer``, connected cells whose
        sample is their ground layer, with nothing lower around them and any points above
        the layer at least :data:`o3d_terrain.ground_layer.OVERHANG_CLEARANCE` higher (ground
        under a canopy, :func:`o3d_terrain.ground_layer.overhung_ground_cells`) get the same
        protection with the threshold widened by half the layer, keeping their sample.
        False = the plain robust weights on eq. 1 samples.
    max_slope_deg: steepest terrain between neighbouring cells (degrees).
    gap_slope_deg: steepest terrain assumed across cells without data (degrees).
    max_obstacle_width: widest obstacle (m): the lowest cell within half this distance seeds
        the connectivity, so a roof narrower than this never seeds it.
    positions: (robust) the points the grid was made from; with ``ground_layer`` they give
        the cells that hold terrain under an object their ground layer as sample
        (:func:`o3d_terrain.ground_layer.ground_layer_samples`).
    ground_layer: (robust) use the ground-layer samples when ``positions`` are given.
    range_noise: (robust, with ``positions``) the sensor's range-dependent noise
        (:class:`o3d_terrain.noise.RangeNoise`, e.g. a stereo rig's): from the second layout
        on, eq. 1 samples discount only the spread the noise does not explain and cells of
        pure noise add their sample's noise to the weights' noise scale
        (:class:`o3d_terrain.noise.GridNoise`); None = one noise scale for the whole grid.
    cell_plane: (robust, with ``terrain_prior``) eq. 1 with the in-cell slope removed in the
        cells whose points are all terrain (the prior's compact cells): their sample is the
        height at the centre of the least-squares plane through their points minus the
        spread about it (``grid.plane_sample``, from
        ``quantize_points(plane=True, tilt_spread=noise_floor)`` as fit_terrain and the stage
        make it; eq. 1 where the tilt is not significant or spreads the points by less than
        ``tilt_spread``), at least that height minus ``noise_floor``; eq. 1 about the mean
        sits about rise / sqrt(12) below a sloped cell's terrain (docs/algorithm.md, "Eq. 1
        with the in-cell slope removed"). False here (a grid made without the planes);
        fit_terrain, segment_terrain and RationalBSplineTerrain default to True.
    sensor_origin: (robust, with ``terrain_prior``) the sensor's (x, y, z) in the grid's
        coordinates, or None. When the ground within PRIOR_LEVEL_RADIUS of it tilts by more
        than PRIOR_LEVEL_MIN_TILT_DEG (a pitched or rolled sensor, the cloud in its frame),
        the prior's connectivity measures slope against that ground's plane
        (:func:`sensor_ground_plane`); its compact test does not. The cells on that plane
        seed the connectivity (:func:`_sensor_seeds`: a vehicle stands on terrain), and the
        compact cells at that level anywhere keep their weight :data:`LEVEL_WIDEN` further
        above the surface. None = the grid's z is level, no seeds of the sensor's.
    knots: (robust) "uniform" spans, or "adaptive": spans narrower where the grid has more
        measured cells and wider where it has few, when the layout's uniform spacing is
        coarse for the grid (:func:`knot_densities`; the stage's default on a vehicle's
        scan).
    stop_after_coarse: (robust) called with the surface of the last coarse layout, before the
        finest one is fitted; when it returns True the fit stops there and returns None (the
        stage RationalBSplineTerrain fits again with a steeper slope limit on strong relief);
        not called when the growth has a single layout.
    """
    problems = []
    if knots not in KNOT_PLACEMENTS:
        problems.append(f"knots must be one of {KNOT_PLACEMENTS}, got {knots!r}")
    if method not in METHODS:
        problems.append(f"method must be one of {METHODS}, got {method!r}")
    if not (isinstance(degree, (int, np.integer)) and 1 <= degree <= 5):
        problems.append(f"degree must be an integer in [1, 5], got {degree!r}")
    for name, value, low in (("smoothing", smoothing, 0.0), ("noise_floor", noise_floor, 0.0),
                             ("filled_weight", filled_weight, 0.0),
                             ("max_obstacle_width", max_obstacle_width, 0.0)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= low):
            problems.append(f"{name} must be a finite number >= {low}, got {value!r}")
    for name, value in (("max_slope_deg", max_slope_deg), ("gap_slope_deg", gap_slope_deg)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and 0 < value < 90):
            problems.append(f"{name} must be a number of degrees in (0, 90), got {value!r}")
    if problems:
        raise InputError("fit_grid: " + "; ".join(problems))
    degree = int(degree)
    if not isinstance(grid, HeightGrid):
        raise InputError(f"fit_grid needs a HeightGrid, got {type(grid).__name__}")
    cell_plane = bool(cell_plane) and method == "robust"
    if cell_plane and (grid.plane_sample is None or grid.level is None):
        raise InputError("fit_grid: cell_plane needs a grid made with the cells' planes "
                         "(quantize_points(..., plane=True))")
    valid = grid.state != 0
    measured = grid.state == MEASURED
    needed = degree + 1
    if int(measured.sum()) < needed:
        raise InputError(
            f"too few valid cells: {int(measured.sum())} measured cell(s), the fit needs at "
            f"least {needed}; give more points, a larger region or a smaller cell_size"
        )
    if control_points is None:
        control_points = default_control_points(grid, degree)
    elif isinstance(control_points, (int, np.integer)):
        control_points = (control_points, control_points)  # one value for both axes
    n_max = tuple(int(v) for v in control_points)
    if len(n_max) != 2 or min(n_max) < degree + 1:
        raise InputError(f"control_points must be two integers >= degree + 1 = {degree + 1}, "
                         f"got {tuple(control_points)}")
    most = (grid.nx + degree, grid.ny + degree)  # knot spans at least one cell wide
    if n_max[0] > most[0] or n_max[1] > most[1]:
        # narrower spans have no data of their own: the solve only grows (500 x 500 control
        # points on an 80 m cloud at 0.5 m cells took minutes) and the penalty decides them
        raise InputError(
            f"control_points {n_max} are more than the grid can carry: its {grid.nx} x "
            f"{grid.ny} cells of {grid.cell_size:g} m allow at most {most} at degree "
            f"{degree} (each knot span at least one cell wide); give fewer control_points, "
            f"a smaller cell_size, or none for the default layout")
    x_min, x_max, y_min, y_max = grid.region
    if not (x_max > x_min and y_max > y_min):
        raise InputError(f"grid region {grid.region} is degenerate")
    origin = ((x_min + x_max) / 2, (y_min + y_max) / 2, float(np.median(grid.z[measured])))
    x0, y0, z0 = origin
    xl = grid.x_centers - x0
    yl = grid.y_centers - y0
    region_local = (x_min - x0, x_max - x0, y_min - y0, y_max - y0)
    samples = grid.z
    use_layer = positions is not None and ground_layer and method == "robust"
    if use_layer:
        layer = default_layer(grid.cell_size, noise_floor=noise_floor,
                              max_slope_deg=max_slope_deg)
        samples, _ = ground_layer_samples(grid, positions, layer=layer)
    grid_noise = None
    if range_noise is not None and positions is not None and method == "robust":
        grid_noise = GridNoise(grid, positions, range_noise, samples)
    if method == "paper":
        z = np.where(valid, samples - z0, 0.0)
        with one_blas_thread():  # small solves: BLAS threads cost more than they give
            fit = _fit_paper(z, valid, xl, yl, region_local, n_max, degree, rational,
                             max_iterations)
    else:
        prior = None
        compact = np.zeros((0, 0), bool)
        if terrain_prior:
            ground = None if sensor_origin is None else _sensor_ground(grid, sensor_origin)
            # the cells at the level of the ground the sensor stands on, anywhere in the grid;
            # those within PRIOR_LEVEL_RADIUS of it seed the prior
            level = _sensor_seeds(grid, sensor_origin, ground, 3.0 * noise_floor,
                                  radius=math.inf)
            connected, compact = _terrain_prior(
                grid, max_slope_deg, gap_slope_deg, max_obstacle_width, 3.0 * noise_floor,
                _level_plane(grid, sensor_origin, ground),
                None if level is None else level & _near_sensor(grid, sensor_origin))
            # compact cells above the surface: threshold widened by half the terrain's rise
            # across one cell (what a control grid of about 2 cells' spacing cannot follow),
            # that rise measured to compact neighbours only: a wall or a bush face next to
            # the cell is no evidence that the terrain climbs (docs/algorithm.md, "Sparse
            # scanners")
            low = grid.lowest if grid.lowest is not None else grid.z
            spread = 0.5 * _ground.compact_rise(
                np.ascontiguousarray(low, dtype=np.float64), compact, float(grid.cell_size),
                math.tan(math.radians(max_slope_deg)))
            if level is not None:  # the ground at the sensor's level (LEVEL_WIDEN)
                spread = spread + np.where(level & compact, LEVEL_WIDEN, 0.0)
            protected = compact
            if use_layer and grid.highest is not None:
                # ground under a canopy: connected cells whose sample is their ground layer,
                # nothing lower around them and a free gap above (docs/algorithm.md, "Ground
                # under a canopy"); widened by half the layer (its points' spread about the
                # sample), not equalized; their sample stays the layer's (not the cell mean)
                _, protected = overhung_ground_cells(
                    grid, positions, connected, compact, samples, layer=layer,
                    tolerance=3.0 * noise_floor, spread=spread, widen=0.5 * layer)
            prior = (protected, spread, compact)
        if cell_plane and terrain_prior:
            # eq. 1 about the cell's plane where all its points are terrain (the prior's
            # compact cells): on a slope eq. 1 about the mean sits about rise / sqrt(12) low,
            # while in a cell holding an object's foot or wall the plane would tilt towards
            # the object and lift the sample (measured: planes in every cell cost a LAS tile
            # with buildings 12 F1 points; docs/algorithm.md)
            samples = np.where(compact, grid.plane_sample, samples)
        # samples z - z0 (0 where invalid) and base weights (1 measured, filled_weight filled);
        # with the prior and the grid's mean, compact cells take max(z, mean - noise_floor):
        # all points of a compact cell are terrain, and eq. 1's "- sigma" (meant to discount
        # obstacle points) would only lower the sample by the terrain's relief inside the cell
        # (0.29 rise on a plane); subtract at most the sensor's noise floor
        # (with cell_plane: at least the plane's height at the cell centre - noise_floor)
        use_mean = terrain_prior and grid.mean is not None
        centre = grid.level if cell_plane and terrain_prior else grid.mean
        z, base = _tk.robust_inputs(
            grid.state, np.ascontiguousarray(samples, dtype=np.float64),
            centre if use_mean else np.zeros((0, 0)), compact if use_mean else
            np.zeros((0, 0), bool), z0, noise_floor, filled_weight, MEASURED, FILLED)
        densities = knot_densities(grid, n_max, degree) if knots == "adaptive" else None
        on_coarse = None
        if stop_after_coarse is not None:
            def on_coarse(basis, q, r):
                return stop_after_coarse(
                    TerrainSurface(degree, basis.knots_x, basis.knots_y, q, r, origin))
        with one_blas_thread():  # small banded solves: BLAS threads cost more than they give
            fit = _fit_robust(z, base, measured, xl, yl, region_local, n_max, degree,
                              rational, smoothing, noise_floor, max_iterations, prior,
                              grid_noise, z0, grid.state, float(grid.cell_size), densities,
                              on_coarse)
        if fit is None:
            return None
    q, r, basis, weights, samples, equalized, outliers, records, noise = fit
    if method == "paper":
        samples = np.where(valid, samples + z0, np.nan)
    surface = TerrainSurface(degree, basis.knots_x, basis.knots_y, q, r, origin)
    return TerrainFit(surface, records, weights, samples, equalized, outliers, noise,
                      max_slope_deg=float(max_slope_deg)
                      if terrain_prior and method == "robust" else None)


def terrain_prior_mask(grid: HeightGrid, *, max_slope_deg: float = MAX_SLOPE_DEG,
                       gap_slope_deg: float = 20.0, max_obstacle_width: float = 40.0,
                       tolerance: float = 0.09) -> tuple[np.ndarray, np.ndarray]:
    """(connected, compact) masks over the grid's cells, from the lowest point of each cell.

    connected: MEASURED cells reachable from seed cells by 8-neighbour steps that climb at most
    cell_size * tan(max_slope_deg) + tolerance (descending is free; empty cells are crossed at
    the height of the lowest gap_slope_deg cone through the data). Seeds: measured cells that
    are the lowest within max_obstacle_width / 2. Obstacle walls are jumps steeper than the
    limit, so roofs and tops are not connected; steep smooth terrain is.
    Cells above the max-slope cone of another cell (Vosselman's slope filter: the top of a
    wall) are neither seeds nor crossed.
    compact: connected cells whose points could all lie on the terrain around them:
    - at least :data:`MIN_COMPACT_POINTS` points (with one or two, eq. 1 equals the lowest
      point whatever the points are, so the next test says nothing; but see below);
    - the sample (eq. 1) within tolerance plus half the terrain's rise across the cell (see
      below) of the lowest point (no wall or person filling the cell);
    - when the grid carries the highest point per cell: highest - lowest within tolerance plus
      the terrain's rise across one cell, cell_size (|gx| + |gy|) of the slopes from the
      cell's lowest point to its neighbours' along x and along y (at most tan(max_slope_deg)
      together; :func:`o3d_terrain._kernels.ground.neighbour_rise`): what a plane spans from
      corner to corner of a cell, whatever its direction to the grid. A cell on a wall or a bush
      face holds points far above its lowest while its neighbours' lowest points (the ground
      along and in front of the face) are level with its own.
    A connected cell with fewer points (and no larger extent) is compact when at least
    :data:`SPARSE_SUPPORT` of its 8-neighbours are compact by the rules above and its lowest
    point is no more than tolerance above the highest of theirs: it lies within the terrain
    they span (a slope seen at a grazing angle), not above it (a step of a wall).
    """
    return _terrain_prior(grid, max_slope_deg, gap_slope_deg, max_obstacle_width, tolerance)


def sensor_ground_plane(grid: HeightGrid, sensor_origin: Sequence[float], *,
                        radius: float = PRIOR_LEVEL_RADIUS,
                        min_cells: int = PRIOR_LEVEL_MIN_CELLS) -> tuple[float, float]:
    """Gradient (dz/dx, dz/dy) of the ground plane around the sensor: a least-squares plane
    through the lowest points of the measured cells within ``radius`` m (x/y) of
    ``sensor_origin``, without the cells whose own slope (differences of the lowest points
    with the neighbours') lies more than PRIOR_LEVEL_MAX_SLOPE_DEG from the plane (faces,
    objects' sides; measured from level for the first fit, from the plane before for the
    next), refitted PRIOR_LEVEL_ROUNDS - 1 times, also without the cells more than twice the
    robust spread (plus 5 cm) above it (objects). (0, 0) with fewer than ``min_cells`` cells
    there (an airborne tile's sensor outside the grid)."""
    gx, gy, _ = _sensor_ground(grid, sensor_origin, radius, min_cells)
    return gx, gy


def _sensor_ground(grid: HeightGrid, sensor_origin, radius: float = PRIOR_LEVEL_RADIUS,
                   min_cells: int = PRIOR_LEVEL_MIN_CELLS) -> tuple[float, float, float]:
    """(gx, gy, height at the sensor's x/y) of :func:`sensor_ground_plane`; the height is NaN
    where the plane is not found."""
    low = grid.lowest if grid.lowest is not None else grid.z
    measured = (grid.state == MEASURED) & np.isfinite(low)
    gx, gy, height = _ground.ground_plane(
        np.ascontiguousarray(low, dtype=np.float64), measured, grid.x_centers,
        grid.y_centers, float(sensor_origin[0]), float(sensor_origin[1]), float(radius),
        math.cos(math.radians(PRIOR_LEVEL_MAX_SLOPE_DEG)), int(min_cells), PRIOR_LEVEL_ROUNDS)
    if math.isfinite(height):
        height = _ground_height(grid, low, measured, sensor_origin, gx, gy, radius, min_cells)
    return float(gx), float(gy), float(height)


def _ground_height(grid, low, measured, sensor_origin, gx, gy, radius, count):
    """The plane's height at the sensor: the median of the lowest points (less the plane's
    tilt) of the ``count`` measured cells nearest the sensor whose points rise less than a
    PRIOR_LEVEL_MAX_SLOPE_DEG plane across a cell: the ground the sensor stands on, where
    the least-squares plane through two levels (a raised road above the ground beside it)
    would sit between them."""
    around = cells_around(grid, sensor_origin, radius)
    if around is None:
        return math.nan
    block, bx, by = around
    ok = measured[block].copy()
    if grid.highest is not None:
        rise = grid.cell_size * math.tan(math.radians(PRIOR_LEVEL_MAX_SLOPE_DEG))
        ok &= grid.highest[block] - low[block] <= rise
    d2 = (bx * bx + by * by)[ok]
    if d2.size < count:
        return math.nan
    level = (low[block] - gx * bx - gy * by)[ok]
    return float(np.median(level[np.argpartition(d2, count - 1)[:count]]))


def _level_plane(grid: HeightGrid, sensor_origin, ground=None) -> np.ndarray | None:
    """The plane of :func:`sensor_ground_plane` over the grid's cells (heights relative to
    the sensor's position) when it tilts by more than PRIOR_LEVEL_MIN_TILT_DEG; None
    otherwise or without ``sensor_origin``. The prior's connectivity takes it off the cells'
    lowest points, so that it measures slope against the ground the sensor stands on.
    ``ground``: :func:`_sensor_ground`'s result when already found."""
    if sensor_origin is None:
        return None
    gx, gy, _ = _sensor_ground(grid, sensor_origin) if ground is None else ground
    if math.degrees(math.atan(math.hypot(gx, gy))) <= PRIOR_LEVEL_MIN_TILT_DEG:
        return None
    return gx * (grid.x_centers - float(sensor_origin[0]))[:, None] + \
        gy * (grid.y_centers - float(sensor_origin[1]))[None, :]


def _near_sensor(grid: HeightGrid, sensor_origin,
                 radius: float = PRIOR_LEVEL_RADIUS) -> np.ndarray:
    """The cells whose centre lies within ``radius`` (x/y) of the sensor (the test of
    :func:`_sensor_seeds`, on the block of :func:`o3d_terrain.grid.cells_around`)."""
    near = np.zeros(grid.shape, bool)
    around = cells_around(grid, sensor_origin, radius)
    if around is not None:
        block, dx, dy = around
        near[block] = dx * dx + dy * dy <= radius * radius
    return near


def _sensor_seeds(grid: HeightGrid, sensor_origin, ground, tolerance: float,
                  radius: float = PRIOR_LEVEL_RADIUS) -> np.ndarray | None:
    """The measured cells within ``radius`` of the sensor whose lowest point lies on the
    ground plane it stands on (:func:`_sensor_ground`): at most ``tolerance`` above it, and
    below it by at most ``tolerance`` plus the plane's rise across half a cell (a cell's
    lowest point on a slope). A vehicle stands on terrain, so they seed the prior's
    connectivity: on a berm or a plateau whose edges the sensor cannot see, the lowest cells
    around (the floor below) would not reach them. With ``radius`` inf: the cells at that
    level anywhere, which :data:`LEVEL_WIDEN` widens. None without a sensor or a plane."""
    if sensor_origin is None or ground is None or not math.isfinite(ground[2]):
        return None
    gx, gy, height = ground
    low = grid.lowest if grid.lowest is not None else grid.z
    seeds = np.zeros(grid.shape, bool)
    around = cells_around(grid, sensor_origin, radius)
    if around is None:
        return seeds
    block, dx, dy = around
    off = low[block] - (height + gx * dx + gy * dy)
    drop = tolerance + 0.5 * grid.cell_size * (abs(gx) + abs(gy))
    seeds[block] = ((grid.state[block] == MEASURED) & (dx * dx + dy * dy <= radius * radius)
                    & (off <= tolerance) & (off >= -drop))
    return seeds


def _terrain_prior(grid, max_slope_deg, gap_slope_deg, max_obstacle_width, tolerance,
                   plane=None, sensor_seeds=None):
    """(connected, compact) of :func:`terrain_prior_mask`. The fit widens compact cells by
    :func:`o3d_terrain._kernels.ground.compact_rise`, not by the rise
    :func:`o3d_terrain._kernels.ground.compact_cells` tests them with. ``plane``: the ground
    plane under a tilted sensor over the cells (:func:`_level_plane`), taken off the lowest
    points for the connectivity's slope tests only; the compact test stays on the grid's
    heights, whose cells' own extents (highest - lowest) hold the tilt's rise across the cell,
    so its rise to the neighbours must hold it too (levelled, it dropped a 5-degree stereo
    frame's compact cells by a quarter)."""
    measured = grid.state == MEASURED
    lowest = grid.lowest if grid.lowest is not None else grid.z
    low = np.where(measured & np.isfinite(lowest), lowest, np.inf)
    measured = np.isfinite(low)
    c = float(grid.cell_size)
    step = math.tan(math.radians(max_slope_deg))
    radius = max(1, int(round(max_obstacle_width / 2 / c)))
    slope_low = low if plane is None else low - plane  # inf stays inf where not measured
    # the gap envelope, walls (above the slope cone of a neighbour) not crossed, seeds
    # (window_min) not on walls: in one kernel
    crossed, seeds = _ground.prior_seeds(slope_low, measured, c,
                                         math.tan(math.radians(gap_slope_deg)), step,
                                         float(tolerance), radius)
    if sensor_seeds is not None:  # the ground the vehicle stands on, where it is no wall
        seeds |= sensor_seeds & measured & np.isfinite(crossed)
    connected = measured & _ground.connected_terrain(crossed, seeds, c, step, float(tolerance))
    # rise: the terrain's rise across one cell, what points on the terrain may span inside it.
    # Eq. 1 gives Z = max(lowest, mean - sigma), which equals the lowest point for any cell
    # with one or two points (mean - sigma of two values is the lower one): such a cell (one
    # ring crossing it, e.g. the slanted line of a tilted ring over a wall or a bush) carries
    # no evidence of its own; it is compact only when it lies within the terrain spanned by at
    # least two compact neighbours, not above the highest of their lowest points (a step of a
    # wall or a bush face is). On a slope Z sits above the lowest point (about 0.21 rise for
    # points spread evenly over a plane), hence half the rise is allowed. Eq. 1 cannot see a
    # vertical extent carried by a few high points; highest - lowest can.
    use_highest = grid.highest is not None
    compact, _ = _ground.compact_cells(
        low, grid.z, grid.highest if use_highest else low, grid.count, connected, c, step,
        float(tolerance), MIN_COMPACT_POINTS, SPARSE_SUPPORT, use_highest)
    return connected, compact


# -------------------------------------------------------------------------------------------
# the two loops


def remap_weights(w: np.ndarray, valid: np.ndarray, basis: GridBasis,
                  empty: float = 1.0) -> np.ndarray:
    """Control-point weights R from sample weights W: W averaged over the valid samples in each
    control point's support (the basis functions as averaging kernels), i.e. W downsampled onto
    the control grid. Control points with no valid sample under them get ``empty``."""
    num = basis.project(np.where(valid, w, 0.0))
    den = basis.project(valid.astype(np.float64))
    return np.where(den > 1e-9, num / np.maximum(den, 1e-12), empty)


def _fit_paper(z, valid, xl, yl, region_local, n_max, degree, rational, max_iterations):
    """Algorithm V-B.1 as printed (resolutions in docs/algorithm.md)."""
    w_cap = 1e3  # eq. 3 is infinite at dz = 0; the printed method needs a cap
    p = z.copy()
    w = valid.astype(float)
    n = [degree + 1, degree + 1]
    r_samples = None  # W of the previous pass, remapped onto each new layout
    records = []
    equalized = np.zeros(z.shape, bool)
    iteration = 0
    while True:
        iteration += 1
        basis = GridBasis(xl, yl, n, degree, region_local)
        r = np.ones((n[0], n[1])) if (r_samples is None or not rational) else \
            remap_weights(r_samples, valid, basis)
        q = basis.solve_two_pass(p, w)  # spline_fitting(P, W, d, dn0, dn1)
        s = basis.evaluate(q, r)
        dz = p - s
        mean_error = float(np.abs(dz[valid]).mean())  # linear_mean(|P - S|)
        th = max(mean_error, 1e-12)
        alpha = float(iteration)
        with np.errstate(divide="ignore", over="ignore"):
            wn = 1.0 + (np.abs(dz) / th) ** (-alpha)  # eq. 3
        wn = np.where(valid, np.minimum(wn, w_cap), 0.0)
        w = wn
        r_samples = w
        r = remap_weights(w, valid, basis) if rational else np.ones_like(q)
        s = basis.evaluate(q, r)
        dz = p - s
        move = valid & (dz > 0)
        previous = p.copy()
        p = np.where(move, p - dz / np.where(w > 0, w, 1.0), p)  # equalization, see docs
        equalized |= move
        moved = int((np.abs(p - previous) > 1e-6).sum())
        records.append(IterationRecord((n[0], n[1]), mean_error, th, moved))
        grow = n[0] < n_max[0] or n[1] < n_max[1]
        if not grow or moved == 0 or iteration >= max_iterations:
            break
        n = [min(n[0] + 1, n_max[0]), min(n[1] + 1, n_max[1])]
    basis = GridBasis(xl, yl, n_max, degree, region_local)
    q = basis.solve_two_pass(p, w)
    r = remap_weights(w, valid, basis) if rational else np.ones_like(q)
    s = basis.evaluate(q, r)
    th = records[-1].threshold
    outliers = valid & (z - s > 2 * th)
    return q, r, basis, w, p, equalized, outliers, records, th


def knot_densities(grid: HeightGrid, control_points: Sequence[int], degree: int = 3, *,
                   share: float | None = None, min_spacing: float | None = None
                   ) -> tuple[np.ndarray | None, np.ndarray | None] | None:
    """Knot densities of an adaptive layout (:func:`o3d_terrain.spline.clamped_knots`), one
    weight per grid column along x and per grid row along y (None along an axis that keeps
    uniform knots), or None for uniform knots on both.

    Part of the density follows the measured cells' share in each column, the rest is
    uniform; no span is narrower than ``min_spacing`` (default 2 cells: the weights are
    capped and the excess spread over the others). The part that follows the data grows with
    how far the uniform spacing exceeds ``min_spacing``: 0 up to 1.5 times it (a layout that
    already resolves what the grid holds stays uniform), ``share`` (default
    :data:`ADAPTIVE_KNOT_SHARE`) from 3 times it (a wide frame whose layout the control-point
    cap made coarse)."""
    share = ADAPTIVE_KNOT_SHARE if share is None else float(share)
    if min_spacing is None:
        min_spacing = 2.0 * grid.cell_size
    measured = grid.state == MEASURED
    x_min, x_max, y_min, y_max = grid.region
    out = []
    for axis, extent in ((0, x_max - x_min), (1, y_max - y_min)):
        marginal = measured.sum(axis=1 - axis).astype(np.float64)
        bins = marginal.size
        n_spans = int(control_points[axis]) - degree
        coarse = extent / n_spans / min_spacing  # the uniform spacing in units of the least
        follow = share * min(max((coarse - 1.5) / 1.5, 0.0), 1.0)
        # a span holds 1 / n_spans of the density; min_spacing metres hold at most that
        cap = grid.cell_size / (n_spans * min_spacing)
        if follow <= 0.0 or cap * bins <= 1.0 + 1e-9 or not marginal.sum() > 0:
            out.append(None)
            continue
        d = (1.0 - follow) / bins + follow * marginal / marginal.sum()
        for _ in range(64):
            over = d > cap
            if not over.any():
                break
            excess = float((d[over] - cap).sum())
            d[over] = cap
            d[~over] += excess * d[~over] / d[~over].sum()
        out.append(d)
    if out[0] is None and out[1] is None:
        return None
    return out[0], out[1]


def _layouts(n_max, degree):
    """Coarse-to-fine control-point counts: halve the spacing at each level up to n_max."""
    levels = []
    for a in range(2):
        seq = [n_max[a]]
        while seq[-1] > 2 * (degree + 1):
            seq.append((seq[-1] - degree) // 2 + degree)
        levels.append(seq[::-1])
    depth = max(len(levels[0]), len(levels[1]))
    out = []
    for k in range(depth):
        out.append(tuple(
            levels[a][max(0, k - (depth - len(levels[a])))] for a in range(2)
        ))
    return [(max(degree + 1, min(a, n_max[0])), max(degree + 1, min(b, n_max[1])))
            for a, b in out]


def _fit_robust(z, base, measured, xl, yl, region_local, n_max, degree, rational, smoothing,
                noise_floor, max_iterations, prior=None, grid_noise=None, z0=0.0, state=None,
                cell_size=0.0, densities=None, on_coarse=None):
    """The robust loop on samples ``z`` (relative to z0) and base weights ``base``; returns
    (Q, R, basis, W, samples, equalized, outliers, records, noise) with the samples in world
    z on the cells of ``state`` != 0 (default: base > 0), NaN elsewhere. ``prior``: (m0, m1)
    grids (protected cells, their threshold widening, the terrain prior's compact cells) or
    None. ``cell_size`` (m, with ``prior``): the grid's, for the runs of
    :func:`_restore_long_terrain` (0: none). ``on_coarse``: called with (basis, Q, R) of the
    last coarse layout before the finest one is fitted; when it returns True the loop stops
    there and returns None (no call when there is a single layout)."""
    above_k = 2.5  # threshold above the surface, in noise scales
    below_k = 6.0  # threshold below the surface (low outliers), in noise scales
    clip_k = 3.0  # equalization clips samples to S + clip_k * threshold_above
    layouts = _layouts(n_max, degree)
    # the passes work on vectors of the valid cells' values (gathered once, scattered back at
    # the end): the per-cell kernels then read small contiguous arrays instead of (m0, m1)
    # grids, which stay cached across the passes (same values, same order of operations)
    z_grid = z_start = np.ascontiguousarray(z, dtype=np.float64)
    base = np.ascontiguousarray(base, dtype=np.float64)
    use_prior = prior is not None
    compact = np.ascontiguousarray(prior[0], dtype=bool) if use_prior else np.zeros((1, 1), bool)
    spread = np.ascontiguousarray(prior[1], dtype=np.float64) if use_prior else np.zeros((1, 1))
    # valid cells (base > 0), their samples and base weights, the measured ones' positions in
    # the vectors, the prior's compact mask and spread at the valid cells: in one pass
    valid_cells, z, base_cells, measured_cells, compact, prior_spread = _tk.gather_cells(
        base.ravel(), z_grid.ravel(), np.ascontiguousarray(measured, dtype=bool).ravel(),
        compact.ravel(), spread.ravel(), use_prior)
    count = valid_cells.size
    cells = np.arange(count)  # the vectors' indices, for the kernels' cell lists
    p = z  # read-only until the first pass writes into the buffers below
    w = base_cells
    # two buffers per product, alternating between passes (the previous pass stays readable)
    weight_buffers = (np.zeros(count), np.zeros(count))
    sample_buffers = (z.copy(), z.copy())
    ratios = np.zeros(count)  # W / base of the last pass, remapped onto each layout
    surface = np.zeros(count)  # the surface at the valid cells
    denominators = np.zeros(count)  # its denominator (from the solve's assembly)
    have_ratios = False
    records = []
    equalized = np.zeros(count, bool)
    iteration = 0
    noise = noise_floor
    cell_sigma = None  # per-cell noise scale of the sensor model, from the second layout on
    no_sigma = np.zeros(1)
    # the coarse layouts fit the measured cells only: the filled ones (their neighbours' mean
    # at filled_weight, about half the valid cells of a lidar frame) add nothing a coarse
    # layout can resolve; they join at the finest layout, weighed against the last coarse
    # surface (docs/performance.md, "Coarse layouts on the measured cells")
    filled = np.ones(count, bool)
    filled[measured_cells] = False
    filled = np.flatnonzero(filled)
    coarse = measured_cells if filled.size else cells
    coarse_surface = np.zeros(coarse.size)
    coarse_denominators = np.zeros(coarse.size)
    last_fit = None  # (basis, Q, R) of the last layout fitted, for the finest one's filled cells
    for level, n in enumerate(layouts):
        knots = None
        if densities is not None:
            knots = (clamped_knots(n[0], degree, *region_local[:2], densities[0]),
                     clamped_knots(n[1], degree, *region_local[2:], densities[1]))
        final = level == len(layouts) - 1
        if final and level > 0 and on_coarse is not None and on_coarse(*last_fit):
            return None  # the caller fits again (stop_after_coarse of fit_grid_detailed)
        basis = GridBasis(xl, yl, n, degree, region_local, knots)
        if final and level > 0 and filled.size:
            # the filled cells: the last coarse surface at them, then their weights, ratios
            # and equalized samples from it (one robust pass over them alone)
            coarse_basis, q, r = last_fit
            surface[filled] = coarse_basis.evaluate_at_cells(q, r, valid_cells[filled])
            _tk.robust_pass(
                z, surface, base_cells, filled, compact, use_prior, prior_spread, noise,
                no_sigma if cell_sigma is None else cell_sigma, cell_sigma is not None,
                above_k, below_k, clip_k, p, w, False, w, ratios, p, equalized)
        # this layout's cells: their positions in the vectors, their flat grid indices, and
        # where the surface and its denominators at them go
        on = cells if final else coarse
        grid_cells = valid_cells if final else valid_cells[coarse]
        out, out_denominators = (surface, denominators) if final else \
            (coarse_surface, coarse_denominators)
        coverage = _project(basis, np.ones(on.size), grid_cells)  # remap denominator
        passes = 4 if final else 2
        if final and level > 0 and use_prior:
            # the prior's compact cells proper, not the canopy rule's (a roof's edge can pass
            # that rule): tests/test_ground_layer.py, the 30 m building
            w = _restore_long_terrain(w, base_cells, prior[2].ravel()[valid_cells],
                                      valid_cells, z_start.shape, cell_size)
        previous_w = w
        converged = False
        for k in range(passes):
            iteration += 1
            p_on, w_on, ratios_on = (p, w, ratios) if final else (p[on], w[on], ratios[on])
            r = _control_weights(ratios_on, coverage, basis, grid_cells) \
                if (have_ratios and rational) else np.ones(n)
            q = basis.solve_cells(grid_cells, p_on, w_on, r, smoothing,
                                  denominators=out_denominators)
            s = basis.evaluate_at_cells(q, r, grid_cells, out, out_denominators)
            if not final:
                surface[on] = s
                s = surface
            # residuals of the original samples (not the equalized ones): noise scale on the
            # terrain side, bounded eq. 3 weights, equalization, in one pass over the cells
            noise, mean_error = _tk.residual_scale(z, s, measured_cells, noise_floor)
            th_above = above_k * noise
            w_next = weight_buffers[iteration % 2]
            p_next = sample_buffers[iteration % 2]
            moved, change = _tk.robust_pass(
                z, s, base_cells, on, compact, use_prior, prior_spread, noise,
                no_sigma if cell_sigma is None else cell_sigma, cell_sigma is not None,
                above_k, below_k, clip_k, p, previous_w, True, w_next, ratios, p_next,
                equalized)
            have_ratios = True
            w, p = w_next, p_next
            records.append(IterationRecord(n, mean_error, th_above, moved))
            # the weights this surface gives against those it was solved with (at a new
            # layout's first pass, the last layout's): within 0.02, the solve is the fixed
            # point of its weights, whichever pass it is (docs/algorithm.md, "The loop's
            # last solve")
            converged = change < 0.02
            if converged:
                break
            previous_w = w
            if iteration >= max_iterations and final:
                break
        last_fit = (basis, q, r)
        if grid_noise is not None and not final:
            # the sensor's noise under this layout's surface: samples and scales of the next
            z_grid, sigma = _noise_update(grid_noise, basis.evaluate(q, r), z_grid, z0, measured)
            z = np.ascontiguousarray(z_grid).ravel()[valid_cells]
            cell_sigma = np.ascontiguousarray(sigma, dtype=np.float64).ravel()[valid_cells]
    basis_final = basis
    if converged:
        # the last pass moved the weights by less than the tolerance: its surface is the
        # loop's (an IRLS stops on the solution whose weights no longer change), and the
        # weights and samples returned are those that surface gives (docs/algorithm.md,
        # "The loop's last solve")
        rr = r
    else:
        rr = np.ones(n) if not rational else _control_weights(ratios, coverage, basis,
                                                                  valid_cells)
        q = basis_final.solve_cells(valid_cells, p, w, rr, smoothing, denominators=denominators)
        s = basis_final.evaluate_at_cells(q, rr, valid_cells, surface, denominators)
    # back onto the grid in one pass: 0 weight, sample z (before any noise update) and False
    # elsewhere
    weights_grid, samples_grid, equalized_grid, outliers = _tk.scatter_cells(
        base > 0 if state is None else state, valid_cells, w, p, equalized, z, s,
        above_k * noise, z_start, z0)
    return q, rr, basis_final, weights_grid, samples_grid, equalized_grid, outliers, records, \
        noise


def _restore_long_terrain(w, base, compact, valid_cells, shape, cell_size):
    """``w`` with the compact cells the coarse layouts dropped (w < base / 2) back at their
    base weight where they form an 8-connected run spanning at least
    :data:`LONG_TERRAIN_SPAN` along x or y (a copy when any changes; ``w`` itself otherwise).
    Vectors over the valid cells (``valid_cells``: their flat indices in the grid of
    ``shape``)."""
    dropped = compact & (w < 0.5 * base)
    if cell_size <= 0 or not dropped.any():
        return w
    where = np.flatnonzero(dropped)
    long_run = _tk.long_runs(valid_cells[where], shape[0], shape[1],
                             math.ceil(LONG_TERRAIN_SPAN / cell_size - 1e-9))
    if not long_run.any():
        return w
    restore = where[long_run]
    w = w.copy()
    w[restore] = base[restore]
    return w


def _noise_update(grid_noise, surface, z, z0, measured):
    """Samples (relative to z0) and per-cell noise scales of the samples for the surface
    values ``surface`` (:meth:`o3d_terrain.noise.GridNoise.update`); a sample is only raised
    (compact-cell and ground-layer samples are kept where higher)."""
    samples, sigma = grid_noise.update(surface + z0)
    return np.where(measured, np.maximum(z, samples - z0), z), sigma


def _control_weights(ratios: np.ndarray, coverage: np.ndarray, basis: GridBasis,
                     cells: np.ndarray) -> np.ndarray:
    """R = 0.5 + 0.5 * :func:`remap_weights` of the weight ratios (one per cell of ``cells``,
    zero elsewhere), with the projection of the valid mask (``coverage``) computed once per
    layout."""
    return _tk.control_weights_cells(basis.spans_x, basis.basis_x, basis.spans_y,
                                     basis.basis_y, ratios, cells, basis.n0, basis.n1, coverage)


def _project(basis: GridBasis, values: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Bx^T V By (:meth:`GridBasis.project`) over the cells ``cells`` (flat indices), V given
    at those cells (``values``, one per cell; zero elsewhere), row by row."""
    return _tk.grid_project_cells(basis.spans_x, basis.basis_x, basis.spans_y, basis.basis_y,
                                  values, cells, basis.n0, basis.n1)
