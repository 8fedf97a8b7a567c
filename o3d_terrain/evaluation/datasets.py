"""Labelled frames for evaluation: SemanticKITTI folders, LAS/LAZ tiles, synthetic scenes.

Each source yields :class:`LabelledFrame` objects, or :class:`FrameFailure` objects for frames
that could not be read (a batch keeps going past a bad frame and reports it). Positions are
float64 and in metres: LAS tiles whose coordinate system is in feet are converted on reading
(the scale factor is kept in ``LabelledFrame.metres_per_unit``), so every method sees metric
data and metric parameters (cell sizes, thresholds) mean the same on every tile.

Ground sets
-----------
* SemanticKITTI: 40 road, 44 parking, 48 sidewalk, 49 other-ground, 60 lane-marking,
  72 terrain (the Patchwork/Patchwork++ convention). 0 (unlabeled) and 1 (outlier) are not
  scored. Obstacles: vehicles, people, riders, buildings, fences, structures, trunks, poles,
  signs, other objects and the moving classes.
* LAS/LAZ (ASPRS): class 2 is ground. 0 (never classified), 7 (low noise) and 18 (high noise)
  are not scored. Obstacles: 4 medium vegetation, 5 high vegetation, 6 building, 14 wire
  conductor, 15 transmission tower, 17 bridge deck.
* Synthetic scenes: every point not on an obstacle is ground; the exact terrain is known.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import InputError
from ..io import las_positions, open_las

SEMANTIC_KITTI_GROUND = (40, 44, 48, 49, 60, 72)
SEMANTIC_KITTI_IGNORED = (0, 1)
SEMANTIC_KITTI_OBSTACLE = (
    10, 11, 13, 15, 16, 18, 20,  # vehicles
    30, 31, 32,  # person, bicyclist, motorcyclist
    50, 51, 52,  # building, fence, other-structure
    71, 80, 81, 99,  # trunk, pole, traffic-sign, other-object
    252, 253, 254, 255, 256, 257, 258, 259,  # moving vehicles and people
)
LAS_GROUND = (2,)
LAS_IGNORED = (0, 7, 18)
LAS_OBSTACLE = (4, 5, 6, 14, 15, 17)

#: the synthetic stereo rig as its user knows it from calibration (``sample_stereo``'s
#: defaults): focal length 0.8 x 320 px, baseline 0.3 m, disparity noise 0.25 px; clouds are in
#: the left camera's frame, so the camera is at the origin
SYNTHETIC_STEREO_RIG = {"focal_px": 0.8 * 320, "baseline": 0.3, "disparity_noise_px": 0.25}

#: frame kinds: how the points were captured (some peers need to know, e.g. Patchwork++)
KINDS = ("vehicle_lidar", "aerial", "stereo")


@dataclass(frozen=True, eq=False)
class LabelledFrame:
    """One labelled cloud: positions (metres) and per-point truth masks."""

    name: str
    positions: np.ndarray  # (N, 3) float64, metres
    is_ground: np.ndarray  # (N,) bool
    scored: np.ndarray  # (N,) bool: points that count in the scores
    obstacle: np.ndarray | None = None  # (N,) bool
    terrain: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None  # exact z(x, y)
    kind: str = "vehicle_lidar"
    source: str = ""
    metres_per_unit: float = 1.0
    sensor_height: float | None = None  # sensor height above the ground (m) when known
    range_noise: Any = None  # the sensor's o3d_terrain.noise.RangeNoise when known (stereo)
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self):
        n = self.positions.shape[0]
        if self.positions.ndim != 2 or self.positions.shape[1] != 3:
            raise InputError(f"{self.name}: positions have shape {self.positions.shape}; need (N, 3)")
        for label, mask in (("is_ground", self.is_ground), ("scored", self.scored),
                            ("obstacle", self.obstacle)):
            if mask is not None and (mask.shape != (n,) or mask.dtype != bool):
                raise InputError(
                    f"{self.name}: the {label} mask has shape {mask.shape} and dtype "
                    f"{mask.dtype}; it must be ({n},) bool"
                )
        if self.kind not in KINDS:
            raise InputError(f"{self.name}: kind '{self.kind}' is not one of {', '.join(KINDS)}")

    def __len__(self) -> int:
        return int(self.positions.shape[0])


@dataclass(frozen=True)
class FrameFailure:
    """A frame that could not be read or evaluated, and why."""

    name: str
    source: str
    reason: str


FrameOrFailure = LabelledFrame | FrameFailure


# ---------------------------------------------------------------------------------------------
# SemanticKITTI


def semantic_kitti_frames(folder: str | os.PathLike, *, limit: int | None = None
                          ) -> Iterator[FrameOrFailure]:
    """Frames of a SemanticKITTI sequence folder holding ``velodyne/*.bin`` and ``labels/*.label``.

    A scan without a label file, or with a label count that does not match its points, is
    yielded as a :class:`FrameFailure`.
    """
    folder = Path(folder)
    velodyne = folder / "velodyne"
    labels = folder / "labels"
    if not velodyne.is_dir():
        raise InputError(
            f"{folder}: no 'velodyne' folder; a SemanticKITTI sequence folder holds "
            "velodyne/NNNNNN.bin and labels/NNNNNN.label"
        )
    scans = sorted(velodyne.glob("*.bin"))
    if not scans:
        raise InputError(f"{velodyne}: no .bin scans found")
    for scan in scans[:limit]:
        label_path = labels / (scan.stem + ".label")
        try:
            yield read_semantic_kitti_frame(scan, label_path)
        except (InputError, OSError, ValueError) as exc:
            yield FrameFailure(scan.stem, str(scan), str(exc))


def read_semantic_kitti_frame(scan_path: str | os.PathLike, label_path: str | os.PathLike
                              ) -> LabelledFrame:
    """One SemanticKITTI scan with its labels (the semantic id is the lower 16 bits)."""
    scan_path, label_path = Path(scan_path), Path(label_path)
    if not label_path.exists():
        raise InputError(f"{scan_path.name}: no label file {label_path}; every scan needs one")
    size = scan_path.stat().st_size
    if size == 0 or size % 16:
        raise InputError(
            f"{scan_path}: {size} bytes is not a whole, non-zero number of KITTI points "
            "(16 bytes each: x, y, z, remission as float32)"
        )
    data = np.fromfile(scan_path, dtype=np.float32).reshape(-1, 4)
    semantic = np.fromfile(label_path, dtype=np.uint32) & 0xFFFF
    if semantic.shape[0] != data.shape[0]:
        raise InputError(
            f"{scan_path.name}: {data.shape[0]} points but {semantic.shape[0]} labels in "
            f"{label_path.name}; the label file must have one uint32 per point"
        )
    positions = data[:, :3].astype(np.float64)
    finite = np.isfinite(positions).all(axis=1)
    return LabelledFrame(
        name=scan_path.stem,
        positions=positions,
        is_ground=np.isin(semantic, SEMANTIC_KITTI_GROUND),
        scored=~np.isin(semantic, SEMANTIC_KITTI_IGNORED) & finite,
        obstacle=np.isin(semantic, SEMANTIC_KITTI_OBSTACLE),
        kind="vehicle_lidar",
        source=str(scan_path),
        sensor_height=None,  # about 1.73 m; peers keep their KITTI defaults
    )


# ---------------------------------------------------------------------------------------------
# LAS / LAZ


def read_las_frame(path: str | os.PathLike) -> LabelledFrame:
    """A LAS/LAZ tile with its ASPRS classes; feet are converted to metres."""
    path = Path(path)
    las = open_las(path)
    positions, units = las_positions(las, to_metres=True)
    factor, unit_source = units.horizontal, units.source
    classification = np.asarray(las.classification, dtype=np.int64)
    notes = ()
    if factor != 1.0:
        notes = (f"coordinates in feet ({unit_source}); converted to metres (x {factor:.7f})",)
    is_ground = np.isin(classification, LAS_GROUND)
    if not is_ground.any():
        notes += ("no point has class 2 (ground): recall is undefined on this tile",)
    return LabelledFrame(
        name=path.name,
        positions=positions,
        is_ground=is_ground,
        scored=~np.isin(classification, LAS_IGNORED) & np.isfinite(positions).all(axis=1),
        obstacle=np.isin(classification, LAS_OBSTACLE),
        kind="aerial",
        source=str(path),
        metres_per_unit=factor,
        notes=notes,
    )


def las_frames(path: str | os.PathLike) -> Iterator[FrameOrFailure]:
    """Frames of one LAS/LAZ file or of every ``*.las``/``*.laz`` in a folder."""
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".las", ".laz"))
        if not files:
            raise InputError(f"{path}: no .las or .laz files in this folder")
    elif path.exists():
        files = [path]
    else:
        raise InputError(f"{path}: no such file or folder")
    for file in files:
        try:
            yield read_las_frame(file)
        except (InputError, OSError, ValueError) as exc:
            yield FrameFailure(file.name, str(file), str(exc))


# ---------------------------------------------------------------------------------------------
# synthetic scenes


#: the sensors of ``synthetic:NAME[:SENSOR]`` (``o3d_terrain.synthetic.sample_SENSOR``)
SYNTHETIC_SENSORS = ("lidar", "stereo", "solid_state")


def synthetic_frames(names: Sequence[str], *, seed: int = 0, sensor: str = "lidar"
                     ) -> Iterator[FrameOrFailure]:
    """Frames sampled from the project's synthetic scenes (exact terrain and obstacle truth) by
    one of :data:`SYNTHETIC_SENSORS`: a spinning lidar, a stereo-like depth sensor, or a
    forward-looking solid-state lidar with a non-repetitive scan (``solid_state``)."""
    if sensor not in SYNTHETIC_SENSORS:
        close = difflib.get_close_matches(sensor, SYNTHETIC_SENSORS, n=1)
        raise InputError(f"synthetic sensor '{sensor}' is not one of "
                         f"{', '.join(SYNTHETIC_SENSORS)}"
                         + (f"; did you mean '{close[0]}'?" if close else ""))
    try:
        from .. import synthetic
        make_scene = synthetic.make_scene
        sample = getattr(synthetic, f"sample_{sensor}")
    except (ImportError, AttributeError) as exc:
        raise InputError(
            f"the synthetic scene generator (o3d_terrain.synthetic.make_scene/sample_{sensor}) "
            f"is not available in this build ({exc})"
        ) from exc
    return _synthetic_frames(make_scene, sample, names, seed, sensor)


def _synthetic_frames(make_scene, sample, names, seed, sensor) -> Iterator[FrameOrFailure]:
    """The frames of :func:`synthetic_frames` once its sensor is known to exist."""
    for name in names:
        try:
            scene = make_scene(name, seed=seed)
            cloud = sample(scene, seed=seed)
            positions = np.asarray(cloud.positions, dtype=np.float64)
            obstacle = np.asarray(cloud.is_obstacle, dtype=bool)
            outlier = np.asarray(getattr(cloud, "is_outlier", np.zeros(len(obstacle), bool)),
                                 dtype=bool)
            finite = np.isfinite(positions).all(axis=1) & ~outlier
            yield LabelledFrame(
                name=f"{name}-{sensor}",
                positions=positions,
                is_ground=~obstacle,
                scored=finite,
                obstacle=obstacle,
                terrain=_terrain_in_sensor_frame(cloud, scene),
                kind="stereo" if sensor == "stereo" else "vehicle_lidar",
                source=f"synthetic:{name}:seed={seed}",
                sensor_height=_sensor_height(cloud),
                range_noise=_stereo_noise() if sensor == "stereo" else None,
            )
        except Exception as exc:  # report the scene and keep going
            yield FrameFailure(f"{name}-{sensor}", f"synthetic:{name}", f"{type(exc).__name__}: {exc}")


def _stereo_noise():
    """The noise model of :data:`SYNTHETIC_STEREO_RIG` (what a user gives for such a rig)."""
    from ..noise import RangeNoise

    return RangeNoise.from_stereo(**SYNTHETIC_STEREO_RIG)


def _sensor_height(cloud) -> float | None:
    """Height of the synthetic sensor above the terrain below it (m)."""
    try:
        pose = np.asarray(cloud.world_from_sensor)
        x, y, z = pose[:3, 3]
        return float(z - cloud.scene.height(np.array([x]), np.array([y]))[0])
    except Exception:  # an older generator without a pose: unknown
        return None


def _terrain_in_sensor_frame(cloud, scene) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The exact terrain height in the cloud's frame (the generator's helper when it has one)."""
    for attribute in ("terrain_height", "height", "terrain"):
        helper = getattr(cloud, attribute, None)
        if callable(helper):
            return helper
    return scene.height


def synthetic_scene_names() -> tuple[str, ...]:
    """Names of the synthetic scenes, or () when the generator is not available."""
    try:
        from .. import synthetic
    except ImportError:
        return ()
    for attribute in ("SCENE_NAMES", "SCENES", "scene_names"):
        names = getattr(synthetic, attribute, None)
        if callable(names):
            names = names()
        if names:
            return tuple(names)
    return ()


# ---------------------------------------------------------------------------------------------
# any source


def open_dataset(spec: str | os.PathLike, *, seed: int = 0, limit: int | None = None
                 ) -> Iterator[FrameOrFailure]:
    """Frames of a dataset given as a path or ``synthetic:NAME[,NAME...][:SENSOR]`` (SENSOR one
    of :data:`SYNTHETIC_SENSORS`, default lidar).

    A folder with ``velodyne/`` is read as SemanticKITTI; a LAS/LAZ file or a folder of them as
    ASPRS-classified tiles.
    """
    text = str(spec)
    if text.startswith("synthetic"):
        parts = text.split(":")
        names = [n for n in (parts[1].split(",") if len(parts) > 1 else []) if n]
        if not names or names == ["all"]:
            names = list(synthetic_scene_names())
            if not names:
                raise InputError("synthetic: no scene names known; give them: synthetic:NAME,NAME")
        sensor = parts[2] if len(parts) > 2 else "lidar"
        return synthetic_frames(names[:limit] if limit else names, seed=seed, sensor=sensor)
    path = Path(text)
    if path.is_dir() and (path / "velodyne").is_dir():
        return semantic_kitti_frames(path, limit=limit)
    if path.is_dir() or path.suffix.lower() in (".las", ".laz"):
        frames = las_frames(path)
        return (f for i, f in enumerate(frames) if limit is None or i < limit)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    raise InputError(
        f"{path}: not a labelled dataset; give a SemanticKITTI sequence folder (with velodyne/ "
        "and labels/), a LAS/LAZ file or folder, or synthetic:NAME"
    )


def data_root() -> Path | None:
    """The shared real-data folder: ``$O3D_TERRAIN_DATA`` or ``../shared/data`` from the repo."""
    env = os.environ.get("O3D_TERRAIN_DATA")
    if env:
        return Path(env) if Path(env).is_dir() else None
    candidate = Path(__file__).resolve().parents[2].parent / "shared" / "data"
    return candidate if candidate.is_dir() else None


def iter_frames(sources: Iterable[FrameOrFailure]) -> tuple[list[LabelledFrame], list[FrameFailure]]:
    """Split a stream into readable frames and failures."""
    good, bad = [], []
    for item in sources:
        (bad if isinstance(item, FrameFailure) else good).append(item)
    return good, bad
