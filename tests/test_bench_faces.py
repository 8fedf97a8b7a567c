"""Bench faces (o3d_terrain.faces): long planar faces of 50-75 degrees in a vehicle's scan
raise the terrain prior's automatic slope limit, which the relief share of the coarse surface
does not do for a pit's benches seen from its floor (docs/algorithm.md, "Bench faces")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from o3d_terrain import terrain as terrain_module
from o3d_terrain.api import segment_terrain
from o3d_terrain.faces import FACE_MAX_LIMIT_DEG, FACE_RUN, face_limit, face_run, planar_cells
from o3d_terrain.grid import quantize_points
from o3d_terrain.refine import REFINE_MAX_CONTROL_POINTS, steep_share
from o3d_terrain.stages import RationalBSplineTerrain
from o3d_terrain.stages import terrain as terrain_stage
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar
from o3d_terrain.synthetic.scene import default_obstacles
from o3d_terrain.synthetic.sensors import rotation_matrix
from o3d_terrain.terrain import (
    MAX_SLOPE_DEG,
    STEEP_LIMIT_SHARE,
    STEEP_MAX_SLOPE_DEG,
    sensor_ground_plane,
)


def _surface_points(rng, u_length, v_length, spacing=0.1):
    """Points on a (u_length x v_length) m patch spanned by u and v, jittered by 1 cm."""
    u, v = np.meshgrid(np.arange(0, u_length, spacing), np.arange(0, v_length, spacing))
    return u.ravel(), v.ravel(), rng.normal(0, 0.01, u.size)


def _face(rng, angle_deg, length=20.0, height=6.0):
    """A face rising at ``angle_deg`` along +x, ``length`` m along y, ``height`` m high."""
    run = height / math.tan(math.radians(angle_deg)) if angle_deg < 90 else 0.0
    s, t, e = _surface_points(rng, math.hypot(run, height), length)
    a = math.radians(angle_deg)
    return np.column_stack([s * math.cos(a) + e * math.sin(a), t, s * math.sin(a) - e * math.cos(a)])


def _run(points, up=(0.0, 0.0, 1.0)):
    grid = quantize_points(points, cell_size=0.5)
    return face_run(planar_cells(grid, points), up)[0]


def test_the_faces_tilt_sets_the_limit_between_60_and_70_degrees(rng):
    for angle in (55.0, 62.0, 72.0):
        p = _face(rng, angle)
        run, tilt = face_run(planar_cells(quantize_points(p, cell_size=0.5), p), (0, 0, 1))
        assert run >= FACE_RUN and abs(tilt - angle) < 1.0
    assert face_limit(55.0) == STEEP_MAX_SLOPE_DEG
    assert face_limit(62.0) == 67.0
    assert face_limit(72.0) == FACE_MAX_LIMIT_DEG


def test_a_long_steep_plane_is_a_face_and_a_wall_or_level_ground_is_not(rng):
    assert _run(_face(rng, 60.0)) >= FACE_RUN
    assert _run(_face(rng, 70.0)) >= FACE_RUN
    assert _run(_face(rng, 90.0)) == 0.0  # a wall
    assert _run(_face(rng, 30.0)) == 0.0  # a slope the default limit takes
    assert _run(_face(rng, 60.0, length=4.0)) < FACE_RUN  # a short one: a windscreen's size
    # rough ground (a hedge, a bush) is not planar
    rough = np.column_stack([rng.uniform(0, 20, 40_000), rng.uniform(0, 3, 40_000),
                             rng.uniform(0, 2, 40_000)])
    assert _run(rough) == 0.0


def test_the_tilt_is_measured_from_the_ground_normal_given(rng):
    # a wall and its ground, seen by a sensor pitched 25 degrees: the wall leans 65 degrees
    # in the cloud's frame, but stands at 90 degrees on the ground's normal
    wall = _face(rng, 90.0)
    gx, gy, ge = _surface_points(rng, 10.0, 20.0)
    ground = np.column_stack([-gx - 0.3, gy, ge])
    turn = rotation_matrix(pitch_deg=25.0)
    p = np.vstack([wall, ground]) @ turn.T
    up = turn @ np.array([0.0, 0.0, 1.0])
    assert _run(p, up) == 0.0
    assert _run(p) >= FACE_RUN  # measured from the cloud's z the wall would pass for a face


def test_face_cells_of_an_empty_or_flat_grid(rng):
    flat = np.column_stack([rng.uniform(0, 10, 5000), rng.uniform(0, 10, 5000),
                            np.zeros(5000)])
    grid = quantize_points(flat, cell_size=0.5)
    faces = planar_cells(grid, flat)
    assert faces.cells.size == 0 and face_run(faces, (0, 0, 1))[0] == 0.0


@pytest.fixture(scope="module")
def pit():
    """Four 6 m benches with 55-degree faces and 8 m berms ahead of a lidar on the pit floor,
    with the default obstacles: the berms above the sensor are not seen, so the surface the
    45-degree prior lets through stays flat and the relief share is 0."""
    run = 6.0 / math.tan(math.radians(55.0))
    features = (Plane(),) + tuple(Ramp(10 + k * (run + 8), 0, 0, 55.0, run) for k in range(4))
    scene = Scene("pit55", features, default_obstacles(0), region=(-30, 60, -30, 30))
    cloud = sample_lidar(scene, beams=32, azimuth_steps=900, fov_deg=(-24.8, 2.0), seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = ~cloud.is_outlier & np.isfinite(p).all(axis=1)
    return p[keep], ~np.asarray(cloud.is_obstacle, dtype=bool)[keep]


def test_a_pits_bench_faces_raise_the_automatic_limit(pit):
    p, ground = pit
    stage = RationalBSplineTerrain()
    grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=stage.noise_floor)
    # the relief rule does not see the benches: the 45-degree surface stays flat ...
    at_limit = RationalBSplineTerrain(max_slope_deg=MAX_SLOPE_DEG).fit(grid, p)
    assert steep_share(at_limit.robust_surface, grid) < STEEP_LIMIT_SHARE
    fit = stage.fit(grid, p)
    assert fit.face_run >= FACE_RUN  # ... their faces do
    assert fit.max_slope_deg == STEEP_MAX_SLOPE_DEG
    # the automatic limit labels as the fixed one it chose, and finds the faces' ground
    _, auto = segment_terrain(p)
    _, fixed = segment_terrain(p, max_slope_deg=STEEP_MAX_SLOPE_DEG)
    np.testing.assert_array_equal(auto, fixed)
    _, at_45 = segment_terrain(p, max_slope_deg=MAX_SLOPE_DEG)
    found = np.zeros(len(p), bool)
    found[auto] = True
    found_45 = np.zeros(len(p), bool)
    found_45[at_45] = True
    assert found[ground].mean() > found_45[ground].mean() + 0.05
    # a limit the user gives is kept
    given = RationalBSplineTerrain(max_slope_deg=45.0).fit(grid, p)
    assert given.max_slope_deg == 45.0 and given.face_run is None


def test_bench_faces_give_the_refit_the_layout_of_steep_relief(pit, monkeypatch):
    # the faces' berms and toes are slopes that change within a few metres: the refit takes
    # the finer layout of steep relief for them, even where the share of the ground whose
    # slope changes stays below STEEP_SHARE (0.193 on a pit seen from its first berm, 4 m up)
    p, _ = pit
    monkeypatch.setattr(terrain_stage, "STEEP_SHARE", 1.0)  # no share is steep relief
    stage = RationalBSplineTerrain()
    grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=stage.noise_floor)
    fit = stage.fit(grid, p)
    assert fit.face_run >= FACE_RUN
    assert max(fit.surface.control_points.shape) > REFINE_MAX_CONTROL_POINTS
    # without a face, a share below STEEP_SHARE keeps the refit's usual cap
    monkeypatch.setattr(terrain_stage, "FACE_RUN", math.inf)
    fit = stage.fit(grid, p)
    assert max(fit.surface.control_points.shape) <= REFINE_MAX_CONTROL_POINTS


def test_a_face_beside_the_sensor_does_not_tilt_its_ground_plane(rng):
    # level ground around the sensor and a 65-degree face 4 m ahead of it, inside the radius
    # the plane is fitted over: the face's cells slope more than 50 degrees from level and
    # stay out of the plane (in it they tilted the plane by ~17 degrees)
    gx, gy, ge = _surface_points(rng, 30.0, 30.0, spacing=0.2)
    ground = np.column_stack([gx - 26.0, gy - 15.0, ge - 4.0])
    face = _face(rng, 65.0, length=30.0) + np.array([4.0, -15.0, -4.0])
    p = np.vstack([ground, face])
    gx, gy = sensor_ground_plane(quantize_points(p, cell_size=0.5), (0.0, 0.0, 0.0))
    assert math.degrees(math.atan(math.hypot(gx, gy))) < 0.2
    # a pitched sensor: the face leans back or forward in its frame (to 40 degrees at 25
    # pitch, within the limit from level); measured from the first plane it is left out again
    for pitch in (15.0, 25.0, -15.0):
        turned = p @ rotation_matrix(pitch_deg=pitch).T
        gx, gy = sensor_ground_plane(quantize_points(turned, cell_size=0.5), (0.0, 0.0, 0.0))
        assert abs(math.degrees(math.atan(math.hypot(gx, gy))) - abs(pitch)) < 0.2


def test_a_vehicle_on_a_berm_finds_the_face_above_it():
    # a haul truck's lidar 4 m up in the middle of an 8 m berm: the 65-degree face above it
    # 4 m ahead, its top not seen; the benches below behind it
    run = 6.0 / math.tan(math.radians(65.0))
    features = (Plane(),) + tuple(Ramp(10 + k * (run + 8), 0, 0, 65.0, run) for k in range(4))
    scene = Scene("pit65", features, (), region=(-30, 70, -40, 40))
    cloud = sample_lidar(scene, sensor_xy=(10 + run + 4, 0.0), sensor_height=4.0, beams=32,
                         azimuth_steps=900, fov_deg=(-24.8, 2.0), seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    p = p[~cloud.is_outlier & np.isfinite(p).all(axis=1)]
    stage = RationalBSplineTerrain()
    grid = quantize_points(p, cell_size=0.5, plane=True, tilt_spread=stage.noise_floor)
    assert math.hypot(*sensor_ground_plane(grid, (0.0, 0.0, 0.0))) < math.tan(math.radians(2.0))
    fit = stage.fit(grid, p)
    assert fit.face_run >= FACE_RUN and fit.max_slope_deg > 65.0


def test_the_berm_a_vehicle_stands_on_is_terrain():
    # a pickup's lidar 1.8 m up on the second berm of 45-degree benches: the faces down to the
    # berm and the floor below face away from it, so the lowest cells around (the floor) do
    # not reach its berm through the scan; the ground it stands on seeds the prior
    run = 6.0
    features = (Plane(),) + tuple(Ramp(10 + k * (run + 8), 0, 0, 45.0, run) for k in range(4))
    scene = Scene("pit45", features, (), region=(-40, 70, -40, 40))
    cloud = sample_lidar(scene, sensor_xy=(10 + 2 * run + 8 + 4, 0.0), beams=64,
                         azimuth_steps=900, fov_deg=(-24.8, 2.0), seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    p = p[~cloud.is_outlier & np.isfinite(p).all(axis=1)]
    _, inliers = segment_terrain(p)
    found = np.zeros(len(p), bool)
    found[inliers] = True
    berm = np.hypot(p[:, 0], p[:, 1]) < 15.0  # the berm and the face above it, no object
    assert found[berm].mean() > 0.97  # 0.385 without the sensor's seeds
    assert found.mean() > 0.97


@pytest.mark.parametrize("yaw", [0.0, 20.0, 45.0])
def test_a_face_at_an_angle_to_the_grid_is_terrain_as_one_along_it(yaw):
    # a pickup's lidar 1.8 m up on the first berm of 65-degree benches, the scan turned about
    # the sensor: the face 4 m ahead runs along the grid's y axis, or across its cells. A cell
    # of the turned face spans up to sqrt(2) times the face's rise along an axis, which the
    # rise across a cell must allow (neighbour_rise; with the steepest neighbour slope,
    # 0.22 of the face was found at 20 degrees, 0.99 along the axis and at 45 degrees)
    run = 6.0 / math.tan(math.radians(65.0))
    features = (Plane(),) + tuple(Ramp(10 + k * (run + 8), 0, 0, 65.0, run) for k in range(4))
    scene = Scene("pit65", features, (), region=(-30, 70, -40, 40))
    cloud = sample_lidar(scene, sensor_xy=(10 + run + 4, 0.0), beams=64, azimuth_steps=900,
                         fov_deg=(-24.8, 2.0), seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    p = p[~cloud.is_outlier & np.isfinite(p).all(axis=1)]
    face = (p[:, 0] > 4.0) & (p[:, 0] < 4.0 + run) & (p[:, 2] > -1.5)  # the face above
    _, inliers = segment_terrain(p @ rotation_matrix(yaw_deg=yaw).T)
    found = np.zeros(len(p), bool)
    found[inliers] = True
    assert face.sum() > 5000
    assert found[face].mean() > 0.95
    assert found.mean() > 0.97


def test_the_edges_of_a_raised_road_stay_terrain():
    # a pickup on a 3 m embankment with 35-degree flanks and an 8 m top: the flanks face
    # away from the lidar, the surface rounds the top's edges; the cells at the level of the
    # ground the vehicle stands on keep their weight a little further above it (LEVEL_WIDEN)
    run = 3.0 / math.tan(math.radians(35.0))
    features = (Plane(), Ramp(0, -4 - run, 90, 35.0, run), Ramp(0, 4, 90, -35.0, run))
    scene = Scene("embankment", features, (), region=(-40, 40, -40, 40))
    cloud = sample_lidar(scene, beams=64, azimuth_steps=900, fov_deg=(-24.8, 2.0), seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    p = p[~cloud.is_outlier & np.isfinite(p).all(axis=1)]
    _, inliers = segment_terrain(p)
    found = np.zeros(len(p), bool)
    found[inliers] = True
    edges = (np.abs(p[:, 1]) > 2.5) & (np.abs(p[:, 1]) < 4.5)
    assert found[edges].mean() > 0.9  # 0.072 before
    assert found.mean() > 0.95  # 0.820 before


def test_the_top_of_a_raised_road_seen_from_a_cab_stays_terrain():
    # a haul truck's lidar 4 m above a 6 m top, 2 m above the ground, flanks of 30 degrees
    # along the grid's x axis: the refit's 40 control points (2.5 m apart) ring by about
    # 0.1 m across the top, beyond the 0.13 m threshold. The misfit below the surface
    # widens the threshold there only if a block can count its 20 cells: blocks of two
    # spacings were 5 x 5 cells (0.75 of the top found), they are 7 x 7 at least (0.95)
    run = 2.0 / math.tan(math.radians(30.0))
    features = (Plane(), Ramp(0, -3 - run, 90, 30.0, run), Ramp(0, 3, 90, -30.0, run))
    scene = Scene("embankment", features, (), region=(-50, 50, -50, 50))
    cloud = sample_lidar(scene, beams=64, azimuth_steps=900, fov_deg=(-24.8, 2.0),
                         sensor_height=4.0, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    p = p[~cloud.is_outlier & np.isfinite(p).all(axis=1)]
    _, inliers = segment_terrain(p)
    found = np.zeros(len(p), bool)
    found[inliers] = True
    top = np.abs(p[:, 1]) < 3.0
    assert top.sum() > 3000
    assert found[top].mean() > 0.9


def test_the_sensors_ground_height_is_the_level_it_stands_on(rng):
    # an 8 m strip 3 m above wide ground on both sides, the sensor 1.8 m above the strip and
    # no points within 3 m of it (a lidar's blind ring): the least-squares plane through 15 m
    # sits between the levels, the ground under the sensor is the strip's
    x = rng.uniform(-15, 15, 60_000)
    y = rng.uniform(-15, 15, 60_000)
    z = np.where(np.abs(y) < 4.0, -1.8, -4.8) + rng.normal(0, 0.01, x.size)
    keep = np.hypot(x, y) > 3.0
    grid = quantize_points(np.column_stack([x, y, z])[keep], cell_size=0.5)
    gx, gy, height = terrain_module._sensor_ground(grid, (0.0, 0.0, 0.0))
    assert abs(gx) < 0.01 and abs(gy) < 0.01
    assert abs(height + 1.8) < 0.05
    seeds = terrain_module._sensor_seeds(grid, (0.0, 0.0, 0.0), (gx, gy, height), 0.09)
    ys = grid.y_centers[np.nonzero(seeds)[1]]
    assert seeds.any() and np.all(np.abs(ys) < 4.0)  # the strip's cells only
