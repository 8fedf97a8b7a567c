"""Free space under the rays: the cells over where a scan's rays went on to farther returns
(a ceiling, a roof, a canopy) are left out of the fit (o3d_terrain.grid.without_overhead)."""

import numpy as np
import pytest

import o3d_terrain
from o3d_terrain import grid as grid_module
from o3d_terrain._kernels.free_space import overhead_cells as overhead_kernel
from o3d_terrain.errors import InputError
from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.grid import (
    overhead_cells,
    quantize_points,
    requantize,
    sensor_above_ground,
    without_cells,
    without_overhead,
)
from o3d_terrain.synthetic import sample_under_ceiling


@pytest.fixture(scope="module")
def cavern():
    """A 32-channel lidar, 90 degree field of view, 2 m over a level floor under a roof 10 m
    over it, no walls: positions in the sensor's frame and ground truth."""
    return sample_under_ceiling(10.0, beams=32, firings=512)


def test_the_roof_over_the_floor_s_rays_is_overhead_and_no_floor_cell_is(cavern):
    p, floor = cavern
    grid = quantize_points(p, cell_size=0.5)
    over = overhead_cells(grid, (0.0, 0.0, 0.0))
    floor_cells = quantize_points(p[floor], cell_size=0.5, region=grid.region).count > 0
    roof_cells = quantize_points(p[~floor], cell_size=0.5, region=grid.region).count > 0
    assert not (over & floor_cells).any()
    # most of the roof within 20 m, where the floor's rings lie close together (beams 2.9
    # degrees apart; farther, a 0.5 degree sector between two of the 512 firings holds fewer
    # floor rays), and none of what is flagged lower than the roof, 8 m over the sensor
    x, y = np.meshgrid(grid.x_centers, grid.y_centers, indexing="ij")
    roof_only = roof_cells & ~floor_cells
    assert over[roof_only & (np.hypot(x, y) < 20.0)].mean() > 0.9
    assert grid.lowest[over].min() > 7.0


def test_a_few_returns_from_below_the_floor_do_not_lower_the_bound():
    """The bound is the third-lowest ray of a sector beyond a cell: two returns 3 m under a
    floor 2 m below the sensor, 40 m out, leave the floor in front of them as it is; the
    lowest ray alone, without the allowances, would flag it."""
    x, y = np.meshgrid(np.arange(-50.0, 50.0, 0.25), np.arange(-50.0, 50.0, 0.25))
    floor = np.c_[x.ravel(), y.ravel(), np.full(x.size, -2.0)]
    angle = np.radians(30.0)
    low = [[40.0 * np.cos(angle), 40.0 * np.sin(angle), -5.0]] * 2
    grid = quantize_points(np.vstack([floor, low]), cell_size=0.5)
    args = (np.ascontiguousarray(grid.lowest), grid.x_min, grid.y_min, grid.cell_size, 0.0, 0.0,
            0.0, grid_module.OVERHEAD_SECTORS, grid_module.OVERHEAD_BIN,
            int(80.0 / grid_module.OVERHEAD_BIN) + 1)
    tolerance = (grid_module.OVERHEAD_CLEARANCE, 8.0 / grid_module.OVERHEAD_SECTORS)
    assert not overhead_kernel(*args, grid_module.OVERHEAD_RANK, *tolerance).any()
    assert overhead_kernel(*args, 1, 0.0, 0.0).sum() > 10


def test_emptied_cells_are_the_grid_made_again_without_their_points(cavern):
    p, _ = cavern
    rng = np.random.default_rng(3)
    for options in ({}, {"layer": 0.3, "plane": True, "tilt_spread": 0.03},
                    {"min_points": 2}, {"fill_empty": False}):
        grid = quantize_points(p, cell_size=0.5, **options)
        cells = (rng.random(grid.shape) < 0.3) & (grid.count > 0)
        index = grid.cell_of(p[:, 0], p[:, 1])
        dropped = (index >= 0) & cells.reshape(-1)[np.maximum(index, 0)]
        expected = requantize(grid, np.ascontiguousarray(p[~dropped]))
        got = without_cells(grid, cells)
        for name in ("z", "count", "state", "lowest", "highest", "mean", "layer_count",
                     "layer_sum", "layer_above", "level", "plane_sample"):
            a, b = getattr(got, name), getattr(expected, name)
            assert (a is None and b is None) or np.array_equal(a, b), (options, name)


def test_only_a_sensor_over_the_ground_casts_rays(cavern):
    p, _ = cavern
    grid = quantize_points(p, cell_size=0.5)
    assert sensor_above_ground(grid, (0.0, 0.0, 0.0))
    assert not sensor_above_ground(grid, (0.0, 0.0, -2.0))  # on the floor: a stereo rig's
    assert not sensor_above_ground(grid, (500.0, 0.0, 0.0))  # no ground around it
    kept_grid, kept, dropped = without_overhead(grid, p, (0.0, 0.0, -2.0))
    assert dropped == 0 and kept is p and kept_grid is grid


def test_segment_terrain_under_a_roof_keeps_to_the_floor(cavern):
    p, floor = cavern

    def f1(**options):
        _, inliers = o3d_terrain.segment_terrain(p, **options)
        labels = np.zeros(len(p), bool)
        labels[inliers] = True
        return segmentation_counts(labels, floor).f1

    with_rays, without = f1(), f1(free_space=False)
    assert with_rays > 0.96
    assert with_rays > without + 0.03


def test_the_stage_says_what_it_left_out(cavern):
    p, _ = cavern
    frame = o3d_terrain.stages.GridQuantize()(p)
    fitted = o3d_terrain.stages.RationalBSplineTerrain()(frame)
    fit = fitted.product("terrain_fit")
    assert fit.overhead > 0
    assert any("free_space" in note for note in fitted.notes)
    off = o3d_terrain.stages.RationalBSplineTerrain(free_space=False)(frame)
    assert off.product("terrain_fit").overhead is None


def test_sample_under_ceiling_rejects_a_roof_under_the_sensor():
    with pytest.raises(InputError, match="roof"):
        sample_under_ceiling(1.5, sensor_height=2.0)
