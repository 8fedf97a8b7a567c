"""Rational tensor-product B-spline surfaces z = S(x, y): the value object and its fitting.

:class:`TerrainSurface` is a frozen value object (degree, knots, control points Q, weights R,
local origin) with evaluation, analytic gradient, slope, normals, save/load, mesh and raster
export. :func:`make_lsq_surface` fits one to gridded samples by weighted least squares, in the
style of ``scipy.interpolate.make_lsq_spline``.

Definitions (Broggi et al. 2013, eq. 2 with the denominator fixed, see docs/algorithm.md)::

    S(x, y) = sum_ab R_ab N_a(x) N_b(y) Q_ab / sum_ab R_ab N_a(x) N_b(y)

with clamped knots over the region (uniform, or following the data on a wide vehicle frame:
:func:`clamped_knots`; a surface evaluates exactly on any clamped, non-decreasing knot
vectors) and B-spline basis functions N of polynomial ``degree`` (the paper's "order 3" is
degree 3). Coordinates are stored relative to ``origin`` = (x0, y0, z0) so that projected
(UTM) coordinates keep sub-millimetre precision.

Outside its region a surface is undefined: evaluation there returns NaN (not a clamped or
extrapolated value), so callers can tell "no terrain model here" from "flat terrain here".
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numba
import numpy as np
from scipy.linalg import get_lapack_funcs

from ._files import open_npz, output_path
from ._kernels import bspline as _bs
from ._kernels import terrain as _tk
from .errors import InputError

__all__ = [
    "TerrainSurface",
    "SlopeGrid",
    "clamped_uniform_knots",
    "clamped_knots",
    "make_lsq_surface",
    "GridBasis",
]


def clamped_uniform_knots(n_ctrl: int, degree: int, low: float, high: float) -> np.ndarray:
    """Clamped uniform knot vector of ``n_ctrl + degree + 1`` knots over [low, high]."""
    _check_knots(n_ctrl, degree, low, high)
    return _bs.clamped_uniform_knots(int(n_ctrl), int(degree), float(low), float(high))


def clamped_knots(n_ctrl: int, degree: int, low: float, high: float,
                  density: np.ndarray | None = None) -> np.ndarray:
    """Clamped knot vector of ``n_ctrl + degree + 1`` knots over [low, high]: the interior
    knots at equal steps of the cumulative ``density`` (non-negative weights of equal bins
    across [low, high], linear within a bin), so spans are narrow where the density is high;
    :func:`clamped_uniform_knots` when ``density`` is None or has no positive weight."""
    _check_knots(n_ctrl, degree, low, high)
    if density is None:
        return clamped_uniform_knots(n_ctrl, degree, low, high)
    d = np.asarray(density, dtype=np.float64).ravel()
    cumulative = np.empty(d.size + 1)
    cumulative[0] = 0.0
    np.cumsum(d, out=cumulative[1:])
    total = cumulative[-1]
    # finite, non-negative and some positive weight (NaN fails every comparison)
    if d.size == 0 or not (0.0 < total < np.inf) or d.min() < 0:
        return clamped_uniform_knots(n_ctrl, degree, low, high)
    cumulative /= total
    edges = np.linspace(low, high, d.size + 1)
    n_spans = n_ctrl - degree
    knots = np.empty(n_ctrl + degree + 1)
    knots[:degree + 1] = low
    knots[n_ctrl:] = high
    knots[degree + 1:n_ctrl] = np.interp(np.arange(1, n_spans) / n_spans, cumulative, edges)
    return knots


def _check_knots(n_ctrl: int, degree: int, low: float, high: float) -> None:
    """The checks of :func:`clamped_uniform_knots`."""
    if degree < 1 or n_ctrl < degree + 1:
        raise InputError(
            f"a degree-{degree} spline needs at least {degree + 1} control points per axis, "
            f"got {n_ctrl}; use more control points or a lower degree"
        )
    if not (high > low):
        raise InputError(f"knot range [{low}, {high}] is empty; high must exceed low")


def _as_xy(x, y) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    try:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"x and y must be numbers or arrays of numbers ({exc})") from None
    try:
        x, y = np.broadcast_arrays(x, y)
    except ValueError:
        raise InputError(f"x of shape {x.shape} and y of shape {y.shape} do not broadcast to "
                         f"one shape; give arrays of one shape (or x[:, None], y[None, :] for "
                         f"a grid)") from None
    shape = x.shape
    return np.ascontiguousarray(x.ravel()), np.ascontiguousarray(y.ravel()), shape


@dataclass(frozen=True, eq=False)
class TerrainSurface:
    """A rational B-spline height surface z = S(x, y) over a rectangular region.

    ``knots_x``/``knots_y`` and ``control_points`` are in local coordinates (relative to
    ``origin``); every public method takes and returns world coordinates. ``cell_size``: the
    cell side (m) of the grid the surface was fitted to, when known; the default spacing of
    :meth:`image_layers`.
    """

    degree: int
    knots_x: np.ndarray
    knots_y: np.ndarray
    control_points: np.ndarray  # Q, (n0 + 1, n1 + 1), heights relative to origin[2]
    weights: np.ndarray  # R, (n0 + 1, n1 + 1), > 0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    cell_size: float | None = None

    def __post_init__(self) -> None:
        kx = np.ascontiguousarray(self.knots_x, dtype=np.float64)
        ky = np.ascontiguousarray(self.knots_y, dtype=np.float64)
        q = np.ascontiguousarray(self.control_points, dtype=np.float64)
        r = np.ascontiguousarray(self.weights, dtype=np.float64)
        p = int(self.degree)
        problems = []
        if p < 1:
            problems.append(f"degree must be >= 1, got {p}")
        if q.ndim != 2:
            problems.append(f"control_points must be 2-D, got shape {q.shape}")
        elif r.shape != q.shape:
            problems.append(f"weights shape {r.shape} must equal control_points shape {q.shape}")
        else:
            if kx.shape != (q.shape[0] + p + 1,) or ky.shape != (q.shape[1] + p + 1,):
                problems.append(
                    f"knots must have n_ctrl + degree + 1 entries: got {kx.size} and {ky.size} "
                    f"for {q.shape} control points of degree {p}"
                )
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(r)) and np.all(r > 0)):
                problems.append("control_points must be finite and weights finite and > 0")
        if kx.size > 1 and (np.any(np.diff(kx) < 0) or np.any(np.diff(ky) < 0)):
            problems.append("knot vectors must be non-decreasing")
        if self.cell_size is not None and not (np.isfinite(self.cell_size) and self.cell_size > 0):
            problems.append(f"cell_size must be None or a finite number > 0, got {self.cell_size!r}")
        if problems:
            raise InputError("invalid TerrainSurface: " + "; ".join(problems))
        for arr in (kx, ky, q, r):
            arr.flags.writeable = False
        object.__setattr__(self, "degree", p)
        object.__setattr__(self, "knots_x", kx)
        object.__setattr__(self, "knots_y", ky)
        object.__setattr__(self, "control_points", q)
        object.__setattr__(self, "weights", r)
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))
        if self.cell_size is not None:
            object.__setattr__(self, "cell_size", float(self.cell_size))

    # -- description -----------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """Number of control points per axis (n0 + 1, n1 + 1)."""
        return tuple(self.control_points.shape)  # type: ignore[return-value]

    @property
    def region(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in world coordinates."""
        x0, y0, _ = self.origin
        return (float(x0 + self.knots_x[0]), float(x0 + self.knots_x[-1]),
                float(y0 + self.knots_y[0]), float(y0 + self.knots_y[-1]))

    @property
    def is_rational(self) -> bool:
        return bool(np.ptp(self.weights) > 0)

    def __repr__(self) -> str:
        r = tuple(round(v, 3) for v in self.region)
        return (f"TerrainSurface(degree={self.degree}, control_points={self.shape}, region={r}, "
                f"rational={self.is_rational})")

    # -- evaluation ------------------------------------------------------------------------
    def _tolerances(self) -> tuple[float, float]:
        """How far outside the knot range a point still counts as inside (rounding)."""
        kx, ky = self.knots_x, self.knots_y
        return 1e-9 * max(1.0, kx[-1] - kx[0]), 1e-9 * max(1.0, ky[-1] - ky[0])

    def _evaluate(self, x, y, derivatives: bool):
        xf, yf, shape = _as_xy(x, y)
        tol_x, tol_y = self._tolerances()
        z, zx, zy = _bs.rational_surface_points(
            xf, yf, self.origin[0], self.origin[1], tol_x, tol_y, self.knots_x, self.knots_y,
            self.degree, self.control_points, self.weights, derivatives)
        return z, zx, zy, shape

    def __call__(self, x, y) -> np.ndarray:
        """Height S(x, y) (world z); NaN outside the region or for non-finite input."""
        z, _, _, shape = self._evaluate(x, y, False)
        return (z + self.origin[2]).reshape(shape)

    def heights_above(self, positions) -> np.ndarray:
        """Signed vertical height z - S(x, y) of (N, >= 3) world points, (N,); NaN for
        non-finite points and points outside the region. One pass, no temporaries."""
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] < 3:
            raise InputError(f"positions must be an (N, 3) array, got shape {p.shape}")
        tol_x, tol_y = self._tolerances()
        x0, y0, z0 = self.origin
        # one numba thread: the same kernel without the parallel loop (same heights)
        kernel = _bs.heights_above_serial if numba.get_num_threads() == 1 else _bs.heights_above
        return kernel(p, x0, y0, z0, self.knots_x, self.knots_y, self.degree,
                      self.control_points, self.weights, tol_x, tol_y)

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Analytic first derivatives (dz/dx, dz/dy) by the quotient rule; NaN outside."""
        _, zx, zy, shape = self._evaluate(x, y, True)
        return zx.reshape(shape), zy.reshape(shape)

    def slope_deg(self, x, y) -> np.ndarray:
        """Slope angle in degrees, atan(|grad S|); NaN outside the region."""
        gx, gy = self.gradient(x, y)
        return np.degrees(np.arctan(np.hypot(gx, gy)))

    def normals(self, x, y) -> np.ndarray:
        """Upward unit normals (-S_x, -S_y, 1)/norm, shape (..., 3); NaN outside."""
        gx, gy = self.gradient(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # -- export ----------------------------------------------------------------------------
    def _axis(self, low: float, high: float, step: float, centers: bool) -> np.ndarray:
        if not (step > 0 and np.isfinite(step)):
            raise InputError(f"the spacing must be a finite number > 0, got {step!r}")
        count = max(1, int(np.ceil((high - low) / step - 1e-9)))
        if count > 20_000:
            raise InputError(f"spacing {step} m gives {count} samples per axis (over 20,000); "
                             f"use a larger spacing")
        if centers:
            return low + (np.arange(count) + 0.5) * step
        return np.linspace(low, high, count + 1)

    def to_raster(self, cell_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Heights at the centres of square cells covering the region.

        Returns ``(z, x_centers, y_centers)`` with ``z[ix, iy]`` (x first, like HeightGrid).
        Cells whose centre falls outside the region (the last partial row/column) are NaN.
        """
        x_min, x_max, y_min, y_max = self.region
        xc = self._axis(x_min, x_max, cell_size, True)
        yc = self._axis(y_min, y_max, cell_size, True)
        z = self(xc[:, None], yc[None, :])
        return z, xc, yc

    def default_cell_size(self) -> float:
        """Raster spacing for images: the fitted grid's cell size when known, else the longer
        side of the region / 200."""
        if self.cell_size is not None:
            return self.cell_size
        x_min, x_max, y_min, y_max = self.region
        return max(x_max - x_min, y_max - y_min) / 200

    def image_layers(self, cell_size: float | None = None) -> dict[str, tuple]:
        """Layers for images (``WriteImage product: surface``): name -> (values [ix, iy], valid
        mask, unit), sampled at cell centres every ``cell_size`` m (None =
        :meth:`default_cell_size`): ``z`` (height, m) and ``slope_deg``."""
        step = self.default_cell_size() if cell_size is None else cell_size
        slope = self.slope_grid(step)
        z, _, _ = self.to_raster(step)
        return {"z": (z, np.isfinite(z), "m"), **slope.image_layers()}

    def slope_grid(self, cell_size: float) -> "SlopeGrid":
        """Slope (degrees) at the centres of square cells of ``cell_size`` m covering the
        region, as a :class:`SlopeGrid`; NaN where the centre is outside the region."""
        x_min, x_max, y_min, y_max = self.region
        xc = self._axis(x_min, x_max, cell_size, True)
        yc = self._axis(y_min, y_max, cell_size, True)
        # the grid's kernel: the tensor product contracted once per row of centres, the values
        # of slope_deg at them (to rounding) in a third of the time
        tol_x, tol_y = self._tolerances()
        _, gx, gy = _bs.rational_surface_grid(xc - self.origin[0], yc - self.origin[1],
                                              self.knots_x, self.knots_y, self.degree,
                                              self.control_points, self.weights, tol_x, tol_y)
        return SlopeGrid(np.degrees(np.arctan(np.hypot(gx, gy))), xc, yc, float(cell_size))

    def to_mesh(self, resolution: float = 0.5):
        """An ``open3d.geometry.TriangleMesh`` of the surface with vertices every
        ``resolution`` metres (at most; the region's edges are always included)."""
        import open3d as o3d

        x_min, x_max, y_min, y_max = self.region
        xs = self._axis(x_min, x_max, resolution, False)
        ys = self._axis(y_min, y_max, resolution, False)
        xs[-1], ys[-1] = x_max, y_max
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        gz = self(gx, gy)
        vertices = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        nx, ny = len(xs), len(ys)
        index = np.arange(nx * ny).reshape(nx, ny)
        a = index[:-1, :-1].ravel()
        b = index[1:, :-1].ravel()
        c = index[1:, 1:].ravel()
        d = index[:-1, 1:].ravel()
        triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
        )
        mesh.vertex_normals = o3d.utility.Vector3dVector(self.normals(gx, gy).reshape(-1, 3))
        return mesh

    # -- persistence -----------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the surface to a ``.npz`` file (exact round trip with :meth:`load`)."""
        extra = {} if self.cell_size is None else {"cell_size": self.cell_size}
        np.savez(output_path(path), kind="TerrainSurface", degree=self.degree, knots_x=self.knots_x,
                 knots_y=self.knots_y, control_points=self.control_points,
                 weights=self.weights, origin=np.asarray(self.origin), **extra)

    @classmethod
    def load(cls, path: str | Path) -> "TerrainSurface":
        """The surface :meth:`save` wrote (``path`` with or without its ``.npz``)."""
        try:
            with open_npz(path, "TerrainSurface") as data:
                cell_size = float(data["cell_size"]) if "cell_size" in data else None
                return cls(int(data["degree"]), data["knots_x"], data["knots_y"],
                           data["control_points"], data["weights"],
                           tuple(float(v) for v in data["origin"]), cell_size)
        except (OSError, ValueError, KeyError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{path}: cannot read a TerrainSurface ({exc})") from exc


@dataclass(frozen=True, eq=False)
class SlopeGrid:
    """Terrain slope at cell centres (the ``slope_grid`` product of SlopeEstimator).

    ``slope_deg[ix, iy]`` in degrees (NaN where undefined) at (x_centers[ix], y_centers[iy]),
    square cells of ``cell_size`` m. Unpacks as ``slope_deg, x_centers, y_centers``.
    """

    slope_deg: np.ndarray
    x_centers: np.ndarray
    y_centers: np.ndarray
    cell_size: float

    def __post_init__(self) -> None:
        values = np.asarray(self.slope_deg, dtype=np.float64)
        xc = np.asarray(self.x_centers, dtype=np.float64).ravel()
        yc = np.asarray(self.y_centers, dtype=np.float64).ravel()
        if values.shape != (xc.size, yc.size):
            raise InputError(f"SlopeGrid: slope_deg shape {values.shape} must be "
                             f"(len(x_centers), len(y_centers)) = {(xc.size, yc.size)}")
        if not (np.isfinite(self.cell_size) and self.cell_size > 0):
            raise InputError(f"SlopeGrid: cell_size must be a finite number > 0, "
                             f"got {self.cell_size!r}")
        for name, arr in (("slope_deg", values), ("x_centers", xc), ("y_centers", yc)):
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "cell_size", float(self.cell_size))

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.slope_deg.shape)  # type: ignore[return-value]

    def __iter__(self):
        return iter((self.slope_deg, self.x_centers, self.y_centers))

    def image_layers(self) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
        """``{"slope_deg": (values[ix, iy], valid mask, "deg")}`` for the image writers."""
        return {"slope_deg": (self.slope_deg, np.isfinite(self.slope_deg), "deg")}

    def save(self, path: str | Path) -> None:
        """Write to an ``.npz`` file (round trip with :meth:`load`)."""
        np.savez_compressed(output_path(path), kind="SlopeGrid", slope_deg=self.slope_deg,
                            x_centers=self.x_centers, y_centers=self.y_centers,
                            cell_size=self.cell_size)

    @classmethod
    def load(cls, path: str | Path) -> "SlopeGrid":
        """The grid :meth:`save` wrote (``path`` with or without its ``.npz``)."""
        try:
            with open_npz(path, "SlopeGrid") as data:
                return cls(data["slope_deg"], data["x_centers"], data["y_centers"],
                           float(data["cell_size"]))
        except (OSError, ValueError, KeyError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{path}: cannot read a SlopeGrid ({exc})") from exc


# -------------------------------------------------------------------------------------------
# fitting


class GridBasis:
    """Basis tables of a spline layout sampled at grid-cell centres (local coordinates).

    Built once per (grid, control points, degree) and reused by every iteration of the terrain
    fit: weighted tensor-product solve, paper two-pass solve, evaluation at the cells.
    """

    def __init__(self, x_local: np.ndarray, y_local: np.ndarray, control_points: Sequence[int],
                 degree: int, region_local: tuple[float, float, float, float],
                 knots: tuple[np.ndarray, np.ndarray] | None = None):
        """``knots``: the (x, y) knot vectors in local coordinates over ``region_local``;
        None = clamped uniform knots."""
        n0, n1 = (int(v) for v in control_points)
        self.n0, self.n1, self.degree = n0, n1, int(degree)
        x_min, x_max, y_min, y_max = region_local
        _check_knots(n0, degree, x_min, x_max)
        _check_knots(n1, degree, y_min, y_max)
        if knots is None:
            knots = (_bs.clamped_uniform_knots(n0, self.degree, float(x_min), float(x_max)),
                     _bs.clamped_uniform_knots(n1, self.degree, float(y_min), float(y_max)))
        # per axis in one kernel: spans and basis values at the cell centres (the values of
        # basis_table), Greville abscissae (mean of knots a + 1 .. a + degree, summed left to
        # right)
        self.knots_x, self.spans_x, self.basis_x, self.greville_x = _tk.axis_basis(
            np.ascontiguousarray(x_local, dtype=np.float64),
            np.ascontiguousarray(knots[0], dtype=np.float64), n0, self.degree)
        self.knots_y, self.spans_y, self.basis_y, self.greville_y = _tk.axis_basis(
            np.ascontiguousarray(y_local, dtype=np.float64),
            np.ascontiguousarray(knots[1], dtype=np.float64), n1, self.degree)
        self._matrix_x: np.ndarray | None = None
        self._matrix_y: np.ndarray | None = None
        self.bandwidth = max(degree * n1 + degree, 2 * n1)
        hx = (x_max - x_min) / max(n0 - 1, 1)
        hy = (y_max - y_min) / max(n1 - 1, 1)
        self.penalty_weights = (hy * hy / (hx * hx), 2.0, hx * hx / (hy * hy))
        self.relative_spacing = (_relative_spacing(self.knots_x, n0, self.degree),
                                 _relative_spacing(self.knots_y, n1, self.degree))

    @property
    def matrix_x(self) -> np.ndarray:
        """Dense (m0, n0) basis matrix along x (built on first use)."""
        if self._matrix_x is None:
            self._matrix_x = _dense(self.spans_x, self.basis_x, self.n0, self.degree)
        return self._matrix_x

    @property
    def matrix_y(self) -> np.ndarray:
        """Dense (m1, n1) basis matrix along y (built on first use)."""
        if self._matrix_y is None:
            self._matrix_y = _dense(self.spans_y, self.basis_y, self.n1, self.degree)
        return self._matrix_y

    def evaluate(self, control: np.ndarray, weights: np.ndarray | None = None,
                 mask: np.ndarray | None = None) -> np.ndarray:
        """Surface at the cell centres, (m0, m1); only where ``mask`` (default: everywhere)."""
        if mask is None:
            mask = np.ones((self.spans_x.size, self.spans_y.size), bool)
        args = (self.spans_x, self.basis_x, self.spans_y, self.basis_y)
        if weights is None:
            return _bs.grid_rational(*args, np.ascontiguousarray(control, dtype=np.float64),
                                     np.zeros((0, 0)), mask)
        return _bs.grid_rational(*args, np.ascontiguousarray(weights * control),
                                 np.ascontiguousarray(weights, dtype=np.float64), mask)

    def denominator(self, weights: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        if mask is None:
            mask = np.ones((self.spans_x.size, self.spans_y.size), bool)
        return _bs.grid_rational(self.spans_x, self.basis_x, self.spans_y, self.basis_y,
                                 np.ascontiguousarray(weights, dtype=np.float64),
                                 np.zeros((0, 0)), mask)

    def project(self, values: np.ndarray) -> np.ndarray:
        """Bx^T V By: grid values gathered onto the control grid, (n0, n1)."""
        return _tk.grid_project(self.spans_x, self.basis_x, self.spans_y, self.basis_y,
                                np.ascontiguousarray(values, dtype=np.float64), self.n0, self.n1)

    def evaluate_cells(self, control: np.ndarray, weights: np.ndarray, cells: np.ndarray,
                       out: np.ndarray) -> np.ndarray:
        """Rational surface at the cells ``cells`` (increasing flat indices into the (m0, m1)
        grid) written into ``out`` (C-ordered (m0, m1), other cells left as they are); the
        values of :meth:`evaluate` there."""
        out.ravel()[cells] = self.evaluate_at_cells(control, weights, cells)
        return out

    def evaluate_at_cells(self, control: np.ndarray, weights: np.ndarray, cells: np.ndarray,
                          out: np.ndarray | None = None,
                          denominators: np.ndarray | None = None) -> np.ndarray:
        """Rational surface at the cells ``cells`` (increasing flat indices into the (m0, m1)
        grid), one value per cell (into ``out`` when given); the values of :meth:`evaluate`
        there. ``denominators``: the denominators at the cells that :meth:`solve_cells`
        wrote for the same ``weights`` (reused instead of summed again)."""
        if out is None:
            out = np.empty(cells.shape[0])
        return _bs.grid_rational_cells(self.spans_x, self.basis_x, self.spans_y, self.basis_y,
                                       np.ascontiguousarray(weights * control),
                                       np.ascontiguousarray(weights, dtype=np.float64), cells,
                                       out, _NONE if denominators is None else denominators)

    def solve_tensor(self, z: np.ndarray, sample_weights: np.ndarray,
                     rational_weights: np.ndarray | None = None, smoothing: float = 0.0,
                     ridge: float = 1e-9, cells: np.ndarray | None = None) -> np.ndarray:
        """Exact weighted least squares over all cells at once, with an optional thin-plate
        penalty ``smoothing`` (relative to the mean data weight per control point).

        Minimises sum_c W_c (Z_c - S(c))^2 + lambda E_thin_plate(Q) over Q for fixed R. With R,
        S is linear in Q through the rational basis R_ab N_a N_b / D, so the fit is consistent
        with rational evaluation. ``cells``: increasing flat indices of the cells that may have
        a weight > 0 (the others must have weight <= 0); None = found here.
        """
        z = np.ascontiguousarray(z, dtype=np.float64).ravel()
        sample_weights = np.ascontiguousarray(sample_weights, dtype=np.float64).ravel()
        if cells is None:
            cells = np.flatnonzero(sample_weights > 0)
        return self.solve_cells(cells, z[cells], sample_weights[cells], rational_weights,
                                smoothing, ridge)

    def solve_cells(self, cells: np.ndarray, z: np.ndarray, sample_weights: np.ndarray,
                    rational_weights: np.ndarray | None = None, smoothing: float = 0.0,
                    ridge: float = 1e-9, denominators: np.ndarray | None = None) -> np.ndarray:
        """:meth:`solve_tensor` from the samples ``z`` and weights ``sample_weights`` of the
        cells ``cells`` only (increasing flat indices; 1-D arrays, one entry per cell; every
        other cell counts as weight 0). ``denominators`` (with ``rational_weights``): a
        float64 array of one entry per cell that receives the rational denominator at each
        cell, for :meth:`evaluate_at_cells` with the same weights."""
        r_in = np.zeros((0, 0)) if rational_weights is None else \
            np.ascontiguousarray(rational_weights, dtype=np.float64)
        lower, rhs, weight_sum = _bs.normal_band_cells(
            self.spans_x, self.basis_x, self.spans_y, self.basis_y,
            np.ascontiguousarray(z, dtype=np.float64),
            np.ascontiguousarray(sample_weights, dtype=np.float64), r_in, cells, self.n0,
            self.n1, self.degree, self.bandwidth, _NONE if denominators is None else denominators)
        band = lower.T  # LAPACK lower band storage, Fortran order: no copy for dpbsv
        diagonal = np.ascontiguousarray(band[0])  # numpy's mean of the strided row: ~20 us
        scale = max(float(np.add.reduce(diagonal)) / diagonal.size, 1e-12)  # = mean()
        if smoothing > 0:
            data_per_ctrl = weight_sum / (self.n0 * self.n1)
            _tk.add_thin_plate_band(band, self.n0, self.n1, smoothing * max(data_per_ctrl, 1e-12),
                                    *self.penalty_weights, self.greville_x, self.greville_y,
                                    *self.relative_spacing)
        band[0] += ridge * scale
        return _solve_band(band, rhs).reshape(self.n0, self.n1)

    def solve_two_pass(self, z: np.ndarray, sample_weights: np.ndarray,
                       ridge: float = 1e-9) -> np.ndarray:
        """The paper's separable fit: weighted least squares along X for every grid column,
        then the intermediate control points fitted along Y.

        Pass 2 weighs intermediate control point (a, j) by the information pass 1 had on it,
        sum_i W_ij N_a(x_i)^2 (columns without data get weight ~0 and are bridged by pass 2).
        """
        bx, by = self.matrix_x, self.matrix_y
        w = np.where(sample_weights > 0, sample_weights, 0.0)
        zz = np.where(w > 0, z, 0.0)
        # pass 1: per column j, (Bx^T W_j Bx) c_j = Bx^T W_j z_j
        normal = np.einsum("ia,ij,ib->jab", bx, w, bx)
        rhs = np.einsum("ia,ij->ja", bx, w * zz)
        trace = np.maximum(np.trace(normal, axis1=1, axis2=2) / self.n0, 1e-12)
        normal += (ridge * trace)[:, None, None] * np.eye(self.n0)
        inter = np.linalg.solve(normal, rhs[..., None])[..., 0]  # (m1, n0)
        info = np.einsum("ia,ij->ja", bx * bx, w)  # (m1, n0)
        # pass 2: per a, (By^T V_a By) q_a = By^T V_a c_a
        normal2 = np.einsum("ja,jb,jc->abc", info, by, by)
        rhs2 = np.einsum("ja,jb->ab", info * inter, by)
        trace2 = np.maximum(np.trace(normal2, axis1=1, axis2=2) / self.n1, 1e-12)
        normal2 += (ridge * trace2)[:, None, None] * np.eye(self.n1)
        return np.linalg.solve(normal2, rhs2[..., None])[..., 0]


def _relative_spacing(knots: np.ndarray, n_ctrl: int, degree: int) -> np.ndarray:
    """Per control point, the mean width of the non-empty knot spans under its support
    relative to the mean span width: the local spacing of the thin-plate penalty
    (:func:`~o3d_terrain._kernels.terrain.add_thin_plate_band`); exactly 1 on uniform knots."""
    if _tk.uniform_knot_spans(knots, n_ctrl, degree, 1e-9):  # one kernel call: ~1 us, not 11
        return np.ones(n_ctrl)
    mean = (knots[n_ctrl] - knots[degree]) / (n_ctrl - degree)
    all_widths = np.diff(knots)  # control point a's support: spans a .. a + degree
    window = np.ones(degree + 1)
    sums = np.convolve(all_widths, window, mode="valid")
    counts = np.convolve(all_widths > 0, window, mode="valid")
    return sums / np.maximum(counts, 1) / mean


def _solve_band(band: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve A q = rhs for symmetric positive definite banded A in LAPACK lower band storage
    (Fortran-ordered, overwritten) by ``dpbsv`` (blocked banded Cholesky), called directly:
    ``scipy.linalg.solveh_banded(band, rhs, lower=True)`` without its checks and copies."""
    _, q, info = _DPBSV(band, rhs[:, None], lower=1, overwrite_ab=1, overwrite_b=1)
    if info > 0:
        raise np.linalg.LinAlgError(f"{info}th leading minor not positive definite")
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal pbsv")
    return q[:, 0]


_DPBSV = get_lapack_funcs("pbsv", dtype=np.float64)
_NONE = np.zeros(0)  # an empty optional array argument of the kernels


def _dense(spans: np.ndarray, values: np.ndarray, n_ctrl: int, degree: int) -> np.ndarray:
    m = spans.shape[0]
    out = np.zeros((m, n_ctrl))
    rows = np.repeat(np.arange(m), degree + 1)
    cols = (spans[:, None] - degree + np.arange(degree + 1)[None, :]).ravel()
    out[rows, cols] = values.ravel()
    return out


def make_lsq_surface(
    x_centers: np.ndarray,
    y_centers: np.ndarray,
    z: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    control_points: Sequence[int],
    degree: int = 3,
    region: tuple[float, float, float, float] | None = None,
    rational_weights: np.ndarray | None = None,
    smoothing: float = 0.0,
    method: str = "tensor",
    origin: tuple[float, float, float] | None = None,
) -> TerrainSurface:
    """Fit a (rational) B-spline surface to gridded samples by weighted least squares.

    ``z[i, j]`` is the sample at (x_centers[i], y_centers[j]); ``weights`` (same shape, >= 0,
    default 1; 0 or NaN z = ignored). ``region`` defaults to the span of the centres.
    ``method`` is "tensor" (exact weighted fit over all samples) or "two_pass" (the paper's
    X-then-Y fit; ignores ``rational_weights`` and ``smoothing`` in the solve).
    ``rational_weights`` R (control-point shape) makes the fit use the rational basis.
    """
    xc = np.asarray(x_centers, dtype=np.float64).ravel()
    yc = np.asarray(y_centers, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64)
    if z.shape != (xc.size, yc.size):
        raise InputError(f"z must have shape (len(x_centers), len(y_centers)) = "
                         f"{(xc.size, yc.size)}, got {z.shape}")
    w = np.ones_like(z) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != z.shape:
        raise InputError(f"weights shape {w.shape} must equal z shape {z.shape}")
    usable = np.isfinite(z) & np.isfinite(w) & (w > 0)
    if usable.sum() < 3:
        raise InputError(f"only {int(usable.sum())} usable samples (finite z, weight > 0); "
                         f"a surface fit needs at least 3")
    if method not in ("tensor", "two_pass"):
        raise InputError(f"method must be 'tensor' or 'two_pass', got {method!r}")
    if region is None:
        region = (xc.min(), xc.max(), yc.min(), yc.max())
    x_min, x_max, y_min, y_max = (float(v) for v in region)
    if not (x_max > x_min and y_max > y_min):
        raise InputError(f"region {region} is degenerate: it needs x_max > x_min and y_max > y_min")
    if origin is None:
        origin = ((x_min + x_max) / 2, (y_min + y_max) / 2, float(np.median(z[usable])))
    x0, y0, z0 = origin
    basis = GridBasis(xc - x0, yc - y0, control_points, degree,
                      (x_min - x0, x_max - x0, y_min - y0, y_max - y0))
    w = np.where(usable, w, 0.0)
    zl = np.where(usable, z - z0, 0.0)
    if method == "two_pass":
        q = basis.solve_two_pass(zl, w)
    else:
        q = basis.solve_tensor(zl, w, rational_weights, smoothing)
    r = np.ones_like(q) if rational_weights is None else np.asarray(rational_weights, float)
    return TerrainSurface(degree, basis.knots_x, basis.knots_y, q, r, (x0, y0, z0))
