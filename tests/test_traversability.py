"""Traversability cost map: against exact synthetic terrain and obstacles, plus its contract."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_terrain.api import fit_terrain
from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.frame import as_frame
from o3d_terrain.obstacles import detect_obstacles
from o3d_terrain.segment import segment_points
from o3d_terrain.spline import TerrainSurface, clamped_uniform_knots
from o3d_terrain.stages import TraversabilityCost
from o3d_terrain.synthetic import default_obstacles, make_scene, sample_lidar
from o3d_terrain.traversability import (FREE, INSCRIBED, LETHAL, UNKNOWN, CostMap,
                                        VehicleProfile, load_vehicle_profile,
                                        surface_on_grid, traversability_cost,
                                        vehicle_profile_names)


def flat_surface(z=0.0, half=100.0) -> TerrainSurface:
    knots = clamped_uniform_knots(4, 3, -half, half)
    return TerrainSurface(3, knots, knots, np.zeros((4, 4)), np.ones((4, 4)), (0.0, 0.0, z))


@pytest.fixture(scope="module")
def obstacle_scene():
    scene = make_scene("flat").with_obstacles(default_obstacles(0))
    cloud = sample_lidar(scene, beams=64, azimuth_steps=1800, seed=2)
    return scene, cloud.world_positions


@pytest.fixture(scope="module")
def ramp_scene():
    scene = make_scene("ramp")
    cloud = sample_lidar(scene, beams=64, azimuth_steps=1800, seed=3)
    positions = cloud.world_positions
    return scene, positions, fit_terrain(positions)


def test_surface_on_grid_equals_point_evaluation(ramp_scene):
    _, _, surface = ramp_scene
    x0, x1, y0, y1 = surface.region
    xs = np.linspace(x0 - 1, x1 + 1, 41)  # includes points outside the region
    ys = np.linspace(y0 + 0.3, y1 - 0.3, 27)
    z, gx, gy = surface_on_grid(surface, xs, ys)
    np.testing.assert_allclose(z, surface(xs[:, None], ys[None, :]), atol=1e-9, equal_nan=True)
    ex, ey = surface.gradient(xs[:, None], ys[None, :])
    np.testing.assert_allclose(gx, ex, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(gy, ey, atol=1e-9, equal_nan=True)
    outside = (xs < x0) | (xs > x1)
    assert outside.any() and np.isnan(z[outside]).all() and np.isfinite(z[~outside]).all()


def test_cells_under_obstacles_are_lethal_and_flat_free_ground_is_cheapest(obstacle_scene):
    scene, positions = obstacle_scene
    surface = flat_surface()  # the exact terrain
    labels, heights = segment_points(surface, positions)
    obstacles = detect_obstacles(positions, labels=labels, heights_above_terrain=heights)
    profile = load_vehicle_profile("offroad_suv")
    cost_map = traversability_cost(surface, positions, vehicle=profile, region=(-5, 35, -15, 15),
                                   labels=labels, heights_above_terrain=heights,
                                   obstacles=obstacles)
    gx, gy = np.meshgrid(cost_map.x_centers, cost_map.y_centers, indexing="ij")
    under = np.zeros(cost_map.shape, bool)
    near = np.zeros(cost_map.shape, bool)
    for obstacle in scene.obstacles:
        assert obstacle.height > profile.lethal_step
        under |= obstacle.contains(gx, gy, margin=-cost_map.cell_size / 2)
        near |= obstacle.contains(gx, gy, margin=profile.circumscribed_radius
                                  + 2 * cost_map.cell_size)
    seen = cost_map.known
    # every observed cell under an obstacle is lethal
    assert under[seen].any()
    assert np.all(cost_map.state[under & seen] == LETHAL)
    # unobserved cells under an obstacle are never cheaper than unknown ground
    assert np.all(cost_map.cost[under] >= cost_map.options["unknown_cost"])
    # every cell holding a point of an obstacle taller than the lethal step is lethal
    ix, iy = cost_map.cells_of(positions[:, 0], positions[:, 1])
    hits = scene.obstacle_at(positions[:, 0], positions[:, 1]) >= 0
    hits &= heights > profile.lethal_step + 0.1
    assert np.all(cost_map.state[ix[hits & (ix >= 0)], iy[hits & (ix >= 0)]] == LETHAL)
    # free flat ground: observed, away from obstacles, not lethal, and the cheapest cells
    free = seen & ~near
    assert free.sum() > 1000
    assert np.all(cost_map.state[free] == FREE)
    assert np.all(cost_map.cost[free] < cost_map.cost[under].min())
    cheapest = np.unravel_index(np.argmin(cost_map.cost), cost_map.shape)
    assert seen[cheapest] and not under[cheapest] and cost_map.state[cheapest] == FREE
    assert np.median(cost_map.cost[free]) < 0.05


def test_obstacle_set_and_a_list_of_its_obstacles_give_the_same_cost_map(obstacle_scene):
    # the cost map reads an ObstacleSet's boxes and heights from its arrays, a plain sequence
    # of obstacles from the values: both must mark the same cells
    scene, positions = obstacle_scene
    surface = flat_surface()
    labels, heights = segment_points(surface, positions)
    obstacles = detect_obstacles(positions, labels=labels, heights_above_terrain=heights)
    assert len(obstacles) >= 2
    common = dict(region=(-5, 35, -15, 15), labels=labels, heights_above_terrain=heights)
    from_set = traversability_cost(surface, positions, obstacles=obstacles, **common)
    from_list = traversability_cost(surface, positions, obstacles=list(obstacles), **common)
    without = traversability_cost(surface, positions, **common)
    for name in ("cost", "state", "slope_deg", "step_height", "roughness"):
        np.testing.assert_array_equal(getattr(from_set, name), getattr(from_list, name))
    # the boxes filled cells that no obstacle point falls in
    assert (from_set.state == LETHAL).sum() > (without.state == LETHAL).sum()
    unseen_lethal = (from_set.state == LETHAL) & ~from_set.known
    assert unseen_lethal.any()


def test_cells_steeper_than_the_profile_are_lethal(ramp_scene):
    scene, positions, surface = ramp_scene
    profile = VehicleProfile(name="test", max_slope_deg=8.0, max_step_height=0.3,
                             ground_clearance=0.3, footprint=(2.0, 1.0))
    cost_map = traversability_cost(surface, positions, vehicle=profile,
                                   region=(-2, 30, -10, 10))
    gx, gy = np.meshgrid(cost_map.x_centers, cost_map.y_centers, indexing="ij")
    true_slope = scene.slope_deg(gx, gy)
    # the fit rounds the ramp's kinks over about a metre: test cells whose exact slope is
    # clear of the limit and that are 1.5 m (6 cells) or more from a kink
    steep = true_slope > profile.max_slope_deg + 1.5
    flat = true_slope < 1.0
    for _ in range(6):
        steep[1:] &= steep[:-1]
        steep[:-1] &= steep[1:]
    for _ in range(8):  # flat cells at least 2 m (8 cells) from any steeper cell
        flat[1:] &= flat[:-1]
        flat[:-1] &= flat[1:]
    flat &= cost_map.known
    steep &= cost_map.known  # cells without a point are UNKNOWN, whatever the surface's slope
    assert steep.sum() > 500 and flat.sum() > 500
    assert np.all(cost_map.state[steep] == LETHAL)
    assert np.all(cost_map.lethal[steep])
    assert not cost_map.lethal[flat].any()
    assert cost_map.cost[flat].max() < cost_map.cost[steep].min()
    np.testing.assert_allclose(cost_map.slope_deg[steep], true_slope[steep], atol=2.0)


def test_cells_without_points_are_unknown_and_slope_only_maps_keep_the_slope(ramp_scene):
    _, positions, surface = ramp_scene
    profile = VehicleProfile(name="test", max_slope_deg=8.0, max_step_height=0.3,
                             ground_clearance=0.3, footprint=(2.0, 1.0))
    region = (-2, 30, -10, 10)
    cost_map = traversability_cost(surface, positions, vehicle=profile, region=region)
    slope_only = traversability_cost(surface, None, vehicle=profile, region=region)
    known = cost_map.known
    assert known.any() and (~known).any()
    # the slope where there are points is the surface's, as in the slope-only map ...
    np.testing.assert_array_equal(cost_map.slope_deg[known], slope_only.slope_deg[known])
    assert np.all(slope_only.state[slope_only.slope_deg > profile.max_slope_deg] == LETHAL)
    # ... and cells without a point are UNKNOWN at the unknown cost, except where the
    # footprint's inflation around a lethal cell reaches them
    lethal_seen = np.zeros(cost_map.shape, bool)
    lethal_seen[known] = cost_map.state[known] == LETHAL
    from scipy.ndimage import distance_transform_edt

    d = distance_transform_edt(~lethal_seen) * cost_map.cell_size
    far = ~known & (d > profile.circumscribed_radius + cost_map.cell_size)
    assert far.sum() > 100
    assert np.all(cost_map.state[far] == UNKNOWN)
    assert np.all(cost_map.cost[far] == np.float32(cost_map.options["unknown_cost"]))
    assert np.isnan(cost_map.slope_deg[~known]).all()


def test_inflation_by_the_footprint():
    surface = flat_surface()
    profile = VehicleProfile(name="test", max_slope_deg=20, max_step_height=0.2,
                             ground_clearance=0.3, footprint=(3.0, 2.0))
    ground = np.stack(np.meshgrid(np.arange(-10, 10, 0.1), np.arange(-10, 10, 0.1)), -1)
    ground = np.column_stack([ground.reshape(-1, 2), np.zeros(ground.size // 2)])
    post = np.array([[0.05, 0.05, 1.0]])
    cost_map = traversability_cost(surface, np.concatenate([ground, post]), vehicle=profile,
                                   region=(-5, 5, -5, 5), cell_size=0.1)
    gx, gy = np.meshgrid(cost_map.x_centers, cost_map.y_centers, indexing="ij")
    d = np.hypot(gx - 0.05, gy - 0.05)
    assert cost_map.state[d < 0.01].tolist() == [LETHAL]
    inner = (d > 0.01) & (d < profile.inscribed_radius - 0.1)
    assert np.all(cost_map.state[inner] == INSCRIBED) and np.all(cost_map.cost[inner] == 1)
    band = (d > profile.inscribed_radius + 0.1) & (d < profile.circumscribed_radius - 0.1)
    assert np.all(cost_map.state[band] == FREE)
    assert np.all((cost_map.cost[band] > 0) & (cost_map.cost[band] < 1))
    # the inflated cost falls with the distance
    order = np.argsort(d[band])
    assert np.all(np.diff(cost_map.cost[band][order]) <= 1e-6)
    assert np.all(cost_map.cost[d > profile.circumscribed_radius + 0.1] == 0)


def test_save_load_uint8_and_layers(tmp_path, ramp_scene):
    _, positions, surface = ramp_scene
    cost_map = traversability_cost(surface, positions, vehicle="small_ugv", cell_size=0.5)
    cost_map.save(tmp_path / "cost.npz")
    loaded = CostMap.load(tmp_path / "cost.npz")
    np.testing.assert_array_equal(loaded.cost, cost_map.cost)
    np.testing.assert_array_equal(loaded.state, cost_map.state)
    assert loaded.vehicle == cost_map.vehicle and loaded.region == cost_map.region
    packed = cost_map.to_uint8()
    assert np.all(packed[cost_map.state == LETHAL] == 254)
    assert np.all(packed[cost_map.state == UNKNOWN] == 255)
    assert np.all(packed[cost_map.state == FREE] <= 252)
    assert set(cost_map.image_layers()) == {"cost", "state", "slope_deg", "step_height",
                                            "roughness"}
    image = cost_map.render_image()
    assert image.ndim == 3 and image.shape[2] == 3


def test_profiles_and_errors():
    assert {"offroad_suv", "haul_truck", "small_ugv"} <= set(vehicle_profile_names())
    for name in vehicle_profile_names():
        profile = load_vehicle_profile(name)
        assert profile.name == name and profile.lethal_step > 0
    with pytest.raises(InputError, match="did you mean 'small_ugv'"):
        load_vehicle_profile("small_ugb")
    with pytest.raises(InputError, match="max_slope_deg must be a finite number > 0"):
        VehicleProfile(name="x", max_slope_deg=-1, max_step_height=0.2, ground_clearance=0.2,
                       footprint=(2, 1))
    with pytest.raises(InputError, match="cell_size must be a finite number > 0"):
        traversability_cost(flat_surface(), None, cell_size=0)
    with pytest.raises(InputError, match="weights must be three numbers"):
        traversability_cost(flat_surface(), None, weights=(0, 0, 0))
    with pytest.raises(ConfigError, match="vehicle"):
        TraversabilityCost(vehicle="no_such_vehicle")
    with pytest.raises(ConfigError, match="slope_weight"):
        TraversabilityCost(slope_weight=0, step_weight=0, roughness_weight=0)


def test_stage_writes_cost_map_and_point_costs(obstacle_scene, tmp_path):
    from o3d_terrain.stages.obstacles import WriteCostMap

    _, positions = obstacle_scene
    frame = as_frame(positions).with_products(surface=flat_surface(half=40))
    stage = TraversabilityCost(vehicle="offroad_suv", max_slope_deg=15.0, cell_size=0.5)
    out = stage(frame)
    cost_map = out.product("cost_map")
    assert cost_map.vehicle.max_slope_deg == 15.0
    np.testing.assert_allclose(out.attribute("costs"),
                               cost_map.cost_at(positions[:, 0], positions[:, 1]))
    [path] = WriteCostMap().write(out, tmp_path)
    assert path.stat().st_size > 0
