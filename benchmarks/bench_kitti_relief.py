"""Relief under a real street scan: the SemanticKITTI frames with smooth relief added.

Every point of a frame (ground, cars, buildings, vegetation alike) is raised by the same
smooth height field h(x, y) of the sensor frame: a ramp, a roadside ditch or berm, rolling
ground, a valley, a bowl, a crest. The labels do not change, so a method that follows the
relief scores what it scores on the level frame; what it loses is what the relief costs it.
The field is smooth at the scale of an object (it shears a car by a few centimetres).

What this does not simulate: the scan is not cast again, so a point stays visible where
the relief would hide it. Relief that rises above the sensor within its range would put
ground in view that a real sensor could not see (the line-of-sight test, rightly, calls it
obstacle), so the fields here stay below the sensor's line of sight: ditches, berms under
2 m, rolling ground of 1.5 m, and slopes the frame extends along. For hills and steep
relief scanned by a sensor standing on them, see ``bench_dem_sites.py``.

Run: .venv/bin/python benchmarks/bench_kitti_relief.py [--reliefs ramp15,ditch,...] [--peers]
(docs/algorithm.md, "Relief under a real street scan"). Needs ``../shared/data`` (or
``$O3D_TERRAIN_DATA``).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from o3d_terrain.evaluation import datasets as ds  # noqa: E402
from o3d_terrain.evaluation.metrics import segmentation_counts  # noqa: E402
from o3d_terrain.evaluation.segmentation import resolve_method  # noqa: E402

#: the height fields (m) over the sensor frame's x (forward) and y (left), in metres
RELIEFS = {
    "level": lambda x, y: 0.0 * x,
    "ramp15": lambda x, y: 0.15 * x,  # 8.5 deg up ahead
    "ramp30": lambda x, y: 0.30 * x,  # 16.7 deg
    "side25": lambda x, y: 0.25 * y,  # 14 deg across the road
    "ditch": lambda x, y: -2.0 * np.exp(-(y - 6.0) ** 2 / (2 * 2.5 ** 2)),  # 2 m deep, left
    "berm": lambda x, y: 1.5 * np.exp(-(y + 7.0) ** 2 / (2 * 2.0 ** 2)),  # 1.5 m high, right
    "rolling": lambda x, y: 1.5 * np.sin(2 * np.pi * x / 30) * np.sin(2 * np.pi * y / 40),
    "valley": lambda x, y: 0.015 * y ** 2,  # the road along a valley floor
    "bowl": lambda x, y: 0.004 * (x ** 2 + y ** 2),
    "crest": lambda x, y: -0.006 * (x ** 2 + y ** 2),  # the sensor on a rounded crest
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reliefs", default=",".join(RELIEFS),
                        help=f"comma-separated, from {', '.join(RELIEFS)}")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++ and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    reliefs = args.reliefs.split(",")
    unknown = [r for r in reliefs if r not in RELIEFS]
    if unknown:
        raise SystemExit(f"unknown relief(s) {unknown}; choose from {list(RELIEFS)}")
    root = ds.data_root()
    if root is None or not (root / "kitti_seq00_lidar").is_dir():
        raise SystemExit("needs ../shared/data/kitti_seq00_lidar (or $O3D_TERRAIN_DATA)")
    frames, failures = ds.iter_frames(ds.semantic_kitti_frames(root / "kitti_seq00_lidar"))
    for failure in failures:
        print(f"skipped {failure.name}: {failure.reason}")
    methods = ["o3d_terrain"] + (["patchworkpp", "ransac_plane"] if args.peers else [])
    print(f"ground F1 %, mean over {len(frames)} SemanticKITTI frames (per frame in brackets)")
    print("| relief | " + " | ".join(methods) + " |")
    print("|---|" + "---:|" * len(methods))
    for name in reliefs:
        cells = []
        for method_name in methods:
            f1 = []
            for frame in frames:
                p = frame.positions.copy()
                p[:, 2] += RELIEFS[name](p[:, 0], p[:, 1])
                method = resolve_method(method_name, kind=frame.kind,
                                        sensor_height=frame.sensor_height)
                ground = np.asarray(method(p), bool)
                f1.append(100 * segmentation_counts(ground, frame.is_ground,
                                                    scored=frame.scored).f1)
            cells.append(f"{np.mean(f1):.2f} ({' '.join(f'{v:.2f}' for v in f1)})")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
