import warnings

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain import InputError, NotACloudError, read_cloud, write_cloud
from o3d_terrain.frame import as_frame
from o3d_terrain.io import file_attributes


def _positions(cloud):
    return cloud.point.positions.numpy()


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".npz"])
def test_write_read_round_trip_keeps_attributes(tmp_path, rng, suffix):
    pts = rng.normal(size=(50, 3)) + [500000.0, 4500000.0, 200.0]
    frame = as_frame(pts).with_attributes(labels=np.arange(50, dtype=np.int32) % 3,
                                          heights=rng.normal(size=50))
    path = write_cloud(tmp_path / f"c{suffix}", frame)
    if suffix == ".npz":
        data = np.load(path)
        np.testing.assert_array_equal(data["positions"], pts)
        return
    back = read_cloud(path)
    np.testing.assert_allclose(_positions(back), pts, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.point.labels.numpy()[:, 0], np.arange(50) % 3)


def test_text_numpy_and_kitti(tmp_path, rng):
    pts = rng.normal(size=(20, 4))
    np.savetxt(tmp_path / "a.xyz", pts)
    np.savetxt(tmp_path / "b.csv", pts, delimiter=",", header="x,y,z,i", comments="")
    np.save(tmp_path / "c.npy", pts[:, :3])
    pts.astype(np.float32).tofile(tmp_path / "d.bin")
    for name in ("a.xyz", "b.csv"):
        cloud = read_cloud(tmp_path / name)
        np.testing.assert_allclose(_positions(cloud), pts[:, :3])
        np.testing.assert_allclose(cloud.point.intensities.numpy()[:, 0], pts[:, 3], rtol=1e-6)
    np.testing.assert_allclose(_positions(read_cloud(tmp_path / "c.npy")), pts[:, :3])
    kitti = read_cloud(tmp_path / "d.bin")
    assert kitti.point.positions.dtype == o3d.core.float64
    np.testing.assert_allclose(_positions(kitti), pts[:, :3].astype(np.float32))
    # what a pipeline checks the attributes its writers name against
    np.save(tmp_path / "e.npy", pts)
    for name in ("a.xyz", "b.csv", "c.npy", "d.bin", "e.npy"):
        given = set(read_cloud(tmp_path / name).point) - {"positions"}
        assert given <= set(file_attributes(tmp_path / name)), name
    assert file_attributes("scan.PLY") is None and file_attributes("scan.pcd") is None


def test_unreadable_inputs(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_cloud(tmp_path / "missing.ply")
    with pytest.raises(InputError, match="unknown point cloud format"):
        read_cloud(tmp_path / "x.abc")
    (tmp_path / "scans.ply").mkdir()  # a folder, even one named like a cloud
    with pytest.raises(InputError, match="is a folder; give one of its point cloud files"):
        read_cloud(tmp_path / "scans.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_cloud(tmp_path / "empty.ply")
    (tmp_path / "bad.bin").write_bytes(b"123")
    with pytest.raises(InputError, match="whole number of KITTI points"):
        read_cloud(tmp_path / "bad.bin")
    (tmp_path / "bad.ply").write_text("not a ply file")
    with pytest.raises(InputError):
        read_cloud(tmp_path / "bad.ply")


def test_las_reads_classification(shared_data):
    cloud = read_cloud(shared_data / "las" / "warsaw_small.las")
    assert cloud.point.positions.dtype == o3d.core.float64
    assert "classification" in cloud.point
    assert (cloud.point.classification.numpy() == 2).any()
    assert set(cloud.point) - {"positions"} <= set(file_attributes("warsaw_small.las"))


def test_as_frame_accepts_all_cloud_kinds_and_never_modifies(rng):
    pts = rng.normal(size=(10, 3))
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts.astype(np.float32)))
    for data in (pts, legacy, tensor, np.column_stack([pts, np.ones(10)])):
        frame = as_frame(data).with_attributes(labels=np.ones(10, np.int32))
        np.testing.assert_allclose(frame.positions, pts, atol=1e-6)
    assert "labels" not in tensor.point
    assert tensor.point.positions.dtype == o3d.core.float32


