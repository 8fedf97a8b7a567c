"""Synthetic scenes: exact truth, sensor geometry, noise models and the rendered stereo pair."""

from __future__ import annotations

import math

import numpy as np
import pytest

from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.synthetic import (
    SCENES,
    GridRelief,
    Obstacle,
    Plane,
    Scene,
    make_scene,
    render_stereo_pair,
    rotation_matrix,
    sample_lidar,
    sample_sequence,
    sample_stereo,
    section6_scene,
    terrain_rmse,
)


def _random_xy(scene, count=400, seed=1):
    rng = np.random.default_rng(seed)
    x_min, x_max, y_min, y_max = scene.region
    return rng.uniform(x_min, x_max, count), rng.uniform(y_min, y_max, count)


@pytest.fixture(scope="module")
def offroad():
    return make_scene("offroad", seed=0)


@pytest.fixture(scope="module")
def offroad_lidar(offroad):
    return sample_lidar(offroad, tilt_deg=(5.0, 3.0))


# -- the exact terrain ------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SCENES))
def test_gradient_equals_central_differences(name):
    scene = make_scene(name, seed=3)
    x, y = _random_xy(scene)
    h = 1e-5
    gx, gy = scene.gradient(x, y)
    fx = (scene.height(x + h, y) - scene.height(x - h, y)) / (2 * h)
    fy = (scene.height(x, y + h) - scene.height(x, y - h)) / (2 * h)
    np.testing.assert_allclose(gx, fx, atol=1e-6)
    np.testing.assert_allclose(gy, fy, atol=1e-6)
    np.testing.assert_allclose(scene.slope_deg(x, y), np.degrees(np.arctan(np.hypot(fx, fy))),
                               atol=1e-4)


def test_heights_are_vectorised_over_any_shape(offroad):
    x, y = np.meshgrid(np.linspace(0, 10, 4), np.linspace(-3, 3, 5))
    z = offroad.height(x, y)
    assert z.shape == x.shape
    assert z[2, 3] == pytest.approx(float(offroad.height(x[2, 3], y[2, 3])))


def test_ramp_is_ten_degrees_between_two_flats():
    scene = make_scene("ramp")
    y = np.linspace(-10, 10, 7)
    for x in (12.0, 14.0, 16.0):  # well inside the ramp (x from 8 to 20)
        np.testing.assert_allclose(scene.slope_deg(np.full_like(y, x), y), 10.0, atol=1e-3)
    for x in (-2.0, 30.0):
        np.testing.assert_allclose(scene.slope_deg(np.full_like(y, x), y), 0.0, atol=1e-3)
    rise = scene.height(30.0, 0.0) - scene.height(0.0, 0.0)
    assert rise == pytest.approx(12.0 * math.tan(math.radians(10.0)), abs=1e-6)


def test_ditch_is_below_and_berm_above_the_surrounding_ground():
    scene = make_scene("ditch_berm")
    assert scene.height(12.0, -5.0) < scene.height(6.0, -5.0) - 0.6
    assert scene.height(5.0, 6.0) > scene.height(5.0, 0.0) + 0.8


def test_seed_gives_the_same_scene_and_another_seed_another_one():
    a, b, c = make_scene("mounds", seed=4), make_scene("mounds", seed=4), make_scene("mounds", seed=5)
    x, y = _random_xy(a)
    np.testing.assert_array_equal(a.height(x, y), b.height(x, y))
    assert not np.allclose(a.height(x, y), c.height(x, y))


def test_unknown_scene_and_bad_obstacle_are_clear_errors():
    with pytest.raises(InputError, match="did you mean 'offroad'"):
        make_scene("ofroad")
    with pytest.raises(InputError, match="kind"):
        Obstacle("shrub", (0, 0), (1, 1), 1.0)
    with pytest.raises(InputError, match="positive size and height"):
        Obstacle("car", (0, 0), (4, 2), -1.0)
    with pytest.raises(InputError, match="obstacle_height"):
        section6_scene(obstacle_height=0.0)


