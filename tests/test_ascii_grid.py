"""ESRI ASCII grids as truth rasters (read_raster / read_ascii_grid; no extra needed)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.evaluation import evaluate_terrain_against_raster, read_raster

X_LL, Y_LL = 500.0, 3000.0  # lower-left corner


def _terrain(x, y):
    return 50.0 + 0.2 * (x - X_LL) + 2.0 * np.sin((y - Y_LL) / 9.0)


def _heights(nrows=40, ncols=50, cell=1.0):
    xc = X_LL + (np.arange(ncols) + 0.5) * cell
    yc = Y_LL + nrows * cell - (np.arange(nrows) + 0.5) * cell  # row 0 = north
    return _terrain(*np.meshgrid(xc, yc))


def _write(path, heights, *, cell=1.0, centre=False, nodata=-9999.0, extra=""):
    nrows, ncols = heights.shape
    if centre:
        corner = f"xllcenter {X_LL + cell / 2}\nyllcenter {Y_LL + cell / 2}\n"
    else:
        corner = f"XLLCORNER {X_LL}\nYLLCORNER {Y_LL}\n"
    rows = "\n".join(" ".join(f"{v:.4f}" for v in row) for row in heights)
    path.write_text(f"ncols {ncols}\nnrows {nrows}\n{corner}cellsize {cell}\n"
                    f"NODATA_value {nodata:g}\n{extra}{rows}\n")
    return path


@pytest.mark.parametrize("centre", [False, True])
def test_the_header_places_the_grid_and_nodata_is_not_data(tmp_path, centre):
    heights = _heights()
    heights[0, :3] = -9999.0
    raster = read_raster(_write(tmp_path / "dem.asc", heights, centre=centre))
    assert raster.origin == (X_LL, Y_LL + 40.0) and raster.cell_size == 1.0
    assert raster.extent == (X_LL, X_LL + 50.0, Y_LL, Y_LL + 40.0)
    assert int(np.isnan(raster.heights).sum()) == 3
    assert raster.heights[5, 7] == pytest.approx(_terrain(X_LL + 7.5, Y_LL + 40 - 5.5), abs=1e-4)


def test_an_exact_cloud_scores_against_the_grid(tmp_path):
    path = _write(tmp_path / "dem.asc", _heights(cell=2.0, nrows=30, ncols=30), cell=2.0)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(X_LL + 5, X_LL + 55, 8000), rng.uniform(Y_LL + 5, Y_LL + 55, 8000)
    cloud = np.column_stack([x, y, _terrain(x, y)])
    report = evaluate_terrain_against_raster(cloud, path)
    assert report.results[0].stats["height_rmse_m"] < 0.05
    shifted = evaluate_terrain_against_raster(cloud + [0.0, 0.0, 0.5], path)
    assert shifted.results[0].stats["height_bias_m"] == pytest.approx(0.5, abs=0.03)


def test_origin_and_cell_size_given_override_the_header(tmp_path):
    raster = read_raster(_write(tmp_path / "dem.asc", _heights()), origin=(0.0, 40.0),
                         cell_size=1.0)
    assert raster.extent == (0.0, 50.0, 0.0, 40.0)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("cellsize 1.0\n", ""), "lacks cellsize"),
    (lambda t: t.replace("nrows 40", "nrows 41"), "41 rows of 50"),
    (lambda t: t.replace("cellsize 1.0", "cellsize one"), "cellsize must be a number"),
    (lambda t: t.replace("cellsize 1.0", "cellsise 1.0"), "did you mean 'cellsize'"),
    (lambda t: t.replace("ncols 50", "ncols 12.5"), "positive integers"),
    (lambda t: t[:-20] + " x1 2\n", "not all numbers"),
])
def test_a_malformed_grid_names_what_is_wrong(tmp_path, edit, message):
    path = _write(tmp_path / "dem.asc", _heights())
    path.write_text(edit(path.read_text()))
    with pytest.raises(InputError, match=message):
        read_raster(path)


def test_non_square_cells_and_missing_files_are_clear_errors(tmp_path):
    path = tmp_path / "dem.asc"
    path.write_text("ncols 4\nnrows 4\nxllcorner 0\nyllcorner 0\ndx 1\ndy 2\n"
                    + "1 2 3 4\n" * 4)
    with pytest.raises(InputError, match="not square"):
        read_raster(path)
    path.write_text("ncols 4\nnrows 4\nxllcorner 0\nyllcorner 0\ndx 1\ndy 1\n" + "1 2 3 4\n" * 4)
    assert read_raster(path).cell_size == 1.0
    with pytest.raises(InputError, match="no such DEM file"):
        read_raster(tmp_path / "missing.asc")


def test_the_eval_terrain_command_reads_an_ascii_grid(tmp_path, capsys):
    from o3d_terrain.cli import main

    path = _write(tmp_path / "dem.asc", _heights())
    rng = np.random.default_rng(1)
    x, y = rng.uniform(X_LL + 3, X_LL + 47, 6000), rng.uniform(Y_LL + 3, Y_LL + 37, 6000)
    np.savetxt(tmp_path / "scan.xyz", np.column_stack([x, y, _terrain(x, y) + 0.3]),
               fmt="%.5f")
    assert main(["eval", "terrain", str(tmp_path / "scan.xyz"), "--truth", str(path),
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)["results"][0]
    assert result["height_bias_m"] == pytest.approx(0.3, abs=0.03)
