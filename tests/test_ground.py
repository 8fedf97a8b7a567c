"""Kernels of the terrain prior (o3d_terrain/_kernels/ground.py) against plain loops."""

from __future__ import annotations

import numpy as np
import pytest
from naive import above_slope_cone, cone_fill

from o3d_terrain._kernels.ground import (below_compact_neighbours,
                                         compact_cells, compact_rise, neighbour_rise,
                                         prior_seeds, window_min)


@pytest.mark.parametrize("shape,radius", [((31, 20), 4), ((7, 5), 3), ((30, 9), 1),
                                          ((5, 40), 10), ((1, 1), 2), ((9, 18), 4),
                                          ((10, 19), 4)])
def test_window_min_matches_a_plain_loop(rng, shape, radius):
    values = rng.normal(size=shape)
    values[rng.uniform(size=shape) < 0.3] = np.inf  # empty cells
    got = window_min(values, radius)
    for i in range(shape[0]):
        for j in range(shape[1]):
            window = values[max(0, i - radius):i + radius + 1, max(0, j - radius):j + radius + 1]
            assert got[i, j] == window.min()


def _rise_reference(h, cell, cap):
    """neighbour_rise in plain Python: of the rises to the two neighbours along x and the two
    along y, the largest and (with neighbours on both axes) the least of the two axes'
    smaller ones, as slopes capped together at ``cap``, summed over the cell; where an axis
    has no neighbour, a diagonal neighbour's rise (at most cell * cap * sqrt(2)) where
    larger."""
    out = np.zeros(h.shape)
    for i in range(h.shape[0]):
        for j in range(h.shape[1]):
            if not np.isfinite(h[i, j]):
                continue
            rises = {"x": [], "y": [], "d": []}
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    a, b = i + di, j + dj
                    if (di or dj) and 0 <= a < h.shape[0] and 0 <= b < h.shape[1] \
                            and np.isfinite(h[a, b]):
                        key = "x" if dj == 0 else "y" if di == 0 else "d"
                        rises[key].append(abs(h[a, b] - h[i, j]))
            both = bool(rises["x"]) and bool(rises["y"])
            large = max(rises["x"] + rises["y"] + [0.0]) / cell
            small = min(min(rises["x"]), min(rises["y"])) / cell if both else 0.0
            scale = min(1.0, cap / np.hypot(large, small)) if large else 1.0
            out[i, j] = cell * scale * (large + small)
            if not both:
                out[i, j] = max(out[i, j], min(max(rises["d"] + [0.0]), cell * cap * np.sqrt(2)))
    return out


def test_neighbour_rise_matches_a_plain_loop(rng):
    h = rng.normal(0, 1, (9, 7))
    h[rng.uniform(size=h.shape) < 0.2] = np.inf
    for cap in (1.0, 100.0):
        np.testing.assert_allclose(neighbour_rise(h, 0.5, cap), _rise_reference(h, 0.5, cap))


@pytest.mark.parametrize("direction_deg", [0.0, 20.0, 45.0, 110.0])
def test_the_rise_across_a_cell_is_the_planes_whatever_its_direction(direction_deg):
    """On a 60° plane whose cells' lowest points lie at their downslope corners, the rise is
    the plane's from one corner of a cell to the opposite one, c tan(60°) (|cos| + |sin|) of
    the plane's direction: a face at an angle to the grid spans that much in a cell (the
    steepest slope to a neighbour, the rise before, gave it along the axes only)."""
    c, g = 0.5, np.tan(np.radians(60.0))
    t = np.radians(direction_deg)
    gx, gy = g * np.cos(t), g * np.sin(t)
    i, j = np.meshgrid(np.arange(12), np.arange(12), indexing="ij")
    # the lowest corner of cell (i, j): the plane's least value over its four corners
    low = np.minimum.reduce([gx * (i + a) * c + gy * (j + b) * c for a in (0, 1) for b in (0, 1)])
    expected = c * g * (abs(np.cos(t)) + abs(np.sin(t)))
    rise = neighbour_rise(low, c, np.tan(np.radians(65.0)))
    np.testing.assert_allclose(rise[1:-1, 1:-1], expected)
    # capped at a 45° limit: the capped plane's rise in the same direction
    capped = neighbour_rise(low, c, 1.0)
    np.testing.assert_allclose(capped[1:-1, 1:-1], c * (abs(np.cos(t)) + abs(np.sin(t))))


@pytest.mark.parametrize("need", [1, 2])
def test_below_compact_neighbours_matches_a_plain_loop(rng, need):
    h = rng.normal(0, 0.2, (12, 9))
    candidate = rng.uniform(size=h.shape) < 0.5
    compact = ~candidate & (rng.uniform(size=h.shape) < 0.7)
    got = below_compact_neighbours(h, candidate, compact, 0.09, need)
    for i in range(12):
        for j in range(9):
            tops = [h[a, b] for a in range(i - 1, i + 2) for b in range(j - 1, j + 2)
                    if (a, b) != (i, j) and 0 <= a < 12 and 0 <= b < 9 and compact[a, b]]
            expected = candidate[i, j] and len(tops) >= need and h[i, j] <= max(tops) + 0.09
            assert got[i, j] == expected


