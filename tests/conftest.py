"""Shared fixtures. Real-data tests use ``../shared/data`` or ``$O3D_TERRAIN_DATA`` and skip
with a reason when it is absent (a user's fresh clone has no such folder)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root() -> Path | None:
    env = os.environ.get("O3D_TERRAIN_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    return root if root.is_dir() else None


@pytest.fixture
def shared_data() -> Path:
    root = data_root()
    if root is None:
        pytest.skip("real scans not available: set O3D_TERRAIN_DATA or place ../shared/data")
    return root


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def vehicle_scan(monkeypatch):
    """Every cloud with points around its ``sensor_origin`` read as a vehicle's scan, whatever
    its density (``o3d_terrain.segment.SCAN_DENSITY_FALL`` off): for the tests of the vehicle
    path on uniform synthetic clouds, which a scan's density would make top-down tiles."""
    import o3d_terrain.segment as seg
    monkeypatch.setattr(seg, "SCAN_DENSITY_FALL", 0.0)


@pytest.fixture
def small_cloud(rng) -> np.ndarray:
    """A gently sloped ground with a box on it: 4000 points, (N, 3) float64."""
    xy = rng.uniform([0, -10], [20, 10], size=(4000, 2))
    z = 0.1 * xy[:, 0] + rng.normal(0, 0.02, len(xy))
    box = (np.abs(xy[:, 0] - 10) < 1) & (np.abs(xy[:, 1]) < 1)
    z[box] += rng.uniform(0.5, 1.5, box.sum())
    return np.column_stack([xy, z])
