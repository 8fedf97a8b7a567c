"""A forest seen from the air: an airborne lidar's returns, several per pulse, under a closed
conifer canopy with shrubs, over any terrain given as z(x, y).

The ray-cast sensors of :mod:`o3d_terrain.synthetic.sensors` stop at the first surface they
hit; a real airborne lidar records returns from inside the crowns and from the ground under
them, numbered along the pulse. This model draws those returns directly:

- pulses fall vertically at random (x, y), ``density`` per square metre;
- crowns are cones (2-4 m in radius at their base, from 30-50 % of the tree's height to its
  top, trees 15-30 m tall); a pulse under a crown meets its surface and goes into it, with
  up to three canopy returns, each with probability :data:`CANOPY_RETURN`, an exponential
  1.5 m apart, the pulse going on after each with probability :data:`CANOPY_ON`;
- shrubs are half-ellipsoids (1-2.5 m in radius, 0.5-2 m high): one under the pulse gives a
  return 0-0.3 m below its top with probability :data:`SHRUB_RETURN` and lets the pulse on
  with probability :data:`SHRUB_ON`;
- a pulse still going returns from the ground.

With the defaults about 42 % of the returns are ground, 57 % of the last returns, at any
density. Truth is exact: a point is ground when its pulse ended on the terrain
(``benchmarks/bench_forest.py``; docs/algorithm.md, "Cells for a sparse top-down scan").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError

CANOPY_RETURN = 0.7
CANOPY_ON = 0.5
SHRUB_RETURN = 0.7
SHRUB_ON = 0.4


@dataclass(frozen=True)
class ForestTile:
    """An airborne tile's returns with exact truth: ``positions`` (N, 3) float64 (with the
    offset, as a LAS tile's projected coordinates), ``is_ground`` (N,) bool, LAS-style
    ``return_numbers`` and ``number_of_returns`` (N,) int32 (1-based, along the pulse), and
    ``terrain_z`` (N,) the terrain's height under each point (with the offset)."""

    positions: np.ndarray
    is_ground: np.ndarray
    return_numbers: np.ndarray
    number_of_returns: np.ndarray
    terrain_z: np.ndarray

    def __len__(self) -> int:
        return len(self.positions)

    def to_pointcloud(self):
        """An Open3D tensor cloud carrying the return numbers, as
        :func:`o3d_terrain.read_cloud` gives a LAS tile (so that ``segment_terrain`` sees
        which returns are not their pulse's last)."""
        from ..frame import NUMBER_OF_RETURNS, RETURN_NUMBERS, cloud_from_numpy

        return cloud_from_numpy(self.positions, **{RETURN_NUMBERS: self.return_numbers,
                                                   NUMBER_OF_RETURNS: self.number_of_returns})


def _cones(x, y, height, rng, count, half_x, half_y, centre):
    """Per pulse: where it meets the highest conical crown over it and that crown's base
    height (-inf where no crown is over it)."""
    tx = centre[0] + rng.uniform(-half_x, half_x, count)
    ty = centre[1] + rng.uniform(-half_y, half_y, count)
    tall, radius = rng.uniform(15.0, 30.0, count), rng.uniform(2.0, 4.0, count)
    base = tall * rng.uniform(0.3, 0.5, count)
    ground = height(tx, ty)
    top = np.full(len(x), -np.inf)
    bottom = np.full(len(x), -np.inf)
    pulses = cKDTree(np.column_stack([x, y]))
    for t, near in enumerate(pulses.query_ball_point(np.column_stack([tx, ty]), radius)):
        near = np.asarray(near, dtype=np.int64)
        d = np.hypot(x[near] - tx[t], y[near] - ty[t])
        z = ground[t] + tall[t] - (tall[t] - base[t]) * d / radius[t]
        higher = z > top[near]
        top[near[higher]] = z[higher]
        bottom[near[higher]] = ground[t] + base[t]
    return top, bottom


def _domes(x, y, height, rng, count, half_x, half_y, centre):
    """Per pulse: the height of the highest shrub (half-ellipsoid) over it, -inf where none."""
    sx = centre[0] + rng.uniform(-half_x, half_x, count)
    sy = centre[1] + rng.uniform(-half_y, half_y, count)
    radius, tall = rng.uniform(1.0, 2.5, count), rng.uniform(0.5, 2.0, count)
    ground = height(sx, sy)
    top = np.full(len(x), -np.inf)
    pulses = cKDTree(np.column_stack([x, y]))
    for s, near in enumerate(pulses.query_ball_point(np.column_stack([sx, sy]), radius)):
        near = np.asarray(near, dtype=np.int64)
        r2 = ((x[near] - sx[s]) ** 2 + (y[near] - sy[s]) ** 2) / radius[s] ** 2
        top[near] = np.maximum(top[near], ground[s] + tall[s] * np.sqrt(np.clip(1.0 - r2, 0, None)))
    return top


