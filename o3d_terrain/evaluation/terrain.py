"""Terrain evaluation: height and slope of a fitted surface against an exact terrain.

Three sources of exact terrain:

* the synthetic scenes (``o3d_terrain.synthetic``): a lidar or stereo frame is sampled, the
  surface is fitted to it in the sensor frame and compared on a grid with the exact terrain in
  that frame; only grid nodes whose cell holds a terrain point are scored (no credit or blame
  for extrapolating into occlusion shadows);
* a DEM raster (e.g. ``dem.tif``, 1 m cells): windows of the DEM the size of a vehicle's area of
  interest are sampled into clouds (bilinear heights, optional noise and box obstacles), each
  window is fitted, and the surface is compared with the DEM heights at the cell centres and
  with the DEM's slope (central differences over one cell);
* a surveyed elevation raster of a measured cloud's area (:func:`evaluate_terrain_against_raster`):
  the cloud (moved by an optional pose into the raster's coordinates) is fitted and compared
  with the raster at the cell centres that lie in the fitted region near a cloud point.

A *fitter* is a callable ``(positions) -> surface`` where ``surface(x, y)`` is the height and
``surface.slope_deg(x, y)`` the slope angle in degrees; ours is
:func:`o3d_terrain.api.fit_terrain`. Results carry per-node error maps; :func:`write_error_map`
draws them as a PNG with OpenCV.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from .._files import output_path
from ..errors import InputError, did_you_mean
from ..frame import transform_points
from ..io import CLOUD_EXTENSIONS, read_cloud
from .metrics import height_rmse, slope_deg_from_gradient, slope_error_deg

Fitter = Callable[[np.ndarray], Any]


@dataclass(frozen=True, eq=False)
class TerrainResult:
    """Errors of one fitted surface: scalar statistics and the error maps (NaN = not scored)."""

    name: str
    points: int
    height_rmse: float
    height_p95_abs: float
    height_bias: float
    slope: dict[str, float]
    seconds: float
    height_error: np.ndarray  # (nx, ny) fitted - true, metres
    slope_error: np.ndarray  # (nx, ny) fitted - true, degrees
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "points": self.points, "seconds": self.seconds,
            "height_rmse_m": self.height_rmse, "height_p95_abs_m": self.height_p95_abs,
            "height_bias_m": self.height_bias,
            "slope_error_deg": self.slope,
            "scored_nodes": int(np.isfinite(self.height_error).sum()),
            "notes": list(self.notes),
        }

    def markdown_details(self) -> list[str]:
        """Lines the report's Markdown adds after its table (none here)."""
        return []


