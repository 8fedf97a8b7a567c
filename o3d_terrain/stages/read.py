"""ReadCloud: a point cloud file as the source of a pipeline."""

from __future__ import annotations

from pathlib import Path

from ..frame import Frame
from ..io import CLOUD_EXTENSIONS, LAS_EXTENSIONS, UNITS, LasSource, file_attributes, read_cloud
from ..options import option
from .base import SourceStage, stage


def _check_extension(path: str) -> str | None:
    if not str(path).lower().endswith(CLOUD_EXTENSIONS):
        return f"must name a point cloud file ({', '.join(CLOUD_EXTENSIONS)})"
    return None


@stage
class ReadCloud(SourceStage):
    """Read a point cloud file: PLY, PCD, XYZ/TXT/CSV, NPY, KITTI .bin, LAS/LAZ.

    A LAS/LAZ file also gives the frame the product ``las_source``
    (:class:`o3d_terrain.io.LasSource`), from which ``WriteLas`` copies the file's header,
    coordinate system and point records.
    """

    path_options = ("path",)
    writes = ()
    example = {"path": "cloud.ply"}

    path: str = option(kind="path", check=_check_extension, help="the point cloud file to read")
    units: str = option("metres", choices=UNITS,
                        help="LAS/LAZ: 'metres' converts from the units the file declares "
                             "(US-feet tiles are scaled by 0.3048) so metric options mean "
                             "metres; 'file' keeps the file's coordinates")

    def given_attributes(self) -> tuple[str, ...] | None:
        """What the file's format may carry (:data:`o3d_terrain.io.FILE_ATTRIBUTES`); None
        for a PLY or PCD file, which carries whatever it was written with."""
        return file_attributes(self.path)

    def read(self) -> Frame:
        frame = Frame(read_cloud(self.path, units=self.units)).with_note(
            f"{self.type_name}: read {self.path}")
        if Path(self.path).suffix.lower() in LAS_EXTENSIONS:
            frame = frame.with_products(
                las_source=LasSource(Path(self.path), self.units, len(frame)))
        return frame
