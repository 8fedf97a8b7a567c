"""A rendered, rectified stereo pair of a Scene with exact per-pixel depth and disparity.

Both cameras are ray cast with Open3D's ``RaycastingScene``. Surfaces are coloured by a
procedural texture of their **world** coordinates (multi-octave 3-D value noise) under
Lambertian sun light, so a surface point has the same intensity in both images (no
view-dependent effect): the right image equals the left one shifted by the true disparity,
up to sensor noise and resampling. The sky is a smooth gradient with no texture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .scene import Scene
from .sensors import (
    SENSOR_FROM_OPTICAL,
    Camera,
    SyntheticCloud,
    _check_non_negative,
    _check_positive,
    cast,
    sensor_pose,
)

#: texture octaves: lattice spacing (metres) of each value-noise layer
_OCTAVES = (0.015, 0.03, 0.06, 0.12, 0.25, 0.5, 1.0, 2.0)
#: albedo of each obstacle kind (terrain is around 0.5)
_ALBEDO = {"car": 0.3, "truck": 0.7, "box": 0.6, "pedestrian": 0.35, "pole": 0.8, "rock": 0.45}
#: direction towards the sun (world), elevation 50°, from the front left
_SUN = np.array([math.cos(math.radians(50)) * math.cos(math.radians(135)),
                 math.cos(math.radians(50)) * math.sin(math.radians(135)),
                 math.sin(math.radians(50))])


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """A uniform value in [0, 1) per integer lattice point (a splitmix64-style mix)."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             ^ iy.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ iz.astype(np.uint64) * np.uint64(0x165667B19E3779F9)
             ^ np.uint64((seed * 0x27D4EB2F165667C5) & 0xFFFFFFFFFFFFFFFF))
        h ^= h >> np.uint64(31)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(29)
        h *= np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(32)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(points: np.ndarray, spacing: float, seed: int = 0) -> np.ndarray:
    """Smooth 3-D value noise in [0, 1] at world points (N, 3), lattice ``spacing`` metres."""
    q = points / spacing
    i = np.floor(q).astype(np.int64)
    f = q - i
    s = f * f * (3.0 - 2.0 * f)
    out = np.zeros(len(points))
    for dx in (0, 1):
        wx = s[:, 0] if dx else 1.0 - s[:, 0]
        for dy in (0, 1):
            wy = s[:, 1] if dy else 1.0 - s[:, 1]
            for dz in (0, 1):
                wz = s[:, 2] if dz else 1.0 - s[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def texture(points: np.ndarray, seed: int = 0) -> np.ndarray:
    """Multi-octave value noise of world points, zero mean, about unit standard deviation."""
    total = np.zeros(len(points))
    for k, spacing in enumerate(_OCTAVES):
        total += value_noise(points, spacing, seed + 7919 * k) - 0.5
    return total / (0.2 * math.sqrt(len(_OCTAVES)))


def shade(scene: Scene, points: np.ndarray, index: np.ndarray, normals: np.ndarray,
          directions: np.ndarray, seed: int) -> np.ndarray:
    """Intensity in [0, 1] of hit points (index -2 = sky, shaded from the ray direction)."""
    out = np.empty(len(points))
    sky = index == -2
    elevation = directions[sky, 2] / np.linalg.norm(directions[sky], axis=1)
    out[sky] = 0.85 - 0.15 * np.clip(elevation, 0.0, 1.0)
    hit = ~sky
    albedo = np.full(int(hit.sum()), 0.5)
    kinds = index[hit]
    for i, obstacle in enumerate(scene.obstacles):
        albedo[kinds == i] = _ALBEDO.get(obstacle.kind, 0.5)
    p = points[hit]
    n = normals[hit]
    # a surface seen from its back side (inside an obstacle) still gets light
    light = np.abs(n @ _SUN)
    pattern = np.clip(1.0 + 0.35 * texture(p, seed), 0.2, 1.8)
    out[hit] = albedo * pattern * (0.35 + 0.65 * light)
    return np.clip(out, 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class StereoPair:
    """A rectified grayscale stereo pair with exact truth for the left camera.

    ``left``/``right`` are (H, W) uint8. ``calibration`` holds ``fx, fy, cx, cy`` (pixels),
    ``baseline`` (metres), ``width``, ``height``: the plain calibration mapping the stereo
    reader takes. ``depth`` (H, W) is the true depth Z along the optical axis (inf where the
    pixel sees the sky), ``disparity`` = fx·baseline/Z (0 for the sky), ``obstacle_ids``
    (H, W) int32 (-1 terrain, -2 sky, else the obstacle index). ``world_from_left`` is the
    left camera's pose with sensor axes (x forward, y left, z up); the optical frame
    (x right, y down, z forward) is ``world_from_left_optical``. The right camera sits
    ``baseline`` metres to the right of the left one (sensor −y).
    """

    left: np.ndarray
    right: np.ndarray
    calibration: dict
    depth: np.ndarray
    disparity: np.ndarray
    obstacle_ids: np.ndarray
    world_from_left: np.ndarray
    scene: Scene

    @property
    def world_from_left_optical(self) -> np.ndarray:
        pose = self.world_from_left.copy()
        pose[:3, :3] = pose[:3, :3] @ SENSOR_FROM_OPTICAL
        return pose

    @property
    def world_from_right(self) -> np.ndarray:
        pose = self.world_from_left.copy()
        pose[:3, 3] += pose[:3, :3] @ np.array([0.0, -self.calibration["baseline"], 0.0])
        return pose

    def true_cloud(self, *, max_range: float = np.inf) -> SyntheticCloud:
        """The noise-free points of every left pixel that sees a surface (left sensor frame)."""
        cal = self.calibration
        camera = Camera(cal["width"], cal["height"], cal["fx"], cal["cx"], cal["cy"])
        v, u = np.nonzero(np.isfinite(self.depth) & (self.depth <= max_range))
        points = camera.directions(u.astype(np.float64), v.astype(np.float64)) \
            * self.depth[v, u][:, None]
        return SyntheticCloud(points, points.copy(), self.obstacle_ids[v, u].astype(np.int64),
                              self.world_from_left, self.scene, "stereo")

    def write(self, folder: str | Path) -> dict[str, Path]:
        """Write left.png, right.png, calibration.yaml, disparity.npy and depth.npy."""
        import cv2
        import yaml

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = {name: folder / name for name in
                 ("left.png", "right.png", "calibration.yaml", "disparity.npy", "depth.npy")}
        for name, image in (("left.png", self.left), ("right.png", self.right)):
            if not cv2.imwrite(str(paths[name]), image):
                raise InputError(f"could not write {paths[name]}; check the folder is writable")
        paths["calibration.yaml"].write_text(yaml.safe_dump(dict(self.calibration), sort_keys=False))
        np.save(paths["disparity.npy"], self.disparity)
        np.save(paths["depth.npy"], self.depth)
        return paths


def render_stereo_pair(scene: Scene, *, width: int = 640, height: int = 480,
                       focal_px: float | None = None, baseline: float = 0.3, camera_xy=None,
                       camera_height: float = 1.6, yaw_deg: float = 0.0, tilt_deg=(0.0, 5.0),
                       supersample: int = 1, image_noise: float = 1.0, seed: int = 0) -> StereoPair:
    """Render the left and right images of a rectified stereo rig looking at ``scene``.

    The left camera stands ``camera_height`` metres above the terrain at ``camera_xy``
    (default: the scene's sensor position) with heading ``yaw_deg`` and ``tilt_deg =
    (roll, pitch)`` (pitch positive = looking down). ``focal_px`` defaults to 0.8·width.
    Each pixel averages ``supersample``² rays (2 anti-aliases the far texture at 4× the cost;
    semi-global matching does as well with 1); the true depth is that of the pixel centre.
    Gaussian noise of ``image_noise`` grey levels is added to each
    image independently.
    """
    camera = Camera.make(width, height, focal_px)
    _check_positive(baseline=baseline, camera_height=camera_height)
    _check_non_negative(image_noise=image_noise)
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) \
            or not 1 <= supersample <= 8:
        raise InputError(f"supersample must be an integer in [1, 8]; got {supersample!r}")
    left_pose = sensor_pose(scene, sensor_xy=camera_xy, sensor_height=camera_height,
                            yaw_deg=yaw_deg, tilt_deg=tilt_deg)
    rotation = left_pose[:3, :3]
    right_origin = left_pose[:3, 3] + rotation @ np.array([0.0, -baseline, 0.0])
    rng = np.random.default_rng(seed)

    # truth: the left camera's pixel centres
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    centre = camera.directions(u.ravel(), v.ravel())
    depth, index, _ = cast(scene, left_pose[:3, 3], centre @ rotation.T, drop_unrefined=False)
    depth = depth.reshape(camera.height, camera.width)
    with np.errstate(divide="ignore"):
        disparity = np.where(np.isfinite(depth), camera.focal_px * baseline / depth, 0.0)

    images = []
    for origin in (left_pose[:3, 3], right_origin):
        radiance = np.zeros(camera.height * camera.width)
        offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
        for dv in offsets:
            for du in offsets:
                directions = camera.directions(u.ravel() + du, v.ravel() + dv) @ rotation.T
                t, hit_index, normals = cast(scene, origin, directions, refine=False)
                points = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * directions
                radiance += shade(scene, points, hit_index, normals, directions, scene.seed)
        radiance = 255.0 * radiance / supersample**2
        if image_noise > 0:
            radiance = radiance + rng.normal(0.0, image_noise, radiance.shape)
        images.append(np.clip(np.rint(radiance), 0, 255).astype(np.uint8)
                      .reshape(camera.height, camera.width))

    calibration = {"fx": camera.focal_px, "fy": camera.focal_px, "cx": camera.cx,
                   "cy": camera.cy, "baseline": float(baseline), "width": camera.width,
                   "height": camera.height}
    return StereoPair(images[0], images[1], calibration, depth, disparity,
                      index.reshape(camera.height, camera.width).astype(np.int32), left_pose,
                      scene)
