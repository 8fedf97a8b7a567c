"""StereoToCloud: a rectified stereo pair as the source of a pipeline (paper Sec. III)."""

from __future__ import annotations

from typing import Any, ClassVar

from ..frame import Frame
from ..options import option
from ..stereo.cloud import StereoCloud
from .base import SourceStage, stage

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


def _check_image(path: str) -> str | None:
    if not str(path).lower().endswith(IMAGE_EXTENSIONS):
        return f"must name an image file ({', '.join(IMAGE_EXTENSIONS)})"
    return None


@stage
class StereoToCloud(SourceStage, StereoCloud):
    """Match a rectified stereo pair (semi-global matching) and reproject it to a coloured cloud.

    Disparity by OpenCV StereoSGBM with a left–right consistency check, uniqueness test and
    speckle filter, sub-pixel (1/16 px); invalid pixels and points outside ``depth_range`` are
    dropped. The cloud is in the rectified left-camera frame (x right, y down, z forward) or,
    with ``frame: vehicle`` and ``camera_height``/``pitch_deg``/``roll_deg``, in a vehicle frame
    (x forward, y left, z up). Each point keeps its pixel's colour (``colors``), its disparity
    and its pixel (``image_rows``, ``image_columns``); the product ``disparity`` holds the map.
    From Python, :meth:`from_images` (or :func:`o3d_terrain.stereo.stereo_to_cloud`) takes
    arrays instead of files.
    """

    path_options: ClassVar[tuple[str, ...]] = ("left", "right", "calibration")
    writes = ("disparity",)
    writes_attributes = ("colors", "disparities", "image_rows", "image_columns")
    example = {"left": "left.png", "right": "right.png", "calibration": "calib.txt"}

    left: str = option(kind="path", check=_check_image, help="the rectified left image")
    right: str = option(kind="path", check=_check_image, help="the rectified right image")
    calibration: str = option(
        kind="path",
        help="calibration file: KITTI or Middlebury calib.txt, OpenCV YAML/XML, or plain YAML "
             "(fx, cx, cy, baseline)")

    def read(self) -> Frame:
        frame = self.make_frame(self.left, self.right, self.calibration)
        return frame.with_note(f"{self.type_name}: matched {self.left} / {self.right}")

    @classmethod
    def from_images(cls, left: Any, right: Any, calibration: Any, **options: Any) -> Frame:
        """Run on image arrays (RGB or grey) or paths and a calibration (path, mapping or
        :class:`~o3d_terrain.stereo.StereoCalibration`), with this stage's other options."""
        return StereoCloud(**options).make_frame(left, right, calibration)