def test_obstacles_move_with_their_velocity():
    scene = make_scene("flat").with_obstacles(
        [Obstacle("pedestrian", (10.0, 0.0), (0.5, 0.5), 1.75, velocity=(0.0, 1.5))])
    later = scene.at_time(2.0)
    assert later.obstacles[0].center == pytest.approx((10.0, 3.0))
    assert later.time == 2.0
    assert scene.obstacles[0].center == (10.0, 0.0)


def test_surface_height_is_the_obstacle_top_inside_a_box(offroad):
    car = next(i for i, o in enumerate(offroad.obstacles) if o.kind == "car")
    cx, cy = offroad.obstacles[car].center
    assert offroad.surface_height(cx, cy) == pytest.approx(offroad.obstacle_top(car))
    assert offroad.obstacle_at(cx, cy) == car
    assert offroad.obstacle_at(-3.0, 0.0) == -1


def test_mesh_holds_terrain_and_obstacles(offroad):
    mesh = offroad.mesh()
    vertices = mesh.vertex.positions.numpy()
    assert vertices.dtype == np.float64
    assert len(mesh.triangle.indices) > 1000
    truck = next(i for i, o in enumerate(offroad.obstacles) if o.kind == "truck")
    assert vertices[:, 2].max() == pytest.approx(offroad.obstacle_top(truck))


# -- lidar ------------------------------------------------------------------------------------


def test_noise_free_terrain_points_lie_exactly_on_the_terrain(offroad, offroad_lidar):
    cloud = offroad_lidar
    world = cloud.to_world(cloud.true_positions)
    above = world[:, 2] - offroad.height(world[:, 0], world[:, 1])
    assert np.abs(above[~cloud.is_obstacle]).max() < 1e-6
    # and the exact terrain in the sensor frame agrees with them
    terrain = cloud.true_positions[~cloud.is_obstacle]
    z = cloud.terrain_height_in_sensor_frame(terrain[:, 0], terrain[:, 1])
    np.testing.assert_allclose(z, terrain[:, 2], atol=1e-6)


def test_range_noise_is_along_the_beam_with_the_requested_spread(offroad):
    cloud = sample_lidar(offroad, range_noise=0.05, seed=2)
    measured = np.linalg.norm(cloud.positions, axis=1)
    true = np.linalg.norm(cloud.true_positions, axis=1)
    assert np.std(measured - true) == pytest.approx(0.05, rel=0.05)
    cross = np.cross(cloud.positions, cloud.true_positions)
    assert np.abs(cross).max() / true.max() < 1e-9  # same ray


def test_obstacle_points_stand_above_the_terrain_inside_their_footprints(offroad, offroad_lidar):
    cloud = offroad_lidar
    world = cloud.to_world(cloud.true_positions)
    above = world[:, 2] - offroad.height(world[:, 0], world[:, 1])
    seen = set(np.unique(cloud.obstacle_id[cloud.is_obstacle]))
    assert {o.kind for i, o in enumerate(offroad.obstacles) if i in seen} >= {"car", "truck", "pole"}
    for i in seen:
        obstacle = offroad.obstacles[i]
        mine = cloud.obstacle_id == i
        assert obstacle.contains(world[mine, 0], world[mine, 1], margin=0.02).all()
        assert world[mine, 2].max() <= offroad.obstacle_top(i) + 1e-3
        assert (above[mine] > -0.02).all()  # nothing seen below the ground
    car = next(i for i, o in enumerate(offroad.obstacles) if o.kind == "car")
    # the sensor (1.8 m) sees the roof of the 1.5 m car
    assert world[cloud.obstacle_id == car, 2].max() == pytest.approx(offroad.obstacle_top(car), abs=1e-3)
    np.testing.assert_allclose(cloud.true_height_above_terrain[~cloud.is_obstacle], 0.0, atol=0.2)