def _feet_las(path, laspy):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([1000.0, 2000.0, 0.0])
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

    vlr = GeoKeyDirectoryVlr()
    vlr.geo_keys_header = GeoKeyEntryStruct(1, 1, 0, 2)
    vlr.geo_keys = [GeoKeyEntryStruct(3076, 0, 1, 9002),  # ProjLinearUnits: foot
                    GeoKeyEntryStruct(4099, 0, 1, 9002)]  # VerticalUnits: foot
    header.vlrs.append(vlr)
    las = laspy.LasData(header)
    las.x = 1000.0 + np.arange(4.0)
    las.y = np.full(4, 2000.0)
    las.z = np.full(4, 100.0)
    las.classification = np.full(4, 2, np.uint8)
    las.write(str(path))


def test_read_cloud_converts_feet_to_metres_by_default(tmp_path):
    laspy = pytest.importorskip("laspy")
    _feet_las(tmp_path / "feet.las", laspy)
    metres = read_cloud(tmp_path / "feet.las").point.positions.numpy()
    np.testing.assert_allclose(metres[:, 0], (1000.0 + np.arange(4)) * 0.3048)
    np.testing.assert_allclose(metres[:, 2], 100.0 * 0.3048)
    feet = read_cloud(tmp_path / "feet.las", units="file").point.positions.numpy()
    np.testing.assert_allclose(feet[:, 0], 1000.0 + np.arange(4))
    with pytest.raises(InputError, match="units"):
        read_cloud(tmp_path / "feet.las", units="yards")


def test_read_cloud_and_evaluation_reader_agree_on_a_feet_tile(shared_data):
    from o3d_terrain.evaluation.datasets import read_las_frame

    path = shared_data / "las" / "4_6_crop.las"  # US survey feet
    frame = read_las_frame(path)
    cloud = read_cloud(path).point.positions.numpy()
    np.testing.assert_allclose(cloud, frame.positions)
    assert frame.metres_per_unit == pytest.approx(1200.0 / 3937.0)


def test_products_save_into_folders_not_made_yet(tmp_path):
    # a product computed for minutes is not lost to a missing folder (as write_cloud)
    import o3d_terrain
    from o3d_terrain.spline import SlopeGrid, TerrainSurface

    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 20, 4000), rng.uniform(0, 20, 4000), rng.normal(0, 0.02, 4000)]
    pts[:40, 2] += 1.5
    surface, _ = o3d_terrain.segment_terrain(pts)
    folder = tmp_path / "run" / "frame_000"
    surface.save(folder / "surface.npz")
    surface.slope_grid(1.0).save(folder / "slope.npz")
    grid = o3d_terrain.quantize_points(pts, cell_size=0.5)
    grid.save(folder / "grid.npz")
    o3d_terrain.detect_obstacles(pts, surface=surface).save(folder / "deep" / "obstacles.json")
    o3d_terrain.traversability_cost(surface, pts).save(folder / "cost.npz")
    back = TerrainSurface.load(folder / "surface.npz")
    np.testing.assert_array_equal(back.control_points, surface.control_points)
    assert SlopeGrid.load(folder / "slope.npz").slope_deg.shape == \
        surface.slope_grid(1.0).slope_deg.shape
    assert (folder / "grid.npz").exists() and (folder / "deep" / "obstacles.json").exists()
    assert (folder / "cost.npz").exists()


