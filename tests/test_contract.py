"""One contract, run over every registered stage and writer.

A stage builds from its defaults (or its ``example``), round-trips its config, rejects unknown
options, leaves the input cloud unmodified, writes exactly what it declares, accepts legacy,
tensor and numpy inputs, and handles an empty cloud with a clear error or an empty result.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain import STAGES, WRITERS, ConfigError, InputError, O3DTerrainError
from o3d_terrain.frame import as_frame

STAGE_NAMES = sorted(STAGES)
WRITER_NAMES = sorted(WRITERS)

#: sources whose options name input files: how to make a valid instance in a temp folder
SOURCE_FACTORIES = {
    "ReadCloud": lambda tmp, cloud: _npy(tmp, cloud),
    "StereoToCloud": lambda tmp, cloud: _stereo_pair(tmp),
}


def _stereo_pair(tmp):
    """A small rendered pair of a synthetic scene, its images and plain YAML calibration."""
    import cv2
    import yaml

    from o3d_terrain.synthetic import make_scene, render_stereo_pair

    pair = render_stereo_pair(make_scene("flat", seed=0), width=160, height=120)
    cv2.imwrite(str(tmp / "left.png"), pair.left)
    cv2.imwrite(str(tmp / "right.png"), pair.right)
    (tmp / "calib.yaml").write_text(yaml.safe_dump({k: float(v) for k, v in pair.calibration.items()}))
    return {"left": str(tmp / "left.png"), "right": str(tmp / "right.png"),
            "calibration": str(tmp / "calib.yaml")}


def _npy(tmp, cloud):
    path = tmp / "cloud.npy"
    np.save(path, cloud)
    return {"path": str(path)}


def _options(cls, tmp_path, cloud):
    if cls.type_name in SOURCE_FACTORIES:
        return SOURCE_FACTORIES[cls.type_name](tmp_path, cloud)
    return dict(cls.example or {})


def _instance(cls, tmp_path, cloud):
    return cls(**_options(cls, tmp_path, cloud))


def _producer(product):
    for name in STAGE_NAMES:
        cls = STAGES[name]
        if product in cls.writes and not cls.is_source and (cls.example is None or cls.example == {}):
            return cls()
    raise AssertionError(f"no stage with defaults makes '{product}'")


def _prepared(cls, cloud):
    """The input frame for a stage: the cloud after the stages that make what it reads."""
    frame = as_frame(cloud)
    needed = list(cls.reads)
    chain = []
    while needed:
        product = needed.pop()
        producer = _producer(product)
        chain.insert(0, producer)
        needed += [p for p in producer.reads if p not in needed]
    for stage in chain:
        frame = stage(frame)
    return frame


@pytest.mark.parametrize("name", STAGE_NAMES)
def test_builds_and_round_trips(name, tmp_path, small_cloud):
    cls = STAGES[name]
    stage = _instance(cls, tmp_path, small_cloud)
    assert cls.from_config(stage.to_config()) == stage
    assert stage.to_config()["type"] == name
    assert cls.summary, f"{name} needs a docstring summary"
    for spec in cls.options():
        assert spec.help, f"{name}.{spec.name} needs help text"


@pytest.mark.parametrize("name", STAGE_NAMES)
def test_rejects_unknown_options(name, tmp_path, small_cloud):
    cls = STAGES[name]
    with pytest.raises(ConfigError, match="unknown option 'not_an_option'"):
        cls(**_options(cls, tmp_path, small_cloud), not_an_option=1)


@pytest.mark.parametrize("name", [n for n in STAGE_NAMES if STAGES[n].is_source])
def test_source_writes_what_it_declares(name, tmp_path, small_cloud):
    source = _instance(STAGES[name], tmp_path, small_cloud)
    frame = source()
    assert len(frame) > 0
    assert set(frame.products) == set(STAGES[name].writes)
    # the attributes a pipeline checks its writers' names against (None: only the data knows)
    if source.given_attributes() is not None:
        assert set(frame.attribute_names()) <= set(source.given_attributes())
    assert frame.cloud.point.positions.dtype == o3d.core.float64


@pytest.mark.parametrize("name", [n for n in STAGE_NAMES if not STAGES[n].is_source])
def test_stage_contract(name, tmp_path, small_cloud):
    cls = STAGES[name]
    stage = _instance(cls, tmp_path, small_cloud)
    before = _prepared(cls, small_cloud)
    snapshot = {k: before.cloud.point[k].numpy().copy() for k in before.cloud.point}
    after = stage(before)
    # the input is unmodified
    assert sorted(before.cloud.point) == sorted(snapshot)
    for key, values in snapshot.items():
        np.testing.assert_array_equal(before.cloud.point[key].numpy(), values)
    # writes exactly what it declares
    assert set(after.products) - set(before.products) == set(cls.writes)
    new_attributes = set(after.cloud.point) - set(before.cloud.point)
    assert new_attributes == set(cls.writes_attributes)
    for attribute in cls.writes_attributes:
        values = after.cloud.point[attribute]
        assert values.shape[0] == len(after) and len(values.shape) == 2


@pytest.mark.parametrize("name", [n for n in STAGE_NAMES if not STAGES[n].is_source and not STAGES[n].reads])
def test_accepts_legacy_tensor_and_numpy(name, tmp_path, small_cloud):
    stage = _instance(STAGES[name], tmp_path, small_cloud)
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(small_cloud))
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(small_cloud))
    results = [stage(data) for data in (small_cloud, legacy, tensor)]
    assert all(len(r) == len(small_cloud) for r in results)
    assert sorted(tensor.point) == ["positions"]


@pytest.mark.parametrize("name", [n for n in STAGE_NAMES if not STAGES[n].is_source])
def test_empty_cloud_is_a_clear_error_or_empty(name, tmp_path, small_cloud):
    stage = _instance(STAGES[name], tmp_path, small_cloud)
    empty = np.zeros((0, 3))
    try:
        if STAGES[name].reads:
            frame = _prepared(STAGES[name], small_cloud).select(np.zeros(0, dtype=np.int64))
        else:
            frame = as_frame(empty)
        result = stage(frame)
    except (InputError, O3DTerrainError) as exc:
        assert str(exc).startswith(name) or name in str(exc)
    else:
        assert len(result) == 0


@pytest.mark.parametrize("name", WRITER_NAMES)
def test_writer_contract(name, tmp_path, small_cloud):
    cls = WRITERS[name]
    writer = cls(**(cls.example or {}))
    assert cls.from_config(writer.to_config()) == writer
    with pytest.raises(ConfigError, match="unknown option"):
        cls(**(cls.example or {}), not_an_option=1)
    # run it after the stages that make what it needs, plus a labels attribute
    frame = as_frame(small_cloud)
    for product in writer.required_products():
        if product not in frame.products:
            producer = _producer(product)
            frame = _prepared(type(producer), frame)
            frame = producer(frame)
    if "labels" not in frame.attribute_names():
        frame = frame.with_attributes(labels=np.ones(len(frame), np.int32))
    written = writer.write(frame, tmp_path / "out")
    assert written and all(p.exists() and p.stat().st_size > 0 for p in written)
