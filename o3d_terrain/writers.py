"""Writers: the ``outputs:`` of a pipeline file. Registered by class name in :data:`WRITERS`.

Each writer is a frozen validated dataclass like a stage. ``path`` is relative to the output
folder (``--output`` on the command line, or ``output_dir`` in the pipeline file).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np

from . import io
from ._files import output_path
from .errors import InputError
from .frame import HEIGHTS_ABOVE_TERRAIN, LABELS, Frame
from .grid import HeightGrid
from .options import NON_NEGATIVE, POSITIVE, Component, Range, component, option
from .raster import LAYERS, MAX_GAP, write_terrain_raster
from .segment import TerrainLabel

#: every registered writer by class name (the YAML ``type:`` under ``outputs:``)
WRITERS: dict[str, type["Writer"]] = {}


def writer(cls: type | None = None, *, summary: str = "") -> Any:
    decorate: Callable[[type], type] = component(WRITERS, summary)
    return decorate(cls) if cls is not None else decorate


class Writer(Component):
    """Writes part of a frame to files."""

    example: ClassVar[dict[str, Any] | None] = None

    def required_products(self) -> tuple[str, ...]:
        return ()

    def required_attributes(self) -> dict[str, str]:
        """The per-point attributes this writer reads, by the option that names each."""
        return {}

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _target(self, out_dir: Path, path: str) -> Path:
        target = Path(path)
        return target if target.is_absolute() else Path(out_dir) / target


# ---------------------------------------------------------------------------------------------
# colours for point labels (values of o3d_terrain.segment.Label)

LABEL_COLORS = {
    0: (0.55, 0.55, 0.55),  # unknown: non-finite or outside the terrain region
    1: (0.20, 0.70, 0.25),  # terrain
    2: (0.90, 0.15, 0.10),  # obstacle
    3: (0.15, 0.35, 0.95),  # below the terrain (noise)
}


def _colors_for(frame: Frame, attribute: str, colormap: str) -> np.ndarray:
    values = np.asarray(frame.attribute(attribute))
    if values.ndim != 1:
        raise InputError(f"attribute '{attribute}' has {values.shape[1]} columns; color_by needs one")
    if attribute == "labels" or np.issubdtype(values.dtype, np.integer) and values.max(initial=0) < 8:
        table = np.array([LABEL_COLORS.get(i, (0.0, 0.0, 0.0)) for i in range(8)])
        return table[np.clip(values.astype(np.int64), 0, 7)]
    import cv2

    finite = np.isfinite(values)
    low, high = (np.percentile(values[finite], [2, 98]) if finite.any() else (0.0, 1.0))
    scaled = np.clip((values - low) / max(high - low, 1e-12), 0, 1)
    scaled[~finite] = 0
    gray = (scaled * 255).astype(np.uint8)[:, None]
    bgr = cv2.applyColorMap(gray, io.COLORMAPS.get(colormap) or 20)[:, 0, :]
    rgb = bgr[:, ::-1].astype(np.float64) / 255.0
    rgb[~finite] = 0.5
    return rgb


@writer
class WriteCloud(Writer):
    """Write the cloud with its per-point attributes (PLY, PCD, NPZ, XYZ)."""

    path: str = option("cloud.ply", kind="path", help="file name (.ply, .pcd, .npz, .xyz, .txt)")
    color_by: str = option(
        None, kind=str, nullable=True,
        help="per-point attribute to colour the points by (e.g. labels, heights_above_terrain); "
             "null keeps the cloud's own colours",
    )
    colormap: str = option("turbo", choices=tuple(io.COLORMAPS), help="colour map for color_by")

    def check_options(self) -> list[str]:
        suffix = Path(self.path).suffix.lower()
        if suffix in io.LAS_EXTENSIONS:
            return [f"The 'path' option of WriteCloud names a LAS file ({self.path!r}); "
                    "write LAS/LAZ with the writer WriteLas (type: WriteLas), which sets "
                    "the points' ASPRS classes."]
        if suffix not in io.WRITE_EXTENSIONS:
            return [f"The 'path' option of WriteCloud must end in one of "
                    f"{', '.join(io.WRITE_EXTENSIONS)}. Got {self.path!r}."]
        return []

    def required_attributes(self) -> dict[str, str]:
        return {"color_by": self.color_by} if self.color_by else {}

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        if self.color_by:
            frame = frame.with_attributes(colors=_colors_for(frame, self.color_by, self.colormap))
        return [io.write_cloud(self._target(out_dir, self.path), frame)]


_CLASS = Range(0, 255)


@writer
class WriteLas(Writer):
    """Write the cloud as LAS/LAZ with ASPRS classes from the Segmenter's labels."""

    path: str = option("classified.laz", kind="path",
                       help="file name (.las, or .laz compressed)")
    ground_class: int = option(2, rule=_CLASS, help="class of the terrain points (ASPRS 2, "
                               "ground)")
    obstacle_class: int = option(
        1, kind=int, rule=_CLASS, nullable=True,
        help="class of the obstacle points (ASPRS 1, unclassified); null keeps the class "
             "the file gives them, except that a point the file called ground_class gets 1")
    below_class: int = option(
        7, kind=int, rule=_CLASS, nullable=True,
        help="class of the points below the terrain (ASPRS 7, low noise); null keeps the "
             "file's, as for obstacle_class")
    height_above_ground: bool = option(
        True, help="add the extra dimension HeightAboveGround (float32, the file's vertical "
                   "units, NaN where the surface is undefined)")

    def check_options(self) -> list[str]:
        if Path(self.path).suffix.lower() not in io.LAS_EXTENSIONS:
            return [f"The 'path' option of WriteLas must end in .las or .laz. Got {self.path!r}."]
        return []

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        """A copy of the LAS/LAZ file ReadCloud read (product ``las_source``: header,
        coordinate system and every point record kept) with the classification replaced,
        or a new LAS 1.4 file of the frame's points (metres) when the cloud came from
        elsewhere. Points the Segmenter could not label (non-finite, outside the surface)
        keep the file's class (0 in a new file)."""
        if not frame.has_attribute(LABELS):
            raise InputError("WriteLas needs the per-point labels of a Segmenter; add "
                             "'- type: Segmenter' to the stages")
        labels = np.asarray(frame.attribute(LABELS), dtype=np.int64)
        source = frame.products.get("las_source")
        old = None  # the classes as read, for the classes kept
        if (self.obstacle_class is None or self.below_class is None) \
                and frame.has_attribute("classification"):
            old = np.asarray(frame.attribute("classification"), dtype=np.int64)
        classes = np.full(len(frame), io.KEEP_CLASS, np.int64)
        classes[labels == TerrainLabel.TERRAIN] = self.ground_class
        for label, value in ((TerrainLabel.OBSTACLE, self.obstacle_class),
                             (TerrainLabel.BELOW_TERRAIN, self.below_class)):
            mine = labels == label
            if value is not None:
                classes[mine] = value
            elif old is not None:
                # the file's class stays, but not a ground class the Segmenter denies
                classes[mine & (old == self.ground_class)] = 1
        heights = None
        if self.height_above_ground and frame.has_attribute(HEIGHTS_ABOVE_TERRAIN):
            heights = frame.attribute(HEIGHTS_ABOVE_TERRAIN)
        target = self._target(out_dir, self.path)
        if source is not None:
            return [io.write_las(target, classes, source=source, heights_above_ground=heights)]
        return [io.write_las(
            target, classes, positions=frame.positions, heights_above_ground=heights,
            intensities=frame.attribute("intensities") if frame.has_attribute("intensities")
            else None,
            colors=frame.attribute("colors") if frame.has_attribute("colors") else None)]


