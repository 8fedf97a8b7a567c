"""Synthetic off-road scenes with exact truth, and lidar/stereo sensors that sample them.

>>> from o3d_terrain.synthetic import make_scene, sample_lidar
>>> scene = make_scene("offroad", seed=0)
>>> cloud = sample_lidar(scene, tilt_deg=(5.0, 3.0))
>>> pcd = cloud.to_pointcloud()          # positions in the sensor frame + ground_truth

See docs/synthetic.md for the scenes, the sensor and noise models and evaluation.
"""

from .scene import (OBSTACLE_SHAPES, SCENES, Obstacle, Scene, default_obstacles, make_scene,
                    section6_scene)
from .sensors import (OBSTACLE, SENSOR_FROM_OPTICAL, TERRAIN, Camera, SyntheticCloud,
                      TerrainError, cast, rotation_matrix, sample_lidar, sample_stereo,
                      sensor_pose, terrain_rmse)
from .render import StereoPair, render_stereo_pair, texture, value_noise
from .terrain import Hill, Plane, Ramp, Ridge, Roughness, Valley

__all__ = [
    "SCENES", "OBSTACLE_SHAPES", "Obstacle", "Scene", "make_scene", "section6_scene",
    "default_obstacles", "SyntheticCloud", "TerrainError", "Camera", "sample_lidar",
    "sample_stereo", "terrain_rmse", "sensor_pose", "rotation_matrix", "cast", "TERRAIN",
    "OBSTACLE", "SENSOR_FROM_OPTICAL", "StereoPair", "render_stereo_pair", "texture", "value_noise",
    "Plane", "Hill", "Ridge", "Ramp", "Valley", "Roughness",
]
