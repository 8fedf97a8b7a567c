"""Open-pit benches: ground F1 and obstacle recall of the automatic slope limit against fixed
limits (and, with --peers, the peers of the bench extra) on a synthetic pit (prints
Markdown, no assertions).

The pit: four benches rising along +x from x = 10 m, 6 m faces of 45-75 degrees with 8 m
berms between them (``synthetic.Ramp`` features), a 64-line lidar 1.8 m (a pickup) or 4 m (a
haul truck's cab) above the ground it stands on; a pole, a pedestrian, a car, a rock and a
truck stand on the pit floor. Ground is every point not on an object; obstacle recall counts
the points of objects more than 0.3 m above the ground.

Where the vehicle stands (``--places``): ``floor``, on the pit floor at the origin, where the
lidar sees the lower part of the first face and the floor, the berms above it hidden, so the
faces are the only relief in the scan; ``berm1`` / ``berm2``, in the middle of the first or
second berm, 4 m from the face above it and 4 m from the edge of the face below, where the
lidar sees that face from close up (not its top), the berm to its sides and, below, the
benches and the floor with the objects (docs/algorithm.md, "Bench faces").

The faces run along the cloud's y axis, and so along the grid's, unless ``--yaws`` turns the
scan about the sensor's vertical: the labels depend on that angle (docs/algorithm.md, "Bench
faces", its paragraph "Faces at an angle to the grid").

Run: .venv/bin/python benchmarks/bench_pit.py [--angles 55,65,75] [--heights 1.8,4]
     [--places floor,berm1,berm2] [--yaws 0,20,45] [--peers]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

import o3d_terrain
from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.evaluation.peers import PEERS, make_peer
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar
from o3d_terrain.synthetic.scene import Obstacle, default_obstacles
from o3d_terrain.synthetic.sensors import rotation_matrix

#: where the default objects stand: on the pit floor, clear of the first face
PLACES = {"pole": (5.0, 6.0), "pedestrian": (4.0, -3.0), "car": (-8.0, 5.0), "rock": (6.0, -8.0),
          "truck": (0.0, 14.0)}
LIMITS = (None, 45.0, 60.0, 65.0, 70.0, 75.0)
OBSTACLE_HEIGHT = 0.3
FIRST_FACE = 10.0  # x (m) where the first face rises from the floor
FACE_HEIGHT = 6.0
BERM = 8.0
#: where the vehicle stands: the pit floor at the origin, or the middle of berm k
PLACES_OF_SENSOR = ("floor", "berm1", "berm2")


def pit_scene(angle_deg: float, *, benches: int = 4, height: float = FACE_HEIGHT,
              berm: float = BERM) -> Scene:
    """Benches of ``height`` m faces at ``angle_deg`` and ``berm`` m berms from x = 10 m."""
    run = height / math.tan(math.radians(angle_deg))
    features = (Plane(),) + tuple(Ramp(FIRST_FACE + k * (run + berm), 0.0, 0.0, angle_deg, run)
                                  for k in range(benches))
    objects = tuple(Obstacle(o.kind, PLACES[o.kind], o.size, o.height, o.yaw_deg)
                    for o in default_obstacles(0))
    return Scene(f"pit {angle_deg:g}", features, objects, region=(-40.0, 70.0, -40.0, 40.0))


def sensor_xy(angle_deg: float, place: str) -> tuple[float, float]:
    """Where the vehicle stands (x, y): ``floor`` (the origin) or ``berm<k>``, the middle of
    the k-th berm."""
    if place == "floor":
        return (0.0, 0.0)
    if not place.startswith("berm") or not place[4:].isdigit() or int(place[4:]) < 1:
        raise ValueError(f"place must be 'floor' or 'berm<k>' (k >= 1), got {place!r}")
    k = int(place[4:])
    run = FACE_HEIGHT / math.tan(math.radians(angle_deg))
    return (FIRST_FACE + k * run + (k - 1) * BERM + BERM / 2, 0.0)


def pit_cloud(angle_deg: float, sensor_height: float, place: str = "floor",
              yaw_deg: float = 0.0):
    """The pit's scan from ``place`` (:func:`sensor_xy`), in the sensor's frame turned by
    ``yaw_deg`` about its vertical (the faces then run at that angle to the cloud's y axis):
    positions (N, 3), ground truth (N,) and the object points more than
    :data:`OBSTACLE_HEIGHT` up (N,); spurious returns and non-finite points dropped."""
    cloud = sample_lidar(pit_scene(angle_deg), sensor_xy=sensor_xy(angle_deg, place), beams=64,
                         azimuth_steps=1800, fov_deg=(-24.8, 2.0), sensor_height=sensor_height,
                         seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = ~cloud.is_outlier & np.isfinite(p).all(axis=1)
    truth = ~np.asarray(cloud.is_obstacle, dtype=bool)[keep]
    tall = ~truth & (cloud.true_height_above_terrain[keep] > OBSTACLE_HEIGHT)
    return p[keep] @ rotation_matrix(yaw_deg=yaw_deg).T, truth, tall


def place_name(place: str) -> str:
    return "floor" if place == "floor" else f"berm {place[4:]}"


def pit_frames(angles=(55.0, 65.0, 75.0), heights=(1.8, 4.0), places=("floor", "berm1")):
    """The pits as labelled frames (``o3d_terrain.evaluation.datasets.LabelledFrame``, every
    point scored, ground = a terrain hit) for ``benchmarks/run_all.py``."""
    from o3d_terrain.evaluation.datasets import LabelledFrame

    for place in places:
        for angle in angles:
            for height in heights:
                p, truth, tall = pit_cloud(angle, height, place)
                on = "the floor" if place == "floor" else place_name(place)
                yield LabelledFrame(name=f"{angle:g}° faces, sensor {height:g} m up on {on}",
                                    positions=p, is_ground=truth,
                                    scored=np.ones(len(p), bool), obstacle=tall,
                                    sensor_height=height, source="benchmarks/bench_pit.py")


def score(ground: np.ndarray, truth: np.ndarray, tall: np.ndarray) -> str:
    """Ground F1 / obstacle recall of the ground mask ``ground``."""
    counts = segmentation_counts(ground, truth, obstacle=tall)
    return f"{counts.f1:.4f} / {counts.obstacle_recall:.3f}"


def score_row(p: np.ndarray, truth: np.ndarray, tall: np.ndarray, option_sets, peers,
              sensor_height: float) -> list[str]:
    """:func:`score` of ``segment_terrain`` with each of ``option_sets`` (dicts of keyword
    arguments), then of each peer named in ``peers`` (given the sensor's height), on one
    cloud."""
    cells = []
    for options in option_sets:
        _, inliers = o3d_terrain.segment_terrain(p, **options)
        ground = np.zeros(len(p), bool)
        ground[inliers] = True
        cells.append(score(ground, truth, tall))
    for name in peers:
        ground = np.asarray(make_peer(name, sensor_height=sensor_height).segment(p), bool)
        cells.append(score(ground, truth, tall))
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--angles", default="45,55,65,75", help="face angles (deg)")
    parser.add_argument("--heights", default="1.8,4", help="sensor heights above the floor (m)")
    parser.add_argument("--places", default="floor,berm1",
                        help="where the vehicle stands: floor, berm1, berm2, ...")
    parser.add_argument("--yaws", default="0",
                        help="the scan turned by these angles about the sensor's vertical "
                             "(deg; 0: the faces run along the grid's y axis)")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    peers = list(PEERS) if args.peers else []
    columns = ["automatic" if v is None else f"{v:g}°" for v in LIMITS] + peers
    print("ground F1 / obstacle recall; `segment_terrain` with `max_slope_deg` automatic or fixed")
    print("| sensor on | faces | sensor height (m) | yaw | points | limit chosen (face run, m) | "
          + " | ".join(columns) + " |")
    print("|---|---|---:|---:|---:|---:|" + "---|" * len(columns))
    for angle, place, height, yaw in ((float(a), place, float(h), float(y))
                                      for place in args.places.split(",")
                                      for a in args.angles.split(",")
                                      for h in args.heights.split(",")
                                      for y in args.yaws.split(",")):
        p, truth, tall = pit_cloud(angle, height, place, yaw)
        cells = score_row(p, truth, tall, [{"max_slope_deg": v} for v in LIMITS], peers, height)
        frame = o3d_terrain.stages.RationalBSplineTerrain()(
            o3d_terrain.stages.GridQuantize()(p))
        fit = frame.product("terrain_fit")
        run = "-" if fit.face_run is None else f"{fit.face_run:.1f}"
        print(f"| {place_name(place)} | {angle:g}° | {height:g} | {yaw:g}° | {len(p):,} | "
              f"{fit.max_slope_deg:.1f}° ({run}) | "
              + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
