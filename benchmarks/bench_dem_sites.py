"""Real terrain, synthetic sensors: sites of the surveyed raster ``dem_1m/dem.tif`` with a
forest and vehicles on them, scanned by a vehicle lidar standing on the slope and from the air.

Each site is a 100 m x 100 m window of the raster (1 m cells, slopes up to ~36 degrees),
made a smooth terrain (:class:`o3d_terrain.synthetic.GridRelief`, the bicubic spline through
the raster's heights) with 30 trees (3-6 m crowns, 8-16 m tall), 8 rocks (0.5-1.4 m) and the
default obstacle set (pole, pedestrian, car, rock, truck) placed at random, none within 5 m of
the site's centre. Sensors:

- ``vehicle64``: a 64-channel lidar (-24.8 to +2 degrees, 1,800 firings a turn) 1.73 m up on
  a vehicle at the centre standing on the slope (``on_terrain=True``: the cloud is tilted by
  the ground under the vehicle, up to the site's slope there), heading at random;
- ``vehicle16``: a 16-channel lidar (+-15 degrees) on the same vehicle;
- ``airborne``: an airborne strip over the window (6 pulses per m2, projected coordinates).

``o3d_terrain + IMU level``: ours on the vehicle's cloud levelled first with the up
direction an IMU gives (``o3d_terrain.level_cloud``; the labels index the same points).

Truth is exact: a point is ground when its ray hit the terrain. Scored: ground F1 (%), the
share of obstacle points more than 0.3 m above the terrain labelled not ground (obstacle
recall, %), and for ours the surface's height RMSE at the terrain points (m). Every method
runs with its documented defaults (``segment_terrain``; the peers of the ``bench`` extra
with the settings of ``o3d_terrain.evaluation.peers``; Patchwork++ gets the sensor height
on the vehicle, a virtual sensor over the tile from the air). Needs ``../shared/data``
(or ``$O3D_TERRAIN_DATA``).

Run: .venv/bin/python benchmarks/bench_dem_sites.py [--sites 6] [--sensors vehicle64,vehicle16,airborne]
[--peers] [--density 6] [--relief-scale 1] (docs/algorithm.md, "Real terrain under synthetic
sensors").
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import o3d_terrain  # noqa: E402
from o3d_terrain.evaluation.datasets import data_root  # noqa: E402
from o3d_terrain.evaluation.peers import PEERS
from o3d_terrain.evaluation.segmentation import resolve_method  # noqa: E402
from o3d_terrain.evaluation.terrain import read_raster  # noqa: E402
from o3d_terrain.synthetic import (GridRelief, Obstacle, Scene, default_obstacles,  # noqa: E402
                                   sample_airborne, sample_lidar)
from o3d_terrain.synthetic.scene import forest_obstacles  # noqa: E402

HALF = 50.0  # half the site's width (m)
OBSTACLE_HEIGHT = 0.3  # obstacle points above this count in the obstacle recall (m)
#: ours on the vehicle's cloud levelled first with its IMU's up (o3d_terrain.level_cloud)
LEVELLED = "o3d_terrain + IMU level"
SENSORS = {
    "vehicle64": dict(beams=64, fov_deg=(-24.8, 2.0), azimuth_steps=1800, sensor_height=1.73),
    "vehicle16": dict(beams=16, fov_deg=(-15.0, 15.0), azimuth_steps=1800, sensor_height=1.73),
}


def raster_relief(heights: np.ndarray, row: int, col: int, half: float,
                  scale: float = 1.0) -> GridRelief:
    """The raster (1 m cells, rows north to south) ``half`` + 12 m around cell (row, col) as a
    smooth terrain in metres about that cell, its ground at z = 0, its relief times
    ``scale`` (the 12 m beyond ``half`` keep the spline's edge away from the scene)."""
    pad = int(half) + 12
    window = heights[row - pad:row + pad + 1, col - pad:col + pad + 1][::-1]  # rows south to north
    if window.shape != (2 * pad + 1, 2 * pad + 1):
        raise ValueError(f"cell ({row}, {col}) lies within {pad} m of the raster's edge")
    return GridRelief(scale * (window - heights[row, col]), 1.0, x0=-float(pad),
                      y0=-float(pad))


def site_scene(heights: np.ndarray, row: int, col: int, seed: int, scale: float = 1.0) -> Scene:
    """The site centred on raster cell (row, col) (rows north to south), in metres about its
    centre, the centre's ground at z = 0, its relief times ``scale``, with its obstacles."""
    relief = raster_relief(heights, row, col, HALF, scale)
    rng = np.random.default_rng(seed)
    inside = (-HALF + 3, HALF - 3)
    obstacles = list(forest_obstacles(rng, inside, inside, count=38, clear_radius=5.0))
    # the default set (pole, pedestrian, car, rock, truck) turned about the centre at random
    turn = float(rng.uniform(0, 2 * math.pi))
    c, s = math.cos(turn), math.sin(turn)
    for o in default_obstacles(seed):
        x, y = o.center
        obstacles.append(Obstacle(o.kind, (c * x - s * y, s * x + c * y), o.size, o.height,
                                  o.yaw_deg + math.degrees(turn)))
    return Scene(f"dem site {row},{col}", (relief,), tuple(obstacles),
                 region=(-HALF, HALF, -HALF, HALF), seed=seed)


def sites(heights: np.ndarray, count: int, seed: int = 0) -> list[tuple[int, int]]:
    """``count`` site centres drawn at random, at least half a site's width (and the
    spline's margin) from the raster's edge."""
    rng = np.random.default_rng(seed)
    pad = int(HALF) + 13
    rows, cols = heights.shape
    return [(int(rng.integers(pad, rows - pad)), int(rng.integers(pad, cols - pad)))
            for _ in range(count)]


def scan(scene: Scene, sensor: str, k: int, density: float = 6.0):
    """Site ``k``'s cloud from ``sensor`` (``vehicle64``, ``vehicle16`` or ``airborne``)."""
    if sensor == "airborne":
        return sample_airborne(scene, density=density, seed=k)
    return sample_lidar(scene, yaw_deg=float(np.random.default_rng(k).uniform(0, 360)),
                        on_terrain=True, seed=k, **SENSORS[sensor])


def site_frames(sensor: str, *, count: int = 8, scale: float = 1.0, seed: int = 0,
                density: float = 6.0):
    """The sites as labelled frames (``o3d_terrain.evaluation.datasets.LabelledFrame``, every
    point scored, ground = a terrain hit) for ``benchmarks/run_all.py``: they need the
    shared data folder (FileNotFoundError without it)."""
    from o3d_terrain.evaluation.datasets import LabelledFrame

    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise FileNotFoundError("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    heights = read_raster(root / "dem_1m" / "dem.tif").heights.astype(np.float64)
    for k, (row, col) in enumerate(sites(heights, count, seed)):
        scene = site_scene(heights, row, col, seed=seed + k, scale=scale)
        cloud = scan(scene, sensor, k, density)
        obstacle = np.asarray(cloud.is_obstacle, dtype=bool)
        yield LabelledFrame(
            name=f"site {row},{col}", positions=np.asarray(cloud.positions, dtype=np.float64),
            is_ground=~obstacle, scored=np.ones(len(obstacle), bool), obstacle=obstacle,
            kind="aerial" if sensor == "airborne" else "vehicle_lidar",
            sensor_height=None if sensor == "airborne" else SENSORS[sensor]["sensor_height"],
            source=f"dem.tif sites, {sensor}")


def score(ground: np.ndarray, truth: np.ndarray, tall: np.ndarray) -> tuple[float, float]:
    tp = float(np.sum(ground & truth))
    precision = tp / max(float(ground.sum()), 1.0)
    recall = tp / max(float(truth.sum()), 1.0)
    f1 = 2 * precision * recall / max(precision + recall, 1e-12)
    return 100 * f1, 100 * float(np.mean(~ground[tall])) if tall.any() else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sites", type=int, default=6)
    parser.add_argument("--sensors", default="vehicle64,vehicle16,airborne")
    parser.add_argument("--peers", action="store_true",
                        help="also Patchwork++, CSF, SMRF and the RANSAC plane (bench extra)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--density", type=float, default=6.0,
                        help="airborne pulses per m2 (a mountain survey may have under 1)")
    parser.add_argument("--relief-scale", type=float, default=1.0,
                        help="multiply the raster's relief (2: slopes up to ~55 degrees)")
    args = parser.parse_args()
    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise SystemExit("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    heights = read_raster(root / "dem_1m" / "dem.tif").heights.astype(np.float64)
    methods = ["o3d_terrain", LEVELLED] + (list(PEERS) if args.peers else [])
    sensors = args.sensors.split(",")
    unknown = [s for s in sensors if s not in SENSORS and s != "airborne"]
    if unknown:
        raise SystemExit(f"unknown sensor(s) {unknown}; choose from {[*SENSORS, 'airborne']}")
    print("ground F1 % / obstacle recall %; ours also the height RMSE (m) at the terrain points "
          "(as scanned / levelled)")
    print("| site (row, col) | slope mean / p95 (deg) | sensor | points | tilt (deg) | "
          + " | ".join(methods) + " | ours RMSE (m) |")
    print("|---|---|---|---:|---:|" + "---|" * len(methods) + "---:|")
    totals: dict = {}
    for k, (row, col) in enumerate(sites(heights, args.sites, args.seed)):
        scene = site_scene(heights, row, col, seed=args.seed + k, scale=args.relief_scale)
        gx, gy = np.meshgrid(np.linspace(-HALF, HALF, 101), np.linspace(-HALF, HALF, 101))
        slope = scene.slope_deg(gx, gy)
        for sensor in sensors:
            cloud = scan(scene, sensor, k, args.density)
            if sensor == "airborne":
                kind, height, tilt = "aerial", None, 0.0
            else:
                kind, height = "vehicle_lidar", SENSORS[sensor]["sensor_height"]
                tilt = math.degrees(math.acos(min(1.0, cloud.world_from_sensor[2, 2])))
            positions = np.asarray(cloud.positions, dtype=np.float64)
            truth = ~cloud.is_obstacle
            tall = cloud.is_obstacle & (cloud.true_height_above_terrain > OBSTACLE_HEIGHT)
            cells, rmse = [], float("nan")
            for name in methods:
                if name == "o3d_terrain":
                    surface, inliers = o3d_terrain.segment_terrain(positions)
                    ground = np.zeros(len(positions), bool)
                    ground[inliers] = True
                    z = cloud.terrain_height(positions[truth, 0], positions[truth, 1])
                    err = surface(positions[truth, 0], positions[truth, 1]) - z
                    rmse = float(np.sqrt(np.nanmean(err ** 2)))
                elif name == LEVELLED:
                    if sensor == "airborne":  # level already
                        cells.append("")
                        continue
                    # the IMU's up: world +z in the sensor's frame
                    levelled, _ = o3d_terrain.level_cloud(positions, cloud.world_from_sensor[2, :3])
                    surface, inliers = o3d_terrain.segment_terrain(levelled)
                    ground = np.zeros(len(positions), bool)
                    ground[inliers] = True
                    q = levelled[truth]  # its z is the world's: the truth is q_z - true height
                    err = surface(q[:, 0], q[:, 1]) - (q[:, 2] - cloud.true_height_above_terrain[truth])
                    rmse_levelled = float(np.sqrt(np.nanmean(err ** 2)))
                    totals.setdefault((sensor, "rmse levelled"), []).append(rmse_levelled)
                else:
                    ground = np.asarray(resolve_method(name, kind=kind, sensor_height=height)(
                        positions), bool)
                f1, rec = score(ground, truth, tall)
                totals.setdefault((sensor, name), []).append((f1, rec))
                cells.append(f"{f1:.2f} / {rec:.1f}")
            totals.setdefault((sensor, "rmse"), []).append(rmse)
            rmse_text = f"{rmse:.3f}" + ("" if sensor == "airborne" else
                                         f" / {totals[(sensor, 'rmse levelled')][-1]:.3f}")
            print(f"| {row},{col} | {np.mean(slope):.1f} / {np.percentile(slope, 95):.1f} | "
                  f"{sensor} | {len(positions):,} | {tilt:.1f} | " + " | ".join(cells)
                  + f" | {rmse_text} |", flush=True)
    print()
    print("| sensor | " + " | ".join(f"{m} F1 / obstacle recall" for m in methods)
          + " | ours RMSE (m), as scanned / levelled |")
    print("|---|" + "---|" * len(methods) + "---:|")
    for sensor in sensors:
        cells = []
        for name in methods:
            if (sensor, name) not in totals:
                cells.append("")
                continue
            f1, rec = np.mean(totals[(sensor, name)], axis=0)
            cells.append(f"{f1:.2f} / {rec:.1f}")
        rmse_text = f"{np.mean(totals[(sensor, 'rmse')]):.3f}"
        if (sensor, "rmse levelled") in totals:
            rmse_text += f" / {np.mean(totals[(sensor, 'rmse levelled')]):.3f}"
        print(f"| {sensor} mean | " + " | ".join(cells) + f" | {rmse_text} |")


if __name__ == "__main__":
    main()
