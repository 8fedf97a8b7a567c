"""Terrain evaluation: height and slope of a fitted surface against an exact terrain.

Two sources of exact terrain:

* the synthetic scenes (``o3d_terrain.synthetic``): a lidar or stereo frame is sampled, the
  surface is fitted to it in the sensor frame and compared on a grid with the exact terrain in
  that frame; only grid nodes whose cell holds a terrain point are scored (no credit or blame
  for extrapolating into occlusion shadows);
* a DEM raster (e.g. ``dem.tif``, 1 m cells): windows of the DEM the size of a vehicle's area of
  interest are sampled into clouds (bilinear heights, optional noise and box obstacles), each
  window is fitted, and the surface is compared with the DEM heights at the cell centres and
  with the DEM's slope (central differences over one cell).

A *fitter* is a callable ``(positions) -> surface`` where ``surface(x, y)`` is the height and
``surface.slope_deg(x, y)`` the slope angle in degrees; ours is
:func:`o3d_terrain.api.fit_terrain`. Results carry per-node error maps; :func:`write_error_map`
draws them as a PNG with OpenCV.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from ..errors import InputError
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
        for name, reason in self.failures:
            lines.append("")
            lines.append(f"- skipped `{name}`: {reason}")
        return "\n".join(lines)


def _f(value: float, digits: int) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def default_fitter(**options: Any) -> Fitter:
    """Our :func:`o3d_terrain.api.fit_terrain` with these options."""
    try:
        from ..api import fit_terrain
    except ImportError as exc:
        raise InputError(f"o3d_terrain.api.fit_terrain is not available in this build ({exc})") from exc

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
    """Fit each synthetic scene's sampled cloud and compare with its exact terrain."""
    from .datasets import synthetic_frames, FrameFailure

    fitter = fitter or default_fitter()
    report = TerrainReport(source=f"synthetic {sensor} (seed {seed})")
    for frame in synthetic_frames(names, seed=seed, sensor=sensor):
        if isinstance(frame, FrameFailure):
            report.failures.append((frame.name, frame.reason))
            continue
        try:
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
    dem = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
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
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise InputError(f"{path}: OpenCV could not write the PNG (check the folder is writable)")
    return path