@dataclass
class TerrainReport:
    """Results of one fitter over several scenes or DEM windows, plus failures."""

    source: str
    results: list[TerrainResult] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)
    maps: dict[str, np.ndarray] = field(default_factory=dict)  # mosaics (DEM)

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "results": [r.to_dict() for r in self.results],
            "failures": [{"name": n, "reason": r} for n, r in self.failures],
            "overall": self.overall(),
        }

    def overall(self) -> dict[str, float]:
        """Height RMSE and slope errors pooled over every scored node of every result."""
        if not self.results:
            return {}
        h = np.concatenate([r.height_error[np.isfinite(r.height_error)] for r in self.results])
        s = np.concatenate([r.slope_error[np.isfinite(r.slope_error)] for r in self.results])
        out = {"height_rmse_m": float(np.sqrt(np.mean(h * h))) if h.size else math.nan,
               "height_p95_abs_m": float(np.percentile(np.abs(h), 95)) if h.size else math.nan}
        out.update({f"slope_{k}_deg": v for k, v in
                    slope_error_deg(s, np.zeros_like(s)).items()})
        return out

    def to_json(self) -> str:
        from .segmentation import _finite

        return json.dumps(_finite(self.to_dict()), indent=2)

    def to_markdown(self) -> str:
        lines = [
            f"Terrain accuracy on `{self.source}`",
            "",
            "| frame | points | height RMSE (m) | height p95 (m) | bias (m) | slope MAE (°) | "
            "slope p95 (°) | fit time (s) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in self.results:
            lines.append(
                f"| {r.name} | {r.points:,} | {_f(r.height_rmse, 3)} | {_f(r.height_p95_abs, 3)} | "
                f"{_f(r.height_bias, 3)} | {_f(r.slope['mean_abs'], 2)} | "
                f"{_f(r.slope['p95_abs'], 2)} | {r.seconds:.3f} |"
            )
        o = self.overall()
        if o:
            lines.append(
                f"| **all** | | {_f(o['height_rmse_m'], 3)} | {_f(o['height_p95_abs_m'], 3)} | | "
                f"{_f(o['slope_mean_abs_deg'], 2)} | {_f(o['slope_p95_abs_deg'], 2)} | |"
            )
        for r in self.results:
            lines += r.markdown_details()
        for name, reason in self.failures:
            lines.append("")
            lines.append(f"- skipped `{name}`: {reason}")
        return "\n".join(lines)


def _f(value: float, digits: int) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def default_fitter(**options: Any) -> Fitter:
    """Our :func:`o3d_terrain.api.fit_terrain` with these options (checked here:
    :func:`o3d_terrain.api.check_fit_options`)."""
    try:
        from ..api import check_fit_options, fit_terrain
    except ImportError as exc:
        raise InputError(f"o3d_terrain.api.fit_terrain is not available in this build ({exc})") from exc
    check_fit_options(**options)  # a bad option fails here, not once per frame

    def fit(positions: np.ndarray):
        return fit_terrain(positions, **options)

    fit.__name__ = "o3d_terrain"
    return fit


def compare_surface(
    name: str,
    surface: Any,
    x: np.ndarray,
    y: np.ndarray,
    true_height: np.ndarray,
    true_slope_deg: np.ndarray,
    *,
    points: int,
    seconds: float,
    notes: Sequence[str] = (),
) -> TerrainResult:
    """Compare ``surface`` with the truth at grid nodes ``x, y`` (2-D arrays, NaN truth = skip)."""
    fitted = np.asarray(surface(x, y), dtype=np.float64).reshape(x.shape)
    if hasattr(surface, "slope_deg"):
        fitted_slope = np.asarray(surface.slope_deg(x, y), dtype=np.float64).reshape(x.shape)
    else:  # any callable: slope by central differences
        h = 0.01
        gx = (np.asarray(surface(x + h, y)) - np.asarray(surface(x - h, y))) / (2 * h)
        gy = (np.asarray(surface(x, y + h)) - np.asarray(surface(x, y - h))) / (2 * h)
        fitted_slope = slope_deg_from_gradient(gx.reshape(x.shape), gy.reshape(x.shape))
    height_error = fitted - true_height
    slope_error = fitted_slope - true_slope_deg
    valid = np.isfinite(height_error)
    slope_error = np.where(valid & np.isfinite(slope_error), slope_error, np.nan)
    height_error = np.where(valid, height_error, np.nan)
    abs_error = np.abs(height_error[valid])
    return TerrainResult(
        name=name,
        points=points,
        height_rmse=height_rmse(fitted, true_height, valid),
        height_p95_abs=float(np.percentile(abs_error, 95)) if abs_error.size else math.nan,
        height_bias=float(height_error[valid].mean()) if valid.any() else math.nan,
        slope=slope_error_deg(fitted_slope, true_slope_deg, np.isfinite(slope_error)),
        seconds=seconds,
        height_error=height_error,
        slope_error=slope_error,
        notes=tuple(notes),
    )


# ---------------------------------------------------------------------------------------------
# synthetic scenes


def evaluate_synthetic_terrain(
    names: Sequence[str],
    fitter: Fitter | None = None,
    *,
    sensor: str = "lidar",
    seed: int = 0,
    spacing: float = 0.5,
    on_result: Callable[[Any], None] | None = None,
) -> TerrainReport:
    """Fit each synthetic scene's sampled cloud and compare with its exact terrain. The
    first scene is fitted once untimed before its timed fit, so that its time, like the
    others', leaves out loading the compiled kernels (numba's cache) on the process's first
    fit."""
    from .datasets import synthetic_frames, FrameFailure

    fitter = fitter or default_fitter()
    report = TerrainReport(source=f"synthetic {sensor} (seed {seed})")
    warm = False
    for frame in synthetic_frames(names, seed=seed, sensor=sensor):
        if isinstance(frame, FrameFailure):
            report.failures.append((frame.name, frame.reason))
            continue
        try:
            if not warm:
                fitter(frame.positions)
                warm = True
            result = _evaluate_synthetic_frame(frame, fitter, spacing)
        except Exception as exc:  # report and keep going
            report.failures.append((frame.name, f"{type(exc).__name__}: {exc}"))
            continue
        report.results.append(result)
        if on_result:
            on_result(result)
    return report


def _evaluate_synthetic_frame(frame, fitter: Fitter, spacing: float) -> TerrainResult:
    positions = frame.positions
    start = time.perf_counter()
    surface = fitter(positions)
    seconds = time.perf_counter() - start
    terrain_points = positions[frame.is_ground & frame.scored]
    x_min, y_min = terrain_points[:, :2].min(axis=0)
    x_max, y_max = terrain_points[:, :2].max(axis=0)
    xs = np.arange(x_min + spacing / 2, x_max, spacing)
    ys = np.arange(y_min + spacing / 2, y_max, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    # score only nodes whose cell holds a terrain point (no extrapolation into shadows)
    ix = np.clip(((terrain_points[:, 0] - x_min) / spacing).astype(np.int64), 0, len(xs) - 1)
    iy = np.clip(((terrain_points[:, 1] - y_min) / spacing).astype(np.int64), 0, len(ys) - 1)
    covered = np.zeros(gx.shape, dtype=bool)
    covered[ix, iy] = True
    truth = np.full(gx.shape, np.nan)
    truth[covered] = frame.terrain(gx[covered], gy[covered])
    slope = exact_slope_deg(frame.terrain, gx, gy, covered)
    return compare_surface(frame.name, surface, gx, gy, truth, slope, points=len(positions),
                           seconds=seconds)


def exact_slope_deg(height: Callable, x: np.ndarray, y: np.ndarray, where: np.ndarray,
                    step: float = 1e-3) -> np.ndarray:
    """Slope angle (degrees) of an exact height function by central differences (step in m)."""
    out = np.full(x.shape, np.nan)
    xs, ys = x[where], y[where]
    gx = (height(xs + step, ys) - height(xs - step, ys)) / (2 * step)
    gy = (height(xs, ys + step) - height(xs, ys - step)) / (2 * step)
    out[where] = slope_deg_from_gradient(gx, gy)
    return out


# ---------------------------------------------------------------------------------------------
# DEM


def read_dem(path: str | os.PathLike) -> np.ndarray:
    """A single-band elevation raster as float64 (rows = north to south); nodata becomes NaN."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such DEM file")
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # GeoTIFF tags: "unknown"
    try:
        dem = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if dem is None:
        raise InputError(f"{path}: OpenCV could not read it as an image; give a float GeoTIFF")
    if dem.ndim != 2:
        raise InputError(f"{path}: has {dem.shape[2]} bands; a DEM must have one")
    dem = dem.astype(np.float64)
    dem[~np.isfinite(dem) | (dem < -1e30) | (dem == -9999) | (dem == -32768)] = np.nan
    return dem


def dem_slope_deg(dem: np.ndarray, cell_size: float) -> np.ndarray:
    """Slope of a DEM by central differences (one-sided on the border), degrees."""
    d_row, d_col = np.gradient(dem, cell_size)
    return slope_deg_from_gradient(d_col, d_row)


def sample_dem_cloud(
    dem: np.ndarray,
    cell_size: float,
    rows: slice,
    cols: slice,
    *,
    density: float = 4.0,
    noise: float = 0.02,
    obstacles: int = 0,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Points (x, y, z) sampled uniformly over a DEM window, heights bilinear in the DEM.

    Coordinates: x = column * cell_size, y = row * cell_size (cell centres at integer nodes).
    ``obstacles`` boxes (0.5-2 m wide, 0.5-2.5 m tall) add points on their tops and sides.
    Returns the positions and the obstacle mask.
    """
    from scipy.ndimage import map_coordinates

    r0, r1 = rows.start, rows.stop - 1
    c0, c1 = cols.start, cols.stop - 1
    area = (r1 - r0) * (c1 - c0) * cell_size**2
    n = max(int(density * area), 16)
    r = rng.uniform(r0, r1, n)
    c = rng.uniform(c0, c1, n)
    z = map_coordinates(dem, [r, c], order=1, mode="nearest")
    z = z + rng.normal(0.0, noise, n) if noise > 0 else z
    positions = [np.column_stack([c * cell_size, r * cell_size, z])]
    is_obstacle = [np.zeros(n, dtype=bool)]
    for _ in range(obstacles):
        width = rng.uniform(0.5, 2.0)
        height = rng.uniform(0.5, 2.5)
        cr, cc = rng.uniform(r0 + 2, r1 - 2), rng.uniform(c0 + 2, c1 - 2)
        base = float(map_coordinates(dem, [[cr], [cc]], order=1, mode="nearest")[0])
        m = max(int(density * 4 * (width * width + 4 * width * height)), 8)
        u = rng.uniform(-width / 2, width / 2, (m, 2))
        h = rng.uniform(0, height, m)
        top = rng.random(m) < width / (width + 4 * height)
        side = rng.integers(0, 4, m)
        u[~top & (side == 0), 0] = -width / 2
        u[~top & (side == 1), 0] = width / 2
        u[~top & (side == 2), 1] = -width / 2
        u[~top & (side == 3), 1] = width / 2
        h[top] = height
        positions.append(np.column_stack([cc * cell_size + u[:, 0], cr * cell_size + u[:, 1],
                                          base + h]))
        is_obstacle.append(np.ones(m, dtype=bool))
    return np.concatenate(positions), np.concatenate(is_obstacle)


def evaluate_dem_terrain(
    dem_path: str | os.PathLike,
    fitter: Fitter | None = None,
    *,
    cell_size: float = 1.0,
    window: float = 40.0,
    max_windows: int | None = 16,
    density: float = 4.0,
    noise: float = 0.02,
    obstacles: int = 0,
    seed: int = 0,
    on_result: Callable[[Any], None] | None = None,
) -> TerrainReport:
    """Fit windows of a DEM sampled into clouds and compare with the DEM heights and slopes.

    ``window`` metres square windows tile the DEM; ``max_windows`` of them, spread evenly over
    the raster, are evaluated (None = all). Only interior cells (one cell from the window
    border) are scored. The report's ``maps`` hold the height and slope error mosaics.
    """
    dem = read_dem(dem_path)
    if not (cell_size > 0 and math.isfinite(cell_size)):
        raise InputError(f"DEM cell_size must be a positive number of metres, got {cell_size}")
    size = int(round(window / cell_size))
    if size < 8:
        raise InputError(f"window {window} m is under 8 cells of {cell_size} m; give a larger one")
    n_rows, n_cols = dem.shape
    if n_rows < size or n_cols < size:
        raise InputError(f"{dem_path}: {n_rows}x{n_cols} cells is smaller than one {size}-cell "
                         "window; give a smaller window")
    fitter = fitter or default_fitter()
    slope = dem_slope_deg(dem, cell_size)
    origins = [(r, c) for r in range(0, n_rows - size + 1, size)
               for c in range(0, n_cols - size + 1, size)]
    if max_windows is not None and len(origins) > max_windows:
        pick = np.linspace(0, len(origins) - 1, max_windows).round().astype(int)
        origins = [origins[i] for i in pick]
    report = TerrainReport(source=f"{Path(dem_path).name} ({window:g} m windows, "
                                  f"{density:g} pts/m², noise {noise:g} m, {obstacles} obstacles)")
    height_map = np.full(dem.shape, np.nan)
    slope_map = np.full(dem.shape, np.nan)
    rng = np.random.default_rng(seed)
    for r0, c0 in origins:
        name = f"rows {r0}-{r0 + size - 1}, cols {c0}-{c0 + size - 1}"
        rows, cols = slice(r0, r0 + size), slice(c0, c0 + size)
        try:
            if np.isnan(dem[rows, cols]).any():
                raise InputError("the window holds nodata cells")
            positions, _ = sample_dem_cloud(dem, cell_size, rows, cols, density=density,
                                            noise=noise, obstacles=obstacles, rng=rng)
            start = time.perf_counter()
            surface = fitter(positions)
            seconds = time.perf_counter() - start
            inner_r = np.arange(r0 + 1, r0 + size - 1)
            inner_c = np.arange(c0 + 1, c0 + size - 1)
            rr, cc = np.meshgrid(inner_r, inner_c, indexing="ij")
            result = compare_surface(name, surface, cc * cell_size, rr * cell_size,
                                     dem[rr, cc], slope[rr, cc], points=len(positions),
                                     seconds=seconds)
        except Exception as exc:  # report the window and keep going
            report.failures.append((name, f"{type(exc).__name__}: {exc}"))
            continue
        height_map[rr, cc] = result.height_error
        slope_map[rr, cc] = result.slope_error
        report.results.append(result)
        if on_result:
            on_result(result)
    report.maps = {"height_error": height_map, "slope_error": slope_map}
    return report


# ---------------------------------------------------------------------------------------------
# a measured cloud against a surveyed elevation raster


#: truth slopes steeper than this (degrees) form the report's "steep" subset
STEEP_SLOPE_DEG = 15.0

#: GeoTIFF tags: ModelPixelScale, ModelTiepoint, ModelTransformation, GeoKeyDirectory, nodata
_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS, _NODATA = 33550, 33922, 34264, 34735, 42113

_GEOREF_FIX = ("give origin= and cell_size= (command line: --truth-origin X Y "
               "--truth-cell-size M)")


class TruthOverlapError(InputError):
    """The cloud and the truth raster share no area, or too few raster cells can be scored."""


@dataclass(frozen=True, eq=False)
class Raster:
    """An elevation raster in the cloud's (metric) coordinates: square cells, no rotation.

    ``heights[row, col]`` in metres, row 0 = north (y falls with the row, as in a GeoTIFF);
    NaN = no data. ``origin``: x, y of the upper-left corner of the upper-left cell;
    ``cell_size``: the cell side in metres. Cell (row, col) has its centre at
    ``(x0 + (col + 0.5) * cell_size, y0 - (row + 0.5) * cell_size)``.
    """

    heights: np.ndarray
    origin: tuple[float, float]
    cell_size: float
    name: str = "raster"

    def __post_init__(self) -> None:
        heights = np.array(self.heights, dtype=np.float64)
        problems = []
        if heights.ndim != 2 or min(heights.shape, default=0) < 3:
            problems.append(f"heights must be a 2-D array of at least 3 x 3 cells, got shape "
                            f"{heights.shape}")
        try:
            origin = tuple(float(v) for v in self.origin)
        except (TypeError, ValueError):
            origin = ()
        if len(origin) != 2 or not all(math.isfinite(v) for v in origin):
            problems.append(f"origin must be two finite numbers (x, y of the upper-left corner), "
                            f"got {self.origin!r}")
        try:
            cell_size = float(self.cell_size)
        except (TypeError, ValueError):
            cell_size = math.nan
        if not (cell_size > 0 and math.isfinite(cell_size)):
            problems.append(f"cell_size must be a positive number of metres, got "
                            f"{self.cell_size!r}")
        if problems:
            raise InputError(f"Raster {self.name}: " + "; ".join(problems))
        heights[~np.isfinite(heights)] = np.nan
        heights.flags.writeable = False
        object.__setattr__(self, "heights", heights)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "cell_size", cell_size)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.heights.shape)  # type: ignore[return-value]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the cells' outer edges."""
        x0, y0 = self.origin
        rows, cols = self.shape
        return (x0, x0 + cols * self.cell_size, y0 - rows * self.cell_size, y0)

    def x_centres(self) -> np.ndarray:
        """x of the cell centres, one per column."""
        return self.origin[0] + (np.arange(self.shape[1]) + 0.5) * self.cell_size

    def y_centres(self) -> np.ndarray:
        """y of the cell centres, one per row (falling)."""
        return self.origin[1] - (np.arange(self.shape[0]) + 0.5) * self.cell_size

    def slope_deg(self) -> np.ndarray:
        """Slope angle (degrees) by central differences over one cell each way; NaN on the
        border and where the cell or one of its 4 neighbours has no data."""
        slope = dem_slope_deg(self.heights, self.cell_size)  # rows run south: sign irrelevant
        slope[np.isnan(self.heights)] = np.nan
        slope[[0, -1], :] = np.nan
        slope[:, [0, -1]] = np.nan
        return slope


