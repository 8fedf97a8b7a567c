"""WriteRaster / raster.write_terrain_raster: the terrain as a GeoTIFF DTM or slope map."""

import math

import numpy as np
import pytest
import yaml

import o3d_terrain
from o3d_terrain import InputError, parse_pipeline
from o3d_terrain.errors import ConfigError
from o3d_terrain.evaluation.terrain import read_raster
from o3d_terrain.io import NODATA, GeoKeys, write_geotiff
from o3d_terrain.raster import terrain_raster, write_terrain_raster

tifffile = pytest.importorskip("tifffile")

E0, N0 = 500000.0, 4500000.0  # a projected (UTM-like) corner


def _tags(path):
    with tifffile.TiffFile(path) as tif:
        return {tag.code: tag.value for tag in tif.pages[0].tags.values()}


def _keys(tags):
    d = tags[34735]
    return {d[i]: d[i + 3] for i in range(4, len(d), 4)}


def _hill(x, y):
    return 100.0 + 0.2 * (x - E0) + 1.5 * np.sin((y - N0) / 7.0)


@pytest.fixture
def hill_cloud():
    rng = np.random.default_rng(3)
    x = E0 + rng.uniform(0.0, 60.0, 24_000)
    y = N0 + rng.uniform(0.0, 40.0, 24_000)
    return np.column_stack([x, y, _hill(x, y) + rng.normal(0.0, 0.01, x.size)])


def test_a_dtm_reads_back_as_the_surface_at_the_cell_centres(tmp_path, hill_cloud):
    surface, inliers = o3d_terrain.segment_terrain(hill_cloud)
    path = write_terrain_raster(tmp_path / "dtm.tif", surface, cell_size=1.0,
                                support=hill_cloud[inliers], epsg=32633)
    raster = read_raster(path)  # the project's GeoTIFF reader (eval terrain --truth)
    assert raster.cell_size == 1.0
    assert raster.origin == (E0, N0 + raster.heights.shape[0])  # corners on whole metres
    rows, cols = np.indices(raster.heights.shape)
    x = raster.origin[0] + cols + 0.5
    y = raster.origin[1] - rows - 0.5
    expected = surface(x, y)
    inside = np.isfinite(expected)
    assert inside.mean() > 0.95
    np.testing.assert_allclose(raster.heights[inside], expected[inside], atol=1e-3)
    assert np.isnan(raster.heights[~inside]).all()  # centres beyond the region: no data
    # against the true terrain, away from the edges
    core = inside & (x > E0 + 3) & (x < E0 + 57) & (y > N0 + 3) & (y < N0 + 37)
    assert np.abs(raster.heights[core] - _hill(x[core], y[core])).max() < 0.05
    keys = _keys(_tags(path))
    assert keys[3072] == 32633 and keys[1024] == 1 and keys[1025] == 1  # projected, area
    assert _tags(path)[42113].strip("\x00") == f"{NODATA:g}"


def test_the_slope_layer_of_a_plane_is_its_angle(tmp_path):
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0.0, 50.0, (2, 20_000))
    cloud = np.column_stack([x, y, 0.2 * x])
    surface = o3d_terrain.fit_terrain(cloud)
    path = write_terrain_raster(tmp_path / "slope.tif", surface, cell_size=2.0, layer="slope")
    raster = read_raster(path)
    rows, cols = np.indices(raster.heights.shape)
    expected = surface.slope_deg(raster.origin[0] + (cols + 0.5) * 2.0,
                                 raster.origin[1] - (rows + 0.5) * 2.0)
    inside = np.isfinite(expected)
    np.testing.assert_allclose(raster.heights[inside], expected[inside], atol=1e-4)
    assert abs(np.nanmedian(raster.heights) - math.degrees(math.atan(0.2))) < 0.2  # degrees
    assert 34736 not in _tags(path) and _keys(_tags(path)) == {1025: 1}  # no CRS given


def test_cells_far_from_the_terrain_points_hold_no_data(hill_cloud):
    """A forward wedge of the cloud: the half of the box the cloud never saw is no data."""
    surface = o3d_terrain.fit_terrain(hill_cloud)
    wedge = hill_cloud[(hill_cloud[:, 1] - N0) < (hill_cloud[:, 0] - E0) * 40.0 / 60.0]
    values, x_min, y_min = terrain_raster(surface, cell_size=1.0, support=wedge, max_gap=5.0)
    ix, iy = np.indices(values.shape)
    u = x_min + ix + 0.5 - E0
    v = y_min + iy + 0.5 - N0
    below = v < u * 40.0 / 60.0
    beyond = v - u * 40.0 / 60.0 > 6.0 / math.cos(math.atan(40.0 / 60.0))  # > 6 m off the edge
    assert np.isfinite(values[below & (u < 59) & (v > 0.5)]).all()
    assert np.isnan(values[beyond]).all()
    everywhere, _, _ = terrain_raster(surface, cell_size=1.0, support=wedge, max_gap=None)
    assert np.isfinite(everywhere[beyond & (u < 59) & (v < 39)]).all()
    nothing, _, _ = terrain_raster(surface, cell_size=1.0, support=np.zeros((0, 3)))
    assert np.isnan(nothing).all()


def _pipeline(source, *writers):
    outputs = "".join("\n  - type: WriteRaster" + "".join(
        f"\n    {k}: {'null' if v is None else v}" for k, v in w.items()) for w in writers)
    return parse_pipeline(yaml.safe_load(f"""
source:
  type: ReadCloud
  path: {source}
stages:
  - type: GridQuantize
    cell_size: 1.0
  - type: RationalBSplineTerrain
  - type: Segmenter
outputs:{outputs}
"""))


