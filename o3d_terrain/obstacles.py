"""Obstacle clustering: the points labelled obstacle grouped into obstacles (the paper's step 5).

Broggi et al. 2013 cluster the terrain outliers into obstacle candidates. Here a point is an
obstacle point when the Segmenter labelled it ``OBSTACLE`` (height above the fitted terrain
over the segmentation threshold). Two clusterings are offered:

- ``method="grid"`` (default): the obstacle points are binned into square cells of
  ``cell_size`` metres and the occupied cells are joined into 8-connected components
  (OpenCV ``connectedComponents``); a point belongs to the component of its cell. Two points
  are in one obstacle when a chain of occupied cells links them, so gaps narrower than one
  cell are bridged. Linear in the number of points.
- ``method="dbscan"``: Open3D's ``cluster_dbscan`` on the 3-D obstacle points with radius
  ``eps``.

Clusters with fewer than ``min_points`` points or whose highest point is less than
``min_height`` above the terrain are dropped. Each obstacle carries its point ``indices`` into
the input cloud, centroid, oriented 2-D box (minimum-area rectangle of its points' x, y), height
above the terrain and point count.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ._files import output_path
from ._kernels import obstacles as _k
from .errors import InputError, checked_keywords
from .frame import HEIGHTS_ABOVE_TERRAIN, LABELS, as_frame
from .segment import TerrainLabel

__all__ = ["DetectedObstacle", "ObstacleSet", "detect_obstacles", "CLUSTER_METHODS",
           "CLUSTER_IDS", "oriented_box", "instances_found", "semantic_kitti_instances",
           "SEMANTIC_KITTI_INSTANCE_CLASSES"]

CLUSTER_METHODS = ("grid", "dbscan")

#: per-point attribute written by the ObstacleDetector stage: obstacle id, -1 for none
CLUSTER_IDS = "cluster_ids"

#: the most cells the clustering grid may have (a typo'd cell size should fail, not swap)
MAX_CLUSTER_CELLS = 16_000_000


@dataclass(frozen=True, eq=False)
class DetectedObstacle:
    """One obstacle: its points and their summary, in the cloud's coordinates.

    ``indices``: int64 indices of its points into the input cloud. ``centroid``: mean position
    (x, y, z). ``box_center``, ``box_size`` (length >= width) and ``box_yaw_deg`` (direction of
    the length, counter-clockwise from +x, in (-90, 90]): the minimum-area rectangle around the
    points' x, y. ``height``: highest point above the terrain (m). ``z_min``/``z_max``: lowest
    and highest point z.
    """

    id: int
    indices: np.ndarray
    centroid: np.ndarray
    box_center: np.ndarray
    box_size: np.ndarray
    box_yaw_deg: float
    height: float
    z_min: float
    z_max: float

    @property
    def point_count(self) -> int:
        return int(len(self.indices))

    def corners(self) -> np.ndarray:
        """The box's corners, (4, 2) x, y, counter-clockwise."""
        return _box_corners(self.box_center, self.box_size, self.box_yaw_deg)

    def to_dict(self, *, include_indices: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "id": int(self.id),
            "point_count": self.point_count,
            "centroid": [float(v) for v in self.centroid],
            "box": {
                "center": [float(v) for v in self.box_center],
                "size": [float(v) for v in self.box_size],
                "yaw_deg": float(self.box_yaw_deg),
                "corners": [[float(a), float(b)] for a, b in self.corners()],
            },
            "height_above_terrain": float(self.height),
            "z_range": [float(self.z_min), float(self.z_max)],
        }
        if include_indices:
            out["indices"] = [int(i) for i in self.indices]
        return out


@dataclass(frozen=True, eq=False)
class ObstacleSet:
    """The obstacles of one cloud (the ``obstacles`` product). Iterable and indexable.

    ``cluster_ids`` (N,) int32 gives, for every point of the cloud, the id of its obstacle
    (its position in the set) or -1.
    """

    obstacles: tuple[DetectedObstacle, ...]
    cluster_ids: np.ndarray
    method: str = "grid"
    options: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.obstacles)

    def __iter__(self) -> Iterator[DetectedObstacle]:
        return iter(self.obstacles)

    def __getitem__(self, index: int) -> DetectedObstacle:
        return self.obstacles[index]

    def __repr__(self) -> str:
        return f"ObstacleSet({len(self)} obstacles, method={self.method!r})"

    @property
    def centroids(self) -> np.ndarray:
        """(K, 3) centroids."""
        return np.array([o.centroid for o in self.obstacles]).reshape(-1, 3)

    def to_json(self, *, include_indices: bool = False) -> dict[str, Any]:
        return {
            "kind": "ObstacleSet",
            "method": self.method,
            "options": self.options,
            "point_count": int(len(self.cluster_ids)),
            "obstacles": [o.to_dict(include_indices=include_indices) for o in self.obstacles],
        }

    def save(self, path: str | Path, *, include_indices: bool = False) -> None:
        """Write the obstacles as JSON (see docs/obstacles.md for the fields)."""
        output_path(path).write_text(json.dumps(self.to_json(include_indices=include_indices),
                                         indent=1))


