"""WriteLas / io.write_las: a LAS/LAZ tile back with its ground in ASPRS class 2."""

import numpy as np
import pytest
import yaml

from o3d_terrain import InputError, load_pipeline, parse_pipeline
from o3d_terrain.errors import ConfigError
from o3d_terrain.io import KEEP_CLASS, LasSource, write_las
from o3d_terrain.segment import TerrainLabel

laspy = pytest.importorskip("laspy")

from las_tiles import write_tile as _tile  # noqa: E402

def _pipeline(source=None, **writer):
    options = "".join(f"\n    {k}: {'null' if v is None else v}" for k, v in writer.items())
    head = f"source:\n  type: ReadCloud\n  path: {source}\n" if source else ""
    return parse_pipeline(yaml.safe_load(head + f"""
stages:
  - type: GridQuantize
    cell_size: 1.0
  - type: RationalBSplineTerrain
  - type: Segmenter
outputs:
  - type: WriteLas
    path: out.laz{options}
  - type: WriteAttribute
    path: labels.npy
"""))


def _run(tmp_path, source, **writer):
    _pipeline(source, **writer).run(output_dir=tmp_path / "out")
    return laspy.read(str(tmp_path / "out" / "out.laz")), np.load(tmp_path / "out" / "labels.npy")


@pytest.mark.parametrize("feet", [False, True])
def test_the_copy_keeps_every_record_and_sets_ground_from_the_labels(tmp_path, feet):
    roof = _tile(tmp_path / "tile.las", feet=feet)
    src = laspy.read(str(tmp_path / "tile.las"))
    out, labels = _run(tmp_path, tmp_path / "tile.las")
    # every record and dimension as read, the header's scale, offset and unit keys
    assert len(out.points) == len(src.points)
    for name in ("X", "Y", "Z", "gps_time", "intensity", "return_number"):
        np.testing.assert_array_equal(out[name], src[name])
    np.testing.assert_array_equal(out.header.scales, src.header.scales)
    np.testing.assert_array_equal(out.header.offsets, src.header.offsets)
    assert [type(v).__name__ for v in out.header.vlrs if "GeoKey" in type(v).__name__] == \
        (["GeoKeyDirectoryVlr"] if feet else [])
    # the classes follow the Segmenter's labels: 2 terrain, 1 obstacle, 7 below
    classes = np.asarray(out.classification)
    np.testing.assert_array_equal(classes == 2, labels == TerrainLabel.TERRAIN)
    np.testing.assert_array_equal(classes == 1, labels == TerrainLabel.OBSTACLE)
    np.testing.assert_array_equal(classes == 7, labels == TerrainLabel.BELOW_TERRAIN)
    assert (classes[roof] == 1).mean() > 0.99 and (classes[~roof] == 2).mean() > 0.98
    # the height above the terrain in the file's vertical units: the roof 3 m up
    height = np.asarray(out["HeightAboveGround"], dtype=np.float64)
    unit = 0.3048 if feet else 1.0
    assert np.median(height[roof]) * unit == pytest.approx(3.0, abs=0.1)
    assert np.median(np.abs(height[~roof])) * unit < 0.05


def test_null_classes_keep_the_files_own_but_never_its_ground(tmp_path):
    roof = _tile(tmp_path / "tile.las")
    out, labels = _run(tmp_path, tmp_path / "tile.las", obstacle_class=None,
                       height_above_ground="false")
    classes = np.asarray(out.classification)
    obstacle = labels == TerrainLabel.OBSTACLE
    assert (classes[obstacle & roof] == 6).all()  # the file's building class stays
    assert (classes[obstacle & ~roof] == 1).all()  # the file's ground the Segmenter denies
    assert "HeightAboveGround" not in out.point_format.extra_dimension_names


def test_the_python_example_of_write_las(tmp_path):
    import o3d_terrain

    roof = _tile(tmp_path / "tile.laz", feet=True)
    cloud = o3d_terrain.read_cloud(tmp_path / "tile.laz")
    surface, inliers = o3d_terrain.segment_terrain(cloud)
    classes = np.full(len(cloud.point.positions), 1)
    classes[inliers] = 2
    heights = surface.heights_above(cloud.point.positions.numpy())
    write_las(tmp_path / "ground.laz", classes, source=tmp_path / "tile.laz",
              heights_above_ground=heights)
    out = laspy.read(str(tmp_path / "ground.laz"))
    assert (np.asarray(out.classification)[roof] == 1).mean() > 0.99
    assert np.median(np.asarray(out["HeightAboveGround"])[roof]) * 0.3048 == \
        pytest.approx(3.0, abs=0.1)  # metres in, feet in the feet tile


