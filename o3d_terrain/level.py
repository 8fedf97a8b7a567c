"""Levelling a tilted sensor's cloud with the direction of gravity.

A vehicle on a 25° slope tilts its lidar by 25°: in the sensor's frame the ground it stands on
is level and a slope facing the other way is 50° steep. The terrain is a height field over
(x, y), so the fit is best where "up" is up: terrain slopes are then the world's, trees and
walls vertical. The scan itself cannot say which way is up (the ground around a vehicle on a
slope looks level to its sensor), but the vehicle's IMU can: at rest its accelerometer reads
the reaction to gravity, the ``up`` direction in the sensor's frame. A sensor fixed on its
mount at a known pitch has a constant ``up`` from its calibration.

:func:`level_cloud` rotates a cloud about the sensor so that ``up`` becomes +z, by the
smallest rotation (the heading is kept); :class:`~o3d_terrain.stages.LevelCloud` does the
same in a pipeline. The surface fitted to the levelled cloud, its slopes and its labels are
then in that frame; the labels still index the caller's points, since a rotation keeps
their order. docs/algorithm.md, "A tilted vehicle on steep ground", measures what it gains.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Sequence

import numpy as np
import open3d as o3d

from .errors import InputError, checked_keywords
from .frame import transform_points

__all__ = ["level_cloud", "level_arrays", "levelling_transform", "tilt_deg", "up_axis_hint",
           "upside_down_hint"]

#: :func:`up_axis_hint`: a cloud flatter than this along its flattest direction (its least
#: variance over the middle one) ...
UP_FLAT_RATIO = 0.2
#: ... with that direction more than this many degrees from z does not have z up
UP_MAX_TILT_DEG = 60.0
#: ... measured on at most this many of its points (evenly picked)
UP_SAMPLE = 4096

#: :func:`upside_down_hint`: the points whose horizontal distance from the sensor lies in
#: this range (m), the ground a vehicle's sensor scans around it ...
NEAR_RING = (2.0, 10.0)
#: ... counted above (below) the sensor when more than this (m) above (below) it ...
NEAR_LEVEL = 0.3
#: ... make a sensor upside down when at least this share lies above it ...
UPSIDE_DOWN_ABOVE = 0.7
#: ... and at most this share below it ...
UPSIDE_DOWN_BELOW = 0.1
#: ... among at least this many such points of the sample ...
UPSIDE_DOWN_MIN_POINTS = 50
#: ... in a scan from that place: at most this share of the points within NEAR_RING[1] lie
#: within NEAR_RING[0] (a sensor does not see the ground under itself: 0.1 % on the
#: SemanticKITTI frames, none on the synthetic sensors' frames; 4 % on points spread evenly
#: around the place, as a terrain patch whose heights lie above the origin of its frame)
SENSOR_DISC_SHARE = 0.01


def _vector(values: Any, name: str) -> np.ndarray:
    try:
        v = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 numbers (x, y, z); got {values!r}") from None
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(f"{name} must be 3 finite numbers (x, y, z); got {values!r}")
    return v


def levelling_transform(up: Sequence[float], sensor_origin: Sequence[float] = (0.0, 0.0, 0.0)
                        ) -> np.ndarray:
    """4 × 4 ``levelled_from_cloud``: the smallest rotation taking ``up`` (any length, in the
    cloud's coordinates) to +z, about ``sensor_origin`` (which stays where it is)."""
    u = _vector(up, "up")
    norm = float(np.linalg.norm(u))
    if norm < 1e-9:
        raise InputError("up must not be the zero vector: give the direction opposite to "
                         "gravity in the cloud's coordinates (an IMU's accelerometer at rest)")
    u = u / norm
    c = float(u[2])  # cos of the tilt
    axis = np.array([u[1], -u[0], 0.0])  # u x z: the axis that tips u onto z
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        rotation = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # level or upside down
    else:
        k = axis / s
        cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rotation = np.eye(3) + s * cross + (1.0 - c) * cross @ cross  # Rodrigues
    origin = _vector(sensor_origin, "sensor_origin")
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = origin - rotation @ origin
    return transform


def level_arrays(transform: np.ndarray, positions: np.ndarray,
                 normals: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``{"positions": ..., "normals": ...}``: (N, 3) positions moved by the 4 × 4
    ``transform`` and, when given, normals turned by its rotation (float64)."""
    moved = {"positions": transform_points(np.asarray(positions, dtype=np.float64), transform)}
    if normals is not None:
        rotation = transform.copy()
        rotation[:3, 3] = 0.0
        moved["normals"] = transform_points(np.asarray(normals, dtype=np.float64), rotation)
    return moved


def tilt_deg(up: Sequence[float]) -> float:
    """The angle between ``up`` and +z (degrees)."""
    u = _vector(up, "up")
    return math.degrees(math.atan2(math.hypot(u[0], u[1]), u[2]))


@checked_keywords()
def level_cloud(cloud: Any, up: Sequence[float], *,
                sensor_origin: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[Any, np.ndarray]:
    """``(levelled, levelled_from_cloud)``: the cloud rotated about ``sensor_origin`` so that
    ``up`` (the direction opposite to gravity in the cloud's coordinates, e.g. an IMU's
    accelerometer at rest in the sensor frame) is +z, and the 4 × 4 transform applied.

    The cloud comes back as it came: an (N, 3) or (N, 4) numpy array (extra columns kept), a
    legacy or a tensor Open3D point cloud (normals rotated too); the caller's is not modified.
    Point order is kept, so indices from the levelled cloud (``segment_terrain``'s inliers)
    index the caller's. Map the surface's frame back with ``np.linalg.inv(transform)``.

    >>> import numpy as np, o3d_terrain
    >>> up = (-np.sin(np.radians(20)), 0.0, np.cos(np.radians(20)))   # pitched 20 deg nose down
    >>> levelled, transform = o3d_terrain.level_cloud(np.array([[10.0, 0.0, 0.0]]), up)
    >>> levelled.round(3)                    # a point straight ahead of the sensor lies below it
    array([[ 9.397,  0.   , -3.42 ]])
    """
    transform = levelling_transform(up, sensor_origin)
    if isinstance(cloud, np.ndarray):
        if cloud.ndim != 2 or cloud.shape[1] < 3 or not np.issubdtype(cloud.dtype, np.number):
            raise InputError(f"a numpy cloud must be (N, 3) or (N, k >= 3) numbers; got shape "
                             f"{cloud.shape}, dtype {cloud.dtype}")
        out = np.array(cloud, dtype=np.result_type(cloud.dtype, np.float64), copy=True)
        out[:, :3] = transform_points(cloud[:, :3], transform)
        return out, transform
    if isinstance(cloud, o3d.geometry.PointCloud):
        out = copy.deepcopy(cloud)
        out.transform(transform)  # rotates the normals too
        return out, transform
    if isinstance(cloud, o3d.t.geometry.PointCloud):
        out = cloud.clone()
        for name, moved in level_arrays(transform, out.point.positions.numpy(),
                                        out.point.normals.numpy() if "normals" in out.point
                                        else None).items():
            out.point[name] = o3d.core.Tensor(moved).to(out.point[name].dtype)
        return out, transform
    raise InputError(f"level_cloud takes a numpy array or an Open3D point cloud; got "
                     f"{type(cloud).__name__}")


def up_axis_hint(positions: np.ndarray, sensor_origin: Sequence[float] = (0.0, 0.0, 0.0)
                 ) -> str | None:
    """A warning's text when the cloud ``positions`` (N, 3) is clearly flat along a direction
    more than :data:`UP_MAX_TILT_DEG` from z, its least variance under :data:`UP_FLAT_RATIO`
    times the middle one (a camera's frame, x right, y down, z forward; a sensor frame tilted
    that far): the terrain is a height field over (x, y). None otherwise, and for clouds of
    fewer than 10 finite points. The levelling it proposes takes the flat direction as up,
    pointing away from the points' side of ``sensor_origin`` (the ground lies below a sensor).

    Every vehicle, stereo and airborne cloud of the project's benchmarks stays under 40°
    (SemanticKITTI rolled 40° 39°, the synthetic stereo clouds about 10°, LAS tiles up to 27°,
    or not flat: ratio 0.40), their camera-frame copies 72-85°."""
    p = np.asarray(positions, dtype=np.float64)
    p = p[:: max(1, len(p) // UP_SAMPLE)]
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < 10:
        return None
    mean = p.mean(axis=0)
    centred = p - mean
    values, vectors = np.linalg.eigh(centred.T @ centred / len(p))
    flat = vectors[:, 0]
    tilt = math.degrees(math.acos(min(1.0, abs(float(flat[2])))))
    if not (values[0] < UP_FLAT_RATIO * values[1] and tilt > UP_MAX_TILT_DEG):
        return None
    if float(np.dot(mean - _vector(sensor_origin, "sensor_origin"), flat)) > 0:
        flat = -flat  # up points away from the points' side: the ground is below the sensor
    up = tuple(round(float(v), 2) + 0.0 for v in flat)
    return (f"the cloud is flat across {up} ({tilt:.0f}° from the z axis), while the terrain "
            f"model takes z as up: if it is in a camera's frame (x right, y down, z forward) "
            f"or in a sensor frame tilted that far, level it first, e.g. "
            f"o3d_terrain.level_cloud(cloud, up={up}) (in a pipeline, the stage LevelCloud "
            f"with up: {list(up)}) with that direction or, better, an IMU's up; ignore this "
            f"for a scan made mostly of one steep face")


def upside_down_hint(positions: np.ndarray, sensor_origin: Sequence[float] = (0.0, 0.0, 0.0)
                     ) -> str | None:
    """A warning's text when the ground a sensor at ``sensor_origin`` scans around it lies
    above it. Of the points (at most :data:`UP_SAMPLE`, evenly picked) whose horizontal
    distance from the sensor is in :data:`NEAR_RING`, at least :data:`UPSIDE_DOWN_ABOVE` lie
    more than :data:`NEAR_LEVEL` above the sensor and at most :data:`UPSIDE_DOWN_BELOW` that
    far below it, as from a sensor mounted upside down. None otherwise; None too when the
    cloud is no scan from that place (fewer than :data:`UPSIDE_DOWN_MIN_POINTS` such points,
    as on an airborne tile away from the default origin; or more than
    :data:`SENSOR_DISC_SHARE` of the points within NEAR_RING[1] lying within NEAR_RING[0],
    where a sensor sees no ground under itself), and for a cloud that :func:`up_axis_hint`
    warns of (a camera's frame: its ground is not under z at all).

    Measured on the project's scans (share above / below): SemanticKITTI 000000-000002
    0.01 / 0.95-0.97 and turned upside down 0.95-0.97 / 0.01; the synthetic lidar, solid-state
    and stereo frames of every scene, the pit from its floor and berms, the embankment: at most
    0.29 above (a solid-state sensor under a forest's crowns), at least 0.66 below."""
    o = _vector(sensor_origin, "sensor_origin")
    p = np.asarray(positions, dtype=np.float64)
    p = p[:: max(1, len(p) // UP_SAMPLE)]
    d2 = (p[:, 0] - o[0]) ** 2 + (p[:, 1] - o[1]) ** 2
    within = (d2 <= NEAR_RING[1] ** 2) & np.isfinite(p[:, 2])
    near = within & (d2 >= NEAR_RING[0] ** 2)
    count, around = int(np.count_nonzero(near)), int(np.count_nonzero(within))
    if count < UPSIDE_DOWN_MIN_POINTS or around - count > SENSOR_DISC_SHARE * around:
        return None  # too few to say, or points under the place: no sensor's scan from it
    z = p[near, 2] - o[2]
    above = np.count_nonzero(z > NEAR_LEVEL) / count
    below = np.count_nonzero(z < -NEAR_LEVEL) / count
    if not (above >= UPSIDE_DOWN_ABOVE and below <= UPSIDE_DOWN_BELOW) or \
            up_axis_hint(positions, o) is not None:
        return None
    return (f"{above:.0%} of the points {NEAR_RING[0]:g}-{NEAR_RING[1]:g} m (x/y) from the "
            f"sensor lie above it and {below:.0%} below, while the terrain model takes z as up "
            f"and the ground below the sensor: if the sensor is mounted upside down, level "
            f"the cloud first, e.g. o3d_terrain.level_cloud(cloud, up=(0, 0, -1)) (in a "
            f"pipeline, the stage LevelCloud with up: [0, 0, -1]) or with an IMU's up; if "
            f"sensor_origin is not where the sensor is, give it; ignore this for a sensor in a "
            f"hollow whose walls rise around it")
