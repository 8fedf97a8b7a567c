"""The evaluation protocol of Broggi et al. 2013, Sec. VI (Fig. 6): terrain deviation caused
by one artificial obstacle.

A flat road over the area of interest x in [0, 22] m, y in [-11, 11] m sampled at 0.5 m; a box
obstacle of a given width (square footprint, width x width) and height centred at
(11.0, 0.0). The terrain is fitted with and without the obstacle (same method, degree and
control points) and the maximum vertical deviation between the two surfaces is reported as a
percentage of the obstacle height. Deviation is measured on a 0.25 m raster away from the
area's border (``border`` metres are left out on every side, where a fit has the least
support). Samples are ideal (one exact sample per cell, the obstacle top inside its footprint)
so the protocol measures the fit, not the sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import ConfigError, InputError, Problem
from .grid import MEASURED, HeightGrid
from .terrain import METHODS, fit_grid

__all__ = ["DeviationRow", "DeviationResult", "run_deviation_protocol",
           "write_deviation_outputs", "PAPER_WIDTHS", "PAPER_HEIGHTS"]

PAPER_WIDTHS = (0.8, 1.6, 2.4, 4.0, 8.0, 12.0)
PAPER_HEIGHTS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)


@dataclass(frozen=True)
class DeviationRow:
    width: float
    height: float
    control_points: int
    method: str
    max_deviation_pct: float


@dataclass(frozen=True)
class DeviationResult:
    rows: list[DeviationRow] = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    def table(self) -> str:
        """A Markdown table: one row per (method, control points, width), one column per height."""
        heights = sorted({r.height for r in self.rows})
        keys = sorted({(r.method, r.control_points, r.width) for r in self.rows},
                      key=lambda k: (k[0], k[1], k[2]))
        lookup = {(r.method, r.control_points, r.width, r.height): r.max_deviation_pct
                  for r in self.rows}
        head = "| method | control points | width (m) | " + " | ".join(
            f"h = {h:g} m" for h in heights) + " |"
        sep = "|---|---|---|" + "---|" * len(heights)
        lines = [head, sep]
        for m, c, w in keys:
            cells = " | ".join(f"{lookup.get((m, c, w, h), float('nan')):.1f} %" for h in heights)
            lines.append(f"| {m} | {c} × {c} | {w:g} | {cells} |")
        return "\n".join(lines)

    def to_csv(self) -> str:
        lines = ["method,control_points,width_m,height_m,max_deviation_pct"]
        lines += [f"{r.method},{r.control_points},{r.width:g},{r.height:g},"
                  f"{r.max_deviation_pct:.4f}" for r in self.rows]
        return "\n".join(lines) + "\n"


def _grid(height: float, width: float, cell_size: float, area: float) -> HeightGrid:
    n = int(round(area / cell_size))
    xc = (np.arange(n) + 0.5) * cell_size
    yc = -area / 2 + (np.arange(n) + 0.5) * cell_size
    z = np.zeros((n, n))
    if height > 0:
        inside = (np.abs(xc[:, None] - area / 2) <= width / 2) & (np.abs(yc[None, :]) <= width / 2)
        z[inside] = height
    return HeightGrid(0.0, -area / 2, cell_size, z, np.ones((n, n), np.int64),
                      np.full((n, n), MEASURED, np.uint8))


def run_deviation_protocol(*, widths: Sequence[float] = PAPER_WIDTHS,
                           heights: Sequence[float] = PAPER_HEIGHTS,
                           control_points: Sequence[int] = (5, 25), degree: int = 3,
                           methods: Sequence[str] = ("robust", "paper"),
                           cell_size: float = 0.5, area: float = 22.0,
                           border: float = 2.0) -> DeviationResult:
    """Run the Sec. VI protocol; one row per (method, control points, width, height).

    Raises :class:`~o3d_terrain.errors.ConfigError` (every problem at once, each naming the
    argument and the ``o3d-terrain eval deviation`` flag) before any fit when a setting is
    out of range."""
    problems = _check_settings(widths, heights, control_points, degree, methods, cell_size,
                               area, border)
    if problems:
        raise ConfigError(problems)
    step = 0.25
    xs = np.arange(border, area - border + 1e-9, step)
    ys = np.arange(-area / 2 + border, area / 2 - border + 1e-9, step)
    rows = []
    for method in methods:
        for c in control_points:
            flat = fit_grid(_grid(0.0, 1.0, cell_size, area), control_points=(c, c),
                            degree=degree, method=method)
            base = flat(xs[:, None], ys[None, :])
            for w in widths:
                for h in heights:
                    s = fit_grid(_grid(h, w, cell_size, area), control_points=(c, c),
                                 degree=degree, method=method)
                    dev = float(np.nanmax(np.abs(s(xs[:, None], ys[None, :]) - base)))
                    rows.append(DeviationRow(float(w), float(h), int(c), method, 100 * dev / h))
    settings = dict(area_m=area, cell_size_m=cell_size, degree=degree, border_m=border,
                    obstacle_center=(area / 2, 0.0), raster_step_m=step)
    return DeviationResult(rows, settings)


def _number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) \
        and not isinstance(value, bool) and math.isfinite(value)


def _check_settings(widths, heights, control_points, degree, methods, cell_size, area,
                    border) -> list[Problem]:
    """The problems of :func:`run_deviation_protocol`'s settings (none: they can run)."""
    problems = []

    def bad(name: str, flag: str | None, message: str, fix: str) -> None:
        what = f"{flag} ({name})" if flag else name
        problems.append(Problem("eval deviation", f"{what} {message}", fix))

    if not (_number(area) and area > 0):
        bad("area", None, f"must be a positive number of metres, got {area!r}", "e.g. 22.0")
        return problems
    for name, values, paper in (("widths", widths, PAPER_WIDTHS),
                                ("heights", heights, PAPER_HEIGHTS)):
        if isinstance(values, (str, bytes)) or not values \
                or not all(_number(v) and v > 0 for v in values):
            bad(name, f"--{name}", f"must be a non-empty list of positive metres, got "
                f"{values!r}", f"give e.g. --{name} {' '.join(f'{v:g}' for v in paper)}, the "
                "paper's and the default")
    if isinstance(methods, (str, bytes)) or not methods \
            or not all(m in METHODS for m in methods):
        bad("methods", "--methods", f"must name one or more of {', '.join(METHODS)}, got "
            f"{methods!r}", "give e.g. --methods robust paper, the default")
    cells = None
    if not (_number(cell_size) and 0 < cell_size <= area / 2):
        bad("cell_size", "--cell-size", f"must be a number of metres in (0, {area / 2:g}] "
            f"(at least 2 x 2 cells over the {area:g} m area), got {cell_size!r}",
            "give e.g. --cell-size 0.5, the default")
    else:
        cells = round(area / cell_size)
    if not (isinstance(degree, (int, np.integer)) and not isinstance(degree, bool)
            and 1 <= degree <= 5):
        bad("degree", None, f"must be an integer in [1, 5], got {degree!r}", "e.g. 3")
    else:
        low, high = degree + 1, None if cells is None else cells + degree
        span = f"[{low}, {high}]" if high is not None else f">= {low}"
        if isinstance(control_points, (str, bytes)) or not control_points or not all(
                isinstance(c, (int, np.integer)) and not isinstance(c, bool)
                and c >= low and (high is None or c <= high) for c in control_points):
            bad("control_points", "--control-points",
                f"must be one or more integers in {span} (at degree {degree}"
                + (f", on {cells} x {cells} cells of {cell_size:g} m" if cells else "")
                + f"), got {control_points!r}", "give e.g. --control-points 5 25, the default")
    if not (_number(border) and 0 <= border < area / 2):
        bad("border", None, f"must be in [0, area / 2) = [0, {area / 2:g}), got {border!r}",
            "e.g. 2.0")
    return problems


