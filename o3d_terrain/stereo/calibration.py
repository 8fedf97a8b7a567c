"""Stereo calibration: the rectified pinhole model of a stereo pair and its file readers.

A rectified pair is described by the left camera's focal lengths and principal point (pixels),
the baseline (metres) and ``doffs``, the principal-point offset ``cx_right - cx_left`` (pixels,
0 for OpenCV's ``CALIB_ZERO_DISPARITY`` rectification, non-zero in Middlebury files). A pixel
``(u, v)`` of the left image with disparity ``d = u_left - u_right`` lies at depth
``Z = fx * baseline / (d + doffs)`` in the rectified left-camera frame (x right, y down,
z forward), at ``X = (u - cx) Z / fx`` and ``Y = (v - cy) Z / fy``.

Readers (:func:`load_calibration` picks one from the file's content):

==========================  =====================================================================
format                      keys used
==========================  =====================================================================
KITTI ``calib.txt``         ``P2``/``P3`` (colour pair, the default when present) or ``P0``/``P1``
                            (object and odometry format ``key: 12 floats``); ``P_rect_02`` /
                            ``P_rect_03`` (raw ``calib_cam_to_cam.txt``); ``R0_rect`` and
                            ``Tr_velo_to_cam`` when present give :attr:`lidar_to_camera`
Middlebury ``calib.txt``    ``cam0``, ``cam1``, ``doffs``, ``baseline`` (mm), ``width``,
                            ``height``, ``ndisp`` (a disparity-range hint)
OpenCV YAML / XML           ``P1``, ``P2`` (rectified projections), or ``Q``, or the unrectified
(``cv2.FileStorage``)       ``M1, D1, M2, D2, R, T`` (+ ``image_width``/``image_height`` or
                            ``imageSize``): the pair is then rectified before matching
plain YAML                  ``fx``, ``cx``, ``cy``, ``baseline`` (m); optional ``fy``,
                            ``doffs``, ``width``, ``height``
==========================  =====================================================================
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import InputError, did_you_mean

__all__ = [
    "StereoCalibration",
    "UnrectifiedStereo",
    "load_calibration",
    "read_kitti_calibration",
    "read_middlebury_calibration",
    "read_opencv_calibration",
    "read_plain_calibration",
]

#: the keys of a plain YAML calibration (required first)
PLAIN_REQUIRED = ("fx", "cx", "cy", "baseline")
PLAIN_OPTIONAL = ("fy", "doffs", "width", "height")


@dataclass(frozen=True, eq=False)
class UnrectifiedStereo:
    """An OpenCV stereo calibration before rectification (``M1, D1, M2, D2, R, T``).

    :meth:`StereoCalibration.rectify` remaps raw images with it; the rectified model is computed
    by ``cv2.stereoRectify`` for the image size.
    """

    camera_matrix_left: np.ndarray  # M1 (3, 3)
    distortion_left: np.ndarray  # D1
    camera_matrix_right: np.ndarray  # M2 (3, 3)
    distortion_right: np.ndarray  # D2
    rotation: np.ndarray  # R (3, 3): right camera from left camera
    translation: np.ndarray  # T (3,): right camera from left camera, in the calibration's unit
    maps: dict = field(default_factory=dict, repr=False)  # cache: (w, h) -> remap tables

    def rectified(self, width: int, height: int, source: str) -> tuple[np.ndarray, ...]:
        """``(R1, R2, P1, P2)`` of ``cv2.stereoRectify`` for this image size (zero disparity at
        infinity, no black border cropping)."""
        import cv2

        r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
            self.camera_matrix_left, self.distortion_left, self.camera_matrix_right,
            self.distortion_right, (int(width), int(height)), self.rotation,
            self.translation.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )
        if abs(p2[1, 3]) > abs(p2[0, 3]):
            raise InputError(
                f"{source}: the cameras are stacked vertically (stereoRectify gives a vertical "
                "baseline); only side-by-side pairs are supported"
            )
        return r1, r2, p1, p2

    def remap_tables(self, width: int, height: int, source: str) -> tuple[np.ndarray, ...]:
        import cv2

        key = (int(width), int(height))
        if key not in self.maps:
            r1, r2, p1, p2 = self.rectified(width, height, source)
            size = key
            left = cv2.initUndistortRectifyMap(
                self.camera_matrix_left, self.distortion_left, r1, p1, size, cv2.CV_16SC2)
            right = cv2.initUndistortRectifyMap(
                self.camera_matrix_right, self.distortion_right, r2, p2, size, cv2.CV_16SC2)
            self.maps[key] = (*left, *right)
        return self.maps[key]


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """The rectified model of a stereo pair (see the module docstring for the equations).

    ``width``/``height`` are the image size the calibration was made for (``None`` when the file
    does not say). ``disparity_hint`` is a ``(min, max)`` disparity range in pixels suggested by
    the file (Middlebury ``ndisp``). ``lidar_to_camera`` is a 4 × 4 transform from a lidar into
    this rectified left-camera frame (KITTI ``R0_rect · Tr_velo_to_cam`` shifted to the left
    camera). ``unrectified`` is set when the images must be rectified before matching.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float  # metres
    doffs: float = 0.0  # cx_right - cx_left, pixels
    width: int | None = None
    height: int | None = None
    disparity_hint: tuple[float, float] | None = None
    lidar_to_camera: np.ndarray | None = None
    unrectified: UnrectifiedStereo | None = None
    source: str = "calibration"

    def __post_init__(self) -> None:
        problems = []
        for name in ("fx", "fy", "cx", "cy", "baseline", "doffs"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                problems.append(f"'{name}' must be a finite number, got {value!r}")
            else:
                object.__setattr__(self, name, float(value))
        if not problems:
            for name in ("fx", "fy", "baseline"):
                if getattr(self, name) <= 0:
                    problems.append(f"'{name}' must be > 0, got {getattr(self, name)!r}"
                                    + (" (is the right camera on the left?)" if name == "baseline" else ""))
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None:
                if float(value) != int(value) or int(value) <= 0:
                    problems.append(f"'{name}' must be a positive whole number of pixels, got {value!r}")
                else:
                    object.__setattr__(self, name, int(value))
        if problems:
            raise InputError(f"{self.source}: invalid stereo calibration: " + "; ".join(problems))

    # -- derived quantities ---------------------------------------------------------------------
    @property
    def camera_matrix(self) -> np.ndarray:
        """The rectified left camera's 3 × 3 intrinsic matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def Q(self) -> np.ndarray:  # noqa: N802 - OpenCV's name
        """OpenCV's 4 × 4 disparity-to-depth matrix (``cv2.reprojectImageTo3D``), with fy = fx."""
        return np.array([
            [1.0, 0.0, 0.0, -self.cx],
            [0.0, 1.0, 0.0, -self.cy],
            [0.0, 0.0, 0.0, self.fx],
            [0.0, 0.0, 1.0 / self.baseline, self.doffs / self.baseline],
        ])

    def depth_from_disparity(self, disparity: np.ndarray | float) -> np.ndarray:
        """Depth Z in metres of a disparity in pixels (inf or negative where d + doffs <= 0)."""
        d = np.asarray(disparity, dtype=np.float64) + self.doffs
        with np.errstate(divide="ignore"):
            return self.fx * self.baseline / d

    def disparity_from_depth(self, depth: np.ndarray | float) -> np.ndarray:
        """Disparity in pixels of a depth Z in metres."""
        return self.fx * self.baseline / np.asarray(depth, dtype=np.float64) - self.doffs

    def scaled(self, factor: float) -> "StereoCalibration":
        """The calibration of the images resized by ``factor`` (0.5 = half size).

        Pixel centres map as ``u' = (u + 0.5) · factor − 0.5`` (``cv2.resize`` convention).
        """
        if factor == 1:
            return self
        if not (factor > 0 and math.isfinite(factor)):
            raise InputError(f"a calibration scale factor must be > 0, got {factor!r}")
        hint = None
        if self.disparity_hint is not None:
            hint = (self.disparity_hint[0] * factor, self.disparity_hint[1] * factor)
        return replace(
            self,
            fx=self.fx * factor, fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5, cy=(self.cy + 0.5) * factor - 0.5,
            doffs=self.doffs * factor,
            width=None if self.width is None else int(round(self.width * factor)),
            height=None if self.height is None else int(round(self.height * factor)),
            disparity_hint=hint, unrectified=None,
        )

    # -- images -------------------------------------------------------------------------------
    def check_image_size(self, width: int, height: int) -> None:
        """Raise :class:`InputError` when the calibration cannot be for images of this size."""
        if self.width is not None and self.height is not None:
            if (self.width, self.height) != (width, height):
                raise InputError(
                    f"{self.source}: the calibration is for {self.width} × {self.height} images but "
                    f"the images are {width} × {height}; use the calibration of these images, or "
                    f"resize the images to {self.width} × {self.height}"
                )
            return
        if not (0 <= self.cx <= width and 0 <= self.cy <= height):
            raise InputError(
                f"{self.source}: the principal point ({self.cx:.1f}, {self.cy:.1f}) px lies outside "
                f"the {width} × {height} images; the calibration does not match these images "
                "(another camera, or images resized after calibration)"
            )

    def for_images(self, width: int, height: int) -> "StereoCalibration":
        """The rectified calibration for images of this size (rectifying an OpenCV raw
        calibration with ``cv2.stereoRectify`` when needed), checked against the size."""
        if self.unrectified is not None:
            _r1, _r2, p1, p2 = self.unrectified.rectified(width, height, self.source)
            rectified = _from_projections(p1, p2, self.source)
            return replace(rectified, width=width, height=height, unrectified=self.unrectified,
                           disparity_hint=self.disparity_hint)
        self.check_image_size(width, height)
        return self

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Remap raw images into the rectified pair (identity when already rectified)."""
        if self.unrectified is None:
            return left, right
        import cv2

        h, w = left.shape[:2]
        lx, ly, rx, ry = self.unrectified.remap_tables(w, h, self.source)
        return (cv2.remap(left, lx, ly, cv2.INTER_LINEAR),
                cv2.remap(right, rx, ry, cv2.INTER_LINEAR))


# ---------------------------------------------------------------------------------------------
# readers


def load_calibration(path: str | os.PathLike, *, cameras: tuple[str, str] | None = None
                     ) -> StereoCalibration:
    """Read a stereo calibration file, recognising its format from its content.

    ``cameras`` picks the projection matrices of a KITTI file (default ``("P2", "P3")`` when
    present, else ``("P0", "P1")``). A :class:`StereoCalibration` is returned unchanged; a
    mapping is read like a plain YAML calibration.
    """
    if isinstance(path, StereoCalibration):
        return path
    if isinstance(path, Mapping):
        return calibration_from_mapping(path, source="calibration mapping")
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"a calibration must be a file path, a mapping or a StereoCalibration, "
                         f"got {type(path).__name__}")
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such calibration file; check the path (relative paths in a "
                         "pipeline file are resolved against the file's folder)")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a calibration file")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{path}: cannot read the calibration file ({exc})") from exc
    if not text.strip():
        raise InputError(f"{path}: the calibration file is empty")
    head = text.lstrip()[:200]
    if path.suffix.lower() == ".xml" or head.startswith("%YAML") or "opencv-matrix" in text \
            or head.startswith("<?xml") or "<opencv_storage>" in head:
        return read_opencv_calibration(path)
    if path.suffix.lower() in (".yaml", ".yml", ".json"):
        return read_plain_calibration(path)
    if re.search(r"^\s*(P[0-3]|P_rect_0[0-3])\s*:(\s*[-+0-9.eE]+){12}\s*$", text, re.MULTILINE):
        return read_kitti_calibration(path, cameras=cameras)
    if re.search(r"^\s*cam0\s*=", text, re.MULTILINE):
        return read_middlebury_calibration(path)
    raise InputError(
        f"{path}: not a recognised stereo calibration; supported: KITTI calib.txt (P0..P3 lines), "
        "Middlebury calib.txt (cam0=...), OpenCV YAML/XML (P1, P2 or Q, or M1, D1, M2, D2, R, T) "
        "and plain YAML (fx, cx, cy, baseline)"
    )


def _kitti_rows(path: Path) -> dict[str, np.ndarray]:
    rows: dict[str, np.ndarray] = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if ":" not in line:
            continue
        key, _, values = line.partition(":")
        try:
            rows[key.strip()] = np.array([float(v) for v in values.split()])
        except ValueError:
            if key.strip() in ("calib_time",):
                continue
            raise InputError(f"{path}:{number}: '{key.strip()}' has a non-numeric value") from None
    return rows


def read_kitti_calibration(path: str | os.PathLike, *, cameras: tuple[str, str] | None = None
                           ) -> StereoCalibration:
    """KITTI ``calib.txt`` (object/odometry ``P0..P3``, raw ``P_rect_0k``)."""
    path = Path(path)
    rows = _kitti_rows(path)
    if cameras is None:
        for pair in (("P2", "P3"), ("P_rect_02", "P_rect_03"), ("P0", "P1"), ("P_rect_00", "P_rect_01")):
            if pair[0] in rows and pair[1] in rows:
                cameras = pair
                break
        else:
            raise InputError(f"{path}: a KITTI calibration needs a pair of projection matrices "
                             f"(P2 and P3, or P0 and P1); found keys {', '.join(rows) or 'none'}")
    projections = []
    for key in cameras:
        if key not in rows:
            hint = did_you_mean(key, list(rows))
            raise InputError(f"{path}: missing key '{key}'" + (f" ({hint})" if hint else "")
                             + f"; keys are {', '.join(rows)}")
        if rows[key].size != 12:
            raise InputError(f"{path}: '{key}' must have 12 values (a 3 × 4 matrix), got {rows[key].size}")
        projections.append(rows[key].reshape(3, 4))
    calibration = _from_projections(projections[0], projections[1], str(path))
    lidar = None
    rect = rows.get("R0_rect", rows.get("R_rect_00"))
    velo = rows.get("Tr_velo_to_cam", rows.get("Tr"))
    if rect is not None and velo is not None and rect.size == 9 and velo.size == 12:
        r0 = np.eye(4)
        r0[:3, :3] = rect.reshape(3, 3)
        tr = np.eye(4)
        tr[:3, :] = velo.reshape(3, 4)
        # rectified camera 0 -> this left camera: P = K [I | t] with t = K^-1 P[:, 3]
        shift = np.eye(4)
        shift[:3, 3] = np.linalg.solve(projections[0][:, :3], projections[0][:, 3])
        lidar = shift @ r0 @ tr
    elif velo is not None and velo.size == 12 and rect is None:
        tr = np.eye(4)
        tr[:3, :] = velo.reshape(3, 4)
        shift = np.eye(4)
        shift[:3, 3] = np.linalg.solve(projections[0][:, :3], projections[0][:, 3])
        lidar = shift @ tr
    return replace(calibration, lidar_to_camera=lidar)


def _from_projections(p_left: np.ndarray, p_right: np.ndarray, source: str) -> StereoCalibration:
    p_left = np.asarray(p_left, dtype=np.float64).reshape(3, 4)
    p_right = np.asarray(p_right, dtype=np.float64).reshape(3, 4)
    fx, fy = p_left[0, 0], p_left[1, 1]
    if not (fx > 0 and fy > 0):
        raise InputError(f"{source}: the left projection matrix has focal lengths {fx}, {fy}; "
                         "they must be > 0")
    if abs(p_right[0, 0] - fx) > 1e-6 * fx or abs(p_right[1, 1] - fy) > 1e-6 * fy \
            or abs(p_right[1, 2] - p_left[1, 2]) > 1e-3:
        raise InputError(
            f"{source}: the two projection matrices do not describe a rectified pair (focal "
            f"lengths {fx:.3f}/{p_right[0, 0]:.3f} px, cy {p_left[1, 2]:.3f}/{p_right[1, 2]:.3f} px "
            "must be equal); rectify the pair first (cv2.stereoRectify)"
        )
    baseline = (p_left[0, 3] - p_right[0, 3]) / fx
    if baseline <= 0:
        raise InputError(
            f"{source}: the baseline from the projection matrices is {baseline:.4f} m; it must be "
            "> 0 (are the left and right cameras swapped?)"
        )
    return StereoCalibration(
        fx=fx, fy=fy, cx=p_left[0, 2], cy=p_left[1, 2], baseline=baseline,
        doffs=p_right[0, 2] - p_left[0, 2], source=source,
    )


def read_middlebury_calibration(path: str | os.PathLike) -> StereoCalibration:
    """Middlebury 2014 ``calib.txt`` (``cam0=[...]``, ``baseline`` in millimetres)."""
    path = Path(path)
    values: dict[str, str] = {}
    for line in path.read_text().splitlines():
        if "=" in line:
            key, _, value = line.partition("=")
            values[key.strip()] = value.strip()
    missing = [k for k in ("cam0", "cam1", "baseline") if k not in values]
    if missing:
        raise InputError(f"{path}: missing key(s) {', '.join(missing)} of a Middlebury calibration "
                         f"(keys found: {', '.join(values) or 'none'})")

    def matrix(key: str) -> np.ndarray:
        numbers = re.findall(r"[-+0-9.eE]+", values[key])
        if len(numbers) != 9:
            raise InputError(f"{path}: '{key}' must be a 3 × 3 matrix [a b c; d e f; g h i]")
        return np.array([float(v) for v in numbers]).reshape(3, 3)

    def number(key: str, default: float | None = None) -> float | None:
        if key not in values:
            return default
        try:
            return float(values[key])
        except ValueError:
            raise InputError(f"{path}: '{key}' must be a number, got {values[key]!r}") from None

    k0, k1 = matrix("cam0"), matrix("cam1")
    doffs = number("doffs", k1[0, 2] - k0[0, 2])
    ndisp = number("ndisp")
    width, height = number("width"), number("height")
    return StereoCalibration(
        fx=k0[0, 0], fy=k0[1, 1], cx=k0[0, 2], cy=k0[1, 2],
        baseline=number("baseline") / 1000.0, doffs=doffs,
        width=None if width is None else int(width), height=None if height is None else int(height),
        disparity_hint=None if ndisp is None else (0.0, float(ndisp)), source=str(path),
    )


def _opencv_nodes(path: Path) -> dict[str, Any]:
    import cv2

    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not storage.isOpened():
        raise InputError(f"{path}: OpenCV cannot parse this YAML/XML file")
    try:
        out: dict[str, Any] = {}
        root = storage.root()
        for key in root.keys():
            node = storage.getNode(key)
            if node.isNone():
                continue
            if node.isMap() or node.isSeq():
                mat = node.mat()
                if mat is not None:
                    out[key] = mat
                elif node.isSeq():
                    out[key] = np.array([node.at(i).real() for i in range(node.size())])
            elif node.isReal() or node.isInt():
                out[key] = node.real()
            elif node.isString():
                out[key] = node.string()
        return out
    finally:
        storage.release()


def read_opencv_calibration(path: str | os.PathLike) -> StereoCalibration:
    """OpenCV ``FileStorage`` YAML/XML: ``P1, P2`` (and/or ``Q``), or ``M1, D1, M2, D2, R, T``."""
    path = Path(path)
    nodes = _opencv_nodes(path)
    return _from_opencv_mapping(nodes, str(path))


def _from_opencv_mapping(nodes: Mapping[str, Any], source: str) -> StereoCalibration:
    def get(key: str) -> np.ndarray:
        return np.asarray(nodes[key], dtype=np.float64)

    width = height = None
    if "image_width" in nodes and "image_height" in nodes:
        width, height = int(nodes["image_width"]), int(nodes["image_height"])
    elif "width" in nodes and "height" in nodes:
        width, height = int(nodes["width"]), int(nodes["height"])
    for key in ("imageSize", "image_size"):
        if key in nodes:
            size = np.asarray(nodes[key]).ravel()
            if size.size == 2:
                width, height = int(size[0]), int(size[1])
    if "P1" in nodes and "P2" in nodes:
        for key in ("P1", "P2"):
            if get(key).size != 12:
                raise InputError(f"{source}: '{key}' must be a 3 × 4 matrix, got {get(key).size} values")
        calibration = _from_projections(get("P1"), get("P2"), source)
        return replace(calibration, width=width, height=height)
    if "Q" in nodes:
        q = get("Q")
        if q.shape != (4, 4):
            raise InputError(f"{source}: 'Q' must be a 4 × 4 matrix, got shape {q.shape}")
        if q[3, 2] == 0:
            raise InputError(f"{source}: 'Q' has Q[3, 2] = 0 (1 / baseline); not a stereo Q matrix")
        # OpenCV: Q[3, 2] = -1 / Tx, Q[3, 3] = (cx - cx') / Tx with Tx = -baseline
        baseline = abs(1.0 / q[3, 2])
        tx = -1.0 / q[3, 2]
        doffs = -(q[3, 3] * tx)
        return StereoCalibration(fx=q[2, 3], fy=q[2, 3], cx=-q[0, 3], cy=-q[1, 3],
                                 baseline=baseline, doffs=doffs, width=width, height=height,
                                 source=source)
    raw_keys = ("M1", "D1", "M2", "D2", "R", "T")
    if all(k in nodes for k in raw_keys):
        translation = get("T").ravel()
        raw = UnrectifiedStereo(
            camera_matrix_left=get("M1").reshape(3, 3), distortion_left=get("D1").ravel(),
            camera_matrix_right=get("M2").reshape(3, 3), distortion_right=get("D2").ravel(),
            rotation=get("R").reshape(3, 3), translation=translation,
        )
        # a placeholder model until the image size is known (StereoCalibration.for_images)
        m1 = raw.camera_matrix_left
        calibration = StereoCalibration(
            fx=m1[0, 0], fy=m1[1, 1], cx=m1[0, 2], cy=m1[1, 2],
            baseline=float(np.linalg.norm(translation)), width=width, height=height,
            unrectified=raw, source=source,
        )
        if width is not None and height is not None:
            calibration = calibration.for_images(width, height)
        return calibration
    present = [k for k in raw_keys if k in nodes]
    missing = [k for k in raw_keys if k not in nodes]
    detail = (f"it has {', '.join(present)} but misses {', '.join(missing)}" if present
              else f"keys found: {', '.join(nodes) or 'none'}")
    raise InputError(f"{source}: an OpenCV stereo calibration needs P1 and P2, or Q, or "
                     f"M1, D1, M2, D2, R, T; {detail}")


def read_plain_calibration(path: str | os.PathLike) -> StereoCalibration:
    """A plain YAML mapping: ``fx, cx, cy, baseline`` (m), optional ``fy, doffs, width, height``.

    A mapping holding OpenCV keys (``P1``, ``P2``, ``Q`` or ``M1`` ...) as nested lists is read
    as an OpenCV calibration.
    """
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(f"{path}: a calibration YAML must be a mapping of keys to values")
    if any(k in data for k in ("P1", "P2", "Q", "M1")):
        nodes = {k: (_opencv_list(v) if isinstance(v, (list, dict)) else v) for k, v in data.items()}
        return _from_opencv_mapping(nodes, str(path))
    return calibration_from_mapping(data, source=str(path))


def _opencv_list(value: Any) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        data = np.asarray(value["data"], dtype=np.float64)
        if "rows" in value and "cols" in value:
            data = data.reshape(int(value["rows"]), int(value["cols"]))
        return data
    return np.asarray(value, dtype=np.float64)


def calibration_from_mapping(data: Mapping[str, Any], *, source: str = "calibration"
                             ) -> StereoCalibration:
    """A calibration from a plain mapping (``fx, cx, cy, baseline``; optional ``fy, doffs,
    width, height``), with every missing or unknown key reported at once."""
    problems = []
    known = PLAIN_REQUIRED + PLAIN_OPTIONAL
    for key in data:
        if key not in known:
            hint = did_you_mean(str(key), known)
            problems.append(f"unknown key '{key}'" + (f" ({hint})" if hint else ""))
    for key in PLAIN_REQUIRED:
        if key not in data:
            problems.append(f"missing key '{key}'")
    if problems:
        raise InputError(f"{source}: " + "; ".join(problems)
                         + f" (a plain calibration has {', '.join(PLAIN_REQUIRED)} and optionally "
                         f"{', '.join(PLAIN_OPTIONAL)}; baseline in metres)")
    return StereoCalibration(
        fx=data["fx"], fy=data.get("fy", data["fx"]), cx=data["cx"], cy=data["cy"],
        baseline=data["baseline"], doffs=data.get("doffs", 0.0),
        width=data.get("width"), height=data.get("height"), source=source,
    )
