"""Slow, obvious reference evaluators for the spline tests (Cox-de Boor recursion as printed)."""

from __future__ import annotations

import numpy as np


def basis(i: int, degree: int, t: float, knots: np.ndarray) -> float:
    """N_{i,degree}(t) by the Cox-de Boor recursion; the last knot closes the last span."""
    if degree == 0:
        if knots[i] <= t < knots[i + 1]:
            return 1.0
        # right end of a clamped vector belongs to the last non-empty span
        if t == knots[-1] and knots[i] < knots[i + 1] == knots[-1]:
            return 1.0
        return 0.0
    out = 0.0
    den = knots[i + degree] - knots[i]
    if den > 0:
        out += (t - knots[i]) / den * basis(i, degree - 1, t, knots)
    den = knots[i + degree + 1] - knots[i + 1]
    if den > 0:
        out += (knots[i + degree + 1] - t) / den * basis(i + 1, degree - 1, t, knots)
    return out


def rational_surface(x: float, y: float, knots_x, knots_y, degree, control, weights) -> float:
    """S = sum R N N Q / sum R N N by full double sums."""
    n0, n1 = control.shape
    num = den = 0.0
    for a in range(n0):
        na = basis(a, degree, x, knots_x)
        if na == 0:
            continue
        for b in range(n1):
            nn = na * basis(b, degree, y, knots_y)
            num += weights[a, b] * nn * control[a, b]
            den += weights[a, b] * nn
    return num / den
