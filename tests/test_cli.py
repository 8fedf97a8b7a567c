import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from o3d_terrain.cli import main


def _pipeline(tmp_path, source_path, **stage):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({
        "source": {"type": "ReadCloud", "path": str(source_path)},
        "stages": [{"type": "GridQuantize", **stage}],
        "outputs": [{"type": "WriteImage", "product": "grid", "path": "height.png"}],
    }))
    return path


def test_validate_says_a_pipeline_without_a_source_needs_input(tmp_path, capsys):
    path = tmp_path / "no_source.yaml"
    path.write_text("stages:\n  - type: GridQuantize\n")
    assert main(["validate", str(path)]) == 0
    assert "valid (1 stage, 0 outputs); it has no source: run it with --input CLOUD" in \
        capsys.readouterr().out
    assert main(["run", str(path)]) == 2  # what run says without --input


def test_validate_reports_three_problems_and_exits_2(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(
        "source:\n  type: ReadCloud\n  path: missing.bin\n"
        "stages:\n  - type: GridQuantise\n  - type: GridQuantize\n    cel_size: 0.3\n"
    )
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "3 problems" in err
    assert "unknown stage 'GridQuantise' (did you mean 'GridQuantize'?)" in err
    assert "unknown option 'cel_size' (did you mean 'cell_size'?)" in err
    assert "input file 'missing.bin' not found" in err
    assert "Traceback" not in err


def test_run_writes_outputs(tmp_path, small_cloud, capsys):
    np.save(tmp_path / "c.npy", small_cloud)
    path = _pipeline(tmp_path, tmp_path / "c.npy", cell_size=1.0)
    assert main(["run", str(path), "--output", str(tmp_path / "out"),
                 "--set", "stages.0.cell_size=2.0"]) == 0
    out = capsys.readouterr().out
    assert "wrote" in out and (tmp_path / "out" / "height.png").exists()
    resolved = yaml.safe_load((tmp_path / "out" / "pipeline.resolved.yaml").read_text())
    assert resolved["stages"][0]["cell_size"] == 2.0


def test_batch_keeps_going_past_a_bad_input(tmp_path, small_cloud, capfd):
    from o3d_terrain import write_cloud

    np.save(tmp_path / "a.npy", small_cloud)
    (tmp_path / "b.npy").write_bytes(b"garbage")
    np.save(tmp_path / "c.npy", small_cloud)
    # a PLY file cut short: Open3D's reader would print its complaint and return the cloud
    # with the missing points made of whatever memory held
    whole = write_cloud(tmp_path / "e.ply", small_cloud).read_bytes()
    (tmp_path / "d.ply").write_bytes(whole[:len(whole) // 2])
    path = _pipeline(tmp_path, tmp_path / "a.npy")
    inputs = [str(tmp_path / name) for name in ("a.npy", "b.npy", "c.npy", "d.ply", "e.ply")]
    code = main(["run", str(path), "-o", str(tmp_path / "out"), "-i", *inputs])
    captured = capfd.readouterr()
    assert code == 1
    assert "b.npy: FAILED" in captured.err
    assert f"{inputs[3]}: FAILED: source ReadCloud: {inputs[3]}: truncated: its header " \
           "declares" in captured.err
    assert "RPly" not in captured.err
    assert "3 of 5 inputs done" in captured.out
    assert f"failed: {inputs[1]}, {inputs[3]}" in captured.out
    assert (tmp_path / "out" / "c" / "height.png").exists()
    assert (tmp_path / "out" / "e" / "height.png").exists()
    assert not (tmp_path / "out" / "d" / "height.png").exists()
    # in a folder, too: a cloud cut short failed, it is not "skipped, not a point cloud"
    (tmp_path / "scans").mkdir()
    for name in ("c.npy", "d.ply"):
        (tmp_path / "scans" / name).write_bytes((tmp_path / name).read_bytes())
    assert main(["run", str(path), "-o", str(tmp_path / "out2"), "-i",
                 str(tmp_path / "scans")]) == 1
    captured = capfd.readouterr()
    assert f"{tmp_path / 'scans' / 'd.ply'}: FAILED: source ReadCloud:" in captured.err
    assert "1 of 2 inputs done" in captured.out


def test_a_folder_file_is_skipped_by_the_kind_of_its_error_not_its_words(tmp_path, small_cloud,
                                                                         capfd, monkeypatch):
    """run over a folder skips a file whose reading raised NotACloudError and fails one whose
    reading raised any other error, whatever their messages say."""
    from o3d_terrain.errors import InputError, NotACloudError
    from o3d_terrain.stages import read as read_stage

    scans = tmp_path / "scans"
    scans.mkdir()
    for name in ("a.npy", "b.npy", "c.npy"):
        np.save(scans / name, small_cloud)
    reading = read_stage.read_cloud

    def read_cloud(path, **kwargs):
        if Path(path).name == "a.npy":
            raise NotACloudError(path, "truncated: words a cloud cut short would use")
        if Path(path).name == "b.npy":
            raise InputError(f"{path}: not a point cloud, in so many words")
        return reading(path, **kwargs)

    monkeypatch.setattr(read_stage, "read_cloud", read_cloud)
    path = _pipeline(tmp_path, scans / "c.npy")
    assert main(["run", str(path), "-o", str(tmp_path / "out"), "-i", str(scans)]) == 1
    captured = capfd.readouterr()
    assert f"{scans / 'a.npy'}: skipped, not a point cloud (truncated: words a cloud cut short " \
           "would use)" in captured.err
    assert f"{scans / 'b.npy'}: FAILED: source ReadCloud: {scans / 'b.npy'}: not a point " \
           "cloud, in so many words" in captured.err
    assert "1 of 3 inputs done" in captured.out


def test_one_input_option_takes_several_paths_and_the_pipeline_after_them(tmp_path, small_cloud,
                                                                          capsys):
    # a shell glob: -i scans/*.npy, the pipeline file before or after the inputs
    np.save(tmp_path / "a.npy", small_cloud)
    np.save(tmp_path / "c.npy", small_cloud)
    (tmp_path / "b.npy").write_bytes(b"garbage")
    path = _pipeline(tmp_path, tmp_path / "a.npy")
    clouds = [str(tmp_path / name) for name in ("a.npy", "b.npy", "c.npy")]
    assert main(["run", "-o", str(tmp_path / "out"), "-i", *clouds, str(path)]) == 1
    captured = capsys.readouterr()
    assert "2 of 3 inputs done" in captured.out
    # the stage's name once: where it failed, then what went wrong there
    assert f"{clouds[1]}: FAILED: source ReadCloud: {clouds[1]}:" in captured.err
    assert (tmp_path / "out" / "c" / "height.png").exists()
    with pytest.raises(SystemExit) as info:
        main(["run", "-i", *clouds])
    assert info.value.code == 2
    assert "the following arguments are required: pipeline" in capsys.readouterr().err


def test_batch_inputs_of_one_name_keep_their_own_outputs(tmp_path, small_cloud, capsys):
    for folder in ("drive1", "drive2"):
        (tmp_path / folder).mkdir()
        points = small_cloud[:300] if folder == "drive1" else small_cloud
        np.save(tmp_path / folder / "000000.npy", points)
    path = _pipeline(tmp_path, tmp_path / "drive1" / "000000.npy")
    out = tmp_path / "out"
    assert main(["run", str(path), "-o", str(out), "-i", str(tmp_path / "drive1"),
                 "-i", str(tmp_path / "drive2")]) == 0
    assert "-> " + str(out / "000000-2") in capsys.readouterr().out
    first = yaml.safe_load((out / "000000" / "pipeline.resolved.yaml").read_text())
    second = yaml.safe_load((out / "000000-2" / "pipeline.resolved.yaml").read_text())
    assert first["source"]["path"].endswith("drive1/000000.npy")
    assert second["source"]["path"].endswith("drive2/000000.npy")


def test_batch_keeps_going_past_an_internal_error(tmp_path, small_cloud, capsys, monkeypatch):
    import o3d_terrain.pipeline as pipeline_module

    run = pipeline_module.Pipeline.run

    def flaky(self, *args, **kwargs):
        if "a.npy" in str(self.source):
            raise RuntimeError("something unforeseen")
        return run(self, *args, **kwargs)

    monkeypatch.setattr(pipeline_module.Pipeline, "run", flaky)
    np.save(tmp_path / "a.npy", small_cloud)
    np.save(tmp_path / "c.npy", small_cloud)
    path = _pipeline(tmp_path, tmp_path / "a.npy")
    code = main(["run", str(path), "-o", str(tmp_path / "out"), "-i", str(tmp_path / "a.npy"),
                 "-i", str(tmp_path / "c.npy")])
    captured = capsys.readouterr()
    assert code == 1
    assert "a.npy: FAILED (RuntimeError" in captured.err and "something unforeseen" in captured.err
    assert "1 of 2 inputs done" in captured.out
    assert (tmp_path / "out" / "c" / "height.png").exists()


def test_a_missing_input_names_the_option(tmp_path, small_cloud, capsys, monkeypatch):
    np.save(tmp_path / "a.npy", small_cloud)
    path = _pipeline(tmp_path, tmp_path / "a.npy")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(path), "-i", "missing.npy"]) == 2
    err = capsys.readouterr().err
    assert f"--input: 'missing.npy' not found (looked for {tmp_path / 'missing.npy'})" in err
    assert "against the current folder" in err and "pipeline file's folder" not in err


def test_a_cloud_in_a_cameras_frame_gets_a_plain_warning(tmp_path, capsys):
    rng = np.random.default_rng(0)
    forward, right = rng.uniform(3, 30, 5_000), rng.uniform(-10, 10, 5_000)
    np.save(tmp_path / "camera.npy", np.c_[right, 1.6 + rng.normal(0, 0.02, 5_000), forward])
    path = _pipeline(tmp_path, tmp_path / "camera.npy")
    assert main(["run", str(path), "-o", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "warning: GridQuantize: the cloud is flat across (0.0, -1.0, 0.0)" in err
    assert "the stage LevelCloud with up: [0.0, -1.0, 0.0]" in err and ".py:" not in err


def test_runtime_failure_exits_1_without_traceback(tmp_path, capsys):
    (tmp_path / "nan.npy").write_bytes(b"")
    np.save(tmp_path / "nan.npy", np.full((5, 3), np.nan))
    path = _pipeline(tmp_path, tmp_path / "nan.npy")
    assert main(["run", str(path), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "GridQuantize" in err and "no finite point" in err and "Traceback" not in err


def test_stages_describe_and_unknown(capsys):
    assert main(["stages"]) == 0
    assert "GridQuantize" in capsys.readouterr().out
    assert main(["describe", "GridQuantize"]) == 0
    assert "cell_size [m] = 0.5" in capsys.readouterr().out
    assert main(["describe", "GridQuantise"]) == 2
    assert "did you mean 'GridQuantize'?" in capsys.readouterr().err


def test_console_script_and_module_entry_points():
    done = subprocess.run([sys.executable, "-m", "o3d_terrain", "--version"], capture_output=True,
                          text=True, check=True)
    assert done.stdout.startswith("o3d-terrain ")
    with pytest.raises(SystemExit) as info:
        main(["run"])
    assert info.value.code == 2


def test_a_folder_of_one_cloud_writes_into_its_own_sub_folder(tmp_path, small_cloud, capsys):
    # docs/pipelines.md, "Batches": a folder's inputs write to OUTPUT/<input name>/, whatever
    # their number; one file named on its own writes into OUTPUT itself
    (tmp_path / "scans").mkdir()
    np.save(tmp_path / "scans" / "000007.npy", small_cloud)
    path = _pipeline(tmp_path, tmp_path / "scans" / "000007.npy")
    out = tmp_path / "out"
    assert main(["run", str(path), "-o", str(out), "-i", str(tmp_path / "scans")]) == 0
    assert (out / "000007" / "height.png").exists() and not (out / "height.png").exists()
    assert "1 of 1 inputs done" in capsys.readouterr().out
    single = tmp_path / "single"
    assert main(["run", str(path), "-o", str(single), "-i",
                 str(tmp_path / "scans" / "000007.npy")]) == 0
    assert (single / "height.png").exists()


def test_a_kitti_sequence_folder_points_to_its_velodyne_folder(tmp_path, small_cloud, capsys):
    sequence = tmp_path / "00"
    (sequence / "velodyne").mkdir(parents=True)
    small_cloud.astype(np.float32).tofile(sequence / "velodyne" / "000000.bin")
    (sequence / "calib.txt").write_text("P0: 7.07e+02 0.0 6.04e+02 0.0 0.0 7.07e+02 1.8e+02 "
                                        "0.0 0.0 0.0 1.0 0.0\nP1: 1 2 3 4 5 6 7 8 9 10 11 12\n")
    (sequence / "times.txt").write_text("0.000000e+00\n1.036742e-01\n")
    path = _pipeline(tmp_path, sequence / "velodyne" / "000000.bin")
    code = main(["run", str(path), "-o", str(tmp_path / "out"), "-i", str(sequence)])
    captured = capsys.readouterr()
    assert code == 1  # the batch went through both files, and neither is a cloud
    assert "0 of 2 inputs done" in captured.out
    for name in ("calib.txt", "times.txt"):
        assert f"{sequence / name}: skipped, not a point cloud (" in captured.err
    assert f"pass its scans with --input {sequence / 'velodyne'}" in captured.err
    # a sequence folder without such files: no cloud in it, and where the scans are
    for name in ("calib.txt", "times.txt"):
        (sequence / name).unlink()
    assert main(["run", str(path), "-o", str(tmp_path / "out"), "-i", str(sequence)]) == 2
    err = capsys.readouterr().err
    assert f"folder '{sequence}' has no point cloud files" in err
    assert f"--input {sequence / 'velodyne'}" in err
    # and the velodyne folder runs
    assert main(["run", str(path), "-o", str(tmp_path / "out"), "-i",
                 str(sequence / "velodyne")]) == 0
    assert (tmp_path / "out" / "000000" / "height.png").exists()


def test_describe_takes_any_case_and_set_says_how_many_stages(capsys):
    assert main(["describe", "gridquantize"]) == 0
    assert capsys.readouterr().out.startswith("GridQuantize:")
    pipeline = Path(__file__).resolve().parents[1] / "pipelines" / "lidar_terrain.yaml"
    assert main(["validate", str(pipeline), "--set", "stages.7.x=1"]) == 2
    assert "this file has 4 stages (0 to 3), 5 outputs (0 to 4)" in capsys.readouterr().err


def test_validate_rejects_an_empty_stage_list(tmp_path, capsys):
    path = tmp_path / "empty_stages.yaml"
    path.write_text("source:\n  type: SyntheticScene\nstages: []\n")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "empty_stages.yaml: stages: is empty" in err
    assert "list at least one stage under 'stages:'" in err
    assert main(["run", str(path), "-o", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_validate_checks_the_attributes_writers_name(tmp_path, small_cloud, capsys):
    from o3d_terrain import write_cloud
    from o3d_terrain.frame import as_frame

    path = tmp_path / "p.yaml"
    path.write_text("source:\n  type: SyntheticScene\nstages:\n  - type: GridQuantize\n"
                    "  - type: RationalBSplineTerrain\n  - type: Segmenter\noutputs:\n"
                    "  - type: WriteCloud\n    color_by: labes\n")
    assert main(["validate", str(path)]) == 2
    assert "outputs[0] WriteCloud: color_by 'labes' is not a per-point attribute the source " \
           "SyntheticScene or a stage gives" in capsys.readouterr().err
    # a PLY file may carry any attribute: validate says which names only it can give
    np.save(tmp_path / "a.npy", small_cloud)
    write_cloud(tmp_path / "b.ply", as_frame(small_cloud).with_attributes(
        reflectance=small_cloud[:, 2]))
    assert main(["validate", str(path), "-i", str(tmp_path / "b.ply")]) == 0
    assert "valid (3 stages, 1 output); attributes the cloud itself must carry (checked when " \
           "it is read): outputs[0] WriteCloud: color_by 'labes' (did you mean 'labels'?)" in \
           capsys.readouterr().out
    # in a batch, the inputs whose format cannot carry it fail alone
    assert main(["run", str(path), "-o", str(tmp_path / "out"), "--set",
                 "outputs.0.color_by=reflectance", "-i", str(tmp_path / "a.npy"),
                 str(tmp_path / "b.ply")]) == 1
    captured = capsys.readouterr()
    assert f"{tmp_path / 'a.npy'}: FAILED: p.yaml: outputs[0] WriteCloud: color_by " \
           "'reflectance' is not a per-point attribute" in captured.err
    assert "1 of 2 inputs done" in captured.out
    assert (tmp_path / "out" / "b" / "cloud.ply").exists()
