"""Levelling a tilted sensor's cloud with gravity's up (o3d_terrain.level, LevelCloud)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import open3d as o3d
import pytest

import o3d_terrain
from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.level import levelling_transform
from o3d_terrain.stages import LevelCloud
from o3d_terrain.synthetic import Plane, Scene, sample_lidar


def _up(roll_deg=0.0, pitch_deg=0.0):
    """World +z in the frame of a sensor rolled and pitched as o3d_terrain.synthetic tilts it."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    return (ry @ rx)[2]


@pytest.mark.parametrize("up", [(0.1, -0.3, 0.9), (0.0, 0.0, 2.0), (0.0, 0.0, -1.0),
                                (1.0, 0.0, 0.0), tuple(_up(12.0, -25.0))])
def test_the_transform_turns_up_onto_z_about_the_sensor(up):
    origin = np.array([3.0, -2.0, 1.5])
    t = levelling_transform(up, origin)
    r = t[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ (np.asarray(up) / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(t[:3, :3] @ origin + t[:3, 3], origin, atol=1e-12)


def test_the_smallest_rotation_keeps_the_heading():
    # a sensor pitched 20 deg nose down: straight ahead stays in the x-z plane, below the sensor
    levelled, _ = o3d_terrain.level_cloud(np.array([[10.0, 0.0, 0.0]]), _up(pitch_deg=20.0))
    np.testing.assert_allclose(levelled, [[10 * math.cos(math.radians(20)), 0.0,
                                           -10 * math.sin(math.radians(20))]], atol=1e-12)


def test_every_cloud_type_comes_back_as_it_came_and_the_callers_is_untouched():
    rng = np.random.default_rng(0)
    points = rng.uniform(-5, 5, (50, 3))
    up = (0.2, 0.1, 1.0)
    r = levelling_transform(up)[:3, :3]
    extra = np.column_stack([points, np.arange(50.0)])
    out, _ = o3d_terrain.level_cloud(extra, up)
    np.testing.assert_allclose(out[:, :3], points @ r.T, atol=1e-12)
    np.testing.assert_array_equal(out[:, 3], np.arange(50.0))  # intensity kept
    np.testing.assert_array_equal(extra[:, :3], points)
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    legacy.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, 1.0], (50, 1)))
    out, _ = o3d_terrain.level_cloud(legacy, up)
    np.testing.assert_allclose(np.asarray(out.points), points @ r.T, atol=1e-12)
    np.testing.assert_allclose(np.asarray(out.normals)[0], r @ [0, 0, 1], atol=1e-12)
    np.testing.assert_array_equal(np.asarray(legacy.points), points)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(points.astype(np.float32)))
    out, _ = o3d_terrain.level_cloud(tensor, up)
    assert out.point.positions.dtype == o3d.core.float32
    np.testing.assert_allclose(out.point.positions.numpy(), points @ r.T, atol=1e-5)
    np.testing.assert_allclose(tensor.point.positions.numpy(), points, atol=1e-6)


@pytest.mark.parametrize("up, match", [((0, 0, 0), "zero vector"), ((0, np.nan, 1), "finite"),
                                       ((0, 1), "3 finite numbers"), ("up", "3 ")])
def test_a_bad_up_is_a_clear_error(up, match):
    with pytest.raises(InputError, match=match):
        o3d_terrain.level_cloud(np.zeros((3, 3)), up)


def test_a_bad_cloud_is_a_clear_error():
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        o3d_terrain.level_cloud(np.zeros((4, 2)), (0, 0, 1))
    with pytest.raises(InputError, match="numpy array or an Open3D point cloud"):
        o3d_terrain.level_cloud([[0.0, 0.0, 0.0]], (0, 0, 1))


def test_the_stage_levels_the_frame_and_records_the_transform():
    points = np.random.default_rng(1).uniform(-5, 5, (40, 3))
    frame = LevelCloud(up=(0.0, 0.5, 1.0), sensor_origin=(1.0, 1.0, 0.0))(points)
    t = frame.product("levelled_from_cloud")
    np.testing.assert_allclose(frame.positions, points @ t[:3, :3].T + t[:3, 3], atol=1e-12)
    assert "26.6 deg" in frame.notes[-1]
    with pytest.raises(ConfigError, match="zero vector"):
        LevelCloud(up=(0, 0, 0))
    with pytest.raises(ConfigError, match="did you mean 'up'"):
        LevelCloud(upp=(0, 0, 1))
    with pytest.raises(ConfigError, match="up"):
        LevelCloud()  # required: a scan cannot tell its tilt from the slope it stands on


