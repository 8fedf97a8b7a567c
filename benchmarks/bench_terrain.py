"""Terrain-model speed: prints median timings (no assertions).

1. ``segment_terrain`` on KITTI seq. 00 frame 000000 (needs ../shared/data or $O3D_TERRAIN_DATA).
2. The paper's configuration: 34 m x 22 m, 0.5 m cells, 25 x 25 control points, degree 3,
   300k synthetic points: grid + fit + slope grid, each stage timed.

Run: .venv/bin/python benchmarks/bench_terrain.py [--repeat N]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from o3d_terrain.api import segment_terrain
from o3d_terrain.grid import quantize_points
from o3d_terrain.terrain import fit_grid


def median_ms(fn, repeat: int) -> float:
    fn()  # compile / warm caches
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1000 * float(np.median(times))


def data_root() -> Path:
    env = os.environ.get("O3D_TERRAIN_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()

    scan = data_root() / "kitti_seq00_lidar" / "velodyne" / "000000.bin"
    if scan.exists():
        points = np.fromfile(scan, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        ms = median_ms(lambda: segment_terrain(points), args.repeat)
        print(f"segment_terrain, KITTI 000000 ({len(points)} points): median {ms:.1f} ms")
    else:
        print(f"KITTI frame not found at {scan}: skipped")

    rng = np.random.default_rng(0)
    n = 300_000
    x = rng.uniform(0, 34, n)
    y = rng.uniform(-11, 11, n)
    z = 0.8 * np.sin(x / 5) + 0.5 * np.cos(y / 4) + 0.1 * x + rng.normal(0, 0.02, n)
    box = (np.abs(x - 15) < 1) & (np.abs(y) < 1)
    z[box] += rng.uniform(0, 1.5, box.sum())
    positions = np.c_[x, y, z]
    region = (0.0, 34.0, -11.0, 11.0)
    grid = quantize_points(positions, cell_size=0.5, region=region)
    surface = fit_grid(grid, control_points=(25, 25), degree=3)
    xc, yc = grid.x_centers, grid.y_centers
    t_grid = median_ms(lambda: quantize_points(positions, cell_size=0.5, region=region),
                       args.repeat)
    for method in ("robust", "paper"):
        t_fit = median_ms(lambda: fit_grid(grid, control_points=(25, 25), degree=3,
                                           method=method), args.repeat)
        t_slope = median_ms(lambda: surface.slope_deg(xc[:, None], yc[None, :]), args.repeat)
        print(f"paper configuration (34 x 22 m, 0.5 m, 25 x 25, degree 3, {n} points), "
              f"method={method}: grid {t_grid:.1f} ms + fit {t_fit:.1f} ms + slope grid "
              f"{t_slope:.1f} ms = {t_grid + t_fit + t_slope:.1f} ms")


if __name__ == "__main__":
    main()
