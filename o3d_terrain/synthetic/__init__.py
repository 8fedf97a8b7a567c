"""Synthetic off-road scenes with exact truth, and lidar/stereo sensors that sample them.

>>> from o3d_terrain.synthetic import make_scene, sample_lidar
>>> scene = make_scene("offroad", seed=0)
>>> cloud = sample_lidar(scene, tilt_deg=(5.0, 3.0))
>>> pcd = cloud.to_pointcloud()          # positions in the sensor frame + ground_truth

See docs/synthetic.md for the scenes, the sensor and noise models and evaluation.
"""

from .ceiling import sample_under_ceiling
from .forest import ForestTile, sample_forest_airborne
from .render import StereoPair, render_stereo_pair, texture, value_noise
from .scene import (
    OBSTACLE_SHAPES,
    SCENES,
    Obstacle,
    Scene,
    default_obstacles,
    make_scene,
    section6_scene,
)
from .sensors import (
    OBSTACLE,
    OUTLIER,
    SENSOR_FROM_OPTICAL,
    TERRAIN,
    Camera,
    SyntheticCloud,
    TerrainError,
    cast,
    rotation_matrix,
    sample_airborne,
    sample_lidar,
    sample_sequence,
    sample_solid_state,
    sample_stereo,
    sensor_pose,
    terrain_rmse,
)
from .sequence import sequence_ground, synthetic_sequence
from .terrain import GridRelief, Hill, Plane, Ramp, Ridge, Roughness, Valley

__all__ = [
    "OBSTACLE", "OBSTACLE_SHAPES", "OUTLIER", "SCENES", "SENSOR_FROM_OPTICAL", "TERRAIN",
    "Camera", "ForestTile", "GridRelief", "Hill", "Obstacle", "Plane", "Ramp", "Ridge",
    "Roughness", "Scene", "StereoPair",
    "SyntheticCloud", "TerrainError", "Valley", "cast", "default_obstacles", "make_scene",
    "render_stereo_pair", "rotation_matrix", "sample_airborne", "sample_forest_airborne",
    "sample_lidar", "sample_sequence",
    "sample_solid_state", "sample_stereo",
    "section6_scene", "sensor_pose", "terrain_rmse", "texture", "value_noise",
]

__all__ += ["sequence_ground", "synthetic_sequence"]  # from .sequence (tracking sequences)
__all__ += ["sample_under_ceiling"]  # from .ceiling (scans under a roof)
