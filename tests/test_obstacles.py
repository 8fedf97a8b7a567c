"""Obstacle clustering against synthetic scenes with exact truth, and on SemanticKITTI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.evaluation.datasets import SEMANTIC_KITTI_GROUND
from o3d_terrain.frame import as_frame
from o3d_terrain.obstacles import (detect_obstacles, instances_found, oriented_box,
                                   semantic_kitti_instances)
from o3d_terrain.segment import TerrainLabel, segment_points
from o3d_terrain.spline import TerrainSurface, clamped_uniform_knots
from o3d_terrain.stages import ObstacleDetector
from o3d_terrain.synthetic import default_obstacles, make_scene, sample_lidar


def flat_surface(z=0.0, half=100.0) -> TerrainSurface:
    """The exact plane z = const as a (non-rational) B-spline surface."""
    knots = clamped_uniform_knots(4, 3, -half, half)
    return TerrainSurface(3, knots, knots, np.zeros((4, 4)), np.ones((4, 4)), (0.0, 0.0, z))


@pytest.fixture(scope="module")
def flat_scene_cloud():
    scene = make_scene("flat").with_obstacles(default_obstacles(0))
    cloud = sample_lidar(scene, beams=48, azimuth_steps=1200, seed=1)
    return scene, cloud


def test_finds_every_obstacle_of_a_flat_scene(flat_scene_cloud):
    scene, cloud = flat_scene_cloud
    positions = cloud.world_positions
    surface = flat_surface()
    labels, heights = segment_points(surface, positions)
    for method in ("grid", "dbscan"):
        obstacles = detect_obstacles(positions, labels=labels, heights_above_terrain=heights,
                                     method=method)
        found = instances_found(obstacles.cluster_ids, cloud.obstacle_id, 50)
        assert found and all(found.values()), (method, found)
        for obstacle in obstacles:
            # no obstacle is made of terrain points
            assert (cloud.obstacle_id[obstacle.indices] >= 0).mean() > 0.5
            # its summary is that of its points
            points = positions[obstacle.indices]
            np.testing.assert_allclose(obstacle.centroid, points.mean(axis=0), atol=1e-9)
            assert obstacle.height == pytest.approx(heights[obstacle.indices].max())
            assert obstacle.z_min == points[:, 2].min() and obstacle.z_max == points[:, 2].max()
            assert obstacle.point_count == len(obstacle.indices) >= 5
            np.testing.assert_array_equal(np.flatnonzero(obstacles.cluster_ids == obstacle.id),
                                          np.sort(obstacle.indices))
            # the box holds the points (to within the hull approximation on cells)
            a = np.radians(obstacle.box_yaw_deg)
            d = points[:, :2] - obstacle.box_center
            u = d @ np.array([np.cos(a), np.sin(a)])
            v = d @ np.array([-np.sin(a), np.cos(a)])
            assert np.all(np.abs(u) <= obstacle.box_size[0] / 2 + 0.05)
            assert np.all(np.abs(v) <= obstacle.box_size[1] / 2 + 0.05)
            assert obstacle.box_size[0] >= obstacle.box_size[1]


def test_height_of_each_obstacle_matches_the_scene(flat_scene_cloud):
    scene, cloud = flat_scene_cloud
    positions = cloud.world_positions
    obstacles = detect_obstacles(positions, surface=flat_surface())
    for obstacle in obstacles:
        truth = np.bincount(cloud.obstacle_id[obstacle.indices] + 1).argmax() - 1
        true_top = scene.obstacle_top(truth) - scene.obstacle_ground(truth)
        # the highest measured point is at most the top plus range noise (3 sigma = 6 cm)
        assert obstacle.height <= true_top + 0.06


def test_oriented_box_of_a_rotated_rectangle(rng):
    length, width, yaw = 4.0, 1.5, 30.0
    u = rng.uniform(-length / 2, length / 2, 2000)
    v = rng.uniform(-width / 2, width / 2, 2000)
    a = np.radians(yaw)
    xy = np.column_stack([u * np.cos(a) - v * np.sin(a), u * np.sin(a) + v * np.cos(a)])
    xy += [1000.0, -2000.0]  # far from the origin: float32 inside must not cost precision
    center, size, angle = oriented_box(xy)
    np.testing.assert_allclose(center, [1000.0, -2000.0], atol=0.02)
    np.testing.assert_allclose(size, [length, width], atol=0.02)
    assert angle == pytest.approx(yaw, abs=0.5)


def test_filters_small_and_low_clusters():
    ground = np.column_stack([np.random.default_rng(0).uniform(-10, 10, (3000, 2)),
                              np.zeros(3000)])
    small = np.array([[5.0, 5.0, 1.0], [5.05, 5.0, 1.1], [5.0, 5.05, 1.2]])  # 3 points
    low = np.column_stack([np.full(20, -5.0), np.linspace(-5, -4.5, 20), np.full(20, 0.25)])
    tall = np.column_stack([np.full(20, 0.0), np.full(20, 3.0), np.linspace(0.3, 2.0, 20)])
    cloud = np.concatenate([ground, small, low, tall])
    obstacles = detect_obstacles(cloud, surface=flat_surface(), min_points=5, min_height=0.3)
    assert len(obstacles) == 1
    np.testing.assert_array_equal(np.sort(obstacles[0].indices),
                                  np.arange(len(cloud) - 20, len(cloud)))
    assert (obstacles.cluster_ids >= 0).sum() == 20
    loose = detect_obstacles(cloud, surface=flat_surface(), min_points=3, min_height=0.2)
    assert len(loose) == 3


def test_input_is_unchanged_and_errors_name_the_option(small_cloud):
    before = small_cloud.copy()
    detect_obstacles(small_cloud, surface=flat_surface())
    np.testing.assert_array_equal(small_cloud, before)
    with pytest.raises(InputError, match="cell_size must be a finite number > 0, got -1"):
        detect_obstacles(small_cloud, cell_size=-1)
    with pytest.raises(InputError, match="method must be one of grid, dbscan"):
        detect_obstacles(small_cloud, method="kmeans")
    with pytest.raises(InputError, match=r"labels must have one value per point \(4000,\)"):
        detect_obstacles(small_cloud, surface=flat_surface(), labels=np.ones(3))
    with pytest.raises(ConfigError, match="min_points"):
        ObstacleDetector(min_points=0)


def test_empty_and_obstacle_free_clouds():
    assert len(detect_obstacles(np.zeros((0, 3)), surface=flat_surface())) == 0
    ground = np.column_stack([np.random.default_rng(0).uniform(-5, 5, (500, 2)), np.zeros(500)])
    result = detect_obstacles(ground, surface=flat_surface())
    assert len(result) == 0 and np.all(result.cluster_ids == -1)


def test_stage_writes_obstacles_and_json(flat_scene_cloud, tmp_path):
    from o3d_terrain.stages.obstacles import WriteObstacles

    _, cloud = flat_scene_cloud
    frame = as_frame(cloud.world_positions).with_products(surface=flat_surface())
    out = ObstacleDetector()(frame)
    obstacles = out.product("obstacles")
    np.testing.assert_array_equal(out.attribute("cluster_ids"), obstacles.cluster_ids)
    [path] = WriteObstacles(include_indices=True).write(out, tmp_path)
    data = json.loads(path.read_text())
    assert len(data["obstacles"]) == len(obstacles)
    first = data["obstacles"][0]
    assert first["point_count"] == obstacles[0].point_count == len(first["indices"])
    assert len(first["box"]["corners"]) == 4


@pytest.mark.realdata
@pytest.mark.parametrize("frame_name", ["000000", "000001", "000002"])
def test_semantic_kitti_instances_are_found(shared_data, frame_name):
    from o3d_terrain.api import fit_terrain

    folder = shared_data / "kitti_seq00_lidar"
    points = np.fromfile(folder / "velodyne" / f"{frame_name}.bin", np.float32).reshape(-1, 4)
    labels = np.fromfile(folder / "labels" / f"{frame_name}.label", np.uint32)
    positions = points[:, :3].astype(np.float64)
    surface = fit_terrain(positions)
    point_labels, heights = segment_points(surface, positions)
    obstacles = detect_obstacles(positions, labels=point_labels, heights_above_terrain=heights)
    found = instances_found(obstacles.cluster_ids, semantic_kitti_instances(labels, positions), 50)
    assert len(found) >= 10
    assert sum(found.values()) >= 0.95 * len(found), found
    ground = np.isin(labels & 0xFFFF, SEMANTIC_KITTI_GROUND)
    mostly_ground = sum(1 for o in obstacles if ground[o.indices].mean() > 0.5)
    assert mostly_ground <= 3
    assert np.all(point_labels[obstacles.cluster_ids >= 0] == TerrainLabel.OBSTACLE)
