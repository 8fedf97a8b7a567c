"""Where output files go: the one place that makes their folder (``write_cloud``,
``write_image``, the pipeline writers, the products' ``save`` methods)."""

from __future__ import annotations

import os
from pathlib import Path


def output_path(path: str | os.PathLike) -> Path:
    """``path`` as a Path with its folder created when missing: a product computed for
    minutes is not lost to a folder not made yet."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path
