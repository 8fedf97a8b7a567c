"""Evaluation: metrics on hand-made cases, dataset readers on tiny generated files, batch
robustness (a bad frame is reported and skipped), the eval commands, real-data checks."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.evaluation import datasets as ds
from o3d_terrain.evaluation.metrics import (
    SegmentationCounts,
    height_rmse,
    segmentation_counts,
    slope_deg_from_gradient,
    slope_error_deg,
)
from o3d_terrain.evaluation.segmentation import evaluate_segmentation
from o3d_terrain.evaluation.terrain import (
    compare_surface,
    dem_slope_deg,
    evaluate_dem_terrain,
    write_error_map,
)

DATA = Path(os.environ.get("O3D_TERRAIN_DATA", Path(__file__).resolve().parents[1].parent
                           / "shared" / "data"))


# ---------------------------------------------------------------------------------------------
# metrics


def test_counts_on_a_hand_made_case():
    truth = np.array([1, 1, 1, 0, 0, 0, 1, 0], bool)
    pred = np.array([1, 1, 0, 1, 0, 0, 1, 1], bool)
    scored = np.array([1, 1, 1, 1, 1, 1, 0, 0], bool)  # the last two do not count
    obstacle = np.array([0, 0, 0, 1, 1, 0, 0, 1], bool)
    c = segmentation_counts(pred, truth, scored=scored, obstacle=obstacle)
    assert (c.true_positive, c.false_positive, c.false_negative, c.true_negative) == (2, 1, 1, 2)
    assert c.precision == pytest.approx(2 / 3)
    assert c.recall == pytest.approx(2 / 3)
    assert c.f1 == pytest.approx(2 / 3)
    assert c.accuracy == pytest.approx(4 / 6)
    # obstacles scored: points 3 (called ground) and 4 (not): half detected
    assert (c.obstacle_points, c.obstacle_detected) == (2, 1)
    assert c.obstacle_recall == pytest.approx(0.5)


def test_perfect_and_empty_classifications():
    truth = np.array([True, False, True])
    perfect = segmentation_counts(truth.copy(), truth)
    assert perfect.precision == perfect.recall == perfect.f1 == 1.0
    nothing = segmentation_counts(np.zeros(3, bool), truth)
    assert math.isnan(nothing.precision) and nothing.recall == 0.0 and nothing.f1 == 0.0
    assert math.isnan(segmentation_counts(truth, truth).obstacle_recall)  # no obstacles


def test_f1_is_the_harmonic_mean_and_counts_add():
    rng = np.random.default_rng(1)
    truth, pred = rng.random(500) < 0.6, rng.random(500) < 0.5
    c = segmentation_counts(pred, truth)
    assert c.f1 == pytest.approx(2 * c.precision * c.recall / (c.precision + c.recall))
    a = segmentation_counts(pred[:200], truth[:200])
    b = segmentation_counts(pred[200:], truth[200:])
    assert a + b == c
    assert isinstance(a + b, SegmentationCounts)


def test_masks_are_checked():
    with pytest.raises(InputError, match="must be bool"):
        segmentation_counts(np.array([0, 1]), np.array([True, False]))
    with pytest.raises(InputError, match=r"must be \(2,\)"):
        segmentation_counts(np.array([True]), np.array([True, False]))


def test_height_rmse_and_slope_errors():
    assert height_rmse(np.array([1.0, 2.0, np.nan]), np.array([0.0, 0.0, 5.0])) == pytest.approx(
        math.sqrt((1 + 4) / 2))
    assert slope_deg_from_gradient(np.array([0.2]), np.array([0.0]))[0] == pytest.approx(
        math.degrees(math.atan(0.2)))
    assert slope_deg_from_gradient(np.array([1.0]), np.array([1.0]))[0] == pytest.approx(
        math.degrees(math.atan(math.sqrt(2))))
    e = slope_error_deg(np.array([10.0, 12.0, 9.0]), np.array([10.0, 10.0, 10.0]))
    assert e["mean_abs"] == pytest.approx(1.0) and e["max_abs"] == pytest.approx(2.0)
    assert e["rmse"] == pytest.approx(math.sqrt(5 / 3))


# ---------------------------------------------------------------------------------------------
# dataset readers on tiny generated files


def _fake_kitti(folder: Path, frames: int = 2, points: int = 50, bad_last: bool = False):
    rng = np.random.default_rng(0)
    (folder / "velodyne").mkdir(parents=True)
    (folder / "labels").mkdir()
    for i in range(frames):
        xyz = rng.uniform(-10, 10, (points, 4)).astype(np.float32)
        labels = np.array([40, 72, 10, 70, 0, 1, 48, 50] * (points // 8 + 1), np.uint32)[:points]
        labels |= np.uint32(7 << 16)  # an instance id in the upper 16 bits
        xyz.tofile(folder / "velodyne" / f"{i:06d}.bin")
        if bad_last and i == frames - 1:
            labels = labels[:-3]  # wrong length
        labels.tofile(folder / "labels" / f"{i:06d}.label")


def test_semantic_kitti_reader(tmp_path):
    _fake_kitti(tmp_path, frames=2, points=16)
    frames, failures = ds.iter_frames(ds.open_dataset(tmp_path))
    assert not failures and [f.name for f in frames] == ["000000", "000001"]
    f = frames[0]
    expected_ground = np.isin([40, 72, 10, 70, 0, 1, 48, 50] * 2, ds.SEMANTIC_KITTI_GROUND)
    assert np.array_equal(f.is_ground, expected_ground)
    assert np.array_equal(f.scored, ~np.isin([40, 72, 10, 70, 0, 1, 48, 50] * 2, [0, 1]))
    assert np.array_equal(f.obstacle, np.isin([40, 72, 10, 70, 0, 1, 48, 50] * 2, [10, 50]))
    assert f.positions.dtype == np.float64 and f.positions.shape == (16, 3)


def test_a_bad_frame_is_reported_and_skipped(tmp_path):
    _fake_kitti(tmp_path, frames=3, points=16, bad_last=True)

    def everything_is_ground(positions):
        return np.ones(len(positions), bool)

    report = evaluate_segmentation(ds.open_dataset(tmp_path), everything_is_ground)
    assert [r.frame for r in report.frames] == ["000000", "000001"]
    assert len(report.failures) == 1 and report.failures[0].name == "000002"
    assert "labels" in report.failures[0].reason
    assert "skipped `000002`" in report.to_markdown()
    assert json.loads(report.to_json())["failures"][0]["name"] == "000002"
    # everything called ground: recall 1, precision = ground share of the scored points
    assert report.total.recall == 1.0
    assert report.total.precision == pytest.approx(3 / 6)  # 40, 72, 48 of 40, 72, 10, 70, 48, 50


def test_a_failing_method_is_reported_per_frame(tmp_path):
    _fake_kitti(tmp_path, frames=2, points=16)
    calls = []

    def flaky(positions):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("solver diverged")
        return np.zeros(len(positions), bool)

    report = evaluate_segmentation(ds.open_dataset(tmp_path), flaky)
    assert len(report.frames) == 1 and "solver diverged" in report.failures[0].reason

    def wrong_shape(positions):
        return np.zeros(3, bool)

    report = evaluate_segmentation(ds.open_dataset(tmp_path), wrong_shape)
    assert not report.frames and "must return" in report.failures[0].reason


def _tiny_las(path: Path, classes, *, feet: bool = False):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500000.0, 4000000.0, 0.0])
    if feet:
        from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

        vlr = GeoKeyDirectoryVlr()
        vlr.geo_keys_header = GeoKeyEntryStruct(1, 1, 0, 1)
        vlr.geo_keys = [GeoKeyEntryStruct(3076, 0, 1, 9002)]  # ProjLinearUnits: foot
        header.vlrs.append(vlr)
    las = laspy.LasData(header)
    n = len(classes)
    las.x = 500000.0 + np.arange(n)
    las.y = 4000000.0 + np.arange(n) * 2
    las.z = np.full(n, 100.0)
    las.classification = np.asarray(classes, np.uint8)
    las.write(str(path))


def test_las_reader_classes_and_metres(tmp_path):
    _tiny_las(tmp_path / "metres.las", [2, 2, 1, 6, 7, 0, 5, 2])
    frame = ds.read_las_frame(tmp_path / "metres.las")
    assert np.array_equal(frame.is_ground, [1, 1, 0, 0, 0, 0, 0, 1])
    assert np.array_equal(frame.scored, [1, 1, 1, 1, 0, 0, 1, 1])  # 7 noise, 0 never classified
    assert np.array_equal(frame.obstacle, [0, 0, 0, 1, 0, 0, 1, 0])
    assert frame.metres_per_unit == 1.0 and frame.kind == "aerial"
    assert frame.positions[0, 0] == pytest.approx(500000.0)


def test_las_in_feet_is_converted(tmp_path):
    _tiny_las(tmp_path / "feet.las", [2, 1, 2], feet=True)
    frame = ds.read_las_frame(tmp_path / "feet.las")
    assert frame.metres_per_unit == pytest.approx(0.3048)
    assert frame.positions[1, 0] - frame.positions[0, 0] == pytest.approx(0.3048)
    assert frame.positions[0, 2] == pytest.approx(100.0 * 0.3048)
    assert any("feet" in n for n in frame.notes)


def test_las_folder_keeps_going_past_a_corrupt_file(tmp_path):
    _tiny_las(tmp_path / "a.las", [2, 1, 2, 2])
    (tmp_path / "b.las").write_bytes(b"not a las file at all")
    frames, failures = ds.iter_frames(ds.open_dataset(tmp_path))
    assert [f.name for f in frames] == ["a.las"]
    assert failures[0].name == "b.las" and "b.las" in failures[0].reason


def _fake_rellis(folder: Path, ids, frames: int = 1):
    """A sequence folder in RELLIS-3D's layout: Ouster scans in the KITTI .bin format beside
    SemanticKITTI-format labels in its own folder."""
    scans = folder / "os1_cloud_node_kitti_bin"
    labels = folder / "os1_cloud_node_semantickitti_label_id"
    scans.mkdir(parents=True)
    labels.mkdir()
    for i in range(frames):
        np.random.default_rng(i).uniform(-5, 5, (len(ids), 4)).astype(np.float32).tofile(
            scans / f"{i:06d}.bin")
        np.asarray(ids, np.uint32).tofile(labels / f"{i:06d}.label")


RELLIS_IDS = [1, 3, 10, 23, 31, 33, 0, 7, 4, 8, 17, 19, 6, 34]


def test_rellis_layout_is_read_with_its_label_set(tmp_path):
    _fake_rellis(tmp_path / "00000", RELLIS_IDS)
    frame, = ds.open_dataset(tmp_path / "00000")
    # dirt, grass, asphalt, concrete, puddle, mud are ground; void and sky not scored; tree,
    # vehicle, person obstacles; bush, water, rubble neither ground nor obstacle
    assert np.array_equal(frame.is_ground, [1] * 6 + [0] * 8)
    assert np.array_equal(frame.scored, [1] * 6 + [0, 0] + [1] * 6)
    assert np.array_equal(frame.obstacle, [0] * 8 + [1, 1, 1, 0, 0, 0])
    # the SemanticKITTI set on the same ids finds no ground, and says so
    frame, = ds.open_dataset(tmp_path / "00000", labels="semantickitti")
    assert not frame.is_ground.any() and "right label set" in frame.notes[0]


def test_a_folder_of_sequences_reads_each_with_a_prefix(tmp_path):
    _fake_rellis(tmp_path / "00001", RELLIS_IDS, frames=2)
    _fake_rellis(tmp_path / "00000", RELLIS_IDS, frames=3)
    (tmp_path / "notes").mkdir()  # not a sequence folder: passed over
    frames, failures = ds.iter_frames(ds.open_dataset(tmp_path, limit=2))
    assert not failures
    assert [f.name for f in frames] == ["00000/000000", "00000/000001", "00001/000000",
                                        "00001/000001"]


def test_label_sets_are_validated():
    with pytest.raises(InputError, match=r"\[3\] are both ground and ignored"):
        ds.LabelSet("x", (1, 3), (3,))
    with pytest.raises(InputError, match="non-negative integers"):
        ds.LabelSet("x", (-1,))
    with pytest.raises(InputError, match="no ground label"):
        ds.LabelSet("x", ())
    with pytest.raises(InputError, match="did you mean 'rellis3d'"):
        ds.label_set("rellis")
    assert ds.label_set("RELLIS-3D") is ds.LABEL_SETS["rellis3d"]
    changed = ds.LABEL_SETS["asprs"].with_ids(ground=(2, 8))
    assert changed.ground == (2, 8) and changed.ignored == ds.LAS_IGNORED
    with pytest.raises(InputError, match="is not one of"):  # before any frame is read
        ds.open_dataset(Path("."), labels="kitti")


def test_las_classes_with_another_label_set(tmp_path):
    _tiny_las(tmp_path / "a.las", [2, 8, 1, 6, 9])
    frame = ds.read_las_frame(tmp_path / "a.las",
                              labels=ds.LABEL_SETS["asprs"].with_ids(ground=(2, 8, 9)))
    assert np.array_equal(frame.is_ground, [1, 1, 0, 0, 1])
    assert np.array_equal(frame.obstacle, [0, 0, 0, 1, 0])


def _labelled_ply(path: Path, ids, field: str = "label", dtype=np.int32):
    import open3d as o3d

    rng = np.random.default_rng(len(ids))
    cloud = o3d.t.geometry.PointCloud()
    cloud.point.positions = o3d.core.Tensor(rng.uniform(-5, 5, (len(ids), 3)).astype(np.float32))
    cloud.point[field] = o3d.core.Tensor(np.asarray(ids, dtype)[:, None])
    o3d.t.io.write_point_cloud(str(path), cloud)


def test_labelled_ply_and_pcd_clouds(tmp_path):
    ids = [1, 3, 0, 4, 19, 10]
    _labelled_ply(tmp_path / "a.ply", ids)
    _labelled_ply(tmp_path / "b.pcd", ids, field="scalar_Classification", dtype=np.float32)
    frames, failures = ds.iter_frames(ds.open_dataset(tmp_path, labels="rellis3d"))
    assert not failures and [f.name for f in frames] == ["a.ply", "b.pcd"]
    for frame in frames:
        assert np.array_equal(frame.is_ground, [1, 1, 0, 0, 0, 1])
        assert np.array_equal(frame.scored, [1, 1, 0, 1, 1, 1])
        assert np.array_equal(frame.obstacle, [0, 0, 0, 1, 0, 0])
    assert "scalar_Classification" in frames[1].notes[0]
    # no ontology in the file: the caller names one
    with pytest.raises(InputError, match="--ground-labels"):
        ds.open_dataset(tmp_path / "a.ply")
    frame, = ds.open_dataset(tmp_path / "a.ply", labels=ds.LabelSet("x", (0,)))
    assert np.array_equal(frame.is_ground, [0, 0, 1, 0, 0, 0])
    # a misspelt attribute, non-integer labels, a file without labels: reported, not raised
    bad, = ds.open_dataset(tmp_path / "a.ply", labels="rellis3d", label_field="lable")
    assert isinstance(bad, ds.FrameFailure) and "did you mean 'label'" in bad.reason
    _labelled_ply(tmp_path / "c.ply", [0.5, 1.0, 2.0], dtype=np.float32)
    bad, = ds.open_dataset(tmp_path / "c.ply", labels="rellis3d")
    assert "non-integer" in bad.reason
    _labelled_ply(tmp_path / "d.ply", [1, 2, 3], field="intensity")
    bad, = ds.open_dataset(tmp_path / "d.ply", labels="rellis3d")
    assert "no label attribute" in bad.reason and "intensity" in bad.reason


def test_eval_segmentation_on_labelled_ply(tmp_path, capsys):
    pytest.importorskip("o3d_terrain.api")
    _labelled_ply(tmp_path / "scan.ply", [1, 3, 0, 4, 19, 10] * 20)
    assert _cli(["eval", "segmentation", str(tmp_path / "scan.ply"), "-m", "ransac_plane",
                 "--json", "--ground-labels", "1,3,10", "--ignore-labels", "0"]) == 0
    frame = json.loads(capsys.readouterr().out)[0]["frames"][0]
    assert frame["true_positive"] + frame["false_negative"] == 60
    assert _cli(["eval", "segmentation", str(tmp_path / "scan.ply"), "-m", "ransac_plane"]) == 2
    assert "--labels: " in capsys.readouterr().err


def test_unknown_sources_name_the_fix(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        ds.open_dataset(tmp_path / "missing")
    (tmp_path / "x.txt").write_text("1 2 3")
    with pytest.raises(InputError, match="SemanticKITTI"):
        ds.open_dataset(tmp_path / "x.txt")


def test_synthetic_frames_have_truth():
    pytest.importorskip("o3d_terrain.synthetic")
    frames, failures = ds.iter_frames(ds.synthetic_frames(["flat"], seed=0))
    assert not failures
    f = frames[0]
    assert f.obstacle is not None and np.array_equal(f.is_ground, ~f.obstacle)
    terrain = f.positions[f.is_ground & f.scored]
    # the exact terrain agrees with the terrain points to the range noise
    z = f.terrain(terrain[:, 0], terrain[:, 1])
    assert np.nanmedian(np.abs(z - terrain[:, 2])) < 0.05
    bad = list(ds.synthetic_frames(["no_such_scene"]))
    assert isinstance(bad[0], ds.FrameFailure)
    # the forward-looking solid-state lidar is a vehicle lidar; a misspelt sensor is named
    solid = next(ds.open_dataset("synthetic:flat:solid_state"))
    assert solid.name == "flat-solid_state" and solid.kind == "vehicle_lidar"
    assert solid.positions[:, 0].min() > 0  # everything ahead of the sensor
    with pytest.raises(InputError, match="did you mean 'solid_state'"):
        ds.open_dataset("synthetic:flat:solidstate")


# ---------------------------------------------------------------------------------------------
# terrain evaluation


class _Plane:
    """z = a x + b y + c with its exact slope."""

    def __init__(self, a, b, c=0.0):
        self.a, self.b, self.c = a, b, c

    def __call__(self, x, y):
        return self.a * np.asarray(x) + self.b * np.asarray(y) + self.c

    def slope_deg(self, x, y):
        return np.full(np.shape(x), math.degrees(math.atan(math.hypot(self.a, self.b))))


def test_compare_surface_oracle():
    x, y = np.meshgrid(np.arange(5.0), np.arange(4.0), indexing="ij")
    truth = 0.2 * x
    slope = np.full(x.shape, math.degrees(math.atan(0.2)))
    exact = compare_surface("plane", _Plane(0.2, 0.0), x, y, truth, slope, points=1, seconds=0)
    assert exact.height_rmse == pytest.approx(0.0, abs=1e-12)
    assert exact.slope["max_abs"] == pytest.approx(0.0, abs=1e-9)
    shifted = compare_surface("shift", _Plane(0.2, 0.0, 0.1), x, y, truth, slope, points=1,
                              seconds=0)
    assert shifted.height_rmse == pytest.approx(0.1) and shifted.height_bias == pytest.approx(0.1)


def test_dem_slope_of_a_plane():
    rows, cols = np.mgrid[0:20, 0:30].astype(float)
    dem = 0.1 * cols + 0.3 * rows
    assert np.allclose(dem_slope_deg(dem, 1.0), math.degrees(math.atan(math.hypot(0.1, 0.3))))
    assert np.allclose(dem_slope_deg(dem * 2, 2.0), math.degrees(math.atan(math.hypot(0.1, 0.3))))


def test_dem_evaluation_with_an_exact_fitter(tmp_path):
    cv2 = pytest.importorskip("cv2")
    rows, cols = np.mgrid[0:40, 0:40].astype(np.float32)
    dem = (100 + 0.05 * cols - 0.1 * rows).astype(np.float32)
    path = tmp_path / "dem.tif"
    assert cv2.imwrite(str(path), dem)

    def plane_fitter(positions):  # least-squares plane: exact on a planar DEM without noise
        a = np.column_stack([positions[:, 0], positions[:, 1], np.ones(len(positions))])
        coef = np.linalg.lstsq(a, positions[:, 2], rcond=None)[0]
        return _Plane(*coef)

    report = evaluate_dem_terrain(path, plane_fitter, window=20, max_windows=None, noise=0.0)
    assert len(report.results) == 4 and not report.failures
    assert report.overall()["height_rmse_m"] < 1e-4  # float32 raster
    assert report.overall()["slope_max_abs_deg"] < 1e-3  # float32 raster
    png = write_error_map(tmp_path / "map.png", report.maps["height_error"],
                          report.maps["slope_error"], grid_is_xy=False)
    assert cv2.imread(str(png)) is not None


# ---------------------------------------------------------------------------------------------
# the eval commands


def _cli(argv):
    from o3d_terrain.cli import main

    return main(argv)


def test_eval_segmentation_command_writes_json_and_reports_bad_frames(tmp_path, capsys):
    pytest.importorskip("o3d_terrain.api")
    data = tmp_path / "seq"
    _fake_kitti(data, frames=2, points=16, bad_last=True)
    out = tmp_path / "out"
    code = _cli(["eval", "segmentation", str(data), "-m", "ransac_plane", "-o", str(out)])
    assert code == 1  # one frame failed; the others are reported
    result = json.loads((out / "segmentation.json").read_text())
    assert result[0]["method"] == "ransac_plane"
    assert len(result[0]["frames"]) == 1 and result[0]["failures"][0]["name"] == "000001"
    assert "skipped `000001`" in (out / "segmentation.md").read_text()


def test_eval_segmentation_label_options(tmp_path, capsys):
    pytest.importorskip("o3d_terrain.api")
    data = tmp_path / "seq"
    _fake_kitti(data, frames=1, points=16)
    out = tmp_path / "out"
    # RANSAC on uniform noise: whatever it calls ground, only the ground set changes between
    # the two runs, so the recall's denominator is the number of points with those ids
    assert _cli(["eval", "segmentation", str(data), "-m", "ransac_plane", "--json"]) == 0
    default = json.loads(capsys.readouterr().out)[0]["frames"][0]
    assert _cli(["eval", "segmentation", str(data), "-m", "ransac_plane", "--json",
                 "--ground-labels", "10,50", "--ignore-labels", "0,1"]) == 0
    custom = json.loads(capsys.readouterr().out)[0]["frames"][0]
    # 16 points of ids 40 72 10 70 0 1 48 50 twice: 12 scored either way
    assert default["true_positive"] + default["false_negative"] == 6  # 40, 72, 48
    assert custom["true_positive"] + custom["false_negative"] == 4  # 10, 50
    # obstacles: every scored non-ground label unless named
    assert custom["obstacle_points"] == 8
    assert _cli(["eval", "segmentation", str(data), "-m", "ransac_plane", "-o", str(out),
                 "--labels", "semantickitti", "--obstacle-labels", "70"]) == 0
    result = json.loads((out / "segmentation.json").read_text())[0]["frames"][0]
    assert result["obstacle_points"] == 2
    capsys.readouterr()
    for argv, message in (
            (["--labels", "kitti"], "is not one of semantickitti"),
            (["--ground-labels", "4O"], "'4O' is not a label id"),
            (["--ignore-labels", "0"], "give --labels NAME"),
            (["--labels", "semantickitti", "--ignore-labels", "40"], "both ground and ignored")):
        assert _cli(["eval", "segmentation", str(data), "-m", "ransac_plane", *argv]) == 2
        assert message in capsys.readouterr().err


def test_eval_segmentation_checks_option_values_before_reading(tmp_path, capsys):
    from o3d_terrain.api import check_segment_options

    check_segment_options(cell_size=0.25, distance_threshold=None, sensor_origin=[0, 0, 1.7])
    with pytest.raises(InputError, match="'cell_size' option of GridQuantize must be a float"):
        check_segment_options(cell_size=-1)
    with pytest.raises(InputError, match="did you mean 'last'"):
        check_segment_options(ground_returns="lsat")
    with pytest.raises(TypeError, match="did you mean 'cell_size'"):
        check_segment_options(cel_size=1)
    _fake_kitti(tmp_path / "seq", frames=2, points=16)
    # one error before any frame, not a frame skipped per frame
    # a bad value is bad usage (exit 2, as a misspelt name), named against --option
    assert _cli(["eval", "segmentation", str(tmp_path / "seq"), "--option", "cell_size=-1"]) == 2
    captured = capsys.readouterr()
    assert "--option: GridQuantize: The 'cell_size' option of GridQuantize must be a float > 0" \
        in captured.err
    assert "skipped" not in captured.out + captured.err
    assert "evaluating" not in captured.err


def test_eval_terrain_checks_option_values_before_fitting(capsys):
    from o3d_terrain.api import check_fit_options

    check_fit_options(cell_size=0.25, control_points=[25, 25], sensor_origin=[0, 0, 1.7])
    with pytest.raises(InputError, match="'knots' option of RationalBSplineTerrain"):
        check_fit_options(knots="adaptve")
    with pytest.raises(TypeError, match="foot_height"):
        check_fit_options(foot_height=0.3)  # a Segmenter option: not fit_terrain's
    assert _cli(["eval", "terrain", "synthetic:hills,ramp", "--option", "cell_size=-1"]) == 2
    captured = capsys.readouterr()
    assert "--option: GridQuantize: The 'cell_size' option of GridQuantize must be a float > 0" \
        in captured.err
    assert "skipped" not in captured.out + captured.err


def test_eval_segmentation_rejects_unknown_method(tmp_path, capsys):
    _fake_kitti(tmp_path / "seq", frames=1, points=16)
    assert _cli(["eval", "segmentation", str(tmp_path / "seq"), "-m", "patchwork"]) == 2
    assert "unknown method 'patchwork'" in capsys.readouterr().err


def test_missing_peer_names_the_bench_extra(monkeypatch):
    from o3d_terrain.evaluation import peers

    real = peers.importlib.util.find_spec
    monkeypatch.setattr(peers.importlib.util, "find_spec",
                        lambda name: None if name == "CSF" else real(name))
    with pytest.raises(InputError, match=r"o3d_terrain\[bench\]"):
        peers.make_peer("csf")


def _run_all():
    """benchmarks/run_all.py as a module (the benchmarks folder is not a package)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "run_all.py"
    spec = importlib.util.spec_from_file_location("run_all_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _no_results() -> dict:
    """What run_all.collect returns when nothing ran: the page's frame without a table."""
    return {"machine": {"cpu": "cpu", "cores": 2, "memory": "1 GiB", "system": "Linux",
                        "python": "3", "versions": {}},
            "date": "today", "command": "python benchmarks/run_all.py --write-docs",
            "threads": 1, "repeats": 2, "segment": {}, "stages": {}, "terrain": None}


def _check_as_recorded(run_all, tmp_path, monkeypatch, recorded, unknown, message):
    """The data set ``recorded`` (e.g. "kitti-lines:64") gives the SemanticKITTI frames as
    ``kitti`` does, and ``unknown`` fails with ``message``."""
    _fake_kitti(tmp_path / "kitti_seq00_lidar", frames=2, points=16)
    monkeypatch.setenv("O3D_TERRAIN_DATA", str(tmp_path))
    frames, _ = run_all.load_frames("kitti")
    same, failures = run_all.load_frames(recorded)
    assert not failures and all(np.array_equal(a.positions, b.positions)
                                for a, b in zip(frames, same))
    with pytest.raises(ValueError, match=message):
        run_all.load_frames(unknown)


def test_kitti_tilt_rotates_about_the_sensor_origin_and_keeps_labels(tmp_path, monkeypatch):
    run_all = _run_all()
    s10, c10 = math.sin(math.radians(10)), math.cos(math.radians(10))
    pitch = run_all.tilt_rotation(0.0, 10.0)
    # a ground point 10 m ahead of a level sensor 1.73 m up: lower by 10 sin 10° after pitching
    assert np.allclose(pitch @ [10.0, 0.0, -1.73], [10 * c10 - 1.73 * s10, 0.0,
                                                    -10 * s10 - 1.73 * c10])
    roll = run_all.tilt_rotation(10.0, 0.0)
    assert np.allclose(roll @ [0.0, 10.0, 0.0], [0.0, 10 * c10, 10 * s10])  # left side rises
    for r in (pitch, roll, run_all.tilt_rotation(5.0, 20.0)):
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    assert np.array_equal(run_all.tilt_rotation(0.0, 0.0), np.eye(3))

    _fake_kitti(tmp_path / "kitti_seq00_lidar", frames=2, points=16)
    monkeypatch.setenv("O3D_TERRAIN_DATA", str(tmp_path))
    level, _ = run_all.load_frames("kitti")
    tilted, failures = run_all.load_frames("kitti-tilt:pitch10")
    assert not failures and [f.name for f in tilted] == [f.name for f in level]
    for a, b in zip(level, tilted):
        assert np.allclose(b.positions, a.positions @ pitch.T)
        assert np.allclose(np.linalg.norm(b.positions, axis=1),
                           np.linalg.norm(a.positions, axis=1))  # distances to the origin kept
        assert not np.allclose(b.positions[:, 2], a.positions[:, 2])
        for mask in ("is_ground", "scored", "obstacle"):
            assert np.array_equal(getattr(b, mask), getattr(a, mask))
        assert b.sensor_height == a.sensor_height and b.kind == a.kind
    assert np.array_equal(run_all.load_frames("kitti-tilt:level")[0][0].positions,
                          level[0].positions)
    with pytest.raises(ValueError, match="unknown tilt 'pitch7'"):
        run_all.load_frames("kitti-tilt:pitch7")


def _patterned_frame(positions, *, obstacle=False):
    """A labelled frame of these points whose masks follow the point index (every 3rd point
    ground, every 5th unscored, with ``obstacle`` every 3rd from the second an obstacle), so a
    variant's subset of the masks can be checked point for point."""
    index = np.arange(len(positions))
    return ds.LabelledFrame("f", positions, is_ground=index % 3 == 0, scored=index % 5 != 0,
                            obstacle=index % 3 == 1 if obstacle else None)


def test_kitti_lines_keep_every_kth_scan_line_with_its_labels(tmp_path, monkeypatch):
    run_all = _run_all()
    # 4 scan lines of 90 points, each sweeping the azimuth from 0.5° to 356.5° at its own
    # elevation, stored line by line as a spinning lidar's frame is
    azimuth = np.radians(np.arange(90) * 4.0 + 0.5)
    lines = [np.stack([10 * np.cos(azimuth), 10 * np.sin(azimuth), np.full(90, -1.0 - k)], 1)
             for k in range(4)]
    positions = np.concatenate(lines)
    assert np.array_equal(run_all.scan_lines(positions), np.repeat(np.arange(4), 90))
    assert run_all.scan_lines(np.zeros((0, 3))).shape == (0,)

    # a recorded frame: every 2nd line kept, masks subset alike
    frame = _patterned_frame(positions, obstacle=True)
    half = run_all.line_frame(frame, 2)
    keep = np.repeat(np.arange(4), 90) % 2 == 0
    assert np.array_equal(half.positions, positions[keep])
    for mask in ("is_ground", "scored", "obstacle"):
        assert np.array_equal(getattr(half, mask), getattr(frame, mask)[keep])
    assert np.array_equal(run_all.line_frame(frame, 1).positions, positions)

    _check_as_recorded(run_all, tmp_path, monkeypatch, "kitti-lines:64", "kitti-lines:8",
                       "unknown line count '8'")


def test_kitti_fov_keeps_the_points_ahead_with_their_labels(tmp_path, monkeypatch):
    run_all = _run_all()
    # one ring of 72 points every 5° of azimuth from -177.5° to 177.5° (none on a boundary)
    azimuth = np.radians(np.arange(72) * 5.0 - 177.5)
    positions = np.stack([10 * np.cos(azimuth), 10 * np.sin(azimuth), np.full(72, -1.7)], 1)
    frame = _patterned_frame(positions, obstacle=True)
    for fov, half in run_all.KITTI_FOVS.items():
        crop = run_all.fov_frame(frame, half)
        keep = np.abs(np.degrees(azimuth)) <= half
        assert keep.sum() == round(72 * half / 180), fov
        assert np.array_equal(crop.positions, positions[keep])
        for mask in ("is_ground", "scored", "obstacle"):
            assert np.array_equal(getattr(crop, mask), getattr(frame, mask)[keep])
    # the camera's 90°: only points ahead (x > 0) within 45° of the x axis
    crop = run_all.fov_frame(frame, run_all.KITTI_FOVS["90"])
    assert (crop.positions[:, 0] > 0).all()
    assert (np.abs(crop.positions[:, 1]) < crop.positions[:, 0]).all()

    _check_as_recorded(run_all, tmp_path, monkeypatch, "kitti-fov:360", "kitti-fov:45",
                       "unknown field of view '45'")


def test_kitti_low_moves_points_down_and_leaves_them_unscored(tmp_path, monkeypatch):
    run_all = _run_all()
    rng = np.random.default_rng(3)
    positions = rng.uniform(-10, 10, (5000, 3))
    frame = _patterned_frame(positions)
    for name, share in run_all.KITTI_LOW.items():
        low = run_all.low_frame(frame, share)
        drop = frame.positions[:, 2] - low.positions[:, 2]
        moved = drop > 0
        assert abs(moved.mean() - share) < 0.005, name
        assert ((drop[moved] >= 0.5) & (drop[moved] <= 3.0)).all()
        assert np.array_equal(low.positions[:, :2], positions[:, :2])
        assert np.array_equal(low.scored, frame.scored & ~moved)
        assert np.array_equal(low.is_ground, frame.is_ground)
    assert np.array_equal(run_all.low_frame(frame, 0.01).positions,
                          run_all.low_frame(frame, 0.01).positions)  # seeded

    _check_as_recorded(run_all, tmp_path, monkeypatch, "kitti-low:0", "kitti-low:5",
                       "unknown share of low returns '5'")


def test_kitti_noise_adds_seeded_gaussian_noise_to_z_only(tmp_path, monkeypatch):
    run_all = _run_all()
    rng = np.random.default_rng(3)
    positions = rng.uniform(-10, 10, (20_000, 3))
    frame = _patterned_frame(positions)
    for name, sigma in run_all.KITTI_NOISE.items():
        noisy = run_all.noise_frame(frame, sigma)
        added = noisy.positions[:, 2] - positions[:, 2]
        assert abs(added.std() - sigma) < 0.02 * sigma + 1e-12, name
        assert np.array_equal(noisy.positions[:, :2], positions[:, :2])
        assert np.array_equal(noisy.scored, frame.scored)
        assert np.array_equal(noisy.is_ground, frame.is_ground)
    assert np.array_equal(run_all.noise_frame(frame, 0.05).positions,
                          run_all.noise_frame(frame, 0.05).positions)  # seeded

    _check_as_recorded(run_all, tmp_path, monkeypatch, "kitti-noise:0", "kitti-noise:4",
                       "unknown noise '4'")


@pytest.mark.parametrize("prefix, title, header, f1s, row", [
    ("kitti-lines", "SemanticKITTI frames seen by a sparser lidar",
     "| method | 64 lines (as recorded) | 32 lines | 16 lines |",
     {"64": 0.9, "32": 0.8, "16": 0.7}, "90.0 | 80.0 | 70.0"),
    ("kitti-fov", "SemanticKITTI frames cropped to a forward field of view",
     "| method | 360° (as recorded) | 180° | 90° | 60° |",
     {"360": 0.9, "180": 0.85, "90": 0.8, "60": 0.7}, "90.0 | 85.0 | 80.0 | 70.0"),
    ("kitti-low", "SemanticKITTI frames with returns from below the ground",
     "| method | 0 % (as recorded) | 0.5 % | 1 % | 2 % |",
     {"0": 0.98, "0.5": 0.97, "1": 0.96, "2": 0.9}, "98.0 | 97.0 | 96.0 | 90.0"),
    ("kitti-noise", "SemanticKITTI frames with a noisier sensor",
     "| method | as recorded | σ 3 cm | σ 5 cm | σ 8 cm |",
     {"0": 0.98, "3": 0.97, "5": 0.96, "8": 0.9}, "98.0 | 97.0 | 96.0 | 90.0"),
], ids=["lines", "fov", "low", "noise"])
def test_kitti_variant_sections_render_only_when_run(prefix, title, header, f1s, row):
    run_all = _run_all()
    results = _no_results()
    assert f"### {title}" not in run_all.render(results)
    for variant, f1 in f1s.items():
        results["segment"][f"{prefix}:{variant}/o3d_terrain"] = {
            "frames": [{"name": "000000", "points": 10, "seconds": 0.01, "f1": f1}],
            "failures": []}
    text = run_all.render(results)
    assert f"### {title}" in text
    assert header in text
    assert f"| **o3d_terrain** (`segment_terrain`) | {row} |" in text


def test_kitti_tilt_section_renders_only_when_run():
    run_all = _run_all()
    results = _no_results()
    title = "### SemanticKITTI frames with a tilted sensor"
    assert title not in run_all.render(results)

    def frame(name, f1):
        return {"name": name, "points": 10, "seconds": 0.01, "f1": f1}

    for tilt in run_all.KITTI_TILTS:
        results["segment"][f"kitti-tilt:{tilt}/o3d_terrain"] = {
            "frames": [frame("000000", 0.9), frame("000001", 0.8)], "failures": []}
    results["segment"]["kitti-tilt:level/csf"] = {"frames": [frame("000000", 0.5)],
                                                  "failures": [{"name": "000001",
                                                                "reason": "broken"}]}
    results["segment"]["kitti-tilt:pitch20/csf"] = {"error": "timeout: no result within 9 s"}
    text = run_all.render(results)
    assert title in text and "about the sensor origin" in text
    assert "| method | level | pitch 5° | pitch 10° | pitch 20° | roll 5° | roll 10° |" in text
    assert "| **o3d_terrain** (`segment_terrain`) |" + " 85.0 |" * 6 in text
    assert "| CSF | 50.0 (1 of 2 frames) | n/a | n/a | n/a | n/a | n/a |" in text
    assert "- CSF, pitch 20°: n/a (timeout: no result within 9 s)" in text
    assert "- CSF, level: skipped `000001`: broken" in text


# ---------------------------------------------------------------------------------------------
# real data (skipped without ../shared/data)


needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"real data folder {DATA} is absent")


