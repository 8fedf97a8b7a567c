"""Scans under a ceiling: a spinning lidar in a mine drift, a tunnel, a cavern or a hall, where
the sensor sees the roof over the floor it stands on.

Each scan is cast analytically by :func:`o3d_terrain.synthetic.sample_under_ceiling`: a floor
(level, or rising along x by ``--grades``), a flat roof over it, vertical side walls (a drift
or a tunnel) or none (a cavern or a hall), a sensor 2 m above the floor with 64 channels
evenly over its vertical field of view and 1024 firings a turn, 1 cm range noise, returns out
to 100 m, in the sensor's frame. Truth is exact: a return from the floor is ground,
from a wall or the ceiling an obstacle. Where the floor's returns thin out with range, the
ceiling's do not: a fit that takes its lowest cells as ground climbs to the roof there.

Scored: ground F1 (%) and precision (%) of ``segment_terrain`` with every default and with
``free_space=False`` (docs/algorithm.md, "Free space under the rays"); ``--peers`` adds
Patchwork++, CSF, SMRF and the RANSAC plane (the bench extra).

Run: .venv/bin/python benchmarks/bench_overhead.py [--peers]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from o3d_terrain.evaluation.datasets import LabelledFrame  # noqa: E402
from o3d_terrain.evaluation.metrics import segmentation_counts  # noqa: E402
from o3d_terrain.evaluation.peers import PEERS  # noqa: E402
from o3d_terrain.evaluation.segmentation import resolve_method, run_method  # noqa: E402
from o3d_terrain.synthetic import sample_under_ceiling  # noqa: E402

SENSOR_HEIGHT = 2.0

#: (name, ceiling height above the floor (m), wall half-width (m) or None, vertical field of
#: view (degrees), channels)
CASES = (
    ("drift 5 x 6 m, 90 deg lidar", 5.0, 3.0, (-45.0, 45.0), 64),
    ("tunnel 6 x 12 m, 90 deg lidar", 6.0, 6.0, (-45.0, 45.0), 64),
    ("tunnel 10 x 16 m, 90 deg lidar", 10.0, 8.0, (-45.0, 45.0), 64),
    ("cavern 10 m, 90 deg lidar", 10.0, None, (-45.0, 45.0), 64),
    ("hall 20 m, 90 deg lidar", 20.0, None, (-45.0, 45.0), 64),
    ("tunnel 6 x 12 m, 45 deg lidar", 6.0, 6.0, (-22.5, 22.5), 64),
    ("cavern 10 m, 45 deg lidar", 10.0, None, (-22.5, 22.5), 64),
)


def overhead_frames(grades=(0.0, 0.15)):
    """The scans of :data:`CASES` at each floor grade, as labelled frames in the sensor's
    frame (every point scored)."""
    for name, height, half_width, fov, beams in CASES:
        for grade in grades:
            positions, ground = sample_under_ceiling(
                height, half_width=half_width, fov_deg=fov, beams=beams, grade=grade,
                sensor_height=SENSOR_HEIGHT)
            yield LabelledFrame(f"{name}, floor grade {grade:g}", positions, ground,
                                np.ones(len(ground), bool), sensor_height=SENSOR_HEIGHT)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grades", default="0,0.15", help="floor grades along x")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    methods = [("o3d_terrain", {}), ("o3d_terrain, free_space=False", {"free_space": False})]
    methods += [(name, None) for name in (PEERS if args.peers else ())]
    print("ground F1 % (precision %), sensor 2 m above the floor")
    print("| scan | points | " + " | ".join(name for name, _ in methods) + " |")
    print("|---|---:|" + "---|" * len(methods))
    for frame in overhead_frames(tuple(float(g) for g in args.grades.split(","))):
        cells = []
        for method_name, options in methods:
            if options is None:
                run = resolve_method(method_name, kind=frame.kind, sensor_height=SENSOR_HEIGHT)
            else:
                run = resolve_method("o3d_terrain", **options)
            counts = segmentation_counts(np.asarray(run_method(run, frame), bool),
                                         frame.is_ground)
            cells.append(f"{100 * counts.f1:.2f} ({100 * counts.precision:.1f})")
        print(f"| {frame.name} | {len(frame.positions):,} | " + " | ".join(cells) + " |",
              flush=True)


if __name__ == "__main__":
    main()
