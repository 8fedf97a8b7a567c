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


def open_npz(path: str | os.PathLike, kind: str):
    """The ``.npz`` archive a product's ``save`` wrote at ``path``, opened, checked to hold a
    ``kind`` (its ``kind`` entry). ``path`` may leave out the ``.npz`` that ``numpy.savez``
    adds, as ``save`` accepts it. InputError naming the file when it is missing, not an
    archive, or another kind."""
    import numpy as np

    from .errors import InputError

    path = Path(path)
    if not path.exists() and path.suffix != ".npz" and path.with_name(path.name + ".npz").exists():
        path = path.with_name(path.name + ".npz")
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError as exc:
        raise InputError(f"{path}: no such file (a {kind} saved with {kind}.save)") from exc
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a {kind} file (not an .npz archive: {exc})") from exc
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"{path}: not a {kind} file (not an .npz archive)")
    held = str(data["kind"]) if "kind" in data.files else None
    if held != kind and not (held is None and kind == "HeightGrid"):  # older grids: no kind
        data.close()
        raise InputError(f"{path}: not a {kind} file ("
                         + (f"it holds a {held})" if held else f"no kind='{kind}')"))
    return data
