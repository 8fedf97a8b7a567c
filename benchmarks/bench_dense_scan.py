"""Dense scans over real relief: the height error of ``segment_terrain``'s surface against the
exact terrain, and its ground F1, for a terrestrial-laser-scanner-like scan of 0.6-0.8
million points (prints one line per site, no assertions).

Each site is a window of the surveyed raster ``dem_1m/dem.tif`` (1 m cells, slopes up to ~36
degrees) made a smooth terrain (``o3d_terrain.synthetic.GridRelief``, as in
``bench_dem_sites.py``) with 60 trees, scanned by a 240-channel spinning scanner (-45 to +15
degrees, 3,600 firings a turn, 5 mm range noise, ``--radius`` metres of range) 1.6 m above the
ground it stands on (the cloud tilted with that ground). Truth is exact: ground = a hit on the
terrain; the height error is the surface minus the terrain under every ground point, as RMSE
over all and per range band.

``--cap-points N`` sets ``o3d_terrain.refine.REFINE_CAP_POINTS`` for the run (the library's
default when not given): a value above the scan's terrain points keeps the refit's layout at
its vehicle-frame caps (40, 64 on steep relief), as before the caps grew with the points
(docs/algorithm.md, "Dense scans: the refit's layout grows with the points").

Run: .venv/bin/python benchmarks/bench_dense_scan.py [--sites 3] [--radius 150]
     [--cap-points 1000000000]
Needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import o3d_terrain  # noqa: E402
import o3d_terrain.refine as refine_module  # noqa: E402
from o3d_terrain.evaluation.datasets import data_root  # noqa: E402
from o3d_terrain.evaluation.terrain import read_raster  # noqa: E402
from o3d_terrain.synthetic import Scene, sample_lidar  # noqa: E402
from o3d_terrain.synthetic.scene import forest_obstacles  # noqa: E402

from bench_dem_sites import raster_relief  # noqa: E402  (the same raster windows)

#: scanner sites (raster row, column), the raster's centre and two around it
SITES = ((200, 200), (170, 230), (230, 170))
BANDS = ((0.0, 30.0), (30.0, 80.0), (80.0, np.inf))


def site_scene(heights: np.ndarray, row: int, col: int, radius: float, seed: int) -> Scene:
    """The raster around (row, col) in metres about it (its ground at z = 0), with trees."""
    relief = raster_relief(heights, row, col, radius)
    inside = (-float(int(radius) + 12) + 3.0, float(int(radius) + 12) - 3.0)
    trees = tuple(forest_obstacles(np.random.default_rng(seed), inside, inside, count=60,
                                   clear_radius=5.0))
    return Scene(f"dense scan {row},{col}", (relief,), trees,
                 region=(inside[0], inside[1], inside[0], inside[1]), seed=seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sites", type=int, default=3, help=f"1-{len(SITES)} (3)")
    parser.add_argument("--radius", type=float, default=150.0, help="scanner range (m)")
    parser.add_argument("--cap-points", type=int, default=None,
                        help="REFINE_CAP_POINTS for this run (default: the library's)")
    args = parser.parse_args()
    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise SystemExit("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    if not 1 <= args.sites <= len(SITES) or args.radius <= 0:
        raise SystemExit(f"--sites must be 1-{len(SITES)} and --radius > 0")
    if args.cap_points is not None:
        refine_module.REFINE_CAP_POINTS = args.cap_points
    heights = read_raster(root / "dem_1m" / "dem.tif").heights.astype(np.float64)
    for k, (row, col) in enumerate(SITES[:args.sites]):
        try:
            scene = site_scene(heights, row, col, args.radius, seed=k)
        except ValueError as exc:
            raise SystemExit(f"--radius {args.radius:g} is too large for the raster: {exc}")
        cloud = sample_lidar(scene, beams=240, fov_deg=(-45.0, 15.0), azimuth_steps=3600,
                             sensor_height=1.6, max_range=args.radius, on_terrain=True,
                             range_noise=0.005, seed=k)
        positions = np.asarray(cloud.positions, dtype=np.float64)
        ground = ~np.asarray(cloud.is_obstacle, dtype=bool)
        start = time.perf_counter()
        surface, inliers = o3d_terrain.segment_terrain(positions)
        seconds = time.perf_counter() - start
        terrain = np.zeros(len(positions), bool)
        terrain[inliers] = True
        f1 = 200.0 * np.sum(terrain & ground) / (terrain.sum() + ground.sum())
        g = positions[ground]
        error = surface(g[:, 0], g[:, 1]) - cloud.terrain_height(g[:, 0], g[:, 1])
        reach = np.hypot(g[:, 0], g[:, 1])
        bands = []
        for low, high in BANDS:
            band = (reach >= low) & (reach < high)
            name = f"{low:.0f}-{high:.0f} m" if np.isfinite(high) else f"{low:.0f}+ m"
            bands.append(f"{name} {np.sqrt(np.mean(error[band] ** 2)):.3f}")
        rmse = np.sqrt(np.mean(error ** 2))
        print(f"site {row},{col}: {len(positions):,} points, {surface.shape[0]} x "
              f"{surface.shape[1]} control points: height RMSE {rmse:.3f} m "
              f"({' '.join(bands)}), ground F1 {f1:.2f}, {seconds:.2f} s", flush=True)


if __name__ == "__main__":
    main()
