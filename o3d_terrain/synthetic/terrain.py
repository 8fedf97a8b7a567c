"""Analytic terrain features: each gives its exact height and gradient at any (x, y).

A terrain is a sum of features. Every feature is smooth (C-infinity; a grid's relief,
:class:`GridRelief`, C²), so the slope is defined everywhere and equals the analytic
gradient; heights and gradients are vectorised over numpy arrays of any shape. Coordinates
are world metres: x forward (away from the sensor), y left, z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError


def _sigmoid(u: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * u))


def _softplus(u: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, u)


@dataclass(frozen=True)
class Plane:
    """z = offset + slope_x·x + slope_y·y (slopes as rise over run)."""

    slope_x: float = 0.0
    slope_y: float = 0.0
    offset: float = 0.0

    def height(self, x, y):
        return self.offset + self.slope_x * x + self.slope_y * y

    def gradient(self, x, y):
        return np.full_like(x, self.slope_x), np.full_like(y, self.slope_y)


@dataclass(frozen=True)
class Hill:
    """A Gaussian bump (negative amplitude: a hollow) centred at (x0, y0), widths in metres."""

    x0: float
    y0: float
    amplitude: float
    sigma_x: float
    sigma_y: float

    def height(self, x, y):
        u = (x - self.x0) / self.sigma_x
        v = (y - self.y0) / self.sigma_y
        return self.amplitude * np.exp(-0.5 * (u * u + v * v))

    def gradient(self, x, y):
        u = (x - self.x0) / self.sigma_x
        v = (y - self.y0) / self.sigma_y
        h = self.amplitude * np.exp(-0.5 * (u * u + v * v))
        return -h * u / self.sigma_x, -h * v / self.sigma_y


@dataclass(frozen=True)
class Ridge:
    """A straight Gaussian ridge (berm, amplitude > 0) or trough (ditch, amplitude < 0).

    The crest runs through (x0, y0) along the heading ``direction_deg`` (0 = along +x); the
    cross-section is ``amplitude · exp(-d² / (2 sigma²))`` with d the distance to the crest line.
    """

    x0: float
    y0: float
    direction_deg: float
    amplitude: float
    sigma: float

    def _distance(self, x, y):
        a = math.radians(self.direction_deg)
        nx, ny = -math.sin(a), math.cos(a)  # unit normal of the crest line
        return (x - self.x0) * nx + (y - self.y0) * ny, nx, ny

    def height(self, x, y):
        d, _, _ = self._distance(x, y)
        return self.amplitude * np.exp(-0.5 * (d / self.sigma) ** 2)

    def gradient(self, x, y):
        d, nx, ny = self._distance(x, y)
        dh = -self.amplitude * d / self.sigma**2 * np.exp(-0.5 * (d / self.sigma) ** 2)
        return dh * nx, dh * ny


@dataclass(frozen=True)
class Ramp:
    """A ramp of constant slope between two flats, rising along the heading ``direction_deg``.

    Along the heading, s = distance past (x0, y0): the height is 0 before s = 0, rises at
    ``tan(slope_deg)`` until s = ``length``, then stays at ``length·tan(slope_deg)``. The two
    kinks are rounded over about ``rounding`` metres (softplus), so away from the ends
    (more than 10·rounding, 2.5 m by default) the slope equals ``slope_deg`` to better than
    1e-3 degrees.
    """

    x0: float
    y0: float
    direction_deg: float
    slope_deg: float
    length: float
    rounding: float = 0.25

    def _along(self, x, y):
        a = math.radians(self.direction_deg)
        ux, uy = math.cos(a), math.sin(a)
        return (x - self.x0) * ux + (y - self.y0) * uy, ux, uy

    def height(self, x, y):
        s, _, _ = self._along(x, y)
        w = self.rounding
        k = math.tan(math.radians(self.slope_deg))
        return k * w * (_softplus(s / w) - _softplus((s - self.length) / w))

    def gradient(self, x, y):
        s, ux, uy = self._along(x, y)
        w = self.rounding
        k = math.tan(math.radians(self.slope_deg))
        ds = k * (_sigmoid(s / w) - _sigmoid((s - self.length) / w))
        return ds * ux, ds * uy


@dataclass(frozen=True)
class Valley:
    """A hyperbolic valley along the heading ``direction_deg`` through (x0, y0).

    z = depth·(sqrt(1 + (d / half_width)²) − 1), d the distance to the valley floor line; the
    flanks tend to a slope of depth / half_width.
    """

    x0: float
    y0: float
    direction_deg: float
    depth: float
    half_width: float

    def _distance(self, x, y):
        a = math.radians(self.direction_deg)
        nx, ny = -math.sin(a), math.cos(a)
        return (x - self.x0) * nx + (y - self.y0) * ny, nx, ny

    def height(self, x, y):
        d, _, _ = self._distance(x, y)
        return self.depth * (np.sqrt(1.0 + (d / self.half_width) ** 2) - 1.0)

    def gradient(self, x, y):
        d, nx, ny = self._distance(x, y)
        u = d / self.half_width
        dh = self.depth * u / (self.half_width * np.sqrt(1.0 + u * u))
        return dh * nx, dh * ny


@dataclass(frozen=True)
class Roughness:
    """Small smooth undulations: a sum of plane waves (amplitude, wavelength, heading, phase)."""

    waves: tuple[tuple[float, float, float, float], ...]

    def height(self, x, y):
        z = np.zeros_like(x)
        for amplitude, wavelength, heading, phase in self.waves:
            k = 2.0 * math.pi / wavelength
            z = z + amplitude * np.sin(k * (x * math.cos(heading) + y * math.sin(heading)) + phase)
        return z

    def gradient(self, x, y):
        gx = np.zeros_like(x)
        gy = np.zeros_like(y)
        for amplitude, wavelength, heading, phase in self.waves:
            k = 2.0 * math.pi / wavelength
            c = amplitude * k * np.cos(k * (x * math.cos(heading) + y * math.sin(heading)) + phase)
            gx = gx + c * math.cos(heading)
            gy = gy + c * math.sin(heading)
        return gx, gy

    @classmethod
    def random(cls, rng: np.random.Generator, *, amplitude: float, count: int = 6,
               wavelengths: tuple[float, float] = (1.5, 6.0)) -> Roughness:
        """``count`` waves of total RMS height about ``amplitude`` metres."""
        each = amplitude * math.sqrt(2.0 / count)
        waves = tuple(
            (each, float(rng.uniform(*wavelengths)), float(rng.uniform(0, math.pi)),
             float(rng.uniform(0, 2 * math.pi)))
            for _ in range(count)
        )
        return cls(waves)


@dataclass(frozen=True, eq=False)
class GridRelief:
    """Heights on a regular grid (a surveyed elevation raster) as a smooth terrain: the
    bicubic spline through the grid's heights (C², so the slope is defined everywhere and is
    the spline's gradient).

    ``heights[j, i]`` is the height at (x0 + i·cell_size, y0 + j·cell_size): row 0 is the
    grid's lowest y (a GeoTIFF's rows run north to south, so pass ``raster[::-1]`` with y0
    its southern row's centre). Outside the grid the edge heights extend level (gradient 0).
    A scene over real terrain is ``Scene(name, (GridRelief(...),), obstacles, region=...)``
    with a region inside the grid.
    """

    heights: np.ndarray
    cell_size: float
    x0: float = 0.0
    y0: float = 0.0

    def __post_init__(self):
        from scipy.interpolate import RectBivariateSpline

        heights = np.asarray(self.heights, dtype=np.float64)
        if heights.ndim != 2 or min(heights.shape) < 4:
            raise InputError(f"GridRelief needs a 2-D grid of at least 4 x 4 heights; got "
                             f"shape {heights.shape}")
        if not np.isfinite(heights).all():
            raise InputError("GridRelief needs finite heights everywhere (fill the raster's "
                             "no-data cells first)")
        if not (math.isfinite(self.cell_size) and self.cell_size > 0):
            raise InputError(f"GridRelief cell_size must be positive; got {self.cell_size}")
        ys = self.y0 + self.cell_size * np.arange(heights.shape[0])
        xs = self.x0 + self.cell_size * np.arange(heights.shape[1])
        object.__setattr__(self, "heights", heights)
        object.__setattr__(self, "_spline", RectBivariateSpline(ys, xs, heights, kx=3, ky=3, s=0))
        object.__setattr__(self, "_bounds", (xs[0], xs[-1], ys[0], ys[-1]))

    def _inside(self, x, y):
        x_min, x_max, y_min, y_max = self._bounds
        xc, yc = np.clip(x, x_min, x_max), np.clip(y, y_min, y_max)
        return xc, yc, xc == x, yc == y

    def height(self, x, y):
        xc, yc, _, _ = self._inside(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return self._spline.ev(yc, xc)

    def gradient(self, x, y):
        xc, yc, in_x, in_y = self._inside(np.asarray(x, dtype=np.float64),
                                          np.asarray(y, dtype=np.float64))
        gx = np.where(in_x, self._spline.ev(yc, xc, dy=1), 0.0)
        gy = np.where(in_y, self._spline.ev(yc, xc, dx=1), 0.0)
        return gx, gy


Feature = Plane | Hill | Ridge | Ramp | Valley | Roughness | GridRelief
