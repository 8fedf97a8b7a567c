"""Obstacles and cost map: speed on a 120k-point frame, detection on SemanticKITTI, tracking on
the synthetic sequence.

    .venv/bin/python benchmarks/bench_obstacles.py [--repeats 30] [--threads N] [--speed-only]

Speed: median wall time of obstacle clustering plus the cost map (ObstacleDetector +
TraversabilityCost given the terrain surface and the Segmenter's labels) on KITTI seq. 00
frame 000000 (124,668 points) when ../shared/data is present, else on a 64-beam synthetic
frame. The terrain fit is not included (it belongs to the terrain benchmark). The 90th
percentile is printed too: on a shared machine, kernels that wait for threads show there first.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from o3d_terrain.api import fit_terrain  # noqa: E402
from o3d_terrain.frame import as_frame  # noqa: E402
from o3d_terrain.obstacles import detect_obstacles  # noqa: E402
from o3d_terrain.segment import segment_points  # noqa: E402
from o3d_terrain.traversability import traversability_cost  # noqa: E402


def data_root() -> Path | None:
    env = os.environ.get("O3D_TERRAIN_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    return root if root.is_dir() else None


def kitti_frame(root: Path, name: str):
    folder = root / "kitti_seq00_lidar"
    points = np.fromfile(folder / "velodyne" / f"{name}.bin", np.float32).reshape(-1, 4)
    labels = np.fromfile(folder / "labels" / f"{name}.label", np.uint32)
    return points[:, :3].astype(np.float64), labels


def speed(positions: np.ndarray, repeats: int) -> None:
    surface = fit_terrain(positions)
    labels, heights = segment_points(surface, positions)
    frame = as_frame(positions).with_attributes(labels=labels, heights_above_terrain=heights)
    times = {"clustering": [], "cost map": [], "total": []}
    for k in range(repeats + 2):
        t0 = time.perf_counter()
        obstacles = detect_obstacles(frame, surface=surface)
        t1 = time.perf_counter()
        cost_map = traversability_cost(surface, frame, obstacles=obstacles)
        t2 = time.perf_counter()
        if k >= 2:  # the first runs compile and warm caches
            times["clustering"].append(t1 - t0)
            times["cost map"].append(t2 - t1)
            times["total"].append(t2 - t0)
    import numba

    print(f"speed: {len(positions)} points, {len(obstacles)} obstacles, cost map "
          f"{cost_map.shape[0]} x {cost_map.shape[1]} cells of {cost_map.cell_size} m; numba "
          f"threads {numba.get_num_threads()}, load average "
          + ", ".join(f"{v:.2f}" for v in os.getloadavg()))
    for key, values in times.items():
        tail = statistics.quantiles(values, n=10)[-1] if len(values) > 1 else values[0]
        print(f"  {key:<11} median {1e3 * statistics.median(values):6.2f} ms   "
              f"90th percentile {1e3 * tail:6.2f} ms   min {1e3 * min(values):6.2f} ms   "
              f"({repeats} runs)")


def kitti_detection(root: Path) -> None:
    from o3d_terrain.evaluation.datasets import SEMANTIC_KITTI_GROUND
    from o3d_terrain.obstacles import instances_found, semantic_kitti_instances

    for name in ("000000", "000001", "000002"):
        positions, labels = kitti_frame(root, name)
        surface = fit_terrain(positions)
        point_labels, heights = segment_points(surface, positions)
        instances = semantic_kitti_instances(labels, positions)
        ground = np.isin(labels & 0xFFFF, SEMANTIC_KITTI_GROUND)
        for method in ("grid", "dbscan"):
            t0 = time.perf_counter()
            obstacles = detect_obstacles(positions, labels=point_labels,
                                         heights_above_terrain=heights, method=method)
            seconds = time.perf_counter() - t0
            found = instances_found(obstacles.cluster_ids, instances, 50)
            mostly_ground = sum(1 for o in obstacles if ground[o.indices].mean() > 0.5)
            print(f"kitti {name} {method:<6}: {sum(found.values())}/{len(found)} instances "
                  f"(>= 50 points) found, {len(obstacles)} obstacles, {mostly_ground} mostly "
                  f"ground, {1e3 * seconds:.0f} ms (one run)")


def tracking() -> None:
    from o3d_terrain.synthetic import sequence_ground, synthetic_sequence
    from o3d_terrain.tracking import ObstacleTracker, score_tracks, track_frames

    frames = synthetic_sequence(frames=20, seed=0)
    for label, detect in (("exact ground", lambda f: detect_obstacles(
            f, surface=sequence_ground())), ("fitted terrain", None)):
        for merge_distance in (0.5, 0.0):
            steps = track_frames(frames, detect=detect,
                                 tracker=ObstacleTracker(merge_distance=merge_distance))
            score = score_tracks(frames, steps)
            print(f"tracking ({label}, {len(frames)} frames, merge_distance {merge_distance}): "
                  f"{score.tracked}/{score.detected} obstacles tracked, "
                  f"{score.identity_switches} identity switches, {score.spurious} one-frame "
                  f"spurious detections, {score.spurious_confirmed} confirmed")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--threads", type=int, default=None,
                        help="numba threads for the kernels that split work over threads")
    parser.add_argument("--speed-only", action="store_true",
                        help="only the speed figures (no detection or tracking runs)")
    args = parser.parse_args()
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    root = data_root()
    if root is not None:
        positions, _ = kitti_frame(root, "000000")
    else:
        from o3d_terrain.synthetic import make_scene, sample_lidar

        positions = sample_lidar(make_scene("offroad"), beams=64, azimuth_steps=1800).positions
    speed(positions, args.repeats)
    if args.speed_only:
        return
    if root is not None:
        kitti_detection(root)
    tracking()


if __name__ == "__main__":
    main()