def read_raster(path: str | os.PathLike, *, origin: Sequence[float] | None = None,
                cell_size: float | None = None) -> Raster:
    """A single-band elevation raster with its georeferencing.

    An ESRI ASCII grid (``.asc``, ``.grd``: the header places it) is read by
    :func:`read_ascii_grid`; surveyed ground points (a point cloud file: LAS/LAZ, PLY, PCD,
    XYZ, ...) are gridded by :func:`read_ground_points` (``cell_size`` default 1 m). Other
    pixel values are read by :func:`read_dem` (OpenCV). ``origin`` (x, y of the upper-left
    corner of the upper-left cell) and ``cell_size`` (m) place it; when not given they come
    from the GeoTIFF tags ModelPixelScale (33550) and ModelTiepoint (33922) (or an unrotated
    ModelTransformation, 34264), read with ``tifffile`` (the ``dem`` extra:
    ``pip install 'o3d_terrain[dem]'``); a raster of type PixelIsPoint is shifted by half a
    cell. The GDAL nodata tag (42113) marks cells without data, when tifffile can read it.
    The raster must be in the cloud's coordinates and metres (no reprojection or unit
    conversion is done).
    """
    path = Path(path)
    if path.suffix.lower() in CLOUD_EXTENSIONS:  # surveyed ground points
        return read_ground_points(path, cell_size=1.0 if cell_size is None else cell_size,
                                  origin=origin)
    if (origin is None) != (cell_size is None):
        raise InputError(f"{path}: origin and cell_size go together; give both or neither "
                         "(neither: the GeoTIFF tags are read)")
    if path.suffix.lower() in ASCII_GRID_SUFFIXES:
        raster = read_ascii_grid(path)
        if origin is not None:  # the caller places it
            raster = Raster(raster.heights, origin, cell_size, name=raster.name)
        return raster
    heights = read_dem(path)
    tags, why = _geotiff_tags(path)
    nodata = tags.get(_NODATA)
    if nodata is not None:
        try:
            value = float(str(nodata).strip().strip("\x00"))
        except ValueError:
            value = math.nan
        if math.isfinite(value):
            heights[np.isclose(heights, value, rtol=1e-6, atol=0.0)] = np.nan
    if origin is None:
        if why:
            raise InputError(f"{path}: {why}")
        origin, cell_size = _georeference(path, tags)
    return Raster(heights, origin, cell_size, name=path.name)


