"""Terrain-model speed: prints median timings (no assertions).

1. ``segment_terrain`` on KITTI seq. 00 frame 000000 (needs ../shared/data or $O3D_TERRAIN_DATA),
   in total and by step: cloud to frame, grid (with the ground-layer statistics), fit (with
   the ground-layer samples; of which the terrain prior), per-point heights and labels.
2. The paper's configuration: 34 m x 22 m, 0.5 m cells, 25 x 25 control points, degree 3,
   300k synthetic points: grid + fit + slope grid, each step timed.

Run: .venv/bin/python benchmarks/bench_terrain.py [--repeat N] [--threads N] [--keep-freed-memory]
(``--threads``: numba threads for the kernels that split work over threads; default: numba's.
``--keep-freed-memory``: call ``o3d_terrain.keep_freed_memory()`` first, as a program that
runs frame after frame does; without it the process keeps glibc's default allocator.)
The machine's load average is printed with the figures: on a shared machine they are noisy.
Every figure is the median wall time with, in brackets, the median CPU time of the calling
thread (less sensitive to other jobs when the kernels run on one thread).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba
import numpy as np

from o3d_terrain import keep_freed_memory
from o3d_terrain.api import segment_terrain
from o3d_terrain.frame import as_frame
from o3d_terrain.grid import quantize_points
from o3d_terrain.ground_layer import default_layer
from o3d_terrain.segment import segment_points
from o3d_terrain.terrain import fit_grid, terrain_prior_mask


class Timing(float):
    """Median wall time (ms) that also carries the median CPU time of the calling thread
    (``time.thread_time``: on a loaded machine the wall time includes waiting for a core)."""

    cpu: float

    def __format__(self, spec: str) -> str:
        return f"{float(self):{spec}} (CPU {self.cpu:{spec}})"


def median_ms(fn, repeat: int) -> Timing:
    fn()  # compile / warm caches
    wall, cpu = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        c = time.thread_time()
        fn()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - t)
    out = Timing(1000 * float(np.median(wall)))
    out.cpu = 1000 * float(np.median(cpu))
    return out


def data_root() -> Path:
    env = os.environ.get("O3D_TERRAIN_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load_text() -> str:
    return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--keep-freed-memory", action="store_true")
    args = parser.parse_args()
    if args.threads:
        numba.set_num_threads(args.threads)
    kept = args.keep_freed_memory and keep_freed_memory()
    print(f"numba threads {numba.get_num_threads()}, allocator "
          f"{'keeps freed memory' if kept else 'default'}, {load_text()}")

    scan = data_root() / "kitti_seq00_lidar" / "velodyne" / "000000.bin"
    if scan.exists():
        points = np.fromfile(scan, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        ms = median_ms(lambda: segment_terrain(points), args.repeat)
        print(f"segment_terrain, KITTI 000000 ({len(points)} points): median {ms:.1f} ms")
        # the steps of segment_terrain: the grid with the ground-layer statistics, the fit
        # with the ground-layer samples (of which the terrain prior), heights and labels
        layer = default_layer(0.5)
        grid = quantize_points(points, cell_size=0.5, layer=layer)
        surface = fit_grid(grid, positions=points)
        steps = {
            "cloud to frame": median_ms(lambda: as_frame(points), args.repeat),
            "grid": median_ms(lambda: quantize_points(points, cell_size=0.5, layer=layer),
                              args.repeat),
            "fit": median_ms(lambda: fit_grid(grid, positions=points), args.repeat),
            "of which terrain prior": median_ms(
                lambda: terrain_prior_mask(grid, tolerance=0.09), args.repeat),
            "heights + labels": median_ms(lambda: segment_points(surface, points,
                                                                 threshold=None), args.repeat),
        }
        print(f"  steps ({grid.nx} x {grid.ny} cells, {surface.shape[0]} x {surface.shape[1]} "
              f"control points): " + ", ".join(f"{k} {v:.1f} ms" for k, v in steps.items()))
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
    t_grid = median_ms(lambda: quantize_points(positions, cell_size=0.5, region=region),
                       args.repeat)
    t_slope = median_ms(lambda: surface.slope_grid(0.5), args.repeat)
    for method in ("robust", "paper"):
        t_fit = median_ms(lambda: fit_grid(grid, control_points=(25, 25), degree=3,
                                           method=method), args.repeat)
        total = Timing(t_grid + t_fit + t_slope)
        total.cpu = t_grid.cpu + t_fit.cpu + t_slope.cpu
        print(f"paper configuration (34 x 22 m, 0.5 m, 25 x 25, degree 3, {n} points), "
              f"method={method}: grid {t_grid:.1f} ms + fit {t_fit:.1f} ms + slope grid "
              f"{t_slope:.1f} ms = {total:.1f} ms")
    print(load_text())


if __name__ == "__main__":
    main()
