"""Steep faces: the terrain prior's slope limit (``max_slope_deg``) through the drop-in
functions. The bench faces of a pit, steeper than the default 45 degrees, are walls to the
prior until the limit is raised (docs/algorithm.md, "Steep slopes and faces"; the thresholds
along the surface normal are tested in tests/test_segment.py)."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain.api import fit_terrain, segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar


@pytest.fixture(scope="module")
def benches():
    """Two 5.4 m benches with 55-degree faces ahead of a lidar on the pit floor, no objects."""
    run = 5.4 / math.tan(math.radians(55.0))
    scene = Scene("benches55", (Plane(), Ramp(12, 0, 0, 55.0, run),
                                Ramp(22 + run, 0, 0, 55.0, run)), ())
    cloud = sample_lidar(scene, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = ~cloud.is_outlier & np.isfinite(p).all(axis=1)
    p = p[keep]
    truth = cloud.terrain_height(p[:, 0], p[:, 1])
    return p, truth


def _rmse(surface, p, truth, mask=None):
    mask = np.ones(len(p), bool) if mask is None else mask
    e = surface(p[mask, 0], p[mask, 1]) - truth[mask]
    return float(np.sqrt(np.mean(e * e)))


def test_raising_the_slope_limit_lets_the_surface_climb_bench_faces(benches):
    p, truth = benches
    face = (p[:, 0] > 12.5) & (truth > -1.4)  # points on the first face and the bench above
    default = fit_terrain(p)
    steep = fit_terrain(p, max_slope_deg=60)
    # with the 45-degree limit the face is a wall: the surface stays metres below its top
    assert _rmse(default, p, truth, face) > 0.3
    # with 60 degrees the face is terrain and the surface follows it
    assert _rmse(steep, p, truth, face) < 0.1
    assert _rmse(steep, p, truth) < 0.06
    _, inliers = segment_terrain(p, max_slope_deg=60)
    assert np.isin(np.flatnonzero(face), inliers).mean() > 0.95
    _, inliers45 = segment_terrain(p)
    assert np.isin(np.flatnonzero(face), inliers45).mean() < 0.5


def test_the_limit_reaches_the_stage_on_every_input_path(benches):
    p, _ = benches
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    s_array, i_array = segment_terrain(p, max_slope_deg=60)
    s_cloud, i_cloud = segment_terrain(pcd, max_slope_deg=60)
    np.testing.assert_array_equal(i_array, i_cloud)
    np.testing.assert_allclose(s_array.control_points, s_cloud.control_points)


@pytest.mark.parametrize("value", [0, 90, 120, float("nan")])
def test_a_slope_limit_out_of_range_is_rejected_with_its_name(benches, value):
    p, _ = benches
    for call in (fit_terrain, segment_terrain):
        with pytest.raises(InputError, match="max_slope_deg"):
            call(p[:1000], max_slope_deg=value)

