"""Height bias of the fitted terrain surface by slope class, on exact truth (no assertions).

The surface is compared with the exact terrain at the centres of the 0.5 m cells that hold a
terrain point (no credit or blame for occlusion shadows), in the cloud's own frame (a tilted
sensor's too). Per slope band of the exact terrain (0-10, 10-20, 20-30, > 30 degrees): the
signed median of surface - truth ("bias"), the RMSE and the number of nodes.

Sources:

- ``synthetic``: the named synthetic scenes, the held-out steep scenes of bench_accuracy.py
  and two planes of 25 and 35 degrees (each with the default obstacle set, seed 0), seen by
  the spinning lidar, the same lidar tilted (5, 3) degrees and the stereo rig (with its range
  noise model, as bench_accuracy.py);
- ``dem``: ``dem_1m/dem.tif`` as terrain (bicubic): windows sampled uniformly at 4 points/m²
  with 2 cm noise (an airborne-like cloud, ``o3d_terrain eval terrain``'s sampler), and 60 m
  windows with the spinning lidar level and tilted (5, 3) degrees at their centre.

Fits run as ``fit_terrain(positions)`` with its defaults plus ``--option KEY=VALUE`` options of
``fit_grid_detailed`` (``--option cell_plane=False``: eq. 1 about the cell means, the default
before the cells' planes).

Run: .venv/bin/python benchmarks/bench_slope_bias.py [--only synthetic,dem] [--option K=V]
"""

from __future__ import annotations

import argparse
import ast
import math
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bench_accuracy as _acc
import numpy as np

from o3d_terrain.noise import RangeNoise

BANDS = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 90.0))
SPACING = 0.5


