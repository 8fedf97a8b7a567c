"""Obstacle tracking: stable identities and pruned one-frame detections on a synthetic sequence."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from o3d_terrain.errors import InputError
from o3d_terrain.obstacles import detect_obstacles
from o3d_terrain.synthetic import sequence_ground, synthetic_sequence
from o3d_terrain.synthetic.sequence import SEQUENCE_OBSTACLES, SPURIOUS
from o3d_terrain.tracking import (ObstacleTracker, _majority, run_sequence, score_tracks,
                                  track_frames, write_sequence)


def detect_on_exact_ground(frame):
    return detect_obstacles(frame, surface=sequence_ground())


@pytest.fixture(scope="module")
def sequence():
    frames = synthetic_sequence(frames=20, seed=0)
    steps = track_frames(frames, detect=detect_on_exact_ground)
    return frames, steps


def test_identities_are_stable_and_spurious_detections_pruned(sequence):
    frames, steps = sequence
    score = score_tracks(frames, steps)
    assert score.spurious >= 15  # one injected per frame, nearly all detected ...
    assert score.spurious_confirmed == 0  # ... and none carried by a confirmed track
    assert score.detected == score.tracked == len(SEQUENCE_OBSTACLES)  # every obstacle ...
    assert score.identity_switches == 0  # ... under one identity ...
    assert len({ids[0] for ids in score.tracks_of_obstacle.values()}) == len(SEQUENCE_OBSTACLES)


def test_fragments_of_one_obstacle_join_its_track(sequence):
    """The oncoming car's side, seen at grazing incidence, breaks into pieces that persist
    (lidar samples ~0.5 m apart along it, more than the clustering cell bridges). Tracked
    one-to-one they become extra confirmed tracks; as fragments they join the car's track."""
    frames, steps = sequence
    car = 4
    assert SEQUENCE_OBSTACLES[car].velocity == (-4.0, 0.0)
    pieces = [sum(_majority(f.truth[o.indices]) == car for o in s.obstacles)
              for f, s in zip(frames, steps)]
    assert max(pieces) >= 3  # the car does come out of the clustering in pieces
    one_to_one = track_frames(frames, tracker=ObstacleTracker(merge_distance=0),
                              detect=detect_on_exact_ground)
    separate = score_tracks(frames, one_to_one)
    assert len(separate.tracks_of_obstacle[car]) > 1
    for frame, step in zip(frames, steps):
        confirmed = {t.id: t for t in step.tracks}
        pieces = [o for o in step.obstacles if _majority(frame.truth[o.indices]) == car]
        ids = {step.track_of_obstacle[o.id] for o in pieces}
        if ids & set(confirmed):  # once the car is confirmed, every piece carries its id
            [track_id] = ids
            assert len(confirmed[track_id].fragments) == len(pieces) - 1


def test_velocities_of_moving_obstacles(sequence):
    """After 10 frames (1 s). Later the oncoming car's centroid lags its motion as more of
    its side comes into view (-3.4 m/s instead of -4 m/s after 2 s)."""
    frames, steps = sequence
    last = steps[9]
    frame = frames[9]
    for track in last.tracks:
        truth = _majority(frame.truth[track.obstacle.indices])
        assert truth != SPURIOUS
        np.testing.assert_allclose(track.velocity, SEQUENCE_OBSTACLES[truth].velocity, atol=0.6)


def box(x, y, length=1.0, width=1.0, ident=0):
    corners = np.array([[x + length / 2, y + width / 2], [x - length / 2, y + width / 2],
                        [x - length / 2, y - width / 2], [x + length / 2, y - width / 2]])
    return SimpleNamespace(centroid=np.array([x, y, 0.5]), id=ident,
                           indices=np.arange(int(10 * length * width)),
                           corners=lambda: corners)


def test_fragment_rules():
    tracker = ObstacleTracker(confirm_hits=2, merge_distance=0.5)
    # new obstacles 0.4 m apart start one track, led by the larger; the third is 2 m away
    tracker.update([box(10, 0, 4, 2, 0), box(12.9, 0, 1, 1, 1), box(17, 0, 1, 1, 2)], time=0.0)
    assert len(tracker.tracks) == 2
    lead, far = tracker.tracks
    assert lead.obstacle.id == 0 and [o.id for o in lead.fragments] == [1]
    np.testing.assert_allclose(lead.position, [10, 0])  # measured on the lead alone
    # a chain of pieces within reach of one another joins the tracked obstacle
    tracker.update([box(10, 0, 4, 2, 0), box(12.9, 0, 1, 1, 1), box(13.8, 0, 0.5, 0.5, 2),
                    box(17, 0, 1, 1, 3)], time=0.1)
    assert [o.id for o in lead.fragments] == [1, 2] and far.obstacle.id == 3
    assert lead.confirmed and far.confirmed and len(tracker.tracks) == 2
    # merge_distance 0: one track per obstacle
    plain = ObstacleTracker(merge_distance=0)
    plain.update([box(10, 0, 4, 2, 0), box(12.9, 0, 1, 1, 1)], time=0.0)
    assert len(plain.tracks) == 2 and not plain.tracks[0].fragments


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
    with pytest.raises(InputError, match="merge_distance must be a finite number >= 0"):
        ObstacleTracker(merge_distance=-1)
    with pytest.raises(InputError, match="is not a folder"):
        run_sequence("/no/such/folder")
    with pytest.raises(InputError, match="2 frames but 1 steps"):
        score_tracks([None, None], [None])


def test_run_sequence_reads_a_folder_in_order(tmp_path):
    frames = synthetic_sequence(frames=4, seed=5, beams=24, azimuth_steps=600)
    write_sequence(frames, tmp_path)
    assert (tmp_path / "poses.txt").is_file()
    steps = run_sequence(tmp_path, tracker=ObstacleTracker(confirm_hits=2),
                         detect=detect_on_exact_ground)
    assert [s.name for s in steps] == [f"{k:06d}.ply" for k in range(4)]
    assert [s.time for s in steps] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert len(steps[-1].tracks) >= 3
