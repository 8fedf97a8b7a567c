"""The sensor found from a scan in a map frame (o3d_terrain.locate), checked against where the
synthetic sensor stood."""

import math

import numpy as np
import pytest

import o3d_terrain
from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.locate import LOCATE_MIN_POINTS, locate_sensor
from o3d_terrain.synthetic import Plane, Ramp, Scene, make_scene, sample_airborne, sample_lidar
from o3d_terrain.synthetic.sensors import rotation_matrix

#: a map frame in projected coordinates: the sensor's pose there
SENSOR = np.array([512345.0, 4123456.0, 310.0])
YAW_DEG = 57.0


def _to_map(p: np.ndarray) -> np.ndarray:
    return p @ rotation_matrix(yaw_deg=YAW_DEG).T + SENSOR


@pytest.fixture(scope="module")
def scan():
    """A 64-line lidar frame, 1.8 m up, from the middle of the 8 m top of a 2 m embankment
    with 35° flanks (a haul road), in the sensor's frame: positions and ground truth."""
    run = 2.0 / math.tan(math.radians(35.0))
    scene = Scene("embankment", (Plane(), Ramp(0.0, -4.0 - run, 90.0, 35.0, run),
                                 Ramp(0.0, 4.0, 90.0, -35.0, run)), (),
                  region=(-50.0, 50.0, -50.0, 50.0))
    cloud = sample_lidar(scene, sensor_xy=(0.0, 0.0), beams=64, azimuth_steps=1800,
                         fov_deg=(-24.8, 2.0), sensor_height=1.8, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = np.isfinite(p).all(axis=1)
    return p[keep], ~np.asarray(cloud.is_obstacle, dtype=bool)[keep]


def test_a_scan_in_a_map_frame_is_found_near_its_sensor_at_ground_level(scan):
    p, _ = scan
    found = locate_sensor(_to_map(p))
    assert found is not None
    assert math.hypot(found[0] - SENSOR[0], found[1] - SENSOR[1]) < 5.0
    # the height of the low ground around it: not above the road 1.8 m below the sensor (the
    # labels that need the sensor's height above the ground stay off), not below the foot of
    # the flanks
    road = SENSOR[2] - 1.8
    assert road - 2.2 <= found[2] <= road + 0.1


def test_segment_terrain_finds_the_sensor_of_a_map_frame_scan(scan):
    """Without sensor_origin the scan moved into a map frame is labelled from the sensor found
    in it, as with the sensor's true position, not as a top-down tile (its origin given)."""
    p, truth = scan
    q = _to_map(p)

    def f1(**options):
        _, inliers = o3d_terrain.segment_terrain(q, **options)
        ground = np.zeros(len(q), bool)
        ground[inliers] = True
        return segmentation_counts(ground, truth).f1

    found = f1()
    assert found == f1(sensor_origin=locate_sensor(q))
    assert found >= f1(sensor_origin=SENSOR) - 0.005
    assert found > f1(sensor_origin=(0.0, 0.0, 0.0)) + 0.02  # the top-down treatment


def test_a_scan_in_its_own_frame_keeps_the_origin(scan):
    p, _ = scan
    surface_default, default = o3d_terrain.segment_terrain(p)
    _, given = o3d_terrain.segment_terrain(p, sensor_origin=(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(default, given)


def test_top_down_tiles_and_drives_have_no_sensor(scan):
    """An airborne tile has no crowd of points; a strip of scans along a 280 m drive has no
    spot with half its points within 30 m; too few points say nothing."""
    tile = np.asarray(sample_airborne(make_scene("hills", seed=0), seed=0).positions)
    assert locate_sensor(tile) is None
    p, _ = scan
    drive = np.concatenate([p + (40.0 * k, 0.0, 0.0) for k in range(8)])
    assert locate_sensor(_to_map(drive)) is None
    assert locate_sensor(_to_map(p)[: LOCATE_MIN_POINTS - 1]) is None


def test_non_finite_points_are_left_out(scan):
    p, _ = scan
    q = _to_map(p)
    bad = q.copy()
    bad[::7] = np.nan
    bad[1::11, 2] = np.inf
    found, with_bad = locate_sensor(q), locate_sensor(bad)
    assert with_bad is not None
    assert math.hypot(with_bad[0] - found[0], with_bad[1] - found[1]) < 1.0