_COLORS = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
           (75, 86, 140), (194, 119, 227), (127, 127, 127)]


def _panel(rows: list[DeviationRow], title: str, size=(520, 420)) -> np.ndarray:
    import cv2

    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 60, 130, 40, 50
    heights = sorted({r.height for r in rows})
    widths = sorted({r.width for r in rows})
    y_max = max(10.0, np.ceil(max(r.max_deviation_pct for r in rows) / 10) * 10)
    x_lo, x_hi = min(heights), max(heights)
    x_hi = x_hi if x_hi > x_lo else x_lo + 1

    def px(x, y):
        u = left + (x - x_lo) / (x_hi - x_lo) * (w - left - right)
        v = h - bottom - y / y_max * (h - top - bottom)
        return int(round(u)), int(round(v))

    cv2.rectangle(img, px(x_lo, y_max), px(x_hi, 0), (0, 0, 0), 1)
    for k in range(6):
        yv = y_max * k / 5
        cv2.putText(img, f"{yv:.0f}", (8, px(x_lo, yv)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (0, 0, 0), 1, cv2.LINE_AA)
    for hv in heights:
        cv2.putText(img, f"{hv:g}", (px(hv, 0)[0] - 8, h - bottom + 18),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "obstacle height (m)", (left + 90, h - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "max deviation (% of height)", (8, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, title, (left + 150, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)
    for i, wv in enumerate(widths):
        color = _COLORS[i % len(_COLORS)]
        pts = [px(r.height, r.max_deviation_pct) for r in
               sorted((r for r in rows if r.width == wv), key=lambda r: r.height)]
        cv2.polylines(img, [np.array(pts, np.int32)], False, color, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, color, -1, cv2.LINE_AA)
        ly = top + 15 + 18 * i
        cv2.line(img, (w - right + 10, ly), (w - right + 30, ly), color, 2, cv2.LINE_AA)
        cv2.putText(img, f"w = {wv:g} m", (w - right + 35, ly + 4), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def write_deviation_outputs(result: DeviationResult, out_dir: str | Path) -> list[Path]:
    """Write ``deviation.md`` (table), ``deviation.csv`` and one ``deviation_<method>.png``
    per method (a panel per control-point count, like the paper's Fig. 6). Returns the paths."""
    import cv2

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    md = out / "deviation.md"
    md.write_text("Max terrain deviation (% of obstacle height), Broggi et al. 2013 Sec. VI "
                  f"protocol; settings: {result.settings}\n\n" + result.table() + "\n")
    csv = out / "deviation.csv"
    csv.write_text(result.to_csv())
    paths += [md, csv]
    for method in sorted({r.method for r in result.rows}):
        panels = []
        for c in sorted({r.control_points for r in result.rows if r.method == method}):
            sub = [r for r in result.rows if r.method == method and r.control_points == c]
            panels.append(_panel(sub, f"{method}, {c} x {c} control points"))
        png = out / f"deviation_{method}.png"
        if not cv2.imwrite(str(png), np.vstack(panels)):
            raise InputError(f"could not write {png}")
        paths.append(png)
    return paths
