"""Ground under grass: the synthetic lidar scenes with a layer of grass over their terrain.

Each ground return of a scene's lidar frame is replaced by the first grass hit along its ray:
the ray is marched back from the soil toward the sensor (2 cm steps, at most 15 m) while it
stays within ``height`` of the exact terrain, and a hit falls at an exponential depth into
that stretch (``extinction`` per metre of path); a ray whose depth exceeds the stretch reaches
the soil and keeps its return. Grass returns are ground in the truth (as RELLIS-3D's grass,
a ground label): the question is whether grass tops beyond the obstacle threshold above the
soil cost ground recall. Obstacles keep their returns (the layer does not hide their lower
parts, so their recall here is not a grass figure).

Run: .venv/bin/python benchmarks/bench_grass.py [--heights 0.1,0.2,0.3] [--scenes ...]
[--peers] (docs/algorithm.md, "Ground under grass").
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from o3d_terrain.evaluation import datasets as ds  # noqa: E402
from o3d_terrain.evaluation.metrics import segmentation_counts  # noqa: E402
from o3d_terrain.evaluation.peers import PEERS
from o3d_terrain.evaluation.segmentation import resolve_method  # noqa: E402


def grass_layer(frame: ds.LabelledFrame, height: float, extinction: float, seed: int = 1,
                step: float = 0.02, max_path: float = 15.0) -> np.ndarray:
    """The frame's positions with its ground returns moved to their first grass hit (module
    docstring); the sensor is at the origin of the frame's coordinates."""
    rng = np.random.default_rng(seed)
    p = frame.positions.copy()
    idx = np.flatnonzero(frame.is_ground & frame.scored)
    q = p[idx]
    r = np.linalg.norm(q, axis=1)
    u = q / r[:, None]
    depth_travelled = rng.exponential(1.0 / extinction, idx.size)
    # march back from the soil while the ray stays in the layer (only the rays still in it)
    stretch = np.zeros(idx.size)
    active = np.arange(idx.size)
    for i in range(1, int(max_path / step) + 1):
        if active.size == 0:
            break
        t = np.maximum(r[active] - step * i, 0.0)
        xyz = u[active] * t[:, None]
        above = xyz[:, 2] - frame.terrain(xyz[:, 0], xyz[:, 1])
        inside = (above <= height) & (above >= -0.02) & (t > 0)
        stretch[active[inside]] = step * i
        active = active[inside]
    hit = depth_travelled < stretch
    p[idx[hit]] = u[hit] * (r[hit] - stretch[hit] + depth_travelled[hit])[:, None]
    return p


def score(frame: ds.LabelledFrame, positions: np.ndarray, method) -> tuple[float, float]:
    """(ground F1 %, ground recall %) of ``method`` on ``positions`` with the frame's truth."""
    counts = segmentation_counts(np.asarray(method(positions), bool), frame.is_ground,
                                 scored=frame.scored)
    return 100 * counts.f1, 100 * counts.recall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heights", default="0.1,0.2,0.3", help="grass heights (m)")
    parser.add_argument("--extinction", type=float, default=4.0,
                        help="grass hits per metre of ray path inside the layer")
    parser.add_argument("--scenes", default="hills,ditch_berm,mounds,offroad,forest")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    methods = ["o3d_terrain"] + (list(PEERS) if args.peers else [])
    heights = [float(h) for h in args.heights.split(",")]
    print(f"ground F1 % (recall %), extinction {args.extinction:g}/m; "
          "columns: no grass, then each grass height")
    print("| scene | method | no grass | " + " | ".join(f"{h:g} m" for h in heights) + " |")
    print("|---|---|---:|" + "---:|" * len(heights))
    for name in args.scenes.split(","):
        frame = next(ds.synthetic_frames([name], seed=0))
        if isinstance(frame, ds.FrameFailure):
            print(f"| {name} | failed: {frame.reason} |")
            continue
        clouds = [frame.positions] + [grass_layer(frame, h, args.extinction) for h in heights]
        for method_name in methods:
            cells = []
            for positions in clouds:
                # a fresh method per cloud: Patchwork++ adapts from frame to frame
                method = resolve_method(method_name, kind=frame.kind,
                                        sensor_height=frame.sensor_height)
                f1, recall = score(frame, positions, method)
                cells.append(f"{f1:.2f} ({recall:.1f})")
            print(f"| {name} | {method_name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
