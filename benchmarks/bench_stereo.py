"""Time the stereo chain: pair -> disparity -> cloud -> grid -> terrain -> segmentation.

    python benchmarks/bench_stereo.py [--repeat 15] [--no-kitti]

Cases:

- a rendered 640 x 480 pair of the synthetic off-road scene (camera 1.6 m high, pitched 5°
  down), depth range 3-40 m, matched at full size and at half size (``downscale: 2``);
- the KITTI object pair (1242 x 375, ``../shared/data/kitti_stereo_object`` or
  ``$O3D_TERRAIN_DATA``) with depth range 3-40 m, when the data is present.

Each step is timed separately (median and 10th/90th percentiles over ``--repeat`` runs, after
one warm-up run); "total" is the median of the summed per-run times. The terrain step uses the
``RationalBSplineTerrain`` / ``Segmenter`` stages when they exist, else
``o3d_terrain.api.segment_terrain`` (grid, fit and segmentation in one call).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from o3d_terrain.stages import GridQuantize
from o3d_terrain.stereo import StereoCloud, load_calibration

REPO = Path(__file__).resolve().parents[1]
REGION = (3.0, 40.0, -15.0, 15.0)  # vehicle frame, metres ahead and to the sides


def data_root() -> Path | None:
    env = os.environ.get("O3D_TERRAIN_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    return root if root.is_dir() else None


def terrain_steps():
    """The terrain and segmentation step as a function of a frame."""
    try:
        from o3d_terrain.stages import RationalBSplineTerrain, Segmenter  # type: ignore

        fit, segment = RationalBSplineTerrain(), Segmenter()
        return "stages RationalBSplineTerrain + Segmenter", lambda frame: segment(fit(frame))
    except ImportError:
        from o3d_terrain.api import segment_terrain

        def run(frame):
            return segment_terrain(frame.positions, region=REGION, cell_size=0.5)

        return "api.segment_terrain (grid + fit + segmentation)", run


def time_chain(settings: StereoCloud, left, right, calibration, repeat: int, with_terrain: bool):
    terrain_name, terrain = terrain_steps()
    grid = GridQuantize(cell_size=0.5, region=REGION)
    steps: dict[str, list[float]] = {"matching": [], "cloud": [], "grid": []}
    if with_terrain:
        steps["terrain + segmentation"] = []
    points = 0
    match = None
    for run in range(repeat + 1):
        t0 = time.perf_counter()
        match = settings.match(left, right, calibration)
        t1 = time.perf_counter()
        frame = settings.frame_from_match(match)
        t2 = time.perf_counter()
        gridded = grid(frame)
        t3 = time.perf_counter()
        if with_terrain:
            terrain(gridded)
        t4 = time.perf_counter()
        points = len(frame)
        if run == 0:
            continue  # warm-up (numba compile, OpenCV buffers)
        steps["matching"].append(t1 - t0)
        steps["cloud"].append(t2 - t1)
        steps["grid"].append(t3 - t2)
        if with_terrain:
            steps["terrain + segmentation"].append(t4 - t3)
    totals = np.sum([steps[k] for k in steps], axis=0)
    return steps, totals, points, match, terrain_name


def report(title: str, steps, totals, points, match) -> None:
    h, w = match.disparity.shape
    print(f"\n{title}")
    print(f"  matched at {w} x {h} px, disparities {match.disparity_range[0]}..{match.disparity_range[1]}"
          f" px, {np.isfinite(match.disparity).mean():.1%} valid, {points} points")
    for name, values in steps.items():
        ms = 1000 * np.asarray(values)
        print(f"  {name:<24s} median {np.median(ms):7.1f} ms  (p10 {np.percentile(ms, 10):6.1f}, "
              f"p90 {np.percentile(ms, 90):6.1f})")
    ms = 1000 * totals
    print(f"  {'total':<24s} median {np.median(ms):7.1f} ms  (p10 {np.percentile(ms, 10):6.1f}, "
          f"p90 {np.percentile(ms, 90):6.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--no-kitti", action="store_true")
    args = parser.parse_args()
    import cv2

    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"OpenCV {cv2.__version__} with {cv2.getNumThreads()} threads")
    from o3d_terrain.synthetic import make_scene, render_stereo_pair

    scene = make_scene("offroad", seed=0)
    pair = render_stereo_pair(scene, width=640, height=480, camera_height=1.6, tilt_deg=(0.0, 5.0))
    terrain_name = terrain_steps()[0]
    print(f"terrain step: {terrain_name}")
    for downscale in (1, 2):
        settings = StereoCloud(depth_range=(3.0, 40.0), downscale=downscale, frame="vehicle",
                               camera_height=1.6, pitch_deg=5.0)
        steps, totals, points, match, _ = time_chain(settings, pair.left, pair.right,
                                                     pair.calibration, args.repeat, True)
        report(f"synthetic off-road pair 640 x 480, downscale {downscale}", steps, totals, points, match)

    root = data_root()
    kitti = None if root is None else root / "kitti_stereo_object"
    if args.no_kitti or kitti is None or not (kitti / "left.png").exists():
        print("\nKITTI pair: skipped (no data or --no-kitti)")
        return
    left = cv2.cvtColor(cv2.imread(str(kitti / "left.png")), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(kitti / "right.png")), cv2.COLOR_BGR2RGB)
    calibration = load_calibration(kitti / "calib.txt")
    for downscale in (1, 2):
        settings = StereoCloud(depth_range=(3.0, 40.0), downscale=downscale, frame="vehicle",
                               camera_height=1.65)
        steps, totals, points, match, _ = time_chain(settings, left, right, calibration,
                                                     args.repeat, True)
        report(f"KITTI object pair 1242 x 375, downscale {downscale}", steps, totals, points, match)


if __name__ == "__main__":
    main()
