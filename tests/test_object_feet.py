"""Object feet: terrain-level points in the column of an object's low part become obstacle."""

from __future__ import annotations

import naive
import numpy as np
import pytest

from o3d_terrain.api import segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.segment import (TerrainLabel, auto_range_coefficient, auto_threshold,
                                 mark_object_feet, scan_line_spacing, segment_points)
from o3d_terrain.spline import make_lsq_surface
from o3d_terrain.synthetic import (Obstacle, default_obstacles, make_scene, sample_lidar,
                                   sample_stereo)

T, O, B, U = (int(v) for v in (TerrainLabel.TERRAIN, TerrainLabel.OBSTACLE,  # noqa: E741
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
    cases = ((0.15, 0.5, 0.3, 0.1, 0.35, 1.0, 3.5, 0.0), (0.3, 0.8, 0.0, 0.0, 0.0, 0.7, 0.5, 0.0),
             (0.07, 0.4, 0.5, 0.25, 1.1, 2.0, 0.0, 0.0), (0.5, 1.2, 0.25, 0.6, 0.2, 1.0, 1.0, 0.0),
             (0.15, 0.3, 0.3, 0.1, 0.35, 1.0, 3.5, 2.0),  # grows with range
             (0.15, 0.5, 0.3, 0.1, 0.35, 1.0, 3.5, 2.0, 0.2, 0.13),  # and behind the marks
             (0.07, 0.5, 0.3, 0.1, 0.35, 1.0, 3.5, 0.0, 0.3, 0.05),
             (0.15, 0.5, 0.3, 0.1, 0.35, 1.0, 3.5, 0.0, 0.0, 0.0, 0.4),  # no free space
             (0.3, 0.8, 0.2, 0.0, 0.35, 1.0, 3.5, 2.0, 0.2, 0.13, 0.2))
    sensor = (0.5, 4.5e6 - 1.0, 0.0)
    counts = []
    for cell, foot_height, fraction, rise, object_height, noise_cell, noise_factor, \
            spacing, *behind in cases:
        radius, margin, gap = (list(behind) + [0.0, 0.0, 0.0])[:3]
        slope = 3.0 * np.tan(np.radians(spacing))
        expected, count = naive.mark_object_feet(labels, heights, positions, foot_height,
                                                 cell, fraction, rise, object_height,
                                                 noise_cell, noise_factor, 0.5, T, O, slope,
                                                 0.9, sensor[:2], radius, margin, gap)
        got = labels.copy()
        changed = mark_object_feet(got, heights, positions, foot_height=foot_height, cell=cell,
                                   fraction=fraction, rise=rise, object_height=object_height,
                                   noise_cell=noise_cell, noise_factor=noise_factor,
                                   line_spacing=spacing, foot_lines=3.0, foot_cap=0.9,
                                   sensor_origin=sensor, behind_radius=radius,
                                   behind_margin=margin, foot_gap=gap)
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
    # the column with the bush above says obstacle (on one of the two lattices: the columns
    # of one that straddle the bush's edge hold more ground than bush)
    assert (labels[bush_base] == O).all()
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
    # the columns lie on a lattice of multiples of 0.15 m: each group lies inside one column
    column = [[5.18, 0.08, 0.03], [5.20, 0.10, 0.06], [5.16, 0.06, 0.11]]  # a 0.08 m rise
    foot = [[8.16, 0.08, 0.03], [8.18, 0.10, 0.06], [8.20, 0.12, 0.17]]  # a post's low part
    post = [[8.19, 0.11, 1.0]]  # the post above it
    positions = np.array(column + foot + post, float)
    labels, _ = segment_points(surface, positions, threshold=0.1)
    assert labels.tolist() == [T, T, O, O, O, O, O]
    labels, _ = segment_points(surface, positions, threshold=0.1, foot_height=0)
    assert labels.tolist() == [T, T, O, T, T, O, O]
    # without the post, nothing shows that an object stands there: a 0.25 m bump of rough
    # ground or the upper tail of a noisy sensor's ground takes no ground along
    labels, _ = segment_points(surface, positions[:-1], threshold=0.1)
    assert labels.tolist() == [T, T, O, T, T, O]


def test_columns_lie_on_a_fixed_lattice():
    """A column's verdict depends on its own points and its neighbours', not on where the
    other obstacle points lie: a low obstacle point far away (which moved the columns when
    they were counted from the lowest candidate) changes nothing."""
    surface = flat_surface()
    foot = [[10.07, 0.08, 0.05], [10.17, 0.10, 0.04], [10.12, 0.09, 0.18]]  # one column
    post = [[10.12, 0.09, 1.0]]
    positions = np.array(foot + post, float)
    labels, _ = segment_points(surface, positions, threshold=0.1, foot_lines=0)
    assert labels.tolist() == [O, O, O, O]
    far = np.array([[3.03, 0.08, 0.3]])  # with columns from it, 10.08 would split the foot
    labels, _ = segment_points(surface, np.vstack([positions, far]), threshold=0.1,
                               foot_lines=0)
    assert labels.tolist() == [O, O, O, O, O]


def test_scan_line_spacing_of_lidars_and_a_stereo_camera():
    scene = make_scene("hills", seed=0)
    for beams, fov, expected in ((16, (-15.0, 15.0), 2.0), (64, (-30.0, 10.0), 40 / 63)):
        cloud = sample_lidar(scene, beams=beams, fov_deg=fov, azimuth_steps=1800, seed=0)
        p = cloud.positions
        assert scan_line_spacing(p) == pytest.approx(expected, rel=0.02)
        # tilted 10 degrees: each line's elevation changes across a wedge, which can only
        # lower the estimate (a smaller foot height, as on a denser lidar)
        c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
        tilted = p @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        assert 0.75 * expected < scan_line_spacing(tilted) < 1.02 * expected
        # seen from a point that is not the sensor, no lines: far away, nothing in the wedges
        assert scan_line_spacing(p, (500.0, 0.0, 0.0)) == 0.0
    stereo = sample_stereo(scene, seed=0).positions
    assert scan_line_spacing(stereo[np.isfinite(stereo).all(axis=1)]) < 0.3  # pixel rows
    assert scan_line_spacing(np.zeros((0, 3))) == 0.0
    nan = sample_lidar(scene, beams=16, fov_deg=(-15.0, 15.0), seed=0).positions.copy()
    nan[::3] = np.nan
    assert scan_line_spacing(nan) == pytest.approx(2.0, rel=0.02)


def test_feet_grow_with_range_on_a_sparse_lidar():
    """A 16-line lidar (2 degrees between lines) sees boxes 18-30 m out: its lowest return on a
    box lies in the terrain threshold and the next line hits the box 0.6-1 m higher, above
    the fixed 0.5 m foot height. With the foot height grown to 3 line gaps (at most 1.5 m)
    those low returns become obstacle; no ground point is lost either way."""
    spots = ((18, 0.3), (22, 1.2), (26, 2.0), (30, 2.9), (24, 3.8), (20, 4.6), (28, 5.5))
    boxes = tuple(Obstacle("box", (r * np.cos(a), r * np.sin(a)), (0.6, 3.0), 1.2,
                           float(np.degrees(a))) for r, a in spots)
    scene = make_scene("flat", seed=0, obstacles=False,
                       region=(-40, 40, -40, 40)).with_obstacles(boxes)
    cloud = sample_lidar(scene, beams=16, fov_deg=(-15.0, 15.0), azimuth_steps=1800, seed=0)
    p = cloud.positions
    surface, _ = segment_terrain(p)
    fixed, h = segment_points(surface, p, threshold=None, foot_lines=0)
    grown, _ = segment_points(surface, p, threshold=None)
    low = cloud.is_obstacle & (h < 0.2)
    assert low.sum() > 50
    assert (fixed[low] == T).all()  # height alone and the fixed foot height miss them
    assert (grown[low] == O).mean() > 0.5  # measured 40 of 72
    ground = ~cloud.is_obstacle
    assert (fixed[ground] == T).all() and (grown[ground] == T).all()
    # segment_terrain passes the option on
    _, inliers = segment_terrain(p, foot_lines=0)
    assert np.isin(np.flatnonzero(low), inliers).all()
    _, inliers = segment_terrain(p)
    assert np.isin(np.flatnonzero(low), inliers).mean() < 0.5
    with pytest.raises(InputError, match="foot_lines"):
        segment_terrain(p, foot_lines=-1)


def test_ground_behind_the_low_part_of_an_object_goes_with_it():
    """Seen from a sensor at the origin, terrain-level returns just behind the low part of a
    bush (within 0.2 m and 0.13 m farther) are its base; those in front of it stay terrain,
    and so do those behind low points with no object beside them."""
    surface = flat_surface()
    low = [[12.02, 0.05, 0.3], [12.05, 0.07, 0.4]]  # the bush's low part: marks
    top = [[12.04, 0.06, 0.9]]  # the bush above them: an object stands there
    behind = [[12.2, 0.06, 0.02], [12.22, 0.1, 0.03]]  # farther, in the next column
    front = [[11.9, 0.06, 0.02], [11.88, 0.02, 0.01]]  # nearer the sensor
    step = [[20.02, 0.05, 0.3], [20.2, 0.06, 0.02]]  # a low step, nothing above it
    positions = np.array(low + top + behind + front + step, float)
    labels, h = segment_points(surface, positions, threshold=0.1, foot_height=0)
    assert labels.tolist() == [O, O, O, T, T, T, T, O, T]
    got = labels.copy()
    assert mark_object_feet(got, h, positions, behind_radius=0.2) == 2
    assert got.tolist() == [O, O, O, O, O, T, T, O, T]
    got = labels.copy()  # off by default, and a margin larger than the step keeps them
    assert mark_object_feet(got, h, positions) == 0
    assert mark_object_feet(got, h, positions, behind_radius=0.2, behind_margin=0.2) == 0
    with pytest.raises(InputError, match="behind_radius"):
        mark_object_feet(labels.copy(), h, positions, behind_radius=-0.1)
    for bad in ("2", 95.0, float("nan")):
        with pytest.raises(InputError, match="line_spacing"):
            mark_object_feet(labels.copy(), h, positions, line_spacing=bad)


def test_behind_the_marks_only_on_a_lidar_scan():
    """A stereo pair's depth noise grows with range (its range coefficient is not 0), so a
    ground point in front of an object can appear behind it: segment_points leaves the rule
    off there."""
    scene = make_scene("hills", seed=0).with_obstacles(default_obstacles(0))
    stereo = sample_stereo(scene, seed=0).positions
    stereo = stereo[np.isfinite(stereo).all(axis=1)]
    surface, _ = segment_terrain(stereo)
    h = surface.heights_above(stereo)
    assert auto_range_coefficient(stereo, h, auto_threshold(h)) > 0  # the premise
    for threshold in (None, 0.2):  # a fixed threshold: the data are asked all the same
        off, _ = segment_points(surface, stereo, threshold=threshold, foot_behind=0)
        on, _ = segment_points(surface, stereo, threshold=threshold)
        np.testing.assert_array_equal(on, off)
    # the rule itself would take ground there (the objects' low parts are marks)
    labels, h = segment_points(surface, stereo, threshold=0.2, foot_height=0)
    assert mark_object_feet(labels.copy(), h, stereo, behind_radius=0.2) > \
        mark_object_feet(labels.copy(), h, stereo)
    with pytest.raises(InputError, match="foot_behind"):
        segment_points(surface, stereo, foot_behind=-1)


def test_free_space_under_an_overhang_is_no_foot():
    """Ground seen under a car's body: the column's lowest mark (the body's underside, 0.35 m
    up) lies more than 0.15 m above its ground points, so the ground stays terrain; the base
    of a bush, whose returns continue up from the ground, still goes with the bush."""
    surface = flat_surface()
    under = [[6.02, 0.02, 0.01], [6.05, 0.06, 0.02], [6.10, 0.04, 0.35], [6.08, 0.08, 0.45]]
    body = [[6.06, 0.05, 0.9]]
    bush = [[9.02, 0.02, 0.01], [9.05, 0.06, 0.02], [9.08, 0.04, 0.12], [9.10, 0.08, 0.24],
            [9.06, 0.05, 0.9]]
    positions = np.array(under + body + bush, float)
    labels, _ = segment_points(surface, positions, threshold=0.1, foot_lines=0)
    assert labels.tolist() == [T, T, O, O, O, O, O, O, O, O]
    labels, h = segment_points(surface, positions, threshold=0.1, foot_height=0)
    got = labels.copy()
    assert mark_object_feet(got, h, positions, foot_gap=0) == 4  # without the rule: both
    assert got.tolist() == [O] * 10
