"""Object feet: terrain-level points in the column of an object's low part become obstacle."""

from __future__ import annotations

import naive
import numpy as np
import pytest

from o3d_terrain.api import segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.segment import TerrainLabel, mark_object_feet, segment_points
from o3d_terrain.spline import make_lsq_surface

T, O, B, U = (int(v) for v in (TerrainLabel.TERRAIN, TerrainLabel.OBSTACLE,
                               TerrainLabel.BELOW_TERRAIN, TerrainLabel.UNKNOWN))


def flat_surface():
    x = np.linspace(0, 30, 31)
    y = np.linspace(-10, 10, 21)
    return make_lsq_surface(x, y, np.zeros((31, 21)), control_points=(5, 5))


def bush_scene(seed=0):
    """Flat ground sampled densely, a bush whose points rise continuously from the ground up
    to 1 m (its lowest points lie inside any terrain threshold), and a car body whose points
    all lie 0.6 m or more above the ground (a gap underneath, ground visible below)."""
    rng = np.random.default_rng(seed)
    n = 40_000
    ground = np.c_[rng.uniform(0, 30, n), rng.uniform(-10, 10, n), rng.normal(0, 0.01, n)]
    m = 3_000
    bush = np.c_[rng.uniform(10, 11, m), rng.uniform(0, 1, m), rng.uniform(0.0, 1.0, m)]
    car = np.c_[rng.uniform(20, 24, m), rng.uniform(-1, 1, m), rng.uniform(0.6, 1.5, m)]
    positions = np.vstack([ground, bush, car])
    kind = np.r_[np.zeros(n, int), np.ones(m, int), np.full(m, 2)]
    return positions, kind


def test_kernel_matches_the_plain_reference():
    rng = np.random.default_rng(3)
    n = 5_000
    positions = np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n) + 4.5e6, rng.normal(0, 1, n)]
    labels = rng.choice(np.array([T, O, B, U], np.uint8), n, p=[0.6, 0.3, 0.05, 0.05])
    heights = np.select([labels == T, labels == O, labels == B],
                        [rng.normal(0, 0.05, n), rng.uniform(0.15, 1.2, n),
                         -rng.uniform(0.5, 1.0, n)], np.nan)
    positions[::97, 0] = np.nan
    heights[::89] = np.nan
    cases = ((0.15, 0.5, 0.3, 0.1, 0.35, 1.0, 3.5), (0.3, 0.8, 0.0, 0.0, 0.0, 0.7, 0.5),
             (0.07, 0.4, 0.5, 0.25, 1.1, 2.0, 0.0), (0.5, 1.2, 0.25, 0.6, 0.2, 1.0, 1.0))
    counts = []
    for cell, foot_height, fraction, rise, object_height, noise_cell, noise_factor in cases:
        expected, count = naive.mark_object_feet(labels, heights, positions, foot_height,
                                                 cell, fraction, rise, object_height,
                                                 noise_cell, noise_factor, 0.5, T, O)
        got = labels.copy()
        changed = mark_object_feet(got, heights, positions, foot_height=foot_height, cell=cell,
                                   fraction=fraction, rise=rise, object_height=object_height,
                                   noise_cell=noise_cell, noise_factor=noise_factor)
        np.testing.assert_array_equal(got, expected)
        assert changed == count
        counts.append(count)
    assert min(counts) > 0 and len(set(counts)) == len(counts)  # each case decides differently
    got = labels.copy()
    assert mark_object_feet(got, heights, positions, foot_height=0.0) == 0  # 0 = off
    np.testing.assert_array_equal(got, labels)


