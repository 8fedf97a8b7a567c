"""Scores for ground segmentation and terrain reconstruction.

Ground segmentation is scored as a binary classification of *ground* points, the convention of
the ground-segmentation literature (Patchwork, Patchwork++): a true positive is a ground point
called ground. Only points in the ``scored`` mask count (SemanticKITTI's unlabeled/outlier
points, LAS noise classes). Obstacle recall is the share of obstacle points (vehicles, people,
buildings, poles, the synthetic scenes' objects) that the method did *not* call ground: a method
that swallows obstacles into the terrain is dangerous for a vehicle even when its F1 is high.

Terrain reconstruction is scored against an exact terrain: height RMSE and the error of the
slope angle (degrees), both over the cells or points where the truth is defined.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class SegmentationCounts:
    """Confusion counts of a ground/non-ground classification (ground is the positive class)."""

    true_positive: int = 0
    false_positive: int = 0
    false_negative: int = 0
    true_negative: int = 0
    obstacle_points: int = 0
    obstacle_detected: int = 0  # obstacle points not called ground

    def __add__(self, other: "SegmentationCounts") -> "SegmentationCounts":
        return SegmentationCounts(*(a + b for a, b in zip(_values(self), _values(other))))

    @property
    def scored_points(self) -> int:
        return self.true_positive + self.false_positive + self.false_negative + self.true_negative

    @property
    def precision(self) -> float:
        return _ratio(self.true_positive, self.true_positive + self.false_positive)

    @property
    def recall(self) -> float:
        return _ratio(self.true_positive, self.true_positive + self.false_negative)

    @property
    def f1(self) -> float:
        return _ratio(
            2 * self.true_positive,
            2 * self.true_positive + self.false_positive + self.false_negative,
        )

    @property
    def accuracy(self) -> float:
        return _ratio(self.true_positive + self.true_negative, self.scored_points)

    @property
    def obstacle_recall(self) -> float:
        return _ratio(self.obstacle_detected, self.obstacle_points)

    def scores(self) -> dict[str, float]:
        """Precision, recall, F1, accuracy, obstacle recall (NaN where undefined)."""
        return {
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "accuracy": self.accuracy,
            "obstacle_recall": self.obstacle_recall,
        }

    def to_dict(self) -> dict[str, float | int]:
        return {**asdict(self), **self.scores()}


def _values(counts: SegmentationCounts) -> tuple[int, ...]:
    return tuple(asdict(counts).values())


def _ratio(numerator: float, denominator: float) -> float:
    return float(numerator) / float(denominator) if denominator else float("nan")


def _mask(name: str, values: np.ndarray | None, n: int, default: bool) -> np.ndarray:
    if values is None:
        return np.full(n, default, dtype=bool)
    values = np.asarray(values)
    if values.shape != (n,):
        raise InputError(
            f"the '{name}' mask has shape {values.shape}; it must be ({n},), one value per point "
            "(give a boolean mask aligned with the positions)"
        )
    if values.dtype != bool:
        raise InputError(
            f"the '{name}' mask has dtype {values.dtype}; it must be bool (a method returning "
            "indices should convert them with a mask: mask = np.zeros(n, bool); mask[idx] = True)"
        )
    return values


def segmentation_counts(
    predicted_ground: np.ndarray,
    is_ground: np.ndarray,
    *,
    scored: np.ndarray | None = None,
    obstacle: np.ndarray | None = None,
) -> SegmentationCounts:
    """Confusion counts of ``predicted_ground`` against ``is_ground`` over the ``scored`` points.

    All masks are (N,) bool. ``scored`` defaults to every point, ``obstacle`` to none.
    """
    truth = np.asarray(is_ground)
    n = truth.shape[0] if truth.ndim == 1 else -1
    truth = _mask("is_ground", truth, n, False)
    predicted = _mask("predicted ground", predicted_ground, n, False)
    scored_mask = _mask("scored", scored, n, True)
    obstacle_mask = _mask("obstacle", obstacle, n, False) & scored_mask
    t = truth[scored_mask]
    p = predicted[scored_mask]
    return SegmentationCounts(
        true_positive=int(np.count_nonzero(t & p)),
        false_positive=int(np.count_nonzero(~t & p)),
        false_negative=int(np.count_nonzero(t & ~p)),
        true_negative=int(np.count_nonzero(~t & ~p)),
        obstacle_points=int(np.count_nonzero(obstacle_mask)),
        obstacle_detected=int(np.count_nonzero(obstacle_mask & ~predicted)),
    )


def _paired_errors(estimated, truth, valid, shape_message: str) -> np.ndarray:
    """``estimated - truth`` where both are finite and ``valid``; shapes must match."""
    estimated = np.asarray(estimated, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if estimated.shape != truth.shape:
        raise InputError(shape_message.format(estimated.shape, truth.shape))
    keep = np.isfinite(estimated) & np.isfinite(truth)
    if valid is not None:
        keep &= np.asarray(valid, dtype=bool)
    return estimated[keep] - truth[keep]


def height_rmse(estimated: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Root-mean-square of ``estimated - truth`` over ``valid`` (and finite) entries."""
    error = _paired_errors(estimated, truth, valid,
                           "height RMSE: estimated heights have shape {} and the truth {}; "
                           "they must match (evaluate both at the same points)")
    if error.size == 0:
        return float("nan")
    return float(np.sqrt(np.mean(error * error)))


def slope_deg_from_gradient(dz_dx: np.ndarray, dz_dy: np.ndarray) -> np.ndarray:
    """Slope angle in degrees of a surface with these partial derivatives: atan(|grad z|)."""
    return np.degrees(np.arctan(np.hypot(dz_dx, dz_dy)))


def slope_error_deg(
    estimated_deg: np.ndarray, truth_deg: np.ndarray, valid: np.ndarray | None = None
) -> dict[str, float]:
    """Slope-angle error statistics in degrees: mean absolute, RMSE, 95th percentile, max."""
    error = np.abs(_paired_errors(
        estimated_deg, truth_deg, valid,
        "slope error: estimated slopes have shape {} and the truth {}; they must match"))
    if error.size == 0:
        nan = float("nan")
        return {"mean_abs": nan, "rmse": nan, "p95_abs": nan, "max_abs": nan}
    return {
        "mean_abs": float(error.mean()),
        "rmse": float(np.sqrt(np.mean(error * error))),
        "p95_abs": float(np.percentile(error, 95)),
        "max_abs": float(error.max()),
    }
