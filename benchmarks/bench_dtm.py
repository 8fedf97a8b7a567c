"""The DTM a survey takes from a tile, against exact terrain: ours (the fitted surface written
by ``o3d_terrain.raster``) and the usual ground-points-to-raster route (a TIN of the points a
ground filter kept, as PDAL's and lidR's DTM writers make it).

The sites of ``bench_dem_sites.py`` (100 m windows of the surveyed raster ``dem_1m/dem.tif``,
made smooth terrain, with 38 trees, rocks and vehicles) seen by an airborne strip (first
returns, ``--density`` pulses per m2). Per site, every method's 1 m raster (cells aligned to
whole metres, as ``WriteRaster`` writes them) is scored at the cells' centres against the
site's exact terrain:

- ``o3d_terrain``: ``segment_terrain``, then ``terrain_raster`` of its surface (``max_gap``
  20 m, so every cell of the site has a value);
- ``TIN of o3d_terrain's ground``, ``TIN of SMRF's ground``: a linear interpolation over the
  Delaunay triangles of the points each method labels ground (``scipy``'s
  ``LinearNDInterpolator``; no value outside their hull);
- ``TIN of the true ground``: the same of the points that truly hit the terrain, the best a
  TIN of this sampling can do whatever the filter.

Scored over the cells more than 3 m inside the site where every method has a value: height
RMSE and the 99th percentile of |error| (m), over all of them and over the cells under the
trees' crowns and the objects (no ground return inside the cell), where the ground is
interpolated.

Run: .venv/bin/python benchmarks/bench_dtm.py [--sites 8] [--density 6] [--no-peers]
(docs/pipelines.md, "The terrain as a GeoTIFF raster"). Needs ``../shared/data`` (or
``$O3D_TERRAIN_DATA``); SMRF needs the ``bench`` extra.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_dem_sites import HALF, scan, site_scene, sites  # noqa: E402
from scipy.interpolate import LinearNDInterpolator  # noqa: E402

import o3d_terrain  # noqa: E402
from o3d_terrain.evaluation.datasets import data_root  # noqa: E402
from o3d_terrain.evaluation.segmentation import resolve_method  # noqa: E402
from o3d_terrain.evaluation.terrain import read_raster  # noqa: E402
from o3d_terrain.grid import quantize_points  # noqa: E402
from o3d_terrain.raster import terrain_raster  # noqa: E402

MARGIN = 3.0  # cells this close to the site's edge are not scored (m)


def tin(points: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Heights of the Delaunay TIN of ``points`` at (x, y); NaN outside their hull."""
    if len(points) < 3:
        return np.full(x.shape, np.nan)
    return LinearNDInterpolator(points[:, :2], points[:, 2])(x, y)


def site_rasters(cloud, methods: dict) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    """Each method's raster at the cells' centres, the truth there and the cells without a
    ground return (all (nx, ny), the cells of ours)."""
    p = np.asarray(cloud.positions, dtype=np.float64)
    truth_ground = ~np.asarray(cloud.is_obstacle, dtype=bool)
    surface, inliers = o3d_terrain.segment_terrain(p)
    values, x_min, y_min = terrain_raster(surface, cell_size=1.0, support=p[inliers])
    ix, iy = np.indices(values.shape)
    x, y = x_min + ix + 0.5, y_min + iy + 0.5
    rasters = {"o3d_terrain": values, "TIN of o3d_terrain's ground": tin(p[inliers], x, y)}
    for name, method in methods.items():
        rasters[f"TIN of {name}'s ground"] = tin(p[np.asarray(method(p), bool)], x, y)
    rasters["TIN of the true ground"] = tin(p[truth_ground], x, y)
    truth = cloud.terrain_height(x, y)
    # the raster's cells that hold a true ground return (the grid's cells of those points)
    region = (x_min, x_min + values.shape[0], y_min, y_min + values.shape[1])
    hit = quantize_points(p[truth_ground], cell_size=1.0, region=region).count > 0
    return rasters, truth, ~hit, np.stack([x, y])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sites", type=int, default=8)
    parser.add_argument("--density", type=float, default=6.0,
                        help="airborne pulses per m2 (a mountain survey may have under 1)")
    parser.add_argument("--no-peers", action="store_true", help="skip SMRF")
    args = parser.parse_args()
    root = data_root()
    if root is None or not (root / "dem_1m" / "dem.tif").exists():
        raise SystemExit("needs ../shared/data/dem_1m/dem.tif (or $O3D_TERRAIN_DATA)")
    heights = read_raster(root / "dem_1m" / "dem.tif").heights.astype(np.float64)
    methods = {} if args.no_peers else {"SMRF": resolve_method("smrf", kind="aerial")}
    errors: dict[str, list] = {}
    occluded: dict[str, list] = {}
    for k, (row, col) in enumerate(sites(heights, args.sites)):
        scene = site_scene(heights, row, col, seed=k)
        cloud = scan(scene, "airborne", k, args.density)
        rasters, truth, no_hit, (x, y) = site_rasters(cloud, methods)
        scene_xy = cloud.to_world(np.stack([x, y, np.zeros_like(x)], axis=-1))
        u, v = scene_xy[..., 0], scene_xy[..., 1]  # about the site's centre
        inside = (np.abs(u) < HALF - MARGIN) & (np.abs(v) < HALF - MARGIN)
        common = inside & np.isfinite(truth)
        for values in rasters.values():
            common &= np.isfinite(values)
        line = [f"site {row},{col}: {int(common.sum())} cells ({int((common & no_hit).sum())} "
                "without a ground return)"]
        for name, values in rasters.items():
            e = values[common] - truth[common]
            errors.setdefault(name, []).append(e)
            occluded.setdefault(name, []).append(values[common & no_hit] - truth[common & no_hit])
            line.append(f"{name} {np.sqrt(np.mean(e ** 2)):.3f}")
        print(" | ".join(line), flush=True)
    print(f"\n{args.sites} sites, airborne {args.density:g} pulses/m2, 1 m cells; height error "
          "against the exact terrain (m)\n")
    print("| DTM | RMSE | p99 abs. error | RMSE, cells without a ground return |")
    print("|---|---:|---:|---:|")
    for name in errors:
        e = np.concatenate(errors[name])
        o = np.concatenate(occluded[name])
        print(f"| {name} | {np.sqrt(np.mean(e ** 2)):.3f} | {np.percentile(np.abs(e), 99):.3f} "
              f"| {np.sqrt(np.mean(o ** 2)) if o.size else float('nan'):.3f} |")


if __name__ == "__main__":
    main()
