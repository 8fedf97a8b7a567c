"""A vehicle on a raised road (an embankment, a levee, a haul road on fill): ground F1 and
obstacle recall of the defaults against a lighter smoothing and a finer layout (and, with
--peers, the peers of the bench extra) on synthetic embankments (prints Markdown, no
assertions).

The embankment runs along x through the sensor: a flat top ``top`` m wide, ``height`` m above
the ground on both sides, flanks of ``flank`` degrees (``synthetic.Ramp`` features); a 64-line
lidar 1.8 m (a pickup) or 4 m (a haul truck's cab) above the middle of the top. From the top
the flanks face away and are not seen: the scan holds the top, and the ground on both sides
beyond the flanks' shadow. The default objects stand on the ground on either side, 18 m out.
Ground is every point not on an object; obstacle recall counts the points of objects more
than 0.3 m above the ground (docs/algorithm.md, "A vehicle on a berm").

Run: .venv/bin/python benchmarks/bench_embankment.py [--peers]
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
from bench_pit import OBSTACLE_HEIGHT, score_row

from o3d_terrain.evaluation.peers import PEERS
from o3d_terrain.synthetic import Plane, Ramp, Scene, sample_lidar
from o3d_terrain.synthetic.scene import Obstacle, default_obstacles

#: (height m, flank deg, top width m)
EMBANKMENTS = ((2.0, 30.0, 6.0), (3.0, 35.0, 8.0), (5.0, 40.0, 10.0), (8.0, 45.0, 12.0))
VARIANTS = {"defaults": {}, "smoothing=0.01": {"smoothing": 0.01},
            "control_points=(64, 64)": {"control_points": (64, 64)}}


def embankment_scene(height: float, flank_deg: float, top: float) -> Scene:
    """An embankment along x, its top ``top`` m wide centred on y = 0, ``height`` m high,
    flanks of ``flank_deg``; the default objects moved 18 m out to either side."""
    run = height / math.tan(math.radians(flank_deg))
    features = (Plane(), Ramp(0.0, -top / 2 - run, 90.0, flank_deg, run),
                Ramp(0.0, top / 2, 90.0, -flank_deg, run))
    objects = tuple(Obstacle(o.kind, (o.center[0], o.center[1] + math.copysign(18.0, o.center[1])),
                             o.size, o.height, o.yaw_deg) for o in default_obstacles(0))
    return Scene(f"embankment {height:g} m", features, objects, region=(-50.0, 50.0, -50.0, 50.0))


def embankment_cloud(height: float, flank_deg: float, top: float, sensor_height: float):
    """The scan from the middle of the top, in the sensor's frame: positions (N, 3), ground
    truth (N,) and the object points more than :data:`OBSTACLE_HEIGHT` up (N,)."""
    cloud = sample_lidar(embankment_scene(height, flank_deg, top), sensor_xy=(0.0, 0.0),
                         beams=64, azimuth_steps=1800, fov_deg=(-24.8, 2.0),
                         sensor_height=sensor_height, seed=0)
    p = np.asarray(cloud.positions, dtype=np.float64)
    keep = ~cloud.is_outlier & np.isfinite(p).all(axis=1)
    truth = ~np.asarray(cloud.is_obstacle, dtype=bool)[keep]
    tall = ~truth & (cloud.true_height_above_terrain[keep] > OBSTACLE_HEIGHT)
    return p[keep], truth, tall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    peers = list(PEERS) if args.peers else []
    columns = list(VARIANTS) + peers
    print("ground F1 / obstacle recall; `segment_terrain` with its defaults and two variants")
    print("| embankment (height, flanks, top) | sensor height (m) | points | "
          + " | ".join(columns) + " |")
    print("|---|---:|---:|" + "---|" * len(columns))
    for height, flank, top in EMBANKMENTS:
        for sensor_height in (1.8, 4.0):
            p, truth, tall = embankment_cloud(height, flank, top, sensor_height)
            cells = score_row(p, truth, tall, VARIANTS.values(), peers, sensor_height)
            print(f"| {height:g} m, {flank:g}°, {top:g} m | {sensor_height:g} | {len(p):,} | "
                  + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
