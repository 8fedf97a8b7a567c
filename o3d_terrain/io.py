"""Reading and writing clouds, grids and images.

Readers return an ``o3d.t.geometry.PointCloud`` with float64 positions and (N, 1) attributes:

========================  =====================================================================
extension                 what is read
========================  =====================================================================
``.ply``, ``.pcd``        every attribute Open3D reads (positions cast to float64)
``.xyz``, ``.txt``,       whitespace-, comma-, semicolon- or tab-separated x y z [intensity]; a
``.csv``, ``.pts``        header line is skipped
``.npy``                  an (N, 3) or (N, 4) array (x, y, z[, intensity])
``.bin``                  KITTI Velodyne float32 x, y, z, remission (``intensities``)
``.las``, ``.laz``        scaled float64 x, y, z; ``classification``, ``intensities``,
                          ``return_numbers``, ``number_of_returns``, ``colors`` when present
                          (needs the ``las`` extra: ``pip install 'o3d_terrain[las]'``)
========================  =====================================================================

:func:`write_las` writes a LAS/LAZ file with ASPRS classes: a copy of the file the cloud was
read from (:class:`LasSource`) with the classification replaced, or a new file.
:func:`write_geotiff` writes a single-band GeoTIFF raster (the terrain's DTM or slope map,
:mod:`o3d_terrain.raster`) in such a file's coordinate system and units.

Units: every metric option of the library (cell sizes, thresholds, widths) is in metres, so
``read_cloud`` converts LAS/LAZ coordinates to metres by default (``units="metres"``), using
the linear units the file declares (:func:`las_units`: GeoTIFF ProjLinearUnitsGeoKey and
VerticalUnitsGeoKey, else the last UNIT of a WKT coordinate system). A US-feet tile read in its
file units would get 0.5 ft cells and 0.5 ft thresholds (3.28 times too small) without any
error. ``units="file"`` keeps the file's coordinates (e.g. to write results back into the
file's coordinate system). Other formats carry no unit and are read as they are.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape as xml_escape

import cv2
import numpy as np
import open3d as o3d

from ._files import output_path
from .errors import InputError, NotACloudError, TerrainWarning, did_you_mean, warn
from .frame import (
    NUMBER_OF_RETURNS,
    RETURN_NUMBERS,
    Frame,
    as_frame,
    cloud_from_numpy,
    warn_coarse_float32,
)

#: the ``units`` choices of :func:`read_cloud`
UNITS = ("metres", "file")

#: EPSG linear unit codes (GeoTIFF ProjLinearUnitsGeoKey, VerticalUnitsGeoKey) in metres
EPSG_LINEAR_UNITS = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0}

CLOUD_EXTENSIONS = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".pts", ".npy", ".bin", ".las", ".laz")
#: the per-point attributes :func:`read_cloud` may give a file of each format besides
#: ``positions`` (the table above); a PLY or PCD file carries whatever it was written with
FILE_ATTRIBUTES = {
    **dict.fromkeys((".xyz", ".txt", ".csv", ".pts", ".npy", ".bin"), ("intensities",)),
    **dict.fromkeys((".las", ".laz"), ("classification", "intensities", RETURN_NUMBERS,
                                       NUMBER_OF_RETURNS, "colors")),
}
WRITE_EXTENSIONS = (".ply", ".pcd", ".npz", ".xyz", ".txt")
#: formats with no header of their own that says what the file holds (a ``.npy`` header
#: declares an array, not a cloud): their reader failing means the file holds no cloud
_HEADERLESS_EXTENSIONS = (".xyz", ".txt", ".csv", ".pts", ".npy", ".bin")


def file_attributes(path: str | os.PathLike) -> tuple[str, ...] | None:
    """The per-point attributes :func:`read_cloud` may give the file at ``path`` besides
    ``positions``, by its format; None for PLY and PCD files, whose attributes only the file
    can tell."""
    return FILE_ATTRIBUTES.get(Path(path).suffix.lower())


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such file; check the path (relative paths in a pipeline "
                         "file are resolved against the file's folder)")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a point cloud file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: not readable (permission denied)")
    if path.stat().st_size == 0:
        raise NotACloudError(path, "the file is empty")


def read_cloud(path: str | os.PathLike, *, units: str = "metres") -> o3d.t.geometry.PointCloud:
    """Read a point cloud file (see the module docstring for the formats).

    units: "metres" (default) converts LAS/LAZ coordinates from the linear units the file
    declares (:func:`las_units`; feet tiles are scaled by 0.3048) so that metric options mean
    metres; "file" keeps the file's coordinates. Formats without unit information are read as
    they are either way.

    Coordinates stored as float32 (a KITTI ``.bin``, a float32 ``.npy``) that reach magnitudes
    where float32 values lie more than a centimetre apart (projected coordinates) give the
    :class:`~o3d_terrain.errors.TerrainWarning` that ``segment_terrain`` gives such an array.

    A file that cannot be read is an :class:`InputError` naming it and what is wrong; a PLY
    file is checked against its header first (a bad header line, a file cut short, a word
    that is not a number), since Open3D's reader returns such a file's missing points as
    whatever memory held. A file that holds no point cloud at all (empty, no points, text
    that is not rows of x y z, a ``.npy`` that is not (N, 3) or (N, 4), a ``.ply`` or LAS
    file without its format's signature) is the subclass
    :class:`~o3d_terrain.errors.NotACloudError`; a cloud file cut short or corrupt is not.
    """
    if units not in UNITS:
        raise InputError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        raise InputError(f"{path} is a folder; give one of its point cloud files (`o3d-terrain "
                         f"run --input` takes a folder: every cloud in it, as a batch)")
    if suffix not in CLOUD_EXTENSIONS:
        raise InputError(
            f"{path}: unknown point cloud format '{suffix}'; supported: {', '.join(CLOUD_EXTENSIONS)}"
        )
    _check_readable(path)
    try:
        if suffix in (".ply", ".pcd"):
            return _read_open3d(path)
        if suffix in (".xyz", ".txt", ".csv", ".pts"):
            return _from_array(_read_text(path), path)
        if suffix == ".npy":
            return _from_array(np.load(path, allow_pickle=False), path)
        if suffix == ".bin":
            return _read_kitti_bin(path)
        return _read_las(path, to_metres=units == "metres")
    except (InputError, Warning):  # a warning made an error by the caller's filter stays one
        raise
    except Exception as exc:  # a reader library failed on the file
        reason = f"could not be read as {suffix} ({exc})"
        if suffix in _HEADERLESS_EXTENSIONS:  # calib.txt, times.txt: no cloud at all
            raise NotACloudError(path, reason) from exc
        raise InputError(f"{path}: {reason}") from exc


def _read_open3d(path: Path) -> o3d.t.geometry.PointCloud:
    if path.suffix.lower() == ".ply":
        _check_ply(path)
    # Open3D's own "Read PLY failed" warnings: the InputErrors here say it, with the file
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.t.io.read_point_cloud(str(path))
    if "positions" not in cloud.point or cloud.point.positions.shape[0] == 0:
        raise NotACloudError(path, "Open3D read no points (corrupt or empty file?)")
    return as_frame(cloud).cloud


#: bytes of each PLY scalar type, by the names Open3D's PLY reader (RPly) accepts
_PLY_TYPE_BYTES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2,
                   "int16": 2, "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4,
                   "float": 4, "float32": 4, "double": 8, "float64": 8}
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
#: where :func:`_ply_header` stops looking for a header's end_header line (bytes)
_PLY_HEADER_LIMIT = 1 << 20


@dataclass(frozen=True)
class _PlyElement:
    """An element of a PLY header: its name and count, its number of properties, and the
    bytes of one row in a binary file (a list property counts its length field only, so a row
    with lists is at least that long)."""

    name: str
    count: int
    properties: int = 0
    row_bytes: int = 0
    has_lists: bool = False


def _ply_header(path: Path) -> tuple[str, list[_PlyElement], int, int]:
    """(format, elements, bytes, lines) of a PLY file's header, read as Open3D's reader reads
    it; InputError naming the header line it would reject."""
    form, elements = None, []
    with open(path, "rb") as handle:
        if handle.readline(16).strip() != b"ply":
            raise NotACloudError(path, "does not start with 'ply' (not a PLY file)")
        size, number = handle.tell(), 1
        while size < _PLY_HEADER_LIMIT:
            raw = handle.readline(_PLY_HEADER_LIMIT)
            if not raw:
                break
            size, number = size + len(raw), number + 1
            line = raw.decode("latin-1").strip()
            words = line.split()
            where = f"{path}: header line {number}"
            keyword = words[0] if words else "comment"
            if keyword == "end_header":
                if form is None:
                    raise InputError(f"{where}: no 'format' line before 'end_header'")
                return form, elements, size, number
            if keyword in ("comment", "obj_info"):
                continue
            if keyword == "format" and len(words) == 3 and words[1] in _PLY_FORMATS:
                form = words[1]
            elif keyword == "format":
                raise InputError(f"{where}: unknown format '{line}' (the formats are "
                                 f"{', '.join(_PLY_FORMATS)})")
            elif keyword == "element" and len(words) == 3 and words[2].isdigit():
                elements.append(_PlyElement(words[1], int(words[2])))
            elif keyword == "property" and elements and len(words) in (3, 5):
                types = words[2:4] if words[1] == "list" and len(words) == 5 else words[1:2]
                for name in types:
                    if name not in _PLY_TYPE_BYTES:
                        hint = did_you_mean(name, list(_PLY_TYPE_BYTES))
                        raise InputError(f"{where}: unknown property type '{name}' ("
                                         + (hint or f"types are: {', '.join(_PLY_TYPE_BYTES)}")
                                         + ")")
                last = elements[-1]
                elements[-1] = _PlyElement(last.name, last.count, last.properties + 1,
                                           last.row_bytes + _PLY_TYPE_BYTES[types[0]],
                                           last.has_lists or len(types) == 2)
            else:
                raise InputError(f"{where}: '{line}' is not a header line Open3D reads (format, "
                                 "element <name> <count>, property <type> <name>, property "
                                 "list <count type> <type> <name>, comment, end_header)")
    raise InputError(f"{path}: no 'end_header' line: not a PLY file, or cut short within its "
                     "header")


def _check_ply(path: Path) -> None:
    """Check a PLY file against its header before Open3D reads it: Open3D's reader prints
    its complaint about a file cut short or a word that is not a number and returns the cloud
    anyway, the points it could not read holding whatever memory held.

    A binary file must hold the bytes its header declares (at least, with list properties);
    an ASCII file's first element (the vertices, in every writer's files) must hold the
    numbers its header declares, one row per line (numpy reads them once more). Garbage of
    the declared length in a binary file cannot be told from data."""
    form, elements, header_bytes, header_lines = _ply_header(path)
    declared = ", ".join(f"{e.count:,} {e.name} elements" for e in elements)
    fix = "copy or export the file again"
    if form == "ascii":
        first = elements[0] if elements else None
        if first is None or first.has_lists or first.count == 0:
            return
        try:
            with warnings.catch_warnings():  # numpy's "input contained no data": said below
                warnings.simplefilter("ignore", UserWarning)
                rows = np.loadtxt(path, skiprows=header_lines, max_rows=first.count, ndmin=2,
                                  comments=None, encoding="latin-1")
        except ValueError as exc:
            raise InputError(f"{path}: the {first.name} data is not {first.properties} numbers "
                             f"per line ({exc}; row 0 is line {header_lines + 1})") from exc
        if len(rows) < first.count:
            raise InputError(f"{path}: truncated: its header declares {first.count:,} "
                             f"{first.name} elements but the file holds {len(rows):,} lines "
                             f"of them; {fix}")
        if rows.shape[1] != first.properties:
            raise InputError(f"{path}: the {first.name} data is not {first.properties} numbers "
                             f"per line (its lines hold {rows.shape[1]})")
        return
    have = path.stat().st_size - header_bytes
    need = sum(e.count * e.row_bytes for e in elements)
    if have >= need:
        return
    start, cut = 0, elements[-1]  # the element the data ends in
    for cut in elements:
        if start + cut.count * cut.row_bytes > have:
            break
        start += cut.count * cut.row_bytes
    whole = (f" (whole {cut.name} elements: {(have - start) // cut.row_bytes:,})"
             if cut.row_bytes and not cut.has_lists else "")
    raise InputError(f"{path}: truncated: its header declares {declared} ({need:,} bytes"
                     f"{' at least' if any(e.has_lists for e in elements) else ''}) but "
                     f"{have:,} bytes follow the header{whole}; {fix}")


def _read_text(path: Path) -> np.ndarray:
    with open(path, "r", errors="replace") as handle:
        first = handle.readline()
    delimiter = next((d for d in (",", ";", "\t") if d in first), None)
    skip = 0
    try:
        [float(v) for v in first.replace(delimiter or " ", " ").split()]
    except ValueError:
        skip = 1  # a header line
    with warnings.catch_warnings():  # numpy's "input contained no data": said below
        warnings.simplefilter("ignore", UserWarning)
        data = np.loadtxt(path, delimiter=delimiter, skiprows=skip, ndmin=2, comments="#")
    if data.size == 0:
        raise NotACloudError(path, "no points (an empty text file)")
    if data.shape[1] < 3:
        raise NotACloudError(path, f"expected at least 3 columns (x y z), found {data.shape[1]}")
    return data[:, :4]


def _from_array(array: np.ndarray, path: Path) -> o3d.t.geometry.PointCloud:
    if array.ndim != 2 or array.shape[1] not in (3, 4):
        raise NotACloudError(path, f"expected an (N, 3) or (N, 4) array, got shape {array.shape}")
    if len(array) == 0:
        raise NotACloudError(path, "contains no points")
    _warn_coarse_float32(array, path)
    return as_frame(np.asarray(array, dtype=np.float64)).cloud


def _warn_coarse_float32(positions: np.ndarray, path: Path) -> None:
    """:func:`~o3d_terrain.frame.warn_coarse_float32` of the coordinates as the file stores
    them (float32 in a KITTI ``.bin``, any dtype in a ``.npy``), before they become float64:
    the same warning as for the array itself, naming the file."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TerrainWarning)
        warn_coarse_float32(positions)
    for found in caught:
        warn(f"{path}: {found.message}")


