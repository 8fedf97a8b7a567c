"""Vehicle scans moved into a map frame: ground F1 of ``segment_terrain`` without
``sensor_origin`` (the sensor found from the scan, :func:`o3d_terrain.locate_sensor`)
against the scan in its own frame, the map-frame scan taken as a top-down tile (the origin
given, the treatment before the sensor was looked for) and the sensor's true position given
(prints Markdown, no assertions).

The map frame: every scan turned by 57° about z and moved to (512345, 4123456, 310) m, a
sensor in projected (UTM-like) coordinates. Scans: the SemanticKITTI frames of
``../shared/data`` (ground set of the data README), the synthetic scenes' 32-line lidar,
solid-state lidar and stereo clouds, the open pit and the embankments of ``bench_pit.py``
and ``bench_embankment.py``, and the ``dem.tif`` sites of ``bench_dem_sites.py`` (64 and 16
lines); the sets that need the shared data are skipped without it.

Run: .venv/bin/python benchmarks/bench_map_frame.py [--sets kitti,synthetic,pit,dem]
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
from o3d_terrain.evaluation.datasets import data_root
from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.synthetic.sensors import rotation_matrix

SENSOR = np.array([512345.0, 4123456.0, 310.0])
YAW_DEG = 57.0
SETS = ("kitti", "synthetic", "pit", "dem")


def to_map(p: np.ndarray) -> np.ndarray:
    """``p`` (sensor frame) in the map frame: turned by YAW_DEG about z, moved to SENSOR."""
    return p @ rotation_matrix(yaw_deg=YAW_DEG).T + SENSOR


def frames(sets):
    """(name, positions in the sensor frame, ground truth, scored) of the chosen sets."""
    root = data_root()
    if "kitti" in sets:
        from o3d_terrain.evaluation.datasets import semantic_kitti_frames
        if root is None or not (root / "kitti_seq00_lidar").exists():
            print("SemanticKITTI frames not found: skipped", file=sys.stderr)
        else:
            for f in semantic_kitti_frames(root / "kitti_seq00_lidar"):
                yield f"SemanticKITTI {f.name}", f.positions, f.is_ground, f.scored
    if "synthetic" in sets:
        from o3d_terrain.synthetic import (make_scene, sample_lidar, sample_solid_state,
                                           sample_stereo)
        for name in ("offroad", "hills", "valley", "forest", "ditch_berm"):
            scene = make_scene(name, seed=0)
            for kind, sample in (("32-line lidar", sample_lidar),
                                 ("solid-state lidar", sample_solid_state),
                                 ("stereo", sample_stereo)):
                cloud = sample(scene, seed=0)
                p = np.asarray(cloud.positions, dtype=np.float64)
                keep = np.isfinite(p).all(axis=1)
                truth = ~np.asarray(cloud.is_obstacle, dtype=bool)[keep]
                yield f"{name}, {kind}", p[keep], truth, np.ones(len(truth), bool)
    if "pit" in sets:
        from bench_embankment import embankment_cloud
        from bench_pit import pit_cloud, place_name
        for angle, height, place in ((55, 1.8, "floor"), (65, 4.0, "berm1"), (45, 1.8, "berm2")):
            p, truth, _ = pit_cloud(angle, height, place)
            yield (f"pit, {angle}° faces, {height:g} m up on {place_name(place)}", p, truth,
                   np.ones(len(truth), bool))
        for height in (2.0, 4.0):
            p, truth, _ = embankment_cloud(height, 35.0, 8.0, 1.8)
            yield f"embankment {height:g} m, 1.8 m up", p, truth, np.ones(len(truth), bool)
    if "dem" in sets:
        from bench_dem_sites import site_frames
        try:
            for sensor in ("vehicle64", "vehicle16"):
                for f in site_frames(sensor):
                    yield f"{sensor} {f.name}", f.positions, f.is_ground, f.scored
        except FileNotFoundError as exc:
            print(f"dem sites: {exc}: skipped", file=sys.stderr)


def f1(p, truth, scored, **options) -> float:
    _, inliers = o3d_terrain.segment_terrain(p, **options)
    ground = np.zeros(len(p), bool)
    ground[inliers] = True
    return 100.0 * segmentation_counts(ground[scored], truth[scored]).f1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", default=",".join(SETS),
                        help=f"comma-separated, from {', '.join(SETS)}")
    args = parser.parse_args()
    sets = [s for s in args.sets.split(",") if s]
    unknown = sorted(set(sets) - set(SETS))
    if unknown:
        parser.error(f"unknown set(s) {', '.join(unknown)}; choose from {', '.join(SETS)}")
    print("| scan | own frame | map frame, as a top-down tile | map frame, sensor found "
          "| map frame, sensor given | sensor found (m from the true one) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, p, truth, scored in frames(sets):
        q = to_map(p)
        found = o3d_terrain.locate_sensor(q)
        where = "not found" if found is None else \
            f"{math.hypot(found[0] - SENSOR[0], found[1] - SENSOR[1]):.1f}"
        print(f"| {name} | {f1(p, truth, scored):.2f} "
              f"| {f1(q, truth, scored, sensor_origin=(0.0, 0.0, 0.0)):.2f} "
              f"| {f1(q, truth, scored):.2f} "
              f"| {f1(q, truth, scored, sensor_origin=SENSOR):.2f} | {where} |", flush=True)


if __name__ == "__main__":
    main()