@pytest.mark.parametrize("suffix", [".bin", ".npy"])
def test_float32_files_far_from_the_origin_warn_as_the_array_does(tmp_path, rng, suffix):
    """A KITTI frame moved into projected coordinates and stored as float32: its points were
    rounded by 0.25-0.5 m before the library read them, and reading the file says so, as
    ``segment_terrain`` of the float32 array itself does."""
    from o3d_terrain.errors import TerrainWarning

    frame = np.column_stack([rng.uniform(-40, 40, (500, 2)), rng.normal(-1.7, 0.1, 500),
                             rng.uniform(0, 1, 500)])
    far = (frame + [5.0e5, 5.0e6, 0.0, 0.0]).astype(np.float32)
    near = frame.astype(np.float32)
    for name, data in (("far", far), ("near", near)):
        path = tmp_path / f"{name}{suffix}"
        if suffix == ".bin":
            data.tofile(path)
        else:
            np.save(path, data)
    with pytest.warns(TerrainWarning, match=r"far\.(bin|npy): .*float32.* m apart"):
        cloud = read_cloud(tmp_path / f"far{suffix}")
    assert cloud.point.positions.dtype == o3d.core.float64
    with pytest.warns(TerrainWarning, match="float32.* m apart"):
        as_frame(far)  # the array itself: the same warning
    with warnings.catch_warnings():
        warnings.simplefilter("error", TerrainWarning)
        read_cloud(tmp_path / f"near{suffix}")  # a sensor-frame scan: float32 is fine
        np.save(tmp_path / "far64.npy", far.astype(np.float64) + 0.001)
        read_cloud(tmp_path / "far64.npy")  # float64 coordinates keep their precision


