"""Kernels of the terrain prior (o3d_terrain/_kernels/ground.py) against plain loops."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_terrain._kernels.ground import (below_compact_neighbours, steepest_neighbour_slope,
                                         window_min)


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


def test_steepest_neighbour_slope_matches_a_plain_loop(rng):
    h = rng.normal(0, 1, (9, 7))
    h[rng.uniform(size=h.shape) < 0.2] = np.inf
    got = steepest_neighbour_slope(h, 0.5)
    for i in range(9):
        for j in range(7):
            best = 0.0
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    a, b = i + di, j + dj
                    if (di or dj) and 0 <= a < 9 and 0 <= b < 7 and np.isfinite(h[a, b]) \
                            and np.isfinite(h[i, j]):
                        best = max(best, abs(h[a, b] - h[i, j]) / (0.5 * np.hypot(di, dj)))
            assert got[i, j] == pytest.approx(best)


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
