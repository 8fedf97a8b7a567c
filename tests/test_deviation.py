"""The Sec. VI deviation protocol (Broggi et al. 2013, Fig. 6)."""

from __future__ import annotations

import pytest

from o3d_terrain.deviation import run_deviation_protocol, write_deviation_outputs
from o3d_terrain.errors import InputError


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
    with pytest.raises(InputError, match="heights"):
        run_deviation_protocol(heights=(-1.0,))
