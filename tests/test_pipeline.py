import numpy as np
import pytest
import yaml

from o3d_terrain import (
    ConfigError,
    GridQuantize,
    Pipeline,
    load_pipeline,
    parse_pipeline,
    write_cloud,
)
from o3d_terrain.frame import as_frame
from o3d_terrain.pipeline import RESOLVED_NAME, apply_overrides


def _write(path, config):
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


@pytest.fixture
def cloud_file(tmp_path, small_cloud):
    path = tmp_path / "data" / "cloud.npy"
    path.parent.mkdir()
    np.save(path, small_cloud)
    return path


def test_relative_paths_resolve_against_the_file(tmp_path, cloud_file):
    pipe = _write(tmp_path / "p.yaml", {
        "source": {"type": "ReadCloud", "path": "data/cloud.npy"},
        "stages": [{"type": "GridQuantize", "cell_size": 1.0}],
        "outputs": [{"type": "WriteImage", "product": "grid", "path": "h.png"}],
    })
    pipeline = load_pipeline(pipe)
    assert pipeline.source.path == str(cloud_file)
    result = pipeline.run(output_dir=tmp_path / "out")
    names = sorted(p.name for p in result.written)
    assert names == sorted(["h.png", RESOLVED_NAME])
    resolved = yaml.safe_load((tmp_path / "out" / RESOLVED_NAME).read_text())
    assert resolved["stages"][0] == GridQuantize(cell_size=1.0).to_config()


def test_every_problem_reported_at_once(tmp_path):
    pipe = _write(tmp_path / "p.yaml", {
        "source": {"type": "ReadCloud", "path": "nowhere.ply"},
        "stages": [{"type": "GridQuantise"}, {"type": "GridQuantize", "cel_size": 1, "min_points": 0}],
        "outputs": [{"type": "WriteImage", "product": "surfce"}],
        "stagse": [],
    })
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe)
    text = str(info.value)
    assert "unknown key 'stagse' (did you mean 'stages'?)" in text
    assert "input file 'nowhere.ply' not found" in text
    assert "stages[0] GridQuantise: unknown stage 'GridQuantise' (did you mean 'GridQuantize'?)" in text
    assert "stages[1] GridQuantize: unknown option 'cel_size' (did you mean 'cell_size'?)" in text
    assert "The 'min_points' option of GridQuantize must be an int >= 1. Got 0." in text


def test_product_chain_checked_before_running():
    with pytest.raises(ConfigError, match="writes the product 'surface', which no stage makes"):
        parse_pipeline({"stages": [{"type": "GridQuantize"}],
                        "outputs": [{"type": "WriteProduct", "product": "surface"}]})


def test_malformed_yaml_reports_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("stages:\n  - type: GridQuantize\n   cell_size: [1\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:\d+:\d+: invalid YAML"):
        load_pipeline(path)


def test_a_key_given_twice_is_an_error_not_the_last_one_silently(tmp_path):
    path = tmp_path / "twice.yaml"
    path.write_text("stages:\n  - type: GridQuantize\n    cell_size: 0.5\n"
                    "    cell_size: 0.25\n")
    with pytest.raises(ConfigError, match=r"twice.yaml:4:5: invalid YAML: the key 'cell_size' "
                                          r"is given twice \(first on line 3\) \(keep one"):
        load_pipeline(path)
    # the same key in two mappings is fine
    path.write_text("stages:\n  - type: GridQuantize\n    cell_size: 0.5\n"
                    "  - type: GridQuantize\n    cell_size: 0.25\n")
    assert [s.cell_size for s in load_pipeline(path).stages] == [0.5, 0.25]


def test_stage_named_as_a_key_says_how_to_write_it():
    with pytest.raises(ConfigError) as info:
        parse_pipeline({"stages": [{"GridQuantize": {"cell_size": 0.5}}, {"Segmenter": None},
                                   {"cell_size": 0.5}]})
    text = str(info.value)
    assert "stages[0]: has no 'type:' (the stage is named as a key, 'GridQuantize:')" in text
    assert "write '- type: GridQuantize' with its options beside 'type:'" in text
    assert "write '- type: Segmenter'" in text
    # a mapping of options alone gets the list of stages
    assert "stages[2]: has no 'type:' (add 'type: <stage>' (one of " in text


def test_overrides():
    config = {"stages": [{"type": "GridQuantize", "cell_size": 0.5}]}
    out = apply_overrides(config, ["stages.0.cell_size=0.25", "stages.0.region=[0, 1, 0, 1]"])
    assert out["stages"][0]["cell_size"] == 0.25 and out["stages"][0]["region"] == [0, 1, 0, 1]
    assert config["stages"][0]["cell_size"] == 0.5  # the original is not modified
    with pytest.raises(ConfigError, match="does not name an option"):
        apply_overrides(config, ["stages.5.cell_size=1"])
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        apply_overrides(config, ["stages.0.cell_size"])