#: file suffixes read as ESRI ASCII grids
ASCII_GRID_SUFFIXES = (".asc", ".grd")
_ASCII_KEYS = ("ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize",
               "nodata_value", "dx", "dy")


def read_ascii_grid(path: str | os.PathLike) -> Raster:
    """An ESRI ASCII grid (the common DEM exchange format): a header of ``ncols``, ``nrows``,
    ``xllcorner``/``xllcenter``, ``yllcorner``/``yllcenter``, ``cellsize`` (or equal ``dx``
    and ``dy``) and optionally ``NODATA_value``, then ``nrows`` rows of heights from north to
    south. Cells at NODATA_value become NaN. Errors name the line and what is wrong."""
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii", errors="strict")
    except FileNotFoundError:
        raise InputError(f"{path}: no such DEM file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot be read as an ESRI ASCII grid ({exc})") from None
    lines = text.splitlines()
    header: dict[str, float] = {}
    start = 0
    for start, line in enumerate(lines):
        parts = line.split()
        if not parts:
            continue
        key = parts[0].lower()
        if key[0].isdigit() or key[0] in "+-.":
            break  # the first row of heights
        if key not in _ASCII_KEYS or len(parts) != 2:
            hint = did_you_mean(key, list(_ASCII_KEYS))
            raise InputError(f"{path}: line {start + 1} ({line.strip()[:40]!r}) is not an ESRI "
                             f"ASCII grid header line 'key value'"
                             + (f" ({hint})" if hint else "")
                             + f"; keys are {', '.join(_ASCII_KEYS)}")
        try:
            header[key] = float(parts[1])
        except ValueError:
            raise InputError(f"{path}: line {start + 1}: {parts[0]} must be a number, got "
                             f"{parts[1]!r}") from None
    else:
        start = len(lines)
    if "cellsize" not in header and "dx" in header and "dy" in header:
        if not math.isclose(header["dx"], header["dy"], rel_tol=1e-9):
            raise InputError(f"{path}: cells of {header['dx']} x {header['dy']} are not square; "
                             "resample the grid to square cells")
        header["cellsize"] = header["dx"]
    missing = [k for k in ("ncols", "nrows", "cellsize") if k not in header]
    if not any(k in header for k in ("xllcorner", "xllcenter")):
        missing.append("xllcorner")
    if not any(k in header for k in ("yllcorner", "yllcenter")):
        missing.append("yllcorner")
    if missing:
        raise InputError(f"{path}: the ESRI ASCII grid header lacks {', '.join(missing)}")
    ncols, nrows, cell = int(header["ncols"]), int(header["nrows"]), header["cellsize"]
    if ncols != header["ncols"] or nrows != header["nrows"] or ncols < 1 or nrows < 1:
        raise InputError(f"{path}: ncols and nrows must be positive integers, got "
                         f"{header['ncols']:g} and {header['nrows']:g}")
    try:
        values = np.array(" ".join(lines[start:]).split(), dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path}: the heights after the header are not all numbers "
                         f"({exc})") from None
    if values.size != ncols * nrows:
        raise InputError(f"{path}: the header gives {nrows} rows of {ncols} heights "
                         f"({nrows * ncols}), the file holds {values.size}")
    heights = values.reshape(nrows, ncols)
    if "nodata_value" in header:
        heights[heights == header["nodata_value"]] = np.nan
    # the lower-left corner (or centre) of the lower-left cell -> the upper-left corner
    x0 = header["xllcorner"] if "xllcorner" in header else header["xllcenter"] - cell / 2
    y_low = header["yllcorner"] if "yllcorner" in header else header["yllcenter"] - cell / 2
    return Raster(heights, (x0, y_low + nrows * cell), cell, name=path.name)


