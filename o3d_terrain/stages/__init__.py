"""The stages, registered by class name in :data:`STAGES`."""

from .base import STAGES, SourceStage, Stage, stage
from .grid_quantize import GridQuantize

__all__ = ["STAGES", "Stage", "SourceStage", "stage", "GridQuantize"]