def test_python_form_equals_file_form(tmp_path, cloud_file, small_cloud):
    pipe = _write(tmp_path / "p.yaml", {"stages": [{"type": "GridQuantize", "cell_size": 0.8}]})
    from_file = load_pipeline(pipe, input_path=cloud_file).run()
    in_python = Pipeline((GridQuantize(cell_size=0.8),)).run(small_cloud)
    np.testing.assert_array_equal(from_file.frame.products["grid"].z,
                                  in_python.frame.products["grid"].z)


def test_paths_given_with_set_resolve_against_the_current_folder(tmp_path, cloud_file,
                                                                 monkeypatch):
    # the pipeline file in one folder, the user in another: a path typed on the command line
    # means what it means in the user's folder, as --input does
    (tmp_path / "pipelines").mkdir()
    pipe = _write(tmp_path / "pipelines" / "p.yaml", {
        "source": {"type": "ReadCloud", "path": "../data/cloud.npy"},
        "stages": [{"type": "GridQuantize", "cell_size": 1.0}],
        "outputs": [{"type": "WriteImage", "product": "grid", "path": "h.png"}],
    })
    assert load_pipeline(pipe).source.path == str(tmp_path / "pipelines" / "../data/cloud.npy")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    for override in ("source.path=../data/cloud.npy",
                     "source={type: ReadCloud, path: ../data/cloud.npy}"):
        pipeline = load_pipeline(pipe, overrides=[override])
        assert pipeline.source.path == str(work / "../data/cloud.npy"), override
    # the file's own relative output_dir stays against the file's folder; --set's is the user's
    assert load_pipeline(pipe, overrides=["output_dir=results"]).output_dir == work / "results"
    # a path relative to the file's folder is not found from the user's folder, and the
    # message says where it looked
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe, overrides=["source.path=data/cloud.npy"])
    assert f"(looked for {work / 'data/cloud.npy'})" in str(info.value)
    # options that are not paths, and writers' paths (relative to the output folder), as given
    out = load_pipeline(pipe, overrides=["stages.0.cell_size=0.5", "outputs.0.path=g/h.png"])
    assert out.stages[0].cell_size == 0.5 and out.outputs[0].path == "g/h.png"


def test_a_product_only_a_source_makes_gets_a_hint_that_can_be_followed(tmp_path, cloud_file):
    stereo = {"type": "StereoToCloud", "left": "l.png", "right": "r.png",
              "calibration": "c.yaml"}
    for name in ("l.png", "r.png", "c.yaml"):
        (tmp_path / name).write_text("x")
    pipe = _write(tmp_path / "p.yaml", {
        "source": stereo, "stages": [{"type": "GridQuantize"}],
        "outputs": [{"type": "WriteImage", "product": "disparity", "path": "d.png"}],
    })
    # --input replaced the stereo source: drop the output, or keep the source
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe, input_path=cloud_file)
    text = str(info.value)
    assert "outputs[0] WriteImage: writes the product 'disparity'" in text
    assert "it comes from the source StereoToCloud, which --input replaced with ReadCloud" in text
    assert "drop this output" in text and "run without --input" in text
    assert "to the stages" not in text  # a source cannot be added to the stages
    # a file whose own source does not make it
    with pytest.raises(ConfigError) as info:
        parse_pipeline({"source": {"type": "SyntheticScene"}, "stages": [{"type": "GridQuantize"}],
                        "outputs": [{"type": "WriteImage", "product": "disparity"}]})
    text = str(info.value)
    assert "only the source StereoToCloud makes it, and the source is SyntheticScene" in text
    assert "use StereoToCloud as 'source:', or drop this output" in text
    assert "to the stages" not in text


def test_a_source_that_fails_to_build_is_the_only_problem_reported(tmp_path):
    for name in ("r.png", "c.yaml"):
        (tmp_path / name).write_text("x")
    pipe = _write(tmp_path / "p.yaml", {
        "source": {"type": "StereoToCloud", "left": "nothere.png", "right": "r.png",
                   "calibration": "c.yaml"},
        "stages": [{"type": "GridQuantize"}],
        "outputs": [{"type": "WriteImage", "product": "disparity", "path": "d.png"}],
    })
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe)
    assert len(info.value.problems) == 1
    assert "input file 'nothere.png' not found" in str(info.value)
    assert "no stage makes" not in str(info.value)


