"""Stereo: rectified image pairs to disparity, to coloured 3-D clouds.

Public functions: :func:`load_calibration`, :func:`compute_disparity`, :func:`stereo_to_cloud`.
"""

from .calibration import StereoCalibration, load_calibration
from .cloud import DisparityMap, StereoCloud, camera_to_vehicle_matrix, disparity_to_points, stereo_to_cloud
from .disparity import StereoMatching, compute_disparity, fill_disparity_holes, read_image
from .evaluation import disparity_errors, lidar_in_camera, read_pfm

__all__ = [
    "DisparityMap",
    "StereoCalibration",
    "StereoCloud",
    "StereoMatching",
    "camera_to_vehicle_matrix",
    "compute_disparity",
    "disparity_errors",
    "disparity_to_points",
    "fill_disparity_holes",
    "lidar_in_camera",
    "load_calibration",
    "read_image",
    "read_pfm",
    "stereo_to_cloud",
]