def _read_kitti_bin(path: Path) -> o3d.t.geometry.PointCloud:
    size = path.stat().st_size
    if size % 16:
        raise NotACloudError(path, f"{size} bytes is not a whole number of KITTI points (16 "
                                   "bytes: x, y, z, remission as float32)")
    data = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    _warn_coarse_float32(data, path)
    return cloud_from_numpy(data[:, :3].astype(np.float64), intensities=data[:, 3])


def _laspy(path: Path, doing: str):
    """The laspy module, or an InputError naming ``path`` and the extra that installs it."""
    try:
        import laspy
    except ImportError:  # pragma: no cover - the extra is installed in the tests
        raise InputError(f"{path}: {doing} LAS/LAZ needs laspy; install the extra: "
                         "pip install 'o3d_terrain[las]'") from None
    return laspy


@contextlib.contextmanager
def _reading_las(path: Path):
    """laspy for reading ``path`` in the ``with`` block, whose failures become an
    :class:`InputError`: a missing LAZ backend names the extra that installs it, anything else
    (laspy raises many types on corrupt or unsupported files) says the file could not be read
    as LAS/LAZ, a :class:`NotACloudError` when the file does not start with the LAS signature
    ``LASF``."""
    laspy = _laspy(path, "reading")
    try:
        yield laspy
    except laspy.errors.LaspyException as exc:
        if "backend" in str(exc).lower() or "laz" in str(exc).lower():
            raise InputError(
                f"{path}: reading LAZ needs a laspy backend; install the extra: "
                "pip install 'o3d_terrain[las]' (laspy[lazrs])"
            ) from exc
        raise _las_failure(path, exc) from exc
    except Exception as exc:
        raise _las_failure(path, exc) from exc


