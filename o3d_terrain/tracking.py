"""Obstacle tracking over a sequence of frames: constant-velocity Kalman tracks.

Broggi et al. 2013 prune false positives with a Kalman filter. Each obstacle's centroid (x, y)
is a measurement. Tracks hold a constant-velocity state (x, y, vx, vy); each frame they are
predicted to the frame's time, associated one-to-one with the new obstacles by the Hungarian
method on the distance between predicted and measured positions (pairs farther apart than
``gate`` metres are never associated), then corrected. A track is *confirmed* after
``confirm_hits`` associated frames and dropped after more than ``max_misses`` consecutive
frames without one (a tentative track at its first miss), so an obstacle seen in a single
frame never becomes a confirmed track.

One object can come out of the clustering as several obstacles: a surface seen at grazing
incidence (the side of a car ahead) is sampled more sparsely along it than the clustering cell
bridges, so it breaks into pieces that persist from frame to frame. An obstacle left without a
track by the assignment whose box lies within ``merge_distance`` metres of the box of an
obstacle a track took this frame (or of another such fragment) is a *fragment* of that
object: it joins that track (``Track.fragments``) instead of starting one; obstacles without
a track that are that close to each other start one track, measured on the one with the most
points. A track's Kalman measurement is the centroid of the obstacle the assignment gave it
(fragments come and go with the sampling, so they do not move the centroid).

With poses (``world_from_sensor`` 4x4 per frame) the tracks live in the world frame, so the
vehicle's own motion does not look like obstacle motion; without poses they live in the
sensor frame and association is by nearest neighbour there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .errors import InputError
from .frame import Frame, as_frame

__all__ = ["Track", "ObstacleTracker", "SequenceFrame", "SequenceStep", "track_frames",
           "run_sequence", "read_poses", "write_sequence", "TrackScore", "score_tracks"]


@dataclass
class Track:
    """One tracked obstacle. ``state`` is (x, y, vx, vy) in the tracking frame (m, m/s)."""

    id: int
    state: np.ndarray
    covariance: np.ndarray
    time: float
    hits: int = 1
    misses: int = 0
    confirmed: bool = False
    obstacle: Any = None  # the obstacle associated in the latest frame (None on a miss)
    fragments: list = field(default_factory=list)  # the latest frame's fragments (see module)

    @property
    def position(self) -> np.ndarray:
        return self.state[:2].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.state[2:].copy()


def _check(name: str, value, *, integer: bool = False, allow_zero: bool = False) -> str | None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        return (f"{name} must be {'an integer' if integer else 'a finite number'} "
                f"{'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return None


class ObstacleTracker:
    """Constant-velocity Kalman tracks of obstacle centroids (see the module docstring).

    confirm_hits: associated frames before a track is confirmed. max_misses: consecutive
    frames a confirmed track survives without an association. gate: largest distance (m)
    between a predicted track and an obstacle that may be associated. acceleration_noise:
    standard deviation of the unmodelled acceleration (m/s²). measurement_noise: standard
    deviation of a centroid measurement (m). merge_distance: largest gap (m) between the boxes
    of an obstacle without a track and of an obstacle a track took for the first to join
    that track as a fragment; 0 = every obstacle without a track starts one.
    """

    def __init__(self, *, confirm_hits: int = 3, max_misses: int = 2, gate: float = 2.0,
                 acceleration_noise: float = 2.0, measurement_noise: float = 0.3,
                 merge_distance: float = 0.5) -> None:
        problems = [p for p in (
            _check("confirm_hits", confirm_hits, integer=True),
            _check("max_misses", max_misses, integer=True, allow_zero=True),
            _check("gate", gate), _check("acceleration_noise", acceleration_noise),
            _check("measurement_noise", measurement_noise),
            _check("merge_distance", merge_distance, allow_zero=True)) if p]
        if problems:
            raise InputError("ObstacleTracker: " + "; ".join(problems))
        self.confirm_hits = int(confirm_hits)
        self.max_misses = int(max_misses)
        self.gate = float(gate)
        self.acceleration_noise = float(acceleration_noise)
        self.measurement_noise = float(measurement_noise)
        self.merge_distance = float(merge_distance)
        self.tracks: list[Track] = []
        self._next_id = 0
        self._time: float | None = None

    # -- Kalman steps ----------------------------------------------------------------------
    def _predict(self, track: Track, time: float) -> None:
        dt = time - track.time
        if dt <= 0:
            return
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        q1 = np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]) * self.acceleration_noise**2
        q = np.zeros((4, 4))
        q[np.ix_([0, 2], [0, 2])] = q1
        q[np.ix_([1, 3], [1, 3])] = q1
        track.state = f @ track.state
        track.covariance = f @ track.covariance @ f.T + q
        track.time = time

    def _correct(self, track: Track, z: np.ndarray) -> None:
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        r = np.eye(2) * self.measurement_noise**2
        s = h @ track.covariance @ h.T + r
        k = track.covariance @ h.T @ np.linalg.inv(s)
        track.state = track.state + k @ (z - h @ track.state)
        track.covariance = (np.eye(4) - k @ h) @ track.covariance

    def _new_track(self, z: np.ndarray, time: float, obstacle: Any) -> Track:
        covariance = np.diag([self.measurement_noise**2] * 2 + [4.0**2] * 2)
        track = Track(self._next_id, np.array([z[0], z[1], 0.0, 0.0]), covariance, time,
                      obstacle=obstacle, confirmed=self.confirm_hits <= 1)
        self._next_id += 1
        return track

    # -- one frame -------------------------------------------------------------------------
    def update(self, obstacles: Iterable[Any], *, time: float,
               world_from_sensor: np.ndarray | None = None) -> list[Track]:
        """Feed one frame's obstacles (objects with ``centroid``); return the confirmed tracks.

        time: the frame's time (s), increasing. world_from_sensor: the frame's 4x4 pose; when
        given, centroids are moved into the world frame before association.
        """
        problems = []
        if not (isinstance(time, (int, float, np.integer, np.floating)) and math.isfinite(time)):
            problems.append(f"time must be a finite number of seconds, got {time!r}")
        elif self._time is not None and time <= self._time:
            problems.append(f"time must increase from frame to frame: got {time} after "
                            f"{self._time}")
        pose = None
        if world_from_sensor is not None:
            pose = np.asarray(world_from_sensor, dtype=np.float64)
            if pose.shape != (4, 4) or not np.isfinite(pose).all():
                problems.append(f"world_from_sensor must be a finite 4x4 matrix, got shape "
                                f"{pose.shape}")
        if problems:
            raise InputError("ObstacleTracker.update: " + "; ".join(problems))
        self._time = float(time)
        obstacles = list(obstacles)
        centroids = np.array([np.asarray(o.centroid, dtype=np.float64)[:3] for o in obstacles])
        centroids = centroids.reshape(-1, 3)
        if pose is not None and len(centroids):
            centroids = centroids @ pose[:3, :3].T + pose[:3, 3]
        measured = centroids[:, :2]
        for track in self.tracks:
            self._predict(track, float(time))
            track.obstacle = None
            track.fragments = []
        pairs: list[tuple[int, int]] = []
        if self.tracks and len(measured):
            from scipy.optimize import linear_sum_assignment

            predicted = np.array([t.state[:2] for t in self.tracks])
            distance = np.linalg.norm(predicted[:, None, :] - measured[None, :, :], axis=2)
            big = 1e6
            rows, cols = linear_sum_assignment(np.where(distance <= self.gate, distance, big))
            pairs = [(r, c) for r, c in zip(rows, cols) if distance[r, c] <= self.gate]
        matched_tracks = {r for r, _ in pairs}
        matched_obstacles = {c for _, c in pairs}
        for r, c in pairs:
            track = self.tracks[r]
            self._correct(track, measured[c])
            track.hits += 1
            track.misses = 0
            track.obstacle = obstacles[c]
            if track.hits >= self.confirm_hits:
                track.confirmed = True
        owner_of = self._fragments(obstacles, pairs, centroids, pose)
        track_of = {c: self.tracks[r] for r, c in pairs}
        for c in sorted(owner_of):
            if owner_of[c] in track_of:
                track_of[owner_of[c]].fragments.append(obstacles[c])
        survivors = []
        for index, track in enumerate(self.tracks):
            if index not in matched_tracks:
                track.misses += 1
                if not track.confirmed or track.misses > self.max_misses:
                    continue
            survivors.append(track)
        new_tracks = {}
        for c in range(len(measured)):
            if c not in matched_obstacles and c not in owner_of:
                new_tracks[c] = self._new_track(measured[c], float(time), obstacles[c])
                survivors.append(new_tracks[c])
        for c in sorted(owner_of):
            if owner_of[c] in new_tracks:
                new_tracks[owner_of[c]].fragments.append(obstacles[c])
        self.tracks = survivors
        return self.confirmed()

    def confirmed(self) -> list[Track]:
        return [t for t in self.tracks if t.confirmed]

    def _fragments(self, obstacles: list, pairs: list[tuple[int, int]], centroids: np.ndarray,
                   pose: np.ndarray | None) -> dict[int, int]:
        """Fragments among the obstacles the assignment left without a track: obstacle index
        -> index of the obstacle whose object it belongs to (the owner). An obstacle within
        ``merge_distance`` of one a track took (boxes, chained through other fragments; the
        nearest wins) belongs to that one; the rest are grouped the same way among themselves
        and each group's owner is its obstacle with the most points."""
        taken = [c for _, c in pairs]
        free = [c for c in range(len(obstacles)) if c not in set(taken)]
        if self.merge_distance <= 0 or not free:
            return {}
        boxes = {c: _world_box(obstacles[c], centroids[c], pose) for c in taken + free}
        owner_of: dict[int, int] = {}

        def spread(frontier: list[int], free: list[int]) -> list[int]:
            while frontier and free:
                gap = np.array([[_box_gap(boxes[f], boxes[a]) for a in frontier]
                                for f in free])
                near = gap.min(axis=1) <= self.merge_distance
                joined = [f for f, ok in zip(free, near) if ok]
                for f, row in zip(free, gap):
                    if row.min() <= self.merge_distance:
                        a = frontier[int(row.argmin())]
                        owner_of[f] = owner_of.get(a, a)
                free = [f for f in free if f not in owner_of]
                frontier = joined
            return free

        free = spread(taken, free)
        while len(free) > 1:  # groups among the rest, each led by its largest obstacle
            lead = max(free, key=lambda c: (_point_count(obstacles[c]), -c))
            free = [f for f in free if f != lead]
            group_free = spread([lead], free)
            free = [f for f in free if f in group_free]
        return owner_of

