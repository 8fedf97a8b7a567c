"""Range-dependent sensor noise: what a stereo rig (or any ranging sensor) tells the terrain fit.

A stereo point is found along its pixel's viewing ray at the depth f·B/d; a disparity error of
σ_d pixels moves it along that ray by about σ_ρ(ρ) = ρ² σ_d / (f B) at range ρ (exact on the
optical axis; up to 1/cos of the angle off the axis more at the image border, e.g. 18 % at the
corner of a 64° field of view). The terrain fit works with heights, so what matters is how
much such a move changes a point's height above the terrain S: with d the unit ray from the
sensor,

    σ_h = σ_ρ(ρ) · |d_z − S_x d_x − S_y d_y|

(on flat ground seen from height H this is σ_ρ H / ρ; on terrain rising away from the sensor,
or in a frame tilted with the camera, the slope term dominates).

:class:`RangeNoise` holds the sensor origin and the coefficient σ_d / (f B); :class:`GridNoise`
turns it into per-cell samples and noise scales of a :class:`~o3d_terrain.grid.HeightGrid`
under the surface fitted so far, which the robust fit uses
(:func:`o3d_terrain.terrain.fit_grid_detailed`, option ``range_noise``): eq. 1 discounts only
the spread of a cell's points that the sensor noise does not explain, and the robust weights
add each sample's own noise to their noise scale. Without a model the fit is unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .errors import InputError

__all__ = ["RangeNoise", "GridNoise", "height_sigma"]


@dataclass(frozen=True)
class RangeNoise:
    """Noise along the viewing ray σ_ρ = ``coefficient`` · ρ² (metres) of a sensor at
    ``sensor_origin`` (x, y, z in the cloud's coordinates, metres).

    For a rectified stereo pair, coefficient = disparity noise (px) / (focal length (px) ·
    baseline (m)): :meth:`from_stereo`.
    """

    sensor_origin: tuple[float, float, float]
    coefficient: float

    def __post_init__(self):
        try:
            origin = tuple(float(v) for v in self.sensor_origin)
        except (TypeError, ValueError):
            origin = ()
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise InputError(f"RangeNoise: sensor_origin must be three finite numbers (x, y, z "
                             f"in metres), got {self.sensor_origin!r}")
        c = self.coefficient
        if isinstance(c, bool) or not isinstance(c, (int, float, np.integer, np.floating)) \
                or not math.isfinite(c) or c < 0:
            raise InputError(f"RangeNoise: coefficient must be a finite number >= 0 (1/m: "
                             f"noise along the ray per squared metre of range), got {c!r}")
        object.__setattr__(self, "sensor_origin", origin)
        object.__setattr__(self, "coefficient", float(c))

    @classmethod
    def from_stereo(cls, *, focal_px: float, baseline: float, disparity_noise_px: float,
                    sensor_origin: Sequence[float] = (0.0, 0.0, 0.0)) -> "RangeNoise":
        """The model of a rectified stereo pair: σ_ρ = ρ² σ_d / (f B)."""
        for name, value in (("focal_px", focal_px), ("baseline", baseline)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"RangeNoise.from_stereo: {name} must be a number > 0, "
                                 f"got {value!r}")
        return cls(tuple(sensor_origin), float(disparity_noise_px) / (focal_px * baseline))

    def range_sigma(self, positions: np.ndarray) -> np.ndarray:
        """(N,) noise along the ray σ_ρ (m) of (N, 3) positions."""
        d = np.asarray(positions, dtype=np.float64)[:, :3] - np.asarray(self.sensor_origin)
        return self.coefficient * np.einsum("ij,ij->i", d, d)


def height_sigma(model: RangeNoise, surface, positions: np.ndarray) -> np.ndarray:
    """(N,) height noise σ_h (m) of each point over the surface z = S(x, y) (a
    :class:`~o3d_terrain.spline.TerrainSurface`): σ_ρ(ρ) · |d_z − S_x d_x − S_y d_y| with d
    the unit ray from the sensor to the point; NaN where the surface is undefined."""
    p = np.asarray(positions, dtype=np.float64)[:, :3]
    d = p - np.asarray(model.sensor_origin)
    rho = np.sqrt(np.einsum("ij,ij->i", d, d))
    sx, sy = surface.gradient(p[:, 0], p[:, 1])
    along = np.abs(d[:, 2] - sx * d[:, 0] - sy * d[:, 1])  # = rho |d_z - S_x d_x - S_y d_y|
    return model.coefficient * rho * along


class GridNoise:
    """The sensor's noise on a height grid, for the robust loop: built once from the grid, the
    points and the model; :meth:`update` gives the samples and per-cell noise scales for the
    surface of the previous layout (the slope of the terrain sets how much of the move along
    the ray is a move in height)."""

    def __init__(self, grid, positions: np.ndarray, model: RangeNoise, samples: np.ndarray):
        p = np.asarray(positions, dtype=np.float64)
        cells = grid.cell_of(p[:, 0], p[:, 1])
        inside = cells >= 0
        cells = cells[inside]
        z = p[inside, 2]
        size = grid.nx * grid.ny
        n = np.maximum(np.bincount(cells, minlength=size).astype(np.float64), 1.0)
        mean = np.bincount(cells, weights=z, minlength=size) / n
        dz = z - mean[cells]
        shape = (grid.nx, grid.ny)
        self.spread = np.sqrt(np.bincount(cells, weights=dz * dz, minlength=size) / n).reshape(shape)
        self.mean = mean.reshape(shape)
        self.grid = grid
        self.model = model
        self.samples = samples
        if grid.lowest is None:
            raise InputError("GridNoise needs a grid with the lowest point per cell "
                             "(made by quantize_points)")
        self.use = (grid.count > 0) & (samples == grid.z)
        x, y = np.meshgrid(grid.x_centers, grid.y_centers, indexing="ij")
        self.dx = x - model.sensor_origin[0]
        self.dy = y - model.sensor_origin[1]

    def sigma(self, surface: np.ndarray) -> np.ndarray:
        """(nx, ny) height noise of each cell under the surface z = ``surface`` (world z on the
        grid): σ_h = coefficient · ρ² · |d_z − S_x d_x − S_y d_y| with d the unit ray."""
        c = self.grid.cell_size
        sx, sy = np.gradient(surface, c, c)
        dz = surface - self.model.sensor_origin[2]
        rho = np.sqrt(self.dx ** 2 + self.dy ** 2 + dz ** 2)
        factor = np.abs(dz - sx * self.dx - sy * self.dy) / np.maximum(rho, 1e-9)
        return self.model.coefficient * rho ** 2 * factor

    def update(self, surface: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(samples, sample_sigma) under the surface z = ``surface`` (world z on the grid):

        samples: eq. 1 discounting only the spread the sensor noise σ_h does not explain,
        max(lowest, mean − sqrt(max(spread² − σ_h², 0))), on cells whose sample is eq. 1's
        (a ground-layer sample is kept). Eq. 1's "− σ" is meant to discount obstacle points;
        a cell of pure terrain with range noise σ_h would otherwise sit σ_h low.
        sample_sigma: σ_h / sqrt(count), the noise of such a sample, on cells whose whole
        spread the sensor noise explains (spread <= σ_h: the sample is their mean; no sign
        of an object in the cell), else 0; the robust weights add it to their noise scale
        cell by cell, so a noisy far cell of terrain is not down-weighted for lying above the
        surface (which would pull the surface low) while a cell on an object face is."""
        sigma = self.sigma(surface)
        excess = np.sqrt(np.maximum(self.spread ** 2 - sigma ** 2, 0.0))
        corrected = np.maximum(self.grid.lowest, self.mean - excess)
        samples = np.where(self.use & np.isfinite(corrected), corrected, self.samples)
        count = self.grid.count
        noise_only = (count > 0) & (self.spread <= sigma)
        return samples, np.where(noise_only, sigma / np.sqrt(np.maximum(count, 1)), 0.0)
