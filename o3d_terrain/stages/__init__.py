"""The stages, registered by class name in :data:`STAGES`."""

from .base import STAGES, SourceStage, Stage, stage
from .grid_quantize import GridQuantize
from .read import ReadCloud
from .synthetic import SyntheticScene
from .stereo import StereoToCloud

__all__ = ["STAGES", "Stage", "SourceStage", "stage", "GridQuantize", "ReadCloud"]
__all__ += ["SyntheticScene"]
__all__ += ["StereoToCloud"]
from .obstacles import ObstacleDetector, TraversabilityCost

__all__ += ["ObstacleDetector", "TraversabilityCost"]
from .terrain import RationalBSplineTerrain, Segmenter, SlopeEstimator

__all__ += ["RationalBSplineTerrain", "SlopeEstimator", "Segmenter"]
from .level import LevelCloud

__all__ += ["LevelCloud"]