@pytest.mark.parametrize("use_highest", [True, False])
def test_compact_cells_matches_its_definition(rng, use_highest):
    shape = (14, 11)
    low = rng.normal(0, 0.3, shape)
    low[rng.uniform(size=shape) < 0.1] = np.inf
    sample = low + rng.uniform(0, 0.2, shape)
    highest = low + rng.uniform(0, 0.6, shape)
    count = rng.integers(1, 6, shape)
    connected = np.isfinite(low) & (rng.uniform(size=shape) < 0.9)
    compact, rise = compact_cells(low, sample, highest, count, connected, 0.5, 1.0, 0.09, 3, 2,
                                  use_highest)
    expected_rise = _rise_reference(low, 0.5, 1.0)
    np.testing.assert_allclose(rise, expected_rise)
    with np.errstate(invalid="ignore"):  # inf - inf at empty cells (never connected)
        extent = (highest - low <= 0.09 + expected_rise) if use_highest else np.ones(shape, bool)
        dense = connected & (count >= 3) & (sample - low <= 0.09 + 0.5 * expected_rise) & extent
    sparse = connected & (count < 3) & extent
    expected = dense | below_compact_neighbours(low, sparse, dense, 0.09, 2)
    assert np.array_equal(compact, expected)
    assert dense.any() and (expected & ~dense).any()  # both kinds occur


def test_compact_rise_matches_its_definition(rng):
    # the rise that widens a compact cell: to compact neighbours only, capped; 0 elsewhere
    shape = (13, 10)
    low = rng.normal(0, 0.3, shape)
    compact = rng.uniform(size=shape) < 0.6
    got = compact_rise(low, compact, 0.5, 1.0)
    np.testing.assert_allclose(got, _rise_reference(np.where(compact, low, np.inf), 0.5, 1.0))
    # a compact cell whose only higher neighbour is not compact (a face above it): no rise
    low = np.zeros((3, 3))
    low[1, 2] = 0.4
    compact = np.ones((3, 3), bool)
    compact[1, 2] = False
    assert compact_rise(low, compact, 0.5, 1.0)[1, 1] == 0.0
    assert neighbour_rise(low, 0.5, 1.0)[1, 1] == pytest.approx(0.4)


@pytest.mark.parametrize("shape", [(23, 17), (1, 6), (6, 1), (40, 33), (1, 1), (2, 3)])
def test_prior_seeds_equals_the_separate_kernels(rng, shape):
    # the fused kernel of the terrain prior gives the values of the plain cone envelope, wall
    # test (tests/naive.py) and window_min composed
    low = np.cumsum(rng.normal(0, 0.3, shape), axis=0) + rng.normal(0, 0.2, shape)
    low[rng.uniform(size=shape) < 0.3] = np.inf
    low[rng.uniform(size=shape) < 0.05] += 3.0  # walls
    measured = np.isfinite(low)
    crossed, seeds = prior_seeds(low, measured, 0.5, 0.36, 1.0, 0.09, 3)
    walls = above_slope_cone(low, 0.5, 1.0, 0.09)
    # empty cells next to a measured one take the slope cone (the points' spacing, no gap)
    padded = np.pad(measured, 1)
    beside = np.zeros(shape, bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di or dj:
                beside |= padded[1 + di:1 + di + shape[0], 1 + dj:1 + dj + shape[1]]
    gap = np.where(beside & ~measured, cone_fill(low, np.zeros(shape, bool), 0.5, 1.0),
                   cone_fill(low, measured, 0.5, 0.36))
    expected = np.where(walls, np.inf, gap)
    np.testing.assert_array_equal(crossed, expected)
    np.testing.assert_array_equal(seeds, measured & (low <= window_min(low, 3)) & ~walls)


def test_prior_connects_a_steep_slope_sampled_sparsely():
    """An airborne tile's one point per four 0.5 m cells leaves every measured cell among empty
    ones: those next to a point are its spacing, not a gap, and take the slope cone, so a 30
    degree slope stays connected (with the gap slope's 20 degrees there: 14 % of its cells)."""
    from o3d_terrain.grid import quantize_points
    from o3d_terrain.terrain import terrain_prior_mask

    rng = np.random.default_rng(3)
    n = 2500  # 60 x 40 m, about one point per m^2
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 40, n)
    for degrees in (25.0, 30.0):
        z = np.tan(np.radians(degrees)) * x + rng.normal(0, 0.02, n)
        grid = quantize_points(np.c_[x, y, z], cell_size=0.5)
        connected, _ = terrain_prior_mask(grid)
        assert connected.sum() >= 0.97 * (grid.state == 1).sum()
