"""``eval terrain CLOUD --truth DEM.tif``: a measured cloud against a surveyed elevation raster.

The truth is an analytic terrain (a 10° plane plus a 3 m hill) rasterised at 1 m and written as
a GeoTIFF; the cloud is sampled from the same function, optionally seen from a sensor tilted by
10° about x (the inverse pose given back). Oracles: an exact surface scores zero height error;
a raster raised by 1 m gives a bias of -1 m; a pose 0.5 m too high gives +0.5 m.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.evaluation import (Raster, TruthOverlapError, evaluate_terrain_against_raster,
                                    read_raster)
from o3d_terrain.evaluation.datasets import data_root
from o3d_terrain.evaluation.terrain import check_pose, read_pose

tifffile = pytest.importorskip("tifffile", reason="the dem extra (tifffile) writes the GeoTIFFs")

X0, Y0 = 1000.0, 2060.0  # upper-left corner of the 60 x 60 m truth raster
PLANE = math.tan(math.radians(10.0))


def terrain(x, y):
    """A 10° plane rising with x plus a 3 m Gaussian hill (sigma 8 m) at (1032, 2040)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return 100.0 + PLANE * (x - X0) + 3.0 * np.exp(-((x - 1032) ** 2 + (y - 2040) ** 2) / 128.0)


def terrain_slope_deg(x, y, step=1e-4):
    gx = (terrain(x + step, y) - terrain(x - step, y)) / (2 * step)
    gy = (terrain(x, y + step) - terrain(x, y - step)) / (2 * step)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def truth_heights(shift=0.0, size=60):
    xc = X0 + np.arange(size) + 0.5
    yc = Y0 - np.arange(size) - 0.5  # row 0 = north
    return (terrain(*np.meshgrid(xc, yc)) + shift).astype(np.float32)


def write_geotiff(path, heights, origin=(X0, Y0), *, georef=True, nodata=None):
    tags = []
    if georef:
        tags += [(33550, "d", 3, (1.0, 1.0, 0.0)),
                 (33922, "d", 6, (0.0, 0.0, 0.0, origin[0], origin[1], 0.0))]
    if nodata is not None:
        tags.append((42113, "s", 0, str(nodata), False))
    tifffile.imwrite(path, heights, extratags=tags)
    return path


def sample_cloud(rng, n=10_000, noise=0.01, box=(1005.0, 1055.0, 2005.0, 2055.0)):
    x = rng.uniform(box[0], box[1], n)
    y = rng.uniform(box[2], box[3], n)
    return np.column_stack([x, y, terrain(x, y) + rng.normal(0.0, noise, n)])


def tilted_pose():
    """Sensor -> map: the sensor is 1.8 m above (1030, 2030), rolled by 10° about x."""
    a = math.radians(10.0)
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    m[:3, 3] = [1030.0, 2030.0, terrain(1030.0, 2030.0) + 1.8]
    return m


def to_sensor(positions, map_to_sensor):
    return positions @ map_to_sensor[:3, :3].T + map_to_sensor[:3, 3]


class ExactSurface:
    """The analytic terrain as a surface over a region: the scoring code's oracle."""

    cell_size = 0.5

    def __init__(self, region, shift=0.0):
        self.region, self.shift = region, shift

    def __call__(self, x, y):
        return terrain(x, y) + self.shift

    def slope_deg(self, x, y):
        return terrain_slope_deg(x, y)


# ---------------------------------------------------------------------------------------------
# reading the truth and the pose


