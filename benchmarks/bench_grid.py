"""Time GridQuantize (eq. 1 + neighbour filling) at standard sizes.

    python benchmarks/bench_grid.py [--repeat 30]

Prints the median and the 10th/90th percentiles per case, for the stage called on a frame (the
cloud already in Open3D tensor form, as in a pipeline) and on a numpy array (which includes
the conversion to a frame). Cases: a 300k-point cloud in the
paper's 34 m x 22 m window at 0.5 m cells (68 x 44 cells), and a 120k-point 360° lidar-like
frame (160 m across, 320 x 320 cells). Points are random (uniform x/y, smooth z plus noise):
the kernel's cost depends on the point and cell counts, not on the shape of the terrain.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from o3d_terrain import GridQuantize, as_frame  # noqa: E402


def cases(rng):
    xy = rng.uniform([0, -11], [34, 11], size=(300_000, 2))
    z = 0.3 * np.sin(xy[:, 0] / 5) + rng.normal(0, 0.05, len(xy))
    yield "paper window 34x22 m, 300k points, 0.5 m", np.column_stack([xy, z]), (0, 34, -11, 11)
    r = 80 * np.sqrt(rng.uniform(0.001, 1, 120_000))
    a = rng.uniform(0, 2 * np.pi, 120_000)
    xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    z = 0.02 * xy[:, 0] + rng.normal(0, 0.05, len(xy))
    yield "360-degree frame 160 m, 120k points, 0.5 m", np.column_stack([xy, z]), None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=30)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")
    for name, points, region in cases(rng):
        stage = GridQuantize(cell_size=0.5, region=region)
        frame = as_frame(points)
        stage(frame)  # compile / load the numba cache
        for label, data in (("on a frame", frame), ("from a numpy array", points)):
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                stage(data)
                times.append(time.perf_counter() - t0)
            ms = np.array(times) * 1000
            print(f"GridQuantize {label}, {name}: median {np.median(ms):.2f} ms "
                  f"(p10 {np.percentile(ms, 10):.2f}, p90 {np.percentile(ms, 90):.2f}), "
                  f"{args.repeat} runs")
    print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")

if __name__ == "__main__":
    main()