def test_an_output_that_fails_loses_none_of_the_others(tmp_path, small_cloud):
    """A misspelt attribute fails its writer after the stages ran (a PLY file's attributes
    are known when it is read): the other outputs and the resolved pipeline are still
    written, and the error says so."""
    from o3d_terrain.errors import O3DTerrainError

    write_cloud(tmp_path / "data" / "cloud.ply", small_cloud)
    pipe = _write(tmp_path / "p.yaml", {
        "source": {"type": "ReadCloud", "path": "data/cloud.ply"},
        "stages": [{"type": "GridQuantize", "cell_size": 1.0},
                   {"type": "RationalBSplineTerrain", "control_points": [6, 6]},
                   {"type": "Segmenter"}],
        "outputs": [{"type": "WriteCloud", "path": "c.ply", "color_by": "labes"},
                    {"type": "WriteAttribute", "attribute": "labels", "path": "l.npy"},
                    {"type": "WriteImage", "product": "grid", "path": "h.png"}],
    })
    with pytest.raises(O3DTerrainError, match=r"outputs\[0\] WriteCloud: .*'labes'.*\(did you "
                                              r"mean 'labels'\?\) \(the other outputs were "
                                              r"written to .*l\.npy, h\.png"):
        load_pipeline(pipe).run(output_dir=tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == \
        sorted(["l.npy", "h.png", RESOLVED_NAME])


@pytest.mark.parametrize("text", ["stages: []\n", "stages:\n", "outputs: []\n"])
def test_a_pipeline_without_stages_is_an_error(tmp_path, text):
    path = tmp_path / "none.yaml"
    path.write_text("source:\n  type: SyntheticScene\n" + text)
    with pytest.raises(ConfigError) as info:
        load_pipeline(path)
    problem, = info.value.problems
    assert problem.location.startswith("none.yaml: ")
    assert "stages" in problem.location + problem.message
    assert "list at least one stage under 'stages:'" in problem.fix
    assert "GridQuantize" in problem.fix and "SyntheticScene" not in problem.fix
    # the same in Python
    with pytest.raises(ConfigError, match="has no stages"):
        Pipeline(())


def test_an_attribute_a_writer_names_is_checked_against_the_source_and_the_stages(
        tmp_path, cloud_file, small_cloud):
    """color_by and WriteAttribute's attribute name per-point attributes: the stages declare
    theirs, and every source but a PLY or PCD file declares what its cloud may carry."""
    from o3d_terrain import ReadCloud
    from o3d_terrain.stages import RationalBSplineTerrain, Segmenter
    from o3d_terrain.writers import WriteCloud

    stages = [{"type": "GridQuantize"}, {"type": "RationalBSplineTerrain"}, {"type": "Segmenter"}]
    pipe = _write(tmp_path / "p.yaml", {
        "source": {"type": "ReadCloud", "path": "data/cloud.npy"}, "stages": stages,
        "outputs": [{"type": "WriteCloud", "path": "c.ply", "color_by": "labes"},
                    {"type": "WriteAttribute", "attribute": "slopes_deg"},
                    {"type": "WriteAttribute", "attribute": "intensities", "path": "i.npy"},
                    {"type": "WriteCloud", "path": "h.ply", "color_by": "heights_above_terrain"},
                    {"type": "WriteAttribute", "attribute": "ground_truth", "path": "g.npy"}],
    })
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe)
    problems = [str(p) for p in info.value.problems]
    assert len(problems) == 3, problems
    assert problems[0].startswith(
        "p.yaml: outputs[0] WriteCloud: color_by 'labes' is not a per-point attribute the "
        "source ReadCloud or a stage gives (attributes: heights_above_terrain, intensities, "
        "labels, positions)")
    assert problems[0].endswith("(did you mean 'labels'?)")
    assert "outputs[1] WriteAttribute: attribute 'slopes_deg'" in problems[1]
    assert problems[1].endswith("(add SlopeEstimator to the stages)")
    assert "outputs[4] WriteAttribute: attribute 'ground_truth'" in problems[2]
    assert "only the source SyntheticScene makes it, and the source is ReadCloud" in problems[2]
    # the same with --input: the input file's format says what its cloud may carry
    las = tmp_path / "tile.las"
    las.write_bytes(b"x")  # only its name is read before the run
    with pytest.raises(ConfigError) as info:
        load_pipeline(pipe, input_path=las)
    assert "attributes: classification, colors, heights_above_terrain, intensities, labels, " \
           "number_of_returns, positions, return_numbers)" in str(info.value)
    # and in Python
    with pytest.raises(ConfigError, match="color_by 'labes' is not a per-point attribute"):
        Pipeline((GridQuantize(), RationalBSplineTerrain(), Segmenter()),
                 ReadCloud(path=str(cloud_file)), (WriteCloud(color_by="labes"),))
    # a PLY or PCD file carries whatever it was written with: only the data can tell
    ply = tmp_path / "data" / "cloud.ply"
    write_cloud(ply, as_frame(small_cloud).with_attributes(reflectance=small_cloud[:, 2]))
    pipeline = Pipeline((GridQuantize(),), ReadCloud(path=str(ply)),
                        (WriteCloud(color_by="reflectance"),))
    assert pipeline.run(output_dir=tmp_path / "out").written
    # as does a cloud given to run() without a source
    Pipeline((GridQuantize(),), None, (WriteCloud(color_by="reflectance"),))
