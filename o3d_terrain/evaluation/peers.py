"""Adapters for the ground-segmentation methods users compare us with.

Every adapter has a ``name`` and ``segment(positions) -> (N,) bool ground mask`` over an
(N, 3) float64 array in metres. Settings are each package's defaults; a parameter is set only
where the peer *requires* knowledge of the data, and each such choice is written next to it:

========================  ===================================================================
peer (pip package)        settings
========================  ===================================================================
``patchworkpp``           ``pypatchworkpp`` defaults (KITTI HDL-64E: sensor height 1.723 m,
(``pypatchworkpp``)       range 2.7-80 m); the sensor height is set to the frame's when the
                          frame knows it (synthetic scenes; Patchwork++ requires it).
                          Reflected-noise removal is switched off because it
                          needs intensities and the adapter gives positions only. Aerial tiles:
                          Patchwork++ assumes a scan centred on a sensor, so a virtual sensor is
                          placed above the tile centre at the default 1.723 m over the lowest
                          5 % of heights within 10 m of it, min range 0 and max range the
                          tile's half diagonal (without these every point is out of range).
``csf``                   ``cloth-simulation-filter`` defaults (cloth resolution 1 m, class
(``CSF``)                 threshold 0.5 m, rigidness 3, slope smoothing on, 500 iterations);
                          positions are shifted to the tile's minimum corner (CSF works in
                          single precision internally; a translation changes nothing else).
``smrf``                  ``pysmrf.classify`` defaults (1 m cells, windows 1-5 cells, slope
(``pysmrf``)              0.15, elevation threshold 0.5 m, scaler 1.25), one worker.
``ransac_plane``          Open3D ``segment_plane(distance_threshold=0.2, ransac_n=3,
(``open3d``)              num_iterations=1000)`` as users typically call it, seeded; the
                          inliers of the dominant plane are the ground.
========================  ===================================================================

Metric parameters mean metres because the evaluation datasets convert feet to metres.
The peers' C++ code prints progress to standard output; the adapters silence it.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import InputError

BENCH_EXTRA_HINT = "install the peers with the bench extra: pip install 'o3d_terrain[bench]'"


@contextlib.contextmanager
def quiet_stdout():
    """Silence writes to file descriptor 1 (C/C++ printf) for the duration of the block."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):  # no real stdout (e.g. captured)
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            try:
                yield
            finally:
                sys.stdout.flush()
                os.dup2(saved, 1)
    finally:
        os.close(saved)


def _check_positions(positions: np.ndarray, who: str) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"{who}: positions have shape {positions.shape}; need (N, 3)")
    return positions


def _finite_points(positions: np.ndarray, who: str) -> tuple[int, np.ndarray, np.ndarray]:
    """(number of points, indices of the finite ones, those points shifted to a local origin):
    the peers get finite points only, near zero so float32 internals keep their precision."""
    positions = _check_positions(positions, who)
    finite = np.flatnonzero(np.isfinite(positions).all(axis=1))
    points = positions[finite]
    return len(positions), finite, points - points.min(axis=0)


def _indices_to_mask(indices: np.ndarray, n: int) -> np.ndarray:
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(indices, dtype=np.int64)] = True
    return mask


@dataclass
class PatchworkPP:
    """Patchwork++ (Lee et al., IROS 2022) through ``pypatchworkpp``."""

    kind: str = "vehicle_lidar"  # or "aerial": place a virtual sensor above the tile centre
    sensor_height: float | None = None  # None: the package default (1.723 m, KITTI)
    name: str = "patchworkpp"
    package: str = "pypatchworkpp"
    _engine: object = field(default=None, repr=False)
    _key: tuple = field(default=(), repr=False)

    def _get_engine(self, min_range: float | None, max_range: float | None):
        import pypatchworkpp

        key = (min_range, max_range)
        if self._engine is None or key != self._key:
            params = pypatchworkpp.Parameters()
            params.enable_RNR = False  # needs intensities; positions only are given
            params.verbose = False
            if self.sensor_height is not None and self.kind != "aerial":
                params.sensor_height = float(self.sensor_height)
            if min_range is not None:
                params.min_range = min_range
            if max_range is not None:
                params.max_range = max_range
            with quiet_stdout():
                self._engine = pypatchworkpp.patchworkpp(params)
            self._key = key
        return self._engine

    def segment(self, positions: np.ndarray) -> np.ndarray:
        positions = _check_positions(positions, self.name)
        n = len(positions)
        points = positions
        min_range = max_range = None
        if self.kind == "aerial":
            points, max_range = _virtual_sensor(positions, sensor_height=1.723)
            min_range = 0.0
        engine = self._get_engine(min_range, max_range)
        finite = np.isfinite(points).all(axis=1)
        with quiet_stdout():
            engine.estimateGround(np.ascontiguousarray(points[finite]))
            ground = engine.getGroundIndices()
        return _indices_to_mask(np.flatnonzero(finite)[ground], n)


