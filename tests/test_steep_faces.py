"""Steep terrain: the terrain prior's slope limit (``max_slope_deg``) through the drop-in
functions (the bench faces of a pit, steeper than the default 45 degrees, are walls to the
prior until the limit is raised), and the thresholds measured along the surface normal
(``along_normal``; docs/algorithm.md, "Steep faces")."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain.api import fit_terrain, segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.segment import NORMAL_FACTOR_MAX, TerrainLabel, segment_points
from o3d_terrain.spline import make_lsq_surface
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar


@pytest.fixture(scope="module")
def benches():
    """Two 5.4 m benches with 55-degree faces ahead of a lidar on the pit floor, no objects."""
    run = 5.4 / math.tan(math.radians(55.0))
    scene = Scene("benches55", (Plane(), Ramp(12, 0, 0, 55.0, run),
                                Ramp(22 + run, 0, 0, 55.0, run)), ())
    cloud = sample_lidar(scene, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = ~cloud.is_outlier & np.isfinite(p).all(axis=1)
    p = p[keep]
    truth = cloud.terrain_height(p[:, 0], p[:, 1])
    return p, truth


def _rmse(surface, p, truth, mask=None):
    mask = np.ones(len(p), bool) if mask is None else mask
    e = surface(p[mask, 0], p[mask, 1]) - truth[mask]
    return float(np.sqrt(np.mean(e * e)))


def test_raising_the_slope_limit_lets_the_surface_climb_bench_faces(benches):
    p, truth = benches
    face = (p[:, 0] > 12.5) & (truth > -1.4)  # points on the first face and the bench above
    default = fit_terrain(p)
    steep = fit_terrain(p, max_slope_deg=60)
    # with the 45-degree limit the face is a wall: the surface stays metres below its top
    assert _rmse(default, p, truth, face) > 0.3
    # with 60 degrees the face is terrain and the surface follows it
    assert _rmse(steep, p, truth, face) < 0.1
    assert _rmse(steep, p, truth) < 0.06
    _, inliers = segment_terrain(p, max_slope_deg=60)
    assert np.isin(np.flatnonzero(face), inliers).mean() > 0.95
    _, inliers45 = segment_terrain(p)
    assert np.isin(np.flatnonzero(face), inliers45).mean() < 0.5


def test_the_limit_reaches_the_stage_on_every_input_path(benches):
    p, _ = benches
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    s_array, i_array = segment_terrain(p, max_slope_deg=60)
    s_cloud, i_cloud = segment_terrain(pcd, max_slope_deg=60)
    np.testing.assert_array_equal(i_array, i_cloud)
    np.testing.assert_allclose(s_array.control_points, s_cloud.control_points)


@pytest.mark.parametrize("value", [0, 90, 120, float("nan")])
def test_a_slope_limit_out_of_range_is_rejected_with_its_name(benches, value):
    p, _ = benches
    for call in (fit_terrain, segment_terrain):
        with pytest.raises(InputError, match="max_slope_deg"):
            call(p[:1000], max_slope_deg=value)


def _sloped_plane(grade):
    x = np.linspace(0, 30, 31)
    y = np.linspace(-10, 10, 21)
    return make_lsq_surface(x, y, grade * x[:, None] + 0 * y[None, :], control_points=(5, 5))


@pytest.mark.parametrize("grade", [0.0, 0.5, 1.0, 3.0])
def test_thresholds_are_distances_along_the_surface_normal(grade):
    s = _sloped_plane(grade)
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
    s = _sloped_plane(1.0)  # factor sqrt(2)
    t, k = 0.2, 0.001
    x = 20.0  # t(r) = 0.2 + 0.001 * 400 = 0.6 m
    pts = np.array([[x, 0.0, x + 0.6 * 1.38], [x + 1.0, 0.0, x + 1.0 + 0.7 * 1.45]])
    labels, _ = segment_points(s, pts, threshold=t, range_coefficient=k, foot_height=0)
    assert labels.tolist() == [TerrainLabel.TERRAIN, TerrainLabel.OBSTACLE]
