"""Segmentation and the Open3D drop-in functions."""

from __future__ import annotations

import math

import naive
import numpy as np
import open3d as o3d
import pytest

from o3d_terrain._kernels import bspline as _bs
from o3d_terrain.api import fit_terrain, segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.frame import HEIGHTS_ABOVE_TERRAIN, LABELS, SLOPES_DEG
from o3d_terrain.segment import (
    NORMAL_FACTOR_MAX,
    TerrainLabel,
    auto_threshold,
    relabel_along_normal,
    segment_points,
)
from o3d_terrain.spline import make_lsq_surface
from o3d_terrain.stages import GridQuantize, RationalBSplineTerrain, Segmenter, SlopeEstimator


def scene(seed=0, n=30_000):
    """Sloped ground (z = 0.1 x) with a box obstacle and a few points below the ground."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 30, n)
    y = rng.uniform(-10, 10, n)
    z = 0.1 * x + rng.normal(0, 0.01, n)
    box = (np.abs(x - 15) < 1.0) & (np.abs(y) < 1.0)
    z[box] += rng.uniform(0.5, 1.5, box.sum())
    below = rng.choice(np.flatnonzero(~box), 50, replace=False)
    z[below] -= 1.0
    truth = np.full(n, TerrainLabel.TERRAIN)
    truth[box] = TerrainLabel.OBSTACLE
    truth[below] = TerrainLabel.BELOW_TERRAIN
    return np.c_[x, y, z], truth


def plane_surface(grade=0.1):
    x = np.linspace(0, 30, 31)
    y = np.linspace(-10, 10, 21)
    return make_lsq_surface(x, y, grade * x[:, None] + 0 * y[None, :], control_points=(5, 5))


def test_labels_follow_the_height_rule():
    s = plane_surface()
    pts = np.array([[5, 0, 0.5 + 0.1], [5, 0, 0.5 + 0.4], [5, 0, 0.5 - 0.6], [5, 0, 0.5 - 0.4],
                    [40, 0, 0], [np.nan, 0, 0]])
    # the points stand in one column: the height rule alone (object feet off) ...
    labels, h = segment_points(s, pts, threshold=0.2, below_threshold=0.5, foot_height=0)
    assert labels.tolist() == [1, 2, 3, 1, 0, 0]
    # ... and with the feet of objects, the obstacle point 0.4 m up takes the column's terrain
    # (without the free-space rule: it lies 0.3 m above the column's highest terrain point,
    # which by default reads as space under an overhang)
    labels, _ = segment_points(s, pts, threshold=0.2, below_threshold=0.5, foot_gap=0)
    assert labels.tolist() == [2, 2, 3, 2, 0, 0]
    labels, _ = segment_points(s, pts, threshold=0.2, below_threshold=0.5)
    assert labels.tolist() == [1, 2, 3, 1, 0, 0]
    np.testing.assert_allclose(h[:4], [0.1, 0.4, -0.6, -0.4], atol=1e-9)


def test_threshold_grows_with_range_squared():
    s = plane_surface()
    pts = np.array([[2.0, 0, 0.2 + 0.25], [20.0, 0, 2.0 + 0.25]])
    labels, _ = segment_points(s, pts, threshold=0.2)
    assert labels.tolist() == [2, 2]
    labels, _ = segment_points(s, pts, threshold=0.2, range_coefficient=0.001)
    assert labels.tolist() == [2, 1]  # 0.2 + 0.001 * 400 = 0.6 m at 20 m


def test_segment_terrain_is_a_segment_plane_drop_in():
    pts, truth = scene()
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    surface, inliers = segment_terrain(legacy, distance_threshold=0.2)
    assert inliers.dtype == np.int64
    ground = legacy.select_by_index(inliers.tolist())
    assert len(ground.points) == len(inliers)
    mask = np.zeros(len(pts), bool)
    mask[inliers] = True
    is_ground = truth == TerrainLabel.TERRAIN
    assert (mask & is_ground).sum() / is_ground.sum() > 0.99
    assert not mask[truth != TerrainLabel.TERRAIN].any()
    np.testing.assert_allclose(surface.slope_deg(10.0, 0.0), np.degrees(np.arctan(0.1)), atol=0.5)


def test_unknown_keywords_name_the_close_ones_before_any_work():
    pts = np.zeros((0, 3))  # never read: the keywords are checked first
    with pytest.raises(TypeError, match=r"'cel_size'; did you mean 'cell_size'\?"):
        segment_terrain(pts, cel_size=0.5)
    # what segment_plane users bring: its threshold's name here, its RANSAC options' absence
    with pytest.raises(TypeError, match=r"'threshold': .*distance_threshold"):
        segment_terrain(pts, threshold=0.2)
    with pytest.raises(TypeError, match=r"'ransac_n': .*not a RANSAC plane"):
        segment_terrain(pts, ransac_n=3, num_iterations=100)
    with pytest.raises(TypeError, match=r"'smooth'; did you mean 'smoothing'\?"):
        fit_terrain(pts, smooth=0.1)
    with pytest.raises(TypeError, match=r"'foot_line'; did you mean 'foot_lines' or "
                                        r"'foot_height'\?"):
        segment_terrain(pts, foot_line=2.0)  # up to three close ones, the closest first
    # a keyword close to none: the whole list, once
    with pytest.raises(TypeError) as info:
        fit_terrain(pts, xyzzy=1, plugh=2)
    assert "'plugh'" in str(info.value) and "'xyzzy'" in str(info.value)
    assert str(info.value).count("fit_terrain() takes cell_plane, cell_size") == 1
    # a label option given to the fit says whose it is, not a far-off fit option
    with pytest.raises(TypeError, match=r"'foot_height': foot_height is an option of "
                                        r"segment_terrain's labels"):
        fit_terrain(pts, foot_height=0.3)


def test_the_label_options_fit_terrain_names_are_segment_terrains_own():
    import inspect

    from o3d_terrain.api import _LABEL_OPTIONS

    def names(function):
        return set(inspect.signature(function).parameters)

    assert set(_LABEL_OPTIONS) == names(segment_terrain) - names(fit_terrain)


@pytest.mark.parametrize("grade", [0.0, 0.5, 1.0, 3.0])
def test_thresholds_are_distances_along_the_surface_normal(grade):
    s = plane_surface(grade)
    factor = min(math.sqrt(1.0 + grade * grade), NORMAL_FACTOR_MAX)
    t, below = 0.2, 0.5
    # points in separate columns (feet of objects off anyway) just inside / outside the
    # vertical bounds t * factor and -below * factor
    offsets = [0.97 * t * factor, 1.03 * t * factor, -0.97 * below * factor,
               -1.03 * below * factor]
    xs = [5.0, 10.0, 15.0, 20.0]
    pts = np.array([[x, 0.0, grade * x + dz] for x, dz in zip(xs, offsets)])
    labels, h = segment_points(s, pts, threshold=t, below_threshold=below, foot_height=0)
    np.testing.assert_allclose(h, offsets, atol=1e-9)
    assert labels.tolist() == [TerrainLabel.TERRAIN, TerrainLabel.OBSTACLE,
                               TerrainLabel.TERRAIN, TerrainLabel.BELOW_TERRAIN]
    # vertical thresholds: beyond t and -below the points are not terrain whatever the slope
    vertical, _ = segment_points(s, pts, threshold=t, below_threshold=below, foot_height=0,
                                 along_normal=False)
    expected = [TerrainLabel.TERRAIN if abs(dz) <= (t if dz > 0 else below) else
                (TerrainLabel.OBSTACLE if dz > 0 else TerrainLabel.BELOW_TERRAIN)
                for dz in offsets]
    assert vertical.tolist() == expected


def test_along_normal_scales_the_range_dependent_threshold():
    s = plane_surface(1.0)  # factor sqrt(2)
    t, k = 0.2, 0.001
    x = 20.0  # t(r) = 0.2 + 0.001 * 400 = 0.6 m
    pts = np.array([[x, 0.0, x + 0.6 * 1.38], [x + 1.0, 0.0, x + 1.0 + 0.7 * 1.45]])
    labels, _ = segment_points(s, pts, threshold=t, range_coefficient=k, foot_height=0)
    assert labels.tolist() == [TerrainLabel.TERRAIN, TerrainLabel.OBSTACLE]


@pytest.mark.parametrize("degree", [2, 3])
def test_along_normal_kernel_matches_the_plain_reference(degree):
    # a curved rational surface (slopes from flat to past the cap) and points at random
    # heights around both bounds, some outside the surface's region or not finite
    rng = np.random.default_rng(degree)
    x = np.linspace(0, 30, 31)
    y = np.linspace(-10, 10, 21)
    z = 0.08 * (x[:, None] - 12.0) ** 2 + np.sin(y[None, :] / 2.0)
    s = make_lsq_surface(x, y, z, control_points=(9, 7), degree=degree,
                         rational_weights=rng.uniform(0.5, 1.5, (9, 7)))
    n = 20_000
    xy = np.c_[rng.uniform(-2, 32, n), rng.uniform(-12, 12, n)]
    xy[::101, 1] = np.nan
    heights = rng.uniform(-1.5, 1.5, n)
    positions = np.c_[xy, s(xy[:, 0], xy[:, 1]) + heights]
    labels = rng.choice(np.array([0, 1, 2, 3], np.uint8), n)
    for threshold, below, k, origin in ((0.2, 0.5, 0.0, (0.0, 0.0, 0.0)),
                                        (0.1, 0.3, 0.002, (4.0, -3.0, 0.0)),
                                        (0.4, 0.2, 0.0, (0.0, 0.0, 0.0))):
        expected = naive.relabel_along_normal(labels, heights, positions, s, threshold, below,
                                              k, origin, NORMAL_FACTOR_MAX)
        got = labels.copy()
        relabel_along_normal(got, heights, positions, s, threshold=threshold,
                             below_threshold=below, range_coefficient=k, sensor_origin=origin)
        np.testing.assert_array_equal(got, expected)
        assert (got != labels).sum() > 500  # the case relabels points


def test_cubic_span_gradient_equals_the_b_spline_derivatives():
    rng = np.random.default_rng(7)
    x = np.linspace(0, 30, 31)
    y = np.linspace(-10, 10, 21)
    z = np.cos(x[:, None] / 3.0) * np.sin(y[None, :] / 2.0) + 0.3 * x[:, None]
    s = make_lsq_surface(x, y, z, control_points=(12, 8),
                         rational_weights=rng.uniform(0.5, 1.5, (12, 8)))
    n0, n1 = s.control_points.shape
    coef = _bs.cubic_span_coefficients(s.knots_x, s.knots_y, s.control_points, s.weights)
    lx = _bs.span_lookup(s.knots_x, n0, 3)
    ly = _bs.span_lookup(s.knots_y, n1, 3)
    px = rng.uniform(s.knots_x[0], s.knots_x[-1], 500)
    py = rng.uniform(s.knots_y[0], s.knots_y[-1], 500)
    gx, gy = s.gradient(px + s.origin[0], py + s.origin[1])
    bx = np.empty(4)
    by = np.empty(4)
    dbx = np.empty(4)
    dby = np.empty(4)
    left = np.empty(4)
    right = np.empty(4)
    for k in range(500):
        b, u, v, wx, wy = _bs._cubic_span_at(px[k], py[k], s.knots_x, s.knots_y, n0, n1, lx, ly)
        su, sv = _bs._cubic_span_gradient(coef, b, u, v)
        # the B-spline sums' derivatives (A2.2 and the derivative formula)
        _, ex, ey = _bs._point_first_derivatives(
            px[k], py[k], s.knots_x, s.knots_y, 3, s.control_points, s.weights, lx[0], lx[1],
            ly[0], ly[1], bx, by, dbx, dby, left, right)
        assert su * wx == pytest.approx(ex, rel=1e-10, abs=1e-12)
        assert sv * wy == pytest.approx(ey, rel=1e-10, abs=1e-12)
        assert gx[k] == pytest.approx(ex, rel=1e-10, abs=1e-12)
        assert gy[k] == pytest.approx(ey, rel=1e-10, abs=1e-12)


def test_tensor_cloud_numpy_and_auto_threshold_agree():
    pts, _ = scene(1)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts))
    _, a = segment_terrain(tensor)
    _, b = segment_terrain(pts)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("layout", ["vehicle", "top_down"])
def test_automatic_threshold_keeps_a_noisy_ground(layout):
    # level ground with 5 cm noise (rough soil, a cheap sensor, photogrammetry), a vehicle's
    # scan around the sensor 1.8 m up or a top-down tile: the surface sits about half a noise
    # scale under the ground's centre, and measured from the surface alone the threshold
    # stood 2.2 noise scales above the ground (1.5-2.1 % of it called obstacle)
    rng = np.random.default_rng(0)
    n = 60_000
    if layout == "vehicle":
        r, a = np.sqrt(rng.uniform(4, 900, n)), rng.uniform(0, 2 * np.pi, n)
        xy, z = np.c_[r * np.cos(a), r * np.sin(a)], -1.8 + rng.normal(0, 0.05, n)
    else:
        xy, z = rng.uniform(-30, 30, (n, 2)), rng.normal(0, 0.05, n)
    surface, inliers = segment_terrain(np.c_[xy, z])
    assert 1 - len(inliers) / n < 0.01  # 2.5 scales above the centre: 0.6 % for Gaussian noise
    heights = surface.heights_above(np.c_[xy, z])
    below = 1.4826 * np.median(-heights[heights <= 0])  # the spread from the surface alone
    assert auto_threshold(heights) > 3.5 * below + 0.005


def test_the_refits_labels_keep_the_threshold_from_below_the_surface(monkeypatch):
    # the centred threshold keeps more of a noisy ground in the final labels; the refit's
    # labels, which pick the points its surface is fitted to, go without it
    import o3d_terrain.refine as refine

    rng = np.random.default_rng(1)
    xy = rng.uniform(-30, 30, (40_000, 2))
    pts = np.c_[xy, rng.normal(0, 0.05, 40_000)]
    surface = fit_terrain(pts, refine=False)
    centred, _ = segment_points(surface, pts, threshold=None)
    below, _ = segment_points(surface, pts, threshold=None, centred_threshold=False)
    assert (centred == TerrainLabel.TERRAIN).sum() > (below == TerrainLabel.TERRAIN).sum()
    seen = []

    def spy(*args, **kwargs):
        seen.append(kwargs.get("centred_threshold", True))
        return segment_points(*args, **kwargs)

    monkeypatch.setattr(refine, "segment_points", spy)
    segment_terrain(pts)
    assert seen and not any(seen)


def test_ground_centre_and_spread_are_numpys_medians():
    rng = np.random.default_rng(4)
    heights = np.r_[rng.normal(0.03, 0.05, 5_000), rng.uniform(0.3, 2.0, 500), [np.nan, -3.0]]
    for step, top in ((1, 0.15), (3, 0.15), (1, 10.0)):
        h = heights[::step]
        kept = h[(h > -0.5) & (h <= top)]
        centre = np.median(kept)
        got = _bs.ground_centre_spread(heights, step, -0.5, top)
        assert got[0] == centre and got[2] == kept.size
        assert got[1] == np.median(centre - kept[kept <= centre])
    assert _bs.ground_centre_spread(heights, 1, 5.0, 6.0)[2] == 0


def test_float32_rows_become_the_float64_positions_numpy_casts():
    from o3d_terrain._kernels.positions import xyz_float64

    rows = np.random.default_rng(4).normal(0, 50, (1001, 4)).astype(np.float32)
    rows[3] = (np.nan, np.inf, -np.inf, 1.0)
    rows[4, :3] = (-0.0, np.float32(1e-45), np.finfo(np.float32).max)
    for values in (rows, np.ascontiguousarray(rows[:, :3]), rows[:0]):
        got = xyz_float64(values)
        assert got.dtype == np.float64 and got.flags.c_contiguous and got.shape == (len(values), 3)
        expected = values[:, :3].astype(np.float64)
        assert np.array_equal(got, expected, equal_nan=True)
        assert np.array_equal(np.signbit(got), np.signbit(expected))


def test_array_inputs_equal_the_frame_path_and_options_are_checked_every_call():
    # numpy arrays skip the frame; (N, 4) float32 and a tensor cloud give the same fit
    pts, _ = scene(5, n=6_000)
    with4 = np.c_[pts, np.ones(len(pts))].astype(np.float32)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(with4[:, :3].astype(np.float64)))
    for kwargs in ({}, {"distance_threshold": 0.2, "range_coefficient": 1e-3}):
        s_array, i_array = segment_terrain(with4, **kwargs)
        s_frame, i_frame = segment_terrain(tensor, **kwargs)
        np.testing.assert_array_equal(i_array, i_frame)
        np.testing.assert_array_equal(s_array.control_points, s_frame.control_points)
        assert s_array.cell_size == s_frame.cell_size == 0.5
    np.testing.assert_array_equal(fit_terrain(with4).weights, fit_terrain(tensor).weights)
    # stages are reused for equal options, never for 1 / 1.0 / True
    segment_terrain(pts, degree=1)
    with pytest.raises(InputError, match="degree"):
        segment_terrain(pts, degree=True)
    with pytest.raises(InputError, match="RationalBSplineTerrain"):
        fit_terrain(pts, control_points=(2, 2), degree=1, region=(100, 101, 100, 101))


def test_non_finite_points_are_ignored_and_indices_stay_aligned():
    pts, truth = scene(2)
    bad = pts.copy()
    bad[::100] = np.nan
    bad[1::100, 2] = np.inf
    _, inliers = segment_terrain(bad, distance_threshold=0.2)
    assert np.isfinite(bad[inliers]).all()
    _, clean = segment_terrain(pts, distance_threshold=0.2)
    assert np.setdiff1d(inliers, clean).size < 0.01 * len(inliers)


def test_bad_clouds_give_clear_errors():
    with pytest.raises(InputError, match="empty"):
        segment_terrain(np.zeros((0, 3)))
    with pytest.raises(InputError, match="no finite point"):
        fit_terrain(np.full((10, 3), np.nan))
    with pytest.raises(InputError, match="degenerate"):
        fit_terrain(np.random.default_rng(0).normal(size=(100, 3)), region=(0, 0, -1, 1))
    with pytest.raises(InputError, match="degenerate"):
        fit_terrain(np.c_[np.arange(100.0), np.zeros(100), np.zeros(100)])
    # a line at any angle, not only along an axis; a thin strip along it is a cloud
    t = np.arange(100.0)
    with pytest.raises(InputError, match="degenerate"):
        segment_terrain(np.c_[t, 0.5 * t + 3.0, 0.1 * t])
    strip = np.c_[t, 0.5 * t + np.random.default_rng(1).normal(0, 0.05, 100), 0.1 * t]
    assert len(segment_terrain(strip)[1]) > 90
    with pytest.raises(InputError, match="too few valid cells"):
        fit_terrain(np.array([[0, 0, 0], [10, 10, 0.0]]))
    # an organised scan (rows, columns, xyz): the error says how to pass it
    with pytest.raises(InputError, match=r"organised scan of 16 × 100 points goes in as "
                                         r"cloud\.reshape\(-1, 3\)"):
        segment_terrain(np.zeros((16, 100, 3)))
    # a path is not a cloud: the error says how to read it
    with pytest.raises(InputError, match=r"o3d_terrain\.read_cloud\(path\)"):
        segment_terrain("scan.ply")
    # one stray return 10,000 km away: too many cells, and the error names the stray point and
    # the region of the others
    pts, _ = scene(5, n=3_000)
    stray = np.r_[pts, [[1e7, 1e7, 0.0]]]
    with pytest.raises(InputError, match=r"1 of the 3,001 points lies far outside the others"
                                         r", which fit in region=\(-"):
        segment_terrain(stray)
    # ... which the region it names labels (the stray point left out)
    _, inliers = segment_terrain(stray, region=(-35.0, 35.0, -35.0, 35.0))
    assert inliers.size > 0.9 * len(pts) and inliers.max() < len(pts)


def test_float32_coordinates_rounded_coarsely_are_warned_of():
    import warnings

    import o3d_terrain

    pts, _ = scene(7, n=4_000)
    utm = (pts + [512_345.0, 4_512_345.0, 250.0]).astype(np.float32)
    with pytest.warns(o3d_terrain.TerrainWarning, match=r"float32 and reach 4,512,3\d\d m, "
                                                        r"where successive float32 values "
                                                        r"are 0\.5 m apart"):
        segment_terrain(utm)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(utm))
    with pytest.warns(o3d_terrain.TerrainWarning, match="0.5 m apart"):
        segment_terrain(tensor)
    # non-finite points neither hide the magnitude nor stand for it
    from o3d_terrain.frame import warn_coarse_float32
    spoilt = utm.copy()
    spoilt[0] = np.nan
    spoilt[1, 2] = np.inf
    with pytest.warns(o3d_terrain.TerrainWarning, match="0.5 m apart"):
        warn_coarse_float32(spoilt)
    local = pts.astype(np.float32)
    local[0] = -np.inf
    local[1] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_coarse_float32(local)
        warn_coarse_float32(np.full((5, 3), np.nan, dtype=np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # float32 in a sensor's frame, float64 in UTM: silent
        segment_terrain(pts.astype(np.float32))
        segment_terrain(pts + [512_345.0, 4_512_345.0, 250.0])


def test_one_control_point_count_serves_both_axes():
    pts, _ = scene(6, n=6_000)
    surface, inliers = segment_terrain(pts, control_points=12, refine=False)
    assert surface.control_points.shape == (12, 12)
    assert repr(surface).startswith("TerrainSurface(degree=3, control_points=(12, 12), "
                                    "region=(0.")  # plain numbers, not np.float64(...)
    assert all(type(v) is float for v in surface.region)
    same, same_inliers = segment_terrain(pts, control_points=[12, 12], refine=False)
    np.testing.assert_array_equal(inliers, same_inliers)
    assert fit_terrain(pts, control_points=9, refine=False).control_points.shape == (9, 9)


def test_more_control_points_than_the_grid_can_carry_is_an_error_that_gives_the_limit():
    import re

    pts, _ = scene(6, n=6_000)  # 30 x 20 m: 15 x 10 cells of 2 m
    with pytest.raises(InputError, match=r"control_points \(500, 500\) are more than the grid "
                                         r"can carry: its 15 x 10 cells of 2 m allow at most "
                                         r"\(18, 13\)") as caught:
        fit_terrain(pts, cell_size=2.0, control_points=500)
    assert "RationalBSplineTerrain" in str(caught.value)
    most = tuple(int(v) for v in re.search(r"at most \((\d+), (\d+)\)",
                                           str(caught.value)).groups())
    with pytest.raises(InputError, match="more than the grid can carry"):
        fit_terrain(pts, cell_size=2.0, control_points=(most[0], most[1] + 1))
    assert fit_terrain(pts, cell_size=2.0, control_points=most).control_points.shape == most


def test_stages_write_declared_products_and_attributes():
    pts, truth = scene(3, n=10_000)
    frame = GridQuantize(cell_size=0.5)(pts)
    frame = RationalBSplineTerrain()(frame)
    frame = SlopeEstimator()(frame)
    frame = Segmenter(threshold=0.2)(frame)
    assert {"surface", "slope_grid"} <= set(frame.products)
    assert {LABELS, HEIGHTS_ABOVE_TERRAIN, SLOPES_DEG} <= set(frame.attribute_names())
    assert frame.cloud.point[LABELS].shape == (10_000, 1)
    labels = frame.attribute(LABELS)
    assert (labels[truth == TerrainLabel.OBSTACLE] == TerrainLabel.OBSTACLE).mean() > 0.95
    slope_grid, xc, yc = frame.product("slope_grid")
    assert slope_grid.shape == (xc.size, yc.size)
    surface = frame.product("surface")
    assert surface.cell_size == 0.5
    np.testing.assert_allclose(slope_grid, surface.slope_deg(xc[:, None], yc[None, :]),
                               atol=1e-12)
    assert np.nanmedian(frame.attribute(SLOPES_DEG)) == pytest.approx(np.degrees(np.arctan(0.1)),
                                                                      abs=0.5)


def test_segment_terrain_equals_the_stage_chain():
    # with every option at its default on both sides: a pipeline labels as the function does
    pts, _ = scene(4, n=8_000)
    surface, inliers = segment_terrain(pts, cell_size=0.5)
    frame = Segmenter()(RationalBSplineTerrain()(GridQuantize(cell_size=0.5)(pts)))
    np.testing.assert_array_equal(
        inliers, np.flatnonzero(frame.attribute(LABELS) == TerrainLabel.TERRAIN))
    np.testing.assert_array_equal(surface.control_points,
                                  frame.product("surface").control_points)
    with pytest.raises(InputError, match="degree"):
        segment_terrain(pts, degree=9)


def test_slope_grid_and_surface_draw_and_save(tmp_path):
    from o3d_terrain.spline import SlopeGrid
    from o3d_terrain.writers import WriteImage, WriteProduct

    pts, _ = scene(5, n=8_000)
    frame = SlopeEstimator(cell_size=1.0)(RationalBSplineTerrain()(GridQuantize()(pts)))
    grid = frame.product("slope_grid")
    assert isinstance(grid, SlopeGrid) and grid.cell_size == 1.0
    values, valid, unit = grid.image_layers()["slope_deg"]
    assert unit == "deg" and values.shape == valid.shape == grid.shape and valid.all()
    WriteProduct(product="slope_grid", path="slope.npz").write(frame, tmp_path)
    loaded = SlopeGrid.load(tmp_path / "slope.npz")
    np.testing.assert_array_equal(loaded.slope_deg, grid.slope_deg)
    np.testing.assert_array_equal(loaded.x_centers, grid.x_centers)
    surface = frame.product("surface")
    layers = surface.image_layers()
    z, z_valid, z_unit = layers["z"]
    assert z_unit == "m" and z.shape == (60, 40) and z_valid.all()  # 30 x 20 m at 0.5 m
    np.testing.assert_allclose(z[10, 10], surface(surface.region[0] + 5.25,
                                                  surface.region[2] + 5.25), atol=1e-12)
    for product in ("slope_grid", "surface"):
        written = WriteImage(product=product, path=f"{product}.png").write(frame, tmp_path)
        assert written[0].stat().st_size > 0


def test_automatic_range_term_only_where_the_noise_grows_with_range():
    """auto_range_coefficient: noise growing with range squared (a stereo camera) gives a
    threshold that grows with r^2, capped at AUTO_RANGE_HIGH within the cloud; constant noise
    (a lidar), noise that levels off (sparse rings), or a sensor outside the cloud give 0."""
    from o3d_terrain.segment import AUTO_RANGE_HIGH, auto_range_coefficient

    rng = np.random.default_rng(0)
    n = 40_000
    r = rng.uniform(3.0, 30.0, n)
    a = rng.uniform(-0.6, 0.6, n)
    p = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)]
    stereo = rng.normal(0, 0.01 + 2e-4 * r**2)
    coefficient = auto_range_coefficient(p, stereo, 0.13)
    assert coefficient == pytest.approx(3.5 * 2e-4, rel=0.25)  # 3.5 x the noise's growth
    lidar = rng.normal(0, 0.02, n)
    assert auto_range_coefficient(p, lidar, 0.13) == 0.0
    levels_off = rng.normal(0, np.minimum(0.01 + 0.01 * r, 0.06))  # grows, then flat
    assert auto_range_coefficient(p, levels_off, 0.13) == 0.0
    far = p + [5e5, 4e6, 0.0]  # an airborne tile's coordinates: no sensor inside
    assert auto_range_coefficient(far, stereo, 0.13) == 0.0
    # segment_points uses it only with the automatic threshold and range_coefficient None
    surface = plane_surface(0.0)
    q = p[(np.abs(p[:, 1]) < 9.5) & (p[:, 0] < 29.5)]
    noisy = q + np.c_[np.zeros((len(q), 2)), rng.normal(0, 0.01 + 2e-4 * np.hypot(q[:, 0], q[:, 1])**2)]
    auto, _ = segment_points(surface, noisy, threshold=None, misfit=False, foot_height=0)
    fixed, _ = segment_points(surface, noisy, threshold=None, range_coefficient=0.0,
                              misfit=False, foot_height=0)
    terrain = TerrainLabel.TERRAIN
    assert (auto == terrain).sum() > (fixed == terrain).sum()
    # the automatic growth stops at AUTO_RANGE_HIGH: a 0.6 m object 29 m out stays an obstacle
    post = np.array([[29.0, 0.0, 0.6]])
    labels, _ = segment_points(surface, np.vstack([noisy, post]), threshold=None, misfit=False,
                               foot_height=0)
    assert 0.13 + coefficient * 29.0**2 > 0.6 > AUTO_RANGE_HIGH
    assert labels[-1] == TerrainLabel.OBSTACLE


def test_the_range_term_of_a_stereo_cloud_and_of_a_rotating_lidar():
    """Noise that grows by 4 x from 3 m to 30 m along r^2 (a stereo cloud of a forest, whose
    near ground is rougher than the open ground ahead) gives a range term; a spread growing
    with r^2 on a rotating lidar's rings (lines 0.4 degrees apart, 1.8 m up) gives none: a
    lidar's spread below the surface grows where its rings thin out, not with its noise."""
    from o3d_terrain.segment import AUTO_RANGE_LINES, auto_range_coefficient, scan_line_spacing

    rng = np.random.default_rng(3)
    n = 40_000
    r = rng.uniform(3.0, 30.0, n)
    a = rng.uniform(-0.6, 0.6, n)
    stereo = np.c_[r * np.cos(a), r * np.sin(a), np.full(n, -1.8)]
    noise = rng.normal(0, 0.015 + 5e-5 * r**2)
    assert scan_line_spacing(stereo) < AUTO_RANGE_LINES
    assert auto_range_coefficient(stereo, noise, 0.13) > 0.0
    elevation = np.radians(rng.integers(0, 67, n) * 0.4 - 30.0)  # the rings on flat ground
    ring_r = 1.8 / np.tan(-elevation)
    keep = (ring_r > 3.0) & (ring_r < 30.0)
    lidar = np.c_[ring_r * np.cos(a), ring_r * np.sin(a), np.full(n, -1.8)][keep]
    ring_noise = rng.normal(0, 0.01 + 1e-4 * ring_r[keep]**2)  # 4.4 x from 3.4 m to 20 m
    assert scan_line_spacing(lidar) >= AUTO_RANGE_LINES
    assert auto_range_coefficient(lidar, ring_noise, 0.13) == 0.0
    assert auto_range_coefficient(lidar, ring_noise, 0.13, line_spacing=0.0) > 0.0


