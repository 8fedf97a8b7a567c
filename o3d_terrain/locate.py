"""Where a ground-based sensor stood, found from its scan alone.

A vehicle's scan moved into a map or world frame (a ROS ``map`` or ``odom`` frame, projected
coordinates) no longer has its sensor at the origin, and without ``sensor_origin`` the
library would take it for a top-down scan (an airborne tile: no points around the origin).
:func:`locate_sensor` finds the sensor from what every scan from the ground shows: its points
crowd around the sensor (the ground within 10-20 m holds most of a rotating lidar's returns,
the density falling about as 1 / r^2 of the range). An airborne or photogrammetric tile has
no such crowd (its densest 3 m neighbourhood holds 1.6-5.5 times its median density on the
LAS tiles of the shared data, against 26-31 times on a rotating lidar's or a stereo camera's
scan), and a strip accumulated along a drive has no spot with half its points within
:data:`LOCATE_REACH` (0.13-0.27 for 4-8 scans 40 m apart): for both the answer is None, and
the scan keeps the treatment it had. A forward-looking sensor (a stereo camera, a
solid-state lidar) is found a few metres into its field of view, where its points crowd.

The position is the density's mode (a Gaussian of :data:`LOCATE_SIGMA` over 1 m cells), then
the centre that minimises the sum of the log distances to the points within
:data:`LOCATE_REACH` (floored at :data:`LOCATE_FLOOR`): the maximum-likelihood centre of a
density falling as 1 / r^2, by the fixed point of its weighted mean. On SemanticKITTI frames
it lies 3.9 m from the sensor (the scene is not symmetric about it), which changes the labels
by less than 0.1 point of F1 (docs/algorithm.md, "A scan in a map frame"). The height is that
of the ground around it (the 10th percentile of the heights within 2-10 m): the labels that
need the sensor's height above the ground (:func:`o3d_terrain.segment.out_of_sight`) then
stay off.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ._kernels import grid as _grid
from ._kernels import locate as _locate
from .frame import as_frame

__all__ = ["locate_sensor", "LOCATE_SIGMA", "LOCATE_PEAK_RATIO", "LOCATE_REACH",
           "LOCATE_FLOOR", "LOCATE_MIN_POINTS", "LOCATE_SHARE"]

#: side of the density's cells (m); wider on a cloud more than 1024 cells across
LOCATE_CELL = 1.0
LOCATE_MAX_CELLS = 1024
#: the density's smoothing (m, Gaussian sigma)
LOCATE_SIGMA = 3.0
#: the smoothed density at its mode must be this many times its median over occupied cells
LOCATE_PEAK_RATIO = 10.0
#: the points within this (m) of the mode place the centre, ...
LOCATE_REACH = 30.0
#: ... each at least this far from it in the log-distance sum (m): a sensor's blind zone
LOCATE_FLOOR = 2.0
#: fewest finite points to look for a sensor in
LOCATE_MIN_POINTS = 1000
#: at least this share of the points lies within LOCATE_REACH of the sensor: one station's
#: scan, not a strip accumulated along a drive
LOCATE_SHARE = 0.5
#: the ground around the centre: the points this far from it (m), their low heights
_GROUND_RING = (2.0, 10.0)
_GROUND_PERCENTILE = 10.0
_SAMPLE = 20000  # points that place the centre at most (every k-th)


def locate_sensor(cloud) -> tuple[float, float, float] | None:
    """(x, y, z) of the sensor that took ``cloud`` (an (N, 3) array or an Open3D point cloud,
    cloud coordinates) from the ground, or None when its points do not crowd around one spot
    (a top-down scan, a strip along a drive, too few points; module docstring). Non-finite
    points are left out."""
    if isinstance(cloud, np.ndarray) and cloud.ndim == 2 and cloud.shape[1] >= 3:
        p = np.ascontiguousarray(cloud[:, :3], dtype=np.float64)
    else:
        p = as_frame(cloud).positions
    x_min, x_max, y_min, y_max, n = _grid.finite_bounds(p[:, 0], p[:, 1], p[:, 2])
    if n < LOCATE_MIN_POINTS:
        return None
    cell = max(LOCATE_CELL, max(x_max - x_min, y_max - y_min) / LOCATE_MAX_CELLS)
    nx = int((x_max - x_min) / cell) + 1
    ny = int((y_max - y_min) / cell) + 1
    counts = _locate.cell_counts(p, x_min, y_min, cell, nx, ny)
    density = ndimage.gaussian_filter(counts.astype(np.float64), LOCATE_SIGMA / cell,
                                      mode="constant")
    i, j = np.unravel_index(int(np.argmax(density)), density.shape)
    if not density[i, j] >= LOCATE_PEAK_RATIO * np.median(density[counts > 0]):
        return None
    x, y = x_min + (i + 0.5) * cell, y_min + (j + 0.5) * cell
    near = _locate.points_within(p, x, y, LOCATE_REACH)
    if len(near) < LOCATE_SHARE * n:
        return None
    x, y = _log_distance_centre(near, x, y)
    d = np.hypot(near[:, 0] - x, near[:, 1] - y)
    ring = (d >= _GROUND_RING[0]) & (d <= _GROUND_RING[1])
    if not ring.any():
        return None
    return (float(x), float(y), float(np.percentile(near[ring, 2], _GROUND_PERCENTILE)))


def _log_distance_centre(q: np.ndarray, x: float, y: float, rounds: int = 30
                         ) -> tuple[float, float]:
    """From (x, y): the centre minimising the sum of log(max(distance, LOCATE_FLOOR)) over
    the points ``q`` (those within LOCATE_REACH of (x, y)), by the fixed point of the mean
    weighted by 1 / distance^2 (the points within the floor weigh nothing); until it moves
    less than 1 cm."""
    q = q[:: max(1, len(q) // _SAMPLE), :2]
    for _ in range(rounds):
        d2 = (q[:, 0] - x) ** 2 + (q[:, 1] - y) ** 2
        w = np.where(d2 > LOCATE_FLOOR ** 2, 1.0 / np.maximum(d2, LOCATE_FLOOR ** 2), 0.0)
        total = w.sum()
        if not total > 0:
            break
        nx, ny = float(w @ q[:, 0]) / total, float(w @ q[:, 1]) / total
        moved = abs(nx - x) + abs(ny - y)
        x, y = nx, ny
        if moved < 0.01:
            break
    return x, y