def sample_forest_airborne(height: Callable[[np.ndarray, np.ndarray], np.ndarray], *,
                           region=(-50.0, 50.0, -50.0, 50.0), density: float = 1.0,
                           trees_per_ha: float = 300.0, shrubs_per_ha: float = 200.0,
                           noise: float = 0.03, offset=(500_000.0, 4_000_000.0, 300.0),
                           seed: int = 0) -> ForestTile:
    """An airborne tile of a forest over the terrain ``height(x, y)`` (vectorised, metres)
    within ``region`` (x_min, x_max, y_min, y_max): ``density`` pulses per square metre,
    ``trees_per_ha`` conifers and ``shrubs_per_ha`` shrubs per hectare at random, ``noise``
    m on each return's height; the tile moved by ``offset`` (projected coordinates, as a LAS
    tile's). The returns come in random order. See the module's docstring for the model."""
    x_min, x_max, y_min, y_max = (float(v) for v in region)
    if not (x_max > x_min and y_max > y_min):
        raise InputError(f"region {tuple(region)} must have x_max > x_min and y_max > y_min")
    for name, value in (("density", density), ("trees_per_ha", trees_per_ha),
                        ("shrubs_per_ha", shrubs_per_ha), ("noise", noise)):
        if not (np.isfinite(value) and value >= 0) or (name == "density" and value <= 0):
            raise InputError(f"{name} must be a finite number {'> 0' if name == 'density' else '>= 0'}, "
                             f"got {value!r}")
    rng = np.random.default_rng(seed)
    area = (x_max - x_min) * (y_max - y_min)
    centre = (0.5 * (x_min + x_max), 0.5 * (y_min + y_max))
    half = (0.5 * (x_max - x_min), 0.5 * (y_max - y_min))
    n = int(round(density * area))
    x, y = rng.uniform(x_min, x_max, n), rng.uniform(y_min, y_max, n)
    top, bottom = _cones(x, y, height, rng, int(round(trees_per_ha * area / 1e4)), *half, centre)
    shrub = _domes(x, y, height, rng, int(round(shrubs_per_ha * area / 1e4)), *half, centre)
    going = np.ones(n, bool)
    pulse, heights, order = [], [], []
    depth = top.copy()
    for k in range(3):  # canopy returns, top down
        z = depth - rng.exponential(1.5, n)
        hit = going & (rng.uniform(size=n) < CANOPY_RETURN) & (z > bottom)
        pulse.append(np.flatnonzero(hit)), heights.append(z[hit]), order.append(np.full(hit.sum(), k))
        depth = np.where(hit, z, depth)
        going &= ~(hit & (rng.uniform(size=n) > CANOPY_ON))
    ground = np.asarray(height(x, y), dtype=np.float64)
    z = shrub - rng.uniform(0.0, 0.3, n)
    hit = going & np.isfinite(shrub) & (rng.uniform(size=n) < SHRUB_RETURN) & (z > ground + 0.05)
    pulse.append(np.flatnonzero(hit)), heights.append(z[hit]), order.append(np.full(hit.sum(), 3))
    going &= ~(hit & (rng.uniform(size=n) > SHRUB_ON))
    pulse.append(np.flatnonzero(going)), heights.append(ground[going])
    order.append(np.full(going.sum(), 4))
    pulse, z, order = np.concatenate(pulse), np.concatenate(heights), np.concatenate(order)
    # returns numbered along each pulse
    sort = np.lexsort((order, pulse))
    starts = np.r_[0, np.flatnonzero(np.diff(pulse[sort])) + 1]
    counts = np.diff(np.r_[starts, len(sort)])
    number_of_returns = np.empty(len(sort), np.int32)
    return_numbers = np.empty(len(sort), np.int32)
    number_of_returns[sort] = np.repeat(counts, counts)
    return_numbers[sort] = np.arange(len(sort)) - np.repeat(starts, counts) + 1
    positions = np.column_stack([x[pulse], y[pulse], z + rng.normal(0.0, noise, len(z))])
    shuffle = rng.permutation(len(z))
    shift = np.asarray(offset, dtype=np.float64)
    return ForestTile(positions[shuffle] + shift, (order == 4)[shuffle],
                      return_numbers[shuffle], number_of_returns[shuffle],
                      ground[pulse][shuffle] + shift[2])