def test_levelled_by_gravity_the_surface_gives_the_worlds_slope():
    # a vehicle on a 20 degree slope: its sensor sees the ground level; levelled with the up
    # its IMU gives, the fitted surface has the world's slope and the inliers index the scan
    slope = math.tan(math.radians(20.0))
    scene = Scene("slope", (Plane(slope_x=slope),), region=(-30.0, 30.0, -30.0, 30.0))
    cloud = sample_lidar(scene, on_terrain=True, yaw_deg=30.0, beams=16, azimuth_steps=600,
                         range_noise=0.01)
    tilted, inliers_tilted = o3d_terrain.segment_terrain(cloud.positions)
    assert abs(float(tilted.slope_deg(5.0, 0.0))) < 1.0
    levelled, _ = o3d_terrain.level_cloud(cloud.positions, cloud.world_from_sensor[2, :3])
    surface, inliers = o3d_terrain.segment_terrain(levelled)
    assert float(surface.slope_deg(5.0, 0.0)) == pytest.approx(20.0, abs=0.5)
    assert len(inliers) > 0.98 * len(cloud.positions)
    assert inliers.max() < len(cloud.positions)


def test_a_cloud_in_a_cameras_frame_is_warned_of_with_its_levelling():
    # a camera 1.6 m above flat ground with a box on it, in OpenCV's frame: x right, y down,
    # z forward; the warning proposes the up that levels it, which gives the ground back
    rng = np.random.default_rng(3)
    forward, right = rng.uniform(3, 30, 20_000), rng.uniform(-10, 10, 20_000)
    up = rng.normal(0.0, 0.02, 20_000)
    box = (np.abs(forward - 12) < 1) & (np.abs(right) < 1)
    up[box] += rng.uniform(0.3, 1.5, box.sum())
    camera = np.c_[right, 1.6 - up, forward]
    with pytest.warns(o3d_terrain.TerrainWarning, match=r"flat across \(0\.0, -1\.0, 0\.0\) "
                                                        r"\(90° from the z axis\)") as caught:
        o3d_terrain.segment_terrain(camera)
    text = str(caught[0].message)
    assert "GridQuantize" in text and "level_cloud(cloud, up=(0.0, -1.0, 0.0))" in text
    assert caught[0].filename == __file__  # the caller's line, not the library's
    levelled, _ = o3d_terrain.level_cloud(camera, (0.0, -1.0, 0.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # levelled, or a vehicle's frame: no warning
        _, inliers = o3d_terrain.segment_terrain(levelled)
        o3d_terrain.segment_terrain(np.c_[forward, -right, up - 1.6])
    assert np.isin(np.flatnonzero(~box), inliers).mean() > 0.99
    assert np.isin(np.flatnonzero(box & (up > 0.3)), inliers).mean() < 0.02


def test_a_sensor_mounted_upside_down_is_warned_of_and_levelling_gives_the_ground_back():
    # a lidar 1.8 m above flat ground with a car on it, turned upside down about x: the ground
    # it scans around it is then 1.8 m over its head (z and y change sign)
    scene = o3d_terrain.synthetic.make_scene("flat")
    cloud = sample_lidar(scene, beams=16, azimuth_steps=600, fov_deg=(-15.0, 15.0))
    truth = ~np.asarray(cloud.is_obstacle, dtype=bool)
    flipped = cloud.positions * np.array([1.0, -1.0, -1.0])
    with pytest.warns(o3d_terrain.TerrainWarning,
                      match=r"RationalBSplineTerrain: 100% of the points 2-10 m \(x/y\) from "
                            r"the sensor lie above it and 0% below") as caught:
        o3d_terrain.segment_terrain(flipped)
    assert "level_cloud(cloud, up=(0, 0, -1))" in str(caught[0].message)
    assert caught[0].filename == __file__
    levelled, _ = o3d_terrain.level_cloud(flipped, (0.0, 0.0, -1.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # upright: no warning
        _, inliers = o3d_terrain.segment_terrain(levelled)
        o3d_terrain.segment_terrain(cloud.positions)
        # an airborne tile far from the default origin is not asked
        o3d_terrain.segment_terrain(flipped + np.array([5.0e5, 4.0e6, 0.0]))
    ground = np.zeros(len(truth), bool)
    ground[inliers] = True
    assert (ground == truth).mean() > 0.98


def test_the_upside_down_hint_counts_only_a_scan_of_the_ring_around_the_sensor():
    from o3d_terrain.level import upside_down_hint

    ring = np.c_[np.linspace(2.0, 9.0, 200), np.zeros(200), np.full(200, 1.5)]
    assert upside_down_hint(ring) is not None
    assert upside_down_hint(ring, sensor_origin=(0.0, 0.0, 2.0)) is None  # level with it
    assert upside_down_hint(ring * np.array([1.0, 1.0, -1.0])) is None  # below: upright
    assert upside_down_hint(ring[:40]) is None  # too few to say
    far = ring + np.array([20.0, 0.0, 0.0])  # beyond 10 m: walls of a hollow, not its floor
    assert upside_down_hint(far) is None
    # points under the place too: a terrain patch above the origin of its frame, no sensor
    rng = np.random.default_rng(0)
    patch = np.c_[rng.uniform(-20, 20, (5000, 2)), rng.uniform(3.0, 4.0, 5000)]
    assert upside_down_hint(patch) is None
    assert upside_down_hint(patch[np.hypot(patch[:, 0], patch[:, 1]) > 2.0]) is not None