def test_tilt_tilts_the_ground_in_the_sensor_frame():
    scene = make_scene("flat")
    for roll, pitch in ((0.0, 0.0), (5.0, 3.0), (-4.0, -6.0)):
        cloud = sample_lidar(scene, tilt_deg=(roll, pitch), range_noise=0.0, beams=16,
                             azimuth_steps=360)
        p = cloud.positions
        centred = p - p.mean(axis=0)
        normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
        normal *= np.sign(normal[2])
        expected = rotation_matrix(roll_deg=roll, pitch_deg=pitch).T @ np.array([0.0, 0.0, 1.0])
        np.testing.assert_allclose(normal, expected, atol=1e-9)
        # the sensor stands 1.8 m above the ground along world z
        assert cloud.world_from_sensor[2, 3] == pytest.approx(1.8)


def test_pitch_down_makes_the_ground_ahead_rise_in_the_sensor_frame():
    cloud = sample_lidar(make_scene("flat"), tilt_deg=(0.0, 5.0), range_noise=0.0)
    ahead = cloud.positions[(cloud.positions[:, 0] > 10) & (np.abs(cloud.positions[:, 1]) < 2)]
    behind = cloud.positions[(cloud.positions[:, 0] < -3) & (np.abs(cloud.positions[:, 1]) < 2)]
    assert ahead[:, 2].mean() > behind[:, 2].mean() + 0.5


def test_grid_relief_interpolates_its_grid_and_extends_level_outside():
    rng = np.random.default_rng(3)
    heights = rng.normal(0.0, 2.0, (30, 40))
    relief = GridRelief(heights, 2.0, x0=-10.0, y0=5.0)
    jj, ii = np.meshgrid(np.arange(30), np.arange(40), indexing="ij")
    np.testing.assert_allclose(relief.height(-10.0 + 2.0 * ii, 5.0 + 2.0 * jj), heights,
                               atol=1e-9)
    # a plane's grid gives the plane and its slopes between the nodes (row j is y = y0 + j·cell)
    plane = 3.0 + 0.2 * (-10.0 + 2.0 * ii) - 0.1 * (5.0 + 2.0 * jj)
    relief = GridRelief(plane, 2.0, x0=-10.0, y0=5.0)
    x, y = rng.uniform(-10.0, 68.0, 200), rng.uniform(5.0, 63.0, 200)
    np.testing.assert_allclose(relief.height(x, y), 3.0 + 0.2 * x - 0.1 * y, atol=1e-9)
    gx, gy = relief.gradient(x, y)
    np.testing.assert_allclose(gx, 0.2, atol=1e-9)
    np.testing.assert_allclose(gy, -0.1, atol=1e-9)
    # beyond the grid's east edge: the edge's height, level along x
    gx, gy = relief.gradient(np.array([100.0]), np.array([20.0]))
    assert gx[0] == 0.0 and gy[0] == pytest.approx(-0.1)
    assert relief.height(100.0, 20.0) == pytest.approx(3.0 + 0.2 * 68.0 - 0.1 * 20.0)
    with pytest.raises(InputError, match="4 x 4"):
        GridRelief(np.zeros((3, 10)), 1.0)
    with pytest.raises(InputError, match="no-data"):
        GridRelief(np.where(ii > 3, 1.0, np.nan), 1.0)
    with pytest.raises(InputError, match="cell_size"):
        GridRelief(heights, 0.0)


