"""Terrain stages: RationalBSplineTerrain (fit), SlopeEstimator (derivation), Segmenter."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import warn
from ..faces import FACE_RUN, face_limit, face_run, planar_cells
from ..frame import (
    HEIGHTS_ABOVE_TERRAIN,
    LABELS,
    NUMBER_OF_RETURNS_ALIASES,
    RETURN_NUMBERS_ALIASES,
    SLOPES_DEG,
    Frame,
)
from ..grid import (HeightGrid, grown_cell, requantize, with_cell_planes, without_low_returns,
                    without_overhead)
from ..ground_layer import default_layer
from ..level import upside_down_hint
from ..noise import RangeNoise
from ..options import NON_NEGATIVE, POSITIVE, Range, option
from ..refine import (
    REFINE_MAX_CONTROL_POINTS,
    STEEP_REFINE_MAX_CONTROL_POINTS,
    STEEP_SHARE,
    refine_surface,
    steep_share,
)
from ..segment import (
    FOOT_BEHIND,
    FOOT_CELL,
    FOOT_GAP,
    FOOT_HEIGHT,
    FOOT_LINES,
    GROUND_RETURNS,
    TerrainLabel,
    earlier_returns,
    keep_last_returns,
    segment_points,
    sensor_in_cloud,
)
from ..spline import TerrainSurface
from ..terrain import (
    KNOT_PLACEMENTS,
    MAX_SLOPE_DEG,
    METHODS,
    NOISE_FLOOR,
    STEEP_LIMIT_SHARE,
    STEEP_MAX_SLOPE_DEG,
    TOP_DOWN_MAX_CONTROL_POINTS,
    TerrainFit,
    default_control_points,
    fit_grid_detailed,
    sensor_ground_plane,
)
from .base import Stage, stage


def earlier_returns_of(frame: Frame) -> np.ndarray | None:
    """(N,) bool: the frame's points that are not the last return of their pulse
    (:func:`~o3d_terrain.segment.earlier_returns`); None when its cloud carries no return
    numbers."""
    numbers = [next((n for n in names if frame.has_attribute(n)), None)
               for names in (RETURN_NUMBERS_ALIASES, NUMBER_OF_RETURNS_ALIASES)]
    if None in numbers:
        return None
    return earlier_returns(*(frame.attribute(n) for n in numbers))


def _check_control_points(value):
    if value is not None and min(value) < 2:
        return "must be at least degree + 1 per axis"
    return None


@stage
class RationalBSplineTerrain(Stage):
    """Fit a rational B-spline terrain surface to the height grid (Broggi et al. 2013, Sec. V).

    Iterative re-weighted least squares with rational control-point weights and equalization,
    growing the control grid from coarse to fine. ``method: robust`` (default) adds bounded
    asymmetric weights, a thin-plate penalty for cells without data and a consistent rational
    fit; ``method: paper`` runs Algorithm V-B.1 as printed (see docs/algorithm.md). With
    ``refine`` (default) the robust fit's surface is then fitted again to the points its
    automatic labels call terrain, and again from the refit's own labels while that moves it
    (o3d_terrain.refine; docs/algorithm.md, "Refit on the terrain points", "The refit made
    again").
    """

    reads = ("grid",)
    writes = ("surface", "terrain_fit")

    control_points: tuple = option(
        None, kind=int, length=2, broadcast=True, nullable=True, rule=Range(2, 1000),
        check=_check_control_points,
        help="control points per axis at the end of the growth; null = about one every "
             "2 cells (at least 1 m), at most 32 per axis (48 on a top-down scan: an airborne "
             "tile with no points near sensor_origin), or one every 6 m (at most 192) where "
             "that would leave them farther apart; on a vehicle's scan one axis's spacing is "
             "at least 1/1.5 of the other's; the refit (refine) then takes up to 40 "
             "per axis (64 on a vehicle's scan of steep relief or of bench faces); a layout "
             "given here is the refit's too",
    )
    degree: int = option(3, rule=Range(1, 5), help="polynomial degree of the B-spline basis")
    method: str = option("robust", choices=METHODS,
                         help="'robust' (default) or 'paper' (Algorithm V-B.1 as printed)")
    smoothing: float = option(0.05, rule=NON_NEGATIVE,
                              help="thin-plate penalty relative to the data weight per control "
                                   "point; keeps areas without data bounded")
    noise_floor: float = option(NOISE_FLOOR, unit="m", rule=NON_NEGATIVE,
                                help="smallest noise threshold of the robust weights")
    rational: bool = option(True, help="derive control-point weights R from the sample weights")
    terrain_prior: bool = option(
        True,
        help="robust method: cells connected to the ground under the slope limit whose points "
             "have no vertical extent beyond the local terrain rise are not rejected as "
             "obstacles (steep berms, ditch walls); false = plain robust weights",
    )
    max_slope_deg: float | None = option(
        None, kind=float, nullable=True, unit="deg", rule=Range(1, 89),
        help="terrain_prior: steepest terrain the prior accepts; null = 45, or 60 on a "
             "vehicle's scan of strong relief (slopes that change, not a tilt: "
             "o3d_terrain.refine.steep_share of the coarse layouts' surface at least 0.35), "
             "where the fit then starts again, or the faces' tilt + 5 (60 to 70) on a "
             "vehicle's scan of a bench face (planar cells 50-75 deg from the ground around "
             "the sensor in a run of 10 m or more: o3d_terrain.faces); give it for faces that "
             "are terrain to you and steeper than that (docs/algorithm.md, 'Steep slopes and "
             "faces', 'Bench faces')")
    gap_slope_deg: float = option(20.0, unit="deg", rule=Range(0, 89),
                                  help="terrain_prior: slope of the cone that crosses empty cells")
    max_obstacle_width: float = option(40.0, unit="m", rule=POSITIVE,
                                       help="terrain_prior: widest obstacle, sets the seed "
                                            "search window")
    ground_layer: bool = option(
        True,
        help="robust method: a cell whose points form a layer just above its lowest point "
             "under an object (canopy, wall) gives the fit the layer's height instead of "
             "eq. 1's lifted sample (o3d_terrain.ground_layer)",
    )
    cell_plane: bool = option(
        True,
        help="robust method with terrain_prior: in cells whose points are all terrain (the "
             "prior's compact cells) eq. 1 about the least-squares plane of the "
             "points where its tilt is significant and spreads them by more than noise_floor "
             "(sample = the plane's height at the cell centre minus the spread about it), not "
             "about their mean, which sits about rise / sqrt(12) low on slopes; needs the "
             "points; false = eq. 1 everywhere (docs/algorithm.md, 'Eq. 1 with the in-cell "
             "slope removed')",
    )

    refine: bool = option(
        True,
        help="robust method, with the points: label them against the fitted surface (the "
             "automatic rule of Segmenter) and fit the same layout again to the terrain points "
             "alone, eq. 1 about each cell's plane at most noise_floor below it, and again "
             "from its own labels while a refit moves the surface by 0.4 noise_floor or more "
             "at the median terrain cell (at most twice more); removes the robust fit's "
             "wobble between sparse scan lines and its bias under noisy cells, and the ground "
             "it lost beside relief its layout cannot follow (o3d_terrain.refine); not with a "
             "range-noise model, whose per-cell noise the robust fit weighs; false = the "
             "robust fit's surface",
    )
    low_returns: bool = option(
        True,
        help="robust method, a vehicle's scan (points around sensor_origin): when at least "
             "2 % of the measured cells have an isolated low point (more than 0.3 m below the "
             "thin layer of the cell's other points: a return from below the ground, "
             "multipath off a wet road or glass), fit without the points more than 0.3 m "
             "below the thin layer of their cell (its median); they are still labelled "
             "(docs/algorithm.md, 'Returns from below the ground'); false = fit every point",
    )
    free_space: bool = option(
        True,
        help="robust method, a vehicle's scan (points around sensor_origin): fit without the "
             "cells whose lowest point lies more than 0.5 m (plus a 45 degree rise across "
             "its azimuth sector, about half a degree) above where rays of the scan passed "
             "on their way to farther returns: the underside of a ceiling, a roof or a canopy "
             "that rays went under, where no ground can be; their points are still labelled "
             "(o3d_terrain.grid.overhead_cells; docs/algorithm.md, 'Free space under the "
             "rays'); only where sensor_origin stands 0.3 m or more over the ground 2-10 m "
             "around it (the rays need the sensor's position); false = fit every cell",
    )
    range_noise: float = option(
        0.0, unit="1/m", rule=NON_NEGATIVE,
        help="range-dependent sensor noise: noise along the viewing ray = range_noise * "
             "range^2 (stereo: disparity noise px / (focal px * baseline m)); 0 = use the "
             "frame's 'range_noise' product when a source made one (StereoToCloud with "
             "disparity_noise_px), else one noise scale for all cells (o3d_terrain.noise)")
    sensor_origin: tuple = option((0.0, 0.0, 0.0), kind=float, length=3, unit="m",
                                  help="sensor position in cloud coordinates, for range_noise, "
                                       "refine's labels and the terrain prior (the ground "
                                       "around it gives level when the sensor is tilted, and "
                                       "seeds the terrain: the vehicle stands on it)")
    grow_cells: bool = option(
        True,
        help="robust method, a top-down scan (no points near sensor_origin: an airborne "
             "tile): where most of its points lie, a cell of the grid should hold about 3 "
             "points, so that one under vegetation also holds a return from the ground; on a "
             "scan too sparse for the grid's cells the fit uses cells grown to hold that "
             "many (at most 3 m; o3d_terrain.grid.grown_cell; docs/algorithm.md, 'Cells for "
             "a sparse top-down scan'); false = the grid's cells",
    )
    ground_returns: str = option(
        "last", choices=GROUND_RETURNS,
        help="with a cloud that carries return_numbers and number_of_returns (a LAS/LAZ "
             "file's): 'last' = fit the terrain to the last return of each pulse only (a "
             "pulse that went on past a point did not stop at the ground there), as PDAL's "
             "ground filters default to; 'all' = fit every return",
    )
    knots: str = option(
        "auto", choices=("auto",) + KNOT_PLACEMENTS,
        help="robust method: 'adaptive' knot spans, narrower where the grid has more "
             "measured cells (near a vehicle's sensor) and wider where it has few, when the "
             "control-point cap leaves the uniform spacing over 1.5 times 2 cells (a wide "
             "frame); 'uniform' spans; 'auto' = uniform on a top-down scan (no points near "
             "sensor_origin: an airborne tile), else adaptive (docs/algorithm.md, 'Knots "
             "where the data are')")

    def check_options(self) -> list[str]:
        if self.control_points is not None and min(self.control_points) < self.degree + 1:
            return [f"control_points {self.control_points} must be >= degree + 1 = "
                    f"{self.degree + 1} per axis"]
        return []

    def run(self, frame: Frame) -> Frame:
        grid, positions = frame.product("grid"), frame.positions
        earlier = earlier_returns_of(frame) if self.ground_returns == "last" else None
        left_out = 0 if earlier is None else int(earlier.sum())
        if left_out and left_out < len(positions):
            # the grid again from the last returns (the one made from every return holds
            # canopy that the pulses went on past)
            positions = np.ascontiguousarray(positions[~earlier])
            grid = requantize(grid, positions)
        fit = self.fit(grid, positions, frame.products.get("range_noise"))
        frame = frame.with_products(surface=fit.surface, terrain_fit=fit)
        if left_out:
            frame = frame.with_note(
                f"{self.type_name}: fitted without {left_out} earlier return(s) of a pulse "
                f"(ground_returns)")
        if fit.low_returns:
            frame = frame.with_note(
                f"{self.type_name}: fitted without {fit.low_returns} isolated low return(s), "
                f"from below the ground (low_returns)")
        if fit.overhead:
            frame = frame.with_note(
                f"{self.type_name}: fitted without {fit.overhead} point(s) over where rays went "
                f"on to farther returns, in cells of nothing lower (free_space)")
        return frame

    def fit(self, grid: HeightGrid, positions: np.ndarray | None = None,
            range_noise: RangeNoise | None = None, *, line_spacing=None) -> TerrainFit:
        """The fit of :meth:`run` on a height grid; ``positions`` (the points the grid was
        made from) give the ground-layer samples, the cells' planes with ``cell_plane`` when
        the grid was made without them, and, with a noise model (this stage's
        ``range_noise`` option, else ``range_noise``), the per-cell noise. The surface carries
        the grid's cell size. ``line_spacing``: the
        :func:`~o3d_terrain.segment.scan_line_spacing` of ``positions`` seen from this
        stage's ``sensor_origin``, for the refit's labels, when the caller has it (a function
        that finds it when first asked, :func:`~o3d_terrain.segment.line_spacing_finder`,
        which the caller may pass on to the Segmenter's labels of the same points); not used
        when the fit leaves low returns out (other points)."""
        if self.range_noise > 0:
            range_noise = RangeNoise(self.sensor_origin, self.range_noise)
        robust = positions is not None and self.method == "robust"
        # a vehicle's scan (points around sensor_origin) or a top-down one (an airborne tile)
        top_down = robust and not sensor_in_cloud(positions, self.sensor_origin)
        cell_size = grid.cell_size  # the refit's and the surface's (rasters)
        if top_down and self.grow_cells:
            cell = grown_cell(grid)
            if cell > grid.cell_size:
                layer = default_layer(cell, noise_floor=self.noise_floor,
                                      max_slope_deg=self.slope_limit) if grid.layer else 0.0
                grid = requantize(grid, positions, cell_size=cell, layer=layer)
        low_returns = None
        if robust and not top_down and self.low_returns:
            grid, positions, low_returns = without_low_returns(grid, positions)
            if low_returns:  # the caller's scan-line spacing is of the points before
                line_spacing = None
        overhead = None
        if robust and not top_down and self.free_space:
            # the caller's scan-line spacing stays: the points left out lie over rays that
            # went on past them, off the faces it is measured on
            grid, positions, overhead = without_overhead(grid, positions, self.sensor_origin)
        if self.cell_plane:  # the grid as it is when it carries planes of this noise floor
            grid = with_cell_planes(grid, positions, tilt_spread=self.noise_floor)
        control_points = self.control_points
        if positions is not None:
            hint = upside_down_hint(positions, self.sensor_origin)
            if hint:
                warn(f"{self.type_name}: {hint}")
        if control_points is None and top_down:
            # a top-down scan (an airborne tile) is not fitted at a vehicle's frame rate
            control_points = default_control_points(grid, self.degree,
                                                    most=TOP_DOWN_MAX_CONTROL_POINTS,
                                                    max_aspect=None)
        knots = self.knots
        if knots == "auto":
            knots = "uniform" if top_down else "adaptive"
        options = dict(
            control_points=control_points, degree=self.degree,
            method=self.method, smoothing=self.smoothing, noise_floor=self.noise_floor,
            rational=self.rational, terrain_prior=self.terrain_prior,
            max_slope_deg=self.slope_limit, gap_slope_deg=self.gap_slope_deg,
            max_obstacle_width=self.max_obstacle_width,
            positions=positions if self.ground_layer else None,
            ground_layer=self.ground_layer, range_noise=range_noise,
            cell_plane=self.cell_plane, sensor_origin=self.sensor_origin, knots=knots,
        )
        # with a range-noise model the loop already weighs each cell's noise, which the refit
        # (one weight per cell) would not: measured on the synthetic stereo scenes, the refit
        # helps their fit without the model (RMSE 0.10 -> 0.08 m on hills) and not with it
        refit = self.refine and robust and range_noise is None
        auto_slope = self.max_slope_deg is None and self.terrain_prior
        vehicle = robust and not top_down
        # a vehicle's scan of relief: with a long bench face in its points the prior's
        # automatic slope limit is the faces' own from the start; on strong relief, seen by the
        # coarse layouts already, it rises and the fit starts again; on steep relief the
        # refit's automatic layout grows (docs/algorithm.md, "Bench faces", "A steeper slope
        # limit on strong relief", "A finer refit on steep relief")
        run = None
        faces = False  # a long bench face in the scan
        if vehicle and auto_slope:
            gx, gy = sensor_ground_plane(grid, self.sensor_origin)
            run, tilt = face_run(planar_cells(grid, positions), (-gx, -gy, 1.0))
            faces = run >= FACE_RUN
            if faces:
                options["max_slope_deg"] = face_limit(tilt)
        coarse_share = []

        def strong_relief(coarse: TerrainSurface) -> bool:
            coarse_share.append(steep_share(coarse, grid))
            return coarse_share[-1] >= STEEP_LIMIT_SHARE

        # the relief rule decides where no face did
        relief_rule = run is not None and not faces
        fit = fit_grid_detailed(grid, **options, stop_after_coarse=strong_relief if relief_rule
                                else None)
        share = coarse_share[-1] if coarse_share else None
        if fit is None:
            fit = fit_grid_detailed(grid, **dict(options, max_slope_deg=STEEP_MAX_SLOPE_DEG))
        elif vehicle and refit and self.control_points is None:
            share = steep_share(fit.surface, grid)  # the refit's layout: the final surface's
        # steep relief for the refit's layout: a share of the ground whose slope changes, or a
        # long bench face (its berms and toes are slopes that change within a few metres,
        # over too few cells to make a share; docs/algorithm.md, "A pit's faces and a raised
        # road's top at the grid's axes")
        steep = (share is not None and share >= STEEP_SHARE) or faces
        surface = dataclasses.replace(fit.surface, cell_size=cell_size)
        fit = dataclasses.replace(fit, relief_share=share, face_run=run, low_returns=low_returns,
                                  overhead=overhead)
        if not refit:
            return dataclasses.replace(fit, surface=surface)
        # an automatic layout may grow for the refit's solve (o3d_terrain.refine), more on
        # steep relief; a layout the user chose stays
        most = None
        if self.control_points is None:
            most = STEEP_REFINE_MAX_CONTROL_POINTS if steep else REFINE_MAX_CONTROL_POINTS
        refined, _, refits = refine_surface(
            surface, positions, cell_size=cell_size, smoothing=self.smoothing,
            noise_floor=self.noise_floor, sensor_origin=self.sensor_origin,
            cell_plane=self.cell_plane, max_control_points=most, vehicle=vehicle,
            top_down=top_down, line_spacing=line_spacing)
        return dataclasses.replace(fit, surface=refined, robust_surface=surface, refits=refits)

    @property
    def slope_limit(self) -> float:
        """The prior's slope limit before the scan is looked at (deg): ``max_slope_deg``, or
        :data:`~o3d_terrain.terrain.MAX_SLOPE_DEG` when that is automatic (null)."""
        return MAX_SLOPE_DEG if self.max_slope_deg is None else float(self.max_slope_deg)


@stage
class SlopeEstimator(Stage):
    """Slope of the terrain surface by analytic derivation, per point and as a grid.

    Writes the per-point attribute ``slopes_deg`` (slope of the terrain under each point,
    NaN outside the surface's region) and the product ``slope_grid``, a SlopeGrid: slope in
    degrees at cell centres (``slope_deg[ix, iy]``, ``x_centers``, ``y_centers``), which
    WriteImage draws and WriteProduct saves.
    """

    reads = ("surface",)
    writes = ("slope_grid",)
    writes_attributes = (SLOPES_DEG,)

    cell_size: float = option(0.5, unit="m", rule=POSITIVE, help="cell side of the slope grid")

    def run(self, frame: Frame) -> Frame:
        surface = frame.product("surface")
        p = frame.positions
        slopes = surface.slope_deg(p[:, 0], p[:, 1]) if len(p) else np.zeros(0)
        frame = frame.with_attributes(**{SLOPES_DEG: slopes.astype(np.float64)[:, None]})
        return frame.with_products(slope_grid=surface.slope_grid(self.cell_size))


@stage
class Segmenter(Stage):
    """Label points against the terrain surface: terrain, obstacle, below-terrain noise.

    Height above terrain h = z - S(x, y). TERRAIN (1) when -below_threshold <= h <= t(r),
    OBSTACLE (2) above, BELOW_TERRAIN (3) below, UNKNOWN (0) for non-finite points and
    points outside the surface's region; t(r) = threshold + range_coefficient * r^2 with r the
    horizontal range from sensor_origin (stereo depth noise grows with range squared). With
    along_normal both thresholds are distances along the surface normal: on a slope theta
    they are 1 / cos(theta) times larger vertically (at most twice, a 60 degree face).
    Then the feet of objects: TERRAIN points in a foot_cell x foot_cell column whose points are
    for a good part (30 %) OBSTACLE points less than foot_height above the terrain, standing
    out of the local noise, next to an object at least 0.35 m high, are the base of that
    object (a bush, a wall, a wheel) and become OBSTACLE (o3d_terrain.segment.mark_object_feet).
    On a rotating lidar's scan the foot height grows with range to foot_lines times the
    height between its neighbouring scan lines on a vertical face (at most 1.5 m), where the
    lowest return on an object lies that far above the ground return before it; and terrain
    points within foot_behind of such a low obstacle point beside an object, 0.13 m or more
    farther from the sensor, lie behind the object's low part and become OBSTACLE too. A
    column whose lowest obstacle point lies more than foot_gap above its terrain points is
    free space under an overhang (a car's body) and no foot. Where the sensor scans the
    ground around it, terrain points above it that the surface would hide from it (an object
    beyond a crest whose own ground is not seen) become OBSTACLE (line_of_sight).
    """

    reads = ("surface",)
    writes_attributes = (LABELS, HEIGHTS_ABOVE_TERRAIN)

    threshold: float = option(None, kind=float, nullable=True, unit="m", rule=POSITIVE,
                              help="height above the terrain that makes a point an obstacle; "
                                   "null (default, as segment_terrain) = from the data: 3.5 "
                                   "times the robust noise of the points below the surface, "
                                   "at least the ground's centre plus 2.5 times its noise "
                                   "where the surface lies under that centre, in [0.13, 0.5] "
                                   "m, widened where the surface misfits (misfit_threshold)")
    below_threshold: float = option(0.5, unit="m", rule=POSITIVE,
                                    help="depth below the terrain that makes a point noise")
    range_coefficient: float = option(
        None, kind=float, nullable=True, unit="1/m", rule=NON_NEGATIVE,
        help="threshold growth per squared metre of range; null (default) = from the data "
             "when threshold is null (grows only where the noise below the surface grows "
             "steadily with range, as a stereo camera's; 0 for a lidar), else 0")
    sensor_origin: tuple = option((0.0, 0.0, 0.0), kind=float, length=3, unit="m",
                                  help="sensor position for the range, in cloud coordinates")
    misfit_threshold: bool = option(
        True,
        help="with threshold null: where 1 m cells lie below the surface by more than the "
             "noise (terrain the control spacing cannot follow), widen the threshold there, "
             "both sides, up to 1.5 m (o3d_terrain.misfit)",
    )
    along_normal: bool = option(
        True,
        help="measure threshold and below_threshold along the surface normal: vertically "
             "they grow by sqrt(1 + slope^2), at most x2 (a 60 deg face), where the terrain "
             "slopes; false = vertical (o3d_terrain.segment.relabel_along_normal)",
    )
    foot_height: float = option(
        FOOT_HEIGHT, unit="m", rule=NON_NEGATIVE,
        help="terrain points in a foot_cell column whose points are for 30 % or more obstacle "
             "points less than this high above the terrain (above the local noise, next to an "
             "object at least 0.35 m high) are the foot of that object and become obstacles; "
             "0 = off (o3d_terrain.segment.mark_object_feet)",
    )
    foot_cell: float = option(FOOT_CELL, unit="m", rule=POSITIVE,
                              help="side of the x/y columns of foot_height")
    foot_lines: float = option(
        FOOT_LINES, rule=NON_NEGATIVE,
        help="on a rotating lidar's scan around sensor_origin, foot_height grows with range r "
             "to this many times r * tan(angle between neighbouring scan lines, found from "
             "the points), at most 1.5 m: a sparse lidar's lowest return on an object at "
             "range lies that far above the ground; 0 = foot_height at every range "
             "(o3d_terrain.segment.scan_line_spacing)",
    )
    foot_behind: float = option(
        FOOT_BEHIND, unit="m", rule=NON_NEGATIVE,
        help="on a lidar's scan (scan lines found, noise not growing with range), terrain "
             "points within this x/y distance of an obstacle point below the foot height "
             "beside an object, and 0.13 m or more farther from the sensor, lie behind the "
             "object's low part (its base, or ground under its overhang) and become "
             "obstacles; 0 = off",
    )
    foot_gap: float = option(
        FOOT_GAP, unit="m", rule=NON_NEGATIVE,
        help="a foot_cell column whose lowest obstacle point lies more than this (or "
             "foot_lines scan-line gaps at its range) above its highest terrain point is free "
             "space under an overhang (a car's body, a branch), not the foot of an object: its "
             "ground stays terrain; 0 = off",
    )
    line_of_sight: bool = option(
        True,
        help="where the sensor scans the ground around sensor_origin, terrain points above "
             "the sensor that the surface would hide from it (it rises along the line of "
             "sight less steeply than the line, by over 5 deg) become obstacles: an object "
             "beyond a crest or a hill whose own ground is not seen "
             "(o3d_terrain.segment.out_of_sight)",
    )
    ground_returns: str = option(
        "last", choices=GROUND_RETURNS,
        help="with a cloud that carries return_numbers and number_of_returns (a LAS/LAZ "
             "file's, o3d_terrain.read_cloud; PDAL's ReturnNumber and NumberOfReturns of a "
             "PLY/PCD file too): 'last' = a point that is not the last return "
             "of its pulse is never terrain (the pulse went on past it: a canopy, a wire, a "
             "roof's edge), as PDAL's ground filters default to; 'all' = every return may be "
             "terrain (o3d_terrain.segment.earlier_returns)",
    )

    def run(self, frame: Frame) -> Frame:
        earlier = earlier_returns_of(frame) if self.ground_returns == "last" else None
        labels, heights = self.label(frame.product("surface"), frame.positions,
                                     earlier=earlier)
        frame = frame.with_attributes(**{LABELS: labels.astype(np.uint8)[:, None],
                                         HEIGHTS_ABOVE_TERRAIN: heights[:, None]})
        counts = np.bincount(labels, minlength=4)
        return frame.with_note(
            f"{self.type_name}: {counts[TerrainLabel.TERRAIN]} terrain, "
            f"{counts[TerrainLabel.OBSTACLE]} obstacle, {counts[TerrainLabel.BELOW_TERRAIN]} "
            f"below-terrain, {counts[TerrainLabel.UNKNOWN]} unknown point(s)"
            + ("" if earlier is None else
               f"; {int(earlier.sum())} earlier return(s) of a pulse, never terrain")
        )

    def label(self, surface, positions: np.ndarray, *, earlier: np.ndarray | None = None,
              line_spacing=None) -> tuple[np.ndarray, np.ndarray]:
        """Labels (N,) uint8 and heights above the terrain (N,) of (N, 3) positions: the
        rule of :meth:`run` (:func:`~o3d_terrain.segment.segment_points`); ``earlier``: (N,)
        bool, the points that are not the last return of their pulse
        (:func:`~o3d_terrain.segment.earlier_returns`), which are then never TERRAIN;
        ``line_spacing``: the scan-line spacing of ``positions`` seen from this stage's
        ``sensor_origin`` when the caller has it (segment_points' ``line_spacing``)."""
        labels, heights = segment_points(
            surface, positions, threshold=self.threshold, below_threshold=self.below_threshold,
            range_coefficient=self.range_coefficient, sensor_origin=self.sensor_origin,
            misfit=self.misfit_threshold, along_normal=self.along_normal,
            foot_height=self.foot_height, foot_cell=self.foot_cell, foot_lines=self.foot_lines,
            foot_behind=self.foot_behind, foot_gap=self.foot_gap,
            line_of_sight=self.line_of_sight, line_spacing=line_spacing)
        if earlier is not None:
            keep_last_returns(labels, earlier)
        return labels, heights
