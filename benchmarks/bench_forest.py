"""Mountain forest from the air: an airborne lidar's returns (several per pulse) over the real
relief of ``dem_1m/dem.tif`` under a closed conifer canopy and shrubs, the kind of tile where
the ground is a minority of the points and, at survey densities of a few pulses per square
metre, a 0.5 m cell rarely holds both a return from the vegetation and one from the ground.

Each site is a 100 m x 100 m window of the raster (``bench_dem_sites.raster_relief``: the
bicubic spline through its heights, slopes up to ~36 degrees; ``--relief-scale 2`` doubles
them) under 300 conifers and 200 shrubs per hectare, sampled by
:func:`o3d_terrain.synthetic.sample_forest_airborne` (conical crowns with returns inside them,
shrubs, several numbered returns per pulse; about 42 % of the returns are ground, 57 % of the
last returns).

Truth is exact: a point is ground when its pulse ended on the terrain; every other point is
an obstacle (obstacle recall counts those more than 0.3 m above the terrain). Scored: ground
F1 (%), obstacle recall (%), and for ours the surface's height RMSE (m) at the ground points.
Ours gets the returns (as ``o3d_terrain.read_cloud`` gives a LAS tile's), and, as
"o3d_terrain, x y z only", the positions alone; the peers get the positions with the
settings of ``o3d_terrain.evaluation.peers``. Needs ``../shared/data`` (or
``$O3D_TERRAIN_DATA``).

Run: .venv/bin/python benchmarks/bench_forest.py [--sites 4] [--density 1,4] [--relief-scale 1]
[--peers] (docs/algorithm.md, "Cells for a sparse top-down scan").
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import o3d_terrain  # noqa: E402
from o3d_terrain.evaluation.commands import parse_options  # noqa: E402
from o3d_terrain.evaluation.datasets import LabelledFrame, data_root  # noqa: E402
from o3d_terrain.evaluation.peers import PEERS  # noqa: E402
from o3d_terrain.evaluation.segmentation import resolve_method  # noqa: E402
from o3d_terrain.evaluation.terrain import read_raster  # noqa: E402
from o3d_terrain.frame import NUMBER_OF_RETURNS, RETURN_NUMBERS, cloud_from_numpy  # noqa: E402
from o3d_terrain.synthetic import sample_forest_airborne  # noqa: E402

from bench_dem_sites import HALF, OBSTACLE_HEIGHT, raster_relief, score, sites  # noqa: E402

XYZ_ONLY = "o3d_terrain, x y z only"


def forest_frames(density: float = 1.0, *, count: int = 4, scale: float = 1.0, seed: int = 0):
    """The sites as (labelled frame, terrain height under each point): every point scored,
    ground = a pulse that ended on the terrain, with the returns; they need the shared data
    folder (FileNotFoundError without it)."""
    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise FileNotFoundError("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    heights = read_raster(root / "dem_1m" / "dem.tif").heights.astype(np.float64)
    for k, (row, col) in enumerate(sites(heights, count, seed)):
        relief = raster_relief(heights, row, col, HALF, scale)
        tile = sample_forest_airborne(relief.height, region=(-HALF, HALF, -HALF, HALF),
                                      density=density, seed=seed + k)
        tall = ~tile.is_ground & (tile.positions[:, 2] - tile.terrain_z > OBSTACLE_HEIGHT)
        yield LabelledFrame(
            name=f"site {row},{col}", positions=tile.positions, is_ground=tile.is_ground,
            scored=np.ones(len(tile), bool), obstacle=tall, kind="aerial",
            source=f"dem.tif sites, forest, {density:g} pulses/m2",
            returns=(tile.return_numbers, tile.number_of_returns)), tile.terrain_z


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sites", type=int, default=4)
    parser.add_argument("--density", default="1,4", help="pulses per m2, comma-separated")
    parser.add_argument("--relief-scale", type=float, default=1.0)
    parser.add_argument("--peers", action="store_true",
                        help="also CSF and SMRF (bench extra)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of segment_terrain for ours, e.g. grow_cells=false")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    options = parse_options(args.option, "--option")
    methods = ["o3d_terrain", XYZ_ONLY] + ([m for m in ("csf", "smrf") if m in PEERS]
                                          if args.peers else [])
    print("ground F1 % / obstacle recall %; ours also the height RMSE (m) at the ground points")
    print("| pulses/m2 | site | points | " + " | ".join(methods) + " | ours RMSE (m) |")
    print("|---:|---|---:|" + "---|" * len(methods) + "---:|")
    totals: dict = {}
    for density in (float(d) for d in args.density.split(",")):
        for frame, terrain_z in forest_frames(density, count=args.sites,
                                              scale=args.relief_scale, seed=args.seed):
            p, truth, tall = frame.positions, frame.is_ground, frame.obstacle
            cells, rmse = [], float("nan")
            for name in methods:
                if name in ("o3d_terrain", XYZ_ONLY):
                    cloud = p if name == XYZ_ONLY else cloud_from_numpy(
                        p, **{RETURN_NUMBERS: frame.returns[0],
                              NUMBER_OF_RETURNS: frame.returns[1]})
                    surface, inliers = o3d_terrain.segment_terrain(cloud, **options)
                    ground = np.zeros(len(p), bool)
                    ground[inliers] = True
                    if name == "o3d_terrain":
                        q = p[truth]
                        err = surface(q[:, 0], q[:, 1]) - terrain_z[truth]
                        rmse = float(np.sqrt(np.nanmean(err ** 2)))
                else:
                    ground = np.asarray(resolve_method(name, kind="aerial")(p), bool)
                f1, recall = score(ground, truth, tall)
                totals.setdefault((density, name), []).append((f1, recall))
                cells.append(f"{f1:.2f} / {recall:.1f}")
            totals.setdefault((density, "rmse"), []).append(rmse)
            print(f"| {density:g} | {frame.name} | {len(p):,} | " + " | ".join(cells)
                  + f" | {rmse:.3f} |", flush=True)
    print()
    print("| pulses/m2 | " + " | ".join(f"{m} F1 / obstacle recall" for m in methods)
          + " | ours RMSE (m) |")
    print("|---:|" + "---|" * len(methods) + "---:|")
    for density in sorted({d for d, _ in totals}):
        row = [np.mean(np.array(totals[(density, m)]), axis=0) for m in methods]
        print(f"| {density:g} | " + " | ".join(f"{f:.2f} / {r:.1f}" for f, r in row)
              + f" | {np.mean(totals[(density, 'rmse')]):.3f} |")


if __name__ == "__main__":
    main()