def test_a_sensor_on_the_terrain_tilts_with_the_slope_under_it():
    slope = math.tan(math.radians(15.0))
    scene = Scene("slope", (Plane(slope_x=slope),), region=(-30.0, 30.0, -30.0, 30.0))
    for yaw in (0.0, 90.0, 200.0):
        cloud = sample_lidar(scene, on_terrain=True, yaw_deg=yaw, range_noise=0.0, beams=16,
                             azimuth_steps=360)
        # the plane is level in the sensor's frame, 1.8 m below it (the mast along the normal)
        np.testing.assert_allclose(cloud.positions[:, 2], -1.8, atol=1e-6)
        r = cloud.world_from_sensor[:3, :3]
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        heading = math.radians(yaw)
        assert math.atan2(r[1, 0], r[0, 0]) == pytest.approx(math.atan2(
            math.sin(heading), math.cos(heading)), abs=1e-9)
    # without it the sensor stays level: the same plane rises 15 degrees ahead
    level = sample_lidar(scene, range_noise=0.0, beams=16, azimuth_steps=360)
    ahead = level.positions[(level.positions[:, 0] > 5) & (np.abs(level.positions[:, 1]) < 1)]
    assert np.all(ahead[:, 2] > -1.8 + 0.2 * (ahead[:, 0] - 0.5))


def test_tall_obstacle_casts_an_occlusion_shadow():
    tall = section6_scene(obstacle_height=3.0, obstacle_width=2.0)
    bare = tall.without_obstacles()

    def count(cloud, y_low, y_high):
        p = cloud.to_world(cloud.positions)
        terrain = ~cloud.is_obstacle
        return int(((p[:, 0] > 13) & (p[:, 0] < 20) & (p[:, 1] > y_low) & (p[:, 1] < y_high)
                    & terrain).sum())

    with_box = sample_lidar(tall, beams=64, azimuth_steps=1800)
    without = sample_lidar(bare, beams=64, azimuth_steps=1800)
    assert count(without, -0.5, 0.5) > 20  # there is ground there to see
    assert count(with_box, -0.5, 0.5) == 0  # but the box hides it
    assert count(with_box, 4.0, 6.0) == count(without, 4.0, 6.0)  # beside the shadow: unchanged


def test_lidar_seed_determinism(offroad):
    a = sample_lidar(offroad, seed=7)
    b = sample_lidar(offroad, seed=7)
    c = sample_lidar(offroad, seed=8)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.obstacle_id, b.obstacle_id)
    assert not np.array_equal(a.positions, c.positions)


def test_bad_sensor_options_are_clear_errors(offroad):
    with pytest.raises(InputError, match="beams"):
        sample_lidar(offroad, beams=0)
    with pytest.raises(InputError, match="tilt_deg"):
        sample_lidar(offroad, tilt_deg=(float("nan"), 0.0))
    with pytest.raises(InputError, match="baseline"):
        sample_stereo(offroad, baseline=-0.3)


def test_to_pointcloud_carries_the_truth(offroad_lidar):
    cloud = offroad_lidar.to_pointcloud()
    n = len(offroad_lidar)
    assert cloud.point.positions.numpy().dtype == np.float64
    truth = cloud.point["ground_truth"].numpy()
    ids = cloud.point["obstacle_ids"].numpy()
    assert truth.shape == (n, 1) and ids.shape == (n, 1)
    np.testing.assert_array_equal(truth[:, 0] == 2, offroad_lidar.is_obstacle)
    np.testing.assert_array_equal(ids[:, 0], offroad_lidar.obstacle_id)


# -- evaluation helper ------------------------------------------------------------------------


def test_terrain_rmse_is_zero_for_the_exact_surface_and_the_offset_otherwise(offroad_lidar):
    exact = terrain_rmse(offroad_lidar.terrain_height, offroad_lidar)
    assert exact.rmse < 1e-6 and exact.samples > 100
    shifted = terrain_rmse(lambda x, y: offroad_lidar.terrain_height(x, y) + 0.1, offroad_lidar)
    assert shifted.rmse == pytest.approx(0.1) and shifted.bias == pytest.approx(0.1)
    # the world height is not the sensor-frame terrain of a raised, tilted sensor
    world = terrain_rmse(offroad_lidar.scene.height, offroad_lidar)
    assert world.rmse > 1.0


