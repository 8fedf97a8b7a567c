"""Steep faces: the terrain prior's slope limit (``max_slope_deg``) through the drop-in
functions. The bench faces of a pit, steeper than 45 degrees, are walls to a 45-degree
prior (docs/algorithm.md, "Steep slopes and faces"; the thresholds along the surface normal
are tested in tests/test_segment.py). The automatic limit rises to 60 degrees on a vehicle's
scan of strong relief (docs/algorithm.md, "A steeper slope limit on strong relief") or of a
long bench face (tests/test_bench_faces.py)."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain.api import fit_terrain, segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.grid import quantize_points
from o3d_terrain.refine import steep_share
from o3d_terrain.stages import RationalBSplineTerrain
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar
from o3d_terrain.terrain import MAX_SLOPE_DEG, STEEP_LIMIT_SHARE, STEEP_MAX_SLOPE_DEG


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
    at_45 = fit_terrain(p, max_slope_deg=45)
    steep = fit_terrain(p, max_slope_deg=60)
    # with the 45-degree limit the face is a wall: the surface stays metres below its top
    assert _rmse(at_45, p, truth, face) > 0.3
    # with 60 degrees the face is terrain and the surface follows it
    assert _rmse(steep, p, truth, face) < 0.1
    assert _rmse(steep, p, truth) < 0.06
    _, inliers = segment_terrain(p, max_slope_deg=60)
    assert np.isin(np.flatnonzero(face), inliers).mean() > 0.95
    _, inliers45 = segment_terrain(p, max_slope_deg=45)
    assert np.isin(np.flatnonzero(face), inliers45).mean() < 0.5
    # the automatic limit rises on these faces by itself (tests/test_bench_faces.py)
    assert _rmse(fit_terrain(p), p, truth, face) < 0.1


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



def _pitched_scan(terrain, pitch_deg, rng, n=60_000, radius=45.0):
    """A ground sensor's scan (denser near it, 2 cm noise) of ``terrain`` over a 90 m disc,
    in the frame of a sensor pitched by ``pitch_deg`` (a vehicle tilted by the slope it
    stands on: the ground ahead rises in the cloud by that much more)."""
    r = radius * np.sqrt(rng.uniform(0.002, 1.0, n))
    r = r[rng.uniform(0, 1, n) < np.minimum(1.0, 5.0 / r)]
    a = rng.uniform(0, 2 * np.pi, r.size)
    p = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(r.size)])
    p[:, 2] = terrain(p[:, 0], p[:, 1]) + rng.normal(0, 0.02, r.size)
    t = math.radians(pitch_deg)
    rotation = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    return p @ rotation.T


def _relief(x, y):  # slopes changing by up to 45 degrees within 10-15 m, every point terrain
    return 4.0 * np.sin(x / 4.0) * np.cos(y / 5.0) - 1.8


def _plane(x, y):
    return np.full_like(x, -1.8)


def test_the_automatic_limit_rises_on_steep_relief_and_not_for_a_tilt(rng):
    stage = RationalBSplineTerrain()
    assert stage.max_slope_deg is None and stage.slope_limit == MAX_SLOPE_DEG
    relief = _pitched_scan(_relief, 25.0, rng)
    street = _pitched_scan(_plane, 25.0, rng)  # a level street under a sensor pitched 25 deg
    for p, steep in ((relief, True), (street, False)):
        grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=stage.noise_floor)
        fit = stage.fit(grid, p)
        share = steep_share(fit.robust_surface, grid)
        assert (share >= STEEP_LIMIT_SHARE) == steep, share
        # the fit says which limit it used and the share that chose it (measured on the
        # first fit's surface, before the fit with the steeper limit)
        assert fit.max_slope_deg == (STEEP_MAX_SLOPE_DEG if steep else MAX_SLOPE_DEG)
        assert (fit.relief_share >= STEEP_LIMIT_SHARE) == steep, fit.relief_share
        # the automatic limit labels as the fixed limit it chose does
        chosen = STEEP_MAX_SLOPE_DEG if steep else MAX_SLOPE_DEG
        _, auto = segment_terrain(p)
        _, fixed = segment_terrain(p, max_slope_deg=chosen)
        np.testing.assert_array_equal(auto, fixed)
    # on the relief (every point terrain) it keeps ground that the 45-degree walls reject
    # (measured: 10,064 against 9,886 of the 12,574 points; 10,014 against 9,813 before the
    # refit was made again from its own labels, which takes some of it back at 45 degrees too)
    _, at_45 = segment_terrain(relief, max_slope_deg=MAX_SLOPE_DEG)
    _, auto = segment_terrain(relief)
    assert len(auto) > len(at_45) + 0.01 * len(relief)


def test_a_given_limit_is_kept_on_steep_relief(rng):
    p = _pitched_scan(_relief, 25.0, rng)
    stage = RationalBSplineTerrain(max_slope_deg=45.0)
    grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=stage.noise_floor)
    given = stage.fit(grid, p)
    assert steep_share(given.robust_surface, grid) >= STEEP_LIMIT_SHARE
    assert given.max_slope_deg == 45.0
    auto = RationalBSplineTerrain().fit(grid, p)
    assert auto.max_slope_deg == STEEP_MAX_SLOPE_DEG
    assert not np.allclose(given.robust_surface.control_points,
                           auto.robust_surface.control_points)


def test_without_the_prior_no_slope_limit_is_recorded_or_chosen(rng):
    p = _pitched_scan(_relief, 25.0, rng)
    grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=0.03)
    plain = RationalBSplineTerrain(terrain_prior=False).fit(grid, p)
    assert plain.max_slope_deg is None
    assert plain.relief_share is not None  # still measured: the refit's layout needs it
    paper = RationalBSplineTerrain(method="paper").fit(grid, p)
    assert paper.max_slope_deg is None and paper.relief_share is None
