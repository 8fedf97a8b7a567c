"""How high any height-based ground filter can score on the LAS tiles' own labels (no assertions).

The LAS tiles of ``../shared/data/las`` are scored against their ASPRS class 2. Some of their
other classes hold points at ground level: unclassified points on the ground
(``autzen_trim.laz`` has only classes 1 and 2), low vegetation a few centimetres up
(``warsaw_small.las``), a bridge deck level with the road (``append-bug.laz``). No method that
labels points by where they lie can tell those from class 2, so F1 has a ceiling below 1 on
each tile, whatever the method.

This script measures that ceiling with the labels' own ground as the terrain: at every point,
the median height of the 8 nearest class-2 points other than itself (x/y), and a point is
called ground when it lies within ``t`` of that height and its nearest class-2 neighbour is
within 5 m (points over large roofs or water, with no class-2 point near, are not). That is a
filter told the true ground, with a fixed threshold ``t``; its F1 at the best ``t`` of 0.1,
0.2 and 0.3 m is the tile's ceiling. On a sparse steep tile the nearest class-2 points
interpolate the terrain less well than a fitted surface, so a method can pass this ceiling
there (``hexbin-crop.las``). Ours (``segment_terrain`` with its defaults and the tiles' return
numbers, as ``o3d-terrain eval segmentation`` runs it) is printed beside it.

Needs ``../shared/data`` (or ``$O3D_TERRAIN_DATA``) and the ``las`` extra (laspy).

Run: .venv/bin/python benchmarks/bench_las_ceiling.py [--no-ours]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from scipy.spatial import cKDTree

from o3d_terrain.evaluation.datasets import data_root, read_las_frame
from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.evaluation.segmentation import resolve_method, run_method

THRESHOLDS = (0.1, 0.2, 0.3)  # m
NEIGHBOURS = 8  # class-2 points whose median height is the ground at a point
REACH = 5.0  # m: no class-2 point within this, no ground height


def labelled_ground_height(positions: np.ndarray, is_ground: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(height, distance): the median z of the NEIGHBOURS nearest class-2 points (x/y) of each
    point, leaving the point itself out, and the x/y distance to the nearest of them."""
    ground = np.flatnonzero(is_ground)
    tree = cKDTree(positions[ground, :2])
    dist, near = tree.query(positions[:, :2], k=NEIGHBOURS + 1)
    index = ground[near]
    itself = index == np.arange(len(positions))[:, None]
    z = np.where(itself, np.nan, positions[index, 2])
    return np.nanmedian(z, axis=1), np.nanmin(np.where(itself, np.nan, dist), axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-ours", action="store_true", help="only the labels' ceiling")
    args = parser.parse_args()
    folder = data_root() / "las"
    tiles = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".las", ".laz"))
    if not tiles:
        raise SystemExit(f"no LAS/LAZ tiles under {folder}")
    ours = None if args.no_ours else resolve_method("o3d_terrain")
    header = " | ".join(f"within {t:.1f} m" for t in THRESHOLDS)
    print(f"| tile | points | {header} | ceiling |" + ("" if ours is None else " ours |"))
    print("|---|---:|" + "---:|" * (len(THRESHOLDS) + 1) + ("" if ours is None else "---:|"))
    ceilings, scores, table = [], [], []
    for path in tiles:
        frame = read_las_frame(path)
        height, reach = labelled_ground_height(frame.positions, frame.is_ground)
        depth = np.abs(frame.positions[:, 2] - height)
        f1 = []
        for t in THRESHOLDS:
            called = (depth < t) & (reach < REACH)
            f1.append(100.0 * segmentation_counts(called, frame.is_ground,
                                                  scored=frame.scored).f1)
        ceilings.append(max(f1))
        table.append(f1)
        row = f"| {path.name} | {len(frame.positions):,} | " + " | ".join(
            f"{v:.2f}" for v in f1) + f" | **{max(f1):.2f}** |"
        if ours is not None:
            mask = np.asarray(run_method(ours, frame), dtype=bool)
            scores.append(100.0 * segmentation_counts(mask, frame.is_ground,
                                                      scored=frame.scored).f1)
            row += f" {scores[-1]:.2f} |"
        print(row, flush=True)
    mean = "| mean | | " + " | ".join(f"{v:.2f}" for v in np.mean(table, axis=0)) + \
        f" | **{np.mean(ceilings):.2f}** |"
    print(mean + ("" if ours is None else f" {np.mean(scores):.2f} |"))


if __name__ == "__main__":
    main()