def test_a_feet_tile_gets_its_raster_in_feet_with_its_keys(tmp_path):
    las_tiles = pytest.importorskip("las_tiles")  # needs laspy
    las_tiles.write_tile(tmp_path / "tile.las", feet=True)
    _pipeline(tmp_path / "tile.las", {"path": "dtm.tif", "cell_size": 0.9144},
              {"path": "slope.tif", "layer": "slope"}).run(output_dir=tmp_path / "out")
    raster = read_raster(tmp_path / "out" / "dtm.tif")
    assert raster.cell_size == pytest.approx(3.0)  # 0.9144 m = 3 ft
    rows, cols = np.indices(raster.heights.shape)
    x_ft = raster.origin[0] + (cols + 0.5) * 3.0
    y_ft = raster.origin[1] - (rows + 0.5) * 3.0
    x, y = (x_ft - E0) * 0.3048, (y_ft - N0) * 0.3048  # the tile's metres from its corner
    away = (x > 2) & (x < 38) & (y > 2) & (y < 38) & ~(
        (x > las_tiles.BOX[0] - 1) & (x < las_tiles.BOX[1] + 1)
        & (y > las_tiles.BOX[2] - 1) & (y < las_tiles.BOX[3] + 1))
    truth_ft = las_tiles.terrain_height(x, y) / 0.3048
    assert np.abs(raster.heights[away] - truth_ft[away]).max() < 0.15  # feet
    assert _keys(_tags(tmp_path / "out" / "dtm.tif"))[3076] == 9002  # the tile's keys copied
    slope = read_raster(tmp_path / "out" / "slope.tif")
    assert slope.cell_size == pytest.approx(1.0 / 0.3048)  # the fitted grid's 1 m cells
    assert np.nanmedian(slope.heights[1:-1, 1:-1]) < 20.0  # degrees, not scaled to feet


def test_a_tile_with_a_wkt_only_gets_it_beside_the_raster(tmp_path):
    las_tiles = pytest.importorskip("las_tiles")
    wkt = 'PROJCS["WGS 84 / UTM zone 33N",GEOGCS["WGS 84",DATUM["WGS_1984"]],UNIT["metre",1]]'
    las_tiles.write_tile(tmp_path / "tile.las", point_format=6, wkt=wkt)
    _pipeline(tmp_path / "tile.las", {"path": "dtm.tif"}).run(output_dir=tmp_path / "out")
    sidecar = tmp_path / "out" / "dtm.tif.aux.xml"
    assert wkt in sidecar.read_text()
    assert _keys(_tags(tmp_path / "out" / "dtm.tif")) == {1025: 1}
    # an EPSG code given replaces it, and a sidecar of an earlier run goes
    _pipeline(tmp_path / "tile.las", {"path": "dtm.tif", "epsg": 32633}).run(
        output_dir=tmp_path / "out")
    assert not sidecar.exists()
    assert _keys(_tags(tmp_path / "out" / "dtm.tif"))[3072] == 32633


def test_geokeys_stay_sorted_and_unique():
    keys = GeoKeys((1, 1, 0, 3, 0, 0, 0, 0, 3072, 0, 1, 2154, 1025, 0, 1, 2))
    assert keys.with_key(1025, 1).directory == (1, 1, 0, 2, 1025, 0, 1, 1, 3072, 0, 1, 2154)
    # a key whose value lies in the doubles (location 34736) is no short
    mixed = GeoKeys((1, 1, 0, 2, 3072, 0, 1, 32633, 4099, 34736, 1, 0), (0.3048,))
    assert mixed.shorts() == {3072: 32633}
    assert mixed.entries()[1] == (4099, 34736, 1, 0)


def test_what_does_not_fit_is_rejected_with_the_fix(tmp_path, hill_cloud):
    surface = o3d_terrain.fit_terrain(hill_cloud)
    with pytest.raises(InputError, match=".tif or .tiff"):
        write_terrain_raster(tmp_path / "dtm.png", surface)
    with pytest.raises(InputError, match="geographic"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, epsg=4326)
    with pytest.raises(InputError, match="projected coordinate system"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, epsg="utm33")
    with pytest.raises(InputError, match="layer must be one of"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, layer="aspect")
    with pytest.raises(InputError, match="cell_size"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, cell_size=-1.0)
    with pytest.raises(InputError, match="larger cell_size"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, cell_size=0.001)
    with pytest.raises(InputError, match="2-D array"):
        write_geotiff(tmp_path / "x.tif", np.zeros(4), 0.0, 0.0, 1.0)
    with pytest.raises(InputError, match="no such file"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, source=tmp_path / "missing.laz")
    (tmp_path / "corrupt.las").write_bytes(b"LASF" + bytes(200))
    with pytest.raises(InputError, match="corrupt.las: could not be read as LAS/LAZ"):
        write_terrain_raster(tmp_path / "dtm.tif", surface, source=tmp_path / "corrupt.las")
    assert not (tmp_path / "dtm.tif").exists()  # nothing half-written


def test_pipeline_files_check_the_raster_options():
    def parse(**options):
        text = "".join(f"\n    {k}: {v}" for k, v in options.items())
        return parse_pipeline(yaml.safe_load(
            "stages:\n  - type: GridQuantize\n  - type: RationalBSplineTerrain\n"
            f"outputs:\n  - type: WriteRaster{text}\n"))

    with pytest.raises(ConfigError, match=".tif or .tiff"):
        parse(path="dtm.asc")
    with pytest.raises(ConfigError, match="geographic"):
        parse(epsg=4326)
    with pytest.raises(ConfigError, match="layer"):
        parse(layer="aspect")
    with pytest.raises(ConfigError, match="max_gap"):
        parse(max_gap=-1)
    parse(path="slope.tif", layer="slope", cell_size=2.0, max_gap="null", epsg=32633)
