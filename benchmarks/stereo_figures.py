"""Regenerate the figures and numbers of docs/stereo.md.

    python benchmarks/stereo_figures.py [--out docs/figures/stereo]

1. Middlebury Motorcycle (quarter size): bad-3px rates, coverage and median error over the
   non-occluded pixels with a ground truth (mask0nocc == 255 and finite disp0GT), for the
   default matcher and with ``fill_holes``; disparity images.
2. KITTI object pair: per-pixel stereo depth against the lidar points of the same instant,
   and the terrain fitted from each cloud over 5-30 m ahead, compared on the cells both measure.
3. A rendered 640 x 480 pair of the synthetic off-road scene: disparity against the exact
   disparity, and the terrain RMSE against the exact terrain next to the same scene's
   lidar-like figure.

Real data comes from ``../shared/data`` or ``$O3D_TERRAIN_DATA``; parts without data are
skipped with a message. Pictures of the synthetic pair go to ``--out`` (shipped with the docs);
pictures made from the real recordings go to ``--real-out`` (default ``out/stereo_figures``,
not part of the repository: those recordings' licences do not allow shipping derivatives).
The numbers are printed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import cv2
import numpy as np

from o3d_terrain.api import fit_terrain
from o3d_terrain.grid import MEASURED, quantize_points
from o3d_terrain.io import render_grid_image
from o3d_terrain.noise import RangeNoise
from o3d_terrain.stereo import (
    StereoCloud, camera_to_vehicle_matrix, compute_disparity, disparity_errors, lidar_in_camera,
    load_calibration, read_pfm,
)

REPO = Path(__file__).resolve().parents[1]

#: disparity noise assumed for the noise-model rows (px at the matching resolution): about
#: 1.4826 x the median disparity error of the matcher on Middlebury (0.176 px)
DISPARITY_NOISE_PX = 0.25


def data_root() -> Path | None:
    env = os.environ.get("O3D_TERRAIN_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    return root if root.is_dir() else None


def colour_disparity(disparity: np.ndarray, high: float) -> np.ndarray:
    """A BGR picture of a disparity map (turbo; invalid pixels dark grey)."""
    scaled = np.clip(np.nan_to_num(disparity) / high, 0, 1)
    image = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    image[~np.isfinite(disparity)] = (60, 60, 60)
    return image


def save(out: Path, name: str, image: np.ndarray) -> None:
    out.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out / name), image):
        raise RuntimeError(f"could not write {out / name}")
    print(f"  wrote {out / name}")


def scores_text(scores: dict) -> str:
    return (f"coverage {scores['coverage']:.1%}, bad-3px over output pixels "
            f"{scores['bad_over_output']:.2%}, over all scored pixels {scores['bad_over_all']:.2%}, "
            f"median error {scores['median_error']:.3f} px")


def middlebury(root: Path, out: Path) -> None:
    folder = root / "middlebury_motorcycle"
    print("\n1. Middlebury Motorcycle (quarter size)")
    if not (folder / "im0.png").exists():
        print("  skipped: no data")
        return
    calib = load_calibration(folder / "calib.txt")
    truth = read_pfm(folder / "disp0GT.pfm")
    mask = cv2.imread(str(folder / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    print(f"  scored pixels: non-occluded with ground truth = {int((mask & np.isfinite(truth)).sum())}")
    variants = {
        "default": {},
        "fill_holes": {"fill_holes": True},
        "match_left_border false (OpenCV default border)": {"match_left_border": False},
        "use_color": {"use_color": True},
        "block_size 5": {"block_size": 5},
    }
    for name, options in variants.items():
        disparity = compute_disparity(folder / "im0.png", folder / "im1.png", calib, **options)
        print(f"  {name}: {scores_text(disparity_errors(disparity, truth, mask))}")
        if name == "default":
            save(out, "middlebury_disparity.png", colour_disparity(disparity, 70))
            save(out, "middlebury_truth.png",
                 colour_disparity(np.where(np.isfinite(truth), truth, np.nan), 70))
            error = np.abs(disparity - truth) > 3
            picture = cv2.imread(str(folder / "im0.png"), cv2.IMREAD_GRAYSCALE)
            picture = cv2.cvtColor(picture // 2, cv2.COLOR_GRAY2BGR)
            picture[error & mask & np.isfinite(disparity)] = (0, 0, 255)
            picture[mask & ~np.isfinite(disparity) & np.isfinite(truth)] = (255, 128, 0)
            save(out, "middlebury_errors.png", picture)


def level(points: np.ndarray) -> np.ndarray:
    """Camera axes (x right, y down, z forward) turned to x forward, y left, z up."""
    axes = camera_to_vehicle_matrix(camera_height=0.0)[:3, :3]
    return np.stack([points @ axes[row] for row in range(3)], axis=1)


def kitti(root: Path, out: Path) -> None:
    folder = root / "kitti_stereo_object"
    print("\n2. KITTI object pair with its lidar")
    if not (folder / "left.png").exists():
        print("  skipped: no data")
        return
    calib = load_calibration(folder / "calib.txt")
    settings = StereoCloud(depth_range=(3.0, 40.0))
    frame = settings.make_frame(folder / "left.png", folder / "right.png", calib)
    disparity_map = frame.product("disparity")
    print(f"  disparity range {disparity_map.disparity_range} px for depth 3-40 m; {len(frame)} points; "
          f"{np.isfinite(disparity_map.values).mean():.1%} pixels valid")
    save(out, "kitti_disparity.png", colour_disparity(disparity_map.values, 100))
    height, width = disparity_map.values.shape
    lidar = np.fromfile(folder / "lidar.bin", np.float32).reshape(-1, 4)[:, :3]
    seen, u, v = lidar_in_camera(lidar, calib.lidar_to_camera, calib.camera_matrix, width, height)
    depth = disparity_map.depth
    rows, cols = np.rint(v).astype(int), np.rint(u).astype(int)
    stereo_depth = depth[np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1)]
    band = (seen[:, 2] >= 5) & (seen[:, 2] <= 30)
    ok = band & np.isfinite(stereo_depth)
    relative = np.abs(stereo_depth[ok] - seen[ok, 2]) / seen[ok, 2]
    print(f"  per pixel, lidar points 5-30 m: {ok.sum()} of {band.sum()} have a stereo depth; "
          f"median |dZ|/Z {np.median(relative):.2%}, median |dZ| "
          f"{np.median(np.abs(stereo_depth[ok] - seen[ok, 2])):.3f} m")
    stereo_points, lidar_points = level(frame.positions), level(seen)
    region = (5.0, 30.0, -10.0, 10.0)
    for cell in (0.5, 1.0):
        grids = [quantize_points(p, cell_size=cell, region=region, fill_empty=False)
                 for p in (stereo_points, lidar_points)]
        common = (grids[0].state == MEASURED) & (grids[1].state == MEASURED)
        x, y = np.meshgrid(grids[0].x_centers, grids[0].y_centers, indexing="ij")
        lidar_surface = fit_terrain(lidar_points, region=region, cell_size=cell)
        # the rig's noise model (camera at the origin of the levelled frame)
        model = RangeNoise.from_stereo(focal_px=calib.fx, baseline=calib.baseline,
                                       disparity_noise_px=DISPARITY_NOISE_PX)
        for label, noise in (("", None), (" with the noise model", model)):
            surfaces = [fit_terrain(stereo_points, region=region, cell_size=cell,
                                    range_noise=noise), lidar_surface]
            diff = surfaces[0](x[common], y[common]) - surfaces[1](x[common], y[common])
            bands = []
            for near, far in ((5, 10), (10, 20), (20, 30)):
                m = (x[common] >= near) & (x[common] < far)
                bands.append(f"{near}-{far} m {np.median(np.abs(diff[m])):.3f}")
            print(f"  terrain{label}, {cell} m cells: {int(common.sum())} common cells, median "
                  f"|dh| {np.median(np.abs(diff)):.3f} m (by range: {', '.join(bands)}), 90th "
                  f"percentile {np.percentile(np.abs(diff), 90):.3f} m, mean {diff.mean():+.3f} m")
        surfaces[0] = fit_terrain(stereo_points, region=region, cell_size=cell)
        if cell == 0.5:
            values = np.where(common, surfaces[0](x, y) - surfaces[1](x, y), np.nan)
            save(out, "kitti_terrain_difference.png",
                 render_grid_image(np.nan_to_num(values), valid=common, value_range=(-0.3, 0.3),
                                   title="stereo - lidar terrain", unit="m"))


def synthetic(out: Path) -> None:
    from o3d_terrain.synthetic import (SENSOR_FROM_OPTICAL, SyntheticCloud, make_scene,
                                       render_stereo_pair, sample_lidar, terrain_rmse)

    print("\n3. Rendered pair of the synthetic off-road scene (640 x 480, camera 1.6 m, pitch 5°)")
    scene = make_scene("offroad", seed=0)
    pair = render_stereo_pair(scene, width=640, height=480, camera_height=1.6, tilt_deg=(0.0, 5.0))
    save(out, "synthetic_left.png", pair.left)
    truth = np.where(np.isfinite(pair.depth), pair.disparity, np.nan)
    region = (4.0, 30.0, -12.0, 12.0)  # sensor frame
    for downscale in (1, 2):
        settings = StereoCloud(depth_range=(3.0, 40.0), downscale=downscale)
        frame = settings.make_frame(pair.left, pair.right, pair.calibration)
        disparity = frame.product("disparity").values
        full = cv2.resize(disparity, (640, 480), interpolation=cv2.INTER_NEAREST) * downscale
        scores = disparity_errors(full, truth, threshold=1.0)
        print(f"  downscale {downscale}: coverage {scores['coverage']:.1%}, bad-1px over output "
              f"{scores['bad_over_output']:.2%}, median error {scores['median_error']:.3f} px")
        if downscale == 1:
            save(out, "synthetic_disparity.png", colour_disparity(disparity, 60))
        sensor = np.stack([frame.positions @ SENSOR_FROM_OPTICAL[row] for row in range(3)], axis=1)
        rows = frame.attribute("image_rows") * downscale
        cols = frame.attribute("image_columns") * downscale
        ids = pair.obstacle_ids[rows, cols].astype(np.int64)
        cloud = SyntheticCloud(sensor, sensor.copy(), ids, pair.world_from_left, scene, "stereo")
        model = RangeNoise.from_stereo(focal_px=pair.calibration["fx"] / downscale,
                                       baseline=pair.calibration["baseline"],
                                       disparity_noise_px=DISPARITY_NOISE_PX)
        for label, noise in (("", None), (" with the noise model", model)):
            error = terrain_rmse(fit_terrain(sensor, region=region, range_noise=noise), cloud,
                                 region=region)
            print(f"  downscale {downscale}{label}: terrain RMSE {error.rmse:.3f} m, mean |e| "
                  f"{error.mean_abs:.3f} m, bias {error.bias:+.3f} m over {error.samples} covered "
                  f"nodes ({len(frame)} points)")
    exact = pair.true_cloud(max_range=40.0)
    error = terrain_rmse(fit_terrain(exact.positions, region=region), exact, region=region)
    print(f"  exact stereo points (no matching error): terrain RMSE {error.rmse:.3f} m over "
          f"{error.samples} nodes")
    lidar = sample_lidar(scene, sensor_height=1.6, tilt_deg=(0.0, 5.0))
    error = terrain_rmse(fit_terrain(lidar.positions, region=region), lidar, region=region)
    print(f"  lidar-like (32 beams, same pose): terrain RMSE {error.rmse:.3f} m, bias "
          f"{error.bias:+.3f} m over {error.samples} nodes ({len(lidar)} points)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "figures" / "stereo")
    parser.add_argument("--real-out", type=Path, default=REPO / "out" / "stereo_figures")
    args = parser.parse_args()
    root = data_root()
    if root is None:
        print("real data not found (../shared/data or $O3D_TERRAIN_DATA): parts 1 and 2 skipped")
    else:
        middlebury(root, args.real_out)
        kitti(root, args.real_out)
    synthetic(args.out)


if __name__ == "__main__":
    main()
