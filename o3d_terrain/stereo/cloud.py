"""From a disparity map to a coloured 3-D cloud, in the camera or a vehicle frame.

Camera frame: the rectified left camera, x right, y down, z forward (metres). Vehicle frame:
x forward, y left, z up, origin on the ground below the left camera; the camera sits at
``camera_height`` and is turned by ``pitch_deg`` (positive = looking down) and ``roll_deg``
(positive = turned clockwise as seen from behind, i.e. about +x, left side up).
The terrain fit itself makes no pose assumption; the vehicle frame only makes maps read naturally.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d

from .._files import output_path
from ..errors import InputError
from ..frame import Frame, cloud_from_numpy, transform_points
from ..noise import RangeNoise
from ..options import Range, component, option
from .calibration import StereoCalibration
from .disparity import SETTINGS, StereoMatch, StereoMatching

__all__ = ["StereoCloud", "DisparityMap", "stereo_to_cloud", "disparity_to_points",
           "camera_to_vehicle_matrix"]

#: camera axes (x right, y down, z forward) expressed in vehicle axes (x forward, y left, z up)
CAMERA_TO_VEHICLE_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class DisparityMap:
    """The ``disparity`` product: a matched pair at the matching resolution.

    ``values`` (H, W) float32 disparity in pixels, NaN where invalid; ``image`` the rectified
    left image (RGB or grey uint8); ``calibration`` for these images; ``camera_to_output`` the
    4 × 4 transform from the camera frame into the cloud's frame; ``disparity_range`` searched.
    """

    values: np.ndarray
    image: np.ndarray
    calibration: StereoCalibration
    camera_to_output: np.ndarray
    disparity_range: tuple[int, int]

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.values)

    @property
    def depth(self) -> np.ndarray:
        """Depth Z (m) per pixel along the optical axis, NaN where invalid."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.calibration.depth_from_disparity(self.values)
        return np.where(np.isfinite(z) & (z > 0), z, np.nan)

    def image_layers(self) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
        """Layers for image writers, in their ``[ix, iy]`` convention (x right, y up), so that
        the drawing shows the camera image upright."""
        def upright(values: np.ndarray) -> np.ndarray:
            return np.flipud(values).T

        grey = self.image if self.image.ndim == 2 else self.image.mean(axis=2)
        return {
            "disparity": (upright(self.values), upright(self.valid), "px"),
            "depth": (upright(self.depth), upright(self.valid), "m"),
            "image": (upright(grey.astype(np.float64)), np.ones(grey.T.shape, bool), ""),
        }

    def save(self, path: Any) -> None:
        """Write an ``.npz`` with the disparity, depth, image and calibration numbers."""
        c = self.calibration
        np.savez_compressed(
            output_path(path), kind="DisparityMap", disparity=self.values, depth=self.depth, image=self.image,
            fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, baseline=c.baseline, doffs=c.doffs,
            camera_to_output=self.camera_to_output, disparity_range=np.array(self.disparity_range),
        )