def _las_failure(path: Path, exc: Exception) -> InputError:
    """The error of a file laspy could not read: corrupt or unsupported when it starts with
    the LAS signature, else no LAS file at all."""
    reason = f"could not be read as LAS/LAZ ({exc})"
    try:
        with open(path, "rb") as handle:
            signature = handle.read(4)
    except OSError:
        signature = b""
    if signature != b"LASF":
        return NotACloudError(path, reason)
    return InputError(f"{path}: {reason}")


def open_las(path: str | os.PathLike):
    """A ``laspy.LasData`` of a LAS/LAZ file, with clear errors for a missing laspy or LAZ
    backend, a corrupt file and a file without points."""
    path = Path(path)
    with _reading_las(path) as laspy:
        las = laspy.read(str(path))
    if len(las.points) == 0:
        raise NotACloudError(path, "contains no points")
    return las


@dataclass(frozen=True)
class LasUnits:
    """Metres per coordinate unit of a LAS/LAZ file, and where that was read."""

    horizontal: float  # metres per x/y unit
    vertical: float  # metres per z unit
    source: str  # "GeoTIFF key EPSG:9002", "WKT unit 'US survey foot'" or "unknown"

    @property
    def is_metres(self) -> bool:
        return self.horizontal == 1.0 and self.vertical == 1.0


