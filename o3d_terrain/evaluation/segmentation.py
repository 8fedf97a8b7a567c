"""Ground-segmentation evaluation: any method over any labelled dataset.

A *method* is a callable ``(positions) -> (N,) bool ground mask``. Ours is
:func:`o3d_terrain.api.segment_terrain` (inlier indices turned into a mask); the peers
(Patchwork++, CSF, SMRF, Open3D RANSAC plane) are selected by name when the ``bench`` extra is
installed. A frame on which reading or the method fails is reported and skipped.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np

from ..errors import InputError
from .datasets import FrameFailure, FrameOrFailure, LabelledFrame
from .metrics import SegmentationCounts, segmentation_counts
from .peers import PEERS, make_peer

Method = Callable[[np.ndarray], np.ndarray]
OURS = "o3d_terrain"


@dataclass(frozen=True)
class FrameResult:
    """Scores of one method on one frame."""

    frame: str
    points: int
    counts: SegmentationCounts
    seconds: float
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"frame": self.frame, "points": self.points, "seconds": self.seconds,
                **self.counts.to_dict(), "notes": list(self.notes)}


@dataclass
class SegmentationReport:
    """Per-frame results, failures and overall scores of one method over one dataset."""

    method: str
    dataset: str
    frames: list[FrameResult] = field(default_factory=list)
    failures: list[FrameFailure] = field(default_factory=list)

    @property
    def total(self) -> SegmentationCounts:
        """Counts pooled over every frame (micro average)."""
        total = SegmentationCounts()
        for result in self.frames:
            total = total + result.counts
        return total

    def mean_scores(self) -> dict[str, float]:
        """Per-frame scores averaged over frames (macro average, as Patchwork++ reports)."""
        keys = ("precision", "recall", "f1", "accuracy", "obstacle_recall")
        out = {}
        for key in keys:
            values = [r.counts.scores()[key] for r in self.frames]
            values = [v for v in values if not math.isnan(v)]
            out[key] = float(np.mean(values)) if values else float("nan")
        return out

    def median_seconds(self) -> float:
        return float(np.median([r.seconds for r in self.frames])) if self.frames else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "dataset": self.dataset,
            "frames": [r.to_dict() for r in self.frames],
            "failures": [vars(f) for f in self.failures],
            "overall": self.total.to_dict(),
            "mean_over_frames": self.mean_scores(),
            "median_seconds": self.median_seconds(),
        }

    def to_json(self) -> str:
        return json.dumps(_finite(self.to_dict()), indent=2)

    def to_markdown(self) -> str:
        """A per-frame table, an overall row, and the failures."""
        lines = [
            f"Method `{self.method}` on `{self.dataset}`",
            "",
            "| frame | points | precision | recall | F1 | obstacle recall | time (s) |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        for r in self.frames:
            s = r.counts.scores()
            lines.append(
                f"| {r.frame} | {r.points:,} | {pct(s['precision'])} | {pct(s['recall'])} | "
                f"{pct(s['f1'])} | {pct(s['obstacle_recall'])} | {r.seconds:.3f} |"
            )
        if self.frames:
            s = self.total.scores()
            lines.append(
                f"| **all (pooled)** | {self.total.scored_points:,} scored | {pct(s['precision'])} | "
                f"{pct(s['recall'])} | {pct(s['f1'])} | {pct(s['obstacle_recall'])} | "
                f"median {self.median_seconds():.3f} |"
            )
            m = self.mean_scores()
            lines.append(
                f"| **mean of frames** | | {pct(m['precision'])} | {pct(m['recall'])} | "
                f"{pct(m['f1'])} | {pct(m['obstacle_recall'])} | |"
            )
        for f in self.failures:
            lines.append("")
            lines.append(f"- skipped `{f.name}`: {f.reason}")
        notes = [(r.frame, n) for r in self.frames for n in r.notes]
        for frame, note in notes:
            lines.append(f"- `{frame}`: {note}")
        return "\n".join(lines)


def pct(value: float) -> str:
    """A ratio as a percentage with one decimal, or 'n/a'."""
    return "n/a" if value is None or math.isnan(value) else f"{100 * value:.1f}"


def _finite(obj: Any) -> Any:
    """JSON cannot hold NaN: write null instead."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


# ---------------------------------------------------------------------------------------------
# methods


