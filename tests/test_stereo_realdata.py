"""Stereo on real pairs: Middlebury Motorcycle (dense truth) and a KITTI pair with its lidar."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from o3d_terrain.stereo import (
    camera_to_vehicle_matrix, compute_disparity, disparity_errors, lidar_in_camera,
    load_calibration, read_pfm, stereo_to_cloud,
)


@pytest.fixture
def middlebury(shared_data):
    folder = shared_data / "middlebury_motorcycle"
    if not (folder / "im0.png").exists():
        pytest.skip(f"Middlebury Motorcycle not found in {folder}")
    return folder


@pytest.fixture
def kitti(shared_data):
    folder = shared_data / "kitti_stereo_object"
    if not (folder / "left.png").exists():
        pytest.skip(f"KITTI stereo object pair not found in {folder}")
    return folder


def test_middlebury_bad_pixels(middlebury):
    """Scored over non-occluded pixels with a ground truth (mask0nocc == 255, finite GT)."""
    calib = load_calibration(middlebury / "calib.txt")
    disparity = compute_disparity(middlebury / "im0.png", middlebury / "im1.png", calib)
    truth = read_pfm(middlebury / "disp0GT.pfm")
    mask = cv2.imread(str(middlebury / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    scores = disparity_errors(disparity, truth, mask, threshold=3.0)
    assert scores["bad_over_output"] <= 0.03  # the target, over the pixels we output
    assert scores["coverage"] >= 0.90
    assert scores["median_error"] < 0.5
    # dense variant: every non-occluded pixel gets a value
    filled = compute_disparity(middlebury / "im0.png", middlebury / "im1.png", calib, fill_holes=True)
    dense = disparity_errors(filled, truth, mask)
    assert dense["coverage"] == 1.0 and dense["bad_over_all"] < 0.06


def test_kitti_calibration(kitti):
    calib = load_calibration(kitti / "calib.txt")
    assert calib.fx == pytest.approx(721.5377)
    assert calib.cx == pytest.approx(609.5593) and calib.cy == pytest.approx(172.854)
    assert calib.baseline == pytest.approx(0.5327, abs=1e-4)
    assert calib.lidar_to_camera is not None


@pytest.fixture
def kitti_clouds(kitti):
    calib = load_calibration(kitti / "calib.txt")
    cloud = stereo_to_cloud(kitti / "left.png", kitti / "right.png", calib, depth_range=(3.0, 40.0))
    lidar = np.fromfile(kitti / "lidar.bin", np.float32).reshape(-1, 4)
    left = cv2.imread(str(kitti / "left.png"))
    height, width = left.shape[:2]
    seen, u, v = lidar_in_camera(lidar[:, :3], calib.lidar_to_camera, calib.camera_matrix, width, height)
    return calib, cloud, seen, u, v


def test_kitti_stereo_depth_agrees_with_lidar(kitti_clouds):
    """Per pixel: the stereo depth where a lidar point projects, 5-30 m."""
    calib, cloud, seen, u, v = kitti_clouds
    rows = cloud.point.image_rows.numpy()[:, 0]
    cols = cloud.point.image_columns.numpy()[:, 0]
    depth_map = np.full((rows.max() + 1, 1242), np.nan)
    depth_map[rows, cols] = cloud.point.positions.numpy()[:, 2]
    r, c = np.rint(v).astype(int), np.rint(u).astype(int)
    keep = (r < depth_map.shape[0]) & (seen[:, 2] > 5) & (seen[:, 2] < 30)
    stereo = depth_map[r[keep], c[keep]]
    lidar = seen[keep, 2]
    ok = np.isfinite(stereo)
    assert ok.mean() > 0.6
    relative = np.abs(stereo[ok] - lidar[ok]) / lidar[ok]
    assert np.median(relative) < 0.03


def test_kitti_terrain_from_stereo_matches_terrain_from_lidar(kitti_clouds):
    """Both clouds in one level frame (camera axes turned to x forward, y left, z up); terrain
    fitted over 5-30 m ahead; compared on the cells measured by both."""
    api = pytest.importorskip("o3d_terrain.api")
    from o3d_terrain.grid import MEASURED, quantize_points

    calib, cloud, seen, _u, _v = kitti_clouds
    axes = camera_to_vehicle_matrix(camera_height=0.0)[:3, :3]
    stereo = cloud.point.positions.numpy() @ axes.T
    lidar = seen @ axes.T
    region = (5.0, 30.0, -10.0, 10.0)
    grids = [quantize_points(p, cell_size=0.5, region=region, fill_empty=False) for p in (stereo, lidar)]
    common = (grids[0].state == MEASURED) & (grids[1].state == MEASURED)
    assert common.sum() > 300
    x, y = np.meshgrid(grids[0].x_centers, grids[0].y_centers, indexing="ij")
    surfaces = [api.fit_terrain(p, region=region, cell_size=0.5) for p in (stereo, lidar)]
    difference = surfaces[0](x[common], y[common]) - surfaces[1](x[common], y[common])
    assert np.median(np.abs(difference)) <= 0.10