def las_units(las) -> LasUnits:
    """The linear units of a ``laspy.LasData``: GeoTIFF ProjLinearUnitsGeoKey (3076) for x/y
    and VerticalUnitsGeoKey (4099) for z (x/y's unit when absent), else the last UNIT of the
    WKT coordinate system for all three. Metres with source "unknown" when the file declares
    no unit (a CRS given only by its EPSG code is not looked up)."""
    keys = None
    for vlr in las.header.vlrs:
        if type(vlr).__name__ == "GeoKeyDirectoryVlr":
            keys = {key.id: key.value_offset for key in vlr.geo_keys}
            break
    wkts = []
    for vlr in las.header.vlrs:
        if type(vlr).__name__ == "WktCoordinateSystemVlr":
            wkts.append(vlr.string if isinstance(vlr.string, str) else str(vlr.string))
    return _units(keys, wkts)


def _header_units(keys: "GeoKeys | None", wkt: str | None) -> LasUnits:
    """:func:`las_units` of the records :func:`las_geokeys` read."""
    return _units(None if keys is None else keys.shorts(), [wkt] if wkt else [])


def _units(keys: dict | None, wkts: list[str]) -> LasUnits:
    """The units of GeoTIFF keys (id -> short value) or, else, of the WKT texts."""
    if keys is not None:
        code = keys.get(3076)
        if code in EPSG_LINEAR_UNITS:
            vertical = keys.get(4099, code)
            factor = EPSG_LINEAR_UNITS[int(code)]
            return LasUnits(factor, EPSG_LINEAR_UNITS.get(int(vertical), factor),
                            f"GeoTIFF key EPSG:{int(code)}")
    for text in wkts:
        units = re.findall(r'UNIT\["([^"]+)",\s*([0-9.eE+-]+)', text)
        if units:  # the last UNIT of a projected CRS is its linear unit
            name, factor = units[-1]
            try:
                value = float(factor)
            except ValueError:
                continue
            if 0.2 < value < 2.0:
                return LasUnits(value, value, f"WKT unit '{name}'")
    return LasUnits(1.0, 1.0, "unknown")


def las_returns(las) -> tuple[np.ndarray, np.ndarray]:
    """(return numbers, numbers of returns) of a ``laspy.LasData``'s points, int32 each: what
    the Segmenter's ``ground_returns`` reads."""
    return (np.asarray(las.return_number, dtype=np.int32),
            np.asarray(las.number_of_returns, dtype=np.int32))


def las_positions(las, *, to_metres: bool = True) -> tuple[np.ndarray, LasUnits]:
    """(N, 3) float64 positions of a ``laspy.LasData`` (in metres when ``to_metres``) and
    the file's :class:`LasUnits`."""
    units = las_units(las)
    positions = np.column_stack([np.asarray(las.x), np.asarray(las.y),
                                 np.asarray(las.z)]).astype(np.float64)
    if to_metres and not units.is_metres:
        positions *= np.array([units.horizontal, units.horizontal, units.vertical])
    return positions, units


def _read_las(path: Path, *, to_metres: bool = True) -> o3d.t.geometry.PointCloud:
    las = open_las(path)
    positions, _ = las_positions(las, to_metres=to_metres)
    attributes: dict[str, np.ndarray] = {
        "classification": np.asarray(las.classification, dtype=np.int32),
        "intensities": np.asarray(las.intensity, dtype=np.float32),
    }
    attributes[RETURN_NUMBERS], attributes[NUMBER_OF_RETURNS] = las_returns(las)
    names = set(las.point_format.dimension_names)
    if {"red", "green", "blue"} <= names:
        rgb = np.column_stack([las.red, las.green, las.blue]).astype(np.float64)
        scale = 65535.0 if rgb.max(initial=0) > 255 else 255.0
        attributes["colors"] = (rgb / scale).astype(np.float32)
    return cloud_from_numpy(positions, **attributes)


