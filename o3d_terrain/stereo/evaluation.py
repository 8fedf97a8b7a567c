"""Scoring a disparity map against ground truth (Middlebury-style bad-pixel rates)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["read_pfm", "disparity_errors", "lidar_in_camera"]


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM image (Middlebury ground truth) as float32, top row first; ``inf`` = unknown."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            kind = f.readline().strip()
            if kind not in (b"Pf", b"PF"):
                raise InputError(f"{path}: not a PFM file (header {kind!r})")
            width, height = (int(v) for v in f.readline().split())
            scale = float(f.readline().strip())
            channels = 3 if kind == b"PF" else 1
            data = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4", count=width * height * channels)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from exc
    except ValueError as exc:
        raise InputError(f"{path}: malformed PFM header ({exc})") from exc
    if data.size != width * height * channels:
        raise InputError(f"{path}: truncated PFM file ({data.size} of {width * height * channels} values)")
    shape = (height, width, 3) if channels == 3 else (height, width)
    return np.ascontiguousarray(np.flipud(data.reshape(shape)).astype(np.float32))


def disparity_errors(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None, *,
                     threshold: float = 3.0) -> dict[str, float]:
    """Bad-pixel rates of a disparity map (NaN = no output) against a ground truth.

    Scored pixels: finite truth, and ``mask`` (e.g. Middlebury non-occluded) when given.
    Returns ``coverage`` (share of scored pixels with an output), ``bad_over_output`` (share of
    output pixels off by more than ``threshold`` px), ``bad_over_all`` (share of all scored
    pixels that are off or have no output), ``median_error`` and ``mean_error`` (px, over output
    pixels) and ``scored_pixels``.
    """
    estimate = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if estimate.shape != truth.shape:
        raise InputError(f"the disparity map is {estimate.shape} and the truth {truth.shape}")
    scored = np.isfinite(truth)
    if mask is not None:
        scored &= np.asarray(mask, dtype=bool)
    if not scored.any():
        raise InputError("no pixel has a ground-truth disparity under the mask")
    output = scored & np.isfinite(estimate)
    error = np.abs(estimate - truth)
    bad = output & (error > threshold)
    n_scored, n_output = int(scored.sum()), int(output.sum())
    return {
        "scored_pixels": float(n_scored),
        "coverage": n_output / n_scored,
        "bad_over_output": float(bad.sum()) / n_output if n_output else float("nan"),
        "bad_over_all": float(bad.sum() + (n_scored - n_output)) / n_scored,
        "median_error": float(np.median(error[output])) if n_output else float("nan"),
        "mean_error": float(np.mean(error[output])) if n_output else float("nan"),
    }


def lidar_in_camera(points: np.ndarray, lidar_to_camera: np.ndarray, camera_matrix: np.ndarray,
                    width: int, height: int, *, min_depth: float = 0.5
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map lidar points into a camera frame and keep those the camera sees.

    Returns ``(points in the camera frame (M, 3), columns (M,), rows (M,))`` (pixel
    coordinates, float) for the points in front of the camera (depth >= ``min_depth``) that
    project inside the ``width`` × ``height`` image.
    """
    points = np.asarray(points, dtype=np.float64)[:, :3]
    transform = np.asarray(lidar_to_camera, dtype=np.float64)
    r, t = transform[:3, :3], transform[:3, 3]
    camera = np.stack([points @ r[row] + t[row] for row in range(3)], axis=1)
    depth = camera[:, 2]
    front = depth >= min_depth
    camera = camera[front]
    k = np.asarray(camera_matrix, dtype=np.float64)
    u = k[0, 0] * camera[:, 0] / camera[:, 2] + k[0, 2]
    v = k[1, 1] * camera[:, 1] / camera[:, 2] + k[1, 2]
    inside = (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
    return camera[inside], u[inside], v[inside]
