"""A synthetic lidar sequence for obstacle tracking: a moving sensor past static and moving
obstacles, with the true obstacle of every point.

>>> from o3d_terrain.synthetic import synthetic_sequence, sequence_ground
>>> frames = synthetic_sequence(frames=20, seed=0)     # list of tracking.SequenceFrame
>>> frames[0].truth                                    # per point: obstacle index, -1, -3

Clouds are in the sensor frame (the lidar is level, ``SENSOR_HEIGHT`` m over flat ground, so
the ground is the plane z = -SENSOR_HEIGHT: :func:`sequence_ground`); ``world_from_sensor`` is
the exact pose. Score a tracker on it with :func:`o3d_terrain.tracking.score_tracks`.
"""

from __future__ import annotations

import numpy as np

from ..tracking import SequenceFrame
from .scene import Obstacle, make_scene
from .sensors import sample_lidar

__all__ = ["SENSOR_HEIGHT", "SEQUENCE_OBSTACLES", "SPURIOUS", "sequence_ground",
           "synthetic_sequence"]

#: height of the sequence's lidar over its flat ground (m)
SENSOR_HEIGHT = 1.8

#: truth value of the points of a spurious one-frame cluster
SPURIOUS = -3

#: the obstacles of :func:`synthetic_sequence`; truth id k is ``SEQUENCE_OBSTACLES[k]``
SEQUENCE_OBSTACLES = (
    Obstacle("pole", (9.0, 4.0), (0.25, 0.25), 3.0),
    Obstacle("car", (16.0, -4.5), (4.5, 1.8), 1.5, yaw_deg=5.0),
    Obstacle("rock", (12.0, 3.5), (1.4, 1.0), 0.8, yaw_deg=30.0),
    Obstacle("pedestrian", (11.0, -6.0), (0.5, 0.5), 1.75, velocity=(0.0, 1.4)),
    Obstacle("car", (26.0, 5.0), (4.5, 1.8), 1.5, velocity=(-4.0, 0.0)),
)


def synthetic_sequence(*, frames: int = 12, frame_interval: float = 0.1, speed: float = 3.0,
                       spurious: bool = True, seed: int = 0, beams: int = 32,
                       azimuth_steps: int = 900) -> list[SequenceFrame]:
    """A lidar on a vehicle driving along +x at ``speed`` m/s over flat ground, past static
    obstacles (a pole, a parked car, a rock) and moving ones (a pedestrian crossing at
    1.4 m/s, an oncoming car at 4 m/s): :data:`SEQUENCE_OBSTACLES`, at t = 0.

    Frame k is taken at t = k * ``frame_interval`` from (speed * t, 0) with noise seed
    ``seed + k`` (:func:`~o3d_terrain.synthetic.sample_lidar` with ``beams`` channels and
    ``azimuth_steps`` firings per turn). With ``spurious`` each frame also holds one cluster
    of 30 points floating 0.5-1.5 m above the ground at a random place 5-25 m ahead and within
    12 m to the side (dust, a reflection), never at the same place twice.

    Returns one :class:`~o3d_terrain.tracking.SequenceFrame` per frame: positions (N, 3) in the
    sensor frame, time, ``world_from_sensor`` and ``truth`` (N,) int64: the index of the
    point's obstacle in :data:`SEQUENCE_OBSTACLES`, -1 terrain, :data:`SPURIOUS` (-3) spurious.
    """
    rng = np.random.default_rng(seed)
    base = make_scene("flat").with_obstacles(SEQUENCE_OBSTACLES)
    out = []
    for k in range(int(frames)):
        t = k * frame_interval
        scene = base.at_time(t)
        cloud = sample_lidar(scene, sensor_xy=(speed * t, 0.0), sensor_height=SENSOR_HEIGHT,
                             beams=beams, azimuth_steps=azimuth_steps, seed=seed + k)
        positions = cloud.positions
        truth = cloud.obstacle_id.astype(np.int64)
        if spurious:
            world_centre = np.array([speed * t + rng.uniform(5, 25), rng.uniform(-12, 12),
                                     rng.uniform(0.5, 1.5)])
            blob = world_centre + rng.normal(0, 0.15, (30, 3))
            positions = np.concatenate([positions, cloud.to_sensor(blob)])
            truth = np.concatenate([truth, np.full(30, SPURIOUS)])
        out.append(SequenceFrame(positions, t, cloud.world_from_sensor, truth, f"{k:06d}"))
    return out


def sequence_ground(half_width: float = 100.0):
    """The exact ground of :func:`synthetic_sequence` in the sensor frame, the plane
    z = -SENSOR_HEIGHT, as a TerrainSurface over [-half_width, half_width]² (m)."""
    from ..spline import TerrainSurface, clamped_uniform_knots

    knots = clamped_uniform_knots(4, 3, -half_width, half_width)
    return TerrainSurface(3, knots, knots, np.zeros((4, 4)), np.ones((4, 4)),
                          (0.0, 0.0, -SENSOR_HEIGHT))
