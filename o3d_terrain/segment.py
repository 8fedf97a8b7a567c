"""Segmentation of points against a terrain surface: signed height above terrain and labels.

A point's height above the terrain is h = z - S(x, y) (vertical, metres). With a threshold
t(r) = threshold + range_coefficient * r^2 that may grow with the point's horizontal range r
from the sensor (stereo depth noise grows with range squared):

- TERRAIN: -below_threshold <= h <= t(r)
- OBSTACLE: h > t(r)
- BELOW_TERRAIN: h < -below_threshold (multipath, reflections, stereo mismatches)
- UNKNOWN: non-finite coordinates or outside the surface's region

Then the feet of objects (:func:`mark_object_feet`): TERRAIN points in a small x/y column
(``foot_cell``, 0.15 m) whose points are for a good part OBSTACLE points less than
``foot_height`` (0.5 m) above the terrain and above the local noise, next to an object at least
0.35 m high, are the base of that object (a bush, a wall, a wheel, a post) and become OBSTACLE.
Height alone cannot tell the lowest centimetres of an object from the ground beside it; the
column can.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from enum import IntEnum

import numpy as np

from ._kernels import bspline as _bs
from ._kernels import foot as _foot
from ._kernels import local_plane as _lp
from .errors import InputError
from .misfit import (
    MISFIT_HIGH,
    block_size,
    face_points,
    local_plane_terrain,
    misfit_reach,
    over_terrain,
    plane_radius,
    widened_thresholds,
)
from .spline import TerrainSurface

__all__ = ["SCAN_DENSITY_FALL", "TerrainLabel", "auto_range_coefficient", "auto_threshold",
           "earlier_returns", "heights_above_terrain", "keep_last_returns", "label_heights",
           "line_spacing_finder", "mark_object_feet", "out_of_sight", "relabel_along_normal",
           "scan_line_spacing", "segment_points", "sensor_ground_gradient", "sensor_in_cloud",
           "thresholds", "widen_labels"]

#: the automatic obstacle threshold: this many robust noise scales, clipped to [low, high] m.
#: The floor covers the terrain's own relief inside a cell, which the surface of 0.5 m cells
#: does not follow, not only the sensor's noise: with a 0.1 m floor a low-noise lidar lost the
#: ground of berms and ditches (synthetic ditch_berm recall 95.9 %; docs/algorithm.md,
#: "Automatic threshold floor")
AUTO_THRESHOLD_FACTOR = 3.5
AUTO_THRESHOLD_RANGE = (0.13, 0.5)
#: where the ground's own centre lies above the surface (eq. 1's low samples leave a noisy
#: ground's surface about half a noise scale under it), the automatic threshold is at least
#: that centre plus this many noise scales measured from the centre: measured from the
#: surface, the points below it are the ground's lower tail alone and their spread about
#: three quarters of the noise, which put a 5 cm noise's threshold 2.2 scales above the
#: ground and lost 1.4-3 % of it (docs/algorithm.md, "The threshold on a noisy ground")
AUTO_CENTRED_FACTOR = 2.5
#: heights sampled for that centre and its spread: their medians stand within about 1.3 % of
#: a noise scale of the whole cloud's (0.06 ms a KITTI frame; 0.8 ms from every second height)
CENTRE_SAMPLE = 10_000

#: which returns of a pulse may be terrain (the Segmenter's ground_returns): the last (or
#: only) one, the ground filters' usual rule (PDAL's SMRF and PMF default to it), or all
GROUND_RETURNS = ("last", "all")

#: the thresholds are distances along the surface normal (:func:`relabel_along_normal`):
#: vertically t * sqrt(1 + |grad S|^2), at most this many times t (the factor of a 60° face)
NORMAL_FACTOR_MAX = 2.0

#: object feet (:func:`mark_object_feet`): column side (m), how high above the terrain an
#: obstacle point marks its column (m), the share of a column's low points the marks need, the
#: side of the cells whose points below the surface give the local noise (m)
FOOT_CELL = 0.15
FOOT_HEIGHT = 0.5
FOOT_FRACTION = 0.3
FOOT_NOISE_CELL = 1.0
#: the least height (m) a foot column's highest mark must reach above its lowest point: what
#: terrain of about 34 degrees rises across a 0.15 m column
FOOT_RISE = 0.1
#: the height (m) above the terrain of an obstacle point that shows an object stands at a
#: column (in it or one of its 8 neighbours)
FOOT_OBJECT = 0.35
#: on a scan of lines (a rotating lidar), the foot height grows with range to this many times
#: the height between neighbouring scan lines on a vertical face there (range x tan of the
#: angle between the lines, :func:`scan_line_spacing`), at most FOOT_CAP (m): a sparse lidar's
#: lowest return on an object's face at range lies that far above the ground return before it
#: (docs/algorithm.md, "Feet of objects", "... on a sparse lidar")
FOOT_LINES = 3.0
FOOT_CAP = 1.5
#: on such a scan whose noise does not grow with range (a lidar's), TERRAIN points within
#: FOOT_BEHIND (m, x/y) of a mark beside an object and at least FOOT_BEHIND_MARGIN (m) farther
#: from the sensor than it lie behind the object's low part, where the sensor sees no ground
#: (docs/algorithm.md, "Ground behind the low part of an object")
FOOT_BEHIND = 0.2
FOOT_BEHIND_MARGIN = 0.13
#: a column is no foot when its lowest mark lies more than FOOT_GAP (m), or FOOT_LINES
#: scan-line gaps at its range, above its highest terrain point: free space under an overhang
#: (a car's body, a branch), where the ground below is seen (docs/algorithm.md, "Free space
#: under an overhang")
FOOT_GAP = 0.15
#: :func:`out_of_sight`: a point above the sensor is terrain only where the surface rises away
#: from the sensor, along the line of sight, at least this many degrees less steeply than the
#: line of sight itself (ground above a ground-based sensor is seen only where it faces it;
#: the margin covers the surface's slope error, docs/algorithm.md, "Ground the sensor could
#: not see")
SIGHT_MARGIN_DEG = 5.0
#: ... and only when the TERRAIN points within :data:`SENSOR_GROUND_RADIUS` of the sensor lie
#: at least this far (m, their median) below it: a sensor that scans the ground from above it,
#: not a frame whose origin sits on the ground (a vehicle's base frame, a tile's corner)
SIGHT_MIN_HEIGHT = 0.3
#: ... measured on every k-th point, k = max(1, count // this)
SIGHT_SAMPLE = 20_000
#: :func:`scan_line_spacing`: the wedges' half-width (deg), the ranges they cover (m), the
#: largest elevation gap within one scan line (deg), the fewest gaps for an estimate and the
#: most points it reads (every k-th point of larger clouds)
LINE_WEDGE_DEG = 0.5
LINE_RANGES = (2.0, 40.0)
LINE_SAME_DEG = 0.1
LINE_MIN_GAPS = 20
LINE_POINTS = 60_000


#: a range-dependent automatic threshold (:func:`auto_range_coefficient`): the points at or
#: below the surface in this many equal-count range bins ...
AUTO_RANGE_BINS = 8
#: ... whose robust spread follows s = a + c r^2 (coefficient of determination at least
#: this) ...
AUTO_RANGE_FIT = 0.4
#: ... and grows by at least this factor from the narrowest bin to the farthest (which is at
#: least :data:`AUTO_RANGE_TOP` times the widest): a sensor whose noise grows with range
#: squared (stereo), not a lidar, whose spread below the surface grows only where sparse rings
#: leave the ground unsampled and then levels off (docs/algorithm.md, "A threshold that grows
#: with range, from the data")
AUTO_RANGE_GROWTH = 3.0
#: ... the farthest bin's spread at least this share of the widest bin's: a terrain feature
#: the surface misses at one range (a ditch) widens that bin alone
AUTO_RANGE_TOP = 0.7
#: ... spreads below this (m) count as this in the growth: a lidar's spread of a few
#: millimetres is its resolution, and ratios of such spreads say nothing about range
AUTO_RANGE_FLOOR = 0.01
#: ... and from each bin to the next it grows at most this many times what the bins' r^2
#: explains: noise growing with range grows gradually, a face or a ditch the surface misses
#: at one range makes the spread jump from one bin to the next
AUTO_RANGE_STEP = 3.0
#: a scan whose lines lie at least this far apart (deg, :func:`scan_line_spacing`) is a rotating
#: lidar's, whose noise does not grow with range squared: no range term (its spread below the
#: surface grows where sparse rings leave the ground unsampled, which the criteria above,
#: loosened for stereo clouds, could take for a stereo camera's noise; docs/algorithm.md, "A
#: threshold that grows with range, from the data", its paragraph "Scan lines, and looser
#: criteria for the other clouds")
AUTO_RANGE_LINES = 0.3
#: ... measured on every k-th of those points, k = max(1, count // this) (a few thousand
#: points give the 8 medians; sorting all of a lidar frame's would cost milliseconds)
AUTO_RANGE_SAMPLE = 2048
#: where the range term stops growing (m): objects taller than this (a rock a vehicle must not
#: drive over; the height the obstacle-recall target counts) stay obstacles at any range
AUTO_RANGE_HIGH = 0.3
#: the least-squares growth of the nearer bins' spread (all but the farthest) with r^2 must be
#: at least this fraction of the growth fitted over all bins (a sensor's noise grows over the
#: whole range; an object or a crest the surface misses at the far end of the scan raises the
#: farthest bin alone)
AUTO_RANGE_NEAR = 0.25

#: the misfit's slope term measures slope against the ground under the sensor: the terrain
#: points (|h| <= threshold) within this horizontal distance (m) of ``sensor_origin`` ...
SENSOR_GROUND_RADIUS = 15.0
#: ... when at least this many of them lie there (otherwise against the cloud's z axis)
SENSOR_GROUND_MIN_POINTS = 100
#: a scan made from ``sensor_origin`` (a lidar's, a stereo camera's) is denser near it: its
#: points per square metre fall with range, from the ring SCAN_NEAR to the ring SCAN_FAR (m,
#: beyond the first points: a sensor mounted high sees no ground within metres of it), by at
#: least this factor (4.0 or more on every vehicle frame measured: SemanticKITTI at 64, 32
#: and 16 lines, cropped, tilted; the synthetic lidars, mounted high, low, pitched, rolled,
#: 16 lines; solid-state lidars and stereo; the `dem.tif` sites; the pit; a cab 4 or 6 m over
#: a raised road), while a top-down tile's stay level (1.5 at most for the LAS tiles and the
#: `dem.tif` airborne strips centred at the origin): a tile in local coordinates around the
#: origin is not a vehicle's scan (docs/algorithm.md, "A tile around the origin"). A tile
#: narrower than about 50 m does not fill the far ring and still reads as a scan.
SCAN_DENSITY_FALL = 2.5
SCAN_NEAR = (0.0, 8.0)
SCAN_FAR = (13.0, 38.0)
#: ... the rings measured from where the first SCAN_FIRST of the points within reach lie
SCAN_FIRST = 0.002
#: ... tested only when both rings hold at least this many points (a small tile does not
#: reach the far ring): fewer keep the scan a vehicle's
SCAN_RING_MIN_POINTS = 50
#: ... counted over every k-th point, k = max(1, N // SCAN_SAMPLE), in 0.5 m bins of range
SCAN_SAMPLE = 20_000
_SCAN_BIN = 0.5


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
               sensor_origin=(0.0, 0.0, 0.0), range_high: float = math.inf) -> np.ndarray:
    """Per-point obstacle threshold t(r) = min(threshold + range_coefficient * r^2,
    max(range_high, threshold)) (metres), r = horizontal distance from ``sensor_origin``."""
    p = _positions(positions)
    if range_coefficient == 0.0:
        return np.full(len(p), float(threshold))
    r2 = (p[:, 0] - sensor_origin[0]) ** 2 + (p[:, 1] - sensor_origin[1]) ** 2
    return np.minimum(threshold + range_coefficient * r2, max(range_high, threshold))


def _check(name: str, value, *, positive: bool, unit: str = "metres") -> str | None:
    if not (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value) and (value > 0 if positive else value >= 0)):
        return f"{name} must be a finite number {'> 0' if positive else '>= 0'} ({unit}), got {value!r}"
    return None


def auto_threshold(heights: np.ndarray, *, factor: float = AUTO_THRESHOLD_FACTOR,
                   low: float = AUTO_THRESHOLD_RANGE[0],
                   high: float = AUTO_THRESHOLD_RANGE[1],
                   centred_factor: float = AUTO_CENTRED_FACTOR) -> float:
    """Obstacle threshold from the data: ``factor`` times the robust spread (1.4826 x median
    absolute value) of the heights at or below the surface (terrain noise; obstacles never lie
    below it), clipped to [low, high] m; where the median c of the heights within that
    threshold and above -high (the ground's centre) lies above the surface, at least c +
    ``centred_factor`` times the robust spread of those heights below c (1.4826 x median of
    c - h), clipped the same way (``centred_factor`` 0: not looked for). Uses every k-th point,
    k = max(1, N // 50,000); for c and its spread k = max(1, N // :data:`CENTRE_SAMPLE`)."""
    step = max(1, len(heights) // 50_000)
    heights = np.ascontiguousarray(heights, dtype=np.float64)
    median, count = _bs.below_surface_median(heights, step, float(high))
    if count < 10:
        return low
    noise = 1.4826 * float(median)
    threshold = float(np.clip(factor * noise, low, high))
    if centred_factor <= 0:
        return threshold
    # the centre and its spread from every k-th of about CENTRE_SAMPLE heights
    centre, spread, count = _bs.ground_centre_spread(
        heights, max(1, len(heights) // CENTRE_SAMPLE), -float(high), threshold)
    if count >= 10 and centre > 0:
        centred = centre + centred_factor * 1.4826 * float(spread)
        threshold = max(threshold, float(np.clip(centred, low, high)))
    return threshold


def auto_range_coefficient(positions, heights: np.ndarray, threshold: float,
                           sensor_origin=(0.0, 0.0, 0.0), *,
                           factor: float = AUTO_THRESHOLD_FACTOR, bins: int = AUTO_RANGE_BINS,
                           fit: float = AUTO_RANGE_FIT, growth: float = AUTO_RANGE_GROWTH,
                           min_points: int = SENSOR_GROUND_MIN_POINTS,
                           line_spacing: float | Callable[[], float] | None = None) -> float:
    """The automatic threshold's growth with range squared (1/m), from the data: 0 for a
    sensor whose noise does not grow with range.

    The points at or below the surface (depth at most 0.5 m; every k-th of them,
    :data:`AUTO_RANGE_SAMPLE`) are split by horizontal range from ``sensor_origin`` into
    ``bins`` bins of equal counts; s_b = 1.4826 x the median depth
    of bin b (the noise scale of :func:`auto_threshold`, per range). When the least-squares fit
    s = a + c r^2 over the bins explains them (coefficient of determination >= ``fit``, c > 0),
    the farthest bin is at least :data:`AUTO_RANGE_TOP` times the widest and ``growth`` times
    the narrowest (spreads under :data:`AUTO_RANGE_FLOOR` counted as that), and from no bin to
    the next the spread grows more than :data:`AUTO_RANGE_STEP` times their ratio of r^2 (a
    face or a ditch the surface misses at one range makes it jump), and the same fit over all
    bins but the farthest grows by at least :data:`AUTO_RANGE_NEAR` times c (an object or a
    crest the surface misses at the far end of the scan raises the farthest bin alone), the
    sensor's noise grows with range squared (a stereo camera's depth noise) and the coefficient
    is ``factor`` x c (:func:`segment_points` stops the threshold's growth at
    :data:`AUTO_RANGE_HIGH`). Otherwise 0: a lidar's spread below the surface is flat with range,
    or grows only where sparse rings leave the ground unsampled and then levels off. 0 too
    when fewer than ``min_points`` of those points lie within
    :data:`SENSOR_GROUND_RADIUS` of the sensor (a sensor outside the cloud: airborne tiles),
    and on a rotating lidar's scan: lines at least :data:`AUTO_RANGE_LINES` apart
    (``line_spacing``: the :func:`scan_line_spacing` of ``positions`` when the caller has it,
    or a function that finds it, asked only past the tests above; None = found here).
    docs/algorithm.md, "A threshold that grows with range, from the data"."""
    p = _positions(positions)
    h = np.asarray(heights, dtype=np.float64)
    below = np.flatnonzero((h <= 0.0) & (h >= -0.5))
    below = below[::max(1, below.size // AUTO_RANGE_SAMPLE)]  # 8 medians need no more
    r2 = (p[below, 0] - sensor_origin[0]) ** 2 + (p[below, 1] - sensor_origin[1]) ** 2
    keep = np.isfinite(r2)
    below, r2 = below[keep], r2[keep]
    if below.size < bins * min_points or \
            np.count_nonzero(r2 <= SENSOR_GROUND_RADIUS ** 2) < min_points:
        return 0.0
    if line_spacing is None:
        line_spacing = scan_line_spacing(p, sensor_origin)
    elif callable(line_spacing):
        line_spacing = line_spacing()
    if line_spacing >= AUTO_RANGE_LINES:
        return 0.0
    order = np.argsort(r2, kind="stable")
    per_bin = order.size // bins
    order = order[:per_bin * bins].reshape(bins, per_bin)  # nearest to farthest
    r2_bins = np.median(r2[order], axis=1)
    spread = 1.4826 * np.median(-h[below[order]], axis=1)
    floored = np.maximum(spread, AUTO_RANGE_FLOOR)
    steps = (floored[1:] / floored[:-1]) / (np.maximum(r2_bins[1:], 1e-12)
                                            / np.maximum(r2_bins[:-1], 1e-12))
    if not (spread[-1] >= AUTO_RANGE_TOP * spread.max()
            and spread[-1] >= growth * floored.min() and steps.max() <= AUTO_RANGE_STEP):
        return 0.0
    c, explained = _line_fit(r2_bins, spread)
    if not (c > 0.0 and explained >= fit):
        return 0.0
    # ... and the nearer bins grow too: a face or a crest the surface misses at the far end of
    # the scan (an object on a plateau beyond it) makes the farthest bin jump alone, which a
    # fit over r^2 (where that bin has the leverage) takes for growth with range
    c_near, _ = _line_fit(r2_bins[:-1], spread[:-1])
    return float(factor * c) if c_near >= AUTO_RANGE_NEAR * c else 0.0


def _line_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(c, R^2) of the least-squares line y = a + c x: its slope and how much of y's spread
    it explains."""
    x = x - x.mean()
    y = y - y.mean()
    c = float(x @ y) / max(float(x @ x), 1e-12)
    residual = y - c * x
    return c, 1.0 - float(residual @ residual) / max(float(y @ y), 1e-12)


def sensor_ground_gradient(surface: TerrainSurface, positions, heights: np.ndarray,
                           threshold: float, sensor_origin=(0.0, 0.0, 0.0), *,
                           radius: float = SENSOR_GROUND_RADIUS,
                           min_points: int = SENSOR_GROUND_MIN_POINTS) -> tuple[float, float]:
    """The surface's gradient (dz/dx, dz/dy) under the sensor: the median over the terrain
    points (|height| <= ``threshold``) within ``radius`` m of ``sensor_origin`` (x, y), or
    (0, 0) when fewer than ``min_points`` valid ones lie there (a sensor outside the cloud, as
    for an airborne tile, or without ground around it).

    A vehicle's sensor stands on the ground it scans, so this is its tilt against that ground
    (pitch and roll, plus the slope the vehicle stands on): the misfit's slope term measures
    slope from it, which makes the labels of a tilted sensor those of a level one on the
    same scene (docs/algorithm.md, "Slope from the ground under the sensor")."""
    p = _positions(positions)
    h = np.asarray(heights, dtype=np.float64)
    d2 = (p[:, 0] - sensor_origin[0]) ** 2 + (p[:, 1] - sensor_origin[1]) ** 2
    near = np.flatnonzero((d2 <= radius * radius) & (np.abs(h) <= threshold))
    if near.size < min_points:
        return 0.0, 0.0
    gx, gy = surface.gradient(p[near, 0], p[near, 1])
    ok = np.isfinite(gx) & np.isfinite(gy)
    if np.count_nonzero(ok) < min_points:
        return 0.0, 0.0
    return float(np.median(gx[ok])), float(np.median(gy[ok]))


def sensor_in_cloud(positions, sensor_origin=(0.0, 0.0, 0.0), *,
                    radius: float = SENSOR_GROUND_RADIUS,
                    min_points: int = SENSOR_GROUND_MIN_POINTS) -> bool:
    """Whether at least ``min_points`` of the points lie within ``radius`` m (x/y) of
    ``sensor_origin`` and the scan looks made from there: a vehicle's lidar or stereo camera
    scans the ground around it; an airborne or photogrammetric tile in projected coordinates
    has no points near the default origin (the scan is top-down), and one moved to local
    coordinates around the origin has as many points per square metre near it as far from it
    (:data:`SCAN_DENSITY_FALL`, where both rings hold :data:`SCAN_RING_MIN_POINTS`)."""
    p = _positions(positions)
    x, y = float(sensor_origin[0]), float(sensor_origin[1])
    if _lp.count_within(p, x, y, float(radius), int(min_points)) < min_points:
        return False
    step = max(1, len(p) // SCAN_SAMPLE)
    bins = round(2.0 * (radius + SCAN_FAR[1]) / _SCAN_BIN)  # the rings' reach at most
    counts = _lp.range_histogram(p, x, y, step, _SCAN_BIN, bins)
    total = np.cumsum(counts)
    first = int(np.searchsorted(total, SCAN_FIRST * total[-1]))  # where the points start
    (a, b), (c, d) = SCAN_NEAR, SCAN_FAR
    start = first * _SCAN_BIN

    def ring(lo, hi):  # points in [start + lo, start + hi), whole bins
        return int(counts[first + round(lo / _SCAN_BIN):first + round(hi / _SCAN_BIN)].sum())

    near, far = ring(a, b), ring(c, d)
    if step * min(near, far) < SCAN_RING_MIN_POINTS:
        return True
    area_near = (start + b) ** 2 - (start + a) ** 2
    area_far = (start + d) ** 2 - (start + c) ** 2
    return bool(near * area_far >= SCAN_DENSITY_FALL * far * area_near)


def scan_line_spacing(positions, sensor_origin=(0.0, 0.0, 0.0)) -> float:
    """The angle (deg) between neighbouring scan lines of a rotating lidar seen from
    ``sensor_origin``; 0.0 when the points show no lines (fewer than :data:`LINE_MIN_GAPS`
    gaps).

    A lidar's points along one azimuth lie on its beams, whatever they hit, so their
    elevation angles from the sensor differ by multiples of the angle between neighbouring
    lines. In 8 narrow wedges around the sensor (:data:`LINE_WEDGE_DEG` either side of the
    x and y axes and the diagonals, ranges :data:`LINE_RANGES`; every k-th point of a
    cloud of more than :data:`LINE_POINTS`) the sorted elevations' gaps larger than
    :data:`LINE_SAME_DEG` (points of one line) are gathered; their median is the spacing
    (lines without a return in a wedge widen some gaps, which the median ignores). A tilted
    sensor's lines change elevation across a wedge, which can only lower the estimate.
    Measured in docs/algorithm.md, "Feet of objects on a sparse lidar"."""
    p = _positions(positions)
    low, high = LINE_RANGES
    gaps = _foot.scan_line_gaps(p, float(sensor_origin[0]), float(sensor_origin[1]),
                                float(sensor_origin[2]), math.tan(math.radians(LINE_WEDGE_DEG)),
                                float(low), float(high), math.radians(LINE_SAME_DEG),
                                max(1, len(p) // LINE_POINTS))
    if gaps.size < LINE_MIN_GAPS:
        return 0.0
    return math.degrees(float(np.median(gaps)))


def line_spacing_finder(positions, sensor_origin=(0.0, 0.0, 0.0)) -> Callable[[], float]:
    """The :func:`scan_line_spacing` of ``positions`` seen from ``sensor_origin`` as a function
    that finds it when first called and returns the same value after: the labellings of one
    cloud (the refit's, :func:`o3d_terrain.refine.refine_surface`, and the Segmenter's that
    follow it) take it as :func:`segment_points`' ``line_spacing``, so the spacing is found
    once per cloud, and only when a labelling needs it."""
    p = _positions(positions)
    return functools.cache(lambda: scan_line_spacing(p, sensor_origin))


def _grade_from_sensor_ground(surface: TerrainSurface, p: np.ndarray, h: np.ndarray,
                              threshold: float, sensor_origin):
    """The misfit's ``grade`` callable: |grad S - g0| at (x, y), g0 the
    :func:`sensor_ground_gradient` (found on the first call: only when a block is widened)."""
    tilt = []

    def grade(x, y):
        if not tilt:
            tilt.extend(sensor_ground_gradient(surface, p, h, threshold, sensor_origin))
        gx, gy = surface.gradient(x, y)
        return np.hypot(gx - tilt[0], gy - tilt[1])
    return grade


def segment_points(surface: TerrainSurface, positions, *, threshold: float | None = 0.2,
                   below_threshold: float = 0.5, range_coefficient: float | None = None,
                   sensor_origin=(0.0, 0.0, 0.0), misfit: bool = True,
                   along_normal: bool = True, foot_height: float = FOOT_HEIGHT,
                   foot_cell: float = FOOT_CELL, foot_lines: float = FOOT_LINES,
                   foot_behind: float = FOOT_BEHIND,
                   foot_gap: float = FOOT_GAP,
                   line_of_sight: bool = True,
                   centred_threshold: bool = True,
                   line_spacing: float | Callable[[], float] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Labels (N,) uint8 :class:`TerrainLabel` values and heights above terrain (N,) float64.

    threshold: points higher than this above the surface are obstacles (m); None = from the
        data (:func:`auto_threshold`).
    below_threshold: points lower than this below the surface are BELOW_TERRAIN noise (m).
    range_coefficient: growth of the threshold with horizontal range squared (1/m), for
        stereo clouds; 0 = constant threshold; None = from the data with ``threshold`` None
        (:func:`auto_range_coefficient`: 0 unless the noise grows with range), else 0.
    sensor_origin: (x, y, z) of the sensor, for the range (cloud coordinates), and where the
        misfit's slope term takes level from (:func:`sensor_ground_gradient`).
    misfit: with ``threshold`` None, widen the threshold (both sides) where the surface's
        local misfit to the ground exceeds the noise (except for points more than 0.5 m up
        in a column whose points stack vertically, the returns of an object's side:
        :func:`o3d_terrain.misfit.face_points`), and there measure the points still
        above it against the plane through the terrain around them
        (:mod:`o3d_terrain.misfit`, :func:`o3d_terrain.misfit.local_plane_terrain`); on a
        top-down scan (not a scan from ``sensor_origin``, :func:`sensor_in_cloud`: an
        airborne tile) measure every point above the threshold, up to
        :data:`o3d_terrain.misfit.MISFIT_HIGH`, against that plane, its radius from the
        terrain's density (:func:`o3d_terrain.misfit.plane_radius`); on either, keep as
        obstacles the points so taken above the threshold that stand over terrain
        (:func:`o3d_terrain.misfit.over_terrain`).
    along_normal: measure both thresholds along the surface normal instead of vertically
        (the vertical threshold grows by sqrt(1 + |grad S|^2), at most x2, on slopes;
        :func:`relabel_along_normal`); False = vertical thresholds.
    foot_height: TERRAIN points in ``foot_cell`` columns that hold OBSTACLE points less than
        this high above the terrain (above the local noise, at least 30 % of the column's low
        points, an object at least 0.35 m high in the column or beside it) become OBSTACLE
        (:func:`mark_object_feet`); 0 = off.
    foot_cell: side of those columns (m).
    foot_lines: on a scan of lines around ``sensor_origin`` (:func:`sensor_in_cloud` and
        :func:`scan_line_spacing` > 0: a rotating lidar), the foot height grows with range
        to this many times the height between neighbouring lines on a vertical face there
        (at most :data:`FOOT_CAP`); 0 = ``foot_height`` at every range.
    foot_behind: on such a scan with a range coefficient of 0 (a lidar's noise), TERRAIN
        points within this distance (m, x/y) of a foot's mark (an OBSTACLE point below the
        foot height, out of the noise, beside an object) and at least
        :data:`FOOT_BEHIND_MARGIN` farther from the sensor than it become OBSTACLE; 0 = off.
    foot_gap: a column whose lowest mark lies more than this (m), or ``foot_lines`` scan-line
        gaps at its range, above its highest TERRAIN point is free space under an overhang,
        not a foot; 0 = off.
    line_of_sight: where the sensor scans the ground around it, TERRAIN points above the
        sensor that the surface would hide from it become OBSTACLE (:func:`out_of_sight`: an
        object beyond a crest or a hill whose ground the sensor cannot see, which the
        surface then runs through).
    centred_threshold: with ``threshold`` None, the automatic threshold is at least the
        ground's centre plus :data:`AUTO_CENTRED_FACTOR` noise scales where that centre lies
        above the surface (:func:`auto_threshold`); False = from the noise below the surface
        alone (the refit's labels: they choose the points a surface is fitted to, where low
        clutter taken as terrain costs more than noisy ground left out; docs/algorithm.md,
        "The threshold on a noisy ground").
    line_spacing: the :func:`scan_line_spacing` of ``positions`` seen from ``sensor_origin``
        when the caller has it: a number, or a function that finds it when first asked
        (:func:`line_spacing_finder`, which the caller may pass on to the next labelling of the
        same points); None = found here, when needed.
    """
    problems = [m for m in (None if threshold is None
                            else _check("threshold", threshold, positive=True),
                            _check("below_threshold", below_threshold, positive=True),
                            None if range_coefficient is None
                            else _check("range_coefficient", range_coefficient, positive=False),
                            _check("foot_height", foot_height, positive=False),
                            _check("foot_cell", foot_cell, positive=True),
                            _check("foot_lines", foot_lines, positive=False,
                                   unit="scan-line gaps"),
                            _check("foot_behind", foot_behind, positive=False),
                            _check("foot_gap", foot_gap, positive=False))
                if m]
    if len(sensor_origin) != 3 or not all(math.isfinite(float(v)) for v in sensor_origin):
        problems.append(f"sensor_origin must be three finite numbers, got {sensor_origin!r}")
    if problems:
        raise InputError("segment_points: " + "; ".join(problems))
    p = _positions(positions)
    h = heights_above_terrain(surface, p)
    centred_factor = AUTO_CENTRED_FACTOR if centred_threshold else 0.0
    local = None
    automatic_range = range_coefficient is None
    measured_range = automatic_range and threshold is None  # the data's range growth is known
    range_coefficient = 0.0 if automatic_range else range_coefficient
    range_high = math.inf  # a range coefficient given by the caller grows without a ceiling
    use_misfit = threshold is None and misfit and isinstance(surface, TerrainSurface)
    block = block_size(surface) if use_misfit else 0.0
    # scan_line_spacing of the cloud, found once when first asked (or the caller's)
    if line_spacing is None:
        line_spacing = line_spacing_finder(p, sensor_origin)
    elif not callable(line_spacing):
        line_spacing = functools.partial(float, line_spacing)

    if threshold is None:
        threshold = auto_threshold(h, centred_factor=centred_factor)
        if automatic_range:
            range_coefficient = auto_range_coefficient(p, h, threshold, sensor_origin,
                                                       line_spacing=line_spacing)
            range_high = AUTO_RANGE_HIGH
        if use_misfit:
            local = widened_thresholds(p, h, threshold, block=block,
                                       grade=_grade_from_sensor_ground(surface, p, h, threshold,
                                                                       sensor_origin))
    labels = label_heights(h, p, threshold=threshold, below_threshold=below_threshold,
                           range_coefficient=range_coefficient, sensor_origin=sensor_origin,
                           range_high=range_high)
    widened = local is not None and local.max(initial=threshold) > threshold
    if widened:
        taken = widen_labels(labels, h, local, threshold)
        # ... but not the returns of a vertical face (an object's side beside ground the
        # surface misfits; docs/algorithm.md, "Knots where the data are", "Vertical faces in
        # widened blocks")
        labels[face_points(p, h, taken)] = TerrainLabel.OBSTACLE
    if along_normal and isinstance(surface, TerrainSurface):
        relabel_along_normal(labels, h, p, surface, threshold=threshold,
                             below_threshold=below_threshold,
                             range_coefficient=range_coefficient, sensor_origin=sensor_origin,
                             range_high=range_high)
    if widened:
        # widened blocks: points above their threshold measured against the local plane of
        # the terrain around them (docs/algorithm.md, "Local planes in widened blocks")
        candidates = np.flatnonzero((local > threshold) & (labels == TerrainLabel.OBSTACLE)
                                    & (h > 0))
        _take_local_planes(labels, h, p, candidates, labels == TerrainLabel.TERRAIN,
                           misfit_reach(block), threshold)
    # whether the sensor scans the ground around it: asked once, when the top-down test or
    # the lidar's rules of the feet need it
    lines_rules = foot_height > 0 and (foot_lines > 0 or foot_behind > 0)
    in_cloud = (use_misfit or lines_rules or line_of_sight) and sensor_in_cloud(p, sensor_origin)
    if use_misfit and not in_cloud:
        # a top-down scan: every point up to MISFIT_HIGH above the surface and above its
        # threshold measured against the local plane of the terrain around it, within the
        # radius that holds PLANE_POINTS terrain points (docs/algorithm.md, "Local planes and
        # a finer layout on a top-down scan")
        _top_down_planes(labels, h, p, threshold, block)
    if use_misfit and (widened or not in_cloud):
        # ... but not the points above the global threshold that the widened threshold or
        # the local planes took (anywhere on a top-down scan, in the widened blocks of a
        # vehicle's) and that stand over terrain: the surface rides over vegetation there
        # (docs/algorithm.md, "Points over the terrain on a top-down scan")
        terrain = labels == TerrainLabel.TERRAIN
        taken = terrain & (h > threshold)
        if in_cloud:
            taken &= local > threshold
        labels[over_terrain(p, np.flatnonzero(taken), terrain, surface.gradient)] = \
            TerrainLabel.OBSTACLE
    if foot_height > 0:
        spacing = line_spacing() if lines_rules and in_cloud else 0.0
        # behind the marks: on a lidar's scan (lines, and noise that does not grow with range:
        # a stereo pair's depth noise would put ground in front of an object behind it),
        # asked of the data also when the caller set the threshold or its range term
        behind = 0.0
        if foot_behind > 0 and spacing > 0 and range_coefficient == 0 and (
                measured_range or auto_range_coefficient(p, h, auto_threshold(
                    h, centred_factor=centred_factor),
                                                         sensor_origin,
                                                         line_spacing=spacing) == 0):
            behind = foot_behind
        mark_object_feet(labels, h, p, foot_height=foot_height, cell=foot_cell,
                         noise_depth=below_threshold, line_spacing=spacing,
                         foot_lines=foot_lines, sensor_origin=sensor_origin,
                         behind_radius=behind, foot_gap=foot_gap)
    if line_of_sight and in_cloud and isinstance(surface, TerrainSurface):
        labels[out_of_sight(surface, p, labels, sensor_origin)] = TerrainLabel.OBSTACLE
    return labels, h


def out_of_sight(surface: TerrainSurface, positions, labels: np.ndarray,
                 sensor_origin=(0.0, 0.0, 0.0), *,
                 margin_deg: float = SIGHT_MARGIN_DEG) -> np.ndarray:
    """Indices of the TERRAIN points above the sensor that the surface would hide from it.

    A ground-based sensor sees the ground above it only where the ground faces it: along the
    line of sight, at elevation angle e, the ground must rise away from the sensor more
    steeply than the line itself (slope angle > e); where the surface at a point rises less
    steeply than that, by more than ``margin_deg``, a terrain point there would be seen from
    below, through the ground. Such a point is not ground on that surface: the upper part of
    an object beyond a crest or a hill, whose own ground the sensor does not see and which
    the surface, with no other data there, runs through. Only points higher than the
    sensor are tested (few on a level scan): below it, the surface's slope where the data
    end (the last ring of a scan, the edge of an occlusion) can be off by more than the
    margin. The test needs the sensor's height: it runs only when the terrain points within
    :data:`SENSOR_GROUND_RADIUS` of it lie :data:`SIGHT_MIN_HEIGHT` or more below it (their
    median); a frame whose origin sits on the ground (a vehicle's base frame without
    ``sensor_origin``) gets no test. Measured in docs/algorithm.md, "Ground the sensor could
    not see"."""
    p = _positions(positions)
    tol_x, tol_y = surface._tolerances()
    step = max(1, len(p) // SIGHT_SAMPLE)  # the ground around the sensor from every step-th
    return _bs.out_of_sight(
        p, np.ascontiguousarray(labels, dtype=np.uint8), int(TerrainLabel.TERRAIN),
        float(sensor_origin[0]), float(sensor_origin[1]), float(sensor_origin[2]),
        math.tan(math.radians(margin_deg)), float(SENSOR_GROUND_RADIUS),
        max(1, SENSOR_GROUND_MIN_POINTS // step), float(SIGHT_MIN_HEIGHT), step,
        float(surface.origin[0]), float(surface.origin[1]), tol_x, tol_y, surface.knots_x,
        surface.knots_y, int(surface.degree), surface.control_points, surface.weights)


def _top_down_planes(labels: np.ndarray, h: np.ndarray, p: np.ndarray, threshold: float,
                     block: float) -> int:
    """In place: OBSTACLE points 0 < h < MISFIT_HIGH that lie at most ``threshold`` above the
    local plane of the TERRAIN points around them become TERRAIN (the misfit's local planes,
    :func:`o3d_terrain.misfit.local_plane_terrain`, applied everywhere), the plane's radius
    from the terrain's density (:func:`o3d_terrain.misfit.plane_radius`, at most ``block``).
    Returns how many changed."""
    candidates = np.flatnonzero((labels == TerrainLabel.OBSTACLE) & (h > 0) & (h < MISFIT_HIGH))
    if candidates.size == 0:
        return 0
    terrain = labels == TerrainLabel.TERRAIN
    return _take_local_planes(labels, h, p, candidates, terrain,
                              plane_radius(p, terrain, most=block), threshold)


def _take_local_planes(labels: np.ndarray, h: np.ndarray, p: np.ndarray,
                       candidates: np.ndarray, terrain: np.ndarray, radius: float,
                       threshold: float) -> int:
    """In place: the ``candidates`` (indices of OBSTACLE points) that lie at most
    ``threshold`` above the local plane of the ``terrain`` points (labels == TERRAIN, a
    scratch copy it extends) within ``radius`` become TERRAIN
    (:func:`o3d_terrain.misfit.local_plane_terrain`). Returns how many changed."""
    if candidates.size == 0 or not local_plane_terrain(p, h, terrain, candidates,
                                                        radius=radius, threshold=threshold):
        return 0
    taken = candidates[terrain[candidates]]
    labels[taken] = TerrainLabel.TERRAIN
    return int(taken.size)


def mark_object_feet(labels: np.ndarray, heights: np.ndarray, positions, *,
                     foot_height: float = FOOT_HEIGHT, cell: float = FOOT_CELL,
                     fraction: float = FOOT_FRACTION, rise: float = FOOT_RISE,
                     object_height: float = FOOT_OBJECT,
                     noise_factor: float = AUTO_THRESHOLD_FACTOR,
                     noise_cell: float = FOOT_NOISE_CELL, noise_depth: float = 0.5,
                     line_spacing: float = 0.0, foot_lines: float = FOOT_LINES,
                     foot_cap: float = FOOT_CAP, sensor_origin=(0.0, 0.0, 0.0),
                     behind_radius: float = 0.0,
                     behind_margin: float = FOOT_BEHIND_MARGIN,
                     foot_gap: float = FOOT_GAP) -> int:
    """In place: TERRAIN labels in the x/y columns (side ``cell``, m) that are the foot of an
    object become OBSTACLE; returns how many changed. A column is a foot when it holds OBSTACLE
    points less than the foot height above the terrain (``foot_height``, m; with
    ``line_spacing`` > 0, ``foot_lines`` x r x tan(line_spacing) where that is higher, at most
    ``foot_cap``: r the point's x/y range from ``sensor_origin``, ``line_spacing`` the angle
    (deg) between neighbouring scan lines, :func:`scan_line_spacing`) that

    - stand out of the local noise: higher than ``noise_factor`` times the noise scale of the
      points between ``-noise_depth`` and 0 m in their ``noise_cell`` cell (from their mean
      depth; cells with fewer than 3 such points set no test), and
    - make up at least ``fraction`` of them and the column's TERRAIN points together, and
    - reach more than ``rise`` (m) above the column's lowest point (marks and TERRAIN points):
      terrain does not rise that much across a column, so where the surface undercuts steep
      ground the ground above the threshold does not take the ground below it along, and
    - the column or one of its 8 neighbours holds an OBSTACLE point at least ``object_height``
      (m) above the terrain: an object stands there, and
    - (with ``foot_gap`` > 0) the column's lowest mark lies at most ``foot_gap`` (m), or
      ``foot_lines`` scan-line gaps at its range where that is more, above its highest
      TERRAIN point: a larger gap is free space under an overhang (a car's body, a branch)
      with the ground seen below it, not an object's base.

    The base of a bush, a wall or a wheel lies within the terrain threshold, and the column
    shows it belongs to the object; a noisy sensor's upper tail of ground points (a stereo
    pair's at range) mostly neither stands out of its cell's noise, nor outnumbers the ground
    in its column, nor has an object beside it. Columns whose obstacle points all lie
    ``foot_height`` or more above the terrain (a canopy, a car body above its ground clearance,
    a threshold at or above foot_height) change nothing; ``foot_height`` 0 changes nothing.
    ``labels`` (N,) uint8 as :func:`label_heights` writes them, ``heights`` (N,) above the
    terrain. The columns and the noise cells lie on fixed lattices (multiples of their side),
    so a column's verdict does not depend on points outside it and its neighbours; the
    columns on two, the second shifted by half a column along x and y, and a TERRAIN point
    goes with a foot column of either (an object's face falls well inside a column of one).

    With ``behind_radius`` > 0 (m), then the TERRAIN points within that x/y distance of a
    mark (an OBSTACLE point below the foot height that stands out of the noise) whose column
    or one of its 8 neighbours holds an OBSTACLE point at least ``object_height`` up, and at
    least ``behind_margin`` (m) farther from ``sensor_origin`` (x/y range) than the mark,
    become OBSTACLE: behind the low part of an object, as the sensor sees it, it hides the
    ground (the ground returns there are the object's base, or ground under its overhang).
    """
    if labels.dtype != np.uint8 or labels.ndim != 1 or not labels.flags.writeable:
        raise InputError("mark_object_feet: labels must be a writeable (N,) uint8 array")
    p = _positions(positions)
    if not (len(p) == len(labels) == len(heights)):
        raise InputError(f"mark_object_feet: labels ({len(labels)}), heights ({len(heights)}) "
                         f"and positions ({len(p)}) must have one entry per point")
    problems = [m for m in (_check("foot_height", foot_height, positive=False),
                            _check("cell", cell, positive=True),
                            _check("fraction", fraction, positive=False),
                            _check("rise", rise, positive=False),
                            _check("object_height", object_height, positive=False),
                            _check("noise_factor", noise_factor, positive=False),
                            _check("noise_cell", noise_cell, positive=True),
                            _check("noise_depth", noise_depth, positive=True),
                            _check("line_spacing", line_spacing, positive=False,
                                   unit="degrees"),
                            _check("foot_lines", foot_lines, positive=False,
                                   unit="scan-line gaps"),
                            _check("foot_cap", foot_cap, positive=False),
                            _check("behind_radius", behind_radius, positive=False),
                            _check("behind_margin", behind_margin, positive=False),
                            _check("foot_gap", foot_gap, positive=False)) if m]
    if isinstance(line_spacing, (int, float)) and line_spacing >= 90:
        problems.append(f"line_spacing must be below 90 degrees, got {line_spacing!r}")
    if len(sensor_origin) != 3 or not all(math.isfinite(float(v)) for v in sensor_origin):
        problems.append(f"sensor_origin must be three finite numbers, got {sensor_origin!r}")
    if problems:
        raise InputError("mark_object_feet: " + "; ".join(problems))
    if foot_height == 0:
        return 0
    return int(_foot.mark_object_feet(
        p, np.ascontiguousarray(heights, dtype=np.float64), labels, float(cell),
        float(foot_height), float(fraction), float(rise), float(object_height),
        float(noise_cell), float(noise_factor),
        float(noise_depth), int(TerrainLabel.TERRAIN), int(TerrainLabel.OBSTACLE),
        float(foot_lines) * math.tan(math.radians(line_spacing)), float(foot_cap),
        float(sensor_origin[0]), float(sensor_origin[1]), float(behind_radius),
        float(behind_margin), float(foot_gap),
        float(foot_lines) * math.tan(math.radians(line_spacing))))


def relabel_along_normal(labels: np.ndarray, heights: np.ndarray, positions,
                         surface: TerrainSurface, *, threshold: float, below_threshold: float,
                         range_coefficient: float = 0.0, sensor_origin=(0.0, 0.0, 0.0),
                         cap: float = NORMAL_FACTOR_MAX, range_high: float = math.inf) -> None:
    """In place: the thresholds taken along the surface normal instead of vertically.

    A point on terrain of slope theta lies off a surface that follows it by its noise along
    the normal, which is 1 / cos(theta) = sqrt(1 + |grad S|^2) times more vertically (and the
    surface's own error is, too): a vertical threshold that fits flat ground cuts the terrain
    of slopes and faces. OBSTACLE points with h <= t(r) * f and BELOW_TERRAIN points with
    h >= -below_threshold * f become TERRAIN, f = min(sqrt(1 + |grad S|^2), ``cap``) at the
    point (t(r): :func:`thresholds`, at most ``range_high`` where it grows with range). Only
    the points within ``cap`` times the thresholds are
    looked at, so the surface's gradient is evaluated at few points."""
    if labels.dtype != np.uint8 or labels.ndim != 1 or not labels.flags.writeable:
        raise InputError("relabel_along_normal: labels must be a writeable (N,) uint8 array")
    p = _positions(positions)
    if not (len(p) == len(labels) == len(heights)):
        raise InputError(f"relabel_along_normal: labels ({len(labels)}), heights "
                         f"({len(heights)}) and positions ({len(p)}) must have one entry per "
                         f"point")
    tol_x, tol_y = surface._tolerances()
    _bs.relabel_along_normal(
        labels, np.ascontiguousarray(heights, dtype=np.float64), p, float(threshold),
        float(below_threshold), float(range_coefficient), float(sensor_origin[0]),
        float(sensor_origin[1]), float(range_high), float(cap), float(surface.origin[0]),
        float(surface.origin[1]),
        tol_x, tol_y, surface.knots_x, surface.knots_y, int(surface.degree),
        surface.control_points, surface.weights, int(TerrainLabel.TERRAIN),
        int(TerrainLabel.OBSTACLE), int(TerrainLabel.BELOW_TERRAIN))


def widen_labels(labels: np.ndarray, heights: np.ndarray, local: np.ndarray,
                 threshold: float) -> np.ndarray:
    """In place, at the points whose threshold ``local`` is wider than the global
    ``threshold`` the labels used: OBSTACLE points with h <= local and BELOW_TERRAIN points
    with h >= -local become TERRAIN. Returns the indices of the OBSTACLE points that did."""
    wide = local > threshold
    taken = np.flatnonzero(wide & (labels == TerrainLabel.OBSTACLE) & (heights <= local))
    labels[taken] = TerrainLabel.TERRAIN
    labels[wide & (labels == TerrainLabel.BELOW_TERRAIN)
           & (heights >= -local)] = TerrainLabel.TERRAIN
    return taken


def earlier_returns(return_numbers, number_of_returns) -> np.ndarray:
    """(N,) bool: the points that are not the last return of their pulse (a LAS/LAZ file's
    ``return_number`` below its ``number_of_returns``): the pulse went on past them, so they
    lie above whatever it hit last (a canopy, a wire, a roof's edge) and are not the ground.
    Points whose numbers are 0 (unknown, as some writers leave them) or inconsistent (a
    return number above the count) are not among them: the file says nothing about them."""
    r = np.asarray(return_numbers).reshape(-1)
    n = np.asarray(number_of_returns).reshape(-1)
    if r.shape != n.shape:
        raise InputError(f"earlier_returns: return numbers ({r.size}) and numbers of returns "
                         f"({n.size}) must have one value per point")
    return (r > 0) & (n > 0) & (r < n)


def keep_last_returns(labels: np.ndarray, earlier: np.ndarray) -> int:
    """In place: the TERRAIN points among ``earlier`` (:func:`earlier_returns`) become
    OBSTACLE; returns how many did."""
    moved = np.flatnonzero(earlier & (labels == TerrainLabel.TERRAIN))
    labels[moved] = TerrainLabel.OBSTACLE
    return int(moved.size)


def label_heights(heights: np.ndarray, positions, *, threshold: float, below_threshold: float,
                  range_coefficient: float = 0.0, sensor_origin=(0.0, 0.0, 0.0),
                  range_high: float = math.inf) -> np.ndarray:
    """Labels (N,) uint8 from heights above the terrain (the rule of :func:`segment_points`,
    options assumed checked); the range-dependent threshold stops growing at ``range_high``."""
    p = _positions(positions)
    return _bs.label_heights(
        np.ascontiguousarray(heights, dtype=np.float64), p, float(threshold),
        float(below_threshold), float(range_coefficient), float(sensor_origin[0]),
        float(sensor_origin[1]), float(range_high), int(TerrainLabel.UNKNOWN),
        int(TerrainLabel.TERRAIN),
        int(TerrainLabel.OBSTACLE), int(TerrainLabel.BELOW_TERRAIN))