def _point_count(obstacle: Any) -> int:
    indices = getattr(obstacle, "indices", None)
    return 0 if indices is None else len(indices)


def _world_box(obstacle: Any, centroid: np.ndarray, pose: np.ndarray | None) -> np.ndarray:
    """An obstacle's box corners (4, 2) in the tracking frame; its centroid (repeated) when it
    has no box."""
    if hasattr(obstacle, "corners"):
        corners = np.asarray(obstacle.corners(), dtype=np.float64)
        if pose is not None:
            z = np.asarray(obstacle.centroid, dtype=np.float64)[2]
            points = np.column_stack([corners, np.full(len(corners), z)])
            corners = (points @ pose[:3, :3].T + pose[:3, 3])[:, :2]
        return corners
    return np.repeat(centroid[None, :2], 4, axis=0)


def _segment_gap(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    d = b - a
    length2 = float(d @ d)
    t = 0.0 if length2 == 0 else min(max(float((p - a) @ d) / length2, 0.0), 1.0)
    return float(np.hypot(*(p - a - t * d)))


def _inside(p: np.ndarray, polygon: np.ndarray) -> bool:
    """p inside or on a convex polygon (either orientation); False for a degenerate one."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    area = float(np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1)
                        - np.roll(polygon[:, 0], -1) * polygon[:, 1]))
    if abs(area) < 1e-12:
        return False
    cross = edges[:, 0] * (p[1] - polygon[:, 1]) - edges[:, 1] * (p[0] - polygon[:, 0])
    return bool(np.all(cross * np.sign(area) >= 0))


def _crosses(a0, a1, b0, b1) -> bool:
    def side(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    return (side(a0, a1, b0) * side(a0, a1, b1) < 0) and (side(b0, b1, a0) * side(b0, b1, a1) < 0)


def _box_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (m) between two convex quadrilaterals (4, 2); 0 when they overlap."""
    if any(_inside(p, b) for p in a) or any(_inside(p, a) for p in b):
        return 0.0
    for i in range(4):
        for j in range(4):
            if _crosses(a[i], a[(i + 1) % 4], b[j], b[(j + 1) % 4]):
                return 0.0
    return min(min(_segment_gap(p, b[j], b[(j + 1) % 4]) for p in a for j in range(4)),
               min(_segment_gap(p, a[j], a[(j + 1) % 4]) for p in b for j in range(4)))


# ---------------------------------------------------------------------------------------------
# sequences


@dataclass(frozen=True, eq=False)
class SequenceFrame:
    """One frame of a sequence: a cloud, its time (s) and its pose (4x4 world_from_sensor or
    None). ``truth`` (N,) int, optional: synthetic obstacle index per point, -1 terrain,
    -3 a spurious one-frame cluster."""

    cloud: Any
    time: float
    world_from_sensor: np.ndarray | None = None
    truth: np.ndarray | None = None
    name: str = ""


@dataclass(frozen=True, eq=False)
class SequenceStep:
    """What the tracker made of one frame."""

    name: str
    time: float
    obstacles: Any  # the frame's ObstacleSet
    tracks: list[Track]  # the confirmed tracks after this frame (copies of id and state)
    track_of_obstacle: dict[int, int] = field(default_factory=dict)  # obstacle id -> track id
    # (fragments included)


def _default_detect(frame: Frame):
    from .obstacles import detect_obstacles

    return detect_obstacles(frame)


def track_frames(frames: Iterable[SequenceFrame], *, tracker: ObstacleTracker | None = None,
                 detect: Callable[[Frame], Any] | None = None,
                 use_poses: bool = True) -> list[SequenceStep]:
    """Detect obstacles in each frame (``detect(frame) -> ObstacleSet``; default: fit the
    terrain and :func:`~o3d_terrain.obstacles.detect_obstacles`) and track them."""
    tracker = tracker if tracker is not None else ObstacleTracker()
    detect = detect if detect is not None else _default_detect
    steps = []
    for frame in frames:
        obstacles = detect(as_frame(frame.cloud))
        pose = frame.world_from_sensor if use_poses else None
        confirmed = tracker.update(obstacles, time=frame.time, world_from_sensor=pose)
        mapping = {}
        for track in tracker.tracks:
            for obstacle in ([track.obstacle] if track.obstacle is not None else []) \
                    + track.fragments:
                mapping[int(obstacle.id)] = track.id
        snapshot = [Track(t.id, t.state.copy(), t.covariance.copy(), t.time, t.hits, t.misses,
                          t.confirmed, t.obstacle, list(t.fragments)) for t in confirmed]
        steps.append(SequenceStep(frame.name, frame.time, obstacles, snapshot, mapping))
    return steps


def read_poses(path: str | Path) -> np.ndarray:
    """KITTI-style poses: one line of 12 numbers (a row-major 3x4 matrix) per frame; (K, 4, 4)."""
    path = Path(path)
    try:
        values = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read poses ({exc}); expected 12 numbers per line") from exc
    if values.shape[1] != 12:
        raise InputError(f"{path}: poses need 12 numbers per line (a 3x4 matrix), got "
                         f"{values.shape[1]}")
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :] = values.reshape(-1, 3, 4)
    return poses


