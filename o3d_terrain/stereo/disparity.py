"""Disparity by semi-global matching (OpenCV ``StereoSGBM``) with validity checks.

The paper's 3-D engine is a semi-global matcher (Hirschmüller 2005). :class:`StereoMatching`
holds the matcher's options (declared once with :func:`~o3d_terrain.options.option`, so the
``StereoToCloud`` stage and the Python functions share them) and computes a disparity map in
pixels, float32, NaN where no disparity is trusted. Validity comes from:

- the left–right consistency check (``max_left_right_difference``; OpenCV computes the
  right-view disparity from the same cost volume and rejects pixels whose two disparities differ);
- the uniqueness test (``uniqueness_ratio``): the best cost must beat the second best;
- speckle filtering (``speckle_window_size``, ``speckle_range``): small connected blobs that
  differ from their surroundings are removed;
- the disparity range: values at its lower end are "no match";
- a texture check (``min_texture``): blank areas (sky, glare) are invalid rather than matched
  on image noise.

Disparities are sub-pixel (OpenCV fits a parabola to the costs around the minimum; 1/16 px
steps). The columns at the left edge, where the search would run off the right image, are matched
against a replicated border (``match_left_border``) rather than dropped; the consistency check then
rejects the ones without a true match.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..options import Component, NON_NEGATIVE, POSITIVE, Range, component, option
from .calibration import StereoCalibration, load_calibration

__all__ = ["StereoMatching", "StereoMatch", "compute_disparity", "read_image",
           "check_rectified", "fill_disparity_holes", "MODES"]

#: OpenCV StereoSGBM modes by name
MODES = {"sgbm": 0, "hh": 1, "sgbm_3way": 2, "hh4": 3}

#: the disparity range when neither the options nor the calibration give one (full-size pixels)
DEFAULT_MAX_DISPARITY = 128

#: image width (px) on which the rectification check detects features (speed)
CHECK_WIDTH = 320

#: registry of the option holders in this package (not pipeline stages)
SETTINGS: dict[str, type] = {}


def _check_block_size(value: int) -> str | None:
    return None if value % 2 == 1 else "must be odd"


def _check_range(value: tuple | None) -> str | None:
    if value is not None and not value[1] > value[0]:
        return "must have max > min"
    return None


@dataclass(frozen=True)
class StereoMatch:
    """One matched pair, at the matching resolution (after ``downscale``).

    ``disparity`` is float32 pixels of these images, NaN where invalid; ``left`` the rectified
    left image (RGB or grey uint8) at this resolution; ``calibration`` describes these images;
    ``disparity_range`` the ``(min, max)`` searched; ``vertical_offset`` the median vertical
    offset of matched features (px, NaN when not checked).
    """

    disparity: np.ndarray
    left: np.ndarray
    calibration: StereoCalibration
    disparity_range: tuple[int, int]
    vertical_offset: float

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.disparity)


@component(SETTINGS)
class StereoMatching(Component):
    """Semi-global matching options (OpenCV StereoSGBM) and the disparity computation."""

    mode: str = option(
        "sgbm_3way", choices=tuple(MODES),
        help="StereoSGBM mode: sgbm (5 paths), sgbm_3way (fast, parallel), hh (8 paths, full "
             "dynamic programming) or hh4 (4 paths)")
    block_size: int = option(3, rule=Range(1, 11), check=_check_block_size, unit="px",
                             help="side of the matched block (odd); 3 keeps thin obstacles")
    penalty_small: int = option(
        None, kind=int, rule=POSITIVE, nullable=True,
        help="SGM P1, the penalty for a ±1 px disparity change between neighbours; "
             "null = 8 · channels · block_size²")
    penalty_large: int = option(
        None, kind=int, rule=POSITIVE, nullable=True,
        help="SGM P2, the penalty for larger disparity jumps (> penalty_small); "
             "null = 32 · channels · block_size²")
    disparity_range: tuple = option(
        None, kind=float, length=2, nullable=True, unit="px", check=_check_range,
        help="min, max disparity searched (full-size pixels); null = from depth_range, else the "
             "calibration's hint (Middlebury ndisp), else 0–128 px")
    depth_range: tuple = option(
        None, kind=float, length=2, nullable=True, unit="m", rule=POSITIVE, check=_check_range,
        help="nearest, farthest depth of interest; sets the disparity range when disparity_range "
             "is null, and points outside it are dropped from the cloud")
    uniqueness_ratio: int = option(
        10, rule=Range(0, 100), unit="%",
        help="the best matching cost must beat the second best by this margin, else invalid")
    max_left_right_difference: int = option(
        1, kind=int, rule=NON_NEGATIVE, nullable=True, unit="px",
        help="left-right consistency check: largest allowed difference between the left and "
             "right disparities; null = no check")
    speckle_window_size: int = option(
        100, rule=NON_NEGATIVE, unit="px",
        help="connected blobs of fewer pixels that differ from their surroundings are removed; "
             "0 = no speckle filter")
    speckle_range: int = option(
        2, rule=Range(1, None), unit="px",
        help="largest disparity step inside one connected blob (speckle filter)")
    pre_filter_cap: int = option(63, rule=Range(1, 63),
                                 help="clip of the x-derivative prefilter (OpenCV preFilterCap)")
    use_color: bool = option(
        False, help="match on the three colour channels (slower) instead of grey levels")
    match_left_border: bool = option(
        True, help="also match the left columns whose search runs off the right image (padded "
                   "border); false = OpenCV's default, those columns are invalid")
    min_texture: float = option(
        0.0, rule=Range(0, None), unit="grey levels",
        help="pixels whose 7 × 7 neighbourhood in the left image has a standard deviation below "
             "this are invalid (sky, glare and blank areas otherwise match image noise); "
             "0 = no check; 2 suits outdoor scenes with sky")
    downscale: int = option(
        1, rule=Range(1, 8), help="shrink both images by this factor before matching (speed); "
                                  "the cloud has one point per matched pixel")
    fill_holes: bool = option(
        False, help="fill invalid pixels along each row from the farther (smaller) neighbouring "
                    "disparity; for dense maps, not for clouds (filled pixels are guesses)")
    max_vertical_disparity: float = option(
        2.0, rule=POSITIVE, nullable=True, unit="px",
        help="rectification check: the median vertical offset of matched features may not exceed "
             "this (full-size pixels); null = no check")

    # -- public ----------------------------------------------------------------------------------
    def compute(self, left: Any, right: Any, calibration: Any) -> np.ndarray:
        """Disparity of the left image in full-size pixels, float32, NaN where invalid.

        With ``downscale`` > 1 the map is upsampled (nearest) to the input size and its values
        rescaled to full-size pixels.
        """
        left_image = read_image(left, "left")
        match = self.match(left_image, right, calibration)
        if self.downscale == 1:
            return match.disparity
        h, w = left_image.shape[:2]
        import cv2

        up = cv2.resize(match.disparity, (w, h), interpolation=cv2.INTER_NEAREST)
        return up * np.float32(self.downscale)

    def match(self, left: Any, right: Any, calibration: Any) -> StereoMatch:
        """Match a pair at the matching resolution (see :class:`StereoMatch`)."""
        import cv2

        left_image = read_image(left, "left")
        right_image = read_image(right, "right")
        if left_image.shape[:2] != right_image.shape[:2]:
            raise InputError(
                f"the left image is {left_image.shape[1]} × {left_image.shape[0]} and the right "
                f"image {right_image.shape[1]} × {right_image.shape[0]}; a stereo pair needs two "
                "images of the same size"
            )
        if left_image.ndim != right_image.ndim:
            raise InputError("one image is colour and the other grey; give two colour or two grey images")
        calib = load_calibration(calibration)
        h, w = left_image.shape[:2]
        calib = calib.for_images(w, h)
        left_image, right_image = calib.rectify(left_image, right_image)
        low, high = self.resolve_disparity_range(calib)
        offset = float("nan")
        if self.max_vertical_disparity is not None:
            offset = check_rectified(left_image, right_image,
                                     max_vertical_disparity=self.max_vertical_disparity,
                                     source=calib.source)
        if self.downscale > 1:
            size = (max(1, round(w / self.downscale)), max(1, round(h / self.downscale)))
            left_image = cv2.resize(left_image, size, interpolation=cv2.INTER_AREA)
            right_image = cv2.resize(right_image, size, interpolation=cv2.INTER_AREA)
            calib = calib.scaled(1.0 / self.downscale)
            low = math.floor(low / self.downscale)
            high = math.ceil(high / self.downscale)
        disparity = self._sgbm(left_image, right_image, low, high)
        if self.min_texture > 0:
            disparity[local_contrast(left_image) < self.min_texture] = np.nan
        if self.fill_holes:
            disparity = fill_disparity_holes(disparity)
        return StereoMatch(disparity, left_image, calib, (low, high), offset)

    def resolve_disparity_range(self, calibration: StereoCalibration) -> tuple[int, int]:
        """The ``(min, max)`` disparity searched, in full-size pixels (whole numbers)."""
        if self.disparity_range is not None:
            low, high = self.disparity_range
        elif self.depth_range is not None:
            near, far = self.depth_range
            high = float(calibration.disparity_from_depth(near))
            low = float(calibration.disparity_from_depth(far))
            if high <= 0:
                raise InputError(
                    f"depth_range {list(self.depth_range)} m gives disparities ≤ 0 px with this "
                    f"calibration (fx {calibration.fx:.1f} px, baseline {calibration.baseline:.4f} m);"
                    " is the baseline in metres?")
            low = max(low, -calibration.doffs)
        elif calibration.disparity_hint is not None:
            low, high = calibration.disparity_hint
        else:
            low, high = 0.0, float(DEFAULT_MAX_DISPARITY)
        return int(math.floor(low)), int(math.ceil(high))

    # -- private ---------------------------------------------------------------------------------
    def _sgbm(self, left: np.ndarray, right: np.ndarray, low: int, high: int) -> np.ndarray:
        import cv2

        if not self.use_color and left.ndim == 3:
            left = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
            right = cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
        channels = 1 if left.ndim == 2 else 3
        count = max(16, int(math.ceil((high - low) / 16.0)) * 16)
        if count >= left.shape[1]:
            raise InputError(
                f"the disparity range {low}..{low + count} px is as wide as the "
                f"{left.shape[1]} px images; narrow disparity_range or depth_range"
            )
        area = self.block_size * self.block_size * channels
        p1 = self.penalty_small if self.penalty_small is not None else 8 * area
        p2 = self.penalty_large if self.penalty_large is not None else 32 * area
        if p2 <= p1:
            p2 = p1 + 1
        matcher = cv2.StereoSGBM_create(
            minDisparity=int(low), numDisparities=count, blockSize=self.block_size,
            P1=int(p1), P2=int(p2),
            disp12MaxDiff=-1 if self.max_left_right_difference is None else self.max_left_right_difference,
            preFilterCap=self.pre_filter_cap, uniquenessRatio=self.uniqueness_ratio,
            speckleWindowSize=self.speckle_window_size, speckleRange=self.speckle_range,
            mode=MODES[self.mode],
        )
        pad = low + count if self.match_left_border and low + count > 0 else 0
        if pad:
            left = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
            right = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        raw = matcher.compute(left, right)
        if pad:
            raw = raw[:, pad:]
        disparity = raw.astype(np.float32) * np.float32(1.0 / 16.0)
        disparity[raw < low * 16] = np.nan  # OpenCV writes (min_disparity - 1) · 16 for invalid
        return disparity


def compute_disparity(left: Any, right: Any, calibration: Any, **options: Any) -> np.ndarray:
    """Disparity of a rectified pair in pixels (float32 array, NaN where invalid).

    ``left``/``right`` are image paths or arrays (H, W) grey or (H, W, 3) RGB, uint8, uint16 or
    float in [0, 1]; ``calibration`` a path or a :class:`StereoCalibration`. ``options`` are
    those of :class:`StereoMatching` (``mode``, ``block_size``, ``disparity_range``,
    ``depth_range``, ``downscale``, ...); unknown or invalid ones raise
    :class:`~o3d_terrain.errors.ConfigError`.
    """
    return StereoMatching(**options).compute(left, right, calibration)


# ---------------------------------------------------------------------------------------------
# images


def read_image(image: Any, name: str = "image") -> np.ndarray:
    """An image as uint8, (H, W) grey or (H, W, 3) RGB. Paths are read with OpenCV (BGR files
    become RGB); arrays are taken as RGB. uint16 keeps the top 8 bits of its used range; float
    must be in [0, 1]."""
    import cv2

    if isinstance(image, (str, os.PathLike)):
        path = Path(image)
        if not path.exists():
            raise InputError(f"{path}: no such {name} image; check the path (relative paths in a "
                             "pipeline file are resolved against the file's folder)")
        array = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if array is None:
            raise InputError(f"{path}: OpenCV cannot read this {name} image (not an image file?)")
        if array.ndim == 3 and array.shape[2] == 4:
            array = cv2.cvtColor(array, cv2.COLOR_BGRA2RGB)
        elif array.ndim == 3 and array.shape[2] == 3:
            array = cv2.cvtColor(array, cv2.COLOR_BGR2RGB)
        where = str(path)
    else:
        array = np.asarray(image)
        where = f"the {name} image"
    if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise InputError(f"{where}: expected a numeric image array, got dtype {array.dtype}")
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim == 3 and array.shape[2] == 4:
        array = array[:, :, :3]
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)):
        raise InputError(f"{where}: expected an (H, W) grey or (H, W, 3) colour image, got shape "
                         f"{array.shape}")
    if array.shape[0] < 8 or array.shape[1] < 8:
        raise InputError(f"{where}: the image is {array.shape[1]} × {array.shape[0]} px; too small "
                         "to match (at least 8 × 8)")
    if array.dtype == np.uint8:
        return np.ascontiguousarray(array)
    if np.issubdtype(array.dtype, np.floating):
        if not np.isfinite(array).all():
            raise InputError(f"{where}: the image has NaN or infinite values")
        if array.min() < 0 or array.max() > 1:
            raise InputError(f"{where}: a float image must have values in [0, 1], got "
                             f"[{array.min():.3g}, {array.max():.3g}]")
        return np.ascontiguousarray(np.round(array * 255).astype(np.uint8))
    if array.dtype == np.uint16:
        top = int(array.max())
        shift = max(0, top.bit_length() - 8)
        return np.ascontiguousarray((array >> shift).astype(np.uint8))
    raise InputError(f"{where}: unsupported image type {array.dtype}; give uint8, uint16 or float "
                     "in [0, 1]")


def check_rectified(left: np.ndarray, right: np.ndarray, *, max_vertical_disparity: float = 2.0,
                    source: str = "calibration", min_matches: int = 30) -> float:
    """Median vertical offset (px) of ORB features matched between the two images.

    Raises :class:`InputError` when it exceeds ``max_vertical_disparity`` (the pair is not
    rectified) or when most matches have a negative disparity (left and right swapped). Returns
    NaN when too few features match to tell (textureless images).
    """
    import cv2

    def grey(image: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image

    a, b = grey(left), grey(right)
    scale = 1.0
    if a.shape[1] > CHECK_WIDTH:  # features on a reduced copy: the check must stay cheap
        scale = CHECK_WIDTH / a.shape[1]
        size = (CHECK_WIDTH, max(8, round(a.shape[0] * scale)))
        a = cv2.resize(a, size, interpolation=cv2.INTER_AREA)
        b = cv2.resize(b, size, interpolation=cv2.INTER_AREA)
    orb = cv2.ORB_create(nfeatures=300)
    ka, da = orb.detectAndCompute(a, None)
    kb, db = orb.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < min_matches or len(kb) < min_matches:
        return float("nan")
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    matches = [m for m in matches if m.distance < 48]
    if len(matches) < min_matches:
        return float("nan")
    pa = np.array([ka[m.queryIdx].pt for m in matches])
    pb = np.array([kb[m.trainIdx].pt for m in matches])
    dy = np.abs(pa[:, 1] - pb[:, 1]) / scale
    dx = (pa[:, 0] - pb[:, 0]) / scale
    # robust to wrong matches: the median of the matches that agree in y within a generous band
    offset = float(np.median(dy))
    if offset > max_vertical_disparity:
        raise InputError(
            f"{source}: the pair does not look rectified: matched features are {offset:.1f} px "
            f"apart vertically (median of {len(matches)} matches; at most "
            f"{max_vertical_disparity:g} px allowed); rectify the images first (cv2.stereoRectify "
            "+ cv2.remap, or give the raw OpenCV calibration M1, D1, M2, D2, R, T), or raise "
            "max_vertical_disparity"
        )
    near_rows = dy <= max(max_vertical_disparity, 1.0)
    if near_rows.sum() >= min_matches and np.mean(dx[near_rows] < -1.0) > 0.8:
        raise InputError(
            f"{source}: most matched features have a negative disparity (the right image's "
            "feature is to the right of the left one's): the left and right images look swapped"
        )
    return offset


def local_contrast(image: np.ndarray, size: int = 7) -> np.ndarray:
    """Standard deviation of the grey levels in a ``size`` × ``size`` window around each pixel."""
    import cv2

    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    values = grey.astype(np.float32)
    mean = cv2.boxFilter(values, -1, (size, size))
    mean_square = cv2.boxFilter(values * values, -1, (size, size))
    return np.sqrt(np.maximum(mean_square - mean * mean, 0.0))


def fill_disparity_holes(disparity: np.ndarray) -> np.ndarray:
    """Fill NaN pixels along each row with the smaller (farther) of the nearest valid
    disparities to their left and right: occlusions belong to the background."""
    d = np.asarray(disparity, dtype=np.float32)
    h, w = d.shape
    valid = np.isfinite(d)
    columns = np.arange(w)[None, :]
    left = np.maximum.accumulate(np.where(valid, columns, -1), axis=1)
    right = np.minimum.accumulate(np.where(valid, columns, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    from_left = np.where(left >= 0, d[rows, np.clip(left, 0, w - 1)], np.inf)
    from_right = np.where(right < w, d[rows, np.clip(right, 0, w - 1)], np.inf)
    fill = np.minimum(from_left, from_right).astype(np.float32)
    fill[~np.isfinite(fill)] = np.nan
    return np.where(valid, d, fill)