# ---------------------------------------------------------------------------------------------
# writing


def write_cloud(path: str | os.PathLike, cloud: Any) -> Path:
    """Write a cloud (any input :func:`as_frame` accepts) with its attributes.

    ``.ply``/``.pcd`` keep every (N, 1) attribute (bool attributes are stored as uint8);
    ``.npz`` stores positions and attributes as arrays; ``.xyz``/``.txt`` store x y z only.
    Raises :class:`InputError` when the writer fails.
    """
    path = Path(path)
    frame = as_frame(cloud)
    suffix = path.suffix.lower()
    if suffix not in WRITE_EXTENSIONS:
        raise InputError(f"{path}: cannot write '{suffix}'; use one of {', '.join(WRITE_EXTENSIONS)}")
    output_path(path)
    if suffix == ".npz":
        arrays = {"positions": np.asarray(frame.positions)}
        for name in frame.attribute_names():
            arrays[name] = np.asarray(frame.cloud.point[name].numpy())
        np.savez_compressed(path, **arrays)
        return path
    if suffix in (".xyz", ".txt"):
        np.savetxt(path, frame.positions, fmt="%.6f")
        return path
    out = o3d.t.geometry.PointCloud({"positions": frame.cloud.point.positions})
    for name in frame.attribute_names():
        values = frame.cloud.point[name]
        if values.dtype == o3d.core.bool:
            values = values.to(o3d.core.uint8)
        elif values.dtype == o3d.core.int64:
            values = values.to(o3d.core.int32)
        out.point[name] = values
    if not o3d.t.io.write_point_cloud(str(path), out):
        raise InputError(f"{path}: Open3D could not write the cloud (check the folder is writable)")
    return path


# ---------------------------------------------------------------------------------------------
# LAS/LAZ with classes


#: the point cloud file extensions :func:`write_las` writes
LAS_EXTENSIONS = (".las", ".laz")
#: classification value of :func:`write_las` that keeps the class the source file gives the
#: point (0, "created, never classified", in a new file)
KEEP_CLASS = -1
#: the extra dimension of :func:`write_las` for the height above the terrain (PDAL's name)
HEIGHT_ABOVE_GROUND = "HeightAboveGround"


@dataclass(frozen=True)
class LasSource:
    """The LAS/LAZ file a cloud was read from (product ``las_source`` of ``ReadCloud``), so a
    writer can copy its header, coordinate system and point records: ``units`` as read
    (:data:`UNITS`), ``points`` the number of point records."""

    path: Path
    units: str
    points: int


