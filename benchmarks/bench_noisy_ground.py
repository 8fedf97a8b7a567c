"""Ground under sensor noise: the synthetic lidar scenes with Gaussian noise added to every z.

Rough soil, a low-cost lidar or a photogrammetric cloud scatter the ground by several
centimetres. Each scene (with the default obstacles where it has none) is scanned by the
synthetic 64-line lidar, then every point's z gets independent N(0, sigma) noise (truth
unchanged); the table gives ground F1 and recall, and the obstacle recall of the points
that lie more than 0.3 m above the exact terrain before the noise (the issue's obstacle
measure): a threshold that rises with the noise keeps the ground and gives up the lowest
obstacle points.

Run: .venv/bin/python benchmarks/bench_noisy_ground.py [--sigmas 0.03,0.05,0.08]
[--scenes ...] [--peers] (docs/algorithm.md, "The threshold on a noisy ground").
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from o3d_terrain.evaluation.metrics import segmentation_counts
from o3d_terrain.evaluation.peers import PEERS
from o3d_terrain.evaluation.segmentation import resolve_method
from o3d_terrain.synthetic import default_obstacles, make_scene, sample_lidar

TALL = 0.3  # m above the exact terrain: the obstacle points the target counts


class Frame:
    """A scene's lidar frame and its truth: ``positions`` (N, 3), ``is_ground`` and ``scored``
    (N,) bool, ``tall`` (N,) bool (obstacle points more than TALL above the exact terrain),
    ``sensor_height`` (m above the terrain under it)."""

    def __init__(self, name: str, seed: int = 0) -> None:
        scene = make_scene(name, seed=seed)
        if not scene.obstacles:
            scene = scene.with_obstacles(default_obstacles(seed))
        cloud = sample_lidar(scene, seed=seed)
        self.positions = np.asarray(cloud.positions, dtype=np.float64)
        obstacle = np.asarray(cloud.is_obstacle, dtype=bool)
        self.scored = np.isfinite(self.positions).all(axis=1) & ~np.asarray(cloud.is_outlier)
        self.is_ground = ~obstacle
        p = np.where(self.scored[:, None], self.positions, 0.0)
        above = p[:, 2] - cloud.terrain_height(p[:, 0], p[:, 1])
        self.tall = self.scored & obstacle & (above > TALL)
        x, y, z = np.asarray(cloud.world_from_sensor)[:3, 3]
        self.sensor_height = float(z - scene.height(np.array([x]), np.array([y]))[0])


def score(frame: Frame, positions: np.ndarray, method) -> tuple[float, float, float | None]:
    """(ground F1 %, ground recall %, obstacle recall % of the frame's ``tall`` points, None
    for a frame without them) of ``method`` on ``positions``."""
    counts = segmentation_counts(np.asarray(method(positions), bool), frame.is_ground,
                                 scored=frame.scored, obstacle=frame.tall)
    obstacle = 100 * counts.obstacle_recall if counts.obstacle_points else None
    return 100 * counts.f1, 100 * counts.recall, obstacle


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sigmas", default="0.03,0.05,0.08", help="noise on z (m)")
    parser.add_argument("--scenes", default="flat,hills,ramp,ditch_berm,mounds,offroad")
    parser.add_argument("--seed", type=int, default=1, help="seed of the noise")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    args = parser.parse_args()
    methods = ["o3d_terrain"] + (list(PEERS) if args.peers else [])
    sigmas = [float(s) for s in args.sigmas.split(",")]
    print("ground F1 % (ground recall %) / obstacle recall % of the points more than "
          f"{TALL:g} m up; columns: no added noise, then each noise sigma")
    print("| scene | method | no noise | " + " | ".join(f"{s:g} m" for s in sigmas) + " |")
    print("|---|---|---:|" + "---:|" * len(sigmas))
    means: dict[str, list[list[float]]] = {m: [[] for _ in range(len(sigmas) + 1)]
                                           for m in methods}
    for name in args.scenes.split(","):
        frame = Frame(name)
        rng = np.random.default_rng(args.seed)
        clouds = [frame.positions]
        for sigma in sigmas:
            noisy = frame.positions.copy()
            noisy[:, 2] += rng.normal(0.0, sigma, len(noisy))
            clouds.append(noisy)
        for method_name in methods:
            cells = []
            for k, positions in enumerate(clouds):
                # a fresh method per cloud: Patchwork++ adapts from frame to frame
                method = resolve_method(method_name, kind="vehicle_lidar",
                                        sensor_height=frame.sensor_height)
                f1, recall, obstacle = score(frame, positions, method)
                means[method_name][k].append(f1)
                cells.append(f"{f1:.2f} ({recall:.1f}) / "
                             + ("-" if obstacle is None else f"{obstacle:.1f}"))
            print(f"| {name} | {method_name} | " + " | ".join(cells) + " |", flush=True)
    for method_name, columns in means.items():
        print(f"| mean F1 | {method_name} | "
              + " | ".join(f"{np.mean(c):.2f}" if c else "-" for c in columns) + " |")


if __name__ == "__main__":
    main()
