"""Sensor models: a spinning lidar and a stereo-like depth sensor, by ray casting a Scene.

Rays are cast with Open3D's ``RaycastingScene`` against the scene's mesh, so occlusion shadows
behind obstacles are real. A ray that hits the terrain is then refined onto the analytic
surface (Newton steps along the ray), so noise-free terrain points lie exactly on the terrain.

Every cloud comes back in the **sensor frame** (x forward, y left, z up, origin at the sensor)
together with ``world_from_sensor``, so a tilted sensor gives tilted data, as on a vehicle.
Angles: ``yaw_deg`` turns the sensor about world z (counter-clockwise from +x);
``tilt_deg = (roll, pitch)``: roll about the forward axis (positive: left side up), pitch about
the left axis (positive: nose **down**, the right-hand rule about y). The rotation is
world_from_sensor = Rz(yaw) · Ry(pitch) · Rx(roll).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import open3d as o3d

from ..errors import InputError
from .scene import Scene

#: ``ground_truth`` attribute values
TERRAIN = 1
OBSTACLE = 2
OUTLIER = 3

#: rotation taking optical camera axes (x right, y down, z forward) to sensor axes
#: (x forward, y left, z up): sensor = SENSOR_FROM_OPTICAL @ optical
SENSOR_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# ---------------------------------------------------------------------------------------------
# poses


def rotation_matrix(*, yaw_deg: float = 0.0, roll_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """Rz(yaw) · Ry(pitch) · Rx(roll), angles in degrees (see the module docstring)."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    return rz @ ry @ rx


def sensor_pose(scene: Scene, *, sensor_xy=None, sensor_height: float, yaw_deg: float = 0.0,
                tilt_deg=(0.0, 0.0), on_terrain: bool = False) -> np.ndarray:
    """4×4 world_from_sensor for a sensor ``sensor_height`` metres above the terrain at sensor_xy.

    ``on_terrain=True`` mounts it on a vehicle standing on the slope there: the sensor's z axis
    is the terrain normal at sensor_xy, its x axis the slope's tangent heading ``yaw_deg``,
    and it stands ``sensor_height`` along the normal; ``tilt_deg`` is then the mount's own tilt
    on top of the vehicle's.
    """
    x, y = scene.sensor_xy if sensor_xy is None else sensor_xy
    _check_finite("sensor_xy", (x, y))
    _check_finite("tilt_deg", tilt_deg, length=2)
    _check_finite("sensor_height", (sensor_height, yaw_deg))
    pose = np.eye(4)
    ground = np.array([x, y, float(scene.height(x, y))])
    if on_terrain:
        mount = rotation_matrix(roll_deg=tilt_deg[0], pitch_deg=tilt_deg[1])
        gx, gy = (float(g) for g in scene.gradient(x, y))
        up = np.array([-gx, -gy, 1.0])
        up /= np.linalg.norm(up)  # the terrain normal, as scene.normal gives it
        cx, cy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
        forward = np.array([cx, cy, gx * cx + gy * cy])  # along the slope, heading yaw_deg
        forward /= np.linalg.norm(forward)
        pose[:3, :3] = np.column_stack([forward, np.cross(up, forward), up]) @ mount
        pose[:3, 3] = ground + sensor_height * up
    else:
        pose[:3, :3] = rotation_matrix(yaw_deg=yaw_deg, roll_deg=tilt_deg[0],
                                       pitch_deg=tilt_deg[1])
        pose[:3, 3] = (x, y, ground[2] + sensor_height)
    return pose


def _check_finite(name, values, length=None):
    try:
        values = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numbers; got {values!r}") from None
    if length is not None and len(values) != length:
        raise InputError(f"{name} must have {length} values; got {values!r}")
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{name} must be finite; got {values!r}")


def _check_positive(**values):
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or value <= 0:
            raise InputError(f"{name} must be a positive number; got {value!r}")


# ---------------------------------------------------------------------------------------------
# ray casting