def raster_from_points(positions: np.ndarray, cell_size: float, *,
                       origin: Sequence[float] | None = None, name: str = "points") -> Raster:
    """Surveyed ground points gridded into a truth raster: per cell the mean height of the
    points in it, NaN where none fell. ``origin`` (the upper-left corner) aligns the grid;
    by default its corners are multiples of ``cell_size``."""
    p = np.asarray(positions, dtype=np.float64)
    p = p[np.isfinite(p[:, :3]).all(axis=1)] if p.ndim == 2 and p.shape[1] >= 3 else p
    if p.ndim != 2 or p.shape[1] < 3 or len(p) < 3:
        raise InputError(f"{name}: needs at least 3 finite ground points (x, y, z) to make a "
                         f"truth raster; got {len(p) if p.ndim == 2 else 0}")
    if not (math.isfinite(cell_size) and cell_size > 0):
        raise InputError(f"{name}: the truth cell size must be a positive number of metres, "
                         f"got {cell_size}")
    if origin is None:
        x0 = math.floor(p[:, 0].min() / cell_size) * cell_size
        y0 = math.ceil(p[:, 1].max() / cell_size) * cell_size
        if y0 == p[:, 1].max():
            y0 += cell_size  # the northernmost point inside the top row
    else:
        x0, y0 = (float(v) for v in origin)
    col = np.floor((p[:, 0] - x0) / cell_size).astype(np.int64)
    row = np.floor((y0 - p[:, 1]) / cell_size).astype(np.int64)
    inside = (col >= 0) & (row >= 0)
    if not inside.any():
        raise InputError(f"{name}: no ground point lies right of and below the origin "
                         f"{(x0, y0)}")
    col, row, z = col[inside], row[inside], p[inside, 2]
    shape = (max(int(row.max()) + 1, 3), max(int(col.max()) + 1, 3))
    flat = row * shape[1] + col
    total = np.bincount(flat, weights=z, minlength=shape[0] * shape[1])
    count = np.bincount(flat, minlength=shape[0] * shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        heights = np.where(count > 0, total / count, np.nan).reshape(shape)
    return Raster(heights, (x0, y0), cell_size, name=name)


def read_ground_points(path: str | os.PathLike, *, cell_size: float = 1.0,
                       origin: Sequence[float] | None = None) -> Raster:
    """A truth raster from a file of surveyed ground points (any cloud
    :func:`o3d_terrain.io.read_cloud` reads; LAS/LAZ in feet become metres): a LAS/LAZ file
    with ground-classified points (ASPRS class 2) gives those alone, any other file all its
    points. Gridded by :func:`raster_from_points`."""
    path = Path(path)
    cloud = read_cloud(path)
    positions = cloud.point.positions.numpy().astype(np.float64)
    name = path.name
    if "classification" in cloud.point:
        classes = cloud.point["classification"].numpy().reshape(-1)
        if np.any(classes == 2):
            positions, name = positions[classes == 2], f"{path.name} (class 2)"
    return raster_from_points(positions, cell_size, origin=origin, name=name)


def _geotiff_tags(path: Path) -> tuple[dict[int, Any], str]:
    """The first page's tags by code, and why they could not be read ("" when they were)."""
    try:
        import tifffile
    except ImportError:
        return {}, ("reading the GeoTIFF georeferencing needs tifffile: "
                    f"pip install 'o3d_terrain[dem]'; or {_GEOREF_FIX}")
    log = logging.getLogger("tifffile")  # it logs GDAL nodata values it cannot cast
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        with tifffile.TiffFile(path) as tif:
            return {tag.code: tag.value for tag in tif.pages[0].tags.values()}, ""
    except Exception as exc:  # not a TIFF, or a corrupt one
        return {}, f"is not a readable GeoTIFF ({exc}); {_GEOREF_FIX}"
    finally:
        log.setLevel(level)


def _georeference(path: Path, tags: dict[int, Any]) -> tuple[tuple[float, float], float]:
    """Upper-left corner and cell size from the GeoTIFF tags (raises when absent)."""
    if _PIXEL_SCALE in tags and _TIEPOINT in tags:
        sx, sy = (float(v) for v in tuple(tags[_PIXEL_SCALE])[:2])
        i, j, _, x, y = (float(v) for v in tuple(tags[_TIEPOINT])[:5])
        x0, y0 = x - i * sx, y + j * sy
    elif _TRANSFORMATION in tags:
        m = np.asarray(tags[_TRANSFORMATION], dtype=np.float64).reshape(4, 4)
        if m[0, 1] != 0 or m[1, 0] != 0:
            raise InputError(f"{path}: the raster is rotated (ModelTransformationTag); "
                             "resample it north-up first (e.g. gdalwarp)")
        sx, sy, x0, y0 = m[0, 0], -m[1, 1], m[0, 3], m[1, 3]
    else:
        raise InputError(f"{path}: has no GeoTIFF georeferencing (ModelPixelScaleTag 33550 and "
                         f"ModelTiepointTag 33922); {_GEOREF_FIX}")
    if not (sx > 0 and sy > 0):
        raise InputError(f"{path}: pixel scale ({sx}, {sy}) is not positive; {_GEOREF_FIX}")
    if abs(sx - sy) > 1e-9 * max(sx, sy):
        raise InputError(f"{path}: cells of {sx} x {sy} are not square; resample the raster to "
                         "square cells (e.g. gdalwarp -tr)")
    keys = tuple(int(v) for v in tags.get(_GEOKEYS, ()))
    for k in range(4, len(keys) - 3, 4):  # GTRasterTypeGeoKey (1025) = 2: PixelIsPoint
        if keys[k] == 1025 and keys[k + 1] == 0 and keys[k + 3] == 2:
            x0, y0 = x0 - sx / 2, y0 + sy / 2
    return (float(x0), float(y0)), float(sx)


def check_pose(matrix: Any, where: str = "pose") -> np.ndarray:
    """A 4x4 rigid transform as float64: finite, last row 0 0 0 1, rotation part orthonormal
    within 1e-6 with determinant +1. Raises :class:`InputError` naming ``where``."""
    fix = "write 4 rows of 4 numbers: a rotation R and translation t as [[R, t], [0 0 0 1]]"
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: not a matrix of numbers ({fix})") from None
    if m.shape != (4, 4):
        raise InputError(f"{where}: shape {m.shape}; a pose is a 4x4 matrix ({fix})")
    if not np.isfinite(m).all():
        raise InputError(f"{where}: holds non-finite numbers ({fix})")
    if not np.allclose(m[3], (0, 0, 0, 1), rtol=0, atol=1e-12):
        raise InputError(f"{where}: the last row is {m[3].tolist()}, it must be 0 0 0 1 ({fix})")
    rotation = m[:3, :3]
    deviation = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if deviation > 1e-6:
        raise InputError(f"{where}: the rotation part is not orthonormal (R^T R differs from I "
                         f"by {deviation:.2g}; scaling and shear are not allowed); give a rigid "
                         "transform with its rotation written to at least 7 digits")
    if np.linalg.det(rotation) < 0:
        raise InputError(f"{where}: the rotation part is a reflection (determinant -1); give "
                         "a proper rotation (determinant +1)")
    return m


def read_pose(path: str | os.PathLike) -> np.ndarray:
    """A 4x4 pose from a text file (whitespace separated, as ``numpy.loadtxt`` reads),
    checked by :func:`check_pose`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such pose file")
    try:
        matrix = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path}: not a matrix of numbers ({exc}); write 4 rows of 4 numbers "
                         "separated by spaces") from exc
    return check_pose(matrix, where=str(path))


def _extent_text(extent: Sequence[float]) -> str:
    x0, x1, y0, y1 = extent
    return f"x {x0:.2f} to {x1:.2f}, y {y0:.2f} to {y1:.2f}"


def _error_stats(height_error: np.ndarray, slope_error: np.ndarray) -> dict[str, float]:
    """Height and slope error statistics of the finite entries (m and degrees)."""
    h = height_error[np.isfinite(height_error)]
    s = slope_error[np.isfinite(slope_error)]
    nan = math.nan
    return {
        "cells": int(h.size),
        "height_bias_m": float(h.mean()) if h.size else nan,
        "height_rmse_m": float(np.sqrt(np.mean(h * h))) if h.size else nan,
        "height_mae_m": float(np.abs(h).mean()) if h.size else nan,
        "height_p95_abs_m": float(np.percentile(np.abs(h), 95)) if h.size else nan,
        "height_max_abs_m": float(np.abs(h).max()) if h.size else nan,
        "slope_cells": int(s.size),
        "slope_bias_deg": float(s.mean()) if s.size else nan,
        "slope_rmse_deg": float(np.sqrt(np.mean(s * s))) if s.size else nan,
        "slope_p95_abs_deg": float(np.percentile(np.abs(s), 95)) if s.size else nan,
    }


@dataclass(frozen=True, eq=False)
class RasterTerrainResult(TerrainResult):
    """A :class:`TerrainResult` against a truth raster: the error maps cover the raster
    window ``rows`` x ``cols`` (``[row, col]``, NaN = not scored); ``stats`` are every scored
    cell's statistics and ``steep`` those of the cells whose truth slope exceeds
    ``steep_slope_deg`` (None when there are none)."""

    rows: tuple[int, int] = (0, 0)  # first and last + 1 raster row of the maps
    cols: tuple[int, int] = (0, 0)
    support_distance: float = math.nan
    truth: str = ""  # the raster's name
    stats: dict[str, float] = field(default_factory=dict)
    steep: dict[str, float] | None = None
    steep_slope_deg: float = STEEP_SLOPE_DEG

    def to_dict(self) -> dict[str, Any]:
        return {
            **super().to_dict(),
            "scored_cells": self.stats["cells"],
            "height_mae_m": self.stats["height_mae_m"],
            "height_max_abs_m": self.stats["height_max_abs_m"],
            "all": self.stats,
            "steep": self.steep,
            "steep_slope_deg": self.steep_slope_deg,
            "support_distance_m": self.support_distance,
            "truth": self.truth,
            "raster_window": {"rows": list(self.rows), "cols": list(self.cols)},
        }

    def markdown_details(self) -> list[str]:
        lines = [
            "",
            f"Scored {self.stats['cells']:,} cells of the raster `{self.truth}`: centre inside "
            f"the fitted region, valid truth, a cloud point within {self.support_distance:g} m; "
            "slope where the 4 neighbours are valid too.",
            "",
            "| cells | n | bias (m) | RMSE (m) | MAE (m) | p95 abs (m) | max abs (m) | "
            "slope RMSE (°) | slope p95 (°) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        subsets = [("all", self.stats)]
        if self.steep:
            subsets.append((f"truth slope > {self.steep_slope_deg:g}°", self.steep))
        for label, s in subsets:
            lines.append(
                f"| {label} | {s['cells']:,} | {_f(s['height_bias_m'], 3)} | "
                f"{_f(s['height_rmse_m'], 3)} | {_f(s['height_mae_m'], 3)} | "
                f"{_f(s['height_p95_abs_m'], 3)} | {_f(s['height_max_abs_m'], 3)} | "
                f"{_f(s['slope_rmse_deg'], 2)} | {_f(s['slope_p95_abs_deg'], 2)} |")
        if not self.steep:
            lines.append(f"| truth slope > {self.steep_slope_deg:g}° | 0 | | | | | | | |")
        return lines


def _truth_raster(raster: Any, origin, cell_size) -> Raster:
    if isinstance(raster, Raster):
        if origin is not None or cell_size is not None:
            raise InputError("origin and cell_size are those of the Raster given; leave them "
                             "out or pass the heights array instead")
        return raster
    if isinstance(raster, (str, os.PathLike)):
        return read_raster(raster, origin=origin, cell_size=cell_size)
    if origin is None or cell_size is None:
        raise InputError("a truth raster given as an array needs origin= (x, y of its "
                         "upper-left corner) and cell_size= (m)")
    return Raster(np.asarray(raster, dtype=np.float64), origin, cell_size, name="array")


def _truth_positions(cloud: Any, pose: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Finite (N, 3) float64 positions of a cloud or file, moved by ``pose``; the checked
    pose matrix (None without one)."""
    from ..api import cloud_positions

    if isinstance(cloud, (str, os.PathLike)):
        cloud = read_cloud(cloud)
    positions = cloud_positions(cloud)
    positions = positions[np.isfinite(positions).all(axis=1)]
    if len(positions) == 0:
        raise InputError("the cloud has no finite points; give a cloud with points")
    if pose is None:
        return positions, None
    m = read_pose(pose) if isinstance(pose, (str, os.PathLike)) else check_pose(pose)
    return transform_points(positions, m), m


def evaluate_terrain_against_raster(
    cloud: Any,
    raster: Raster | np.ndarray | str | os.PathLike,
    *,
    origin: Sequence[float] | None = None,
    cell_size: float | None = None,
    pose: np.ndarray | str | os.PathLike | None = None,
    fitter: Fitter | None = None,
    fit_options: dict[str, Any] | None = None,
    surface: Any = None,
    support_distance: float | None = None,
    steep_slope_deg: float = STEEP_SLOPE_DEG,
    min_cells: int = 10,
    name: str | None = None,
) -> TerrainReport:
    """Fit the terrain of a measured cloud and compare it with a surveyed elevation raster.

    cloud: a file :func:`o3d_terrain.io.read_cloud` reads (LAS/LAZ in feet become metres), an
    Open3D cloud or an (N, 3) array. raster: a :class:`Raster`, a GeoTIFF/raster path
    (:func:`read_raster` with ``origin``/``cell_size``) or a heights array with ``origin``
    and ``cell_size``; it must be in metres and in the coordinates of the cloud after
    ``pose``. pose: a 4x4 rigid transform (array or text file) from the cloud's coordinates
    into the raster's, applied before fitting. fitter: ``positions -> surface``; default
    :func:`o3d_terrain.api.fit_terrain` with ``fit_options``, whose ``sensor_origin``
    defaults to where the pose puts the cloud's origin (a scan's sensor). Or give ``surface``,
    already fitted in the raster's coordinates.

    Scored raster cells: the centre lies inside the surface's region (the cloud's extent when
    the surface has none), the truth is valid (not nodata/NaN) and a cloud point lies within
    ``support_distance`` m horizontally of the centre (default: the larger of the raster's
    cell and the fit grid's cell, ``surface.cell_size`` or 0.5 m). Height error = surface -
    truth at the centres; slope error = ``surface.slope_deg`` - the raster's slope by central
    differences (cells whose 4 neighbours are valid). Raises :class:`TruthOverlapError` when
    cloud and raster do not overlap or fewer than ``min_cells`` cells are scored.
    """
    problems = []
    if sum(v is not None for v in (fitter, fit_options, surface)) > 1:
        problems.append("give one of fitter, fit_options and surface, not several")
    if support_distance is not None and not (support_distance > 0
                                             and math.isfinite(support_distance)):
        problems.append(f"support_distance must be a positive number of metres (or None), "
                        f"got {support_distance}")
    if not (isinstance(min_cells, int) and min_cells >= 1):
        problems.append(f"min_cells must be an integer >= 1, got {min_cells!r}")
    if not (0 <= steep_slope_deg < 90):
        problems.append(f"steep_slope_deg must be in [0, 90) degrees, got {steep_slope_deg}")
    if problems:
        raise InputError("evaluate_terrain_against_raster: " + "; ".join(problems))
    # the truth, and the points in its coordinates
    truth = _truth_raster(raster, origin, cell_size)
    positions, pose_matrix = _truth_positions(cloud, pose)
    label = name or (Path(cloud).stem if isinstance(cloud, (str, os.PathLike)) else "cloud")
    # the two must share some area
    lo, hi = positions[:, :2].min(axis=0), positions[:, :2].max(axis=0)
    cloud_extent = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    rx0, rx1, ry0, ry1 = truth.extent
    if lo[0] >= rx1 or hi[0] <= rx0 or lo[1] >= ry1 or hi[1] <= ry0:
        raise TruthOverlapError(
            f"the cloud ({_extent_text(cloud_extent)}"
            f"{' after the pose' if pose is not None else ''}) and the raster {truth.name} "
            f"({_extent_text(truth.extent)}) do not overlap; give the raster of the cloud's "
            "area, or a pose mapping the cloud into the raster's coordinates")
    # fit
    seconds = 0.0
    if surface is None:
        if fitter is None:
            options = dict(fit_options or {})
            if pose_matrix is not None:  # the cloud's origin, e.g. the sensor, after the pose
                options.setdefault("sensor_origin", tuple(float(v) for v in pose_matrix[:3, 3]))
            fitter = default_fitter(**options)
        start = time.perf_counter()
        surface = fitter(positions)
        seconds = time.perf_counter() - start
    # score
    result = _score_against_raster(label, surface, truth, positions, seconds=seconds,
                                   support_distance=support_distance,
                                   steep_slope_deg=steep_slope_deg, min_cells=min_cells,
                                   cloud_extent=cloud_extent)
    report = TerrainReport(source=f"{label} against {truth.name}"
                                  + (" (with a pose)" if pose is not None else ""))
    report.results.append(result)
    report.maps = {"height_error": result.height_error, "slope_error": result.slope_error}
    return report


def _score_against_raster(name: str, surface: Any, truth: Raster, positions: np.ndarray, *,
                          seconds: float, support_distance: float | None,
                          steep_slope_deg: float, min_cells: int,
                          cloud_extent: tuple[float, float, float, float]
                          ) -> RasterTerrainResult:
    """Compare ``surface`` with ``truth`` at the supported raster cell centres."""
    from scipy.spatial import cKDTree

    region = tuple(float(v) for v in getattr(surface, "region", cloud_extent))
    if support_distance is None:
        support_distance = max(truth.cell_size, float(getattr(surface, "cell_size", None) or 0.5))
    # the raster window under the fitted region
    xc, yc = truth.x_centres(), truth.y_centres()
    cols = np.flatnonzero((xc >= region[0]) & (xc <= region[1]))
    rows = np.flatnonzero((yc >= region[2]) & (yc <= region[3]))
    if cols.size == 0 or rows.size == 0:
        raise TruthOverlapError(
            f"no cell centre of the raster {truth.name} ({_extent_text(truth.extent)}) lies in "
            f"the fitted region ({_extent_text(region)}); give the raster of the cloud's area")
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    gx, gy = np.meshgrid(xc[c0:c1], yc[r0:r1])  # [row, col] like the raster
    heights = truth.heights[r0:r1, c0:c1]
    # cells with valid truth and a cloud point within support_distance of the centre
    scored = np.isfinite(heights)
    distance, _ = cKDTree(positions[:, :2]).query(
        np.column_stack([gx[scored], gy[scored]]), distance_upper_bound=support_distance)
    scored[scored] = np.isfinite(distance)
    if int(scored.sum()) < min_cells:
        raise TruthOverlapError(
            f"only {int(scored.sum())} cells of the raster {truth.name} have valid truth and a "
            f"cloud point within {support_distance:g} m (at least {min_cells} are needed; cloud "
            f"{_extent_text(cloud_extent)}, raster {_extent_text(truth.extent)}); give the "
            "raster of the cloud's area, a denser cloud or a larger support_distance "
            "(--support-distance)")
    true_slope = np.where(scored, truth.slope_deg()[r0:r1, c0:c1], np.nan)
    notes = (f"truth: {truth.name}, {truth.shape[0]} x {truth.shape[1]} cells of "
             f"{truth.cell_size:g} m, {_extent_text(truth.extent)}",
             f"cloud: {len(positions):,} points, {_extent_text(cloud_extent)}")
    base = compare_surface(name, surface, gx, gy, np.where(scored, heights, np.nan), true_slope,
                           points=len(positions), seconds=seconds, notes=notes)
    steep = np.isfinite(true_slope) & (true_slope > steep_slope_deg)
    steep_stats = None
    if steep.any():
        steep_stats = _error_stats(np.where(steep, base.height_error, np.nan),
                                   np.where(steep, base.slope_error, np.nan))
    return RasterTerrainResult(
        **{f.name: getattr(base, f.name) for f in fields(TerrainResult)},
        rows=(r0, r1), cols=(c0, c1), support_distance=float(support_distance), truth=truth.name,
        stats=_error_stats(base.height_error, base.slope_error), steep=steep_stats,
        steep_slope_deg=float(steep_slope_deg))


# ---------------------------------------------------------------------------------------------
# error-map image


def _colourise(values: np.ndarray, limit: float, label: str, scale: int) -> np.ndarray:
    """A diverging colour image (blue below, red above, grey NaN) with a legend line."""
    v = np.clip(np.nan_to_num(values / limit if limit > 0 else values * 0), -1, 1)
    t = ((v + 1) * 127.5).astype(np.uint8)
    image = cv2.applyColorMap(t, cv2.COLORMAP_JET)
    image[~np.isfinite(values)] = (96, 96, 96)
    image = np.ascontiguousarray(np.rot90(image))  # [ix, iy] arrays: y up, x right
    image = cv2.resize(image, (image.shape[1] * scale, image.shape[0] * scale),
                       interpolation=cv2.INTER_NEAREST)
    band = np.full((28, image.shape[1], 3), 255, np.uint8)
    cv2.putText(band, f"{label}: blue -{limit:.2g}, red +{limit:.2g}", (4, 19),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([band, image])


def write_error_map(path: str | os.PathLike, height_error: np.ndarray, slope_error: np.ndarray,
                    *, height_limit: float | None = None, slope_limit: float | None = None,
                    grid_is_xy: bool = True) -> Path:
    """Write height and slope error maps side by side as a PNG (fitted minus true).

    Arrays are indexed ``[ix, iy]`` when ``grid_is_xy`` (the synthetic grids), else
    ``[row, col]`` like a raster. Limits default to the 99th percentile of |error|.
    """
    path = Path(path)
    if not grid_is_xy:  # raster [row, col] -> [ix, iy] with y up
        height_error = np.flipud(height_error).T
        slope_error = np.flipud(slope_error).T
    def limit(values, given):
        if given:
            return given
        finite = np.abs(values[np.isfinite(values)])
        return float(np.percentile(finite, 99)) if finite.size else 1.0
    longest = max(height_error.shape)
    scale = max(1, int(600 // max(longest, 1)))
    left = _colourise(height_error, limit(height_error, height_limit), "height error (m)", scale)
    right = _colourise(slope_error, limit(slope_error, slope_limit), "slope error (deg)", scale)
    gap = np.full((left.shape[0], 8, 3), 255, np.uint8)
    image = np.hstack([left, gap, right])
    output_path(path)
    if not cv2.imwrite(str(path), image):
        raise InputError(f"{path}: OpenCV could not write the PNG (check the folder is writable)")
    return path
