"""Every file in pipelines/ validates and runs, in its YAML form and in its Python form.

Each ``pipelines/NAME.yaml`` has a twin ``pipelines/NAME.py`` defining
``run(output_dir, input_path=None) -> Frame`` that builds the same stages in Python. Both run on
the same input and must give the same per-point attributes and products.
"""

from __future__ import annotations

import importlib.util
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from o3d_terrain import load_pipeline
from o3d_terrain.cli import main

PIPELINES = Path(__file__).resolve().parents[1] / "pipelines"
FILES = sorted(PIPELINES.glob("*.yaml"))


def _twin(path: Path):
    twin = path.with_suffix(".py")
    assert twin.exists(), f"{path.name} needs its Python form {twin.name}"
    spec = importlib.util.spec_from_file_location(f"pipeline_{path.stem}", twin)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _input_for(path: Path, tmp_path: Path) -> Path | None:
    """Pipelines without a source run on a generated input: a small lidar frame, or a LAS tile
    (projected coordinates, as airborne tiles have) for the las_* pipelines."""
    if _has_source(path):
        return None
    from o3d_terrain.synthetic import make_scene, sample_lidar

    cloud = sample_lidar(make_scene("hills", seed=1), beams=16, azimuth_steps=360)
    if path.stem.startswith("las"):
        import laspy

        header = laspy.LasHeader(point_format=1, version="1.2")
        header.offsets = [500000.0, 4500000.0, 0.0]
        header.scales = [0.001, 0.001, 0.001]
        las = laspy.LasData(header)
        las.x = cloud.positions[:, 0] + 500000.0
        las.y = cloud.positions[:, 1] + 4500000.0
        las.z = cloud.positions[:, 2] + 200.0
        las.classification = (cloud.ground_truth == 1) * 2 + (cloud.ground_truth != 1) * 1
        target = tmp_path / "tile.las"
        las.write(str(target))
        return target
    target = tmp_path / "input.npy"
    np.save(target, cloud.positions)
    return target


def _has_source(path: Path) -> bool:
    import yaml

    return bool(yaml.safe_load(path.read_text()).get("source"))


def test_there_are_pipelines():
    assert FILES


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_validates(path, tmp_path):
    args = ["validate", str(path)]
    source_input = _input_for(path, tmp_path)
    if source_input is not None:
        args += ["--input", str(source_input)]
    assert main(args) == 0


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_yaml_and_python_forms_agree(path, tmp_path):
    source_input = _input_for(path, tmp_path)
    pipeline = load_pipeline(path, input_path=source_input)
    result = pipeline.run(output_dir=tmp_path / "yaml")
    assert all(p.exists() for p in result.written)
    frame = _twin(path).run(tmp_path / "python", input_path=source_input)
    assert sorted(frame.products) == sorted(result.frame.products)
    assert frame.attribute_names() == result.frame.attribute_names()
    for name in frame.attribute_names():
        np.testing.assert_array_equal(frame.attribute(name), result.frame.attribute(name))
    yaml_files = sorted(p.name for p in (tmp_path / "yaml").iterdir())
    python_files = sorted(p.name for p in (tmp_path / "python").iterdir())
    assert set(python_files) <= set(yaml_files)


def test_the_stereo_pipeline_on_a_cloud_file_says_how_to_run(tmp_path, capsys):
    source_input = tmp_path / "scan.npy"
    np.save(source_input, np.random.default_rng(0).normal(size=(100, 3)))
    assert main(["run", str(PIPELINES / "stereo_terrain.yaml"), "-i", str(source_input),
                 "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "the source StereoToCloud, which --input replaced with ReadCloud" in err
    assert "add StereoToCloud to the stages" not in err


def test_overriding_the_stereo_pair_from_the_repository_root(tmp_path, capsys, monkeypatch):
    """docs/pipelines.md, "Overrides": the pair's paths given with --set from the repository's
    root (relative to the current folder, not to the pipeline file's)."""
    monkeypatch.chdir(PIPELINES.parent)
    pair = "pipelines/data/offroad_pair/"
    args = ["validate", "pipelines/stereo_terrain.yaml", "--set", f"source.left={pair}left.png",
            "--set", f"source.right={pair}right.png",
            "--set", f"source.calibration={pair}calibration.yaml"]
    assert main(args) == 0
    assert main(["validate", "pipelines/stereo_terrain.yaml", "--set",
                 "source.left=nothere.png"]) == 2
    err = capsys.readouterr().err
    assert "nothere.png' not found" in err and "no stage makes" not in err


def test_the_overrides_example_of_the_docs_validates(monkeypatch):
    monkeypatch.chdir(PIPELINES.parent)
    text = (PIPELINES.parent / "docs" / "pipelines.md").read_text()
    section = text.split("## Overrides", 1)[1].split("\n## ", 1)[0]
    commands = re.findall(r"```bash\n(.*?)```", section, flags=re.DOTALL)
    assert commands
    for command in commands:
        args = shlex.split(command.replace("\\\n", " "))
        assert args[:2] == ["o3d-terrain", "run"]
        assert main(["validate", *args[2:]]) == 0, command