def test_geotiff_georeferencing_and_nodata_are_read(tmp_path):
    heights = truth_heights()
    heights[:2, :2] = -32767  # not one of read_dem's built-in sentinels: the tag must be read
    raster = read_raster(write_geotiff(tmp_path / "t.tif", heights, nodata=-32767))
    assert raster.origin == (X0, Y0) and raster.cell_size == 1.0
    assert raster.extent == (X0, X0 + 60, Y0 - 60, Y0)
    assert int(np.isnan(raster.heights).sum()) == 4
    # cell centres: row 0 is north
    assert raster.x_centres()[20] == X0 + 20.5 and raster.y_centres()[10] == Y0 - 10.5
    assert raster.heights[10, 20] == pytest.approx(terrain(X0 + 20.5, Y0 - 10.5), abs=1e-4)
    # slope by central differences, NaN on the border and next to nodata
    slope = raster.slope_deg()
    assert np.isnan(slope[0]).all() and np.isnan(slope[:, -1]).all() and np.isnan(slope[2, 1])
    assert slope[30, 10] == pytest.approx(terrain_slope_deg(X0 + 10.5, Y0 - 30.5), abs=0.2)


def test_origin_and_cell_size_place_a_plain_raster(tmp_path):
    path = write_geotiff(tmp_path / "plain.tif", truth_heights(), georef=False)
    with pytest.raises(InputError, match="--truth-origin"):
        read_raster(path)
    raster = read_raster(path, origin=(X0, Y0), cell_size=1.0)
    assert raster.extent == (X0, X0 + 60, Y0 - 60, Y0)
    with pytest.raises(InputError, match="together"):
        read_raster(path, origin=(X0, Y0))


def test_a_missing_tifffile_names_the_extra(tmp_path, monkeypatch):
    path = write_geotiff(tmp_path / "t.tif", truth_heights())
    monkeypatch.setitem(__import__("sys").modules, "tifffile", None)
    with pytest.raises(InputError, match=r"o3d_terrain\[dem\]"):
        read_raster(path)
    assert read_raster(path, origin=(X0, Y0), cell_size=1.0).cell_size == 1.0