def run_sequence(folder: str | Path, *, tracker: ObstacleTracker | None = None,
                 detect: Callable[[Frame], Any] | None = None, stages: Sequence[Any] = (),
                 poses: str | Path | np.ndarray | None = None, frame_interval: float = 0.1,
                 pattern: str = "*") -> list[SequenceStep]:
    """Track obstacles through the cloud files of a folder, in file-name order.

    Frames are the files matching ``pattern`` with a cloud extension (``poses.txt`` aside); frame k has time
    k * frame_interval. poses: a (K, 4, 4) array or a KITTI-style poses file; None = the
    folder's ``poses.txt`` when present, else no poses (nearest-neighbour association in the
    sensor frame). stages: stages run on each frame before detection (e.g. GridQuantize,
    RationalBSplineTerrain, Segmenter, ObstacleDetector); when the last one writes
    ``obstacles`` that product is used, else ``detect``.
    """
    from .io import CLOUD_EXTENSIONS, read_cloud

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"run_sequence: {folder} is not a folder; give the folder of the frames")
    problem = _check("frame_interval", frame_interval)
    if problem:
        raise InputError(f"run_sequence: {problem}")
    files = sorted(p for p in folder.glob(pattern)
                   if p.suffix.lower() in CLOUD_EXTENSIONS and p.name != "poses.txt")
    if not files:
        raise InputError(f"run_sequence: no cloud file matching {pattern!r} in {folder} "
                         f"(extensions: {', '.join(CLOUD_EXTENSIONS)})")
    if poses is None and (folder / "poses.txt").is_file():
        poses = folder / "poses.txt"
    if poses is not None and not isinstance(poses, np.ndarray):
        poses = read_poses(poses)
    if poses is not None and len(poses) < len(files):
        raise InputError(f"run_sequence: {len(poses)} poses for {len(files)} frames; give one "
                         f"pose per frame")

    def frames():
        for k, path in enumerate(files):
            yield SequenceFrame(read_cloud(path), k * frame_interval,
                                None if poses is None else poses[k], name=path.name)

    if stages:
        def run_stages(frame: Frame):
            for stage in stages:
                frame = stage(frame)
            if "obstacles" in frame.products:
                return frame.product("obstacles")
            return (detect or _default_detect)(frame)

        return track_frames(frames(), tracker=tracker, detect=run_stages)
    return track_frames(frames(), tracker=tracker, detect=detect)


