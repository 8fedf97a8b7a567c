"""The frame: a point cloud plus the products that later stages need.

A stage takes a :class:`Frame` and returns a new one. The cloud is an
``o3d.t.geometry.PointCloud`` whose positions are float64 and whose per-point attributes are
shaped (N, 1) (so Open3D's PLY/PCD writers keep them). Products are the non-per-point results:
the height grid, the fitted surface, slope and cost maps, obstacles.

Stages never modify the caller's cloud: :func:`as_frame` makes a shallow copy (new tensor map,
shared tensors) and attributes are always *added* to a fresh copy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
import open3d as o3d

from .errors import InputError, did_you_mean, warn

#: per-point attribute names written by the stages (Open3D style: plural snake_case)
LABELS = "labels"
HEIGHTS_ABOVE_TERRAIN = "heights_above_terrain"
SLOPES_DEG = "slopes_deg"
#: per-point attributes read from LAS/LAZ files (o3d_terrain.io.read_cloud): a pulse's return
#: number and its number of returns, which the Segmenter reads (its option ground_returns)
RETURN_NUMBERS = "return_numbers"
NUMBER_OF_RETURNS = "number_of_returns"
#: ... and the names other tools give them in PLY/PCD files (PDAL's dimension names, laspy's)
RETURN_NUMBERS_ALIASES = (RETURN_NUMBERS, "ReturnNumber", "return_number")
NUMBER_OF_RETURNS_ALIASES = (NUMBER_OF_RETURNS, "NumberOfReturns")


def _tensor(array: np.ndarray) -> o3d.core.Tensor:
    """An Open3D tensor holding its own copy of ``array`` (one copy, never shared)."""
    array = np.asarray(array)
    if array.flags.c_contiguous:
        return o3d.core.Tensor(array)  # copies
    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(array))  # shares our fresh copy


def _readonly(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True)
class Frame:
    """A point cloud with its products. Immutable: the ``with_*`` methods return new frames."""

    cloud: o3d.t.geometry.PointCloud
    products: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    notes: tuple[str, ...] = ()

    # -- reading -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.cloud.point.positions.shape[0])

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) float64 positions, read-only."""
        return _readonly(self.cloud.point.positions.numpy())

    def has_attribute(self, name: str) -> bool:
        return name in self.cloud.point

    def attribute(self, name: str) -> np.ndarray:
        """A per-point attribute as a read-only array: (N,) for one column, (N, k) otherwise."""
        if name not in self.cloud.point:
            names = sorted(k for k in self.cloud.point if k != "positions")
            hint = did_you_mean(name, names)
            raise KeyError(f"the cloud has no attribute '{name}' (attributes: "
                           f"{', '.join(names) or 'none'})" + (f" ({hint})" if hint else ""))
        values = self.cloud.point[name].numpy()
        if values.ndim == 2 and values.shape[1] == 1:
            values = values[:, 0]
        return _readonly(values)

    def attribute_names(self) -> list[str]:
        return sorted(k for k in self.cloud.point if k != "positions")

    def product(self, name: str) -> Any:
        if name not in self.products:
            have = ", ".join(sorted(self.products)) or "none"
            raise KeyError(f"the frame has no product '{name}' (products: {have})")
        return self.products[name]

    # -- deriving new frames -------------------------------------------------------------------
    def with_attributes(self, **arrays: np.ndarray) -> "Frame":
        """A new frame whose cloud has these per-point attributes added or replaced."""
        n = len(self)
        cloud = _shallow_copy(self.cloud)
        for name, values in arrays.items():
            values = np.asarray(values)
            if values.ndim == 1:
                values = values[:, None]
            if values.ndim != 2 or values.shape[0] != n:
                raise ValueError(
                    f"attribute '{name}' has shape {values.shape}; it must have {n} rows"
                )
            cloud.point[name] = _tensor(values)
        return Frame(cloud, self.products, self.notes)

    def with_products(self, **products: Any) -> "Frame":
        merged = dict(self.products)
        merged.update(products)
        return Frame(self.cloud, MappingProxyType(merged), self.notes)

    def with_note(self, note: str) -> "Frame":
        return Frame(self.cloud, self.products, self.notes + (note,))

    def select(self, mask_or_indices: np.ndarray) -> "Frame":
        """A frame with a subset of the points and the same products."""
        index = np.asarray(mask_or_indices)
        if index.dtype == bool:
            index = np.flatnonzero(index)
        cloud = o3d.t.geometry.PointCloud(
            {k: _tensor(self.cloud.point[k].numpy()[index]) for k in self.cloud.point}
        )
        return Frame(cloud, self.products, self.notes)


def _shallow_copy(cloud: o3d.t.geometry.PointCloud) -> o3d.t.geometry.PointCloud:
    return o3d.t.geometry.PointCloud({k: cloud.point[k] for k in cloud.point})


