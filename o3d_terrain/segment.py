"""Segmentation of points against a terrain surface: signed height above terrain and labels.

A point's height above the terrain is h = z - S(x, y) (vertical, metres). With a threshold
t(r) = threshold + range_coefficient * r^2 that may grow with the point's horizontal range r
from the sensor (stereo depth noise grows with range squared):

- TERRAIN: -below_threshold <= h <= t(r)
- OBSTACLE: h > t(r)
- BELOW_TERRAIN: h < -below_threshold (multipath, reflections, stereo mismatches)
- UNKNOWN: non-finite coordinates or outside the surface's region
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from ._kernels import bspline as _bs
from .errors import InputError
from .misfit import block_size, misfit_thresholds
from .spline import TerrainSurface

__all__ = ["TerrainLabel", "heights_above_terrain", "segment_points", "thresholds",
           "auto_threshold", "label_heights", "widen_labels"]

#: the automatic obstacle threshold: this many robust noise scales, clipped to [low, high] m
AUTO_THRESHOLD_FACTOR = 3.5
AUTO_THRESHOLD_RANGE = (0.1, 0.5)


class TerrainLabel(IntEnum):
    """Per-point labels written by :func:`segment_points` (attribute ``labels``)."""

    UNKNOWN = 0
    TERRAIN = 1
    OBSTACLE = 2
    BELOW_TERRAIN = 3


def _positions(positions) -> np.ndarray:
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 3:
        raise InputError(f"positions must be an (N, 3) array, got shape {p.shape}")
    return p[:, :3]


def heights_above_terrain(surface: TerrainSurface, positions) -> np.ndarray:
    """Signed vertical height z - S(x, y) of each point (N,); NaN when undefined."""
    p = _positions(positions)
    if isinstance(surface, TerrainSurface):
        return surface.heights_above(p)
    return p[:, 2] - surface(p[:, 0], p[:, 1])


def thresholds(positions, *, threshold: float, range_coefficient: float = 0.0,
               sensor_origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Per-point obstacle threshold t(r) = threshold + range_coefficient * r^2 (metres),
    r = horizontal distance from ``sensor_origin``."""
    p = _positions(positions)
    if range_coefficient == 0.0:
        return np.full(len(p), float(threshold))
    r2 = (p[:, 0] - sensor_origin[0]) ** 2 + (p[:, 1] - sensor_origin[1]) ** 2
    return threshold + range_coefficient * r2


def _check(name: str, value, *, positive: bool) -> str | None:
    if not (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value) and (value > 0 if positive else value >= 0)):
        return f"{name} must be a finite number {'> 0' if positive else '>= 0'} (metres), got {value!r}"
    return None


def auto_threshold(heights: np.ndarray, *, factor: float = AUTO_THRESHOLD_FACTOR,
                   low: float = AUTO_THRESHOLD_RANGE[0],
                   high: float = AUTO_THRESHOLD_RANGE[1]) -> float:
    """Obstacle threshold from the data: ``factor`` times the robust spread (1.4826 x median
    absolute value) of the heights at or below the surface (terrain noise; obstacles never lie
    below it), clipped to [low, high] m. Uses every k-th point, k = max(1, N // 50,000)."""
    step = max(1, len(heights) // 50_000)
    median, count = _bs.below_surface_median(
        np.ascontiguousarray(heights, dtype=np.float64), step, float(high))
    if count < 10:
        return low
    noise = 1.4826 * float(median)
    return float(np.clip(factor * noise, low, high))


def segment_points(surface: TerrainSurface, positions, *, threshold: float | None = 0.2,
                   below_threshold: float = 0.5, range_coefficient: float = 0.0,
                   sensor_origin=(0.0, 0.0, 0.0), misfit: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Labels (N,) uint8 :class:`TerrainLabel` values and heights above terrain (N,) float64.

    threshold: points higher than this above the surface are obstacles (m); None = from the
        data (:func:`auto_threshold`).
    below_threshold: points lower than this below the surface are BELOW_TERRAIN noise (m).
    range_coefficient: growth of the threshold with horizontal range squared (1/m), for
        stereo clouds; 0 = constant threshold.
    sensor_origin: (x, y, z) of the sensor, for the range (cloud coordinates).
    misfit: with ``threshold`` None, widen the threshold (both sides) where the surface's
        local misfit to the ground exceeds the noise (:mod:`o3d_terrain.misfit`).
    """
    problems = [m for m in (None if threshold is None
                            else _check("threshold", threshold, positive=True),
                            _check("below_threshold", below_threshold, positive=True),
                            _check("range_coefficient", range_coefficient, positive=False))
                if m]
    if len(sensor_origin) != 3 or not all(math.isfinite(float(v)) for v in sensor_origin):
        problems.append(f"sensor_origin must be three finite numbers, got {sensor_origin!r}")
    if problems:
        raise InputError("segment_points: " + "; ".join(problems))
    p = _positions(positions)
    h = heights_above_terrain(surface, p)
    local = None
    if threshold is None:
        threshold = auto_threshold(h)
        if misfit and isinstance(surface, TerrainSurface):
            local = misfit_thresholds(p, h, threshold, block=block_size(surface),
                                      grade=lambda x, y: np.hypot(*surface.gradient(x, y)))
    labels = label_heights(h, p, threshold=threshold, below_threshold=below_threshold,
                           range_coefficient=range_coefficient, sensor_origin=sensor_origin)
    if local is not None and local.max(initial=threshold) > threshold:
        widen_labels(labels, h, local, threshold)
    return labels, h


def widen_labels(labels: np.ndarray, heights: np.ndarray, local: np.ndarray,
                 threshold: float) -> None:
    """In place, at the points whose threshold ``local`` is wider than the global
    ``threshold`` the labels used: OBSTACLE points with h <= local and BELOW_TERRAIN points
    with h >= -local become TERRAIN."""
    wide = local > threshold
    labels[wide & (labels == TerrainLabel.OBSTACLE) & (heights <= local)] = TerrainLabel.TERRAIN
    labels[wide & (labels == TerrainLabel.BELOW_TERRAIN)
           & (heights >= -local)] = TerrainLabel.TERRAIN


def label_heights(heights: np.ndarray, positions, *, threshold: float, below_threshold: float,
                  range_coefficient: float = 0.0, sensor_origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Labels (N,) uint8 from heights above the terrain (the rule of :func:`segment_points`,
    options assumed checked)."""
    p = _positions(positions)
    return _bs.label_heights(
        np.ascontiguousarray(heights, dtype=np.float64), p, float(threshold),
        float(below_threshold), float(range_coefficient), float(sensor_origin[0]),
        float(sensor_origin[1]), int(TerrainLabel.UNKNOWN), int(TerrainLabel.TERRAIN),
        int(TerrainLabel.OBSTACLE), int(TerrainLabel.BELOW_TERRAIN))