def _virtual_sensor(positions: np.ndarray, sensor_height: float) -> tuple[np.ndarray, float]:
    """Shift an aerial tile so a virtual sensor sits at the origin, 1.723 m over the ground."""
    lo, hi = positions[:, :2].min(axis=0), positions[:, :2].max(axis=0)
    centre = (lo + hi) / 2
    distance = np.hypot(*(positions[:, :2] - centre).T)
    near = distance < 10.0
    if near.sum() < 10:
        near = distance <= np.partition(distance, min(50, len(distance) - 1))[min(50, len(distance) - 1)]
    ground_z = np.percentile(positions[near, 2], 5)
    shifted = positions - np.array([centre[0], centre[1], ground_z + sensor_height])
    return shifted, float(distance.max() + 1.0)


@dataclass
class ClothSimulationFilter:
    """CSF (Zhang et al., Remote Sensing 2016) through ``cloth-simulation-filter``."""

    kind: str = "vehicle_lidar"
    name: str = "csf"
    package: str = "cloth-simulation-filter"

    def segment(self, positions: np.ndarray) -> np.ndarray:
        import CSF

        n, finite, points = _finite_points(positions, self.name)
        csf = CSF.CSF()  # defaults: cloth_resolution 1.0, class_threshold 0.5, rigidness 3
        ground, non_ground = CSF.VecInt(), CSF.VecInt()
        with quiet_stdout():
            csf.setPointCloud(np.ascontiguousarray(points))
            csf.do_filtering(ground, non_ground, exportCloth=False)
        return _indices_to_mask(finite[np.asarray(ground, dtype=np.int64)], n)


@dataclass
class SimpleMorphologicalFilter:
    """SMRF (Pingel et al., ISPRS J. 2013) through ``pysmrf``."""

    kind: str = "vehicle_lidar"
    name: str = "smrf"
    package: str = "pysmrf"

    def segment(self, positions: np.ndarray) -> np.ndarray:
        import pysmrf

        n, finite, points = _finite_points(positions, self.name)
        with quiet_stdout(), warnings.catch_warnings():
            warnings.simplefilter("ignore", PendingDeprecationWarning)  # rasterio/affine inside
            result = pysmrf.classify(points[:, 0], points[:, 1], points[:, 2], workers=1)
        mask = np.zeros(n, dtype=bool)
        mask[finite] = np.asarray(result.is_ground, dtype=bool)
        return mask


@dataclass
class RansacPlane:
    """The dominant plane of Open3D ``segment_plane`` (distance 0.2 m) taken as the ground."""

    kind: str = "vehicle_lidar"
    name: str = "ransac_plane"
    package: str = "open3d"
    distance_threshold: float = 0.2
    seed: int = 0

    def segment(self, positions: np.ndarray) -> np.ndarray:
        import open3d as o3d

        n, finite, points = _finite_points(positions, self.name)
        if len(points) < 3:
            return np.zeros(n, dtype=bool)
        o3d.utility.random.seed(self.seed)
        cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(points)))
        _, inliers = cloud.segment_plane(
            distance_threshold=self.distance_threshold, ransac_n=3, num_iterations=1000
        )
        return _indices_to_mask(finite[inliers.numpy().astype(np.int64)], n)


#: peer name -> (adapter class, importable module that must be present)
PEERS: dict[str, tuple[Callable[..., object], str]] = {
    "patchworkpp": (PatchworkPP, "pypatchworkpp"),
    "csf": (ClothSimulationFilter, "CSF"),
    "smrf": (SimpleMorphologicalFilter, "pysmrf"),
    "ransac_plane": (RansacPlane, "open3d"),
}


def peer_status() -> dict[str, str | None]:
    """Peer name -> None when usable, else the reason it is not (missing package)."""
    status = {}
    for name, (factory, module) in PEERS.items():
        if importlib.util.find_spec(module) is None:
            status[name] = f"module '{module}' not installed ({BENCH_EXTRA_HINT})"
        else:
            status[name] = None
    return status


def make_peer(name: str, *, kind: str = "vehicle_lidar", sensor_height: float | None = None):
    """An adapter for the named peer; :class:`InputError` naming the bench extra when missing.

    ``sensor_height`` (m) is used by the peers that need it (Patchwork++); None = default.
    """
    if name not in PEERS:
        raise InputError(
            f"unknown peer method '{name}'; choose one of {', '.join(PEERS)}"
        )
    reason = peer_status()[name]
    if reason:
        raise InputError(f"peer '{name}' is not available: {reason}")
    factory, _ = PEERS[name]
    if name == "patchworkpp":
        return factory(kind=kind, sensor_height=sensor_height)
    return factory(kind=kind)