def test_terrain_truth_samples_lie_on_the_terrain(offroad_lidar):
    samples = offroad_lidar.terrain_truth_samples(spacing=1.0)
    world = offroad_lidar.to_world(samples)
    np.testing.assert_allclose(world[:, 2], offroad_lidar.scene.height(world[:, 0], world[:, 1]),
                               atol=1e-6)


# -- stereo-like cloud ------------------------------------------------------------------------


def test_stereo_noise_is_along_the_ray_and_grows_with_range_squared(offroad):
    focal, baseline, sigma = 256.0, 0.3, 0.25
    cloud = sample_stereo(offroad, width=320, height=240, focal_px=focal, baseline=baseline,
                          disparity_noise_px=sigma, seed=1)
    depth = cloud.true_positions[:, 0]  # forward component = depth along the optical axis
    error = cloud.positions[:, 0] - depth
    cross = np.cross(cloud.positions, cloud.true_positions)
    assert np.abs(cross).max() / depth.max() < 1e-9
    spreads = []
    for low, high in ((4.0, 6.0), (12.0, 15.0), (20.0, 25.0)):
        band = (depth > low) & (depth < high)
        assert band.sum() > 500
        z = np.sqrt(np.mean(depth[band] ** 2))
        spreads.append(np.std(error[band]))
        # first-order propagation: sigma_Z = Z² sigma_d / (f B)
        assert spreads[-1] == pytest.approx(z**2 * sigma / (focal * baseline), rel=0.15)
    assert spreads[0] < spreads[1] < spreads[2]


def test_stereo_cloud_sees_obstacles_and_exact_terrain(offroad):
    cloud = sample_stereo(offroad, disparity_noise_px=0.0)
    assert cloud.is_obstacle.any()
    world = cloud.to_world(cloud.positions)
    above = world[:, 2] - offroad.height(world[:, 0], world[:, 1])
    assert np.abs(above[~cloud.is_obstacle]).max() < 1e-6


# -- rendered stereo pair ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def pair(offroad):
    return render_stereo_pair(offroad, width=192, height=144, baseline=0.3, seed=0)


def test_right_image_is_the_left_shifted_by_the_true_disparity(pair):
    left = pair.left.astype(np.float64)
    right = pair.right.astype(np.float64)
    _h, w = left.shape
    v, u = np.nonzero(np.isfinite(pair.depth))
    d = pair.disparity[v, u]
    # textured pixels away from depth edges, whose match stays inside the right image
    gradient = np.abs(np.gradient(left, axis=1))[v, u]
    depth = pair.depth
    smooth = np.ones_like(depth, dtype=bool)
    with np.errstate(invalid="ignore"):  # inf - inf next to the sky
        smooth[:, 1:-1] = np.abs(depth[:, 2:] - depth[:, :-2]) < 0.05 * depth[:, 1:-1]
    keep = (gradient > 4) & smooth[v, u] & (u - d > 2) & (u < w - 2)
    v, u, d = v[keep], u[keep], d[keep]
    assert len(v) > 1000

    def difference(shift):
        x = u - shift
        x0 = np.floor(x).astype(int)
        a = x - x0
        sampled = (1 - a) * right[v, x0] + a * right[v, np.minimum(x0 + 1, w - 1)]
        return np.median(np.abs(sampled - left[v, u]))

    true = difference(d)
    assert true < 8.0
    assert difference(d + 3.0) > 2 * true
    assert difference(d - 3.0) > 2 * true