def write_las(path: str | os.PathLike, classification, *,
              source: LasSource | str | os.PathLike | None = None, positions=None,
              heights_above_ground=None, intensities=None, colors=None) -> Path:
    """Write a LAS/LAZ file (``.las``, or ``.laz`` compressed) with one ASPRS class per point.

    ``classification``: (N,) integers 0-255, :data:`KEEP_CLASS` for the source file's class.
    With ``source`` (a :class:`LasSource`, or the path of a LAS/LAZ file read with
    ``read_cloud``'s default units) the file is a copy of the source, its header, coordinate
    system and every point dimension kept, with the classification replaced; ``positions``
    are not written (the source's coordinates stay as they are)::

        cloud = o3d_terrain.read_cloud("tile.laz")
        surface, inliers = o3d_terrain.segment_terrain(cloud)
        classes = np.full(len(cloud.point.positions), 1)
        classes[inliers] = 2
        write_las("tile_ground.laz", classes, source="tile.laz")

    Without, a new LAS 1.4 file of ``positions`` ((N, 3), metres, written to the millimetre;
    point format 6, or 7 with ``colors`` in [0, 1]), with ``intensities`` when given (scaled
    to 16 bits when all lie in [0, 1]). ``heights_above_ground`` (N,) metres, NaN where
    undefined, are stored as the float32 extra dimension :data:`HEIGHT_ABOVE_GROUND`, in the
    file's vertical units. Needs the ``las`` extra; raises :class:`InputError` with the fix
    when something does not fit.
    """
    path = Path(path)
    if path.suffix.lower() not in LAS_EXTENSIONS:
        raise InputError(f"{path}: a LAS file name must end in .las or .laz")
    laspy = _laspy(path, "writing")
    classes = np.asarray(classification)
    if classes.ndim != 1 or not np.issubdtype(classes.dtype, np.integer):
        raise InputError(f"{path}: classification must be a 1-D integer array, got "
                         f"{classes.dtype} of shape {classes.shape}")
    if classes.size and (classes.min() < KEEP_CLASS or classes.max() > 255):
        raise InputError(f"{path}: ASPRS classes are 0-255 (or {KEEP_CLASS}: keep the source's)")
    n = classes.size
    if isinstance(source, (str, os.PathLike)):
        source = LasSource(Path(source), "metres", n)
    if source is not None:
        las = open_las(source.path)
        if len(las.points) != n or source.points != n:
            raise InputError(
                f"{path}: {n} classes for the {len(las.points)} points of {source.path}; a stage "
                "added or dropped points, so they no longer match the file's records (write "
                "the cloud itself with WriteCloud)")
        vertical = 1.0 if source.units == "file" else las_units(las).vertical
        old = np.asarray(las.classification, dtype=np.int64)
    else:
        p = np.asarray(positions, dtype=np.float64) if positions is not None else None
        if p is None or p.ndim != 2 or p.shape != (n, 3):
            raise InputError(f"{path}: a new LAS file needs (N, 3) positions for its {n} "
                             "classes")
        finite = np.isfinite(p).all(axis=1)
        if not finite.all():
            raise InputError(f"{path}: {int((~finite).sum())} points have non-finite "
                             "coordinates, which LAS cannot store")
        header = laspy.LasHeader(point_format=7 if colors is not None else 6, version="1.4")
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.floor(p.min(axis=0)) if n else np.zeros(3)
        las = laspy.LasData(header)
        las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
        if intensities is not None:
            values = np.asarray(intensities, dtype=np.float64).reshape(n)
            values = np.nan_to_num(values)
            if values.size and values.min() >= 0.0 and values.max() <= 1.0:
                values = values * 65535.0
            las.intensity = np.clip(np.round(values), 0, 65535).astype(np.uint16)
        if colors is not None:
            rgb = np.clip(np.asarray(colors, dtype=np.float64).reshape(n, 3), 0.0, 1.0)
            rgb = np.round(rgb * 65535.0).astype(np.uint16)
            las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        vertical = 1.0
        old = np.zeros(n, np.int64)
    new = np.where(classes == KEEP_CLASS, old, classes)
    if las.point_format.id < 6 and new.size and new.max() > 31:
        raise InputError(f"{path}: point format {las.point_format.id} of {source.path} stores "
                         "classes 0-31 only; choose classes below 32")
    las.classification = new.astype(np.uint8)
    if heights_above_ground is not None:
        heights = np.asarray(heights_above_ground, dtype=np.float64).reshape(n) / vertical
        if HEIGHT_ABOVE_GROUND not in las.point_format.extra_dimension_names:
            las.add_extra_dim(laspy.ExtraBytesParams(
                name=HEIGHT_ABOVE_GROUND, type=np.float32,
                description="height above the terrain"))
        las[HEIGHT_ABOVE_GROUND] = heights.astype(np.float32)
    output_path(path)
    try:
        las.write(str(path))
    except Exception as exc:  # laspy raises many types (no LAZ backend, a full disk)
        raise InputError(f"{path}: could not write the LAS file ({exc})") from exc
    return path


#: file suffixes :func:`write_geotiff` writes
GEOTIFF_EXTENSIONS = (".tif", ".tiff")
#: the value :func:`write_geotiff` stores in cells without data (GDAL_NODATA tag 42113 too)
NODATA = -9999.0
#: GeoTIFF tags and keys :func:`write_geotiff` writes
_PIXEL_SCALE, _TIEPOINT, _GEOKEYS, _GEODOUBLES, _GEOASCII, _GDAL_NODATA = \
    33550, 33922, 34735, 34736, 34737, 42113
_RASTER_TYPE_KEY, _PIXEL_IS_AREA = 1025, 1


@dataclass(frozen=True)
class GeoKeys:
    """A coordinate system as GeoTIFF stores it: the GeoKeyDirectory (uint16, a header of four
    then four per key), and the double and ASCII parameters its keys point into. A LAS file
    carries the same three records (LASF_Projection VLRs 34735-34737)."""

    directory: tuple[int, ...]
    doubles: tuple[float, ...] = ()
    ascii: str = ""

    @classmethod
    def from_epsg(cls, code: int) -> "GeoKeys":
        """A projected coordinate system by its EPSG code (ProjectedCSTypeGeoKey)."""
        return cls((1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, int(code)))

    def entries(self) -> list[tuple[int, ...]]:
        """The directory's keys as stored: (key id, location, count, value or offset) each;
        location 0 holds the short value in the entry itself."""
        d = self.directory
        return [tuple(d[i:i + 4]) for i in range(4, 4 + 4 * d[3], 4)]

    def shorts(self) -> dict[int, int]:
        """Key id -> value of the keys whose value is a short stored in the directory."""
        return {key: value for key, location, _, value in self.entries() if location == 0}

    def with_key(self, key: int, value: int) -> "GeoKeys":
        """The same keys with ``key`` set to the short ``value`` (kept in ascending order)."""
        # (key 0 is no GeoKey: a few LAS writers leave such an empty entry)
        keys = sorted([k for k in self.entries() if k[0] not in (0, key)]
                      + [(key, 0, 1, int(value))])
        d = self.directory
        return GeoKeys((d[0], d[1], d[2], len(keys), *[v for k in keys for v in k]),
                       self.doubles, self.ascii)