def test_automatic_range_term_ignores_a_jump_and_a_wide_near_bin(monkeypatch):
    """The spread below the surface that jumps at one range (a face the surface misses, here a
    lidar's constant noise plus 0.3 m depth beyond 20 m) is no noise growing with range; a
    stereo spread whose nearest bin is wide (matching errors at the image bottom) and whose
    farthest is a little narrower than one before it still is."""
    import o3d_terrain.segment as segment
    from o3d_terrain.segment import auto_range_coefficient

    rng = np.random.default_rng(1)
    n = 40_000
    r = rng.uniform(3.0, 30.0, n)
    a = rng.uniform(-0.6, 0.6, n)
    p = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)]
    jump = rng.normal(0, np.where(r > 20.0, 0.3, 0.004))
    assert auto_range_coefficient(p, jump, 0.13) == 0.0
    with monkeypatch.context() as m:  # the step test is what rejects it
        m.setattr(segment, "AUTO_RANGE_STEP", np.inf)
        assert auto_range_coefficient(p, jump, 0.13) > 0.0
    sigma = 0.01 + 2e-4 * r**2
    sigma = np.where(r < 4.5, 0.05, sigma)  # the nearest bin wide
    sigma = np.where(r > 27.0, 0.9 * (0.01 + 2e-4 * 27.0**2), sigma)  # the farthest a bit less
    stereo = rng.normal(0, sigma)
    assert auto_range_coefficient(p, stereo, 0.13) > 0.0


