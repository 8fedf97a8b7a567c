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


def test_relative_links_resolve():
    missing = []
    for page in [REPO / "README.md", *DOCS.glob("*.md")]:
        for target in re.findall(r"\]\(([^)#:]+)\)", page.read_text()):
            if not (page.parent / target).exists():
                missing.append(f"{page.name} -> {target}")
    assert not missing, missing
