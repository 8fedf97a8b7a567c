"""A spinning lidar under a ceiling: a mine drift, a tunnel, a cavern or a hall, cast
analytically (a flat floor, a flat roof over it, optional side walls), with exact truth.

Where the floor's returns thin out with range, the roof's do not: a fit that takes a
scan's lowest cells for the ground climbs to the roof there (docs/algorithm.md, "Free space
under the rays").
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def sample_under_ceiling(height: float, *, half_width: float | None = None,
                         fov_deg: tuple[float, float] = (-45.0, 45.0), beams: int = 64,
                         firings: int = 1024, grade: float = 0.0, sensor_height: float = 2.0,
                         max_range: float = 100.0, noise: float = 0.01, seed: int = 0
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3), is_ground (N,)) of one turn of a lidar ``sensor_height`` m over the
    floor z = grade * x - sensor_height, under a roof ``height`` m over the floor, between
    vertical walls at y = +-``half_width`` (None: no walls), in the sensor's frame (the
    sensor at the origin, as a lidar driver gives a scan): ``beams`` channels evenly over
    ``fov_deg`` (elevation, degrees), ``firings`` a turn, returns from 0.5 m to ``max_range``
    with Gaussian range noise ``noise`` (m, seeded). A return from the floor is ground; from
    the roof or a wall it is not."""
    if not (height > sensor_height > 0):
        raise InputError(f"sample_under_ceiling: the roof ({height!r} m) must lie above the "
                         f"sensor ({sensor_height!r} m over the floor), which lies above it")
    if half_width is not None and not half_width > 0:
        raise InputError(f"sample_under_ceiling: half_width must be > 0 m or None, got "
                         f"{half_width!r}")
    if not (-90.0 <= fov_deg[0] < fov_deg[1] <= 90.0) or beams < 1 or firings < 1:
        raise InputError("sample_under_ceiling: fov_deg must rise within [-90, 90] degrees, "
                         "with at least one beam and one firing")
    elevation = np.radians(np.linspace(fov_deg[0], fov_deg[1], beams))
    azimuth = np.radians(np.linspace(-180.0, 180.0, firings, endpoint=False))
    e, a = np.meshgrid(elevation, azimuth)
    d = np.c_[(np.cos(e) * np.cos(a)).ravel(), (np.cos(e) * np.sin(a)).ravel(),
              np.sin(e).ravel()]
    climb = d[:, 2] - grade * d[:, 0]  # the ray's rise over the floor's, per metre of ray
    with np.errstate(divide="ignore", invalid="ignore"):
        to_floor = np.where(climb < 0, -sensor_height / climb, np.inf)
        to_roof = np.where(climb > 0, (height - sensor_height) / climb, np.inf)
        to_wall = np.inf if half_width is None else half_width / np.abs(d[:, 1])
    t = np.minimum(np.minimum(to_floor, to_roof), to_wall)
    floor = to_floor <= t
    keep = (t > 0.5) & (t < max_range)
    reach = t[keep] + np.random.default_rng(seed).normal(0.0, noise, int(keep.sum()))
    return d[keep] * reach[:, None], floor[keep]
