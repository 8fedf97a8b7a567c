"""The Sec. VI deviation protocol (Broggi et al. 2013, Fig. 6)."""

from __future__ import annotations

import pytest

from o3d_terrain.cli import main
from o3d_terrain.deviation import run_deviation_protocol, write_deviation_outputs
from o3d_terrain.errors import ConfigError


def test_thin_obstacles_are_cut_off_at_25_control_points():
    result = run_deviation_protocol(widths=(0.8, 4.0), heights=(0.5, 2.0), control_points=(25,),
                                    methods=("robust",))
    assert len(result.rows) == 4
    for row in result.rows:
        assert 0 <= row.max_deviation_pct <= 5.0


def test_outputs_are_written(tmp_path):
    result = run_deviation_protocol(widths=(1.0,), heights=(1.0,), control_points=(5,),
                                    methods=("robust", "paper"))
    paths = write_deviation_outputs(result, tmp_path)
    names = sorted(p.name for p in paths)
    assert names == ["deviation.csv", "deviation.md", "deviation_paper.png",
                     "deviation_robust.png"]
    assert all(p.stat().st_size > 0 for p in paths)
    assert "| robust | 5 × 5 | 1 |" in (tmp_path / "deviation.md").read_text()


def test_bad_protocol_settings_are_rejected():
    with pytest.raises(ConfigError, match="heights"):
        run_deviation_protocol(heights=(-1.0,))


@pytest.mark.parametrize("settings, named", [
    ({"cell_size": 0.0}, "--cell-size"),
    ({"cell_size": -1.0}, "--cell-size"),
    ({"cell_size": float("nan")}, "--cell-size"),
    ({"cell_size": 30.0}, "--cell-size"),
    ({"widths": [0.0]}, "--widths"),
    ({"control_points": [0]}, "--control-points"),
    ({"control_points": [200]}, "--control-points"),
    ({"control_points": [5.5]}, "--control-points"),
    ({"methods": ["fast"]}, "--methods"),
    ({"methods": []}, "--methods"),
])
def test_out_of_range_settings_name_the_flag_before_any_fit(settings, named, monkeypatch):
    from o3d_terrain import deviation

    monkeypatch.setattr(deviation, "fit_grid", lambda *a, **k: pytest.fail("fitted"))
    with pytest.raises(ConfigError, match=named) as raised:
        run_deviation_protocol(**settings)
    assert "eval deviation" in str(raised.value) and "give e.g." in str(raised.value)


def test_every_bad_setting_is_reported_at_once():
    with pytest.raises(ConfigError) as raised:
        run_deviation_protocol(heights=(-1.0,), cell_size=0.0)
    assert len(raised.value.problems) == 2


@pytest.mark.parametrize("flags", [["--cell-size", "0"], ["--cell-size", "-1"],
                                   ["--control-points", "2"], ["--methods", "fast"]])
def test_the_command_exits_2_on_a_bad_flag(flags, capsys):
    assert main(["eval", "deviation", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: eval deviation: " + flags[0])
    assert "Traceback" not in err and "ZeroDivisionError" not in err
