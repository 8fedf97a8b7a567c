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
* RELLIS-3D (off-road, SemanticKITTI file format): 1 dirt, 3 grass, 10 asphalt, 23 concrete,
  31 puddle, 33 mud are ground; 0 (void) and 7 (sky) are not scored. Obstacles: 4 tree, 5 pole,
  8 vehicle, 9 object, 12 building, 15 log, 17 person, 18 fence, 27 barrier. Bush, water and
  rubble count as not ground but stay out of obstacle recall (as SemanticKITTI's vegetation).
* Synthetic scenes: every point not on an obstacle is ground; the exact terrain is known.

Any other ontology is a :class:`LabelSet` of its own (``eval segmentation --ground-labels``):
the presets are in :data:`LABEL_SETS`.
"""

from __future__ import annotations

import difflib
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import InputError
from ..io import las_positions, las_returns, open_las

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
RELLIS_3D_GROUND = (1, 3, 10, 23, 31, 33)
RELLIS_3D_IGNORED = (0, 7)
RELLIS_3D_OBSTACLE = (4, 5, 8, 9, 12, 15, 17, 18, 27)


@dataclass(frozen=True)
class LabelSet:
    """Which per-point label ids are ground, which are not scored, and which count for obstacle
    recall (``obstacle`` None: every scored point that is not ground)."""

    name: str
    ground: tuple[int, ...]
    ignored: tuple[int, ...] = ()
    obstacle: tuple[int, ...] | None = None

    def __post_init__(self):
        where = f"label set '{self.name}'"
        sets = {"ground": self.ground, "ignored": self.ignored, "obstacle": self.obstacle or ()}
        for part, ids in sets.items():
            if any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0
                   for i in ids):
                raise InputError(f"{where}: the {part} labels {list(ids)} must be "
                                 "non-negative integers")
        if not self.ground:
            raise InputError(f"{where}: no ground label; give at least one ground id")
        for a, b in (("ground", "ignored"), ("ground", "obstacle"), ("ignored", "obstacle")):
            both = sorted(set(sets[a]) & set(sets[b]))
            if both:
                raise InputError(f"{where}: label(s) {both} are both {a} and {b}; "
                                 f"a label id can be in one of them only")

    def masks(self, ids: np.ndarray, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                    np.ndarray]:
        """(is_ground, scored, obstacle) per point from its label id and finiteness."""
        is_ground = np.isin(ids, self.ground)
        scored = ~np.isin(ids, self.ignored) & finite
        obstacle = ~is_ground & scored if self.obstacle is None else np.isin(ids, self.obstacle)
        return is_ground, scored, obstacle

    def with_ids(self, *, ground: Sequence[int] | None = None,
                 ignored: Sequence[int] | None = None,
                 obstacle: Sequence[int] | str | None = None) -> "LabelSet":
        """This set with the parts given replaced (the name marks the change); ``obstacle``
        "all" = every scored label that is not ground."""
        if ground is None and ignored is None and obstacle is None:
            return self
        return LabelSet(
            f"{self.name} (changed)",
            tuple(self.ground if ground is None else ground),
            tuple(self.ignored if ignored is None else ignored),
            self.obstacle if obstacle is None else None if obstacle == "all" else tuple(obstacle))

    def describe(self) -> str:
        obstacle = "every other scored label" if self.obstacle is None else \
            ", ".join(map(str, self.obstacle))
        return (f"{self.name}: ground {', '.join(map(str, self.ground))}; not scored "
                f"{', '.join(map(str, self.ignored)) or 'none'}; obstacles {obstacle}")


#: the label sets known by name (``eval segmentation --labels NAME``)
LABEL_SETS = {
    "semantickitti": LabelSet("semantickitti", SEMANTIC_KITTI_GROUND, SEMANTIC_KITTI_IGNORED,
                              SEMANTIC_KITTI_OBSTACLE),
    "rellis3d": LabelSet("rellis3d", RELLIS_3D_GROUND, RELLIS_3D_IGNORED, RELLIS_3D_OBSTACLE),
    "asprs": LabelSet("asprs", LAS_GROUND, LAS_IGNORED, LAS_OBSTACLE),
}


def label_set(name: str | LabelSet) -> LabelSet:
    """A :class:`LabelSet` by its name in :data:`LABEL_SETS` (a LabelSet is returned as is)."""
    if isinstance(name, LabelSet):
        return name
    key = str(name).lower().replace("-", "").replace("_", "")
    if key not in LABEL_SETS:
        close = difflib.get_close_matches(key, LABEL_SETS, n=1)
        raise InputError(f"label set '{name}' is not one of {', '.join(LABEL_SETS)}"
                         + (f"; did you mean '{close[0]}'?" if close else
                            "; give the ids instead (--ground-labels, --ignore-labels)"))
    return LABEL_SETS[key]


#: scan and label folders of a sequence folder in the SemanticKITTI file format, with the label
#: set a layout implies: SemanticKITTI's own, and RELLIS-3D's Ouster scans
SEQUENCE_LAYOUTS = (
    ("velodyne", "labels", "semantickitti"),
    ("os1_cloud_node_kitti_bin", "os1_cloud_node_semantickitti_label_id", "rellis3d"),
)


def sequence_layout(folder: str | os.PathLike) -> tuple[Path, Path, str] | None:
    """(scan folder, label folder, label set name) of a sequence folder, None when ``folder``
    has none of :data:`SEQUENCE_LAYOUTS`' scan folders."""
    folder = Path(folder)
    for scans, labels, name in SEQUENCE_LAYOUTS:
        if (folder / scans).is_dir():
            return folder / scans, folder / labels, name
    return None

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
    #: (return numbers, numbers of returns), (N,) int each, when the file gives them (LAS)
    returns: tuple[np.ndarray, np.ndarray] | None = None

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
        if self.returns is not None and (len(self.returns) != 2 or any(
                np.shape(r) != (n,) for r in self.returns)):
            raise InputError(f"{self.name}: returns must be (return numbers, numbers of "
                             f"returns), {n} values each")

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


def semantic_kitti_frames(folder: str | os.PathLike, *, limit: int | None = None,
                          labels: str | LabelSet | None = None, prefix: str = ""
                          ) -> Iterator[FrameOrFailure]:
    """Frames of a sequence folder in the SemanticKITTI file format: ``velodyne/*.bin`` with
    ``labels/*.label`` (SemanticKITTI), or RELLIS-3D's ``os1_cloud_node_kitti_bin/`` with
    ``os1_cloud_node_semantickitti_label_id/`` (:data:`SEQUENCE_LAYOUTS`).

    ``labels``: the :class:`LabelSet` (or its name); None = the one the layout implies.
    ``prefix`` goes before each frame's name (the sequence, when reading several). A scan
    without a label file, or with a label count that does not match its points, is yielded
    as a :class:`FrameFailure`.
    """
    folder = Path(folder)
    layout = sequence_layout(folder)
    if layout is None:
        raise InputError(
            f"{folder}: no 'velodyne' folder; a SemanticKITTI sequence folder holds "
            "velodyne/NNNNNN.bin and labels/NNNNNN.label (RELLIS-3D: "
            "os1_cloud_node_kitti_bin/ and os1_cloud_node_semantickitti_label_id/)"
        )
    scan_folder, label_folder, implied = layout
    chosen = label_set(implied if labels is None else labels)
    scans = sorted(scan_folder.glob("*.bin"))
    if not scans:
        raise InputError(f"{scan_folder}: no .bin scans found")
    for scan in scans[:limit]:
        label_path = label_folder / (scan.stem + ".label")
        try:
            yield read_semantic_kitti_frame(scan, label_path, labels=chosen, prefix=prefix)
        except (InputError, OSError, ValueError) as exc:
            yield FrameFailure(prefix + scan.stem, str(scan), str(exc))


def sequence_folders(folder: str | os.PathLike) -> list[Path]:
    """The sequence folders (:func:`sequence_layout`) directly inside ``folder``, sorted by
    name (a dataset root such as ``sequences/`` or RELLIS-3D's ``Rellis-3D/``)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_dir() and sequence_layout(p) is not None)


def read_semantic_kitti_frame(scan_path: str | os.PathLike, label_path: str | os.PathLike, *,
                              labels: str | LabelSet = "semantickitti", prefix: str = ""
                              ) -> LabelledFrame:
    """One scan in the SemanticKITTI file format with its labels (the semantic id is the lower
    16 bits), scored by the :class:`LabelSet` ``labels``."""
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
    is_ground, scored, obstacle = label_set(labels).masks(semantic, finite)
    return LabelledFrame(
        name=prefix + scan_path.stem,
        positions=positions,
        is_ground=is_ground,
        scored=scored,
        obstacle=obstacle,
        kind="vehicle_lidar",
        source=str(scan_path),
        sensor_height=None,  # KITTI: about 1.73 m; peers keep their KITTI defaults
        notes=_ground_notes(is_ground, scored, label_set(labels)),
    )


def _ground_notes(is_ground: np.ndarray, scored: np.ndarray, labels: LabelSet
                  ) -> tuple[str, ...]:
    """A note when no scored point is ground (recall undefined: likely the wrong label set)."""
    if (is_ground & scored).any():
        return ()
    return (f"no scored point has a ground label ({labels.describe()}): recall is undefined; "
            "is this the right label set (--labels, --ground-labels)?",)


# ---------------------------------------------------------------------------------------------
# LAS / LAZ


def read_las_frame(path: str | os.PathLike, *, labels: str | LabelSet = "asprs"
                   ) -> LabelledFrame:
    """A LAS/LAZ tile with its classes scored by the :class:`LabelSet` ``labels`` (ASPRS:
    class 2 is ground); feet are converted to metres."""
    path = Path(path)
    labels = label_set(labels)
    las = open_las(path)
    positions, units = las_positions(las, to_metres=True)
    factor, unit_source = units.horizontal, units.source
    classification = np.asarray(las.classification, dtype=np.int64)
    notes = ()
    if factor != 1.0:
        notes = (f"coordinates in feet ({unit_source}); converted to metres (x {factor:.7f})",)
    is_ground, scored, obstacle = labels.masks(classification,
                                               np.isfinite(positions).all(axis=1))
    if not is_ground.any():
        notes += (f"no point has a ground class ({', '.join(map(str, labels.ground))}): "
                  "recall is undefined on this tile",)
    return LabelledFrame(
        name=path.name,
        positions=positions,
        is_ground=is_ground,
        scored=scored,
        obstacle=obstacle,
        kind="aerial",
        source=str(path),
        metres_per_unit=factor,
        notes=notes,
        returns=las_returns(las),
    )


def las_frames(path: str | os.PathLike, *, labels: str | LabelSet = "asprs"
               ) -> Iterator[FrameOrFailure]:
    """Frames of one LAS/LAZ file or of every ``*.las``/``*.laz`` in a folder (classes scored
    by ``labels``: :func:`read_las_frame`)."""
    labels = label_set(labels)
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".las", ".laz"))
        if not files:
            raise InputError(f"{path}: no .las or .laz files in this folder")
    elif path.exists():
        files = [path]
    else:
        raise InputError(f"{path}: no such file or folder")
    yield from _read_each(files, lambda file: read_las_frame(file, labels=labels))


def _read_each(files: Iterable[Path], read: Callable[[Path], LabelledFrame]
               ) -> Iterator[FrameOrFailure]:
    """``read(file)`` for each file in turn, a :class:`FrameFailure` for one that cannot be
    read (the batch goes on)."""
    for file in files:
        try:
            yield read(file)
        except (InputError, OSError, ValueError) as exc:
            yield FrameFailure(file.name, str(file), str(exc))


# ---------------------------------------------------------------------------------------------
# PLY / PCD clouds with a per-point label attribute


#: the per-point label attributes a labelled PLY/PCD cloud is searched for, in this order (as
#: labelling tools write them: CloudCompare's scalar fields get the ``scalar_`` prefix)
LABEL_FIELDS = ("label", "labels", "semantic", "semantic_label", "class", "classification",
                "scalar_label", "scalar_Label", "scalar_Classification", "scalar_classification")
#: extensions of labelled clouds read with Open3D
LABELLED_CLOUD_EXTENSIONS = (".ply", ".pcd")
#: what such a cloud lacks, and the fix (open_dataset's error, the CLI's usage error)
NO_ONTOLOGY = "a PLY/PCD cloud carries label ids but no ontology"
NAME_THE_LABELS = ("say which ids are ground: --labels NAME (" + ", ".join(LABEL_SETS)
                   + ") or --ground-labels IDS")


def read_labelled_cloud(path: str | os.PathLike, *, labels: str | LabelSet,
                        field: str | None = None) -> LabelledFrame:
    """A PLY/PCD cloud whose points carry a label attribute (``field``, default the first of
    :data:`LABEL_FIELDS` present), scored by the :class:`LabelSet` ``labels``: such a file
    carries no ontology, so the caller names it. The frame's kind is a vehicle's scan when
    points lie around the origin (:func:`o3d_terrain.segment.sensor_in_cloud`), else aerial."""
    from ..io import read_cloud
    from ..segment import sensor_in_cloud

    path = Path(path)
    labels = label_set(labels)
    cloud = read_cloud(path)
    present = [name for name in cloud.point if name != "positions"]
    if field is None:
        found = [name for name in LABEL_FIELDS if name in present]
        if not found:
            raise InputError(f"{path.name}: no label attribute ({', '.join(LABEL_FIELDS)}); "
                             f"its attributes: {', '.join(present) or 'none'}; name one with "
                             "--label-field")
        field = found[0]
    elif field not in present:
        hint = difflib.get_close_matches(field, present, n=1)
        raise InputError(f"{path.name}: no attribute '{field}'"
                         + (f"; did you mean '{hint[0]}'?" if hint else
                            f"; its attributes: {', '.join(present) or 'none'}"))
    values = np.asarray(cloud.point[field].numpy()).reshape(-1)
    finite = np.isfinite(values)
    if not np.all(values[finite] == np.round(values[finite])):
        raise InputError(f"{path.name}: the attribute '{field}' holds non-integer values; "
                         "labels must be integer ids (name another one with --label-field)")
    ids = np.where(finite, values, -1).astype(np.int64)
    positions = np.asarray(cloud.point.positions.numpy(), dtype=np.float64)
    is_ground, scored, obstacle = labels.masks(ids, np.isfinite(positions).all(axis=1) & finite)
    return LabelledFrame(
        name=path.name,
        positions=positions,
        is_ground=is_ground,
        scored=scored,
        obstacle=obstacle,
        kind="vehicle_lidar" if sensor_in_cloud(positions) else "aerial",
        source=str(path),
        notes=(f"labels from the attribute '{field}'",) + _ground_notes(is_ground, scored,
                                                                           labels),
    )


def labelled_cloud_frames(path: str | os.PathLike, *, labels: str | LabelSet,
                          field: str | None = None) -> Iterator[FrameOrFailure]:
    """Frames of one labelled PLY/PCD cloud or of every one in a folder
    (:func:`read_labelled_cloud`); a file that cannot be read is a :class:`FrameFailure`."""
    labels = label_set(labels)
    path = Path(path)
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in LABELLED_CLOUD_EXTENSIONS) \
        if path.is_dir() else [path]
    yield from _read_each(files, lambda file: read_labelled_cloud(file, labels=labels,
                                                                   field=field))


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


def open_dataset(spec: str | os.PathLike, *, seed: int = 0, limit: int | None = None,
                 labels: str | LabelSet | None = None, label_field: str | None = None
                 ) -> Iterator[FrameOrFailure]:
    """Frames of a dataset given as a path or ``synthetic:NAME[,NAME...][:SENSOR]`` (SENSOR one
    of :data:`SYNTHETIC_SENSORS`, default lidar).

    A sequence folder in the SemanticKITTI file format (``velodyne/``, or RELLIS-3D's
    ``os1_cloud_node_kitti_bin/``: :data:`SEQUENCE_LAYOUTS`) is read as one sequence; a folder
    of such sequence folders as all of them (``limit`` frames from each); a LAS/LAZ file or a
    folder of them as classified tiles; a PLY/PCD cloud with a label attribute, or a folder of
    them (:func:`read_labelled_cloud`, its attribute ``label_field`` or found by name).
    ``labels``: the :class:`LabelSet` (or its name) that says which label ids are ground; None
    = the format's own (SemanticKITTI's, RELLIS-3D's for its layout, ASPRS for LAS; a PLY/PCD
    cloud has none and needs it). Synthetic scenes carry their truth and ignore it.
    """
    if labels is not None:
        labels = label_set(labels)  # a wrong name fails here, before any frame is read
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
    if path.is_dir() and sequence_layout(path) is not None:
        return semantic_kitti_frames(path, limit=limit, labels=labels)
    sequences = sequence_folders(path)
    if sequences:
        return (frame for folder in sequences for frame in
                semantic_kitti_frames(folder, limit=limit, labels=labels,
                                      prefix=f"{folder.name}/"))
    if labelled_clouds(path):
        if labels is None:
            raise InputError(f"{path}: {NO_ONTOLOGY}; {NAME_THE_LABELS}")
        return itertools.islice(labelled_cloud_frames(path, labels=labels, field=label_field),
                                limit)
    if path.is_dir() or path.suffix.lower() in (".las", ".laz"):
        return itertools.islice(las_frames(path, labels="asprs" if labels is None else labels),
                                limit)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    raise InputError(
        f"{path}: not a labelled dataset; give a SemanticKITTI sequence folder (with velodyne/ "
        "and labels/), a folder of them, a LAS/LAZ file or folder, a PLY/PCD cloud with a "
        "label attribute, or synthetic:NAME"
    )


def labelled_clouds(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a PLY/PCD file, or a folder holding some and no LAS/LAZ tile."""
    path = Path(path)
    if path.is_file():
        return path.suffix.lower() in LABELLED_CLOUD_EXTENSIONS
    if not path.is_dir():
        return False
    suffixes = {p.suffix.lower() for p in path.iterdir()}
    return bool(suffixes & set(LABELLED_CLOUD_EXTENSIONS)) and not suffixes & {".las", ".laz"}


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
