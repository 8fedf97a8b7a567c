"""Obstacle tracking: stable identities and pruned one-frame detections on a synthetic sequence."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.obstacles import detect_obstacles
from o3d_terrain.spline import TerrainSurface, clamped_uniform_knots
from o3d_terrain.tracking import (ObstacleTracker, run_sequence, synthetic_sequence,
                                  track_frames, write_sequence)

SENSOR_HEIGHT = 1.8  # synthetic_sequence's lidar height over its flat ground


def flat_surface(z, half=100.0) -> TerrainSurface:
    knots = clamped_uniform_knots(4, 3, -half, half)
    return TerrainSurface(3, knots, knots, np.zeros((4, 4)), np.ones((4, 4)), (0.0, 0.0, z))


@pytest.fixture(scope="module")
def sequence():
    frames = synthetic_sequence(frames=10, seed=4)
    surface = flat_surface(-SENSOR_HEIGHT)  # the exact ground in the (untilted) sensor frame
    steps = track_frames(frames, detect=lambda f: detect_obstacles(f, surface=surface))
    return frames, steps


def majority(values):
    keys, counts = np.unique(values, return_counts=True)
    return int(keys[counts.argmax()])


def test_identities_are_stable_and_spurious_detections_pruned(sequence):
    frames, steps = sequence
    identities: dict[int, set] = {}
    spurious = 0
    for frame, step in zip(frames, steps):
        confirmed = {t.id for t in step.tracks}
        for obstacle in step.obstacles:
            truth = majority(frame.truth[obstacle.indices])
            track = step.track_of_obstacle.get(obstacle.id)
            if truth == -3:
                spurious += 1
                assert track not in confirmed  # a one-frame detection never gets confirmed
            elif truth >= 0 and track in confirmed:
                identities.setdefault(truth, set()).add(track)
    assert spurious == len(frames)  # one injected per frame, each detected ...
    scene_obstacles = 5
    assert len(identities) == scene_obstacles  # ... every real obstacle is tracked ...
    assert all(len(ids) == 1 for ids in identities.values())  # ... under one identity
    assert len({next(iter(ids)) for ids in identities.values()}) == scene_obstacles


def test_velocities_of_moving_obstacles(sequence):
    frames, steps = sequence
    last = steps[-1]
    frame = frames[-1]
    scene_velocity = {3: (0.0, 1.4), 4: (-4.0, 0.0), 0: (0.0, 0.0), 1: (0.0, 0.0),
                      2: (0.0, 0.0)}  # as built by synthetic_sequence
    for track in last.tracks:
        truth = majority(frame.truth[track.obstacle.indices])
        np.testing.assert_allclose(track.velocity, scene_velocity[truth], atol=0.6)


def test_confirmation_and_drop_rules():
    tracker = ObstacleTracker(confirm_hits=3, max_misses=1, gate=1.0)
    seen = [SimpleNamespace(centroid=np.array([5.0, 0.0, 0.0]), id=0)]
    assert tracker.update(seen, time=0.0) == []
    assert tracker.update(seen, time=0.1) == []
    [track] = tracker.update(seen, time=0.2)
    assert track.hits == 3 and track.confirmed
    assert tracker.update([], time=0.3) == [track]  # one miss is tolerated
    assert tracker.update([], time=0.4) == []  # the second drops it
    assert tracker.tracks == []
    far = [SimpleNamespace(centroid=np.array([9.0, 0.0, 0.0]), id=0)]
    tracker.update(seen, time=0.5)
    tracker.update(far, time=0.6)  # out of the gate: a new tentative track, the old one dropped
    assert [t.hits for t in tracker.tracks] == [1]


def test_poses_move_detections_to_the_world():
    still = [SimpleNamespace(centroid=np.array([10.0, 0.0, 0.0]), id=0)]
    tracker = ObstacleTracker(confirm_hits=2)
    for k in range(4):  # the sensor drives 1 m per frame towards a static obstacle
        pose = np.eye(4)
        pose[0, 3] = float(k)
        obstacle = [SimpleNamespace(centroid=np.array([10.0 - k, 0.0, 0.0]), id=0)]
        confirmed = tracker.update(obstacle, time=0.1 * k, world_from_sensor=pose)
    [track] = confirmed
    np.testing.assert_allclose(track.position, [10.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(track.velocity, [0.0, 0.0], atol=1e-6)
    assert still  # without poses the same detections would move at -10 m/s


def test_errors():
    with pytest.raises(InputError, match="confirm_hits must be an integer > 0, got 0"):
        ObstacleTracker(confirm_hits=0)
    tracker = ObstacleTracker()
    tracker.update([], time=1.0)
    with pytest.raises(InputError, match="time must increase"):
        tracker.update([], time=1.0)
    with pytest.raises(InputError, match="4x4"):
        tracker.update([], time=2.0, world_from_sensor=np.eye(3))
    with pytest.raises(InputError, match="is not a folder"):
        run_sequence("/no/such/folder")


def test_run_sequence_reads_a_folder_in_order(tmp_path):
    frames = synthetic_sequence(frames=4, seed=5, beams=24, azimuth_steps=600)
    write_sequence(frames, tmp_path)
    assert (tmp_path / "poses.txt").is_file()
    surface = flat_surface(-SENSOR_HEIGHT)
    steps = run_sequence(tmp_path, tracker=ObstacleTracker(confirm_hits=2),
                         detect=lambda f: detect_obstacles(f, surface=surface))
    assert [s.name for s in steps] == [f"{k:06d}.ply" for k in range(4)]
    assert [s.time for s in steps] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert len(steps[-1].tracks) >= 3
