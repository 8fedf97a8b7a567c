"""o3d_terrain: rational B-spline terrain models for Open3D point clouds.

Drop-in use in Open3D code::

    import o3d_terrain
    surface, inliers = o3d_terrain.segment_terrain(pcd)   # like pcd.segment_plane(...)
    ground = pcd.select_by_index(inliers)
    slope = surface.slope_deg(x, y)

    obstacles = o3d_terrain.detect_obstacles(pcd, surface=surface)   # .indices, boxes, heights
    costmap = o3d_terrain.traversability_cost(surface, pcd, vehicle="offroad_suv")

Stages compose into pipelines (``o3d-terrain run pipelines/lidar_terrain.yaml``) or run as
plain calls: ``frame = GridQuantize(cell_size=0.5)(pcd)``.
"""

__version__ = "0.1.0"

from .errors import (ConfigError, InputError, NotACloudError, O3DTerrainError, StageError,
                     TerrainWarning)
from .frame import Frame, as_frame
from .grid import HeightGrid, quantize_points
from .io import read_cloud, write_cloud
from .stages import STAGES, GridQuantize, ReadCloud
from .pipeline import Pipeline, load_pipeline, parse_pipeline
from .writers import WRITERS
from .spline import TerrainSurface, make_lsq_surface
from .terrain import fit_grid, fit_grid_detailed
from .segment import TerrainLabel
from .noise import RangeNoise
from .api import fit_terrain, segment_terrain
from .locate import locate_sensor
from .level import level_cloud
from .obstacles import DetectedObstacle, ObstacleSet, detect_obstacles
from .traversability import CostMap, VehicleProfile, load_vehicle_profile, traversability_cost
from .tracking import ObstacleTracker
from ._malloc import keep_freed_memory

__all__ = [
    "__version__",
    "ConfigError", "InputError", "NotACloudError", "O3DTerrainError", "StageError",
    "TerrainWarning",
    "Frame", "as_frame", "HeightGrid", "quantize_points",
    "read_cloud", "write_cloud",
    "STAGES", "GridQuantize", "ReadCloud",
    "Pipeline", "load_pipeline", "parse_pipeline", "WRITERS",
    "TerrainSurface", "make_lsq_surface", "fit_grid", "fit_grid_detailed",
    "TerrainLabel", "RangeNoise", "fit_terrain", "segment_terrain", "locate_sensor",
    "level_cloud",
    "DetectedObstacle", "ObstacleSet", "detect_obstacles",
    "CostMap", "VehicleProfile", "load_vehicle_profile", "traversability_cost",
    "ObstacleTracker", "keep_freed_memory",
]