def cast(scene: Scene, origins: np.ndarray, directions: np.ndarray, *,
         refine: bool = True, drop_unrefined: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast world rays; return (t, obstacle_index, normals).

    ``t`` (N,) is the hit parameter in units of the direction's length (inf on a miss);
    ``obstacle_index`` (N,) is -1 for terrain, -2 for a miss, else the obstacle's index;
    ``normals`` (N, 3) are unit surface normals (analytic on terrain). Terrain hits are refined
    onto the analytic surface unless ``refine`` is False; the rare grazing ray that crosses the
    mesh but not the analytic surface within 2 m is reported as a miss (``drop_unrefined``) or
    keeps its mesh hit (a few millimetres off).
    """
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
    raycasting, ids = scene.raycasting_scene()
    rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
    result = raycasting.cast_rays(o3d.core.Tensor(rays))
    t = result["t_hit"].numpy().astype(np.float64)
    geometry = result["geometry_ids"].numpy().astype(np.int64)
    normals = result["primitive_normals"].numpy().astype(np.float64)
    hit = np.isfinite(t)
    index = np.full(len(t), -2, dtype=np.int64)
    lookup = np.full(max(ids) + 1, -2, dtype=np.int64)
    for geometry_id, obstacle in ids.items():
        lookup[geometry_id] = obstacle
    index[hit] = lookup[geometry[hit]]
    terrain = index == -1
    if refine and terrain.any():
        refined = _refine(scene, origins[terrain], directions[terrain], t[terrain])
        lost = np.isnan(refined)
        if drop_unrefined:  # a grazing ray that hits the mesh but not the exact surface
            refined[lost] = np.inf
            where = np.flatnonzero(terrain)[lost]
            index[where] = -2
        else:
            refined[lost] = t[terrain][lost]
        t[terrain] = refined
        terrain = index == -1
    if terrain.any():
        p = origins[terrain] + t[terrain, None] * directions[terrain]
        normals[terrain] = scene.normal(p[:, 0], p[:, 1])
    return t, index, normals


def _refine(scene: Scene, origins, directions, t, steps: int = 4) -> np.ndarray:
    """Newton steps on f(t) = z(t) − h(x(t), y(t)) from the mesh hit, bisection where they
    fail; NaN where the ray does not cross the analytic surface near the mesh hit."""
    start = t.copy()
    for _ in range(steps):
        p = origins + t[:, None] * directions
        f = p[:, 2] - scene.height(p[:, 0], p[:, 1])
        gx, gy = scene.gradient(p[:, 0], p[:, 1])
        df = directions[:, 2] - gx * directions[:, 0] - gy * directions[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = t - np.where(np.abs(df) > 1e-9, f / df, 0.0)
    p = origins + t[:, None] * directions
    residual = np.abs(p[:, 2] - scene.height(p[:, 0], p[:, 1]))
    length = np.linalg.norm(directions, axis=1)
    good = np.isfinite(t) & (residual < 1e-7) & (np.abs(t - start) * length < 0.5) & (t > 0)
    t = np.where(good, t, start)
    bad = np.flatnonzero(~good)
    if len(bad):  # grazing rays: first sign change near the mesh hit, then bisection
        t[bad] = _bracket(scene, origins[bad], directions[bad], start[bad], 2.0 / length[bad])
    return t


def _bracket(scene: Scene, origins, directions, start, reach, samples: int = 257) -> np.ndarray:
    """The first crossing of the terrain within ``start ± reach``; ``start`` where none."""
    steps = np.linspace(-1.0, 1.0, samples)
    ts = np.clip(start[:, None] + reach[:, None] * steps[None, :], 0.0, None)  # (K, S)
    p = origins[:, None, :] + ts[..., None] * directions[:, None, :]
    f = p[..., 2] - scene.height(p[..., 0], p[..., 1])
    crossing = (f[:, :-1] > 0) & (f[:, 1:] <= 0)
    found = crossing.any(axis=1)
    first = np.argmax(crossing, axis=1)
    rows = np.arange(len(start))
    low, high = ts[rows, first], ts[rows, first + 1]
    for _ in range(40):
        mid = 0.5 * (low + high)
        q = origins + mid[:, None] * directions
        above = q[:, 2] - scene.height(q[:, 0], q[:, 1]) > 0
        low = np.where(above, mid, low)
        high = np.where(above, high, mid)
    return np.where(found, 0.5 * (low + high), np.nan)


# ---------------------------------------------------------------------------------------------
# the result


@dataclass(frozen=True, eq=False)
class TerrainError:
    """Vertical error of a fitted surface against the exact terrain (metres)."""

    rmse: float
    mean_abs: float
    p95_abs: float
    max_abs: float
    bias: float
    samples: int


@dataclass(frozen=True, eq=False)
class SyntheticCloud:
    """Points sampled from a :class:`Scene` by a sensor, with exact truth.

    ``positions`` are the measured points (with noise) and ``true_positions`` the noise-free
    hits of the same rays, both (N, 3) float64 in the sensor frame. ``obstacle_id`` is -1 for
    terrain, else the index of the obstacle in ``scene.obstacles`` (stable over a sequence,
    so it doubles as the track id).
    """

    positions: np.ndarray
    true_positions: np.ndarray
    obstacle_id: np.ndarray
    world_from_sensor: np.ndarray
    scene: Scene
    sensor: str
    #: seconds since the start of a sequence (the scene is the one at this time)
    time: float = 0.0
    #: (N,) bool: a spurious return moved along its ray off the surface (None = none)
    outliers: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def is_obstacle(self) -> np.ndarray:
        """(N,) bool: the ray hit an obstacle."""
        return self.obstacle_id >= 0

    @property
    def is_outlier(self) -> np.ndarray:
        """(N,) bool: a spurious return (dust, multipath) that lies on no surface."""
        if self.outliers is None:
            return np.zeros(len(self.positions), dtype=bool)
        return self.outliers

    @property
    def ground_truth(self) -> np.ndarray:
        """(N,) int32: 1 = terrain, 2 = obstacle, 3 = spurious return (outlier)."""
        truth = np.where(self.is_obstacle, OBSTACLE, TERRAIN).astype(np.int32)
        truth[self.is_outlier] = OUTLIER
        return truth

    # -- frames ------------------------------------------------------------------------------
    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Sensor-frame points (..., 3) to world."""
        r, t = self.world_from_sensor[:3, :3], self.world_from_sensor[:3, 3]
        return np.asarray(points, dtype=np.float64) @ r.T + t

    def to_sensor(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) to the sensor frame."""
        r, t = self.world_from_sensor[:3, :3], self.world_from_sensor[:3, 3]
        return (np.asarray(points, dtype=np.float64) - t) @ r

    @property
    def world_positions(self) -> np.ndarray:
        return self.to_world(self.positions)

    @property
    def true_height_above_terrain(self) -> np.ndarray:
        """(N,) height of each measured point above the terrain along world z (metres)."""
        p = self.world_positions
        return p[:, 2] - self.scene.height(p[:, 0], p[:, 1])

    def to_pointcloud(self) -> o3d.t.geometry.PointCloud:
        """A tensor cloud: float64 positions (sensor frame), (N, 1) int32 attributes
        ``ground_truth`` (1 terrain, 2 obstacle, 3 outlier) and ``obstacle_ids`` (-1 terrain,
        else the index of the obstacle the ray hit)."""
        cloud = o3d.t.geometry.PointCloud(
            {"positions": o3d.core.Tensor(np.ascontiguousarray(self.positions, dtype=np.float64))}
        )
        cloud.point["ground_truth"] = o3d.core.Tensor(self.ground_truth[:, None].copy())
        cloud.point["obstacle_ids"] = o3d.core.Tensor(
            self.obstacle_id.astype(np.int32)[:, None].copy())
        return cloud

    # -- exact terrain in the sensor frame -----------------------------------------------------
    def terrain_height_in_sensor_frame(self, x, y) -> np.ndarray:
        """Exact terrain z at sensor-frame (x, y): the z where (x, y, z) lies on the terrain.

        Solved by Newton steps along the sensor's z axis, so it is exact for a tilted sensor
        too. NaN where there is no solution (a sensor tilted past the terrain's slope).
        """
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                   np.asarray(y, dtype=np.float64))
        r, t = self.world_from_sensor[:3, :3], self.world_from_sensor[:3, 3]
        base = t + x[..., None] * r[:, 0] + y[..., None] * r[:, 1]
        axis = r[:, 2]
        z = (self.scene.height(base[..., 0], base[..., 1]) - base[..., 2]) / axis[2]
        for _ in range(8):
            p = base + z[..., None] * axis
            f = p[..., 2] - self.scene.height(p[..., 0], p[..., 1])
            gx, gy = self.scene.gradient(p[..., 0], p[..., 1])
            df = axis[2] - gx * axis[0] - gy * axis[1]
            z = z - f / np.where(np.abs(df) > 1e-9, df, np.nan)
        p = base + z[..., None] * axis
        residual = np.abs(p[..., 2] - self.scene.height(p[..., 0], p[..., 1]))
        return np.where(residual < 1e-6, z, np.nan)

    def terrain_height(self, x, y) -> np.ndarray:
        """Same as :meth:`terrain_height_in_sensor_frame` (the exact terrain in this cloud's frame)."""
        return self.terrain_height_in_sensor_frame(x, y)

    def terrain_truth_samples(self, spacing: float = 0.5, region=None) -> np.ndarray:
        """Exact terrain points (M, 3) in the sensor frame on a sensor-frame (x, y) grid.

        ``region`` is (x_min, x_max, y_min, y_max) in the sensor frame; by default the extent
        of the terrain points of this cloud.
        """
        xs, ys = _grid_axes(self._region(region), spacing)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        z = self.terrain_height_in_sensor_frame(gx, gy)
        out = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
        return out[np.isfinite(out[:, 2])]

    def _region(self, region):
        if region is not None:
            _check_finite("region", region, length=4)
            if not (region[1] > region[0] and region[3] > region[2]):
                raise InputError(f"region must have x_max > x_min and y_max > y_min; got {region}")
            return tuple(float(v) for v in region)
        terrain = self.positions[~self.is_obstacle & ~self.is_outlier]
        if len(terrain) == 0:
            raise InputError("the cloud has no terrain point; give a region")
        return (terrain[:, 0].min(), terrain[:, 0].max(), terrain[:, 1].min(), terrain[:, 1].max())


def _grid_axes(region, spacing):
    _check_positive(spacing=spacing)
    x_min, x_max, y_min, y_max = region
    if (x_max - x_min) / spacing * (y_max - y_min) / spacing > 5e7:
        raise InputError(f"spacing {spacing} m is too fine for region {region}; use a larger one")
    xs = np.arange(x_min + spacing / 2, x_max, spacing)
    ys = np.arange(y_min + spacing / 2, y_max, spacing)
    return xs, ys


def terrain_rmse(surface: Callable, cloud: SyntheticCloud, *, region=None,
                 spacing: float = 0.5, covered_only: bool = True) -> TerrainError:
    """Vertical error of a fitted surface z = surface(x, y) (sensor frame) against the truth.

    Compared on a grid of sensor-frame (x, y) nodes ``spacing`` metres apart over ``region``
    (default: the extent of the cloud's terrain points). With ``covered_only`` a node counts
    only when its cell holds at least one terrain point of the cloud, so extrapolation into
    occlusion shadows and beyond the data is not scored. Nodes outside the scene are skipped.
    """
    if not callable(surface):
        raise InputError(f"surface must be callable as surface(x, y); got {type(surface).__name__}")
    region = cloud._region(region)
    xs, ys = _grid_axes(region, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    keep = np.ones(gx.shape, dtype=bool)
    if covered_only:
        terrain = cloud.positions[~cloud.is_obstacle & ~cloud.is_outlier]
        ix = np.floor((terrain[:, 0] - region[0]) / spacing).astype(np.int64)
        iy = np.floor((terrain[:, 1] - region[2]) / spacing).astype(np.int64)
        inside = (ix >= 0) & (ix < len(xs)) & (iy >= 0) & (iy < len(ys))
        covered = np.zeros(gx.shape, dtype=bool)
        covered[ix[inside], iy[inside]] = True
        keep &= covered
    x, y = gx[keep], gy[keep]
    truth = cloud.terrain_height_in_sensor_frame(x, y)
    world = cloud.to_world(np.stack([x, y, np.nan_to_num(truth)], axis=1))
    x_min, x_max, y_min, y_max = cloud.scene.region
    in_scene = ((world[:, 0] >= x_min) & (world[:, 0] <= x_max) & (world[:, 1] >= y_min)
                & (world[:, 1] <= y_max) & np.isfinite(truth))
    x, y, truth = x[in_scene], y[in_scene], truth[in_scene]
    if len(x) == 0:
        raise InputError("terrain_rmse: no grid node to compare in the region "
                         f"{tuple(round(v, 3) for v in region)}; check the region and spacing")
    fitted = np.asarray(surface(x, y), dtype=np.float64).reshape(-1)
    if fitted.shape != truth.shape:
        raise InputError(f"surface(x, y) returned {fitted.shape[0]} values for {len(x)} nodes")
    error = fitted - truth
    error = error[np.isfinite(error)]
    if len(error) == 0:
        raise InputError("terrain_rmse: the surface returned no finite value")
    a = np.abs(error)
    return TerrainError(rmse=float(np.sqrt(np.mean(error**2))), mean_abs=float(a.mean()),
                        p95_abs=float(np.percentile(a, 95)), max_abs=float(a.max()),
                        bias=float(error.mean()), samples=len(error))


# ---------------------------------------------------------------------------------------------
# sensors


def sample_lidar(scene: Scene, *, sensor_xy=None, sensor_height: float = 1.8,
                 yaw_deg: float = 0.0, tilt_deg=(0.0, 0.0), beams: int = 32,
                 azimuth_steps: int = 900, fov_deg=(-25.0, 3.0), min_range: float = 1.0,
                 max_range: float = 80.0, range_noise: float = 0.02, outlier_fraction: float = 0.0,
                 on_terrain: bool = False, seed: int = 0) -> SyntheticCloud:
    """A spinning multi-beam lidar frame.

    ``beams`` channels with elevations evenly spread over ``fov_deg`` (degrees, in the sensor
    frame), ``azimuth_steps`` firings over 360°. Returns hits between ``min_range`` and
    ``max_range`` metres, with Gaussian range noise of ``range_noise`` metres (standard
    deviation) along each beam. A fraction ``outlier_fraction`` of the returns are spurious
    (dust, multipath): moved along their beam to between 0.5 and 1.5 times the true range
    (``is_outlier``, ground_truth 3). The defaults give about 20k points on the 40 m × 30 m scenes;
    ``beams=64, azimuth_steps=1800`` gives a 360° frame of about 80k-120k points.
    ``on_terrain=True``: the sensor tilts with the slope under it, as on a vehicle
    (:func:`sensor_pose`).
    """
    _check_int(beams=beams, azimuth_steps=azimuth_steps)
    _check_positive(max_range=max_range, sensor_height=sensor_height)
    _check_finite("fov_deg", fov_deg, length=2)
    if not (-90 <= fov_deg[0] <= fov_deg[1] <= 90):
        raise InputError(f"fov_deg must be (low, high) with -90 <= low <= high <= 90; got {fov_deg}")
    _check_non_negative(range_noise=range_noise, min_range=min_range)
    pose = sensor_pose(scene, sensor_xy=sensor_xy, sensor_height=sensor_height, yaw_deg=yaw_deg,
                       tilt_deg=tilt_deg, on_terrain=on_terrain)
    elevation = np.radians(np.linspace(fov_deg[0], fov_deg[1], beams))
    azimuth = np.arange(azimuth_steps) * (2 * math.pi / azimuth_steps)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    return _lidar_returns(scene, pose, _beam_directions(az.ravel(), el.ravel()), min_range,
                          max_range, range_noise, outlier_fraction, seed)


def _beam_directions(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Unit beam directions (N, 3) in the sensor frame from azimuth and elevation (rad)."""
    return np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                     np.sin(elevation)], axis=-1)


def _lidar_returns(scene: Scene, pose: np.ndarray, directions: np.ndarray, min_range: float,
                   max_range: float, range_noise: float, outlier_fraction: float,
                   seed: int) -> SyntheticCloud:
    """The returns of a lidar at ``pose`` firing along ``directions`` (sensor frame): the
    hits between ``min_range`` and ``max_range`` m, Gaussian range noise of ``range_noise`` m
    along the beam and a fraction ``outlier_fraction`` of spurious returns (:func:`_spurious`),
    in the sensor frame."""
    t, index, _ = cast(scene, pose[:3, 3], directions @ pose[:3, :3].T)
    keep = np.isfinite(t) & (t >= min_range) & (t <= max_range)
    directions, t, index = directions[keep], t[keep], index[keep]
    rng = np.random.default_rng(seed)
    measured = t + rng.normal(0.0, range_noise, len(t)) if range_noise > 0 else t
    measured, outliers = _spurious(measured, outlier_fraction, rng)
    return SyntheticCloud(directions * measured[:, None], directions * t[:, None], index, pose,
                          scene, "lidar", outliers=outliers)


def sample_solid_state(scene: Scene, *, sensor_xy=None, sensor_height: float = 1.8,
                       yaw_deg: float = 0.0, tilt_deg=(0.0, 0.0), fov_deg: float = 70.0,
                       points: int = 100_000, min_range: float = 1.0, max_range: float = 80.0,
                       range_noise: float = 0.02, outlier_fraction: float = 0.0,
                       on_terrain: bool = False, seed: int = 0) -> SyntheticCloud:
    """A forward-looking solid-state lidar with a non-repetitive (rosette) scan pattern, as
    the prism-scanning units mounted on small off-road and mining vehicles have.

    ``points`` firings (the frame's integration time times the firing rate: 100,000 is about
    half a second of a 200 kHz unit) trace a rose of incommensurate rates over a circular field
    of view ``fov_deg`` wide about the sensor's x axis (azimuth and elevation offsets within
    ``fov_deg`` / 2 of it): no scan lines, denser at the centre, every ray's direction
    different. Returns hits between ``min_range`` and ``max_range`` metres with Gaussian range
    noise of ``range_noise`` metres along the beam, and a fraction ``outlier_fraction`` of
    spurious returns as :func:`sample_lidar`; poses (``on_terrain`` among them) and frames as
    :func:`sample_lidar`.
    """
    _check_int(points=points)
    _check_positive(max_range=max_range, sensor_height=sensor_height, fov_deg=fov_deg,
                    points=points)
    if fov_deg > 170.0:
        raise InputError(f"fov_deg must be at most 170 (a forward-looking unit); got {fov_deg}")
    _check_non_negative(range_noise=range_noise, min_range=min_range)
    pose = sensor_pose(scene, sensor_xy=sensor_xy, sensor_height=sensor_height, yaw_deg=yaw_deg,
                       tilt_deg=tilt_deg, on_terrain=on_terrain)
    # the rose: the beam turns about the axis while its offset swings out to the edge of the
    # field of view and back, at rates whose ratio is irrational (the pattern never repeats)
    phase = np.arange(points) * (2 * math.pi * ROSETTE_TURNS / points)
    offset = math.radians(fov_deg / 2) * np.abs(np.sin(ROSETTE_PETALS * phase))
    directions = _beam_directions(offset * np.cos(phase), offset * np.sin(phase))
    return _lidar_returns(scene, pose, directions, min_range, max_range, range_noise,
                          outlier_fraction, seed)


#: the rose of :func:`sample_solid_state`: turns of the beam about the axis per frame, and
#: swings of its offset per radian of turn (irrational: the pattern does not repeat)
ROSETTE_TURNS = 100
ROSETTE_PETALS = 3.7 * math.pi


#: where :func:`sample_airborne` puts the scene's origin: projected coordinates (UTM-like
#: metres), as an airborne tile has them, so no point lies near a sensor at (0, 0, 0)
AIRBORNE_OFFSET = (500000.0, 6600000.0, 100.0)


def sample_airborne(scene: Scene, *, density: float = 6.0, altitude: float = 300.0,
                    scan_angle_deg: float = 15.0, range_noise: float = 0.03,
                    offset=AIRBORNE_OFFSET, seed: int = 0) -> SyntheticCloud:
    """An airborne lidar strip over the scene's region: about ``density`` pulses per square
    metre at random (x, y), each from ``altitude`` m up along a line of flight parallel to x,
    tilted across it by up to ``scan_angle_deg``; first returns, with Gaussian range noise of
    ``range_noise`` m along the beam. The cloud is in projected coordinates: the scene's
    point (x, y, z) is at (x, y, z) + ``offset`` (``world_from_sensor`` undoes it), so, as
    for a LAS tile, no point lies near the origin."""
    _check_positive(density=density, altitude=altitude)
    _check_non_negative(range_noise=range_noise, scan_angle_deg=scan_angle_deg)
    _check_finite("offset", offset, length=3)
    if scan_angle_deg >= 60:
        raise InputError(f"scan_angle_deg must be below 60 degrees; got {scan_angle_deg}")
    rng = np.random.default_rng(seed)
    x_min, x_max, y_min, y_max = scene.region
    n = int(round(density * (x_max - x_min) * (y_max - y_min)))
    x = rng.uniform(x_min, x_max, n)
    y = rng.uniform(y_min, y_max, n)
    angle = np.radians(rng.uniform(-scan_angle_deg, scan_angle_deg, n))
    directions = np.stack([np.zeros(n), np.sin(angle), -np.cos(angle)], axis=1)
    # each pulse leaves the line of flight where its beam meets (x, y) at z = 0
    origins = np.stack([x, y - altitude * np.tan(angle), np.full(n, float(altitude))], axis=1)
    t, index, _ = cast(scene, origins, directions)
    keep = np.isfinite(t)
    origins, directions, t, index = origins[keep], directions[keep], t[keep], index[keep]
    measured = t + rng.normal(0.0, range_noise, len(t)) if range_noise > 0 else t
    shift = np.asarray(offset, dtype=np.float64)
    pose = np.eye(4)
    pose[:3, 3] = -shift
    return SyntheticCloud(origins + directions * measured[:, None] + shift,
                          origins + directions * t[:, None] + shift, index, pose, scene,
                          "airborne")


def _spurious(measured: np.ndarray, fraction: float, rng: np.random.Generator):
    """Move a random ``fraction`` of the ranges to 0.5-1.5 times their value (spurious returns)."""
    if not (isinstance(fraction, (int, float)) and 0.0 <= fraction <= 1.0):
        raise InputError(f"outlier_fraction must be a number in [0, 1]; got {fraction!r}")
    if fraction == 0:
        return measured, None
    outliers = rng.random(len(measured)) < fraction
    factor = rng.uniform(0.5, 1.0, len(measured))
    factor = np.where(rng.random(len(measured)) < 0.5, factor, 2.0 - factor)  # 0.5-1.5, not 1
    return np.where(outliers, measured * factor, measured), outliers


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size in pixels, focal length and principal point in pixels."""

    width: int
    height: int
    focal_px: float
    cx: float
    cy: float

    @classmethod
    def make(cls, width: int, height: int, focal_px: float | None) -> Camera:
        _check_int(width=width, height=height)
        focal = 0.8 * width if focal_px is None else focal_px
        _check_positive(focal_px=focal)
        return cls(int(width), int(height), float(focal), (width - 1) / 2.0, (height - 1) / 2.0)

    def directions(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Sensor-frame ray directions with unit forward component (so t = depth)."""
        return np.stack([np.ones_like(u, dtype=np.float64), -(u - self.cx) / self.focal_px,
                         -(v - self.cy) / self.focal_px], axis=-1)


def sample_stereo(scene: Scene, *, camera_xy=None, camera_height: float = 1.6,
                  yaw_deg: float = 0.0, tilt_deg=(0.0, 5.0), width: int = 320, height: int = 240,
                  focal_px: float | None = None, baseline: float = 0.3, pixel_step: int = 1,
                  disparity_noise_px: float = 0.25, min_disparity_px: float = 1.0,
                  max_range: float = 60.0, outlier_fraction: float = 0.0,
                  seed: int = 0) -> SyntheticCloud:
    """A stereo-like cloud: one point per pixel of the left camera that sees a surface.

    The true depth Z of each pixel gives the disparity d = f·B/Z; Gaussian noise of
    ``disparity_noise_px`` pixels is added to d and the point is moved along its viewing ray
    to the depth f·B/d', so the depth noise grows with Z² (σ_Z ≈ Z²·σ_d / (f·B)). Pixels with
    d' below ``min_disparity_px`` or depth beyond ``max_range`` are dropped. A fraction
    ``outlier_fraction`` of the points are gross mismatches: moved along their ray to between
    0.5 and 1.5 times their depth (``is_outlier``, ground_truth 3). ``focal_px``
    defaults to 0.8·width (a 64° horizontal field of view). Positions are in the left
    camera's sensor frame (x forward, y left, z up). 320×240 gives about 40k points; 640×480
    about 150k; ``width=1024, height=768`` about 400k.
    """
    camera = Camera.make(width, height, focal_px)
    _check_int(pixel_step=pixel_step)
    _check_positive(baseline=baseline, max_range=max_range, camera_height=camera_height)
    _check_non_negative(disparity_noise_px=disparity_noise_px, min_disparity_px=min_disparity_px)
    pose = sensor_pose(scene, sensor_xy=camera_xy, sensor_height=camera_height, yaw_deg=yaw_deg,
                       tilt_deg=tilt_deg)
    u, v = np.meshgrid(np.arange(0, camera.width, pixel_step, dtype=np.float64),
                       np.arange(0, camera.height, pixel_step, dtype=np.float64))
    directions = camera.directions(u.ravel(), v.ravel())
    depth, index, _ = cast(scene, pose[:3, 3], directions @ pose[:3, :3].T)
    hit = np.isfinite(depth)
    directions, depth, index = directions[hit], depth[hit], index[hit]
    fb = camera.focal_px * baseline
    rng = np.random.default_rng(seed)
    disparity = fb / depth
    if disparity_noise_px > 0:
        disparity = disparity + rng.normal(0.0, disparity_noise_px, len(depth))
    with np.errstate(divide="ignore"):
        measured = fb / disparity
    keep = (disparity >= max(min_disparity_px, 1e-9)) & (measured <= max_range) & (depth <= max_range)
    directions, depth, measured, index = directions[keep], depth[keep], measured[keep], index[keep]
    measured, outliers = _spurious(measured, outlier_fraction, rng)
    return SyntheticCloud(directions * measured[:, None], directions * depth[:, None], index, pose,
                          scene, "stereo", outliers=outliers)


def _check_int(**values):
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InputError(f"{name} must be a positive integer; got {value!r}")


def _check_non_negative(**values):
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or value < 0:
            raise InputError(f"{name} must be a number >= 0; got {value!r}")


def sample_sequence(scene: Scene, *, frames: int = 10, rate_hz: float = 10.0, speed: float = 5.0,
                    start_xy=None, yaw_deg: float = 0.0, sensor: str = "lidar", seed: int = 0,
                    **options) -> list[SyntheticCloud]:
    """A sequence of frames from a sensor driving past static and moving obstacles.

    The sensor starts at ``start_xy`` (default: the scene's sensor position) and drives along
    its heading ``yaw_deg`` at ``speed`` m/s, following the terrain; frame k is taken at
    t = k / ``rate_hz`` seconds from the scene at that time (every obstacle moved by its
    velocity, :meth:`Scene.at_time`). Frame k uses the noise seed ``seed + k``. Other keyword
    options go to :func:`sample_lidar` or :func:`sample_stereo`. Each cloud's
    ``world_from_sensor`` is the sensor pose (the odometry truth) and ``time`` its time.
    """
    _check_int(frames=frames)
    _check_positive(rate_hz=rate_hz)
    _check_non_negative(speed=speed)
    if sensor not in ("lidar", "stereo"):
        raise InputError(f"sensor must be 'lidar' or 'stereo'; got {sensor!r}")
    for reserved in ("sensor_xy", "camera_xy", "yaw_deg", "seed"):
        if reserved in options:
            raise InputError(f"sample_sequence sets {reserved} itself; use start_xy, yaw_deg "
                             "and seed")
    x0, y0 = scene.sensor_xy if start_xy is None else start_xy
    _check_finite("start_xy", (x0, y0))
    heading = math.radians(yaw_deg)
    out = []
    for k in range(frames):
        t = k / rate_hz
        at = scene.at_time(t)
        xy = (x0 + speed * t * math.cos(heading), y0 + speed * t * math.sin(heading))
        if sensor == "lidar":
            cloud = sample_lidar(at, sensor_xy=xy, yaw_deg=yaw_deg, seed=seed + k, **options)
        else:
            cloud = sample_stereo(at, camera_xy=xy, yaw_deg=yaw_deg, seed=seed + k, **options)
        out.append(replace(cloud, time=t))
    return out