def test_a_cloud_not_read_from_a_las_file_gets_a_new_one(tmp_path, rng):
    pts = np.c_[rng.uniform(0, 30, 6000), rng.uniform(0, 30, 6000), rng.normal(0, 0.02, 6000)]
    pts[:300, 2] += 2.0
    pts[:, :2] += (300000.0, 5000000.0)
    result = _pipeline().run(pts, output_dir=tmp_path / "out")
    out = laspy.read(str(tmp_path / "out" / "out.laz"))
    labels = result.frame.attribute("labels")
    assert out.header.version.minor == 4 and out.point_format.id == 6
    np.testing.assert_allclose(np.c_[out.x, out.y, out.z], pts, atol=0.0006)
    np.testing.assert_array_equal(np.asarray(out.classification) == 2,
                                  labels == TerrainLabel.TERRAIN)
    assert (np.asarray(out.classification)[:300] == 1).all()


def test_write_las_rejects_what_does_not_fit(tmp_path):
    _tile(tmp_path / "tile.las", point_format=1)
    n = len(laspy.read(str(tmp_path / "tile.las")).points)
    source = LasSource(tmp_path / "tile.las", "metres", n)
    with pytest.raises(InputError, match="added or dropped points"):
        write_las(tmp_path / "a.las", np.full(n - 1, 2), source=LasSource(
            tmp_path / "tile.las", "metres", n - 1))
    with pytest.raises(InputError, match="classes 0-31"):  # point format 1: five bits
        write_las(tmp_path / "a.las", np.full(n, 40), source=source)
    with pytest.raises(InputError, match="0-255"):
        write_las(tmp_path / "a.las", np.full(n, 300), source=source)
    with pytest.raises(InputError, match=".las or .laz"):
        write_las(tmp_path / "a.ply", np.full(n, 2), source=source)
    with pytest.raises(InputError, match="positions"):
        write_las(tmp_path / "a.las", np.full(3, 2))
    with pytest.raises(InputError, match="non-finite"):
        write_las(tmp_path / "a.las", np.full(2, 2),
                  positions=np.array([[0, 0, 0], [np.nan, 0, 0]]))
    # a path for the source: the points must still match
    with pytest.raises(InputError, match="added or dropped points"):
        write_las(tmp_path / "a.las", np.full(n + 1, 2), source=str(tmp_path / "tile.las"))
    # KEEP_CLASS keeps the file's classes; nothing else changes
    write_las(tmp_path / "kept.las", np.full(n, KEEP_CLASS), source=source)
    np.testing.assert_array_equal(laspy.read(str(tmp_path / "kept.las")).classification,
                                  laspy.read(str(tmp_path / "tile.las")).classification)


def _outputs(text):
    return parse_pipeline(yaml.safe_load("stages:\n  - type: GridQuantize\noutputs:\n  - "
                                          + text))


def test_pipeline_files_say_which_writer_writes_las(tmp_path):
    with pytest.raises(ConfigError, match="WriteLas"):
        _outputs("type: WriteCloud\n    path: a.laz\n")
    with pytest.raises(ConfigError, match=".las or .laz"):
        _outputs("type: WriteLas\n    path: a.ply\n")
    with pytest.raises(ConfigError, match="ground_class"):
        _outputs("type: WriteLas\n    ground_class: 300\n")
    pipeline = _outputs("type: WriteLas\n")
    with pytest.raises(Exception, match="Segmenter"):
        pipeline.run(np.zeros((10, 3)), output_dir=tmp_path)


def test_the_las_pipeline_writes_the_classified_tile(tmp_path):
    _tile(tmp_path / "tile.laz")
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pipeline = load_pipeline(root / "pipelines" / "las_terrain.yaml",
                             input_path=tmp_path / "tile.laz")
    result = pipeline.run(output_dir=tmp_path / "out")
    assert tmp_path / "out" / "classified.laz" in result.written
    out = laspy.read(str(tmp_path / "out" / "classified.laz"))
    assert len(out.points) == 12_800 and (np.asarray(out.classification) == 2).mean() > 0.9
    assert {tmp_path / "out" / "dtm.tif", tmp_path / "out" / "slope.tif"} <= set(result.written)
