"""Survey tiles wider than the development tiles: ground F1, time and peak memory of
``segment_terrain`` on a k x k mosaic of the 350 m x 370 m LAS tile (prints one line per
run, no assertions).

The shared LAS tiles are at most 1000 m wide and only one of them (``append-bug.laz``, 0.05
points/m2) is wider than 576 m, where the automatic layout stops keeping its control points
6 m apart (``o3d_terrain.terrain.AUTO_LIMIT_CONTROL_POINTS``). National survey tiles are 1-1.5
km wide at 2-20 points/m2. The mosaic lays ``las_with_several_extra_byte_bloc.laz`` (697,721
points, class 2 = ground) side by side k times along x and y, every other copy mirrored so the
terrain is continuous across the seams: k = 3 gives a 1052 x 1111 m tile of 6.3M points,
k = 4 1403 x 1481 m and 11.2M points. Truth is the tile's own classification, scored as by
``o3d-terrain eval segmentation`` (classes 0, 7 and 18 left out).

``--limit N`` sets ``AUTO_LIMIT_CONTROL_POINTS`` for the run (the default's value when not
given), to compare layouts; ``--blocks B`` instead segments the mosaic in B x B blocks, each
with ``--margin`` metres of its neighbours' points around it, and keeps each block's labels
inside the block (a point-labelling reference without the layout's limit; no surface).
Peak memory is the process's peak resident set (``ru_maxrss``), the mosaic included: run one
configuration per process.

Run: .venv/bin/python benchmarks/bench_wide_tiles.py [--tiles 3] [--limit 96] [--blocks 3]
     [--margin 40]
Needs ../shared/data/las (or $O3D_TERRAIN_DATA).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

import o3d_terrain  # noqa: E402
import o3d_terrain.terrain as terrain_module  # noqa: E402
from o3d_terrain.evaluation.datasets import data_root, read_las_frame  # noqa: E402
from o3d_terrain.evaluation.metrics import segmentation_counts  # noqa: E402

TILE = "las/las_with_several_extra_byte_bloc.laz"


def mosaic(positions: np.ndarray, tiles: int) -> np.ndarray:
    """``tiles`` x ``tiles`` copies of the cloud side by side, every other one mirrored along
    the axis it is shifted on (the terrain meets itself at each seam)."""
    low = positions.min(axis=0)
    high = positions.max(axis=0)
    width = high - low
    parts = []
    for i in range(tiles):
        for j in range(tiles):
            part = positions.copy()
            if i % 2:
                part[:, 0] = high[0] - (positions[:, 0] - low[0])
            if j % 2:
                part[:, 1] = high[1] - (positions[:, 1] - low[1])
            part[:, 0] += i * width[0]
            part[:, 1] += j * width[1]
            parts.append(part)
    return np.concatenate(parts)


def in_blocks(positions: np.ndarray, blocks: int, margin: float) -> np.ndarray:
    """Terrain labels of ``segment_terrain`` run on blocks x blocks blocks with ``margin``."""
    low = positions[:, :2].min(axis=0)
    high = positions[:, :2].max(axis=0)
    xs = np.linspace(low[0], high[0], blocks + 1)
    ys = np.linspace(low[1], high[1], blocks + 1)
    terrain = np.zeros(len(positions), bool)
    for i in range(blocks):
        for j in range(blocks):
            x, y = positions[:, 0], positions[:, 1]
            near = np.flatnonzero((x >= xs[i] - margin) & (x <= xs[i + 1] + margin)
                                  & (y >= ys[j] - margin) & (y <= ys[j + 1] + margin))
            _, inliers = o3d_terrain.segment_terrain(positions[near])
            labels = np.zeros(len(near), bool)
            labels[inliers] = True
            inside = ((x[near] >= xs[i]) & (x[near] <= xs[i + 1])
                      & (y[near] >= ys[j]) & (y[near] <= ys[j + 1]))
            terrain[near[inside]] = labels[inside]
    return terrain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, default=3, help="copies per axis (3)")
    parser.add_argument("--limit", type=int, default=None,
                        help="AUTO_LIMIT_CONTROL_POINTS for this run (default: the library's)")
    parser.add_argument("--blocks", type=int, default=0, help="segment in B x B blocks (0: no)")
    parser.add_argument("--margin", type=float, default=40.0, help="block margin (m)")
    args = parser.parse_args()
    root = data_root()
    if root is None or not (root / TILE).exists():
        raise SystemExit(f"needs ../shared/data/{TILE} (or $O3D_TERRAIN_DATA)")
    if args.tiles < 1 or args.blocks < 0 or args.margin < 0:
        raise SystemExit("--tiles must be >= 1, --blocks and --margin >= 0")
    if args.limit is not None:
        terrain_module.AUTO_LIMIT_CONTROL_POINTS = args.limit
    frame = read_las_frame(root / TILE)
    positions = mosaic(frame.positions, args.tiles)
    truth = np.tile(frame.is_ground, args.tiles ** 2)
    scored = np.tile(frame.scored, args.tiles ** 2)
    extent = np.ptp(positions[:, :2], axis=0)
    start = time.perf_counter()
    if args.blocks:
        terrain = in_blocks(positions, args.blocks, args.margin)
        layout = f"{args.blocks} x {args.blocks} blocks, {args.margin:g} m margins"
    else:
        surface, inliers = o3d_terrain.segment_terrain(positions)
        terrain = np.zeros(len(positions), bool)
        terrain[inliers] = True
        layout = "{} x {} control points".format(*surface.control_points.shape)
    seconds = time.perf_counter() - start
    counts = segmentation_counts(terrain[scored], truth[scored])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(f"{args.tiles} x {args.tiles} mosaic, {extent[0]:.0f} x {extent[1]:.0f} m, "
          f"{len(positions):,} points; {layout}: F1 {100 * counts.f1:.2f} "
          f"(precision {100 * counts.precision:.2f}, recall {100 * counts.recall:.2f}), "
          f"{seconds:.1f} s, peak RSS {peak:,.0f} MiB")


if __name__ == "__main__":
    main()