def test_run_input_shows_the_float32_warning(tmp_path, rng, capsys):
    from o3d_terrain.cli import main

    pts = np.column_stack([rng.uniform(-20, 20, (3000, 2)), rng.normal(-1.7, 0.05, 3000),
                           rng.uniform(0, 1, 3000)]) + [5.0e5, 5.0e6, 0.0, 0.0]
    pts.astype(np.float32).tofile(tmp_path / "frame.bin")
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text("stages:\n  - type: GridQuantize\n")
    assert main(["run", str(pipeline), "--input", str(tmp_path / "frame.bin"),
                 "-o", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "frame.bin: " in err and "m apart" in err


def test_text_files_with_semicolons_tabs_or_only_a_header(tmp_path, recwarn):
    (tmp_path / "semi.csv").write_text("x;y;z\n1;2;3\n4;5;6\n7;8;9.5\n")
    (tmp_path / "tab.txt").write_text("1\t2\t3\n4\t5\t6\n")
    (tmp_path / "header.csv").write_text("x,y,z\n")
    np.testing.assert_array_equal(read_cloud(tmp_path / "semi.csv").point.positions.numpy()[-1],
                                  [7.0, 8.0, 9.5])
    assert read_cloud(tmp_path / "tab.txt").point.positions.shape[0] == 2
    with pytest.raises(InputError, match="header.csv: no points"):
        read_cloud(tmp_path / "header.csv")
    assert not [w for w in recwarn if "no data" in str(w.message)]  # numpy's, said by the error


def _ply(header_lines, body=b""):
    return ("\n".join(["ply", *header_lines, "end_header"]) + "\n").encode() + body


def test_a_truncated_or_corrupt_ply_names_the_file_and_what_is_wrong(tmp_path, rng, capfd):
    """Open3D's PLY reader prints its complaint and returns the cloud anyway, the points it
    could not read holding whatever memory held: read_cloud checks the file against its header
    first."""
    pts = rng.normal(size=(100, 3))
    raw = write_cloud(tmp_path / "good.ply", pts).read_bytes()
    body = raw.index(b"end_header\n") + len(b"end_header\n")  # 100 vertices of 3 doubles
    xyz = ["format ascii 1.0", "element vertex 100", "property float x", "property float y",
           "property float z"]
    rows = [b"%f %f %f\n" % tuple(p) for p in pts]
    lines = b"".join(rows)
    cases = {
        "cut.ply": (raw[:body + 500], (r"truncated: its header declares 100 vertex elements "
                                       r"\(2,400 bytes\) but 500 bytes follow the header "
                                       r"\(whole vertex elements: 20\)")),
        "header_only.ply": (raw[:body], r"truncated: .* but 0 bytes follow the header"),
        "garbage.ply": (raw[:body] + bytes(range(37)), r"truncated: .* but 37 bytes follow"),
        "ascii_cut.ply": (_ply(xyz, b"".join(rows[:10])),
                          (r"truncated: its header declares 100 vertex elements but the file "
                           r"holds 10 lines of them")),
        "ascii_garbage.ply": (_ply(xyz, b"".join(rows[:30]) + b"foo bar baz\n"
                                   + b"".join(rows[31:])),
                              r"the vertex data is not 3 numbers per line .*foo"),
        "bad_type.ply": (_ply(["format binary_little_endian 1.0", "element vertex 100",
                               "property floot x"], bytes(1200)),
                         r"header line 4: unknown property type 'floot'"),
        "no_end.ply": (b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n"
                       + b"property float x\n", r"no 'end_header' line"),
        "not_ply.ply": (b"solid cube\n" + bytes(100), r"does not start with 'ply'"),
    }
    for name, (data, expected) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError, match=expected) as info:
            read_cloud(path)
        assert str(info.value).startswith(f"{path}: "), name
        # a PLY cut short or corrupt is a cloud that failed; only a file that is no PLY at
        # all is not a cloud
        assert isinstance(info.value, NotACloudError) == (name == "not_ply.ply"), name
    assert "RPly" not in capfd.readouterr().err  # nothing reached Open3D's reader
    # a valid binary file with a face list after its vertices, and an ASCII one, still read
    mesh = raw[:body].replace(b"end_header\n", b"element face 1\nproperty list uchar int "
                              b"vertex_indices\nend_header\n") + raw[body:] + b"\x03" + bytes(12)
    (tmp_path / "mesh.ply").write_bytes(mesh)
    np.testing.assert_allclose(_positions(read_cloud(tmp_path / "mesh.ply")), pts)
    (tmp_path / "ascii.ply").write_bytes(_ply(xyz, lines))
    np.testing.assert_allclose(_positions(read_cloud(tmp_path / "ascii.ply")), pts, atol=1e-5)


def test_a_file_holding_no_cloud_is_a_not_a_cloud_error_through_stage_and_pipeline(tmp_path):
    """NotACloudError (a file that holds no point cloud at all) against a plain InputError (a
    cloud file cut short or corrupt); the kind, the file and the reason survive the ReadCloud
    stage and the pipeline putting their names before the message."""
    from o3d_terrain import GridQuantize, Pipeline, ReadCloud

    (tmp_path / "calib.txt").write_text("P0: 7.07e+02 0.0 6.04e+02\nP1: 1 2 3 4\n")
    (tmp_path / "times.txt").write_text("0.000000e+00\n1.036742e-01\n")
    (tmp_path / "empty.bin").write_bytes(b"")
    (tmp_path / "odd.bin").write_bytes(bytes(20))
    np.save(tmp_path / "pairs.npy", np.zeros((5, 2)))
    (tmp_path / "notes.las").write_bytes(b"not a LAS file at all" + bytes(400))
    (tmp_path / "cut.las").write_bytes(b"LASF" + bytes(40))  # the signature, then nothing
    not_clouds = {"calib.txt": "could not be read as .txt", "times.txt": "at least 3 columns",
                  "empty.bin": "the file is empty", "odd.bin": "20 bytes is not a whole",
                  "pairs.npy": r"got shape \(5, 2\)", "notes.las": "could not be read as LAS"}
    for name, reason in not_clouds.items():
        with pytest.raises(NotACloudError, match=reason) as info:
            read_cloud(tmp_path / name)
        assert info.value.path == str(tmp_path / name)
        assert str(info.value) == f"{tmp_path / name}: {info.value.reason}"
    with pytest.raises(InputError, match="could not be read as LAS") as info:
        read_cloud(tmp_path / "cut.las")
    assert not isinstance(info.value, NotACloudError)

    path = str(tmp_path / "times.txt")
    with pytest.raises(NotACloudError) as info:
        ReadCloud(path=path)()
    assert str(info.value).startswith(f"ReadCloud: {path}: ")
    with pytest.raises(NotACloudError) as info:
        Pipeline((GridQuantize(),), ReadCloud(path=path)).run()
    assert str(info.value) == f"source ReadCloud: {path}: expected at least 3 columns (x y z), " \
        "found 1"
    assert (info.value.path, info.value.reason) == (path, "expected at least 3 columns (x y z), "
                                                          "found 1")