def test_automatic_range_term_ignores_the_farthest_bin_alone(monkeypatch):
    """A lidar whose ground ends at a crest 9 m out, with an object's face 23 m out that the
    surface misses (the face's low points below it): the farthest bin's spread jumps alone
    across the empty ranges, where r^2 grows as much as the spread, so only the growth of the
    nearer bins tells it from a stereo camera's noise."""
    import o3d_terrain.segment as segment
    from o3d_terrain.segment import auto_range_coefficient

    rng = np.random.default_rng(2)
    near, face = 35_000, 5_000
    r = np.r_[rng.uniform(2.5, 9.0, near), rng.uniform(22.5, 23.5, face)]
    a = rng.uniform(-0.6, 0.6, near + face)
    p = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(near + face)]
    depth = rng.normal(0, np.where(r > 20.0, 0.06, 0.004))
    assert auto_range_coefficient(p, depth, 0.13) == 0.0
    with monkeypatch.context() as m:  # the nearer bins' test is what rejects it
        m.setattr(segment, "AUTO_RANGE_NEAR", -np.inf)
        assert auto_range_coefficient(p, depth, 0.13) > 0.0
    # a stereo camera seen over the same ranges still grows in the nearer bins
    stereo = rng.normal(0, 0.005 + 1e-4 * r**2)
    assert auto_range_coefficient(p, stereo, 0.13) > 0.0


