"""Open3D drop-in functions: ``fit_terrain`` and ``segment_terrain``.

``segment_terrain`` returns ``(surface, inliers)`` in the manner of
``open3d.geometry.PointCloud.segment_plane`` (which returns ``(plane_model, inliers)``):
``inliers`` are int64 indices into the caller's cloud of the points labelled terrain.
Both accept a legacy or tensor Open3D point cloud, an (N, 3)/(N, 4) numpy array or a Frame;
the caller's cloud is never modified. Non-finite points are ignored (never inliers).
"""

from __future__ import annotations

import inspect
import math
from typing import Any, Sequence

import numpy as np

from ._kernels import positions as _positions
from .errors import ConfigError, InputError, checked_keywords
from .frame import LABELS, Frame, as_frame, warn_coarse_float32
from .grid import region_of
from .ground_layer import default_layer
from .locate import locate_sensor
from .noise import RangeNoise
from .segment import (AUTO_CENTRED_FACTOR, AUTO_THRESHOLD_FACTOR, AUTO_THRESHOLD_RANGE,
                      FOOT_HEIGHT, FOOT_LINES, TerrainLabel, line_spacing_finder,
                      sensor_in_cloud)
from .segment import auto_threshold as _auto_threshold
from .spline import TerrainSurface
from .stages.grid_quantize import GridQuantize
from .stages.terrain import RationalBSplineTerrain, Segmenter

__all__ = ["fit_terrain", "segment_terrain", "check_fit_options", "check_segment_options",
           "cloud_positions"]


#: what a keyword users bring from elsewhere (Open3D's ``segment_plane``, voxel grids) is
#: called here, or why it has no counterpart (:func:`~o3d_terrain.errors.checked_keywords`)
_RANSAC = "the terrain is a fitted surface, not a RANSAC plane: there is no sampling to set"
_KEYWORD_HINTS = {
    "threshold": "the obstacle threshold is segment_terrain's distance_threshold (m above the "
                 "surface; None = from the data)",
    "ransac_n": _RANSAC, "num_iterations": _RANSAC, "probability": _RANSAC,
    "voxel_size": "the grid's cell is cell_size (m)",
    "resolution": "the grid's cell is cell_size (m)",
}
#: the options of segment_terrain's labels (the Segmenter's), which fit_terrain does not take
_LABEL_OPTIONS = ("distance_threshold", "below_threshold", "range_coefficient",
                  "misfit_threshold", "along_normal", "foot_height", "foot_lines",
                  "line_of_sight")
_FIT_HINTS = {**_KEYWORD_HINTS, **{
    name: f"{name} is an option of segment_terrain's labels, not of the fit"
    for name in _LABEL_OPTIONS}}


def cloud_positions(cloud: Any) -> np.ndarray:
    """(N, 3) float64 positions of anything :func:`~o3d_terrain.frame.as_frame` accepts."""
    frame = as_frame(cloud)
    return np.asarray(frame.positions, dtype=np.float64)


def _check_region(region) -> tuple[float, float, float, float] | None:
    if region is None:
        return None
    try:
        values = tuple(float(v) for v in region)
    except (TypeError, ValueError):
        raise InputError(f"region must be (x_min, x_max, y_min, y_max) in metres, got {region!r}")
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise InputError(f"region must be four finite numbers (x_min, x_max, y_min, y_max), "
                         f"got {region!r}")
    if not (values[1] > values[0] and values[3] > values[2]):
        raise InputError(f"region {values} is degenerate: it needs x_max > x_min and "
                         f"y_max > y_min; give a region with a positive area")
    return values


