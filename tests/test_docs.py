"""The docs stay true: generated pages are current, tutorials run, links resolve."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from o3d_terrain import STAGES, WRITERS
from o3d_terrain.docgen import stage_page

DOCS = Path(__file__).resolve().parents[1] / "docs"
REPO = DOCS.parent


@pytest.mark.parametrize("name", sorted({**STAGES, **WRITERS}))
def test_stage_pages_are_current(name):
    page = DOCS / "stages" / f"{name}.md"
    assert page.exists(), f"run: python -m o3d_terrain.docgen docs/stages ({name}.md is missing)"
    expected = stage_page({**STAGES, **WRITERS}[name])
    assert page.read_text() == expected, "stale page: run python -m o3d_terrain.docgen docs/stages"


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_quickstart_code_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    blocks = _python_blocks(DOCS / "quickstart.md")
    assert blocks
    for block in blocks:
        exec(compile(block, "quickstart.md", "exec"), namespace)  # noqa: S102 - our own docs


def test_evaluation_page_scan_against_a_raster_runs(tmp_path, monkeypatch):
    """docs/evaluation.md's scan of dem.tif and its comparison from code, as printed (the
    shared data folder put where the page's relative paths point)."""
    from o3d_terrain.evaluation.datasets import data_root

    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        pytest.skip("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    pytest.importorskip("tifffile", reason="the dem extra reads the GeoTIFF's georeferencing")
    work = tmp_path / "project"
    work.mkdir()
    (tmp_path / "shared").mkdir()
    (tmp_path / "shared" / "data").symlink_to(root, target_is_directory=True)
    monkeypatch.chdir(work)
    blocks = [b for b in _python_blocks(DOCS / "evaluation.md")
              if "scan.xyz" in b or "evaluate_terrain_against_raster" in b]
    assert len(blocks) == 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "evaluation.md", "exec"), namespace)  # noqa: S102 - our own docs
    # the figure the page prints (0.023 m) within what a platform's float rounding moves
    assert namespace["result"].stats["height_rmse_m"] == pytest.approx(0.023, abs=0.004)


def test_relative_links_resolve():
    missing = []
    for page in [REPO / "README.md", *DOCS.glob("*.md")]:
        for target in re.findall(r"\]\(([^)#:]+)\)", page.read_text()):
            if not (page.parent / target).exists():
                missing.append(f"{page.name} -> {target}")
    assert not missing, missing
