"""The stages, registered by class name in :data:`STAGES`."""

from .base import STAGES, SourceStage, Stage, stage
from .grid_quantize import GridQuantize
from .read import ReadCloud
from .synthetic import SyntheticScene
from .stereo import StereoToCloud
from .obstacles import ObstacleDetector, TraversabilityCost
from .terrain import RationalBSplineTerrain, Segmenter, SlopeEstimator
from .level import LevelCloud

__all__ = ["STAGES", "Stage", "SourceStage", "stage", "GridQuantize", "ReadCloud",
           "SyntheticScene", "StereoToCloud", "ObstacleDetector", "TraversabilityCost",
           "RationalBSplineTerrain", "SlopeEstimator", "Segmenter", "LevelCloud"]