def write_sequence(frames: Sequence[SequenceFrame], folder: str | Path) -> list[Path]:
    """Write frames as ``NNNNNN.ply`` (with a ``truth`` attribute when known) and ``poses.txt``."""
    from .frame import cloud_from_numpy
    from .io import write_cloud

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for k, frame in enumerate(frames):
        positions = np.asarray(as_frame(frame.cloud).positions)
        attributes = {} if frame.truth is None else {"truth": frame.truth.astype(np.int32)}
        written.append(write_cloud(folder / f"{k:06d}.ply",
                                   cloud_from_numpy(positions, **attributes)))
    if all(f.world_from_sensor is not None for f in frames):
        rows = [np.asarray(f.world_from_sensor)[:3, :].reshape(-1) for f in frames]
        np.savetxt(folder / "poses.txt", np.array(rows))
        written.append(folder / "poses.txt")
    return written


# ---------------------------------------------------------------------------------------------
# scoring against truth


@dataclass(frozen=True)
class TrackScore:
    """How tracks followed a sequence with per-point truth (:func:`score_tracks`).

    ``tracks_of_obstacle``: true obstacle id -> the confirmed track ids its detections carried.
    ``identity_switches``: sum over true obstacles of (number of those track ids - 1): a track
    changing, or a second confirmed track on a piece of the same obstacle, each count.
    ``spurious``: detections of spurious clusters; ``spurious_confirmed``: those carried by a
    confirmed track. ``detected``: true obstacles detected at least once.
    """

    detected: int
    tracks_of_obstacle: dict
    identity_switches: int
    spurious: int
    spurious_confirmed: int

    @property
    def tracked(self) -> int:
        """True obstacles carried by a confirmed track in at least one frame."""
        return len(self.tracks_of_obstacle)