def _build(make, **options):
    """A stage from the api's keyword arguments; option errors become InputError.

    Stages are immutable, so the last few built are kept and reused for the same options
    (keyed by each value's type and repr, so 1, 1.0 and True stay apart)."""
    try:
        key = (make, tuple((k, type(v), repr(v)) for k, v in sorted(options.items())))
        hash(key)
    except Exception:  # an option value without a usable repr: build every time
        key = None
    if key is not None and key in _STAGE_CACHE:
        return _STAGE_CACHE[key]
    try:
        built = make(**options)
    except ConfigError as exc:
        raise InputError(str(exc)) from exc
    if key is not None:
        if len(_STAGE_CACHE) >= 64:
            _STAGE_CACHE.pop(next(iter(_STAGE_CACHE)))
        _STAGE_CACHE[key] = built
    return built


_STAGE_CACHE: dict = {}


def _array_positions(cloud: Any) -> np.ndarray | None:
    """(N, 3) float64 positions of a numeric (N, 3)/(N, 4) numpy array without making a frame
    (no copy when it is already float64 and C-ordered (N, 3); a C-ordered float32 array, a
    lidar's usual rows, in one pass of :func:`~o3d_terrain._kernels.positions.xyz_float64`);
    None for anything else."""
    if not (isinstance(cloud, np.ndarray) and cloud.ndim == 2 and cloud.shape[1] in (3, 4)
            and cloud.dtype != object and np.issubdtype(cloud.dtype, np.number)):
        return None
    warn_coarse_float32(cloud)
    if cloud.dtype == np.float32 and cloud.flags.c_contiguous:
        return _positions.xyz_float64(cloud)
    return np.ascontiguousarray(cloud[:, :3], dtype=np.float64)


def _terrain_stages(region, cell_size, control_points, degree, method, smoothing,
                    terrain_prior, range_noise, sensor_origin, max_slope_deg, cell_plane,
                    refine, knots, low_returns=True, ground_returns="last", grow_cells=True,
                    free_space=True):
    """The GridQuantize and RationalBSplineTerrain stages of the api's options (cached)."""
    region = _check_region(region)
    quantize = _build(GridQuantize, cell_size=cell_size, region=region)
    noise = {"sensor_origin": _origin(sensor_origin)}  # refine's labels measure range from it
    if isinstance(range_noise, RangeNoise):
        noise = {"range_noise": range_noise.coefficient,
                 "sensor_origin": range_noise.sensor_origin}
    elif range_noise is not None:
        noise["range_noise"] = range_noise
    terrain = _build(RationalBSplineTerrain,
                     control_points=_sequence(control_points),
                     degree=degree, method=method, smoothing=smoothing,
                     terrain_prior=terrain_prior, max_slope_deg=max_slope_deg,
                     cell_plane=cell_plane, refine=refine, knots=knots,
                     low_returns=low_returns, ground_returns=ground_returns,
                     grow_cells=grow_cells, free_space=free_space, **noise)
    return quantize, terrain


def _sequence(value):
    """A list or array option as a tuple (the stage cache keys on its repr); anything else, a
    single number for both axes among it, as given for the stage to check."""
    return tuple(value) if isinstance(value, (list, np.ndarray)) else value


def _origin(sensor_origin) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in sensor_origin)
    except (TypeError, ValueError):
        raise InputError(f"sensor_origin must be three numbers (x, y, z), got {sensor_origin!r}")


def _sensor_origin(sensor_origin, positions: np.ndarray) -> tuple[float, ...]:
    """``sensor_origin`` as given, or for None: the origin when points lie around it (a
    scan in its sensor's frame), else the sensor found from the scan
    (:func:`o3d_terrain.locate.locate_sensor`: a vehicle's scan in a map or world frame),
    else the origin (a top-down scan)."""
    if sensor_origin is not None:
        return _origin(sensor_origin)
    origin = (0.0, 0.0, 0.0)
    if len(positions) == 0 or sensor_in_cloud(positions, origin):
        return origin
    found = locate_sensor(positions)
    return origin if found is None else found


