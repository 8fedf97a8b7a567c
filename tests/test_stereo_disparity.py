"""Disparity, reprojection and clouds on rendered pairs with exact disparity."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from o3d_terrain.errors import ConfigError, InputError
from o3d_terrain.stereo import (
    StereoCalibration, StereoMatching, camera_to_vehicle_matrix, compute_disparity,
    disparity_errors, disparity_to_points, fill_disparity_holes, stereo_to_cloud,
)

W, H = 320, 240
F, BASELINE, CAMERA_HEIGHT = 300.0, 0.3, 1.5
CALIB = StereoCalibration(fx=F, fy=F, cx=W / 2 - 0.5, cy=H / 2 - 0.5, baseline=BASELINE,
                          width=W, height=H)


def texture(width, height, seed=0, colour=True):
    """Band-limited random texture (interpolates cleanly, has corners for features)."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (height, width, 3 if colour else 1)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.2)
    if smooth.ndim == 2:
        smooth = smooth[:, :, None]
    lo, hi = smooth.min(), smooth.max()
    return ((smooth - lo) / (hi - lo) * 255).astype(np.uint8).squeeze()


def warp_pair(disparity):
    """A left texture and the right view of the same surface: right(u, v) = left(u + d(u, v), v)
    (exact for a surface whose disparity varies slowly; no occlusions)."""
    left = texture(W + 200, H)[:, 100:100 + W].copy()
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    wide = texture(W + 200, H)
    right = cv2.remap(wide, u + 100 + disparity.astype(np.float32), v, cv2.INTER_CUBIC)
    return left, right


def ground_disparity():
    """Disparity of a flat ground seen by a level camera CAMERA_HEIGHT above it (rows below the
    horizon), and a far wall above the horizon so that every row is textured."""
    v = np.arange(H, dtype=np.float64)[:, None] - CALIB.cy
    d = np.where(v > 2, BASELINE * v / CAMERA_HEIGHT, BASELINE * 2 / CAMERA_HEIGHT)
    return np.repeat(d, W, axis=1)


def test_constant_disparity_is_recovered_with_subpixel_accuracy():
    truth = np.full((H, W), 12.25)
    left, right = warp_pair(truth)
    d = compute_disparity(left, right, CALIB, disparity_range=(0, 32))
    assert d.shape == (H, W) and d.dtype == np.float32
    scores = disparity_errors(d, truth)
    assert scores["coverage"] > 0.9
    assert scores["median_error"] < 0.25  # sub-pixel
    assert scores["bad_over_output"] < 0.01


def test_invalid_pixels_are_nan_and_inputs_unchanged():
    truth = np.full((H, W), 10.0)
    left, right = warp_pair(truth)
    left[:, 150:200] = texture(50, H, seed=7)  # seen by the left camera only: no true match
    before = left.copy(), right.copy()
    d = compute_disparity(left, right, CALIB, disparity_range=(0, 32), match_left_border=False)
    assert np.isnan(d[:, :32]).all()  # the search runs off the right image: no disparity
    assert np.isnan(d[:, 155:195]).mean() > 0.5
    assert np.nanmedian(np.abs(d[:, 40:140] - 10.0)) < 0.25
    np.testing.assert_array_equal(left, before[0])
    np.testing.assert_array_equal(right, before[1])


def test_downscale_returns_full_size_pixels():
    truth = np.full((H, W), 14.0)
    left, right = warp_pair(truth)
    d = compute_disparity(left, right, CALIB, disparity_range=(0, 32), downscale=2)
    assert d.shape == (H, W)
    assert np.nanmedian(np.abs(d - truth)) < 0.5


def test_depth_range_sets_the_disparity_range():
    matcher = StereoMatching(depth_range=(2.0, 50.0))
    low, high = matcher.resolve_disparity_range(CALIB)
    assert high == int(np.ceil(F * BASELINE / 2.0))
    assert low == int(np.floor(F * BASELINE / 50.0))


def test_reprojection_matches_opencv():
    rng = np.random.default_rng(1)
    d = rng.uniform(5, 40, (H, W)).astype(np.float32)
    d[rng.random((H, W)) < 0.2] = np.nan
    calib = StereoCalibration(fx=F, fy=F, cx=150.2, cy=110.7, baseline=BASELINE, doffs=3.5)
    points, index = disparity_to_points(d, calib)
    opencv = cv2.reprojectImageTo3D(np.nan_to_num(d), calib.Q).reshape(-1, 3)[index]
    np.testing.assert_allclose(points, opencv, rtol=1e-5)
    assert index.size == np.isfinite(d).sum()


def test_ground_pair_gives_flat_ground_in_both_frames():
    truth = ground_disparity()
    left, right = warp_pair(truth)
    common = dict(disparity_range=(0, 48), depth_range=(2.0, 20.0))
    camera = stereo_to_cloud(left, right, CALIB, **common)
    xyz = camera.point.positions.numpy()
    assert xyz.dtype == np.float64
    # camera frame: y down, the ground is CAMERA_HEIGHT below the camera
    ground = xyz[:, 1] > 0.5
    assert np.median(np.abs(xyz[ground, 1] - CAMERA_HEIGHT)) < 0.05
    vehicle = stereo_to_cloud(left, right, CALIB, frame="vehicle", camera_height=CAMERA_HEIGHT, **common)
    v = vehicle.point.positions.numpy()
    ground = v[:, 2] < 0.5
    assert np.median(np.abs(v[ground, 2])) < 0.05  # z up, ground at 0
    assert np.all(v[:, 0] > 1.9)  # x forward, within the depth range
    # colours are the left image's pixels
    colours = vehicle.point.colors.numpy()
    rows = vehicle.point.image_rows.numpy()[:, 0]
    cols = vehicle.point.image_columns.numpy()[:, 0]
    np.testing.assert_allclose(colours, left[rows, cols] / 255.0, atol=1e-6)
    assert colours.shape[1] == 3 and colours.min() >= 0 and colours.max() <= 1


