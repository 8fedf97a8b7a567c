"""Cells for a sparse top-down scan (RationalBSplineTerrain grow_cells, o3d_terrain.grid.grown_cell)
and the fit on the last returns of a LAS tile's pulses (ground_returns), checked against the
exact terrain of small synthetic forests seen from the air."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_terrain import fit_terrain, segment_terrain
from o3d_terrain.grid import (
    CELL_POINTS,
    GROWN_CELL_STEP,
    MAX_GROWN_CELL,
    block_sums,
    grown_cell,
    quantize_points,
    requantize,
    typical_density,
)
from o3d_terrain.synthetic import sample_forest_airborne



def hills(x, y):
    return 2.0 * np.sin(x / 12.0) + 1.5 * np.cos(y / 9.0) + 0.15 * x


def _forest(density, size=60.0, seed=0):
    """A conifer forest with shrubs over ``hills``, seen from the air (several returns per
    pulse, :func:`o3d_terrain.synthetic.sample_forest_airborne`)."""
    return sample_forest_airborne(hills, region=(0.0, size, 0.0, size), density=density,
                                  seed=seed)


def _height_error(surface, tile) -> float:
    """Root mean square of the surface's height error at the ground points (exact terrain)."""
    q = tile.positions[tile.is_ground]
    err = surface(q[:, 0], q[:, 1]) - tile.terrain_z[tile.is_ground]
    return float(np.sqrt(np.mean(err ** 2)))


def test_block_sums_pad_the_last_blocks(rng):
    values = rng.integers(0, 5, (7, 10))
    sums = block_sums(values, 3)
    assert sums.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert sums[i, j] == values[3 * i:3 * i + 3, 3 * j:3 * j + 3].sum()
    np.testing.assert_array_equal(block_sums(values > 2, 3) > 0,
                                  [[(values[3 * i:3 * i + 3, 3 * j:3 * j + 3] > 2).any()
                                    for j in range(4)] for i in range(3)])


def test_typical_density_is_where_most_points_lie(rng):
    uniform = np.column_stack([rng.uniform(0, 100, (2, 20_000)).T, np.zeros(20_000)])
    assert typical_density(quantize_points(uniform, cell_size=0.5)) == pytest.approx(2.0, rel=0.15)
    # a dense corner holding most of the points sets it; the sparse rest does not lower it
    corner = np.column_stack([rng.uniform(0, 20, (2, 16_000)).T, np.zeros(16_000)])
    rest = np.column_stack([rng.uniform(0, 200, (2, 2_000)).T, np.zeros(2_000)])
    mixed = quantize_points(np.vstack([corner, rest]), cell_size=0.5)
    assert typical_density(mixed) == pytest.approx(40.0, rel=0.2)


@pytest.mark.parametrize("density, expected", [(20.0, 0.5), (4.0, 0.5), (2.0, 1.25),
                                               (1.0, 1.75), (0.5, 2.5), (0.05, MAX_GROWN_CELL)])
def test_grown_cell_holds_about_three_points(rng, density, expected):
    n = int(density * 120 * 120)
    cloud = np.column_stack([rng.uniform(0, 120, (2, n)).T, np.zeros(n)])
    grid = quantize_points(cloud, cell_size=0.5)
    cell = grown_cell(grid)
    assert cell == pytest.approx(expected, abs=GROWN_CELL_STEP)
    if cell > grid.cell_size:
        assert cell <= MAX_GROWN_CELL
        held = len(cloud) / requantize(grid, cloud, cell_size=cell).count.size
        assert held == pytest.approx(density * cell * cell, rel=0.1)
        if cell < MAX_GROWN_CELL:  # about CELL_POINTS, rounded up to the next step
            assert CELL_POINTS <= held < CELL_POINTS * ((cell + GROWN_CELL_STEP) / cell) ** 2


def test_requantize_at_another_cell_keeps_the_region_and_options(rng):
    cloud = np.column_stack([rng.uniform(0, 30, (2, 3000)).T, rng.normal(0, 0.02, 3000)])
    grid = quantize_points(cloud, cell_size=0.5, layer=0.2, plane=True, tilt_spread=0.03)
    coarse = requantize(grid, cloud, cell_size=1.5, layer=0.4)
    assert coarse.cell_size == 1.5 and coarse.layer == 0.4
    assert coarse.plane_sample is not None and coarse.tilt_spread == 0.03
    assert (coarse.x_min, coarse.y_min) == (grid.x_min, grid.y_min)
    assert coarse.count.sum() == grid.count.sum() == len(cloud)


def test_a_sparse_forest_tile_is_fitted_on_grown_cells():
    tiles = [_forest(0.7, seed=seed) for seed in range(3)]
    # at 0.5 m most cells hold one return, from the vegetation more often than from the
    # ground, and the surface rides into it (by metres on two of the three tiles); grown
    # cells also hold a ground return
    fixed = [_height_error(fit_terrain(t.positions, grow_cells=False), t) for t in tiles]
    assert sorted(fixed)[1] > 1.0
    for tile in tiles:
        grown, inliers = segment_terrain(tile.positions)
        assert _height_error(grown, tile) < 0.05
        terrain = np.zeros(len(tile), bool)
        terrain[inliers] = True
        assert terrain[tile.is_ground].mean() > 0.97
        assert terrain[~tile.is_ground].mean() < 0.01
        # the refit fits the terrain points at the grid's own cell, which the surface keeps
        assert grown.cell_size == 0.5


def test_a_dense_tile_keeps_its_cells():
    tile = _forest(6.0, size=40.0)
    a = fit_terrain(tile.positions)
    b = fit_terrain(tile.positions, grow_cells=False)
    np.testing.assert_array_equal(a.control_points, b.control_points)


def test_the_fit_leaves_earlier_returns_out():
    tiles = [_forest(1.5, seed=seed) for seed in range(3)]
    clouds = [t.to_pointcloud() for t in tiles]
    # the crowns' returns before the last of their pulse hold many 0.5 m cells: without them
    # the fit sees the ground (or the shrub) the same pulses went on to
    last = [_height_error(fit_terrain(c, grow_cells=False), t) for c, t in zip(clouds, tiles)]
    every = [_height_error(fit_terrain(c, grow_cells=False, ground_returns="all"), t)
             for c, t in zip(clouds, tiles)]
    assert max(last) < 0.05
    assert max(every) > 0.3
    for cloud, tile in zip(clouds, tiles):
        surface, inliers = segment_terrain(cloud)
        assert _height_error(surface, tile) < 0.05
        terrain = np.zeros(len(tile), bool)
        terrain[inliers] = True
        assert terrain[tile.is_ground].mean() > 0.97
        assert terrain[~tile.is_ground].mean() < 0.01


def test_a_vehicle_scan_keeps_its_cells(vehicle_scan, small_cloud):
    # points around the sensor: never grown, however sparse the scan
    sparse = small_cloud[::8]
    a, inliers = segment_terrain(sparse)
    b, inliers_fixed = segment_terrain(sparse, grow_cells=False)
    np.testing.assert_array_equal(inliers, inliers_fixed)
    np.testing.assert_array_equal(a.control_points, b.control_points)