@writer
class WriteRaster(Writer):
    """Write the terrain surface as a GeoTIFF raster: a DTM (heights) or a slope map."""

    path: str = option("terrain.tif", kind="path", help="file name (.tif or .tiff)")
    layer: str = option("height", choices=LAYERS,
                        help="height: the terrain's height (a DTM, in the cloud's units); "
                             "slope: its slope in degrees")
    cell_size: float = option(None, kind=float, nullable=True, unit="m", rule=POSITIVE,
                              help="raster cell size; null = the fitted grid's cell size")
    max_gap: float = option(
        MAX_GAP, kind=float, nullable=True, unit="m", rule=NON_NEGATIVE,
        help="cells farther than this from every terrain point hold no data (null: every "
             "cell of the surface's region)")
    epsg: int = option(None, kind=int, nullable=True,
                       help="EPSG code of the projected coordinate system the cloud is in; "
                            "null = the LAS/LAZ file's own (none for other clouds)")

    def required_products(self) -> tuple[str, ...]:
        return ("surface",)

    def check_options(self) -> list[str]:
        problems = []
        if Path(self.path).suffix.lower() not in io.GEOTIFF_EXTENSIONS:
            problems.append(f"The 'path' option of WriteRaster must end in .tif or .tiff. "
                            f"Got {self.path!r}.")
        if self.epsg is not None:
            try:
                io.check_epsg(self.epsg)
            except InputError as exc:
                problems.append(f"The 'epsg' option of WriteRaster: {exc}")
        return problems

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        """The surface at the cells' centres (:func:`o3d_terrain.raster.terrain_raster`),
        supported by the Segmenter's terrain points (every point without a Segmenter), in the
        coordinate system and units of the LAS/LAZ file ReadCloud read (product
        ``las_source``) or ``epsg``."""
        surface = frame.product("surface")
        positions = frame.positions
        if frame.has_attribute(LABELS):
            labels = np.asarray(frame.attribute(LABELS))
            positions = positions[labels == TerrainLabel.TERRAIN]
        return [write_terrain_raster(
            self._target(out_dir, self.path), surface, cell_size=self.cell_size,
            layer=self.layer, support=positions, max_gap=self.max_gap,
            source=frame.products.get("las_source"), epsg=self.epsg)]


