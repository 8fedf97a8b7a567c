"""Obstacle clustering against synthetic scenes with exact truth, and on SemanticKITTI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.evaluation.datasets import SEMANTIC_KITTI_GROUND
from o3d_terrain.frame import as_frame
from o3d_terrain.obstacles import (_oriented_boxes, detect_obstacles, instances_found,
                                   oriented_box, semantic_kitti_instances)
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
            # a complete, frozen value (built without the generated __init__)
            copy = dataclasses.replace(obstacle)
            assert all(np.array_equal(getattr(copy, f.name), getattr(obstacle, f.name))
                       for f in dataclasses.fields(obstacle))
            with pytest.raises(dataclasses.FrozenInstanceError):
                obstacle.height = 0.0
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


def opencv_box(xy):
    """cv2.minAreaRect on float32 coordinates relative to the first point, as
    (center, (length, width), yaw in (-90, 90]): the box the clustering used before."""
    import cv2

    (cx, cy), (w, h), angle = cv2.minAreaRect((xy - xy[0]).astype(np.float32))
    if h > w:
        w, h, angle = h, w, angle + 90.0
    angle = (angle + 90.0) % 180.0 - 90.0
    if angle == -90.0:
        angle = 90.0
    return xy[0] + [cx, cy], np.array([w, h]), angle


def naive_min_area(xy):
    """Least area over boxes flush with the direction of every pair of points (float64)."""
    best = np.inf
    for i in range(len(xy)):
        for j in range(len(xy)):
            d = xy[j] - xy[i]
            if i == j or not d.any():
                continue
            u = d / np.hypot(*d)
            a, b = xy @ u, xy @ [-u[1], u[0]]
            best = min(best, np.ptp(a) * np.ptp(b))
    return best


def box_holds(xy, center, size, yaw, tol):
    a = np.radians(yaw)
    d = xy - center
    u = d @ [np.cos(a), np.sin(a)]
    v = d @ [-np.sin(a), np.cos(a)]
    return np.all(np.abs(u) <= size[0] / 2 + tol) and np.all(np.abs(v) <= size[1] / 2 + tol)


def test_boxes_are_minimum_area_rectangles_as_opencv(rng):
    """The kernel's boxes against cv2.minAreaRect and a brute-force minimum on random sets:
    the least area (exact in float64), holding every point, and OpenCV's box (to float32
    precision) except where another edge ties for the least area (OpenCV then picks by
    rounding; the kernel takes the smallest perimeter)."""
    groups = []
    for g in range(600):
        n = int(rng.integers(3, 40))
        kind = g % 4
        if kind == 0:
            xy = rng.normal(0, rng.uniform(0.1, 3), (n, 2)) * [1, rng.uniform(0.1, 1)]
        elif kind == 1:
            xy = rng.uniform(-2, 2, (n, 2))
        elif kind == 2:  # a rotated rectangle's outline and inside
            u, v = rng.uniform(-2, 2, n), rng.uniform(-0.6, 0.6, n)
            xy = np.column_stack([u, v])
        else:
            xy = rng.uniform(-1, 1, (3, 2))  # triangles: all three edges tie when acute
        a = rng.uniform(0, np.pi)
        rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        groups.append(xy @ rotation.T + rng.uniform(-500, 500, 2))
    xy = np.concatenate(groups)
    starts = np.cumsum([0] + [len(g) for g in groups])
    centers, sizes, yaws = _oriented_boxes(xy, starts)
    agree = 0
    for g, points in enumerate(groups):
        area = sizes[g].prod()
        assert area == pytest.approx(naive_min_area(points - points[0]), rel=1e-9, abs=1e-12)
        assert box_holds(points, centers[g], sizes[g], yaws[g], 1e-9)
        assert sizes[g][0] >= sizes[g][1] and -90 < yaws[g] <= 90
        center, size, yaw = opencv_box(points)
        assert area <= size.prod() * (1 + 1e-5)  # never larger than OpenCV's
        same = (np.allclose(center, centers[g], atol=1e-4) and np.allclose(size, sizes[g],
                atol=1e-4) and abs((yaw - yaws[g] + 90) % 180 - 90) < 0.01)
        agree += same
        if not same:  # a tie: OpenCV's box is another least-area box
            assert size.prod() == pytest.approx(area, rel=1e-5)
    assert agree >= 0.9 * len(groups)


def test_degenerate_boxes():
    center, size, yaw = oriented_box(np.array([[3.0, 4.0]] * 3))
    np.testing.assert_array_equal(center, [3.0, 4.0])
    assert tuple(size) == (0.0, 0.0) and yaw == 90.0  # as cv2.minAreaRect
    line = np.array([[0.0, 0.0], [1.0, 1.0], [3.0, 3.0], [2.0, 2.0]]) + 100.0
    center, size, yaw = oriented_box(line)
    np.testing.assert_allclose(center, [101.5, 101.5])
    np.testing.assert_allclose(size, [3 * np.sqrt(2), 0.0], atol=1e-12)
    assert yaw == pytest.approx(45.0)
    with pytest.raises(InputError, match="no points"):
        oriented_box(np.zeros((0, 2)))


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