def check_epsg(code) -> int:
    """An EPSG code of a projected coordinate system (metres or feet), as an int; raises
    :class:`InputError` for anything else (a geographic CRS in degrees cannot hold a cloud
    in metres)."""
    if isinstance(code, bool) or not isinstance(code, (int, np.integer)) or \
            not 1024 <= int(code) <= 32766:
        raise InputError(f"epsg must be the EPSG code of a projected coordinate system (an "
                         f"integer such as 32633 for UTM zone 33N), got {code!r}")
    if 4000 <= int(code) < 5000:
        raise InputError(f"EPSG:{int(code)} is a geographic coordinate system (degrees); give the "
                         "projected one the cloud's metres are in (e.g. its UTM zone, 326xx "
                         "north or 327xx south)")
    return int(code)


def las_geokeys(source: "LasSource | str | os.PathLike") -> tuple[GeoKeys | None, str | None]:
    """The coordinate system of a LAS/LAZ file, read from its header alone: its GeoTIFF keys
    (the LASF_Projection records 34735-34737) when it has them, and its WKT (record 2112)
    when it has one; (None, None) for a file that declares neither."""
    path = Path(source.path if isinstance(source, LasSource) else source)
    _check_readable(path)
    with _reading_las(path) as laspy, laspy.open(str(path)) as reader:
        header = reader.header
    records = {}
    for vlr in list(header.vlrs) + list(getattr(header, "evlrs", None) or []):
        if getattr(vlr, "user_id", "").rstrip("\0") == "LASF_Projection":
            records.setdefault(int(vlr.record_id), vlr)
    keys = wkt = None
    if 34735 in records:
        directory = np.frombuffer(records[34735].record_data_bytes(), "<u2")
        doubles = np.frombuffer(records[34736].record_data_bytes(), "<f8") \
            if 34736 in records else np.zeros(0)
        text = records[34737].record_data_bytes().decode("latin-1").rstrip("\0") \
            if 34737 in records else ""
        if directory.size >= 4 and directory.size >= 4 + 4 * int(directory[3]):
            keys = GeoKeys(tuple(int(v) for v in directory[:4 + 4 * int(directory[3])]),
                           tuple(float(v) for v in doubles), text)
    if 2112 in records:
        raw = records[2112].record_data_bytes()
        wkt = raw.decode("utf-8", errors="replace").rstrip("\0").strip()
        wkt = wkt if "[" in wkt else None  # some writers leave the record empty or quoted
    return keys, wkt


def write_geotiff(path: str | os.PathLike, values, x_min: float, y_min: float,
                  cell_size: float, *, heights: bool = True,
                  source: "LasSource | str | os.PathLike | None" = None,
                  epsg: int | None = None) -> Path:
    """Write a single-band float32 GeoTIFF of square cells (deflate-compressed, north up,
    PixelIsArea): ``values[ix, iy]`` (x first, like a HeightGrid; NaN = no data, stored as
    :data:`NODATA` with the GDAL_NODATA tag) of cells ``cell_size`` m wide whose lower-left
    corner is (``x_min``, ``y_min``) in metres.

    With ``source`` (a :class:`LasSource`, or the path of a LAS/LAZ file read with
    ``read_cloud``'s default units) the raster takes the file's coordinate system: its GeoTIFF
    keys, copied, or its WKT in a ``.aux.xml`` file beside the raster (which GDAL and QGIS
    read) when it has no keys; and its units: a tile in US feet gets its cells, corner and,
    with ``heights``, its values back in feet. ``epsg`` (a projected coordinate system's
    code) gives or replaces the keys. Without either, the raster is placed in the cloud's own
    coordinates with no coordinate system. Needs ``tifffile`` (the ``las`` or ``dem`` extra).
    """
    path = Path(path)
    if path.suffix.lower() not in GEOTIFF_EXTENSIONS:
        raise InputError(f"{path}: a GeoTIFF name must end in .tif or .tiff")
    try:
        import tifffile
    except ImportError:
        raise InputError(f"{path}: writing GeoTIFF needs tifffile; install the extra: "
                         "pip install 'o3d_terrain[las]' (or [dem])") from None
    grid = np.asarray(values, dtype=np.float64)
    if grid.ndim != 2 or min(grid.shape) < 1:
        raise InputError(f"{path}: values must be a 2-D array of cells [ix, iy], got shape "
                         f"{grid.shape}")
    if not (math.isfinite(cell_size) and cell_size > 0):
        raise InputError(f"{path}: cell_size must be a positive number of metres, got "
                         f"{cell_size!r}")
    if not (math.isfinite(x_min) and math.isfinite(y_min)):
        raise InputError(f"{path}: the raster's corner ({x_min}, {y_min}) is not finite")
    keys = GeoKeys.from_epsg(check_epsg(epsg)) if epsg is not None else None
    sidecar_wkt = None  # a WKT for GDAL's .aux.xml: the file's, when it has no keys
    horizontal = vertical = 1.0
    if source is not None:
        if not isinstance(source, LasSource):
            source = LasSource(Path(source), "metres", 0)
        file_keys, wkt = las_geokeys(source)
        if keys is None:
            keys = file_keys
            sidecar_wkt = wkt if file_keys is None else None
        if source.units == "metres":  # the cloud was converted to metres on reading
            units = _header_units(file_keys, wkt)
            horizontal, vertical = units.horizontal, units.vertical
    if heights and vertical != 1.0:
        grid = grid / vertical
    image = np.where(np.isfinite(grid), grid, NODATA).astype(np.float32).T[::-1]
    scale = cell_size / horizontal
    top = (y_min + grid.shape[1] * cell_size) / horizontal
    tags = [(_PIXEL_SCALE, "d", 3, (scale, scale, 0.0), True),
            (_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, x_min / horizontal, top, 0.0), True)]
    keys = (keys or GeoKeys((1, 1, 0, 0))).with_key(_RASTER_TYPE_KEY, _PIXEL_IS_AREA)
    tags.append((_GEOKEYS, "H", len(keys.directory), keys.directory, True))
    if keys.doubles:
        tags.append((_GEODOUBLES, "d", len(keys.doubles), keys.doubles, True))
    if keys.ascii:
        tags.append((_GEOASCII, "s", 0, keys.ascii, True))
    tags.append((_GDAL_NODATA, "s", 0, f"{NODATA:g}", True))
    output_path(path)
    try:
        tifffile.imwrite(path, np.ascontiguousarray(image), photometric="minisblack",
                         compression="zlib", extratags=tags)
    except Exception as exc:  # a full disk, a non-ASCII key parameter
        raise InputError(f"{path}: could not write the GeoTIFF ({exc})") from exc
    sidecar = path.with_name(path.name + ".aux.xml")
    if sidecar_wkt:
        sidecar.write_text("<PAMDataset>\n  <SRS dataAxisToSRSAxisMapping=\"1,2\">"
                           f"{xml_escape(sidecar_wkt)}</SRS>\n</PAMDataset>\n",
                           encoding="utf-8")
    elif sidecar.exists():  # an older run's coordinate system must not describe this raster
        sidecar.unlink()
    return path


