"""Surveyed ground points as the truth of eval terrain (raster_from_points, read_ground_points)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.evaluation import evaluate_terrain_against_raster, read_raster
from o3d_terrain.evaluation.terrain import raster_from_points


def _terrain(x, y):
    return 20.0 + 0.15 * x - 0.1 * y + 1.5 * np.sin(x / 7.0)


def _points(rng, n, box=(300.0, 360.0, 700.0, 750.0)):
    x, y = rng.uniform(box[0], box[1], n), rng.uniform(box[2], box[3], n)
    return np.column_stack([x, y, _terrain(x, y)])


def test_points_grid_into_cell_means_with_corners_on_the_cell_lattice():
    p = np.array([[0.2, 0.3, 1.0], [0.7, 0.8, 3.0], [2.5, 0.5, 5.0], [0.5, 2.9, 7.0],
                  [np.nan, 1.0, 1.0]])
    raster = raster_from_points(p, 1.0)
    assert raster.origin == (0.0, 3.0) and raster.heights.shape == (3, 3)
    assert raster.heights[2, 0] == 2.0  # row 2 = the southern row: mean of 1 and 3
    assert raster.heights[2, 2] == 5.0 and raster.heights[0, 0] == 7.0
    assert np.isnan(raster.heights[1, 1])
    with pytest.raises(InputError, match="at least 3"):
        raster_from_points(p[:2], 1.0)
    with pytest.raises(InputError, match="positive"):
        raster_from_points(p, 0.0)


def test_a_ground_point_file_scores_a_fit_and_a_las_keeps_its_class_2(tmp_path):
    rng = np.random.default_rng(0)
    truth = _points(rng, 40_000)
    np.savetxt(tmp_path / "ground.xyz", truth, fmt="%.4f")
    cloud = _points(rng, 12_000, box=(305.0, 355.0, 705.0, 745.0))
    raster = read_raster(tmp_path / "ground.xyz", cell_size=2.0)
    assert raster.cell_size == 2.0 and raster.name == "ground.xyz"
    report = evaluate_terrain_against_raster(cloud + [0, 0, 0.4], raster)
    assert report.results[0].stats["height_bias_m"] == pytest.approx(0.4, abs=0.05)
    laspy = pytest.importorskip("laspy", reason="the las extra writes the LAS file")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([300.0, 700.0, 0.0])
    las = laspy.LasData(header)
    tree = truth[:5000] + [0, 0, 8.0]  # vegetation the survey classified 5
    everything = np.vstack([truth, tree])
    las.x, las.y, las.z = everything[:, 0], everything[:, 1], everything[:, 2]
    las.classification = np.r_[np.full(len(truth), 2), np.full(len(tree), 5)].astype(np.uint8)
    las.write(tmp_path / "survey.las")
    raster = read_raster(tmp_path / "survey.las")
    assert raster.name == "survey.las (class 2)"
    report = evaluate_terrain_against_raster(cloud, raster)
    assert abs(report.results[0].stats["height_bias_m"]) < 0.05


def test_the_command_takes_ground_points_and_a_cell_size_alone(tmp_path, capsys):
    from o3d_terrain.cli import main

    rng = np.random.default_rng(2)
    np.savetxt(tmp_path / "ground.xyz", _points(rng, 30_000), fmt="%.4f")
    np.savetxt(tmp_path / "scan.xyz", _points(rng, 8_000, box=(310.0, 350.0, 710.0, 740.0))
               - [0, 0, 0.25], fmt="%.4f")
    assert main(["eval", "terrain", str(tmp_path / "scan.xyz"), "--truth",
                 str(tmp_path / "ground.xyz"), "--truth-cell-size", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)["results"][0]
    assert result["height_bias_m"] == pytest.approx(-0.25, abs=0.05)
    # a raster still needs both
    (tmp_path / "dem.tif").write_bytes(b"")
    assert main(["eval", "terrain", str(tmp_path / "scan.xyz"), "--truth",
                 str(tmp_path / "dem.tif"), "--truth-cell-size", "2"]) == 2
    assert "--truth-origin" in capsys.readouterr().err
