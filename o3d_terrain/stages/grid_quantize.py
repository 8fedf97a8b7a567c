"""GridQuantize: points to a 2.5-D height grid (Broggi et al. 2013, Sec. IV, eq. 1)."""

from __future__ import annotations

import numpy as np

from ..errors import warn
from ..frame import Frame
from ..grid import HeightGrid, quantize_points
from ..ground_layer import default_layer
from ..level import up_axis_hint
from ..options import POSITIVE, Range, option
from ..terrain import NOISE_FLOOR
from .base import Stage, stage


def check_region(region):
    """Rule for a (x_min, x_max, y_min, y_max) option."""
    if region is not None and not (region[1] > region[0] and region[3] > region[2]):
        return "must have x_max > x_min and y_max > y_min"
    return None


@stage
class GridQuantize(Stage):
    """Quantize the cloud into a 2.5-D height grid: per cell Z = max(min z, mean z − σ).

    Cells without points take the mean of their measured neighbours (FILLED); with no measured
    neighbour they are INVALID with Z = 0 and carry no weight in the terrain fit. Non-finite
    points and points outside the region are skipped and counted in the frame's notes. The
    same pass also gathers what RationalBSplineTerrain's defaults read: the ground-layer
    statistics and each cell's least-squares plane (eq. 1 with the in-cell slope removed,
    its cell_plane option).
    """

    reads = ()
    writes = ("grid",)

    cell_size: float = option(0.5, unit="m", rule=POSITIVE, help="side of a square grid cell")
    region: tuple = option(
        None, kind=float, length=4, nullable=True, unit="m", check=check_region,
        help="x_min, x_max, y_min, y_max of the area of interest; null = the cloud's extent",
    )
    min_points: int = option(
        1, rule=Range(1, None), help="points a cell needs to be measured; fewer = empty cell"
    )
    fill_empty: bool = option(
        True, help="fill empty cells from the mean of measured 8-neighbours (the paper's rule)"
    )

    def run(self, frame: Frame) -> Frame:
        grid = self.grid(frame.positions)
        frame = frame.with_products(grid=grid)
        if grid.skipped_nonfinite:
            frame = frame.with_note(
                f"{self.type_name}: skipped {grid.skipped_nonfinite} non-finite point(s)")
        if grid.skipped_outside:
            frame = frame.with_note(
                f"{self.type_name}: {grid.skipped_outside} point(s) outside the region")
        return frame

    def grid(self, positions: np.ndarray, *, region=None, layer: float | None = None,
             plane: bool = True, tilt_spread: float = NOISE_FLOOR) -> HeightGrid:
        """The grid of :meth:`run` from (N, 3) positions. region: overrides the option (e.g.
        an extent already computed); layer: thickness of the ground-layer statistics
        gathered in the same pass (None = :func:`~o3d_terrain.ground_layer.default_layer`,
        what RationalBSplineTerrain's defaults use; 0 = none); plane, tilt_spread: also the
        cells' planes (:func:`quantize_points`; by default those RationalBSplineTerrain's
        defaults use, cell_plane with tilt_spread = its noise_floor). Warns
        (:class:`~o3d_terrain.errors.TerrainWarning`) when the cloud is clearly not z-up
        (:func:`~o3d_terrain.level.up_axis_hint`)."""
        hint = up_axis_hint(positions)
        if hint:
            warn(f"{self.type_name}: {hint}")
        return quantize_points(
            positions, cell_size=self.cell_size,
            region=self.region if region is None else region,
            min_points=self.min_points, fill_empty=self.fill_empty,
            layer=default_layer(self.cell_size) if layer is None else layer, plane=plane,
            tilt_spread=tilt_spread,
        )