def _majority(values: np.ndarray) -> int:
    keys, counts = np.unique(values, return_counts=True)
    return int(keys[counts.argmax()])


def score_tracks(frames: Sequence[SequenceFrame], steps: Sequence[SequenceStep], *,
                 spurious_truth: int = -3) -> TrackScore:
    """Score :func:`track_frames` output against the frames' per-point ``truth``.

    Each detected obstacle's truth is the most common truth value of its points (obstacle ids
    >= 0; ``spurious_truth`` marks a spurious cluster; other negative values are terrain).
    """
    if len(frames) != len(steps):
        raise InputError(f"score_tracks: {len(frames)} frames but {len(steps)} steps")
    detected: set[int] = set()
    identities: dict[int, set[int]] = {}
    spurious = spurious_confirmed = 0
    for k, (frame, step) in enumerate(zip(frames, steps)):
        if frame.truth is None:
            raise InputError(f"score_tracks: frame {k} ({frame.name!r}) has no truth")
        confirmed = {t.id for t in step.tracks}
        for obstacle in step.obstacles:
            truth = _majority(np.asarray(frame.truth)[obstacle.indices])
            track = step.track_of_obstacle.get(int(obstacle.id))
            if truth == spurious_truth:
                spurious += 1
                spurious_confirmed += track in confirmed
            elif truth >= 0:
                detected.add(truth)
                if track in confirmed:
                    identities.setdefault(truth, set()).add(track)
    switches = sum(len(v) - 1 for v in identities.values())
    return TrackScore(len(detected), {k: tuple(sorted(v)) for k, v in sorted(identities.items())},
                      switches, spurious, spurious_confirmed)