def cloud_from_numpy(positions: np.ndarray, **attributes: np.ndarray) -> o3d.t.geometry.PointCloud:
    """A tensor cloud from float64 positions and (N,) or (N, k) attributes."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    cloud = o3d.t.geometry.PointCloud({"positions": _tensor(positions)})
    for name, values in attributes.items():
        values = np.asarray(values)
        if values.ndim == 1:
            values = values[:, None]
        if values.shape[0] != positions.shape[0]:
            raise ValueError(f"attribute '{name}' has {values.shape[0]} rows, positions {len(positions)}")
        cloud.point[name] = _tensor(values)
    return cloud


#: :func:`warn_coarse_float32`: float32 coordinates more than this far apart (m) at the cloud's
#: largest magnitude have lost the points' geometry
FLOAT32_STEP = 0.01


def warn_coarse_float32(positions: np.ndarray) -> None:
    """Warn (:class:`~o3d_terrain.errors.TerrainWarning`) when the float32 or float16 (N, >= 3)
    ``positions`` reach a magnitude where successive values lie more than
    :data:`FLOAT32_STEP` apart: projected coordinates (UTM northings of millions of metres are
    0.25-0.5 m apart in float32) rounded before they reached the library."""
    if positions.dtype not in (np.float32, np.float16) or positions.size == 0:
        return
    kind = positions.dtype.type
    # every column of a C-ordered array at once (0.1 ms for a KITTI frame against 1.2 ms for
    # its first three as a strided view): the coordinates reach at most what all values do
    whole = positions.reshape(-1) if positions.flags.c_contiguous else positions[:, :3]
    bound = float(max(np.max(whole), -np.min(whole)))
    if np.isfinite(bound) and float(np.spacing(kind(bound))) <= FLOAT32_STEP:
        return
    coordinates = positions[:, :3]
    finite = coordinates[np.isfinite(coordinates)]
    if finite.size == 0:
        return
    largest = float(np.abs(finite).max())
    step = float(np.spacing(kind(largest)))
    if step > FLOAT32_STEP:
        warn(
            f"the cloud's coordinates are {positions.dtype} and reach {largest:,.0f} m, where "
            f"successive {positions.dtype} values are {step:g} m apart: the points were rounded "
            f"that much before they reached the library. Read them as float64, or subtract an "
            f"offset (e.g. the tile's corner) before converting them to {positions.dtype}")


def as_frame(data: Any) -> Frame:
    """Accept a Frame, an Open3D legacy or tensor PointCloud, or an (N, 3)/(N, 4) array.

    The caller's object is never modified. Positions become float64. A fourth array column
    becomes the ``intensities`` attribute. Non-finite points are kept (so indices stay aligned
    with the caller's cloud); stages skip them and say how many they skipped.
    """
    if isinstance(data, Frame):
        return data
    if isinstance(data, o3d.t.geometry.PointCloud):
        if "positions" not in data.point:
            return Frame(cloud_from_numpy(np.zeros((0, 3))))
        cloud = _shallow_copy(data)
        positions = cloud.point.positions
        if positions.device.get_type() != o3d.core.Device.DeviceType.CPU:
            cloud = cloud.cpu()
        if cloud.point.positions.dtype != o3d.core.float64:
            if cloud.point.positions.dtype == o3d.core.float32:
                warn_coarse_float32(cloud.point.positions.numpy())
            cloud.point.positions = cloud.point.positions.to(o3d.core.float64)
        for name in list(cloud.point):
            values = cloud.point[name]
            if len(values.shape) == 1:  # Open3D accepts (N,) but cannot write it: make (N, 1)
                cloud.point[name] = values.reshape((values.shape[0], 1))
        return Frame(cloud)
    if isinstance(data, o3d.geometry.PointCloud):
        attributes = {}
        if data.has_colors():
            attributes["colors"] = np.asarray(data.colors)
        if data.has_normals():
            attributes["normals"] = np.asarray(data.normals)
        return Frame(cloud_from_numpy(np.asarray(data.points), **attributes))
    if isinstance(data, np.ndarray) or isinstance(data, (list, tuple)):
        array = np.asarray(data)
        if array.dtype == object or not np.issubdtype(array.dtype, np.number):
            raise InputError(f"expected a numeric (N, 3) or (N, 4) array, got dtype {array.dtype}")
        if array.ndim != 2 or array.shape[1] not in (3, 4):
            if array.size == 0:
                return Frame(cloud_from_numpy(np.zeros((0, 3))))
            hint = ""
            if array.ndim == 3 and array.shape[2] in (3, 4):  # an organised (rows, columns) scan
                hint = (f"; an organised scan of {array.shape[0]} × {array.shape[1]} points "
                        f"goes in as cloud.reshape(-1, {array.shape[2]}) (the indices returned "
                        f"then index that order)")
            raise InputError(
                f"expected an (N, 3) or (N, 4) array of x, y, z[, intensity], got shape "
                f"{array.shape}{hint}")
        warn_coarse_float32(array)
        attributes = {}
        if array.shape[1] == 4:
            attributes["intensities"] = array[:, 3].astype(np.float32)
        return Frame(cloud_from_numpy(np.asarray(array[:, :3], dtype=np.float64), **attributes))
    hint = ""
    if isinstance(data, (str, os.PathLike)):
        hint = f"; to read the file {str(data)!r}, pass o3d_terrain.read_cloud(path)"
    raise InputError(
        "expected an Open3D PointCloud (legacy or tensor), an (N, 3)/(N, 4) numpy array or a "
        f"Frame, got {type(data).__name__}{hint}"
    )


def finite_mask(positions: np.ndarray) -> np.ndarray:
    """True where all three coordinates are finite."""
    return np.isfinite(positions).all(axis=1)


def transform_points(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """Apply a 4 × 4 rigid transform to (N, 3) points (column by column: for tall arrays this
    is several times faster than a BLAS matrix product with a 3 × 3 matrix)."""
    r, t = transform[:3, :3], transform[:3, 3]
    out = np.empty_like(points, dtype=np.float64)
    for row in range(3):
        out[:, row] = (points[:, 0] * r[row, 0] + points[:, 1] * r[row, 1]
                       + points[:, 2] * r[row, 2] + t[row])
    return out