def test_pair_calibration_and_truth_are_consistent(pair, offroad):
    cal = pair.calibration
    assert {"fx", "fy", "cx", "cy", "baseline", "width", "height"} <= set(cal)
    assert pair.left.shape == (cal["height"], cal["width"]) and pair.left.dtype == np.uint8
    sky = ~np.isfinite(pair.depth)
    assert sky.any() and (pair.disparity[sky] == 0).all() and (pair.obstacle_ids[sky] == -2).all()
    seen = np.isfinite(pair.depth)
    np.testing.assert_allclose(pair.disparity[seen] * pair.depth[seen], cal["fx"] * cal["baseline"])
    cloud = pair.true_cloud()
    world = cloud.to_world(cloud.positions)
    above = world[:, 2] - offroad.height(world[:, 0], world[:, 1])
    assert np.abs(above[~cloud.is_obstacle]).max() < 1e-5
    baseline = np.linalg.norm(pair.world_from_right[:3, 3] - pair.world_from_left[:3, 3])
    assert baseline == pytest.approx(cal["baseline"])


def test_pair_write(tmp_path, pair):
    import cv2
    import yaml

    paths = pair.write(tmp_path)
    np.testing.assert_array_equal(cv2.imread(str(paths["left.png"]), cv2.IMREAD_GRAYSCALE), pair.left)
    assert yaml.safe_load(paths["calibration.yaml"].read_text())["baseline"] == pytest.approx(0.3)
    np.testing.assert_array_equal(np.load(paths["disparity.npy"]), pair.disparity)


# -- the source stage -------------------------------------------------------------------------


def test_source_stage_makes_a_frame_with_truth():
    from o3d_terrain.stages import STAGES, SyntheticScene

    assert STAGES["SyntheticScene"] is SyntheticScene
    stage = SyntheticScene(scene="section6", tilt_deg=[5, 3], beams=16, azimuth_steps=360)
    frame = stage()
    assert len(frame) > 500
    assert set(SyntheticScene.writes_attributes) <= set(frame.attribute_names())
    assert set(SyntheticScene.writes) <= set(frame.products)
    assert frame.product("truth").name == "section6"
    truth = frame.product("sensor_truth")
    np.testing.assert_array_equal(frame.positions, truth.positions)
    assert (frame.attribute("ground_truth") == 2).sum() == truth.is_obstacle.sum()
    again = SyntheticScene.from_config({"type": "SyntheticScene", "scene": "section6",
                                        "tilt_deg": [5, 3], "beams": 16,
                                        "azimuth_steps": 360})()
    np.testing.assert_array_equal(frame.positions, again.positions)
    stereo = SyntheticScene(scene="flat", sensor="stereo", image_size=[64, 48])()
    assert len(stereo) > 500
    solid = SyntheticScene(scene="forest", sensor="solid_state", points=5000, fov_deg=40)()
    assert len(solid) > 2000 and solid.positions[:, 0].min() > 0
    assert (solid.attribute("ground_truth") == 2).any()  # the forest's trees


def test_source_stage_rejects_bad_options():
    from o3d_terrain.stages import SyntheticScene

    with pytest.raises(ConfigError, match="did you mean 'offroad'"):
        SyntheticScene(scene="ofroad")
    with pytest.raises(ConfigError, match="sensor"):
        SyntheticScene(sensor="radar")


# -- sequences --------------------------------------------------------------------------------


def test_sequence_moves_the_sensor_and_the_obstacles():
    scene = make_scene("crossing", seed=0)
    frames = sample_sequence(scene, frames=3, rate_hz=10.0, speed=5.0, beams=16,
                             azimuth_steps=360)
    assert [f.time for f in frames] == pytest.approx([0.0, 0.1, 0.2])
    for k, frame in enumerate(frames):
        assert frame.world_from_sensor[0, 3] == pytest.approx(0.5 * k)
        for i, obstacle in enumerate(frame.scene.obstacles):
            start = scene.obstacles[i]
            expected = np.asarray(start.center) + np.asarray(start.velocity) * frame.time
            assert obstacle.center == pytest.approx(tuple(expected))
        world = frame.to_world(frame.true_positions)
        for i in np.unique(frame.obstacle_id[frame.is_obstacle]):
            mine = frame.obstacle_id == i
            assert frame.scene.obstacles[i].contains(world[mine, 0], world[mine, 1],
                                                     margin=0.02).all()