def image_layers(product: Any) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """The 2-D layers a product offers for images: name -> (values [ix, iy], valid mask, unit)."""
    if isinstance(product, HeightGrid):
        valid = product.valid
        return {
            "z": (product.z, valid, "m"),
            "count": (product.count.astype(float), product.count > 0, "pts"),
            "state": (product.state.astype(float), np.ones_like(valid), ""),
        }
    if hasattr(product, "image_layers"):
        return product.image_layers()
    if isinstance(product, np.ndarray) and product.ndim == 2:
        return {"values": (product, np.isfinite(product), "")}
    raise InputError(f"a {type(product).__name__} product cannot be drawn as an image")


@writer
class WriteImage(Writer):
    """Write a PNG image of a grid product (height grid, surface raster, slope or cost map)."""

    product: str = option("grid", kind=str, help="product to draw (grid, surface, slope_grid, ...)")
    layer: str = option(
        None, kind=str, nullable=True,
        help="layer of the product (grid: z, count, state); null = the product's first layer",
    )
    path: str = option("height.png", kind="path", help="image file name (.png)")
    colormap: str = option("turbo", choices=tuple(io.COLORMAPS), help="colour map")
    value_range: tuple = option(
        None, kind=float, length=2, nullable=True,
        help="values mapped to the ends of the colour map; null = 1st-99th percentile",
    )

    def required_products(self) -> tuple[str, ...]:
        return (self.product,)

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        layers = image_layers(frame.product(self.product))
        name = self.layer or next(iter(layers))
        if name not in layers:
            raise InputError(
                f"WriteImage: product '{self.product}' has no layer '{name}' "
                f"(layers: {', '.join(layers)})"
            )
        values, valid, unit = layers[name]
        image = io.render_grid_image(
            values, valid=valid, colormap=self.colormap, value_range=self.value_range,
            title=f"{self.product}: {name}", unit=unit,
        )
        return [io.write_image(self._target(out_dir, self.path), image)]


@writer
class WriteProduct(Writer):
    """Save a product (grid, surface, ...) to an NPZ file with its ``save`` method."""

    product: str = option("surface", kind=str, help="product to save")
    path: str = option("surface.npz", kind="path", help="file name (.npz)")

    def required_products(self) -> tuple[str, ...]:
        return (self.product,)

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        value = frame.product(self.product)
        target = output_path(self._target(out_dir, self.path))
        if hasattr(value, "save"):
            value.save(target)
        elif isinstance(value, np.ndarray):
            np.savez_compressed(target, values=value)
        else:
            raise InputError(f"WriteProduct: product '{self.product}' cannot be saved to a file")
        return [target]


@writer
class WriteAttribute(Writer):
    """Save one per-point attribute (e.g. labels) as a NumPy .npy or a text file."""

    attribute: str = option("labels", kind=str, help="per-point attribute name")
    path: str = option("labels.npy", kind="path", help="file name (.npy or .txt)")

    def required_attributes(self) -> dict[str, str]:
        return {"attribute": self.attribute}

    def write(self, frame: Frame, out_dir: Path) -> list[Path]:
        values = np.asarray(frame.attribute(self.attribute))
        target = output_path(self._target(out_dir, self.path))
        if target.suffix.lower() == ".txt":
            np.savetxt(target, values, fmt="%d" if np.issubdtype(values.dtype, np.integer) else "%.6f")
        else:
            np.save(target, values)
        return [target]