@dataclass(frozen=True)
class DemTerrain:
    """A DEM raster as a smooth terrain feature (bicubic spline; x = column, y = row, metres)."""

    spline: object

    @classmethod
    def window(cls, dem: np.ndarray, rows: slice, cols: slice) -> DemTerrain:
        from scipy.interpolate import RectBivariateSpline

        block = dem[rows, cols]
        x = np.arange(block.shape[1], dtype=np.float64)
        y = np.arange(block.shape[0], dtype=np.float64)
        return cls(RectBivariateSpline(x, y, (block - np.nanmean(block)).T, kx=3, ky=3))

    def height(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        return self.spline.ev(x.ravel(), y.ravel()).reshape(x.shape)

    def gradient(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        gx = self.spline.ev(x.ravel(), y.ravel(), dx=1).reshape(x.shape)
        gy = self.spline.ev(x.ravel(), y.ravel(), dy=1).reshape(x.shape)
        return gx, gy


def node_errors(surface, cloud) -> tuple[np.ndarray, np.ndarray]:
    """(surface - truth, slope of the truth in degrees) at the centres of the SPACING cells
    that hold a terrain point of a SyntheticCloud, in its frame."""
    terrain = cloud.positions[~cloud.is_obstacle & ~cloud.is_outlier]
    x0, y0 = terrain[:, 0].min(), terrain[:, 1].min()
    ix = np.floor((terrain[:, 0] - x0) / SPACING).astype(np.int64)
    iy = np.floor((terrain[:, 1] - y0) / SPACING).astype(np.int64)
    cells = np.unique(np.stack([ix, iy], axis=1), axis=0)
    x = x0 + (cells[:, 0] + 0.5) * SPACING
    y = y0 + (cells[:, 1] + 0.5) * SPACING
    truth = cloud.terrain_height(x, y)
    step = 0.01
    gx = (cloud.terrain_height(x + step, y) - cloud.terrain_height(x - step, y)) / (2 * step)
    gy = (cloud.terrain_height(x, y + step) - cloud.terrain_height(x, y - step)) / (2 * step)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    world = cloud.to_world(np.stack([x, y, np.nan_to_num(truth)], axis=1))
    xa, xb, ya, yb = cloud.scene.region
    inside = ((world[:, 0] >= xa + 1) & (world[:, 0] <= xb - 1) & (world[:, 1] >= ya + 1)
              & (world[:, 1] <= yb - 1))
    error = np.asarray(surface(x, y), dtype=np.float64) - truth
    keep = inside & np.isfinite(error) & np.isfinite(slope)
    return error[keep], slope[keep]


def band_row(error: np.ndarray, slope: np.ndarray) -> str:
    cells = []
    for low, high in BANDS:
        e = error[(slope >= low) & (slope < high)]
        if e.size < 20:
            cells.append("- | - | 0")
            continue
        cells.append(f"{np.median(e):+.3f} | {np.sqrt(np.mean(e * e)):.3f} | {e.size}")
    return " | ".join(cells)


def header(first: str) -> None:
    names = ("0-10°", "10-20°", "20-30°", "> 30°")
    print(f"| {first} | RMSE (m) | " + " | ".join(
        f"{n} bias (m) | {n} RMSE (m) | {n} nodes" for n in names) + " |")
    print("|---|---|" + "---|---|---|" * len(names))


def fit(positions: np.ndarray, range_noise=None):
    return _acc.fit_terrain(positions, range_noise=range_noise)


def synthetic_scenes() -> dict:
    from o3d_terrain.synthetic import Plane, Scene, default_obstacles, make_scene

    scenes = {name: make_scene(name, seed=0) for name in _acc.SCENES}
    scenes = {k: (s if s.obstacles else s.with_obstacles(default_obstacles(0)))
              for k, s in scenes.items()}
    scenes.update(_acc.steep_scenes())
    for deg in (25, 35):
        scenes[f"plane{deg}"] = Scene(f"plane{deg}", (Plane(math.tan(math.radians(deg))),),
                                      default_obstacles(0))
    return scenes


def run_synthetic(sensors) -> None:
    from o3d_terrain.synthetic import sample_lidar, sample_stereo

    for sensor in sensors:
        print(f"\n{sensor}\n")
        header("scene")
        pooled_e, pooled_s = [], []
        for name, scene in synthetic_scenes().items():
            range_noise = None
            if sensor == "lidar":
                cloud = sample_lidar(scene, seed=0)
            elif sensor == "tilt":
                cloud = sample_lidar(scene, tilt_deg=(5.0, 3.0), seed=0)
            else:
                cloud = sample_stereo(scene, seed=0)
                range_noise = RangeNoise.from_stereo(**_acc.STEREO_RIG)
            positions = np.asarray(cloud.positions, dtype=np.float64)
            usable = ~cloud.is_outlier & np.isfinite(positions).all(axis=1)
            surface = fit(positions[usable], range_noise)
            error, slope = node_errors(surface, cloud)
            pooled_e.append(error)
            pooled_s.append(slope)
            print(f"| {name} | {np.sqrt(np.mean(error ** 2)):.3f} | {band_row(error, slope)} |",
                  flush=True)
        e, s = np.concatenate(pooled_e), np.concatenate(pooled_s)
        print(f"| **all** | {np.sqrt(np.mean(e ** 2)):.3f} | {band_row(e, s)} |", flush=True)


def run_dem(path: Path, windows: int = 9) -> None:
    from o3d_terrain.evaluation.terrain import read_dem, sample_dem_cloud
    from o3d_terrain.synthetic import Scene, sample_lidar

    dem = read_dem(path)
    n_rows, n_cols = dem.shape
    size = 60
    origins = [(r, c) for r in range(0, n_rows - size + 1, size)
               for c in range(0, n_cols - size + 1, size)]
    pick = np.linspace(0, len(origins) - 1, windows).round().astype(int)
    origins = [origins[i] for i in pick]
    for kind in ("uniform 4/m²", "lidar", "tilted lidar"):
        print(f"\nDEM {path.name}, {len(origins)} windows of {size} m, {kind}\n")
        header("window")
        rng = np.random.default_rng(0)
        pooled_e, pooled_s = [], []
        for r0, c0 in origins:
            rows, cols = slice(r0, r0 + size), slice(c0, c0 + size)
            feature = DemTerrain.window(dem, rows, cols)
            scene = Scene(f"dem {r0},{c0}", (feature,), (), region=(0.0, size - 1.0, 0.0,
                                                                    size - 1.0),
                          sensor_xy=(size / 2, size / 2))
            if kind.startswith("uniform"):
                positions, _ = sample_dem_cloud(dem, 1.0, rows, cols, density=4.0, noise=0.02,
                                                rng=rng)
                positions[:, 0] -= c0
                positions[:, 1] -= r0
                positions[:, 2] -= np.nanmean(dem[rows, cols])
                from o3d_terrain.synthetic.sensors import SyntheticCloud

                cloud = SyntheticCloud(positions, positions, np.full(len(positions), -1),
                                       np.eye(4), scene, "uniform")
                # sample_dem_cloud interpolates bilinearly: score against its bilinear truth
                block = dem[rows, cols] - np.nanmean(dem[rows, cols])
                cloud = _Bilinear(cloud, _bilinear_height(block))
            else:
                tilt = (5.0, 3.0) if kind.startswith("tilted") else (0.0, 0.0)
                cloud = sample_lidar(scene, tilt_deg=tilt, seed=0, max_range=40.0)
                positions = np.asarray(cloud.positions, dtype=np.float64)
            surface = fit(positions)
            error, slope = node_errors(surface, cloud)
            pooled_e.append(error)
            pooled_s.append(slope)
            print(f"| {r0},{c0} | {np.sqrt(np.mean(error ** 2)):.3f} | "
                  f"{band_row(error, slope)} |", flush=True)
        e, s = np.concatenate(pooled_e), np.concatenate(pooled_s)
        print(f"| **all** | {np.sqrt(np.mean(e ** 2)):.3f} | {band_row(e, s)} |", flush=True)


def _bilinear_height(block: np.ndarray):
    """(x, y) -> the bilinear height of a raster block (x = column, y = row)."""
    from scipy.ndimage import map_coordinates

    def height(x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        return map_coordinates(block, [y.ravel(), x.ravel()], order=1,
                               mode="nearest").reshape(x.shape)

    return height


class _Bilinear:
    """A SyntheticCloud whose terrain is the bilinear DEM (what sample_dem_cloud samples)."""

    def __init__(self, cloud, height):
        self._cloud = cloud
        self.terrain_height = height

    def __getattr__(self, name):
        return getattr(self._cloud, name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="synthetic,dem")
    parser.add_argument("--sensors", default="lidar,tilt,stereo")
    parser.add_argument("--option", action="append", default=[],
                        help="KEY=VALUE option of fit_grid_detailed")
    args = parser.parse_args()
    for item in args.option:
        key, _, value = item.partition("=")
        try:
            _acc.FIT_OPTIONS[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            _acc.FIT_OPTIONS[key] = value
    parts = set(args.only.split(","))
    if "synthetic" in parts:
        run_synthetic(args.sensors.split(","))
    if "dem" in parts:
        run_dem(_acc.data_root() / "dem_1m" / "dem.tif")


if __name__ == "__main__":
    main()