def test_ground_above_the_sensor_must_face_it():
    """out_of_sight: a terrain point above the sensor is ground only where the surface rises
    along the line of sight at least as steeply as the line (less SIGHT_MARGIN_DEG). A level
    surface 2.5 m above the sensor (a ceiling to it) hides every point on it; a 30° slope
    rising away from a sensor 1.8 m above its foot shows them; points below the sensor are
    not tested; a sensor whose ground lies less than SIGHT_MIN_HEIGHT below it gets no test;
    segment_points applies it only where the sensor scans the ground around it, and
    line_of_sight=False keeps the labels."""
    from o3d_terrain.segment import SIGHT_MARGIN_DEG, SIGHT_MIN_HEIGHT, out_of_sight

    rng = np.random.default_rng(3)
    x = rng.uniform(5, 25, 400)
    y = rng.uniform(-8, 8, 400)
    xs, ys = np.linspace(-10, 30, 41), np.linspace(-10, 10, 21)
    ring = np.c_[rng.uniform(-6, 6, 3000), rng.uniform(-6, 6, 3000), np.full(3000, -1.8)]
    ring = ring[np.hypot(ring[:, 0], ring[:, 1]) > 2.0]  # the ground 1.8 m under the sensor

    def hidden(surface, points, ground=ring):
        cloud = np.vstack([ground, points])
        labels = np.full(len(cloud), TerrainLabel.TERRAIN, np.uint8)
        flagged = out_of_sight(surface, cloud, labels)
        assert (flagged >= len(ground)).all()  # never the ground under the sensor
        return flagged.size

    def plane(grade, offset, at=0.0):
        return make_lsq_surface(xs, ys, grade * (xs[:, None] - at) + offset + 0 * ys[None, :],
                                control_points=(5, 5))

    high = np.c_[x, y, np.full(400, 2.5)]
    assert hidden(plane(0.0, 2.5), high) == 400
    grade = math.tan(math.radians(30))
    on_slope = np.c_[x, y, grade * x - 1.8]
    assert (on_slope[:, 2] > 0).mean() > 0.8  # most of them above the sensor
    assert hidden(plane(grade, -1.8), on_slope) == 0
    # the margin: a slope just less steep than the line of sight does not hide a point
    e = math.atan2(2.0, 10.0)
    point = np.array([[10.0, 0.0, 2.0]])
    assert hidden(plane(math.tan(e - math.radians(SIGHT_MARGIN_DEG - 1)), 2.0, 10.0), point) == 0
    assert hidden(plane(math.tan(e - math.radians(SIGHT_MARGIN_DEG + 1)), 2.0, 10.0), point) == 1
    # below the sensor: never tested, whatever the surface's slope there
    assert hidden(plane(0.0, 2.5), np.c_[x, y, np.full(400, -1.0)]) == 0
    # the origin on the ground (a vehicle's base frame): its height is unknown, no test
    assert hidden(plane(0.0, 2.5), high, ring + [0, 0, 1.8 - SIGHT_MIN_HEIGHT / 2]) == 0
    assert hidden(plane(0.0, 2.5), high, ring + [0, 0, 1.8 - 2 * SIGHT_MIN_HEIGHT]) == 400
    # in segment_points: the ground around the sensor and the ceiling's points
    ceiling = np.vstack([ring, high])
    both = make_lsq_surface(xs, ys, np.where(xs[:, None] < 4.5, -1.8, 2.5) + 0 * ys[None, :],
                            control_points=(41, 21))
    labels, _ = segment_points(both, ceiling, threshold=0.2, foot_height=0)
    kept, _ = segment_points(both, ceiling, threshold=0.2, foot_height=0, line_of_sight=False)
    on_ceiling = np.arange(len(ring), len(ceiling))
    assert (kept[on_ceiling] == TerrainLabel.TERRAIN).all()
    assert (labels[on_ceiling] == TerrainLabel.OBSTACLE).mean() > 0.95
    np.testing.assert_array_equal(labels[:len(ring)], kept[:len(ring)])  # the ground's own
    # a sensor outside the cloud (a top-down scan): no test
    labels, _ = segment_points(both, ceiling, threshold=0.2, foot_height=0,
                               sensor_origin=(500.0, 500.0, 0.0))
    assert (labels[on_ceiling] == TerrainLabel.TERRAIN).all()


def test_an_object_beyond_a_crest_is_an_obstacle():
    """A 30° ramp to a plateau above a solid-state lidar's height: the sensor sees no ground
    on the plateau, only the upper part of the truck standing there, which the surface runs
    through; the line-of-sight test takes it back (obstacle recall 0.924 -> 0.986 with
    segment_terrain's defaults on this frame)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_accuracy import steep_scenes

    from o3d_terrain.synthetic import sample_solid_state

    cloud = sample_solid_state(steep_scenes()["ramp30"], points=20_000, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    tall = cloud.is_obstacle & (p[:, 2] - cloud.terrain_height(p[:, 0], p[:, 1]) > 0.3)
    recall = {}
    for line_of_sight in (True, False):
        _, inliers = segment_terrain(p, line_of_sight=line_of_sight)
        ground = np.zeros(len(p), bool)
        ground[inliers] = True
        recall[line_of_sight] = np.mean(~ground[tall])
        assert np.mean(ground[~cloud.is_obstacle]) > 0.99  # the ground stays ground
    assert recall[False] < 0.95 < 0.97 < recall[True]
