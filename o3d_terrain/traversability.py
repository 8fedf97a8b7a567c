"""Traversability cost map: slope, step height, roughness and occupancy for a vehicle profile.

Broggi et al. 2013 only outline it: a cost that grows with slope and with occupancy. Here each
square cell ``c`` of a grid over the terrain surface gets (the formula of docs/obstacles.md):

- slope θ(c) = atan |∇S| at the cell centre, from the surface's analytic derivatives;
- step s(c) = max(0, highest point above the surface in the cell) (m), over points up to
  ``vehicle_height`` above the terrain (higher ones are overhangs the vehicle passes under);
- roughness ρ(c) = RMS of the heights above the surface of the cell's points no higher than the
  lethal step (m);
- occupancy: the cell holds a point of a detected obstacle taller than the lethal step, or lies
  in such an obstacle's oriented box.

With the profile's θmax, lethal step s* = min(max_step_height, ground_clearance) (a wheel climbs
at most max_step_height, the belly clears at most ground_clearance) and ρmax:

    LETHAL            if θ > θmax or s > s* or occupied
    cost = (wθ (θ/θmax)² + ws (s/s*)² + wρ min(ρ/ρmax, 1)²) / (wθ + ws + wρ)   otherwise

Cells with no point are UNKNOWN: they cost ``unknown_cost``, have no slope, step or roughness
(NaN) and are lethal only when occupied; no work is spent on them beyond that fill. A
slope-only map (no cloud) is the exception: every cell is UNKNOWN with the slope of the surface,
cost max(slope term, ``unknown_cost``), and LETHAL over θmax. Lethal cells
are inflated by the footprint: a cell whose centre is within the inscribed radius (half the
width) of a lethal cell is INSCRIBED (cost 1: the vehicle's centre cannot be there); out to the
circumscribed radius the cost is at least 0.99 exp(-(d - r_in) / inflation_scale). Costs are in
[0, 1]; 1 means not traversable.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ._files import open_npz, output_path
from ._kernels import bspline as _bs
from ._kernels import obstacles as _k
from .errors import InputError, checked_keywords
from .frame import as_frame
from .segment import TerrainLabel

__all__ = ["VehicleProfile", "load_vehicle_profile", "vehicle_profile_names", "CostMap",
           "traversability_cost", "surface_on_grid", "VEHICLES_DIR",
           "UNKNOWN", "FREE", "INSCRIBED", "LETHAL"]


def _vehicles_dir() -> Path:
    """The built-in vehicle profiles: configs/vehicles/<name>.yaml in a source checkout,
    o3d_terrain/vehicles/ in an installed wheel (pyproject.toml ships the one as the other)."""
    here = Path(__file__).resolve()
    installed = here.parent / "vehicles"
    return installed if installed.is_dir() else here.parents[1] / "configs" / "vehicles"


#: built-in vehicle profiles (see _vehicles_dir)
VEHICLES_DIR = _vehicles_dir()

#: cell states of a cost map
UNKNOWN, FREE, INSCRIBED, LETHAL = 0, 1, 2, 3
STATE_NAMES = {UNKNOWN: "unknown", FREE: "free", INSCRIBED: "inscribed", LETHAL: "lethal"}

#: the most cells a cost map may have
MAX_COST_CELLS = 16_000_000


# ---------------------------------------------------------------------------------------------
# vehicle profiles


@dataclass(frozen=True)
class VehicleProfile:
    """What the vehicle can drive over. Lengths in metres, angles in degrees.

    max_slope_deg: steepest slope it climbs or crosses. max_step_height: highest step a wheel
    climbs. ground_clearance: lowest point of the body above the ground. footprint: (length,
    width). vehicle_height: points higher than this above the terrain are overhangs it passes
    under. max_roughness: RMS roughness at which the roughness cost saturates.
    """

    name: str
    max_slope_deg: float
    max_step_height: float
    ground_clearance: float
    footprint: tuple[float, float]
    vehicle_height: float = 2.0
    max_roughness: float = 0.1
    description: str = ""

    def __post_init__(self) -> None:
        problems = []
        for key in ("max_slope_deg", "max_step_height", "ground_clearance", "vehicle_height",
                    "max_roughness"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value <= 0:
                problems.append(f"{key} must be a finite number > 0, got {value!r}")
        if isinstance(self.max_slope_deg, (int, float)) and not self.max_slope_deg < 90:
            problems.append(f"max_slope_deg must be < 90, got {self.max_slope_deg!r}")
        try:
            footprint = tuple(float(v) for v in self.footprint)
        except (TypeError, ValueError):
            footprint = ()
        if len(footprint) != 2 or not all(math.isfinite(v) and v > 0 for v in footprint):
            problems.append(f"footprint must be two numbers > 0 (length, width in metres), got "
                            f"{self.footprint!r}")
        if problems:
            raise InputError(f"vehicle profile {self.name!r}: " + "; ".join(problems))
        object.__setattr__(self, "footprint", (max(footprint), min(footprint)))
        for key in ("max_slope_deg", "max_step_height", "ground_clearance", "vehicle_height",
                    "max_roughness"):
            object.__setattr__(self, key, float(getattr(self, key)))

    @property
    def lethal_step(self) -> float:
        """The step above which a cell is lethal: min(max_step_height, ground_clearance)."""
        return min(self.max_step_height, self.ground_clearance)

    @property
    def inscribed_radius(self) -> float:
        return self.footprint[1] / 2

    @property
    def circumscribed_radius(self) -> float:
        return math.hypot(*self.footprint) / 2

    def replace(self, **changes: Any) -> "VehicleProfile":
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update({k: v for k, v in changes.items() if v is not None})
        return VehicleProfile(**values)

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["footprint"] = list(self.footprint)
        return out

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, source: str = "") -> "VehicleProfile":
        names = [f.name for f in fields(cls)]
        where = source or "vehicle profile"
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: must be a mapping of {', '.join(names)}")
        unknown = [k for k in data if k not in names]
        required = [f.name for f in fields(cls) if f.default is dataclasses.MISSING]
        missing = [k for k in required if k not in data and k != "name"]
        if unknown or missing:
            parts = []
            if unknown:
                parts.append(f"unknown key(s) {', '.join(map(str, unknown))}")
            if missing:
                parts.append(f"missing key(s) {', '.join(missing)}")
            raise InputError(f"{where}: {'; '.join(parts)} (keys are: {', '.join(names)})")
        values = dict(data)
        values.setdefault("name", Path(source).stem if source else "vehicle")
        return cls(**values)


def vehicle_profile_names() -> list[str]:
    """Names of the built-in profiles (configs/vehicles/*.yaml)."""
    return sorted(p.stem for p in VEHICLES_DIR.glob("*.yaml")) if VEHICLES_DIR.is_dir() else []


def load_vehicle_profile(name_or_path: str | Path | VehicleProfile) -> VehicleProfile:
    """A built-in profile by name (e.g. ``"offroad_suv"``) or a YAML file by path."""
    if isinstance(name_or_path, VehicleProfile):
        return name_or_path
    path = _profile_path(str(name_or_path))
    return _read_profile(str(path), path.stat().st_mtime_ns)


def _profile_path(text: str) -> Path:
    path = Path(text)
    if path.suffix.lower() not in (".yaml", ".yml"):
        built_in = VEHICLES_DIR / f"{text}.yaml"
        if path.name == text and built_in.is_file():  # the common case, without a listing
            return built_in
        names = vehicle_profile_names()
        if text not in names:
            from .errors import did_you_mean

            hint = did_you_mean(text, names)
            raise InputError(f"unknown vehicle profile {text!r}" + (f" ({hint})" if hint else "")
                             + f"; built-in profiles: {', '.join(names) or 'none found'} "
                             f"(in {VEHICLES_DIR}), or give a path to a .yaml file")
        path = VEHICLES_DIR / f"{text}.yaml"
    if not path.is_file():
        raise InputError(f"vehicle profile file {path} not found; check the path")
    return path


@functools.lru_cache(maxsize=64)
def _read_profile(path_text: str, mtime_ns: int) -> VehicleProfile:
    """Parse a profile file once per modification time (profiles are immutable values)."""
    import yaml

    path = Path(path_text)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: invalid YAML ({exc})") from exc
    return VehicleProfile.from_mapping(data, source=str(path))


# ---------------------------------------------------------------------------------------------
# the surface on a regular grid


def surface_on_grid(surface, x_centers: np.ndarray, y_centers: np.ndarray):
    """Height and gradient of a TerrainSurface at every (x_centers[i], y_centers[j]).

    Returns ``z, dz_dx, dz_dy`` shaped (len(x), len(y)), NaN outside the region. The tensor
    product is contracted along x once per row and then summed per node (equal to calling the
    surface point by point, up to rounding).
    """
    x0, y0, z0 = surface.origin
    kx, ky = surface.knots_x, surface.knots_y
    z, gx, gy = _bs.rational_surface_grid(
        np.ascontiguousarray(np.asarray(x_centers, float) - x0),
        np.ascontiguousarray(np.asarray(y_centers, float) - y0), kx, ky, surface.degree,
        np.asarray(surface.control_points), np.asarray(surface.weights), 1e-9, 1e-9)
    return z + z0, gx, gy


# ---------------------------------------------------------------------------------------------
# the cost map


@dataclass(frozen=True, eq=False)
class CostMap:
    """A traversability cost grid (the ``cost_map`` product). Arrays are indexed [ix, iy].

    ``cost`` float32 in [0, 1] (1 = not traversable); ``state`` uint8 (UNKNOWN 0, FREE 1,
    INSCRIBED 2, LETHAL 3); ``slope_deg``, ``step_height``, ``roughness`` float32 (NaN where
    undefined); ``vehicle`` the profile used.
    """

    x_min: float
    y_min: float
    cell_size: float
    cost: np.ndarray
    state: np.ndarray
    slope_deg: np.ndarray
    step_height: np.ndarray
    roughness: np.ndarray
    vehicle: VehicleProfile
    options: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.cost.shape)  # type: ignore[return-value]

    @property
    def region(self) -> tuple[float, float, float, float]:
        nx, ny = self.shape
        c = self.cell_size
        return (self.x_min, self.x_min + nx * c, self.y_min, self.y_min + ny * c)

    @property
    def x_centers(self) -> np.ndarray:
        return self.x_min + (np.arange(self.shape[0]) + 0.5) * self.cell_size

    @property
    def y_centers(self) -> np.ndarray:
        return self.y_min + (np.arange(self.shape[1]) + 0.5) * self.cell_size

    @property
    def lethal(self) -> np.ndarray:
        """True where the vehicle's centre may not be (LETHAL or INSCRIBED)."""
        return self.state >= INSCRIBED

    @property
    def known(self) -> np.ndarray:
        return np.isfinite(self.step_height)

    def cells_of(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(ix, iy) of points; -1 outside the map."""
        nx, ny = self.shape
        return _k.bin_points(np.ascontiguousarray(x, dtype=np.float64),
                             np.ascontiguousarray(y, dtype=np.float64),
                             self.x_min, self.y_min, self.cell_size, nx, ny)

    def cost_at(self, x, y) -> np.ndarray:
        """Cost of the cell under each (x, y); NaN outside the map."""
        ix, iy = self.cells_of(np.ravel(x), np.ravel(y))
        out = np.full(ix.shape, np.nan)
        inside = ix >= 0
        out[inside] = self.cost[ix[inside], iy[inside]]
        return out.reshape(np.shape(x))

    def to_uint8(self) -> np.ndarray:
        """The ROS / Nav2 costmap convention: 0-252 cost, 253 inscribed, 254 lethal, 255 unknown."""
        out = np.round(np.clip(self.cost, 0, 1) * 252).astype(np.uint8)
        out[(self.state == UNKNOWN)] = 255
        out[self.state == INSCRIBED] = 253
        out[self.state == LETHAL] = 254
        return out

    def image_layers(self) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
        known = self.known
        everywhere = np.ones(self.shape, bool)
        return {
            "cost": (self.cost.astype(np.float64), everywhere, ""),
            "state": (self.state.astype(np.float64), everywhere, ""),
            "slope_deg": (self.slope_deg.astype(np.float64), np.isfinite(self.slope_deg), "deg"),
            "step_height": (self.step_height.astype(np.float64), known, "m"),
            "roughness": (self.roughness.astype(np.float64), np.isfinite(self.roughness), "m"),
        }

    def save(self, path: str | Path) -> None:
        """Write the cost map to an ``.npz`` file (round trip with :meth:`load`)."""
        import json

        np.savez_compressed(
            output_path(path), kind="CostMap", x_min=self.x_min, y_min=self.y_min, cell_size=self.cell_size,
            cost=self.cost, state=self.state, slope_deg=self.slope_deg,
            step_height=self.step_height, roughness=self.roughness,
            vehicle=json.dumps(self.vehicle.to_dict()), options=json.dumps(self.options))

    @classmethod
    def load(cls, path: str | Path) -> "CostMap":
        import json

        try:
            with open_npz(path, "CostMap") as data:
                return cls(float(data["x_min"]), float(data["y_min"]), float(data["cell_size"]),
                           data["cost"], data["state"], data["slope_deg"], data["step_height"],
                           data["roughness"],
                           VehicleProfile.from_mapping(json.loads(str(data["vehicle"]))),
                           json.loads(str(data["options"])))
        except (OSError, ValueError, KeyError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{path}: cannot read a CostMap ({exc})") from exc

    def render_image(self, *, min_size: int = 480, title: str = "", obstacles=None) -> np.ndarray:
        """A BGR image (x right, y up) with a legend: cost from green (0) through yellow to red
        (just below 1), INSCRIBED purple, LETHAL black, UNKNOWN grey (lighter = costlier).
        ``obstacles`` (an ObstacleSet) are outlined in cyan."""
        import cv2

        cost = np.clip(self.cost.astype(np.float64), 0, 1)
        colour = _ramp(cost)
        unknown = self.state == UNKNOWN
        grey = (150 + 60 * cost[unknown])[:, None].repeat(3, axis=1)
        colour[unknown] = grey.astype(np.uint8)
        colour[self.state == INSCRIBED] = (150, 60, 140)
        colour[self.state == LETHAL] = (0, 0, 0)
        image = np.ascontiguousarray(np.flipud(np.transpose(colour, (1, 0, 2))))
        factor = max(1, int(np.ceil(min_size / max(image.shape[:2]))))
        image = cv2.resize(image, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
        h, w = image.shape[:2]
        top, legend_w = 30, 170
        canvas = np.full((max(h + top + 10, 260), w + legend_w, 3), 255, np.uint8)
        canvas[top:top + h, :w] = image
        if obstacles is not None:
            ny = self.shape[1]
            for obstacle in obstacles:
                corners = obstacle.corners()
                col = (corners[:, 0] - self.x_min) / self.cell_size * factor
                row = top + (ny - (corners[:, 1] - self.y_min) / self.cell_size) * factor
                polygon = np.round(np.stack([col, row], axis=1)).astype(np.int32)
                cv2.polylines(canvas, [polygon], True, (255, 255, 0), 1, cv2.LINE_AA)
        font = cv2.FONT_HERSHEY_SIMPLEX
        entries = [("cost 0 (free, flat)", _ramp(np.array([0.0]))[0]),
                   ("cost 0.5", _ramp(np.array([0.5]))[0]),
                   ("cost 0.99", _ramp(np.array([0.99]))[0]),
                   ("inscribed (cost 1)", (150, 60, 140)),
                   ("lethal (cost 1)", (0, 0, 0)),
                   ("unknown", (170, 170, 170)),
                   ("obstacle box", (255, 255, 0))]
        for i, (label, bgr) in enumerate(entries):
            y = top + 8 + 24 * i
            cv2.rectangle(canvas, (w + 8, y), (w + 26, y + 16), tuple(int(v) for v in bgr), -1)
            cv2.rectangle(canvas, (w + 8, y), (w + 26, y + 16), (0, 0, 0), 1)
            cv2.putText(canvas, label, (w + 32, y + 13), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        y = top + 8 + 24 * len(entries) + 10
        for line in (f"vehicle: {self.vehicle.name}", f"max slope {self.vehicle.max_slope_deg:g} deg",
                     f"lethal step {self.vehicle.lethal_step:g} m",
                     f"cell {self.cell_size:g} m"):
            cv2.putText(canvas, line, (w + 8, y), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
            y += 18
        cv2.putText(canvas, title or "traversability cost", (4, 20), font, 0.55, (0, 0, 0), 1,
                    cv2.LINE_AA)
        return canvas


def _ramp(cost: np.ndarray) -> np.ndarray:
    """BGR uint8 from green (0) to yellow (0.5) to red (1)."""
    c = np.clip(cost, 0, 1)
    red = np.clip(2 * c, 0, 1) * 230
    green = np.clip(2 * (1 - c), 0, 1) * 200
    return np.stack([np.full_like(c, 30), green, red], axis=-1).astype(np.uint8)


def _check_positive(name: str, value, *, allow_zero: bool = False, high: float | None = None):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if ok and high is not None:
        ok = value <= high
    if not ok:
        rule = (">= 0" if allow_zero else "> 0") + (f" and <= {high:g}" if high is not None else "")
        return f"{name} must be a finite number {rule}, got {value!r}"
    return None


def _obstacle_arrays(obstacles):
    """The (centers (K, 2), sizes (K, 2), yaws (K,), heights (K,)) arrays behind an
    ObstacleSet from :func:`~o3d_terrain.obstacles.detect_obstacles` (the box centres and
    sizes are the obstacles' own memory), or None for other sequences of obstacles."""
    arrays = getattr(obstacles, "_arrays", None)
    if arrays is None or len(arrays[2]) != len(obstacles):
        return None
    return arrays


def _tall_obstacles(obstacles, n: int, lethal_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Per point the index of its obstacle in ``obstacles`` (-1 none), and per obstacle
    whether it is taller than the lethal step. An ObstacleSet of this cloud already carries
    the first (``cluster_ids``: obstacle g is ``obstacles[g]``); other sequences of obstacles
    are mapped through their ``indices``."""
    if obstacles is None:
        return np.full(n, -1, np.int32), np.zeros(0, bool)
    arrays = _obstacle_arrays(obstacles)
    if arrays is not None:
        tall = arrays[3] > lethal_step
    else:
        tall = np.array([o.height > lethal_step for o in obstacles], bool)
    ids = getattr(obstacles, "cluster_ids", None)
    if ids is not None and len(ids) == n:
        return np.ascontiguousarray(ids, dtype=np.int32), tall
    point_obstacle = np.full(n, -1, np.int32)
    for g, obstacle in enumerate(obstacles):
        point_obstacle[np.asarray(obstacle.indices, np.int64)] = g
    return point_obstacle, tall


@checked_keywords()
def traversability_cost(surface, cloud: Any = None, *,
                        vehicle: str | Path | VehicleProfile = "offroad_suv",
                        cell_size: float = 0.25,
                        region: Sequence[float] | None = None,
                        labels: np.ndarray | None = None,
                        heights_above_terrain: np.ndarray | None = None,
                        obstacles: Any = None, fill_obstacle_boxes: bool = True,
                        unknown_cost: float = 0.5,
                        weights: Sequence[float] = (0.5, 0.3, 0.2),
                        inflation_scale: float = 0.5) -> CostMap:
    """The traversability cost map of a terrain surface and the points on it.

    surface: a TerrainSurface (its analytic gradient gives the slope). cloud: the points
        (anything :func:`~o3d_terrain.frame.as_frame` accepts) for step, roughness and
        occupancy (cells without a point are UNKNOWN at ``unknown_cost``); None = slope only
        (every cell UNKNOWN, with the slope term and slope lethality). vehicle: a built-in profile name, a
        YAML path or a :class:`VehicleProfile`. cell_size: cell side (m). region: (x_min, x_max,
        y_min, y_max); None = the surface's region. labels, heights_above_terrain: per-point
        arrays overriding the cloud's attributes (BELOW_TERRAIN and UNKNOWN points are left
        out). obstacles: an ObstacleSet (or a sequence of obstacles) whose cells, and boxes
        with ``fill_obstacle_boxes``, are occupied when taller than the lethal step.
        unknown_cost: the cost of a cell with no point (the least, on a slope-only map), in
        [0, 1]. weights: (slope, step,
        roughness) weights, >= 0 with a positive sum. inflation_scale: decay length (m) of the
        cost beyond the inscribed radius.
    """
    profile = load_vehicle_profile(vehicle)
    problems = [p for p in (
        _check_positive("cell_size", cell_size),
        _check_positive("unknown_cost", unknown_cost, allow_zero=True, high=1.0),
        _check_positive("inflation_scale", inflation_scale),
    ) if p]
    try:
        w = tuple(float(v) for v in weights)
    except (TypeError, ValueError):
        w = ()
    if len(w) != 3 or not all(math.isfinite(v) and v >= 0 for v in w) or sum(w) <= 0:
        problems.append(f"weights must be three numbers >= 0 (slope, step, roughness) with a "
                        f"positive sum, got {weights!r}")
    if not callable(surface) or not hasattr(surface, "knots_x"):
        problems.append(f"surface must be a TerrainSurface, got {type(surface).__name__}")
    if problems:
        raise InputError("traversability_cost: " + "; ".join(problems))
    if region is None:
        region = surface.region
    region = tuple(float(v) for v in region)
    if len(region) != 4 or not all(math.isfinite(v) for v in region) \
            or not (region[1] > region[0] and region[3] > region[2]):
        raise InputError(f"traversability_cost: region must be (x_min, x_max, y_min, y_max) "
                         f"with x_max > x_min and y_max > y_min, got {region!r}")
    nx = max(1, int(math.ceil((region[1] - region[0]) / cell_size - 1e-9)))
    ny = max(1, int(math.ceil((region[3] - region[2]) / cell_size - 1e-9)))
    if nx * ny > MAX_COST_CELLS:
        raise InputError(f"traversability_cost: {nx} x {ny} cells of {cell_size} m over region "
                         f"{region} is over {MAX_COST_CELLS}; use a larger cell_size or a "
                         f"smaller region")
    x_min, y_min = region[0], region[2]
    xc = x_min + (np.arange(nx) + 0.5) * cell_size
    yc = y_min + (np.arange(ny) + 0.5) * cell_size

    # step and roughness from the points (in the cells holding points), occupancy from the
    # obstacles
    slot = None
    occupied = np.zeros((nx, ny), bool)
    lethal_step = profile.lethal_step
    if cloud is not None:
        from .obstacles import resolve_heights_and_labels

        frame = as_frame(cloud)
        if len(frame):
            heights, point_labels = resolve_heights_and_labels(
                frame, surface, labels, heights_above_terrain)
            point_obstacle, tall = _tall_obstacles(obstacles, len(frame), lethal_step)
            slot, count, highest, rn, rs2, cell_i, cell_j = _k.observed_cells(
                frame.positions, np.ascontiguousarray(point_labels),
                np.ascontiguousarray(heights, dtype=np.float64), point_obstacle, tall,
                float(x_min), float(y_min), float(cell_size), nx, ny,
                int(TerrainLabel.BELOW_TERRAIN), int(TerrainLabel.UNKNOWN),
                profile.vehicle_height, lethal_step, occupied)
            if fill_obstacle_boxes and tall.any():
                arrays = _obstacle_arrays(obstacles)
                if arrays is not None:  # 0.09 ms less than gathering them from the values
                    centers, sizes, yaws = arrays[0][tall], arrays[1][tall], arrays[2][tall]
                else:
                    boxes = [o for o, is_tall in zip(obstacles, tall) if is_tall]
                    centers = np.array([o.box_center for o in boxes], np.float64)
                    sizes = np.array([o.box_size for o in boxes], np.float64)
                    yaws = np.array([o.box_yaw_deg for o in boxes], np.float64)
                _k.fill_boxes(centers, sizes, yaws, float(x_min), float(y_min),
                              float(cell_size), occupied)

    # the cost formula, with the slope from the surface's analytic derivatives: at the cells
    # holding points (the others are UNKNOWN), or everywhere for a slope-only map
    x0, y0, _ = surface.origin
    slope_only = cloud is None
    if slot is None:
        count = rn = cell_i = cell_j = np.zeros(0, np.int32)
        highest = rs2 = np.zeros(0)
    if slope_only:
        slope_grid = _k.gradient_norm_grid(xc - x0, yc - y0, surface.knots_x, surface.knots_y,
                                           surface.degree, surface.control_points,
                                           surface.weights, 1e-9)
        np.arctan(slope_grid, out=slope_grid)  # vectorised, unlike a per-cell atan in a kernel
    else:
        slope_grid = np.zeros((1, 1))
    entry_slope = _k.slope_at_cells(xc - x0, yc - y0, cell_i, cell_j, surface.knots_x,
                                    surface.knots_y, surface.degree, surface.control_points,
                                    surface.weights, 1e-9)
    slope, step, rough, cost, lethal, state = _k.cost_cells(
        cell_i, cell_j, entry_slope, count, highest, rn, rs2, occupied, profile.max_slope_deg,
        lethal_step, profile.max_roughness, w[0], w[1], w[2], float(unknown_cost), FREE,
        UNKNOWN, LETHAL, slope_only, slope_grid)

    # inflation by the footprint (the cells near lethal ones)
    _k.inflate(cost, state, lethal, float(cell_size), profile.inscribed_radius,
               profile.circumscribed_radius, float(inflation_scale), INSCRIBED)
    options = {"cell_size": float(cell_size), "unknown_cost": float(unknown_cost),
               "weights": list(w), "inflation_scale": float(inflation_scale),
               "fill_obstacle_boxes": bool(fill_obstacle_boxes)}
    return CostMap(float(x_min), float(y_min), float(cell_size), cost, state, slope, step,
                   rough, profile, options)