def _input(cloud: Any, sensor_origin) -> tuple[np.ndarray | None, Frame | None, tuple]:
    """(positions, frame, origin) of the api's input: a numeric array's positions without a
    frame (:func:`_array_positions`), else its frame (:func:`as_frame`); and the sensor's
    position in it (:func:`_sensor_origin`)."""
    positions = _array_positions(cloud)
    frame = as_frame(cloud) if positions is None else None
    return positions, frame, _sensor_origin(sensor_origin,
                                            positions if frame is None else frame.positions)


def _checked_region(positions: np.ndarray, region):
    """The region the grid covers: ``region`` or the cloud's extent (checked)."""
    if len(positions) == 0:
        raise InputError("the cloud is empty; give a cloud with points")
    if region is not None:
        return region
    extent = region_of(positions)  # raises when no point is finite
    if not (extent[1] > extent[0] and extent[3] > extent[2]) or _collinear(positions):
        raise InputError(f"the cloud's x/y extent {extent} is degenerate (all points on a "
                         f"line or one spot); give a region")
    return extent


def _collinear(positions: np.ndarray, sample: int = 2000) -> bool:
    """Whether the points lie on one line in x/y (at any angle): the spread across their
    principal axis, from every k-th finite point (at most ``sample``), under 1e-9 of the
    spread along it."""
    p = positions[:: max(1, len(positions) // sample), :2]
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < 3:
        return False
    smallest, largest = np.linalg.eigvalsh(np.cov(p.T, bias=True))
    return bool(smallest <= 1e-18 * largest)


def _terrain_frame(cloud: Any, quantize: GridQuantize, terrain: RationalBSplineTerrain) -> Frame:
    """The api's path for clouds and frames: GridQuantize then RationalBSplineTerrain."""
    frame = as_frame(cloud)
    _checked_region(frame.positions, quantize.region)
    return terrain(quantize(frame))


def _array_fit(positions: np.ndarray, quantize: GridQuantize,
               terrain: RationalBSplineTerrain, line_spacing=None) -> TerrainSurface:
    """What ``terrain(quantize(frame))`` computes, on an array without a frame: the same
    functions with the stages' options (the grid covers the extent computed once);
    ``line_spacing``: the refit's scan-line spacing of the points
    (:meth:`RationalBSplineTerrain.fit`)."""
    extent = _checked_region(positions, quantize.region)
    # the ground-layer statistics of the fit are gathered in the grid's pass over the points
    layer = default_layer(quantize.cell_size, noise_floor=terrain.noise_floor,
                          max_slope_deg=terrain.slope_limit) \
        if terrain.ground_layer and terrain.method == "robust" else 0.0
    grid = quantize._guard(lambda: quantize.grid(positions, region=extent, layer=layer,
                                                 plane=terrain.cell_plane,
                                                 tilt_spread=terrain.noise_floor))
    return terrain._guard(lambda: terrain.fit(grid, positions,
                                              line_spacing=line_spacing)).surface


def auto_threshold(surface: TerrainSurface, positions: np.ndarray, *,
                   factor: float = AUTO_THRESHOLD_FACTOR, low: float = AUTO_THRESHOLD_RANGE[0],
                   high: float = AUTO_THRESHOLD_RANGE[1],
                   centred_factor: float = AUTO_CENTRED_FACTOR) -> float:
    """Obstacle threshold from the data: ``factor`` times the robust spread of the points
    at or below the surface (terrain noise; obstacles never lie below it), in [low, high] m;
    where the ground's centre lies above the surface, at least that centre plus
    ``centred_factor`` times the ground's spread below it
    (:func:`o3d_terrain.segment.auto_threshold` of the heights above the surface)."""
    return _auto_threshold(surface.heights_above(positions), factor=factor, low=low, high=high,
                           centred_factor=centred_factor)


@checked_keywords(_FIT_HINTS)
def fit_terrain(cloud: Any, *, region: Sequence[float] | None = None, cell_size: float = 0.5,
                control_points: Sequence[int] | int | None = None, degree: int = 3,
                method: str = "robust", smoothing: float = 0.05,
                terrain_prior: bool = True, range_noise: RangeNoise | float | None = None,
                sensor_origin: Sequence[float] | None = None,
                max_slope_deg: float | None = None,
                cell_plane: bool = True, refine: bool = True,
                knots: str = "auto", low_returns: bool = True, grow_cells: bool = True,
                ground_returns: str = "last", free_space: bool = True) -> TerrainSurface:
    """Fit a rational B-spline terrain surface to a point cloud.

    region: (x_min, x_max, y_min, y_max) in the cloud's coordinates; None = the cloud's extent.
    cell_size: grid cell side (m). control_points: per axis (one int: both); None = about one
    every 2 cells (at least 1 m), at most 32 per axis (48 on a top-down scan, no points near
    ``sensor_origin``; one every 6 m on tiles wider than that allows), the refit (``refine``)
    up to 40 per axis (:data:`o3d_terrain.refine.REFINE_MAX_CONTROL_POINTS`; 64 on a
    vehicle's scan of steep relief, :func:`o3d_terrain.refine.steep_share`). degree: B-spline
    degree.
    method: "robust" or "paper".
    smoothing: thin-plate penalty (relative) that keeps data-free areas bounded.
    terrain_prior: do not reject compact cells connected to the ground under the
    ``max_slope_deg`` slope limit as obstacles (steep berms and ditch walls;
    docs/algorithm.md); False = plain robust weights.
    max_slope_deg: the prior's slope limit (deg): faces steeper than this are walls, not
    terrain. None = 45 (:data:`o3d_terrain.terrain.MAX_SLOPE_DEG`), or 60 on a vehicle's scan
    of strong relief (slopes that change, not a tilt: :func:`o3d_terrain.refine.steep_share`
    of the robust fit's coarse layouts at least :data:`o3d_terrain.terrain.STEEP_LIMIT_SHARE`),
    where the fit then starts again (docs/algorithm.md, "A steeper slope limit on strong
    relief"), or the faces' tilt + 5, 60 to 70, on a vehicle's scan of a bench face (planar
    cells 50-75 deg from the ground around the sensor in a run of 10 m or more,
    :mod:`o3d_terrain.faces`; docs/algorithm.md, "Bench faces"). Give it (e.g. 60-75) for
    shorter or steeper faces and on airborne tiles; on street scenes a higher limit connects
    the walls of cars and buildings to the ground (docs/algorithm.md, "Steep slopes and
    faces").
    range_noise: the sensor's range-dependent noise, a :class:`~o3d_terrain.noise.RangeNoise`
    (e.g. ``RangeNoise.from_stereo(focal_px=..., baseline=..., disparity_noise_px=...)``) or
    its coefficient in 1/m with ``sensor_origin`` (cloud coordinates); None = none (lidar).
    cell_plane: (default; with terrain_prior) in cells whose points are all terrain (the
    prior's compact cells), eq. 1 about their
    least-squares plane where it tilts them by more than the noise floor, instead of about
    their mean, which sits about rise / sqrt(12) below sloped terrain; False = eq. 1
    everywhere (docs/algorithm.md, "Eq. 1 with the in-cell slope removed").
    refine: (default; robust method) label the points against the fitted surface with the
    automatic rule of :func:`segment_terrain` and fit the same layout again to the terrain
    points alone (:func:`o3d_terrain.refine.refine_surface`; docs/algorithm.md, "Refit on the
    terrain points"); False = the robust loop's surface, about 30 % sooner on a 120k-point
    lidar frame. ``sensor_origin`` (cloud coordinates) is where those labels measure range
    from; the ground plane around it (the ground the vehicle stands on) seeds the prior and,
    on a tilted sensor, gives it level; None = as in :func:`segment_terrain`.
    knots: "auto" (default) = "adaptive" on a vehicle's scan, "uniform" on a top-down scan
    (no points near ``sensor_origin``); "adaptive" = knot spans narrower where the grid has
    more measured cells and wider where it has few, when the layout's uniform spacing is
    over 1.5 times 2 cells (a wide frame: the control points follow the ground near the
    sensor; docs/algorithm.md, "Knots where the data are"); "uniform" = evenly spaced.
    low_returns: (default; robust method, a vehicle's scan) when at least 2 % of the grid's
    measured cells have an isolated low point (more than 0.3 m below the thin layer of the
    cell's other points: a return from below the ground, multipath off a wet road or glass),
    fit without the points well below the thin layer of their cell
    (:func:`o3d_terrain.grid.without_low_returns`; docs/algorithm.md, "Returns from below the
    ground"); False = fit every point.
    free_space: (default; robust method, a vehicle's scan) fit without the cells whose lowest
    point lies well above where rays of the scan passed on their way to farther returns (the
    underside of a ceiling, a roof or a canopy that rays went under: no ground can be there;
    :func:`o3d_terrain.grid.without_overhead`; docs/algorithm.md, "Free space under the
    rays"); False = fit every cell. It acts only where ``sensor_origin`` stands at least
    0.3 m over the ground 2-10 m around it (the rays need the sensor's position: not the
    ground under a stereo rig in a vehicle frame, nor a sensor found from a map-frame scan).
    grow_cells: (default; robust method, a top-down scan: no points near ``sensor_origin``, an
    airborne tile) where a cell of ``cell_size`` holds under 3/4 of a point where most of
    the scan's points lie, the robust fit uses cells grown to hold about 3 (at most 3 m), so
    that a cell under vegetation also holds a return from the ground; the refit (``refine``)
    then fits the terrain points at ``cell_size`` (:func:`o3d_terrain.grid.grown_cell`;
    docs/algorithm.md, "Cells for a sparse top-down scan"); False = ``cell_size``
    throughout.
    ground_returns: with a cloud that carries each point's ``return_numbers`` and
    ``number_of_returns`` (a LAS/LAZ tile read by :func:`o3d_terrain.read_cloud`), "last"
    (default) = fit the last return of each pulse only (one that went on past a point did
    not stop at the ground there); "all" = fit every return.

    Runs the stages GridQuantize and RationalBSplineTerrain with these options (the same code
    as a pipeline).
    """
    positions, frame, origin = _input(cloud, sensor_origin)
    quantize, terrain = _terrain_stages(region, cell_size, control_points, degree, method,
                                        smoothing, terrain_prior, range_noise, origin,
                                        max_slope_deg, cell_plane, refine, knots, low_returns,
                                        ground_returns, grow_cells, free_space)
    if frame is None:  # numpy input: the stages' functions without a frame
        return _array_fit(positions, quantize, terrain)
    return _terrain_frame(frame, quantize, terrain).product("surface")


@checked_keywords(_KEYWORD_HINTS)
def segment_terrain(cloud: Any, *, region: Sequence[float] | None = None,
                    cell_size: float = 0.5, control_points: Sequence[int] | int | None = None,
                    degree: int = 3, distance_threshold: float | None = None,
                    below_threshold: float = 0.5, range_coefficient: float | None = None,
                    sensor_origin: Sequence[float] | None = None, method: str = "robust",
                    smoothing: float = 0.05, terrain_prior: bool = True,
                    range_noise: RangeNoise | float | None = None,
                    misfit_threshold: bool = True, along_normal: bool = True,
                    foot_height: float = FOOT_HEIGHT, max_slope_deg: float | None = None,
                    cell_plane: bool = True, refine: bool = True,
                    knots: str = "auto",
                    foot_lines: float = FOOT_LINES,
                    line_of_sight: bool = True,
                    low_returns: bool = True, grow_cells: bool = True,
                    ground_returns: str = "last",
                    free_space: bool = True) -> tuple[TerrainSurface, np.ndarray]:
    """Fit the terrain and return ``(surface, inliers)``: int64 indices of the terrain points.

    A point is terrain when -below_threshold <= z - S(x, y) <= distance_threshold +
    range_coefficient * r^2 (r: horizontal range from ``sensor_origin``); with
    ``along_normal`` (default) both bounds are distances along the surface normal, i.e.
    vertically sqrt(1 + |grad S|^2) times larger on slopes (at most twice, a 60° face).
    ``distance_threshold`` None = from the data: 3.5 times the robust noise of the points
    just below the surface, at least the ground's centre plus 2.5 times its noise where the
    surface lies under that centre, clipped to [0.13, 0.5] m (:func:`auto_threshold`), widened with
    ``misfit_threshold`` where the surface's local misfit to the ground exceeds that noise
    (:mod:`o3d_terrain.misfit`, at most 1.5 m, both sides). ``range_coefficient`` None = from
    the data with the automatic threshold: it grows with r^2 only where the noise below the
    surface grows steadily with range, as a stereo camera's does
    (:func:`o3d_terrain.segment.auto_range_coefficient`; 0 on lidar scans), else 0.
    ``foot_height``: terrain points in a
    0.15 m x/y column that also holds obstacle points less than this high above the terrain
    (above the local noise, 30 % or more of the column, with an object at least 0.35 m high
    in it or beside it) are the foot of that object (a bush, a wall, a wheel) and not
    inliers; 0 = off (:func:`o3d_terrain.segment.mark_object_feet`); on a rotating lidar's
    scan around ``sensor_origin`` the foot height grows with range to ``foot_lines`` times the
    height between neighbouring scan lines on a vertical face there, at most 1.5 m (0 = the
    same at every range; :func:`o3d_terrain.segment.scan_line_spacing`). With
    ``line_of_sight`` (and the sensor in the cloud), terrain points above the sensor that the
    surface would hide from it are obstacles (:func:`o3d_terrain.segment.out_of_sight`: an
    object beyond a crest whose own ground is not seen). ``sensor_origin``: where
    the sensor is in the cloud's coordinates: the range of the thresholds and of
    ``range_noise``, and the ground around it defines level for the misfit's slope term, so
    that a tilted sensor is labelled as a level one
    (:func:`o3d_terrain.segment.sensor_ground_gradient`). None (default) = (0, 0, 0) when
    points lie around it (a cloud in its sensor's frame), else the sensor found from the scan
    (:func:`o3d_terrain.locate.locate_sensor`: a vehicle's scan moved into a map or world
    frame, found within a few metres and at the height of the ground there), else (0, 0, 0)
    (a top-down scan); give it when you know it. ``ground_returns``: with a cloud that
    carries each point's ``return_numbers`` and ``number_of_returns`` (an Open3D tensor cloud
    from :func:`o3d_terrain.read_cloud` of a LAS/LAZ file, or a :class:`~o3d_terrain.Frame`),
    "last" (default) = a point that is not the last return of its pulse is never an inlier
    (:func:`o3d_terrain.segment.earlier_returns`) and the fit uses the last returns only;
    "all" = every return may be one, and the fit uses them all. Other
    options as in :func:`fit_terrain` (``range_noise`` given as a coefficient uses
    ``sensor_origin``; ``refine`` refits the surface to the points its automatic labels call
    terrain before these labels are made; ``low_returns`` leaves isolated returns from below
    the ground out of the fit, not out of the labels, and ``free_space`` the cells over where
    rays went on, a ceiling's or a canopy's).

    Runs the stages GridQuantize, RationalBSplineTerrain and Segmenter with these options.
    """
    positions, frame, origin = _input(cloud, sensor_origin)
    quantize, terrain, segmenter = _segment_stages(
        origin, region=region, cell_size=cell_size, control_points=control_points,
        degree=degree, distance_threshold=distance_threshold, below_threshold=below_threshold,
        range_coefficient=range_coefficient, method=method, smoothing=smoothing,
        terrain_prior=terrain_prior, range_noise=range_noise,
        misfit_threshold=misfit_threshold, along_normal=along_normal, foot_height=foot_height,
        max_slope_deg=max_slope_deg, cell_plane=cell_plane, refine=refine, knots=knots,
        foot_lines=foot_lines, line_of_sight=line_of_sight, low_returns=low_returns,
        grow_cells=grow_cells, ground_returns=ground_returns, free_space=free_space)
    if frame is None:  # numpy input: the stages' functions without a frame
        # the points' scan-line spacing, found once for the refit's labels and the final ones
        # (when both see the sensor at the same place)
        spacing = line_spacing_finder(positions, segmenter.sensor_origin) \
            if tuple(terrain.sensor_origin) == tuple(segmenter.sensor_origin) else None
        surface = _array_fit(positions, quantize, terrain, spacing)
        labels, _ = segmenter._guard(lambda: segmenter.label(surface, positions,
                                                             line_spacing=spacing))
        return surface, np.flatnonzero(labels == TerrainLabel.TERRAIN).astype(np.int64, copy=False)
    frame = segmenter(_terrain_frame(frame, quantize, terrain))
    labels = frame.attribute(LABELS)
    terrain_indices = np.flatnonzero(labels == TerrainLabel.TERRAIN).astype(np.int64, copy=False)
    return frame.product("surface"), terrain_indices


def _segment_stages(origin, *, region, cell_size, control_points, degree, distance_threshold,
                    below_threshold, range_coefficient, method, smoothing, terrain_prior,
                    range_noise, misfit_threshold, along_normal, foot_height, max_slope_deg,
                    cell_plane, refine, knots, foot_lines, line_of_sight, low_returns,
                    grow_cells, ground_returns, free_space):
    """The GridQuantize, RationalBSplineTerrain and Segmenter stages of
    :func:`segment_terrain`'s options (cached; option errors raise InputError), the sensor at
    ``origin``."""
    segmenter = _build(Segmenter, threshold=distance_threshold, below_threshold=below_threshold,
                       range_coefficient=range_coefficient, sensor_origin=origin,
                       misfit_threshold=misfit_threshold, along_normal=along_normal,
                       foot_height=foot_height, foot_lines=foot_lines,
                       line_of_sight=line_of_sight, ground_returns=ground_returns)
    quantize, terrain = _terrain_stages(region, cell_size, control_points, degree, method,
                                        smoothing, terrain_prior, range_noise, origin,
                                        max_slope_deg, cell_plane, refine, knots, low_returns,
                                        ground_returns, grow_cells, free_space)
    return quantize, terrain, segmenter


def _with_defaults(function, options: dict) -> tuple[dict, tuple[float, ...]]:
    """``function``'s keyword defaults updated with ``options`` (its keyword check raises the
    TypeError of an unknown one), without ``sensor_origin``, and that origin ((0, 0, 0) for
    None: what the stages are built with before a cloud says where the sensor is)."""
    params = inspect.signature(function).parameters
    if options.keys() - params.keys() or "cloud" in options:
        function(None, **options)  # its keyword check raises the TypeError
    values = {name: p.default for name, p in params.items() if name != "cloud"}
    values.update(options)
    sensor_origin = values.pop("sensor_origin")
    return values, (0.0, 0.0, 0.0) if sensor_origin is None else _origin(sensor_origin)


def check_segment_options(**options: Any) -> None:
    """Raise what :func:`segment_terrain` would raise for these options before it looks at a
    cloud: TypeError for an unknown keyword (with the closest known ones), InputError for a
    value its stages reject (naming the stage, the option and what it takes). A batch over
    many clouds (``o3d-terrain eval segmentation --option``) checks once, before reading any."""
    values, origin = _with_defaults(segment_terrain, options)
    _segment_stages(origin, **values)


def check_fit_options(**options: Any) -> None:
    """:func:`check_segment_options` for :func:`fit_terrain` (``o3d-terrain eval terrain
    --option``)."""
    values, origin = _with_defaults(fit_terrain, options)
    _terrain_stages(sensor_origin=origin, **values)  # its parameters are fit_terrain's