#: OpenCV colour maps by name, for grid images
COLORMAPS = {
    "turbo": cv2.COLORMAP_TURBO,
    "viridis": cv2.COLORMAP_VIRIDIS,
    "jet": cv2.COLORMAP_JET,
    "inferno": cv2.COLORMAP_INFERNO,
    "magma": cv2.COLORMAP_MAGMA,
    "gray": None,
}


def render_grid_image(
    values: np.ndarray,
    *,
    valid: np.ndarray | None = None,
    colormap: str = "turbo",
    value_range: tuple[float, float] | None = None,
    title: str = "",
    unit: str = "",
    min_size: int = 480,
) -> np.ndarray:
    """A BGR image of a grid indexed ``[ix, iy]``, with a colour scale bar and a title.

    The image shows x to the right and y up (a map seen from above). Invalid cells are dark grey.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or values.size == 0:
        raise InputError(f"a grid image needs a non-empty 2-D array, got shape {values.shape}")
    valid = np.isfinite(values) if valid is None else (np.asarray(valid, bool) & np.isfinite(values))
    if value_range is None:
        if valid.any():
            low, high = np.percentile(values[valid], [1, 99])
        else:
            low, high = 0.0, 1.0
    else:
        low, high = value_range
    if not high > low:
        high = low + 1.0
    scaled = np.clip((values - low) / (high - low), 0, 1)
    scaled[~valid] = 0.0  # drawn grey below; keeps NaN out of the integer cast
    # [ix, iy] -> image rows from top (high y) to bottom, columns left (low x) to right
    scaled = np.flipud(scaled.T)
    mask = np.flipud(valid.T)
    gray = (scaled * 255).astype(np.uint8)
    cmap = COLORMAPS.get(colormap, cv2.COLORMAP_TURBO)
    color = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR) if cmap is None else cv2.applyColorMap(gray, cmap)
    color[~mask] = (60, 60, 60)
    factor = max(1, int(np.ceil(min_size / max(color.shape[:2]))))
    color = cv2.resize(color, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
    h, w = color.shape[:2]
    bar_w, margin, top = 24, 90, 30
    canvas = np.full((h + top + 10, w + bar_w + margin, 3), 255, np.uint8)
    canvas[top:top + h, :w] = color
    ramp = np.linspace(255, 0, h).astype(np.uint8)[:, None].repeat(bar_w, axis=1)
    bar = cv2.cvtColor(ramp, cv2.COLOR_GRAY2BGR) if cmap is None else cv2.applyColorMap(ramp, cmap)
    canvas[top:top + h, w + 8:w + 8 + bar_w] = bar
    font = cv2.FONT_HERSHEY_SIMPLEX
    for frac, val in ((0.0, high), (0.5, (low + high) / 2), (1.0, low)):
        y = top + int(frac * (h - 1))
        label = f"{val:.2f}{(' ' + unit) if unit else ''}"
        cv2.putText(canvas, label, (w + bar_w + 12, max(y + 4, top + 10)), font, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
    if title:
        cv2.putText(canvas, title, (4, 20), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an image (PNG, JPG); raises when OpenCV fails."""
    path = output_path(path)
    if not cv2.imwrite(str(path), image):
        raise InputError(f"{path}: OpenCV could not write the image (unknown extension or folder?)")
    return path


def as_cloud(data: Any) -> o3d.t.geometry.PointCloud:
    """The tensor cloud of anything :func:`as_frame` accepts, or of a file path."""
    if isinstance(data, (str, os.PathLike)):
        return read_cloud(data)
    return as_frame(data).cloud


def frame_from_file(path: str | os.PathLike) -> Frame:
    return Frame(read_cloud(path)).with_note(f"read {path}")
