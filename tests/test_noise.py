"""Range-dependent sensor noise (o3d_terrain.noise) and its use by the terrain fit."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_terrain import segment_terrain
from o3d_terrain.api import fit_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.grid import quantize_points, region_of
from o3d_terrain.noise import GridNoise, RangeNoise
from o3d_terrain.stages.terrain import RationalBSplineTerrain
from o3d_terrain.synthetic import default_obstacles, make_scene, sample_stereo
from o3d_terrain.terrain import fit_grid_detailed

RIG = {"focal_px": 256.0, "baseline": 0.3, "disparity_noise_px": 0.25}


def test_stereo_coefficient_matches_the_spread_of_reprojected_depths():
    """sigma along the ray = rho^2 sigma_d / (f B): against depths f B / (d + noise)."""
    model = RangeNoise.from_stereo(**RIG)
    assert model.coefficient == pytest.approx(0.25 / (256.0 * 0.3))
    rng = np.random.default_rng(0)
    for depth in (5.0, 10.0, 20.0):
        d = 256.0 * 0.3 / depth + rng.normal(0.0, 0.25, 200_000)
        measured = 256.0 * 0.3 / d
        expected = model.range_sigma(np.array([[depth, 0.0, 0.0]]))[0]
        # first-order model: within 6 % up to 20 m (d = 3.8 px)
        assert np.std(measured) == pytest.approx(expected, rel=0.06)


def test_height_noise_of_a_cell_matches_points_moved_along_their_rays():
    """GridNoise.sigma against the spread of heights of points on a tilted plane moved along
    their viewing rays by sigma_rho = k rho^2 (the slope term included), where the move is
    shorter than a cell (farther, the cell collects points from other ranges)."""
    model = RangeNoise((0.0, 0.0, 1.5), 0.004)
    rng = np.random.default_rng(1)
    n = 400_000
    xy = np.column_stack([rng.uniform(4, 24, n), rng.uniform(-6, 6, n)])
    slope = (0.15, -0.05)
    z = slope[0] * xy[:, 0] + slope[1] * xy[:, 1]
    truth = np.column_stack([xy, z])
    ray = truth - np.array(model.sensor_origin)
    rho = np.linalg.norm(ray, axis=1)
    moved = truth + ray / rho[:, None] * (model.coefficient * rho ** 2 * rng.normal(0, 1, n))[:, None]
    grid = quantize_points(moved, cell_size=1.0, region=(4, 24, -6, 6))
    noise = GridNoise(grid, moved, model, grid.z)
    xc, yc = np.meshgrid(grid.x_centers, grid.y_centers, indexing="ij")
    plane = slope[0] * xc + slope[1] * yc
    sigma = noise.sigma(plane)
    height = moved[:, 2] - (slope[0] * moved[:, 0] + slope[1] * moved[:, 1])
    cells = grid.cell_of(moved[:, 0], moved[:, 1])
    ok = cells >= 0
    count = np.bincount(cells[ok], minlength=grid.nx * grid.ny)
    spread = np.sqrt(np.bincount(cells[ok], weights=height[ok] ** 2, minlength=grid.nx * grid.ny)
                     / np.maximum(count, 1)).reshape(grid.shape)
    reach = model.coefficient * (xc ** 2 + yc ** 2 + 1.5 ** 2)
    inner = (count.reshape(grid.shape) > 200) & (xc > 6) & (reach < 0.5)
    assert inner.sum() > 50
    assert np.median(np.abs(sigma[inner] / spread[inner] - 1)) < 0.05


def test_zero_coefficient_is_the_fit_without_a_model():
    scene = make_scene("hills", seed=0).with_obstacles(default_obstacles(0))
    cloud = sample_stereo(scene, seed=0)
    p = cloud.positions
    grid = quantize_points(p, cell_size=0.5, region=region_of(p))
    plain = fit_grid_detailed(grid, positions=p).surface
    zero = fit_grid_detailed(grid, positions=p, range_noise=RangeNoise((0, 0, 0), 0.0)).surface
    x, y = p[:, 0], p[:, 1]
    assert np.nanmax(np.abs(plain(x, y) - zero(x, y))) < 1e-9


@pytest.mark.parametrize("name", ["hills", "offroad"])
def test_stereo_fit_with_the_rig_model_is_closer_to_the_truth(name):
    scene = make_scene(name, seed=0)
    if not scene.obstacles:
        scene = scene.with_obstacles(default_obstacles(0))
    cloud = sample_stereo(scene, seed=0)
    p = cloud.positions
    terrain = ~cloud.is_obstacle & ~cloud.is_outlier
    truth = cloud.terrain_height(p[terrain, 0], p[terrain, 1])

    def rmse(surface):
        e = surface(p[terrain, 0], p[terrain, 1]) - truth
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e ** 2)))

    without = rmse(fit_terrain(p))
    model = RangeNoise.from_stereo(**RIG)
    with_model = rmse(fit_terrain(p, range_noise=model))
    assert with_model < 0.75 * without
    assert with_model < 0.11
    # the same through a coefficient and sensor_origin, and through the stage option
    same = fit_terrain(p, range_noise=model.coefficient, sensor_origin=(0, 0, 0))
    assert rmse(same) == pytest.approx(with_model, abs=1e-9)
    surface, inliers = segment_terrain(p, range_noise=model)
    assert len(inliers) > 0.8 * terrain.sum()


def test_stage_option_and_frame_product():
    stage = RationalBSplineTerrain(range_noise=0.003, sensor_origin=(0.0, 0.0, 1.6))
    assert stage.range_noise == 0.003 and stage.sensor_origin == (0.0, 0.0, 1.6)
    with pytest.raises(Exception, match="range_noise"):
        RationalBSplineTerrain(range_noise=-1.0)


def test_bad_models_are_rejected_with_the_reason():
    with pytest.raises(InputError, match="sensor_origin"):
        RangeNoise((0.0, 0.0), 0.001)
    with pytest.raises(InputError, match="coefficient"):
        RangeNoise((0.0, 0.0, 0.0), -0.1)
    with pytest.raises(InputError, match="baseline"):
        RangeNoise.from_stereo(focal_px=100.0, baseline=0.0, disparity_noise_px=0.2)


def test_stereo_source_attaches_the_rig_model_and_the_terrain_stage_uses_it():
    from o3d_terrain.stages.grid_quantize import GridQuantize
    from o3d_terrain.stages.stereo import StereoToCloud
    from o3d_terrain.synthetic import render_stereo_pair

    pair = render_stereo_pair(make_scene("flat", seed=0), width=160, height=120)
    options = {"frame": "vehicle", "camera_height": 1.6, "pitch_deg": 5.0,
               "depth_range": (3.0, 30.0)}
    frame = StereoToCloud.from_images(pair.left, pair.right, pair.calibration,
                                      disparity_noise_px=0.3, **options)
    model = frame.product("range_noise")
    cal = pair.calibration
    assert model.coefficient == pytest.approx(0.3 / (cal["fx"] * cal["baseline"]))
    assert model.sensor_origin == pytest.approx((0.0, 0.0, 1.6))
    assert "range_noise" not in StereoToCloud.from_images(
        pair.left, pair.right, pair.calibration, **options).products
    grid_frame = GridQuantize()(frame)
    stage = RationalBSplineTerrain()
    from_product = stage(grid_frame).product("surface")
    explicit = stage.fit(grid_frame.product("grid"), grid_frame.positions, model).surface
    plain = stage.fit(grid_frame.product("grid"), grid_frame.positions).surface
    x, y = grid_frame.positions[:, 0], grid_frame.positions[:, 1]
    assert np.nanmax(np.abs(from_product(x, y) - explicit(x, y))) < 1e-12
    assert np.nanmax(np.abs(from_product(x, y) - plain(x, y))) > 1e-6  # the model is used
    # the stage's own option wins over the product (free_space off: from the camera 1.6 m up
    # it would leave out cells that the stage above, its sensor on the ground, keeps)
    option = RationalBSplineTerrain(range_noise=model.coefficient, sensor_origin=(0, 0, 1.6),
                                    free_space=False)
    assert np.nanmax(np.abs(option(grid_frame).product("surface")(x, y)
                            - explicit(x, y))) < 1e-12


def test_height_sigma_of_points_on_a_plane():
    """Per-point height noise over a plane z = a x: sigma_rho |d_z - a d_x| (unit ray d)."""
    from o3d_terrain.noise import height_sigma

    x = np.linspace(2.0, 30.0, 50)
    points = np.column_stack([x, np.zeros_like(x), 0.1 * x])
    model = RangeNoise((0.0, 0.0, 1.5), 0.002)

    class Plane:
        def gradient(self, x, y):
            return np.full_like(x, 0.1), np.zeros_like(y)

    d = points - np.array(model.sensor_origin)
    rho = np.linalg.norm(d, axis=1)
    expected = model.coefficient * rho ** 2 * np.abs(d[:, 2] / rho - 0.1 * d[:, 0] / rho)
    assert height_sigma(model, Plane(), points) == pytest.approx(expected, rel=1e-12)