def test_region_override_gives_a_larger_scene():
    small = make_scene("offroad")
    large = make_scene("offroad", region=(-40, 40, -40, 40))
    x, y = _random_xy(small)
    np.testing.assert_array_equal(small.height(x, y), large.height(x, y))
    assert len(sample_lidar(large, beams=16, azimuth_steps=360)) > \
        len(sample_lidar(small, beams=16, azimuth_steps=360))
    with pytest.raises(InputError, match="x_max > x_min"):
        make_scene("flat", region=(10, 0, 0, 10))


def test_spurious_returns_are_labelled_and_off_the_surface(offroad):
    from o3d_terrain.synthetic import OUTLIER

    cloud = sample_lidar(offroad, range_noise=0.0, outlier_fraction=0.05, seed=3)
    outliers = cloud.is_outlier
    assert 0.03 < outliers.mean() < 0.07
    assert (cloud.ground_truth[outliers] == OUTLIER).all()
    ratio = np.linalg.norm(cloud.positions, axis=1) / np.linalg.norm(cloud.true_positions, axis=1)
    assert ((ratio[outliers] >= 0.5) & (ratio[outliers] <= 1.5)).all()
    np.testing.assert_allclose(ratio[~outliers], 1.0)
    clean = sample_lidar(offroad, range_noise=0.0)
    assert not clean.is_outlier.any() and (clean.ground_truth < OUTLIER).all()
    with pytest.raises(InputError, match="outlier_fraction"):
        sample_stereo(offroad, outlier_fraction=2.0)


def test_airborne_strip_is_top_down_in_projected_coordinates(offroad):
    """sample_airborne: about density x area first returns, in projected coordinates (the
    scene's origin at AIRBORNE_OFFSET); noise-free terrain hits lie on the exact terrain,
    obstacle hits above it, and the noise is along the (near-vertical) beam."""
    from o3d_terrain.synthetic import sample_airborne
    from o3d_terrain.synthetic.sensors import AIRBORNE_OFFSET
    cloud = sample_airborne(offroad, density=4.0, seed=1)
    x_min, x_max, y_min, y_max = offroad.region
    assert abs(len(cloud) - 4.0 * (x_max - x_min) * (y_max - y_min)) < 0.05 * len(cloud)
    world = cloud.to_world(cloud.true_positions)
    np.testing.assert_allclose(world, cloud.true_positions - AIRBORNE_OFFSET)
    assert world[:, 0].min() >= x_min - 1e-6 and world[:, 0].max() <= x_max + 1e-6
    terrain = ~cloud.is_obstacle
    gap = world[terrain, 2] - offroad.height(world[terrain, 0], world[terrain, 1])
    assert np.abs(gap).max() < 1e-4
    assert cloud.is_obstacle.any() and (cloud.true_height_above_terrain[cloud.is_obstacle]
                                        > -0.05).all()
    noise = cloud.positions - cloud.true_positions
    assert 0.02 < np.std(noise[:, 2]) < 0.04 and np.std(noise[:, 0]) < 1e-9
    with pytest.raises(InputError, match="scan_angle_deg"):
        sample_airborne(offroad, scan_angle_deg=70.0)


