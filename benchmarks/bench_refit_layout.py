"""The refit's control-point cap (o3d_terrain.refine.REFINE_MAX_CONTROL_POINTS) against height
truth and time.

Height truth: discs of the real bare-earth raster ``dem_1m/dem.tif`` of the shared data
folder scanned as a ground sensor 1.8 m up takes them (radius 40 m, point density falling as
1 / r, 2 cm noise), fitted with ``fit_terrain``'s defaults in the sensor's frame and scored
by ``evaluate_terrain_against_raster`` (raster cells within 1 m of a point). Time: the median
of ``segment_terrain`` on the first SemanticKITTI frame. Each cap is set on the stage module
for its run only.

Run: .venv/bin/python benchmarks/bench_refit_layout.py [--caps 32,40,48,64] [--discs 6]
(docs/algorithm.md, "A finer layout for the refit").
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.interpolate import RegularGridInterpolator  # noqa: E402

import o3d_terrain  # noqa: E402
import o3d_terrain.stages.terrain as stage_module  # noqa: E402
from o3d_terrain.evaluation.datasets import data_root  # noqa: E402
from o3d_terrain.evaluation.terrain import evaluate_terrain_against_raster, read_raster  # noqa: E402


def scans(raster, discs: int, radius: float, seed: int = 0):
    """(positions in the sensor's frame, 4 x 4 pose into the raster's) of ``discs`` scans."""
    heights = raster.heights
    rows, cols = heights.shape
    x0, y0 = raster.origin
    cs = raster.cell_size
    xc = x0 + (np.arange(cols) + 0.5) * cs
    yc = y0 - (np.arange(rows) + 0.5) * cs
    truth = RegularGridInterpolator((yc[::-1], xc), heights[::-1], method="cubic")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(discs):
        cx = rng.uniform(xc[0] + radius + 3, xc[-1] - radius - 3)
        cy = rng.uniform(yc[-1] + radius + 3, yc[0] - radius - 3)
        n = 60_000
        r = radius * np.sqrt(rng.uniform((2 / radius) ** 2, 1, n))
        r = r[rng.uniform(0, 1, n) < np.minimum(1, 4.0 / r)]  # density falling as 1 / r
        a = rng.uniform(0, 2 * np.pi, r.size)
        x, y = cx + r * np.cos(a), cy + r * np.sin(a)
        z = truth(np.column_stack([y, x])) + rng.normal(0, 0.02, r.size)
        sensor = np.array([cx, cy, float(truth([[cy, cx]])[0]) + 1.8])
        pose = np.eye(4)
        pose[:3, 3] = sensor
        out.append((np.column_stack([x, y, z]) - sensor, pose))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--caps", default="32,40,48,64")
    parser.add_argument("--discs", type=int, default=6)
    parser.add_argument("--radius", type=float, default=40.0)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise SystemExit("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    raster = read_raster(root / "dem_1m" / "dem.tif")
    discs = scans(raster, args.discs, args.radius)
    kitti = root / "kitti_seq00_lidar" / "velodyne" / "000000.bin"
    frame = (np.fromfile(kitti, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
             if kitti.exists() else None)
    default = stage_module.REFINE_MAX_CONTROL_POINTS
    print(f"{len(discs)} discs of {args.radius:g} m radius, "
          f"{np.mean([len(p) for p, _ in discs]):,.0f} points each; default cap {default}")
    print("| refit cap | height RMSE (m), mean over discs | KITTI segment_terrain (ms) |")
    print("|---:|---:|---:|")
    try:
        for cap in (int(c) for c in args.caps.split(",")):
            stage_module.REFINE_MAX_CONTROL_POINTS = cap
            rmse = []
            for positions, pose in discs:
                report = evaluate_terrain_against_raster(positions, raster, pose=pose)
                rmse.append(report.results[0].stats["height_rmse_m"])
            ms = float("nan")
            if frame is not None:
                for _ in range(2):
                    o3d_terrain.segment_terrain(frame)
                times = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    o3d_terrain.segment_terrain(frame)
                    times.append(time.perf_counter() - start)
                ms = 1e3 * float(np.median(times))
            print(f"| {cap} | {np.mean(rmse):.4f} | {ms:.1f} |", flush=True)
    finally:
        stage_module.REFINE_MAX_CONTROL_POINTS = default


if __name__ == "__main__":
    main()
