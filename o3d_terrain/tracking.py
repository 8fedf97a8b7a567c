"""Obstacle tracking over a sequence of frames: constant-velocity Kalman tracks.

Broggi et al. 2013 prune false positives with a Kalman filter. Each obstacle's centroid (x, y)
is a measurement. Tracks hold a constant-velocity state (x, y, vx, vy); each frame they are
predicted to the frame's time, associated one-to-one with the new obstacles by the Hungarian
method on the distance between predicted and measured positions (pairs farther apart than
``gate`` metres are never associated), then corrected. A track is *confirmed* after
``confirm_hits`` associated frames and dropped after more than ``max_misses`` consecutive
frames without one (a tentative track at its first miss), so an obstacle seen in a single
frame never becomes a confirmed track.

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
           "run_sequence", "read_poses", "synthetic_sequence", "write_sequence"]


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
    deviation of a centroid measurement (m).
    """

    def __init__(self, *, confirm_hits: int = 3, max_misses: int = 2, gate: float = 2.0,
                 acceleration_noise: float = 2.0, measurement_noise: float = 0.3) -> None:
        problems = [p for p in (
            _check("confirm_hits", confirm_hits, integer=True),
            _check("max_misses", max_misses, integer=True, allow_zero=True),
            _check("gate", gate), _check("acceleration_noise", acceleration_noise),
            _check("measurement_noise", measurement_noise)) if p]
        if problems:
            raise InputError("ObstacleTracker: " + "; ".join(problems))
        self.confirm_hits = int(confirm_hits)
        self.max_misses = int(max_misses)
        self.gate = float(gate)
        self.acceleration_noise = float(acceleration_noise)
        self.measurement_noise = float(measurement_noise)
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
        survivors = []
        for index, track in enumerate(self.tracks):
            if index not in matched_tracks:
                track.misses += 1
                if not track.confirmed or track.misses > self.max_misses:
                    continue
            survivors.append(track)
        for c in range(len(measured)):
            if c not in matched_obstacles:
                survivors.append(self._new_track(measured[c], float(time), obstacles[c]))
        self.tracks = survivors
        return self.confirmed()

    def confirmed(self) -> list[Track]:
        return [t for t in self.tracks if t.confirmed]


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
            if track.obstacle is not None:
                mapping[int(track.obstacle.id)] = track.id
        snapshot = [Track(t.id, t.state.copy(), t.covariance.copy(), t.time, t.hits, t.misses,
                          t.confirmed, t.obstacle) for t in confirmed]
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


# ---------------------------------------------------------------------------------------------
# a synthetic sequence (a moving sensor past static and moving obstacles)


def synthetic_sequence(*, frames: int = 12, frame_interval: float = 0.1, speed: float = 3.0,
                       spurious: bool = True, seed: int = 0, beams: int = 32,
                       azimuth_steps: int = 900) -> list[SequenceFrame]:
    """A lidar on a vehicle driving along +x at ``speed`` m/s over flat ground, past static
    obstacles (a pole, a car, a rock) and moving ones (a pedestrian crossing, an oncoming
    car). With ``spurious`` each frame also holds one cluster of 30 points floating 0.5-1.5 m
    above the ground at a random place (dust, a reflection), never at the same place twice.
    Truth per point: obstacle index, -1 terrain, -3 spurious."""
    from .synthetic import Obstacle, make_scene, sample_lidar

    rng = np.random.default_rng(seed)
    obstacles = [
        Obstacle("pole", (9.0, 4.0), (0.25, 0.25), 3.0),
        Obstacle("car", (16.0, -4.5), (4.5, 1.8), 1.5, yaw_deg=5.0),
        Obstacle("rock", (12.0, 3.5), (1.4, 1.0), 0.8, yaw_deg=30.0),
        Obstacle("pedestrian", (11.0, -6.0), (0.5, 0.5), 1.75, velocity=(0.0, 1.4)),
        Obstacle("car", (26.0, 5.0), (4.5, 1.8), 1.5, velocity=(-4.0, 0.0)),
    ]
    base = make_scene("flat").with_obstacles(obstacles)
    out = []
    for k in range(int(frames)):
        t = k * frame_interval
        scene = base.at_time(t)
        cloud = sample_lidar(scene, sensor_xy=(speed * t, 0.0), beams=beams,
                             azimuth_steps=azimuth_steps, seed=seed + k)
        positions = cloud.positions
        truth = cloud.obstacle_id.astype(np.int64)
        if spurious:
            world_centre = np.array([speed * t + rng.uniform(5, 25), rng.uniform(-12, 12),
                                     rng.uniform(0.5, 1.5)])
            blob = world_centre + rng.normal(0, 0.15, (30, 3))
            positions = np.concatenate([positions, cloud.to_sensor(blob)])
            truth = np.concatenate([truth, np.full(30, -3)])
        out.append(SequenceFrame(positions, t, cloud.world_from_sensor, truth, f"{k:06d}"))
    return out


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