def test_solid_state_lidar_looks_ahead_without_scan_lines(offroad):
    """sample_solid_state: every ray within half the field of view of the sensor's x axis,
    noise-free terrain points on the terrain, seeds and bad options as sample_lidar's; its
    rose has no scan lines (neighbouring elevations seen from the sensor a few hundredths of
    a degree apart, where a 32-channel lidar's lines lie 0.9 degrees apart), so the lidar
    rules that grow the feet of objects with the line spacing stay near the plain foot height."""
    from o3d_terrain.segment import scan_line_spacing
    from o3d_terrain.synthetic import sample_solid_state

    cloud = sample_solid_state(offroad, points=20_000, range_noise=0.0, fov_deg=60.0)
    p = cloud.positions
    off_axis = np.degrees(np.arccos(p[:, 0] / np.linalg.norm(p, axis=1)))
    assert len(p) > 10_000 and off_axis.max() <= 30.0 + 1e-6
    assert np.all(p[:, 0] > 0)  # ahead of the sensor only
    world = cloud.to_world(p[~cloud.is_obstacle])
    np.testing.assert_allclose(world[:, 2], offroad.height(world[:, 0], world[:, 1]), atol=1e-6)
    assert scan_line_spacing(sample_solid_state(offroad, points=100_000).positions) < 0.2
    assert scan_line_spacing(sample_lidar(offroad).positions) > 0.8
    a = sample_solid_state(offroad, points=5_000, seed=3)
    np.testing.assert_array_equal(a.positions, sample_solid_state(offroad, points=5_000,
                                                                  seed=3).positions)
    assert not np.array_equal(a.positions, sample_solid_state(offroad, points=5_000,
                                                              seed=4).positions)
    with pytest.raises(InputError, match="points"):
        sample_solid_state(offroad, points=0)
    with pytest.raises(InputError, match="fov_deg"):
        sample_solid_state(offroad, fov_deg=200.0)


def test_forest_trees_have_a_trunk_under_a_crown_and_ground_beneath_it():
    """The forest scene's trees: from above a ray meets the crown's top where surface_height
    says; from a point under the crown, 1 m from the trunk, a horizontal ray meets the trunk,
    a ray up the crown and a ray down the ground (the free space under the crown)."""
    from o3d_terrain.synthetic import cast
    from o3d_terrain.synthetic.scene import TREE_CROWN_BASE, TREE_TRUNK_SHARE

    scene = make_scene("forest", seed=0)
    trees = [(i, o) for i, o in enumerate(scene.obstacles) if o.kind == "tree"]
    assert len(trees) == 30 and any(o.kind == "rock" for o in scene.obstacles)
    tested = 0
    for i, tree in trees:
        cx, cy = tree.center
        ground = scene.obstacle_ground(i)
        # a point 1 m from the trunk under this crown, it and the centre under no other
        # obstacle's footprint (crowns overlap in the forest)
        sides = [d for d in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))
                 if sum(bool(o.contains(cx - d[0], cy - d[1], margin=0.2))
                        or bool(o.contains(cx, cy, margin=0.2)) for o in scene.obstacles) == 1]
        if not sides:
            continue
        tested += 1
        t, index, _ = cast(scene, np.array([cx, cy, ground + 100.0]),
                           np.array([[0.0, 0.0, -1.0]]))
        assert index[0] == i
        assert ground + 100.0 - t[0] == pytest.approx(scene.surface_height(cx, cy), abs=0.05)
        assert scene.surface_height(cx, cy) == pytest.approx(ground + tree.height, abs=0.05)
        dx, dy = sides[0]
        under = np.array([cx - dx, cy - dy, ground + 0.5 * TREE_CROWN_BASE * tree.height])
        radius = max(0.15, TREE_TRUNK_SHARE * sum(tree.size) / 2) / 2
        t, index, _ = cast(scene, under, np.array([[dx, dy, 0.0], [0.0, 0.0, 1.0],
                                                   [0.0, 0.0, -1.0]]))
        assert list(index) == [i, i, -1]  # the trunk, the crown, the ground
        assert t[0] == pytest.approx(1.0 - radius, abs=0.02)
        # the crown's underside: an ellipsoid from the crown base up
        u, v = tree._local(under[0], under[1])
        reach = (1 - TREE_CROWN_BASE) * tree.height / 2
        r = 1 - (u / (tree.size[0] / 2)) ** 2 - (v / (tree.size[1] / 2)) ** 2
        underside = ground + TREE_CROWN_BASE * tree.height + reach * (1 - np.sqrt(r))
        assert under[2] + t[1] == pytest.approx(underside, abs=0.1)  # a 24-segment mesh
    assert tested >= 10