def test_vehicle_transform_axes():
    level = camera_to_vehicle_matrix(camera_height=2.0)
    np.testing.assert_allclose(level[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # optical axis forward
    np.testing.assert_allclose(level[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # image right = -y
    np.testing.assert_allclose(level[:3, :3] @ [0, 1, 0], [0, 0, -1], atol=1e-12)  # image down = -z
    pitched = camera_to_vehicle_matrix(camera_height=2.0, pitch_deg=10)
    np.testing.assert_allclose(pitched[:3, :3] @ [0, 0, 1],
                               [np.cos(np.radians(10)), 0, -np.sin(np.radians(10))], atol=1e-12)
    rolled = camera_to_vehicle_matrix(camera_height=2.0, roll_deg=5)
    right_axis = rolled[:3, :3] @ [1, 0, 0]
    assert right_axis[2] < 0  # positive roll: the right side goes down, left side up
    # a pitched camera sees a flat ground at z = 0: a ray hitting the ground checks the chain
    ray = np.linalg.inv(pitched[:3, :3]) @ np.array([np.cos(0.3), 0.0, -np.sin(0.3)])
    hit = pitched[:3, :3] @ (ray * (2.0 / np.sin(0.3))) + pitched[:3, 3]
    assert hit[2] == pytest.approx(0.0, abs=1e-12)


def test_unrectified_pair_is_rejected():
    left, right = warp_pair(np.full((H, W), 10.0))
    shifted = np.roll(right, 6, axis=0)
    with pytest.raises(InputError, match="rectified"):
        compute_disparity(left, shifted, CALIB, disparity_range=(0, 32))
    # the check can be switched off
    compute_disparity(left, shifted, CALIB, disparity_range=(0, 32), max_vertical_disparity=None)


def test_swapped_pair_is_rejected():
    left, right = warp_pair(np.full((H, W), 10.0))
    with pytest.raises(InputError, match="swapped"):
        compute_disparity(right, left, CALIB, disparity_range=(0, 32))


def test_images_of_different_sizes():
    left, right = warp_pair(np.full((H, W), 10.0))
    with pytest.raises(InputError, match="same size"):
        compute_disparity(left, right[:, :-4], CALIB)


def test_calibration_for_another_image_size():
    left, right = warp_pair(np.full((H, W), 10.0))
    other = StereoCalibration(fx=F, fy=F, cx=319.5, cy=239.5, baseline=BASELINE, width=640, height=480)
    with pytest.raises(InputError, match="640 × 480"):
        compute_disparity(left, right, other)


def test_textureless_pair_gives_a_clear_error():
    flat = np.full((H, W), 90, np.uint8)
    with pytest.raises(InputError, match="no valid disparity"):
        stereo_to_cloud(flat, flat, CALIB)


@pytest.mark.parametrize("options, text", [
    ({"block_size": 4}, "must be odd"),
    ({"mod": "sgbm"}, "did you mean 'mode'"),
    ({"mode": "sgbm3"}, "mode"),
    ({"depth_range": (10.0, 2.0)}, "max > min"),
    ({"downscale": 0}, "downscale"),
])
def test_bad_options_are_named(options, text):
    left, right = warp_pair(np.full((H, W), 10.0))
    with pytest.raises(ConfigError, match=text):
        compute_disparity(left, right, CALIB, **options)


def test_vehicle_frame_needs_camera_height():
    with pytest.raises(ConfigError, match="camera_height"):
        stereo_to_cloud(np.zeros((H, W)), np.zeros((H, W)), CALIB, frame="vehicle")


def test_bad_images():
    with pytest.raises(InputError, match="float image"):
        compute_disparity(np.full((H, W), 2.0), np.full((H, W), 2.0), CALIB)
    with pytest.raises(InputError, match="no such left image"):
        compute_disparity("/nonexistent/left.png", "/nonexistent/right.png", CALIB)
    with pytest.raises(InputError, match="shape"):
        compute_disparity(np.zeros((H, W, 5), np.uint8), np.zeros((H, W, 5), np.uint8), CALIB)


def test_fill_holes_takes_the_farther_neighbour():
    d = np.array([[5.0, np.nan, np.nan, 9.0, np.nan], [np.nan, np.nan, 3.0, np.nan, 7.0]], np.float32)
    filled = fill_disparity_holes(d)
    np.testing.assert_array_equal(filled, [[5, 5, 5, 9, 9], [3, 3, 3, 3, 7]])
    assert np.isnan(fill_disparity_holes(np.full((2, 3), np.nan, np.float32))).all()


def test_disparity_errors_definitions():
    truth = np.array([[10.0, 10.0, 10.0, np.inf]])
    estimate = np.array([[10.5, 20.0, np.nan, 10.0]])
    scores = disparity_errors(estimate, truth)
    assert scores["scored_pixels"] == 3
    assert scores["coverage"] == pytest.approx(2 / 3)
    assert scores["bad_over_output"] == pytest.approx(1 / 2)
    assert scores["bad_over_all"] == pytest.approx(2 / 3)