def test_bush_base_becomes_obstacle_and_ground_beside_it_stays_terrain():
    positions, kind = bush_scene()
    surface = flat_surface()
    plain, h = segment_points(surface, positions, threshold=0.2, foot_height=0)
    labels, _ = segment_points(surface, positions, threshold=0.2)
    bush_base = (kind == 1) & (h <= 0.2)
    assert bush_base.sum() > 300
    assert (plain[bush_base] == T).all()  # height alone calls them terrain
    assert (labels[bush_base] == O).all()  # the column with the bush above says obstacle
    ground = kind == 0
    # ground under the bush's footprint goes with it; the rest of the ground is untouched
    under = ground & (positions[:, 0] >= 10) & (positions[:, 0] < 11) & \
        (positions[:, 1] >= 0) & (positions[:, 1] < 1)
    far = ground & ~((np.abs(positions[:, 0] - 10.5) < 1) & (np.abs(positions[:, 1] - 0.5) < 1))
    assert (labels[far] == T).all()
    assert (labels[under] == O).mean() > 0.9
    # the car body starts 0.6 m up: its columns are not marked, the ground under it is terrain
    below_car = ground & (np.abs(positions[:, 0] - 22) < 2) & (np.abs(positions[:, 1]) < 1)
    assert below_car.sum() > 100 and (labels[below_car] == T).all()


def test_feet_need_obstacle_points_below_foot_height():
    positions, _ = bush_scene()
    surface = flat_surface()
    labels, _ = segment_points(surface, positions, threshold=0.2, foot_height=0.15)
    plain, _ = segment_points(surface, positions, threshold=0.2, foot_height=0)
    np.testing.assert_array_equal(labels, plain)  # no obstacle point lies in (0.2, 0.15)


def test_segment_terrain_option_and_errors():
    positions, kind = bush_scene(1)
    _, with_feet = segment_terrain(positions, distance_threshold=0.2)
    _, without = segment_terrain(positions, distance_threshold=0.2, foot_height=0)
    assert set(with_feet.tolist()) < set(without.tolist())
    removed = np.setdiff1d(without, with_feet)
    assert (kind[removed] != 2).all() and (kind[removed] == 1).mean() > 0.5
    with pytest.raises(InputError, match="foot_height"):
        segment_terrain(positions, foot_height=-1)
    labels = np.ones(3, np.uint8)
    with pytest.raises(InputError, match="one entry per point"):
        mark_object_feet(labels, np.zeros(2), np.zeros((3, 3)))
    with pytest.raises(InputError, match="fraction"):
        mark_object_feet(labels, np.zeros(3), np.zeros((3, 3)), fraction=-0.1)
    with pytest.raises(InputError, match="uint8"):
        mark_object_feet(labels.astype(np.int64), np.zeros(3), np.zeros((3, 3)))


def test_a_column_that_rises_no_more_than_terrain_is_not_a_foot():
    """Where the surface undercuts steep ground, ground points just above the threshold share
    columns with ground points just below it: a column must reach more than 0.1 m above its
    lowest point to be the foot of an object."""
    surface = flat_surface()
    # columns are counted from the lowest x and y of the obstacle points below foot_height
    # (5.08, 0.06): each group lies inside one 0.15 m column
    column = [[5.10, 0.08, 0.03], [5.12, 0.10, 0.06], [5.08, 0.06, 0.11]]  # a 0.08 m rise
    foot = [[8.10, 0.08, 0.03], [8.12, 0.10, 0.06], [8.14, 0.12, 0.25]]  # a post's low part
    post = [[8.13, 0.11, 1.0]]  # the post above it
    positions = np.array(column + foot + post, float)
    labels, _ = segment_points(surface, positions, threshold=0.1)
    assert labels.tolist() == [T, T, O, O, O, O, O]
    labels, _ = segment_points(surface, positions, threshold=0.1, foot_height=0)
    assert labels.tolist() == [T, T, O, T, T, O, O]
    # without the post, nothing shows that an object stands there: a 0.25 m bump of rough
    # ground or the upper tail of a noisy sensor's ground takes no ground along
    labels, _ = segment_points(surface, positions[:-1], threshold=0.1)
    assert labels.tolist() == [T, T, O, T, T, O]