def _box_corners(center, size, yaw_deg) -> np.ndarray:
    a = math.radians(yaw_deg)
    u = np.array([math.cos(a), math.sin(a)]) * size[0] / 2
    v = np.array([-math.sin(a), math.cos(a)]) * size[1] / 2
    c = np.asarray(center, dtype=np.float64)
    return np.array([c + u + v, c - u + v, c - u - v, c + u - v])


def oriented_box(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Minimum-area rectangle of (K, 2) points: (center, (length, width), yaw_deg).

    Length >= width; yaw is the direction of the length in (-90, 90] degrees (see
    :func:`~o3d_terrain._kernels.obstacles.min_area_boxes` for ties and degenerate sets).
    Computed in float64 on coordinates relative to the first point.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        raise InputError("oriented_box: no points")
    centers, sizes, yaws = _oriented_boxes(xy, np.array([0, len(xy)], np.int64))
    return centers[0], sizes[0], float(yaws[0])


def _oriented_boxes(xy: np.ndarray, starts: np.ndarray):
    """:func:`oriented_box` of each group ``xy[starts[g]:starts[g + 1]]``: (centers (K, 2),
    sizes (K, 2), yaws (K,))."""
    return _k.min_area_boxes(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                             np.asarray(starts, np.int64))


# ---------------------------------------------------------------------------------------------
# inputs


def _positive(name: str, value, *, allow_zero: bool = False, integer: bool = False) -> str | None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        kind = "an integer" if integer else "a finite number"
        return f"{name} must be {kind} {'>= 0' if allow_zero else '> 0'}, got {value!r}"
    return None


def _per_point(name: str, values, n: int) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim == 2 and array.shape[1] == 1:
        array = array[:, 0]
    if array.shape != (n,):
        raise InputError(f"detect_obstacles: {name} must have one value per point ({n},), got "
                         f"shape {array.shape}")
    return array


def resolve_heights_and_labels(frame, surface=None, labels=None, heights=None,
                               threshold: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Heights above the terrain and labels for a frame: given arrays first, then the frame's
    ``heights_above_terrain``/``labels`` attributes, then computed from ``surface``, then from a
    terrain fitted here with the library defaults."""
    n = len(frame)
    positions = frame.positions
    if heights is not None:
        heights = _per_point("heights_above_terrain", heights, n).astype(np.float64)
    elif frame.has_attribute(HEIGHTS_ABOVE_TERRAIN):
        heights = np.asarray(frame.attribute(HEIGHTS_ABOVE_TERRAIN), dtype=np.float64)
    else:
        if surface is None:
            from .api import fit_terrain

            surface = fit_terrain(positions)
        if not callable(surface):
            raise InputError(f"detect_obstacles: surface must be a TerrainSurface (callable as "
                             f"surface(x, y)), got {type(surface).__name__}")
        heights = positions[:, 2] - np.asarray(surface(positions[:, 0], positions[:, 1]))
    if labels is not None:
        labels = _per_point("labels", labels, n)
    elif frame.has_attribute(LABELS):
        labels = np.asarray(frame.attribute(LABELS))
    else:
        labels = np.full(n, TerrainLabel.UNKNOWN, np.uint8)
        known = np.isfinite(heights)
        labels[known] = TerrainLabel.TERRAIN
        labels[known & (heights > threshold)] = TerrainLabel.OBSTACLE
    return heights, labels


# ---------------------------------------------------------------------------------------------
# clustering


def _grid_size(ix: np.ndarray, iy: np.ndarray, cell_size: float) -> tuple[int, int]:
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    if nx * ny > MAX_CLUSTER_CELLS:
        raise InputError(
            f"detect_obstacles: the obstacle points span {nx * cell_size:.0f} m x "
            f"{ny * cell_size:.0f} m, {nx * ny} cells of {cell_size} m (limit "
            f"{MAX_CLUSTER_CELLS}); use a larger cell_size or crop the cloud")
    return nx, ny


def _grid_components(ix: np.ndarray, iy: np.ndarray, nx: int,
                     ny: int) -> tuple[np.ndarray, np.ndarray]:
    """Component id (0..K-1) of each point (8-connected occupied cells), and the (nx, ny)
    int32 label image (component id + 1, 0 for empty cells)."""
    import cv2

    mask = _k.occupancy_mask(ix, iy, nx, ny)
    if nx >= 32767 or ny >= 32767:  # OpenCV image sides are limited to 2^15
        from scipy import ndimage

        components, _ = ndimage.label(mask, structure=np.ones((3, 3)))
    else:
        _, components = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    components = np.ascontiguousarray(components, dtype=np.int32)
    return _k.labels_at(components, ix, iy, -1), components


def _dbscan_components(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points - points.mean(axis=0)))
    return np.asarray(cloud.cluster_dbscan(eps=eps, min_points=min_points), dtype=np.int64)


def _hull_candidates(points: np.ndarray, cluster: np.ndarray, ix, iy, nx: int, ny: int,
                     n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """Candidate hull points grouped by cluster: (order, starts) over point indices, for
    clusterings where clusters may share a cell (DBSCAN): cells are keyed by (cluster, cell).
    """
    inside = cluster >= 0
    key = cluster * (nx * ny) + ix * ny + iy
    unique, rank = np.unique(key[inside], return_inverse=True)
    cell = np.zeros(len(points), np.int64)
    cell[inside] = rank
    sub = np.flatnonzero(inside)
    best = _k.hull_candidates(cell[sub], points[sub, 0], points[sub, 1], len(unique))
    candidates = np.unique(sub[best[best >= 0]])
    order, starts = _k.group_by(cluster[candidates], n_clusters)
    return candidates[order], starts


@checked_keywords()
def detect_obstacles(cloud: Any, *, surface=None, labels: np.ndarray | None = None,
                     heights_above_terrain: np.ndarray | None = None, method: str = "grid",
                     cell_size: float = 0.3, eps: float = 0.5, min_points: int = 5,
                     min_height: float = 0.3, max_height: float | None = None,
                     threshold: float = 0.2) -> ObstacleSet:
    """Cluster the obstacle points of a cloud into obstacles.

    cloud: anything :func:`~o3d_terrain.frame.as_frame` accepts (Open3D cloud, (N, 3) array,
        Frame); never modified. Obstacle ``indices`` index into it.
    surface: the terrain (a TerrainSurface); used when the cloud has no
        ``heights_above_terrain``; None with no heights = fit the terrain here.
    labels, heights_above_terrain: per-point arrays (N,) overriding the cloud's attributes.
        Without labels a point is an obstacle point when its height exceeds ``threshold``.
    method: "grid" (8-connected cells of ``cell_size`` m) or "dbscan" (radius ``eps`` m).
    min_points: fewest points an obstacle may have. min_height: lowest top height above the
        terrain (m) an obstacle may have. max_height: obstacle points higher than this above
        the terrain (overhangs: branches, wires) are left out; None keeps them all.
    """
    problems = [p for p in (
        _positive("cell_size", cell_size), _positive("eps", eps),
        _positive("min_points", min_points, integer=True),
        _positive("min_height", min_height, allow_zero=True),
        _positive("threshold", threshold),
        None if max_height is None else _positive("max_height", max_height),
    ) if p]
    if method not in CLUSTER_METHODS:
        problems.append(f"method must be one of {', '.join(CLUSTER_METHODS)}, got {method!r}")
    if problems:
        raise InputError("detect_obstacles: " + "; ".join(problems))
    frame = as_frame(cloud)
    n = len(frame)
    options = {"cell_size": float(cell_size), "eps": float(eps), "min_points": int(min_points),
               "min_height": float(min_height), "max_height": max_height}
    cluster_ids = np.full(n, -1, np.int32)
    if n == 0:
        return ObstacleSet((), cluster_ids, method, options)
    heights, labels = resolve_heights_and_labels(frame, surface, labels, heights_above_terrain,
                                                 threshold)
    positions = np.asarray(frame.positions)
    members, points, member_heights, ix, iy = _k.obstacle_points(
        np.ascontiguousarray(labels), positions, np.ascontiguousarray(heights),
        int(TerrainLabel.OBSTACLE), np.inf if max_height is None else float(max_height),
        float(cell_size))
    if len(members) == 0:
        return ObstacleSet((), cluster_ids, method, options)
    nx, ny = _grid_size(ix, iy, float(cell_size))
    if method == "grid":
        component, cell_labels = _grid_components(ix, iy, nx, ny)
    else:
        component = _dbscan_components(points, float(eps), min(3, int(min_points)))
    n_components = int(component.max()) + 1 if len(component) else 0
    count, sums, z_low, z_high, h_high = _k.cluster_moments(
        component, points[:, 0], points[:, 1], points[:, 2], member_heights, n_components)
    keep = (count >= min_points) & (h_high >= min_height)
    kept = np.flatnonzero(keep)
    new_id = np.full(max(n_components, 1), -1, np.int64)
    new_id[kept] = np.arange(len(kept))
    point_ids, indices_all, starts = _k.relabel_points(component, new_id, members, cluster_ids,
                                                       len(kept))
    if method == "grid":  # the cluster is a function of the cell
        hull_x, hull_y, hull_starts = _k.grid_box_candidates(
            point_ids, ix, iy, cell_labels, points[:, 0], points[:, 1], len(kept))
        centers, sizes, yaws = _k.min_area_boxes(hull_x, hull_y, hull_starts)
    else:
        hull, hull_starts = _hull_candidates(points, point_ids, ix, iy, nx, ny, len(kept))
        centers, sizes, yaws = _oriented_boxes(points[hull, :2], hull_starts)
    centroids = sums[kept] / count[kept][:, None]
    heights_kept = h_high[kept]
    obstacles = _obstacles_from_arrays(indices_all, starts, centroids, centers, sizes, yaws,
                                       heights_kept, z_low[kept], z_high[kept])
    result = ObstacleSet(obstacles, cluster_ids, method, options)
    # the arrays behind the obstacles' boxes and heights, for the cost map (not a field: it
    # adds nothing to the value; the box centres and sizes are the same memory as the
    # obstacles' own arrays)
    object.__setattr__(result, "_arrays", (centers, sizes, yaws, heights_kept))
    return result


def _obstacles_from_arrays(indices_all, starts, centroids, centers, sizes, yaws, heights,
                           z_low, z_high) -> tuple[DetectedObstacle, ...]:
    """The DetectedObstacle values of K obstacles given as arrays (obstacle g: indices
    ``indices_all[starts[g]:starts[g + 1]]``, row g of the others; arrays are shared as views).

    Each value's fields are written straight into its ``__dict__``, as the generated frozen
    ``__init__`` would (it sets them one by one through ``object.__setattr__``), from Python
    lists: 184 KITTI obstacles in 0.15 ms instead of 0.8 ms.
    """
    make = object.__new__
    bounds = starts.tolist()
    yaw_list, height_list = yaws.tolist(), heights.tolist()
    low_list, high_list = z_low.tolist(), z_high.tolist()
    out = []
    for g in range(len(yaw_list)):
        obstacle = make(DetectedObstacle)
        obstacle.__dict__.update(
            id=g, indices=indices_all[bounds[g]:bounds[g + 1]], centroid=centroids[g],
            box_center=centers[g], box_size=sizes[g], box_yaw_deg=yaw_list[g],
            height=height_list[g], z_min=low_list[g], z_max=high_list[g])
        out.append(obstacle)
    return tuple(out)



# ---------------------------------------------------------------------------------------------
# scoring against instance truth

#: SemanticKITTI classes scored as object instances: vehicles, people, riders (and their
#: moving variants), trunk, pole, traffic sign
SEMANTIC_KITTI_INSTANCE_CLASSES = (10, 11, 13, 15, 16, 18, 20, 30, 31, 32, 71, 80, 81,
                                   252, 253, 254, 255, 256, 257, 258, 259)


def instances_found(cluster_ids: np.ndarray, instance_ids: np.ndarray,
                    min_points: int = 50) -> dict[int, bool]:
    """Per true instance with at least ``min_points`` points: True when at least half of its
    points lie in one obstacle. ``cluster_ids`` (N,) obstacle id per point (-1 none),
    ``instance_ids`` (N,) true instance per point (-1 none)."""
    cluster_ids = np.asarray(cluster_ids)
    instance_ids = np.asarray(instance_ids)
    out = {}
    for k in np.unique(instance_ids[instance_ids >= 0]):
        members = instance_ids == k
        if members.sum() < min_points:
            continue
        c = cluster_ids[members]
        c = c[c >= 0]
        out[int(k)] = bool(len(c)) and bool(np.bincount(c).max() >= 0.5 * members.sum())
    return out


def semantic_kitti_instances(labels: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Instance id per point of :data:`SEMANTIC_KITTI_INSTANCE_CLASSES`, -1 elsewhere, from
    SemanticKITTI labels (semantic id in the lower 16 bits, instance in the upper 16).

    Trunk, pole and traffic-sign points carry instance 0 in SemanticKITTI, so for classes
    without instance ids an instance is a 0.5 m single-linkage connected component (Open3D
    DBSCAN with one point) of that class's points.
    """
    import open3d as o3d

    labels = np.asarray(labels, dtype=np.uint32)
    semantic = labels & 0xFFFF
    out = np.full(len(labels), -1, np.int64)
    objects = np.isin(semantic, SEMANTIC_KITTI_INSTANCE_CLASSES)
    with_id = objects & ((labels >> 16) > 0)
    _, out[with_id] = np.unique(labels[with_id], return_inverse=True)
    next_id = out.max() + 1
    for cls in np.unique(semantic[objects & ~with_id]):
        members = np.flatnonzero(objects & ~with_id & (semantic == cls))
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(positions[members]))
        parts = np.asarray(pcd.cluster_dbscan(eps=0.5, min_points=1))
        out[members] = parts + next_id
        next_id += parts.max() + 1
    return out