def disparity_to_points(disparity: np.ndarray, calibration: StereoCalibration
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Reproject the finite pixels of a disparity map: ``(points (N, 3) float64 in the camera
    frame, flat pixel indices (N,))``. Pixels with ``d + doffs <= 0`` (at or beyond infinity)
    are dropped."""
    d = np.asarray(disparity)
    if d.ndim != 2:
        raise InputError(f"a disparity map must be a 2-D array, got shape {d.shape}")
    flat = d.ravel()
    index = np.flatnonzero(np.isfinite(flat) & (flat + calibration.doffs > 0))
    h, w = d.shape
    v, u = np.divmod(index, w)
    z = calibration.fx * calibration.baseline / (flat[index].astype(np.float64) + calibration.doffs)
    points = np.empty((index.size, 3))
    points[:, 0] = (u - calibration.cx) * z / calibration.fx
    points[:, 1] = (v - calibration.cy) * z / calibration.fy
    points[:, 2] = z
    return points, index


def camera_to_vehicle_matrix(*, camera_height: float, pitch_deg: float = 0.0,
                             roll_deg: float = 0.0) -> np.ndarray:
    """4 × 4 transform from the camera frame into the vehicle frame (module docstring)."""
    pitch, roll = math.radians(pitch_deg), math.radians(roll_deg)
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    about_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    transform = np.eye(4)
    transform[:3, :3] = about_y @ about_x @ CAMERA_TO_VEHICLE_AXES
    transform[2, 3] = camera_height
    return transform



@component(SETTINGS)
class StereoCloud(StereoMatching):
    """Matching options plus how the cloud is made: output frame, pose, colours."""

    frame: str = option(
        "camera", choices=("camera", "vehicle"),
        help="camera: rectified left camera (x right, y down, z forward); vehicle: x forward, "
             "y left, z up with the origin on the ground below the camera (needs camera_height)")
    camera_height: float = option(
        None, kind=float, rule=Range(0, None), nullable=True, unit="m",
        help="height of the left camera above the ground (vehicle frame)")
    pitch_deg: float = option(
        0.0, rule=Range(-90, 90), unit="deg",
        help="camera pitch in the vehicle frame, positive = looking down")
    roll_deg: float = option(
        0.0, rule=Range(-90, 90), unit="deg",
        help="camera roll in the vehicle frame, positive = left side up (about the forward axis)")
    keep_colors: bool = option(True, help="store the left image's pixel colours as 'colors'")
    disparity_noise_px: float = option(
        None, kind=float, rule=Range(0, None, low_open=True), nullable=True, unit="px",
        help="disparity noise (standard deviation, px at the matching resolution): the frame "
             "gets the product 'range_noise' (o3d_terrain.noise.RangeNoise: noise along the "
             "ray = range^2 * this / (focal * baseline), from the camera's position), which "
             "RationalBSplineTerrain uses; null = no noise model")

    def check_options(self) -> list[str]:
        problems = []
        if self.frame == "vehicle" and self.camera_height is None:
            problems.append("frame 'vehicle' needs 'camera_height' (the camera's height above "
                            "the ground, m); give it, or use frame: camera")
        if self.frame == "camera" and (self.camera_height is not None or self.pitch_deg
                                       or self.roll_deg):
            problems.append("camera_height, pitch_deg and roll_deg apply to frame 'vehicle' only; "
                            "set frame: vehicle, or remove them")
        return problems

    def camera_to_output(self) -> np.ndarray:
        """4 × 4 transform from the camera frame to the output frame."""
        if self.frame == "camera":
            return np.eye(4)
        return camera_to_vehicle_matrix(camera_height=float(self.camera_height),
                                        pitch_deg=self.pitch_deg, roll_deg=self.roll_deg)

    def make_frame(self, left: Any, right: Any, calibration: Any) -> Frame:
        """Match, reproject, drop invalid and out-of-range points, and build the frame.

        Attributes: ``colors`` (N, 3) float32 in [0, 1] (``keep_colors``), ``disparities``
        (N, 1) float32 px at the matching resolution, ``image_rows``/``image_columns`` (N, 1)
        int32 pixel of each point. Products: ``disparity`` (the map, NaN invalid),
        ``left_image``, ``stereo_calibration`` (both at the matching resolution) and
        ``camera_to_output`` (4 × 4).
        """
        match = self.match(left, right, calibration)
        return self.frame_from_match(match)

    def frame_from_match(self, match: StereoMatch) -> Frame:
        calib = match.calibration
        points, index = disparity_to_points(match.disparity, calib)
        matched = int(index.size)
        if self.depth_range is not None:
            near, far = self.depth_range
            keep = (points[:, 2] >= near) & (points[:, 2] <= far)
            points, index = points[keep], index[keep]
        transform = self.camera_to_output()
        if self.frame != "camera":
            points = transform_points(points, transform)
        h, w = match.disparity.shape
        rows, columns = np.divmod(index, w)
        attributes: dict[str, np.ndarray] = {
            "disparities": match.disparity.ravel()[index].astype(np.float32),
            "image_rows": rows.astype(np.int32),
            "image_columns": columns.astype(np.int32),
        }
        if self.keep_colors:
            image = match.left
            pixels = image.reshape(-1, 3)[index] if image.ndim == 3 else \
                np.repeat(image.ravel()[index][:, None], 3, axis=1)
            attributes["colors"] = pixels.astype(np.float32) * np.float32(1.0 / 255.0)
        cloud = cloud_from_numpy(points, **attributes)
        frame = Frame(cloud).with_products(disparity=DisparityMap(
            match.disparity, match.left, calib, transform, match.disparity_range))
        if self.disparity_noise_px is not None:
            frame = frame.with_products(range_noise=RangeNoise.from_stereo(
                focal_px=float(calib.fx), baseline=float(calib.baseline),
                disparity_noise_px=self.disparity_noise_px,
                sensor_origin=tuple(float(v) for v in transform[:3, 3])))
        valid_share = matched / float(h * w)
        frame = frame.with_note(
            f"stereo: {w} × {h} px matched over disparities {match.disparity_range[0]}.."
            f"{match.disparity_range[1]} px; {valid_share:.1%} of pixels valid; {len(frame)} points"
            + (f" ({matched - len(frame)} outside depth_range)" if matched != len(frame) else "")
        )
        if len(frame) == 0:
            raise InputError(
                "no valid disparity in the pair: nothing to reproject (textureless or "
                "over-exposed images, a disparity/depth range that misses the scene, or images "
                "that do not overlap)")
        return frame


def stereo_to_cloud(left: Any, right: Any, calibration: Any, *, frame: str = "camera",
                    **options: Any) -> o3d.t.geometry.PointCloud:
    """A rectified stereo pair to an ``o3d.t.geometry.PointCloud`` (float64 positions).

    ``left``/``right``: image paths or arrays (RGB or grey); ``calibration``: a path or a
    :class:`~o3d_terrain.stereo.StereoCalibration`. ``frame="vehicle"`` needs ``camera_height``
    (and takes ``pitch_deg``, ``roll_deg``). Other options are those of :class:`StereoMatching`
    (``mode``, ``block_size``, ``depth_range``, ``downscale``, ...). Points get ``colors``
    (N, 3) in [0, 1], ``disparities`` and ``image_rows``/``image_columns``.
    """
    settings = StereoCloud(frame=frame, **options)
    return settings.make_frame(left, right, calibration).cloud