@pytest.mark.parametrize("text, message", [
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", r"shape \(3, 4\)"),
    ("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not orthonormal"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", "last row"),
    ("1 0 0 0\n0 1 0 0\n0 0 -1 0\n0 0 0 1\n", "reflection"),
    ("1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "non-finite"),
    ("1 0 0 x\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not a matrix"),
])
def test_bad_poses_are_rejected(tmp_path, text, message):
    path = tmp_path / "pose.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        read_pose(path)


def test_a_pose_within_the_tolerance_is_accepted():
    m = tilted_pose()
    assert np.array_equal(check_pose(np.round(m, 9)), np.round(m, 9))


# ---------------------------------------------------------------------------------------------
# scoring


def test_an_exact_surface_scores_zero_and_only_supported_cells_count():
    raster = Raster(truth_heights(), (X0, Y0), 1.0, name="truth")
    rng = np.random.default_rng(0)
    west = sample_cloud(rng, 4000, noise=0.0, box=(1000.0, 1030.0, 2000.0, 2060.0))
    surface = ExactSurface((X0, X0 + 60, Y0 - 60, Y0))
    report = evaluate_terrain_against_raster(west, raster, surface=surface)
    result = report.results[0]
    assert result.height_rmse == pytest.approx(0.0, abs=1e-4)  # float32 raster
    # central differences over 1 m against the analytic slope on a 3 m, 8 m-wide hill
    assert result.stats["slope_rmse_deg"] < 0.3
    # support: the cloud ends at x = 1030, so no cell centre beyond x = 1031 is scored
    scored = np.isfinite(report.maps["height_error"])
    x = raster.x_centres()[result.cols[0]:result.cols[1]]
    assert x[scored.any(axis=0)].max() < 1031.0
    assert 30 * 60 * 0.9 < result.stats["cells"] <= 31 * 60
    # steep subset: cells whose truth slope exceeds 15° (the plane is 10°, the hill adds up to 12°)
    assert result.steep is not None and 0 < result.steep["cells"] < result.stats["cells"]
    shifted = evaluate_terrain_against_raster(west, raster, surface=ExactSurface(
        surface.region, shift=0.25)).results[0]
    assert shifted.height_bias == pytest.approx(0.25, abs=1e-4)
    assert shifted.stats["height_max_abs_m"] == pytest.approx(0.25, abs=1e-4)


def test_fit_of_a_tilted_scan_with_its_pose_matches_the_truth(tmp_path):
    tif = write_geotiff(tmp_path / "truth.tif", truth_heights())
    map_to_sensor = np.linalg.inv(tilted_pose())
    sensor_cloud = to_sensor(sample_cloud(np.random.default_rng(1)), map_to_sensor)
    report = evaluate_terrain_against_raster(sensor_cloud, tif, pose=tilted_pose())
    s = report.results[0].stats
    assert s["cells"] > 2000
    assert s["height_rmse_m"] < 0.05 and abs(s["height_bias_m"]) < 0.02
    assert s["slope_rmse_deg"] < 1.5
    # the same cloud without the tilt corrected: the surface leans by 10° about x
    wrong = tilted_pose()
    wrong[:3, :3] = np.eye(3)
    leaning = evaluate_terrain_against_raster(sensor_cloud, tif, pose=wrong,
                                              support_distance=60.0, min_cells=1)
    assert leaning.results[0].height_rmse > 1.0


def test_offsets_give_a_bias_of_their_size(tmp_path):
    rng = np.random.default_rng(2)
    cloud = sample_cloud(rng)
    raised = write_geotiff(tmp_path / "raised.tif", truth_heights(shift=1.0))
    result = evaluate_terrain_against_raster(cloud, raised).results[0]
    assert result.height_bias == pytest.approx(-1.0, abs=0.03)
    assert result.stats["slope_rmse_deg"] < 1.5  # the slope does not move with an offset
    up = np.eye(4)
    up[2, 3] = 0.5
    lifted = evaluate_terrain_against_raster(cloud, Raster(truth_heights(), (X0, Y0), 1.0),
                                             pose=up).results[0]
    assert lifted.height_bias == pytest.approx(0.5, abs=0.03)
    with pytest.raises(InputError, match="not several"):
        evaluate_terrain_against_raster(cloud, raised, fitter=lambda p: None, fit_options={})


def test_no_overlap_names_both_extents():
    raster = Raster(truth_heights(), (X0 + 500, Y0), 1.0, name="far")
    cloud = sample_cloud(np.random.default_rng(3), 500)
    with pytest.raises(TruthOverlapError, match=r"x 1500\.00 to 1560\.00.*do not overlap"):
        evaluate_terrain_against_raster(cloud, raster, surface=ExactSurface((X0, X0 + 60,
                                                                             Y0 - 60, Y0)))


def test_too_few_scored_cells_are_an_error():
    raster = Raster(truth_heights(), (X0, Y0), 1.0)
    corner = sample_cloud(np.random.default_rng(4), 50, box=(1000.0, 1002.0, 2000.0, 2002.0))
    with pytest.raises(TruthOverlapError, match="only .* cells"):
        evaluate_terrain_against_raster(corner, raster, surface=ExactSurface(
            (X0, X0 + 60, Y0 - 60, Y0)), min_cells=20)


# ---------------------------------------------------------------------------------------------
# the command


def _cli(argv):
    from o3d_terrain.cli import main

    return main(argv)


def _write_scan(tmp_path, pose=True):
    map_to_sensor = np.linalg.inv(tilted_pose())
    positions = sample_cloud(np.random.default_rng(5))
    if pose:
        positions = to_sensor(positions, map_to_sensor)
        np.savetxt(tmp_path / "pose.txt", tilted_pose())
    cloud = tmp_path / "scan.xyz"
    np.savetxt(cloud, positions, fmt="%.5f")
    return cloud


def test_eval_terrain_command_against_a_geotiff(tmp_path, capsys):
    cloud = _write_scan(tmp_path)
    tif = write_geotiff(tmp_path / "truth.tif", truth_heights())
    out = tmp_path / "out"
    code = _cli(["eval", "terrain", str(cloud), "--truth", str(tif), "--pose",
                 str(tmp_path / "pose.txt"), "-o", str(out), "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    result = json.loads((out / "terrain.json").read_text())["results"][0]
    assert printed["results"][0]["scored_cells"] == result["scored_cells"] > 2000
    for key in ("height_rmse_m", "height_bias_m", "height_mae_m", "height_p95_abs_m",
                "height_max_abs_m", "slope_error_deg", "steep", "support_distance_m"):
        assert key in result, key
    assert result["height_rmse_m"] < 0.05
    assert result["steep"]["cells"] > 0 and result["steep"]["slope_rmse_deg"] is not None
    assert (out / "error_map_scan.png").stat().st_size > 0
    assert "truth slope > 15°" in (out / "terrain.md").read_text()


def test_eval_terrain_command_usage_errors(tmp_path, capsys):
    cloud = _write_scan(tmp_path)
    tif = write_geotiff(tmp_path / "truth.tif", truth_heights())
    far = write_geotiff(tmp_path / "far.tif", truth_heights(), origin=(X0 + 500, Y0))
    plain = write_geotiff(tmp_path / "plain.tif", truth_heights(), georef=False)
    bad_pose = tmp_path / "bad_pose.txt"
    bad_pose.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    pose = ["--pose", str(tmp_path / "pose.txt")]

    def run(*argv):
        code = _cli(["eval", "terrain", *argv])
        return code, capsys.readouterr().err

    code, err = run(str(cloud), "--truth", str(far), *pose)
    assert code == 2 and "--truth" in err and "do not overlap" in err
    assert "x 1500.00 to 1560.00" in err and "x 1005.00 to 1055.00" in err
    code, err = run(str(cloud), "--truth", str(tif), "--pose", str(bad_pose))
    assert code == 2 and "--pose" in err and "4x4" in err
    code, err = run(str(cloud), "--truth", str(plain), *pose)
    assert code == 2 and "--truth-origin X Y --truth-cell-size M" in err
    code, err = run(str(cloud), "--truth", str(plain), *pose, "--truth-origin", str(X0), str(Y0))
    assert code == 2 and "--truth-cell-size" in err
    code, err = run(str(tmp_path / "missing.ply"), "--truth", str(tif))
    assert code == 2 and "CLOUD" in err and "no such file" in err
    code, err = run("synthetic:flat", "--pose", str(bad_pose))
    assert code == 2 and "applies only with --truth" in err
    # a plain raster placed by the options works
    code, _ = run(str(cloud), "--truth", str(plain), *pose, "--truth-origin", str(X0), str(Y0),
                  "--truth-cell-size", "1")
    assert code == 0


# ---------------------------------------------------------------------------------------------
# real data: a tilted scan sampled from ../shared/data/dem_1m/dem.tif


@pytest.mark.realdata
def test_a_tilted_scan_of_the_real_dem(tmp_path):
    root = data_root()
    dem_path = None if root is None else root / "dem_1m" / "dem.tif"
    if dem_path is None or not dem_path.is_file():
        pytest.skip("../shared/data/dem_1m/dem.tif is absent (set O3D_TERRAIN_DATA)")
    from scipy.ndimage import map_coordinates

    raster = read_raster(dem_path)
    rng = np.random.default_rng(6)
    n = 4 * 40 * 40  # 4 points/m² over a 40 m window, rows/cols 100-140
    r, c = rng.uniform(100, 140, n), rng.uniform(100, 140, n)
    z = map_coordinates(raster.heights, [r, c], order=1) + rng.normal(0, 0.02, n)
    x = raster.origin[0] + (c + 0.5) * raster.cell_size
    y = raster.origin[1] - (r + 0.5) * raster.cell_size
    a = math.radians(10.0)
    pose = np.eye(4)  # sensor -> map: rolled 10° about x, 1.8 m above the window's centre
    pose[:3, :3] = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    pose[:3, 3] = [x.mean(), y.mean(), z.mean() + 1.8]
    sensor = (np.column_stack([x, y, z]) - pose[:3, 3]) @ pose[:3, :3]
    report = evaluate_terrain_against_raster(sensor, raster, pose=pose)
    s = report.results[0].stats
    assert s["cells"] > 1400
    assert s["height_rmse_m"] < 0.1 and abs(s["height_bias_m"]) < 0.03