def ours(**options: Any) -> Method:
    """Our ``segment_terrain`` as a method (keyword options are passed through, checked here:
    :func:`o3d_terrain.api.check_segment_options`). A frame's sensor noise model is passed as
    ``range_noise`` unless the options give one, and its return numbers (a LAS tile's) go with
    the points, as :func:`o3d_terrain.read_cloud` gives them (``ground_returns``)."""
    try:
        from ..api import check_segment_options, segment_terrain
        from ..frame import NUMBER_OF_RETURNS, RETURN_NUMBERS, cloud_from_numpy
    except ImportError as exc:
        raise InputError(f"o3d_terrain.api.segment_terrain is not available in this build ({exc})") from exc
    check_segment_options(**options)  # a bad option fails here, not once per frame

    def segment(positions: np.ndarray, range_noise: Any = None,
                returns: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        given = {} if range_noise is None else {"range_noise": range_noise}
        cloud = positions if returns is None else cloud_from_numpy(
            positions, **{RETURN_NUMBERS: returns[0], NUMBER_OF_RETURNS: returns[1]})
        _, inliers = segment_terrain(cloud, **{**given, **options})
        mask = np.zeros(len(positions), dtype=bool)
        mask[np.asarray(inliers, dtype=np.int64)] = True
        return mask

    segment.__name__ = OURS
    segment.takes_range_noise = True  # run_method passes a frame's sensor noise model ...
    segment.takes_returns = True  # ... and its return numbers
    return segment


def method_names() -> tuple[str, ...]:
    return (OURS, *PEERS)


def resolve_method(name: str, *, kind: str = "vehicle_lidar", sensor_height: float | None = None,
                   **options: Any) -> Method:
    """A method callable by name: ``o3d_terrain`` or one of the peers."""
    if name in (OURS, "ours"):
        return ours(**options)
    if name in PEERS:
        if options:
            raise InputError(f"peer '{name}' takes no options here (got {', '.join(options)}); "
                             "peers run with their documented settings")
        return make_peer(name, kind=kind, sensor_height=sensor_height).segment
    raise InputError(f"unknown method '{name}'; choose one of {', '.join(method_names())}")


# ---------------------------------------------------------------------------------------------
# evaluation


def run_method(method: Method, frame: LabelledFrame) -> np.ndarray:
    """``method`` on the frame's points, with what else the frame knows that the method takes:
    its sensor noise model (``range_noise``, a stereo frame's) and its return numbers
    (``returns``, a LAS tile's)."""
    extra = {}
    if frame.range_noise is not None and getattr(method, "takes_range_noise", False):
        extra["range_noise"] = frame.range_noise
    if frame.returns is not None and getattr(method, "takes_returns", False):
        extra["returns"] = frame.returns
    return method(frame.positions, **extra)


def evaluate_frame(method: Method, frame: LabelledFrame) -> FrameResult:
    """Run ``method`` on one frame and score it (raises on a bad method output)."""
    start = time.perf_counter()
    predicted = run_method(method, frame)
    seconds = time.perf_counter() - start
    predicted = np.asarray(predicted)
    if predicted.shape != (len(frame),) or predicted.dtype != bool:
        raise InputError(
            f"{frame.name}: the method returned shape {predicted.shape}, dtype {predicted.dtype}; "
            f"it must return a ({len(frame)},) bool ground mask"
        )
    counts = segmentation_counts(predicted, frame.is_ground, scored=frame.scored,
                                 obstacle=frame.obstacle)
    return FrameResult(frame.name, len(frame), counts, seconds, frame.notes)


def evaluate_segmentation(
    frames: Iterable[FrameOrFailure],
    method: Method | str = OURS,
    *,
    dataset: str = "",
    method_for_kind: Callable[[str], Method] | None = None,
    on_frame: Callable[[FrameResult | FrameFailure], None] | None = None,
) -> SegmentationReport:
    """Score a method on every frame; failing frames are recorded in ``report.failures``.

    ``method`` is a callable or a name from :func:`method_names`. With a name, peers that need
    to know how a frame was captured (Patchwork++) are built per frame kind.
    """
    name = method if isinstance(method, str) else getattr(method, "__name__", "method")
    report = SegmentationReport(method=name, dataset=dataset)
    cache: dict[tuple, Method] = {}
    for item in frames:
        if isinstance(item, FrameFailure):
            report.failures.append(item)
            if on_frame:
                on_frame(item)
            continue
        try:
            if isinstance(method, str):
                key = (item.kind, item.sensor_height)
                if key not in cache:
                    cache[key] = (method_for_kind(item.kind) if method_for_kind
                                  else resolve_method(method, kind=item.kind,
                                                      sensor_height=item.sensor_height))
                run = cache[key]
            else:
                run = method
            result = evaluate_frame(run, item)
        except Exception as exc:  # a failing frame is reported, the batch goes on
            failure = FrameFailure(item.name, item.source, f"{type(exc).__name__}: {exc}")
            report.failures.append(failure)
            if on_frame:
                on_frame(failure)
            continue
        report.frames.append(result)
        if on_frame:
            on_frame(result)
    return report