@pytest.mark.realdata
@needs_data
def test_real_kitti_frame_matches_the_readme():
    frames, failures = ds.iter_frames(
        ds.semantic_kitti_frames(DATA / "kitti_seq00_lidar", limit=1))
    assert not failures
    f = frames[0]
    assert len(f) == 124_668 and int(f.is_ground.sum()) == 67_873  # figures of data/README.md


@pytest.mark.realdata
@needs_data
def test_real_las_feet_tiles_are_detected():
    feet = {"autzen_trim.laz", "4_6_crop.las", "file_with_both_wkt_and_geotiff_vlrs.las"}
    for path in sorted((DATA / "las").iterdir()):
        if path.name in feet or path.name == "hexbin-crop.las":
            frame = ds.read_las_frame(path)
            assert (frame.metres_per_unit != 1.0) == (path.name in feet), path.name


def test_eval_terrain_command_on_a_flat_scene(tmp_path, capsys):
    pytest.importorskip("o3d_terrain.api")
    pytest.importorskip("o3d_terrain.synthetic")
    out = tmp_path / "terrain"
    assert _cli(["eval", "terrain", "synthetic:flat", "-o", str(out)]) == 0
    result = json.loads((out / "terrain.json").read_text())
    # a plane sampled with 2 cm range noise: the fit is within a few noise sigmas
    assert result["results"][0]["height_rmse_m"] < 0.06
    assert (out / "error_map_flat-lidar.png").exists()


@pytest.mark.parametrize("name", ["ransac_plane", "csf", "smrf"])
def test_peer_adapters_on_a_plane_with_a_box(name):
    from o3d_terrain.evaluation import peers

    if peers.peer_status()[name]:
        pytest.skip(peers.peer_status()[name])
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(0, 40, 8000), rng.uniform(0, 40, 8000),
                              rng.normal(0, 0.01, 8000)])
    box = np.column_stack([rng.uniform(18, 22, 400), rng.uniform(18, 22, 400),
                           np.full(400, 2.5)])
    positions = np.vstack([ground, box])
    mask = peers.make_peer(name, kind="aerial").segment(positions)
    assert mask.shape == (8400,) and mask.dtype == bool
    assert mask[:8000].mean() > 0.9 and mask[8000:].mean() < 0.1
