"""LevelCloud: rotate a tilted sensor's cloud so that gravity's up is +z (o3d_terrain.level)."""

from __future__ import annotations

import numpy as np

from ..frame import Frame
from ..level import level_arrays, levelling_transform, tilt_deg
from ..options import option
from .base import Stage, stage


def _check_up(up) -> str | None:
    if up is not None and float(np.linalg.norm(np.asarray(up, dtype=np.float64))) < 1e-9:
        return "must not be the zero vector"
    return None


@stage
class LevelCloud(Stage):
    """Level a tilted sensor's cloud: turn it about the sensor so that ``up`` becomes +z.

    ``up`` is the direction opposite to gravity in the cloud's coordinates; the rotation is the
    smallest one (the heading is kept). For a sensor mounted at a fixed tilt (a lidar pitched
    down on a haul truck): ``up`` from
    its mount calibration, e.g. ``[-0.259, 0, 0.966]`` for 15° nose down; for a vehicle that
    tilts with the ground, use :func:`o3d_terrain.level_cloud` per frame with its IMU's
    reading. The terrain, its slopes and the labels that follow are then in the levelled
    frame (the product ``levelled_from_cloud`` is the 4 × 4 transform; normals are rotated
    too); the points keep their order. A scan cannot tell its own tilt from the slope it
    stands on, hence an option and not an estimate (docs/algorithm.md, "A tilted vehicle on
    steep ground").
    """

    writes = ("levelled_from_cloud",)
    example = {"up": [-0.259, 0.0, 0.966]}

    up: tuple = option(kind=float, length=3, check=_check_up,
                       help="direction opposite to gravity in the cloud's coordinates (any "
                            "length; an IMU's accelerometer at rest)")
    sensor_origin: tuple = option((0.0, 0.0, 0.0), kind=float, length=3, unit="m",
                                  help="the point the cloud turns about (the sensor's "
                                       "position in cloud coordinates); it stays in place")

    def run(self, frame: Frame) -> Frame:
        transform = levelling_transform(self.up, self.sensor_origin)
        changed = level_arrays(transform, frame.positions, frame.attribute("normals")
                               if frame.has_attribute("normals") else None)
        return (frame.with_attributes(**changed).with_products(levelled_from_cloud=transform)
                .with_note(f"{self.type_name}: turned {tilt_deg(self.up):.1f} deg to level"))
