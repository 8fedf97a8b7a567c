"""Synthetic off-road scenes: an analytic terrain plus obstacles standing on it.

A :class:`Scene` knows its terrain exactly (height, gradient, slope at any (x, y)) and its
obstacles exactly (footprint, top). :func:`make_scene` builds the named scenes of
:data:`SCENES`; :func:`section6_scene` builds the flat road with one box of Broggi et al. 2013,
Sec. VI. Scenes are deterministic: the same name and seed give the same scene.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d

from ..errors import InputError, did_you_mean
from .terrain import Feature, Hill, Plane, Ramp, Ridge, Roughness, Valley

#: the shape used to model each obstacle kind
OBSTACLE_SHAPES = {
    "car": "box",
    "truck": "box",
    "box": "box",
    "pedestrian": "cylinder",
    "pole": "cylinder",
    "rock": "ellipsoid",
    "tree": "tree",
}

#: a tree's crown starts this share of its height above the ground (its trunk below), and its
#: trunk's diameter is this share of the crown's mean diameter (at least 0.15 m)
TREE_CROWN_BASE = 0.45
TREE_TRUNK_SHARE = 0.08

#: how far an obstacle's mesh reaches below the lowest terrain under its footprint (metres)
_SINK = 0.3


@dataclass(frozen=True)
class Obstacle:
    """An obstacle standing on the terrain.

    ``center`` is (x, y) in metres; ``size`` is (length, width) in metres along and across the
    heading ``yaw_deg`` (for a cylinder both are the diameter); ``height`` is the height of
    its top above the terrain at its centre; ``velocity`` (m/s, world x and y) moves it with
    :meth:`at_time`. Boxes (car, truck, box) are vertical prisms with a flat top; cylinders
    (pedestrian, pole) likewise; a rock is the upper half of an ellipsoid centred on the
    terrain at ``center`` (semi-axes length/2, width/2, height). A tree is a vertical trunk
    (a cylinder :data:`TREE_TRUNK_SHARE` of the crown's diameter wide) under an ellipsoidal
    crown ``size`` wide that spans from :data:`TREE_CROWN_BASE` of ``height`` to ``height``
    (the free space under the crown is an overhang a vehicle's lidar sees ground through);
    its footprint is the crown's.
    """

    kind: str
    center: tuple[float, float]
    size: tuple[float, float]
    height: float
    yaw_deg: float = 0.0
    velocity: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        if self.kind not in OBSTACLE_SHAPES:
            raise InputError(
                f"obstacle kind must be one of {', '.join(OBSTACLE_SHAPES)}; got {self.kind!r}"
            )
        values = (*self.center, *self.size, self.height, self.yaw_deg, *self.velocity)
        if not all(math.isfinite(v) for v in values):
            raise InputError(f"obstacle {self.kind!r} has a non-finite value: {values}")
        if min(self.size) <= 0 or self.height <= 0:
            raise InputError(
                f"obstacle {self.kind!r} needs a positive size and height; got size "
                f"{self.size}, height {self.height}"
            )

    @property
    def shape(self) -> str:
        return OBSTACLE_SHAPES[self.kind]

    def at_time(self, t: float) -> Obstacle:
        """The obstacle after ``t`` seconds of motion at its velocity."""
        cx, cy = self.center
        vx, vy = self.velocity
        return replace(self, center=(cx + vx * t, cy + vy * t))

    def _local(self, x, y):
        a = math.radians(self.yaw_deg)
        dx = np.asarray(x, dtype=np.float64) - self.center[0]
        dy = np.asarray(y, dtype=np.float64) - self.center[1]
        return dx * math.cos(a) + dy * math.sin(a), -dx * math.sin(a) + dy * math.cos(a)

    def contains(self, x, y, *, margin: float = 0.0):
        """True where (x, y) is inside the footprint grown by ``margin`` metres."""
        u, v = self._local(x, y)
        half_l = self.size[0] / 2 + margin
        half_w = self.size[1] / 2 + margin
        if self.shape == "box":
            return (np.abs(u) <= half_l) & (np.abs(v) <= half_w)
        return (u / half_l) ** 2 + (v / half_w) ** 2 <= 1.0

    def footprint(self, segments: int = 32) -> np.ndarray:
        """The footprint outline, (K, 2) world x, y (4 corners for a box)."""
        half_l, half_w = self.size[0] / 2, self.size[1] / 2
        if self.shape == "box":
            local = np.array([[half_l, half_w], [-half_l, half_w], [-half_l, -half_w],
                              [half_l, -half_w]])
        else:
            angles = np.linspace(0, 2 * math.pi, segments, endpoint=False)
            local = np.stack([half_l * np.cos(angles), half_w * np.sin(angles)], axis=1)
        a = math.radians(self.yaw_deg)
        rotation = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        return local @ rotation.T + np.asarray(self.center)


@dataclass(frozen=True, eq=False)
class Scene:
    """Exact terrain (a sum of analytic features) and the obstacles standing on it.

    ``region`` is (x_min, x_max, y_min, y_max) in metres: the terrain mesh covers it, so a
    sensor sees nothing beyond it. ``sensor_xy`` is the suggested sensor position.
    """

    name: str
    features: tuple[Feature, ...]
    obstacles: tuple[Obstacle, ...] = ()
    region: tuple[float, float, float, float] = (-5.0, 35.0, -15.0, 15.0)
    sensor_xy: tuple[float, float] = (0.0, 0.0)
    seed: int = 0
    time: float = 0.0
    #: spacing of the terrain mesh used for ray casting (metres); hits are then refined onto
    #: the analytic surface, so this only affects speed and which surface shades the images
    mesh_spacing: float = 0.25
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- exact terrain -----------------------------------------------------------------------
    def height(self, x, y) -> np.ndarray:
        """Terrain height z at (x, y) (arrays of any broadcastable shape), metres."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                   np.asarray(y, dtype=np.float64))
        z = np.zeros(x.shape)
        for feature in self.features:
            z = z + feature.height(x, y)
        return z

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(dz/dx, dz/dy) of the terrain at (x, y), exact."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                   np.asarray(y, dtype=np.float64))
        gx = np.zeros(x.shape)
        gy = np.zeros(x.shape)
        for feature in self.features:
            fx, fy = feature.gradient(x, y)
            gx = gx + fx
            gy = gy + fy
        return gx, gy

    def slope_deg(self, x, y) -> np.ndarray:
        """Terrain slope (angle of the steepest descent to the horizontal), degrees."""
        gx, gy = self.gradient(x, y)
        return np.degrees(np.arctan(np.hypot(gx, gy)))

    def normal(self, x, y) -> np.ndarray:
        """Unit upward terrain normal, shape (..., 3)."""
        gx, gy = self.gradient(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # -- obstacles ---------------------------------------------------------------------------
    def obstacle_ground(self, index: int) -> float:
        """Terrain height under the centre of obstacle ``index`` (its base reference)."""
        cx, cy = self.obstacles[index].center
        return float(self.height(cx, cy))

    def obstacle_top(self, index: int) -> float:
        """World z of the top of obstacle ``index``."""
        return self.obstacle_ground(index) + self.obstacles[index].height

    def obstacle_at(self, x, y, *, margin: float = 0.0) -> np.ndarray:
        """Index of the obstacle whose footprint holds (x, y), or -1 (the last one wins)."""
        x = np.asarray(x, dtype=np.float64)
        out = np.full(x.shape, -1, dtype=np.int64)
        for i, obstacle in enumerate(self.obstacles):
            out[obstacle.contains(x, y, margin=margin)] = i
        return out

    def surface_height(self, x, y) -> np.ndarray:
        """Height of the top visible surface: terrain, or obstacle top inside a footprint.

        For rocks the ellipsoid's own height is used, for trees their crown's top. A reference
        for occupancy maps.
        """
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                   np.asarray(y, dtype=np.float64))
        z = np.array(self.height(x, y), dtype=np.float64)
        for i, obstacle in enumerate(self.obstacles):
            inside = obstacle.contains(x, y)
            if not inside.any():
                continue
            if obstacle.shape in ("ellipsoid", "tree"):
                u, v = obstacle._local(x[inside], y[inside])
                r = 1.0 - (u / (obstacle.size[0] / 2)) ** 2 - (v / (obstacle.size[1] / 2)) ** 2
                if obstacle.shape == "ellipsoid":
                    centre, reach = self.obstacle_ground(i), obstacle.height
                else:
                    centre, reach = _crown(obstacle, self.obstacle_ground(i))
                top = centre + reach * np.sqrt(np.clip(r, 0, None))
            else:
                top = np.full(int(inside.sum()), self.obstacle_top(i))
            z[inside] = np.maximum(z[inside], top)
        return z

    # -- variants ----------------------------------------------------------------------------
    def without_obstacles(self) -> Scene:
        """The same terrain with no obstacle (the reference of Sec. VI comparisons)."""
        return replace(self, obstacles=(), _cache={})

    def with_obstacles(self, obstacles: Sequence[Obstacle]) -> Scene:
        return replace(self, obstacles=tuple(obstacles), _cache={})

    def with_region(self, region) -> Scene:
        """The same scene over another (x_min, x_max, y_min, y_max) region, metres."""
        try:
            region = tuple(float(v) for v in region)
        except (TypeError, ValueError):
            raise InputError("region must be 4 numbers (x_min, x_max, y_min, y_max); got "
                             f"{region!r}") from None
        if len(region) != 4 or not all(math.isfinite(v) for v in region) \
                or not (region[1] > region[0] and region[3] > region[2]):
            raise InputError("region must be 4 finite numbers with x_max > x_min and "
                             f"y_max > y_min; got {region!r}")
        return replace(self, region=region, _cache={})

    def at_time(self, t: float) -> Scene:
        """The scene ``t`` seconds later: every obstacle moved by its velocity."""
        return replace(self, obstacles=tuple(o.at_time(t) for o in self.obstacles),
                       time=self.time + t, _cache={})

    # -- meshes ------------------------------------------------------------------------------
    def terrain_mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (V, 3) float64 and triangles (T, 3) int of the terrain over the region."""
        x_min, x_max, y_min, y_max = self.region
        nx = max(2, math.ceil((x_max - x_min) / self.mesh_spacing) + 1)
        ny = max(2, math.ceil((y_max - y_min) / self.mesh_spacing) + 1)
        xs = np.linspace(x_min, x_max, nx)
        ys = np.linspace(y_min, y_max, ny)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        vertices = np.stack([gx.ravel(), gy.ravel(), self.height(gx, gy).ravel()], axis=1)
        index = np.arange(nx * ny).reshape(nx, ny)
        a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
        c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
        triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        return vertices, triangles

    def obstacle_mesh_arrays(self, index: int, *, segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
        """Vertices and triangles of obstacle ``index`` placed on the terrain."""
        obstacle = self.obstacles[index]
        ground = self.obstacle_ground(index)
        top = ground + obstacle.height
        if obstacle.shape == "ellipsoid":
            return _ellipsoid(obstacle, ground, segments)
        if obstacle.shape == "tree":
            return self._tree_mesh_arrays(obstacle, ground, segments)
        outline = obstacle.footprint(segments)
        fx = np.concatenate([outline[:, 0], [obstacle.center[0]]])
        fy = np.concatenate([outline[:, 1], [obstacle.center[1]]])
        bottom = float(self.height(fx, fy).min()) - _SINK
        return _prism(outline, bottom, top)

    def _tree_mesh_arrays(self, obstacle: Obstacle, ground: float, segments: int):
        """A tree's trunk (from below the terrain to the crown's centre) and crown."""
        centre, reach = _crown(obstacle, ground)
        trunk = replace(obstacle, kind="pole", size=(_trunk_diameter(obstacle),) * 2)
        outline = trunk.footprint(segments)
        bottom = float(self.height(outline[:, 0], outline[:, 1]).min()) - _SINK
        v1, t1 = _prism(outline, bottom, centre)
        crown = replace(obstacle, kind="rock", height=reach)
        v2, t2 = _ellipsoid(crown, centre, segments)
        return np.concatenate([v1, v2]), np.concatenate([t1, t2 + len(v1)])

    def mesh(self) -> o3d.t.geometry.TriangleMesh:
        """Terrain and obstacles as one tensor triangle mesh (float64 vertices)."""
        parts = [self.terrain_mesh_arrays()]
        parts += [self.obstacle_mesh_arrays(i) for i in range(len(self.obstacles))]
        vertices, triangles, offset = [], [], 0
        for v, t in parts:
            vertices.append(v)
            triangles.append(t + offset)
            offset += len(v)
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(np.concatenate(vertices))
        mesh.triangle.indices = o3d.core.Tensor(np.concatenate(triangles).astype(np.int32))
        return mesh

    def raycasting_scene(self) -> tuple[o3d.t.geometry.RaycastingScene, dict[int, int]]:
        """An Open3D ray casting scene and the map geometry id -> obstacle index (-1 terrain).

        Built once per scene and cached.
        """
        if "raycasting" not in self._cache:
            scene = o3d.t.geometry.RaycastingScene()
            ids = {}
            v, t = self.terrain_mesh_arrays()
            ids[scene.add_triangles(_f32(v), _u32(t))] = -1
            for i in range(len(self.obstacles)):
                v, t = self.obstacle_mesh_arrays(i)
                ids[scene.add_triangles(_f32(v), _u32(t))] = i
            self._cache["raycasting"] = (scene, ids)
        return self._cache["raycasting"]


def _f32(a: np.ndarray) -> o3d.core.Tensor:
    return o3d.core.Tensor(np.ascontiguousarray(a, dtype=np.float32))


def _u32(a: np.ndarray) -> o3d.core.Tensor:
    return o3d.core.Tensor(np.ascontiguousarray(a, dtype=np.uint32))


def _prism(outline: np.ndarray, bottom: float, top: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed vertical prism over a convex counter-clockwise outline."""
    k = len(outline)
    low = np.column_stack([outline, np.full(k, bottom)])
    high = np.column_stack([outline, np.full(k, top)])
    centre = outline.mean(axis=0)
    vertices = np.concatenate([low, high, [[*centre, bottom], [*centre, top]]])
    triangles = []
    for i in range(k):
        j = (i + 1) % k
        triangles += [[i, j, k + j], [i, k + j, k + i]]  # side
        triangles += [[2 * k + 1, k + i, k + j]]  # top
        triangles += [[2 * k, j, i]]  # bottom
    return vertices, np.array(triangles)


def _crown(tree: Obstacle, ground: float) -> tuple[float, float]:
    """(z of the centre, vertical semi-axis) of a tree's crown standing on ``ground``."""
    base = ground + TREE_CROWN_BASE * tree.height
    top = ground + tree.height
    return (base + top) / 2, (top - base) / 2


def _trunk_diameter(tree: Obstacle) -> float:
    return max(0.15, TREE_TRUNK_SHARE * (tree.size[0] + tree.size[1]) / 2)


def _ellipsoid(obstacle: Obstacle, ground: float, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """A full ellipsoid centred on the terrain at the obstacle's centre (lower half buried)."""
    rings = max(4, segments // 2)
    theta = np.linspace(0, math.pi, rings + 1)  # from the top pole to the bottom pole
    phi = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    a, b, c = obstacle.size[0] / 2, obstacle.size[1] / 2, obstacle.height
    st, ct = np.sin(theta[1:-1]), np.cos(theta[1:-1])
    u = (a * st[:, None] * np.cos(phi)[None, :]).ravel()
    v = (b * st[:, None] * np.sin(phi)[None, :]).ravel()
    w = (c * ct[:, None] * np.ones_like(phi)[None, :]).ravel()
    yaw = math.radians(obstacle.yaw_deg)
    x = obstacle.center[0] + u * math.cos(yaw) - v * math.sin(yaw)
    y = obstacle.center[1] + u * math.sin(yaw) + v * math.cos(yaw)
    body = np.column_stack([x, y, ground + w])
    poles = np.array([[*obstacle.center, ground + c], [*obstacle.center, ground - c]])
    vertices = np.concatenate([body, poles])
    n_body = len(body)
    top_pole, bottom_pole = n_body, n_body + 1
    triangles = []
    for j in range(segments):
        k = (j + 1) % segments
        triangles.append([top_pole, j, k])
        last = (rings - 2) * segments
        triangles.append([bottom_pole, last + k, last + j])
    for r in range(rings - 2):
        for j in range(segments):
            k = (j + 1) % segments
            a0, a1 = r * segments + j, r * segments + k
            b0, b1 = (r + 1) * segments + j, (r + 1) * segments + k
            triangles += [[a0, b0, b1], [a0, b1, a1]]
    return vertices, np.array(triangles)


# ---------------------------------------------------------------------------------------------
# named scenes


def _obstacle_set(rng: np.random.Generator) -> tuple[Obstacle, ...]:
    """One obstacle of every kind ahead of the sensor (positions fixed, small seeded jitter)."""
    def j() -> float:  # a small seeded jitter of a position
        return float(rng.uniform(-0.3, 0.3))

    return (
        Obstacle("pole", (8.0 + j(), 4.0 + j()), (0.2, 0.2), 3.0),
        Obstacle("pedestrian", (10.0 + j(), -2.5 + j()), (0.5, 0.5), 1.75),
        Obstacle("car", (15.0 + j(), 3.0 + j()), (4.5, 1.8), 1.5, yaw_deg=20.0),
        Obstacle("rock", (18.0 + j(), -5.0 + j()), (1.4, 1.0), 0.7, yaw_deg=35.0),
        Obstacle("truck", (27.0 + j(), -1.0 + j()), (8.0, 2.5), 3.5, yaw_deg=-10.0),
    )


def _mounds(rng: np.random.Generator, count: int, x_range, y_range) -> tuple[Hill, ...]:
    out = []
    for _ in range(count):
        sigma = float(rng.uniform(0.7, 1.5))
        out.append(Hill(float(rng.uniform(*x_range)), float(rng.uniform(*y_range)),
                        float(rng.uniform(0.4, 1.0)), sigma, sigma * float(rng.uniform(0.8, 1.25))))
    return tuple(out)


def _flat(rng):
    return (Plane(),), ()


def _hills(rng):
    return (
        Plane(slope_x=0.02),
        Hill(14.0, 7.0, 1.8, 4.0, 3.0),
        Hill(26.0, -6.0, 2.5, 5.0, 4.0),
        Hill(20.0, 12.0, -1.0, 3.0, 3.0),
        Roughness.random(rng, amplitude=0.03),
    ), ()


def _ramp(rng):
    # flat to x = 8, a 10° ramp to x = 20 (2.12 m rise), a plateau beyond
    return (Ramp(8.0, 0.0, 0.0, 10.0, 12.0),), ()


def _ditch_berm(rng):
    return (
        Ridge(12.0, 0.0, 90.0, -0.8, 0.6),  # a ditch across the path at x = 12
        Ridge(0.0, 6.0, 0.0, 1.0, 0.8),  # a berm along the path at y = 6
        Roughness.random(rng, amplitude=0.02),
    ), ()


def _valley(rng):
    return (Valley(0.0, 0.0, 0.0, 3.0, 6.0), Plane(slope_x=-0.02),
            Roughness.random(rng, amplitude=0.02)), ()


def _gravel_mounds(rng):
    return (Plane(),) + _mounds(rng, 8, (6.0, 32.0), (-12.0, 12.0)), ()


def _offroad(rng):
    features = (
        Plane(slope_x=0.02),
        Hill(24.0, 9.0, 1.5, 4.0, 3.0),
        Ridge(0.0, -9.0, 0.0, -0.6, 0.6),  # a ditch along the right edge of the track
        Ridge(0.0, 8.0, 0.0, 0.8, 0.8),  # a berm along the left edge
        Ramp(20.0, 0.0, 0.0, 6.0, 8.0),
        Roughness.random(rng, amplitude=0.03),
    ) + _mounds(rng, 3, (24.0, 33.0), (-14.0, -11.0))
    return features, _obstacle_set(rng)


def _forest(rng):
    """A steep forested hillside: the ground rises 25° across the track (y), with a gully
    along it and a knoll; trees and bushes (low ellipsoids) everywhere but within 4 m of the
    sensor."""
    features = (Plane(slope_x=0.05, slope_y=math.tan(math.radians(25.0))),
                Ridge(0.0, -5.0, 0.0, -1.0, 1.2), Hill(22.0, 7.0, 2.5, 5.0, 4.0),
                Roughness.random(rng, amplitude=0.05))
    return features, forest_obstacles(rng, (-3.0, 34.0), (-14.0, 14.0), count=40,
                                      clear_radius=4.0)


def forest_obstacles(rng: np.random.Generator, x_range, y_range, *, count: int = 40,
                     trees: int = 30, clear_radius: float = 4.0) -> tuple[Obstacle, ...]:
    """``count`` obstacles at random (x, y) within the ranges, none within ``clear_radius``
    of the origin (the sensor): first ``trees`` trees (crowns 3-6 m wide, 8-16 m tall), then
    rocks and bushes (low ellipsoids 1-2.5 m wide, 0.5-1.4 m high), turned at random. The
    ``forest`` scene's vegetation, and that of other scenes built on the same pattern."""
    obstacles = []
    while len(obstacles) < count:
        x, y = float(rng.uniform(*x_range)), float(rng.uniform(*y_range))
        if math.hypot(x, y) < clear_radius:
            continue
        if len(obstacles) < trees:
            width = float(rng.uniform(3.0, 6.0))
            obstacles.append(Obstacle("tree", (x, y), (width, width * float(rng.uniform(0.8, 1.2))),
                                      float(rng.uniform(8.0, 16.0)),
                                      yaw_deg=float(rng.uniform(0.0, 180.0))))
        else:
            width = float(rng.uniform(1.0, 2.5))
            obstacles.append(Obstacle("rock", (x, y), (width, width * float(rng.uniform(0.6, 1.0))),
                                      float(rng.uniform(0.5, 1.4)),
                                      yaw_deg=float(rng.uniform(0.0, 180.0))))
    return tuple(obstacles)


def _crossing(rng):
    """Moving obstacles for sequences: a pedestrian crossing, a car coming, a truck leaving."""
    features = (Plane(slope_x=0.01), Hill(26.0, 10.0, 1.5, 4.0, 3.0),
                Roughness.random(rng, amplitude=0.02))
    def j() -> float:  # a small seeded jitter of a position
        return float(rng.uniform(-0.3, 0.3))

    obstacles = (
        Obstacle("pedestrian", (12.0 + j(), -6.0 + j()), (0.5, 0.5), 1.75, velocity=(0.0, 1.4)),
        Obstacle("car", (30.0 + j(), 3.0 + j()), (4.5, 1.8), 1.5, yaw_deg=180.0,
                 velocity=(-6.0, 0.0)),
        Obstacle("truck", (20.0 + j(), -3.0 + j()), (8.0, 2.5), 3.5, velocity=(4.0, 0.0)),
        Obstacle("pole", (9.0, 5.0), (0.2, 0.2), 3.0),
        Obstacle("rock", (16.0, 4.0), (1.2, 1.0), 0.6),
    )
    return features, obstacles


_BUILDERS = {
    "flat": _flat,
    "hills": _hills,
    "ramp": _ramp,
    "ditch_berm": _ditch_berm,
    "valley": _valley,
    "mounds": _gravel_mounds,
    "offroad": _offroad,
    "crossing": _crossing,
    "forest": _forest,
}

#: the named scenes and what they hold
SCENES: dict[str, str] = {
    "flat": "a horizontal plane z = 0",
    "hills": "three Gaussian hills/hollows on a 2% slope with 3 cm undulations",
    "ramp": "flat, then a 10° ramp rising along x from x = 8 m to x = 20 m, then a plateau",
    "ditch_berm": "a 0.8 m deep ditch across the path at x = 12 m and a 1 m berm along y = 6 m",
    "valley": "a hyperbolic valley along x (flanks tending to 26.6°), falling 2% along x",
    "mounds": "eight gravel mounds 0.4-1.0 m high on flat ground (seeded positions)",
    "offroad": "a track between a ditch and a berm, a hill, a 6° ramp, gravel mounds; "
               "a pole, a pedestrian, a car, a rock and a truck",
    "crossing": "gentle slope and a hill; a pedestrian crossing (1.4 m/s), an oncoming car "
                "(6 m/s), a truck driving away (4 m/s), a static pole and rock (for sequences)",
    "section6": "the paper's Sec. VI: flat road, one box at (11, 0); 22 m x 22 m",
    "forest": "a 25° hillside with a gully and a knoll under 30 trees (8-16 m, crowns from "
              "45 % of their height) and 10 bushes (seeded)",
}


def make_scene(name: str = "offroad", *, seed: int = 0, obstacles: bool = True,
               region=None) -> Scene:
    """The named scene (see :data:`SCENES`), deterministic in ``seed``.

    ``obstacles=False`` gives the bare terrain. Only ``offroad``, ``crossing``, ``forest`` and
    ``section6`` have obstacles; add some with :meth:`Scene.with_obstacles` (for example
    :func:`default_obstacles`). ``region`` (x_min, x_max, y_min, y_max) in metres replaces
    the default 40 m × 30 m extent (the terrain is defined everywhere; a larger region gives
    a lidar more to see, e.g. (-40, 40, -40, 40) for a full 360° frame).
    """
    if name not in SCENES:
        hint = did_you_mean(str(name), list(SCENES))
        raise InputError(f"unknown scene {name!r}" + (f" ({hint})" if hint else "")
                         + f"; scenes are: {', '.join(SCENES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise InputError(f"seed must be an integer; got {seed!r}")
    if name == "section6":
        scene = section6_scene()
    else:
        rng = np.random.default_rng(int(seed))
        features, obstacle_set = _BUILDERS[name](rng)
        scene = Scene(name, tuple(features), obstacle_set, seed=int(seed))
    if not obstacles:
        scene = scene.without_obstacles()
    if region is not None:
        scene = scene.with_region(region)
    return scene


def default_obstacles(seed: int = 0) -> tuple[Obstacle, ...]:
    """One obstacle of each kind (pole, pedestrian, car, rock, truck), as in ``offroad``."""
    return _obstacle_set(np.random.default_rng(int(seed)))


def section6_scene(*, obstacle_height: float = 1.0, obstacle_width: float = 2.0,
                   obstacle_depth: float = 1.0, obstacle_x: float = 11.0) -> Scene:
    """Broggi et al. 2013, Sec. VI: a flat road and one box obstacle at (obstacle_x, 0).

    The area of interest is 22 m x 22 m ahead of the sensor: x in [0, 22], y in [-11, 11].
    ``obstacle_width`` is across the road (y), ``obstacle_depth`` along it (x); the paper
    varies the height over 0.5-3 m and the width over 0.8-12 m.
    """
    for label, value in (("obstacle_height", obstacle_height), ("obstacle_width", obstacle_width),
                         ("obstacle_depth", obstacle_depth)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise InputError(f"section6_scene: {label} must be a positive number of metres; "
                             f"got {value!r}")
    box = Obstacle("box", (float(obstacle_x), 0.0), (float(obstacle_depth), float(obstacle_width)),
                   float(obstacle_height))
    return Scene("section6", (Plane(),), (box,), region=(-2.0, 24.0, -11.0, 11.0))
