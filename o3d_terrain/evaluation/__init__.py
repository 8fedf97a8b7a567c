"""Evaluation: labelled datasets, metrics, segmentation and terrain evaluation, peer adapters.

>>> from o3d_terrain.evaluation import open_dataset, evaluate_segmentation
>>> report = evaluate_segmentation(open_dataset("../shared/data/kitti_seq00_lidar"))
>>> print(report.to_markdown())

See docs/evaluation.md; ``o3d-terrain eval segmentation|terrain`` wraps these functions.
"""

from .datasets import (
    FrameFailure,
    LabelledFrame,
    las_frames,
    open_dataset,
    read_las_frame,
    semantic_kitti_frames,
    synthetic_frames,
)
from .metrics import SegmentationCounts, height_rmse, segmentation_counts, slope_error_deg
from .peers import PEERS, make_peer, peer_status
from .segmentation import SegmentationReport, evaluate_segmentation, method_names, resolve_method
from .terrain import (
    Raster,
    TerrainReport,
    TruthOverlapError,
    evaluate_dem_terrain,
    evaluate_synthetic_terrain,
    evaluate_terrain_against_raster,
    read_pose,
    read_raster,
    write_error_map,
)

__all__ = [
    "FrameFailure", "LabelledFrame", "PEERS", "Raster", "SegmentationCounts",
    "SegmentationReport", "TerrainReport", "TruthOverlapError", "evaluate_dem_terrain",
    "evaluate_segmentation", "evaluate_synthetic_terrain", "evaluate_terrain_against_raster",
    "read_pose", "read_raster",
    "height_rmse", "las_frames", "make_peer", "method_names", "open_dataset", "peer_status",
    "read_las_frame", "resolve_method", "segmentation_counts", "semantic_kitti_frames",
    "slope_error_deg", "synthetic_frames", "write_error_map",
]
