"""Compile the numba kernels before the first real call (``o3d-terrain warmup``).

The kernels are compiled the first time they run and cached on disk (numba ``cache=True``): the
first ``segment_terrain`` after an install takes tens of seconds, every later process about a
second to load the cache. :func:`warm_up` runs the library's stages on small generated clouds so
that the compilation happens at install or image-build time instead of on a vehicle's first
frame, and reports which kernels were compiled and where the cache lies.

numba keys its cache by the source files and the machine's CPU: reinstalling the package or
moving the cache to a different CPU model compiles again (docs/quickstart.md, "The first call").
"""

from __future__ import annotations

import importlib
import pkgutil
import time
from dataclasses import dataclass, field

import numba
import numpy as np

__all__ = ["WarmupReport", "kernels", "warm_up"]

@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warm_up` did: time taken, the kernels called from Python that now hold
    machine code (compiled, or loaded from the cache), where the cache lies, the paths run."""

    seconds: float
    ready: tuple[str, ...]
    cache_dir: str | None
    steps: tuple[str, ...] = field(default_factory=tuple)

    def summary(self) -> str:
        return (f"{len(self.ready)} numba kernel(s) ready in {self.seconds:.1f} s "
                f"({', '.join(self.steps)})\n"
                f"cache: {self.cache_dir or 'none (caching is off: NUMBA_DISABLE_JIT?)'}")


def kernels() -> dict[str, object]:
    """Every numba dispatcher defined in the package, by ``module.name``."""
    import numba.core.registry

    import o3d_terrain

    found: dict[str, object] = {}
    for info in pkgutil.walk_packages(o3d_terrain.__path__, "o3d_terrain."):
        if info.name.startswith("o3d_terrain.evaluation") or info.name.endswith("__main__"):
            continue  # the eval commands' optional peers; the command line's entry point
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, numba.core.registry.CPUDispatcher) \
                    and value.py_func.__module__ == info.name:
                found[f"{info.name}.{name}"] = value
    return found


def _cache_dir(dispatchers) -> str | None:
    for dispatcher in dispatchers:
        cache = getattr(dispatcher, "_cache", None)
        path = getattr(cache, "cache_path", None)
        if path:
            return str(path)
    return None


def warm_up() -> WarmupReport:
    """Run every default path once on small generated clouds (a 32-beam lidar and a stereo
    camera over the off-road scene, an airborne strip over a forested hillside):
    ``segment_terrain`` on an array and on an Open3D cloud, and on a scan moved into a map
    frame (its sensor found from the scan), the stage chain with obstacles and a cost map, the
    stereo chain with its range-dependent noise, the paper's fit, and a top-down tile in
    projected coordinates through the LAS pipeline's stages and rasters
    (:func:`_top_down_tile`). Returns the :class:`WarmupReport`."""
    import open3d as o3d

    from ._kernels.positions import xyz_float64
    from .api import fit_terrain, segment_terrain
    from .pipeline import parse_pipeline
    from .stages import ObstacleDetector

    start = time.perf_counter()
    steps = []
    lidar = {"type": "SyntheticScene", "scene": "offroad", "sensor": "lidar", "beams": 16,
             "azimuth_steps": 360}
    result = parse_pipeline({"source": lidar, "stages": [
        {"type": "GridQuantize"}, {"type": "RationalBSplineTerrain"},
        {"type": "SlopeEstimator"}, {"type": "Segmenter"}, {"type": "ObstacleDetector"},
        {"type": "TraversabilityCost"}]}).run()
    ObstacleDetector(method="dbscan")(result.frame)
    steps.append("lidar stage chain")
    positions = np.array(result.frame.positions, dtype=np.float64)
    segment_terrain(positions)
    # a lidar's float32 (x, y, z, intensity) rows, as KITTI stores them, become float64
    # positions in their own kernel; everything after it is the float64 path above
    xyz_float64(np.zeros((1, 4), np.float32))
    segment_terrain(o3d.t.geometry.PointCloud(o3d.core.Tensor(positions)))
    segment_terrain(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(positions)))
    segment_terrain(_ridged_slope())
    threads = numba.get_num_threads()
    if threads > 1:  # some kernels have a serial twin for one thread (heights_above)
        numba.set_num_threads(1)
        try:
            segment_terrain(positions)
        finally:
            numba.set_num_threads(threads)
    steps.append("segment_terrain")
    # a vehicle's scan in a map frame: the sensor found from the scan (o3d_terrain.locate)
    from .synthetic import make_scene, sample_lidar
    valley = sample_lidar(make_scene("valley", seed=0), azimuth_steps=360, seed=0)
    segment_terrain(np.asarray(valley.positions, dtype=np.float64) + (5.0e5, 4.0e6, 100.0))
    steps.append("segment_terrain in a map frame")
    fit_terrain(positions, method="paper")
    steps.append("paper fit")
    stereo = {"type": "SyntheticScene", "scene": "offroad", "sensor": "stereo",
              "image_size": [160, 120]}
    parse_pipeline({"source": stereo, "stages": [
        {"type": "GridQuantize"}, {"type": "RationalBSplineTerrain", "range_noise": 0.001},
        {"type": "SlopeEstimator"},
        {"type": "Segmenter", "threshold": 0.2, "range_coefficient": 0.0005}]}).run()
    steps.append("stereo stage chain")
    _top_down_tile()
    steps.append("top-down tile")
    found = kernels()
    ready = tuple(sorted(k for k, d in found.items() if d.signatures))
    return WarmupReport(time.perf_counter() - start, ready, _cache_dir(found.values()),
                        tuple(steps))


#: the stages of the packaged LAS pipeline (pipelines/las_terrain.yaml), which
#: :func:`_top_down_tile` runs
_TOP_DOWN_STAGES = ({"type": "GridQuantize", "cell_size": 1.0},
                   {"type": "RationalBSplineTerrain"},
                   {"type": "SlopeEstimator", "cell_size": 1.0},
                   {"type": "Segmenter"})


def _top_down_tile() -> None:
    """The top-down path (an airborne LAS tile in projected coordinates, far from the
    origin: no sensor in the cloud) on two generated strips over a forested hillside, one as
    it is and one with ridges the surface cannot follow (the misfit's widened blocks): each
    with the attributes ``read_cloud`` gives a LAS tile (classes, intensities, return
    numbers) through the LAS pipeline's stages (pipelines/las_terrain.yaml) and its rasters
    (:func:`o3d_terrain.raster.terrain_raster`, what ``WriteRaster`` computes), and through
    ``segment_terrain`` as an array and as an Open3D cloud."""
    from .api import segment_terrain
    from .frame import LABELS, NUMBER_OF_RETURNS, RETURN_NUMBERS, cloud_from_numpy
    from .pipeline import parse_pipeline
    from .raster import LAYERS, terrain_raster
    from .segment import TerrainLabel
    from .synthetic import make_scene, sample_airborne

    scene = make_scene("forest", seed=0, region=(-60.0, 60.0, -50.0, 50.0))
    tile = sample_airborne(scene, density=3.0, offset=(6.3e5, 4.8e6, 120.0), seed=0)
    for ridges in (0.0, 0.6):
        positions = np.array(tile.positions, dtype=np.float64)
        # ridges and gullies 10 m apart that the automatic layout cannot follow
        positions[:, 2] += ridges * np.sin(2.0 * np.pi * positions[:, 1] / 10.0)
        n = len(positions)
        # every tenth pulse gave two returns, both kept (the first never terrain)
        number_of_returns = np.where(np.arange(n) % 10 == 0, 2, 1).astype(np.int32)
        return_numbers = np.ones(n, np.int32)
        return_numbers[np.arange(n) % 20 == 0] = 2
        cloud = cloud_from_numpy(
            positions, classification=np.ones(n, np.int32),
            intensities=np.full(n, 100.0, np.float32),
            **{RETURN_NUMBERS: return_numbers, NUMBER_OF_RETURNS: number_of_returns})
        frame = parse_pipeline({"stages": list(_TOP_DOWN_STAGES)}).run(cloud).frame
        terrain = frame.positions[np.asarray(frame.attribute(LABELS)) == TerrainLabel.TERRAIN]
        for layer in LAYERS:  # WriteRaster's DTM and slope map, without the GeoTIFF file
            terrain_raster(frame.product("surface"), cell_size=1.0, layer=layer,
                           support=terrain)
        segment_terrain(positions)
        segment_terrain(cloud)


def _ridged_slope() -> np.ndarray:
    """A sparse 35° slope with ridges and gullies 10 m apart that the automatic control
    spacing cannot follow: the surface's misfit widens the threshold there (the
    :mod:`o3d_terrain.misfit` path, which level scans rarely take)."""
    rng = np.random.default_rng(0)
    n = 12_000
    x, y = rng.uniform(0, 150, n), rng.uniform(0, 120, n)
    z = 0.7 * x + 0.6 * np.sin(2 * np.pi * y / 10.0) + rng.normal(0, 0.03, n)
    return np.column_stack([x, y, z])
