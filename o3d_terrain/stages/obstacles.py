"""ObstacleDetector and TraversabilityCost stages; WriteObstacles and WriteCostMap writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..frame import Frame
from ..obstacles import CLUSTER_IDS, CLUSTER_METHODS, detect_obstacles
from ..options import NON_NEGATIVE, POSITIVE, UNIT_INTERVAL, Range, option
from ..traversability import load_vehicle_profile, traversability_cost
from ..writers import Writer, writer
from .base import Stage, stage
from .grid_quantize import check_region

COSTS = "costs"


@stage
class ObstacleDetector(Stage):
    """Cluster the points labelled obstacle into obstacles with boxes, heights and point indices.

    Uses the ``labels`` and ``heights_above_terrain`` attributes of the Segmenter when present;
    otherwise heights come from the ``surface`` and a point is an obstacle point when it is
    more than ``threshold`` above it. Writes the ``obstacles`` product (an ObstacleSet) and the
    per-point ``cluster_ids`` (obstacle id, -1 for none). See docs/obstacles.md.
    """

    reads = ("surface",)
    writes = ("obstacles",)
    writes_attributes = (CLUSTER_IDS,)

    method: str = option("grid", choices=CLUSTER_METHODS,
                         help="grid: 8-connected cells of cell_size; dbscan: Open3D DBSCAN "
                              "with radius eps (slower)")
    cell_size: float = option(0.3, unit="m", rule=POSITIVE,
                              help="grid method: cell side; gaps narrower than a cell are bridged")
    eps: float = option(0.5, unit="m", rule=POSITIVE, help="dbscan method: neighbour radius")
    min_points: int = option(5, rule=Range(1, None), help="fewest points an obstacle may have")
    min_height: float = option(0.3, unit="m", rule=NON_NEGATIVE,
                               help="lowest top height above the terrain an obstacle may have")
    max_height: float = option(None, kind=float, unit="m", rule=POSITIVE,
                               help="obstacle points higher above the terrain are left out "
                                    "(overhangs); null keeps all")
    threshold: float = option(0.2, unit="m", rule=POSITIVE,
                              help="height above the surface that makes a point an obstacle "
                                   "point when the cloud has no labels")

    def run(self, frame: Frame) -> Frame:
        obstacles = detect_obstacles(
            frame, surface=frame.product("surface"), method=self.method,
            cell_size=self.cell_size, eps=self.eps, min_points=self.min_points,
            min_height=self.min_height, max_height=self.max_height, threshold=self.threshold)
        frame = frame.with_attributes(**{CLUSTER_IDS: obstacles.cluster_ids})
        frame = frame.with_products(obstacles=obstacles)
        return frame.with_note(f"{self.type_name}: {len(obstacles)} obstacle(s)")


def _check_vehicle(value) -> str | None:
    try:
        load_vehicle_profile(value)
    except InputError as exc:
        return f"names no usable vehicle profile: {exc}"
    return None


@stage
class TraversabilityCost(Stage):
    """Traversability cost map from slope, step height, roughness and occupancy for a vehicle.

    Slope comes from the surface's derivatives; step and roughness from the points' heights
    above the surface; occupancy from the ``obstacles`` product when an ObstacleDetector ran.
    Cells without any point are UNKNOWN at ``unknown_cost`` (no work is spent on them). Lethal
    cells are inflated by the vehicle footprint. Writes the ``cost_map`` product (a CostMap)
    and the per-point ``costs`` (cost of the cell under the point). The formula is in
    docs/obstacles.md.
    """

    reads = ("surface",)
    writes = ("cost_map",)
    writes_attributes = (COSTS,)

    vehicle: str = option("offroad_suv", kind=str, check=_check_vehicle,
                          help="built-in vehicle profile (offroad_suv, haul_truck, small_ugv) or "
                               "a path to a profile .yaml")
    max_slope_deg: float = option(None, kind=float, unit="deg", rule=Range(0, 90, True, True),
                                  help="override the profile's maximum slope; null = profile")
    max_step_height: float = option(None, kind=float, unit="m", rule=POSITIVE,
                                    help="override the profile's maximum step; null = profile")
    ground_clearance: float = option(None, kind=float, unit="m", rule=POSITIVE,
                                     help="override the profile's ground clearance; null = profile")
    cell_size: float = option(0.25, unit="m", rule=POSITIVE, help="cost map cell side")
    region: tuple = option(None, kind=float, length=4, nullable=True, unit="m",
                           check=check_region,
                           help="x_min, x_max, y_min, y_max of the map; null = the surface's region")
    unknown_cost: float = option(0.5, rule=UNIT_INTERVAL,
                                 help="cost of a cell without any point (UNKNOWN)")
    slope_weight: float = option(0.5, rule=NON_NEGATIVE, help="weight of the slope term")
    step_weight: float = option(0.3, rule=NON_NEGATIVE, help="weight of the step-height term")
    roughness_weight: float = option(0.2, rule=NON_NEGATIVE, help="weight of the roughness term")
    inflation_scale: float = option(0.5, unit="m", rule=POSITIVE,
                                    help="decay length of the inflated cost beyond the "
                                         "inscribed radius")
    fill_obstacle_boxes: bool = option(True, help="mark each obstacle's whole oriented box "
                                                  "occupied, not only the cells of its points")

    def check_options(self) -> list[str]:
        if self.slope_weight + self.step_weight + self.roughness_weight <= 0:
            return ["slope_weight + step_weight + roughness_weight must be > 0"]
        return []

    def profile(self):
        """The vehicle profile with this stage's overrides."""
        return load_vehicle_profile(self.vehicle).replace(
            max_slope_deg=self.max_slope_deg, max_step_height=self.max_step_height,
            ground_clearance=self.ground_clearance)

    def run(self, frame: Frame) -> Frame:
        cost_map = traversability_cost(
            frame.product("surface"), frame, vehicle=self.profile(), cell_size=self.cell_size,
            region=self.region, obstacles=frame.products.get("obstacles"),
            fill_obstacle_boxes=self.fill_obstacle_boxes, unknown_cost=self.unknown_cost,
            weights=(self.slope_weight, self.step_weight, self.roughness_weight),
            inflation_scale=self.inflation_scale)
        positions = frame.positions
        costs = cost_map.cost_at(positions[:, 0], positions[:, 1]) if len(frame) else np.zeros(0)
        frame = frame.with_attributes(**{COSTS: costs.astype(np.float32)})
        lethal = int(cost_map.lethal.sum())
        return frame.with_products(cost_map=cost_map).with_note(
            f"{self.type_name}: {cost_map.shape[0]} x {cost_map.shape[1]} cells, {lethal} lethal "
            f"or inscribed")


@writer
class WriteObstacles(Writer):
    """Write the obstacles (ids, point counts, centroids, boxes, heights) as JSON."""

    path: str = option("obstacles.json", kind="path", help="file name (.json)")
    include_indices: bool = option(False, help="also write each obstacle's point indices")

    def required_products(self) -> tuple[str, ...]:
        return ("obstacles",)

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        target = self._target(out_dir, self.path)
        frame.product("obstacles").save(target, include_indices=self.include_indices)
        return [target]


@writer
class WriteCostMap(Writer):
    """Write a PNG of the cost map with a legend (free, inscribed, lethal, unknown)."""

    path: str = option("cost_map.png", kind="path", help="image file name (.png)")
    draw_obstacles: bool = option(True, help="outline the obstacles' boxes when present")

    def required_products(self) -> tuple[str, ...]:
        return ("cost_map",)

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        from .. import io

        cost_map = frame.product("cost_map")
        obstacles = frame.products.get("obstacles") if self.draw_obstacles else None
        image = cost_map.render_image(obstacles=obstacles)
        return [io.write_image(self._target(out_dir, self.path), image)]

