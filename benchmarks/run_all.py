"""Regenerate docs/benchmarks.md: accuracy and speed of o3d_terrain against its peers.

    python benchmarks/run_all.py --write-docs          # what `make bench` runs
    python benchmarks/run_all.py --quick               # fewer repeats, print only

Every measurement runs in its own subprocess (``--worker``) with the thread counts pinned
before any import (OMP/NUMBA/BLAS env vars, plus threadpoolctl when installed), a time limit,
and its own peak memory (tracemalloc peak of one run; process peak RSS from ru_maxrss). Times
are medians of ``--repeats`` runs after one warm-up run (which also compiles numba kernels).
A missing method, peer or data set gives "n/a" with the reason, never a crash.

Data: the real scans in ../shared/data (or $O3D_TERRAIN_DATA) and the synthetic scenes;
``kitti-tilt`` is the SemanticKITTI frames rotated about the sensor origin (KITTI_TILTS);
``kitti-lines`` the same frames with every 2nd or 4th scan line only (KITTI_LINES), what a
32- or 16-line lidar sees; ``kitti-fov`` the same frames cropped to a forward field of view
(KITTI_FOVS), a camera's or a solid-state lidar's; ``kitti-low`` the same frames with some
points moved below the ground (KITTI_LOW); ``kitti-noise`` the same frames with Gaussian
noise added to every z (KITTI_NOISE), a noisier sensor's or rough ground's (the families:
KITTI_FAMILIES); ``synthetic-solid`` the synthetic scenes seen by a forward-looking
solid-state lidar with a non-repetitive scan (``synthetic.sample_solid_state``);
``dem-sites`` the 8 sites of the real raster ``dem_1m/dem.tif`` of
benchmarks/bench_dem_sites.py (DEM_SENSORS); ``forest`` 4 of those sites under a conifer
forest with shrubs seen from the air, several returns per pulse, at FOREST_DENSITIES
(benchmarks/bench_forest.py); ``pit`` an open pit's benches seen from its floor and from a
berm (benchmarks/bench_pit.py); ``overhead`` a lidar under a roof: mine drifts, tunnels, a
cavern and a hall (benchmarks/bench_overhead.py).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import itertools
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "benchmarks.md"
FIGURES = ROOT / "docs" / "figures"
OURS = "o3d_terrain"
#: ours with the option the README gives for a forward crop of a street scan, on the
#: ``kitti-fov`` frames only (docs/algorithm.md, "A 30° slope limit for a street crop")
OURS_STREET = "o3d_terrain_street"
STREET_OPTIONS = {"max_slope_deg": 30.0}
PEER_NAMES = ("patchworkpp", "csf", "smrf", "ransac_plane")
#: the sensors of the ``dem-sites`` data set (benchmarks/bench_dem_sites.py), with their titles
DEM_SENSORS = {"vehicle64": "a 64-line lidar on the tilted vehicle",
               "vehicle16": "a 16-line lidar on the tilted vehicle",
               "airborne": "an airborne strip (6 pulses per m²)"}
#: pulses per m² of the ``forest`` data set (benchmarks/bench_forest.py): a sparse mountain
#: survey's and a common one's
FOREST_DENSITIES = ("0.5", "2")


def _pin_threads(threads: int) -> None:
    for var in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
        os.environ[var] = str(threads)


# =============================================================================================
# worker side (a subprocess per measurement)


def _data_root() -> Path | None:
    from o3d_terrain.evaluation.datasets import data_root

    return data_root()


def load_frames(spec: str, seed: int = 0):
    """Labelled frames and failures for a benchmark data-set name."""
    from o3d_terrain.evaluation import datasets as ds

    root = _data_root()
    if spec.startswith("las:"):
        if root is None:
            raise FileNotFoundError("no ../shared/data folder (set O3D_TERRAIN_DATA)")
        return ds.iter_frames(ds.las_frames(root / "las" / spec[4:]))
    if spec in ("kitti", "kitti1", "las", "las700k"):
        if root is None:
            raise FileNotFoundError("no ../shared/data folder (set O3D_TERRAIN_DATA)")
        if spec.startswith("kitti"):
            items = list(ds.semantic_kitti_frames(root / "kitti_seq00_lidar",
                                                  limit=1 if spec == "kitti1" else None))
        elif spec == "las":
            items = list(ds.las_frames(root / "las"))
        else:
            items = [ds.read_las_frame(root / "las" / "las_with_several_extra_byte_bloc.laz")]
        return ds.iter_frames(items)
    family = spec.split(":", 1)[0]
    if ":" in spec and family in KITTI_FAMILIES:
        return _kitti_variant(root, spec, *KITTI_FAMILIES[family])
    if spec == "synthetic":
        return ds.iter_frames(ds.synthetic_frames(list(ds.synthetic_scene_names()), seed=seed))
    if spec == "synthetic-solid":  # a forward-looking lidar with a non-repetitive scan
        return ds.iter_frames(ds.synthetic_frames(list(ds.synthetic_scene_names()), seed=seed,
                                                  sensor="solid_state"))
    if spec.startswith("dem-sites:"):  # the real raster's relief, synthetic sensors
        from bench_dem_sites import site_frames

        return list(site_frames(spec.split(":", 1)[1])), []
    if spec.startswith("forest:"):  # the raster's relief under a forest, from the air
        from bench_forest import forest_frames

        return [frame for frame, _ in forest_frames(float(spec.split(":", 1)[1]))], []
    if spec == "pit":  # an open pit's benches seen from its floor and from the first berm
        from bench_pit import pit_frames

        return list(pit_frames()), []
    if spec == "overhead":  # a lidar under a roof: drifts, tunnels, caverns, halls
        from bench_overhead import overhead_frames

        return list(overhead_frames()), []
    if spec in ("lidar120k", "stereo300k", "paper34x22"):
        return [_standard_frame(spec, seed)], []
    raise ValueError(f"unknown benchmark data set '{spec}'")


def _kitti_variant(root, spec: str, variants: dict, what: str, make):
    """The SemanticKITTI frames of a ``family:variant`` data set (a family of
    :data:`KITTI_FAMILIES`): ``make(frame, variants[variant])`` of each frame, and the
    frames that failed to load."""
    from o3d_terrain.evaluation import datasets as ds

    if root is None:
        raise FileNotFoundError("no ../shared/data folder (set O3D_TERRAIN_DATA)")
    variant = spec.split(":", 1)[1]
    if variant not in variants:
        raise ValueError(f"unknown {what} '{variant}' in '{spec}'; choose one of "
                         f"{', '.join(variants)}")
    frames, failures = ds.iter_frames(ds.semantic_kitti_frames(root / "kitti_seq00_lidar"))
    return [make(f, variants[variant]) for f in frames], failures


#: the ``kitti-tilt`` data set: the SemanticKITTI frames rotated about the sensor origin by
#: (roll about x, pitch about y) in degrees; "level" is the unrotated reference
KITTI_TILTS = {"level": (0.0, 0.0), "pitch5": (0.0, 5.0), "pitch10": (0.0, 10.0),
               "pitch20": (0.0, 20.0), "roll5": (5.0, 0.0), "roll10": (10.0, 0.0)}


def tilt_rotation(roll_deg: float, pitch_deg: float):
    """The 3 x 3 rotation R_y(pitch) @ R_x(roll) (right-handed, angles in degrees).

    Applied to the points (``positions @ R.T``), a positive pitch lowers the ground ahead
    (+x) by x sin(pitch), as a sensor pitched nose-up sees it; a positive roll raises the ground
    on the left (+y) by y sin(roll)."""
    import numpy as np

    r, p = np.radians(roll_deg), np.radians(pitch_deg)
    roll = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(r), -np.sin(r)], [0.0, np.sin(r), np.cos(r)]])
    pitch = np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])
    return pitch @ roll


def tilt_frame(frame, roll_deg: float, pitch_deg: float):
    """A copy of a labelled frame with its points rotated about the sensor origin (0, 0, 0);
    labels, scored and obstacle masks and the sensor height are unchanged."""
    import dataclasses

    import numpy as np

    rotation = tilt_rotation(roll_deg, pitch_deg)
    positions = np.ascontiguousarray(frame.positions @ rotation.T)
    return dataclasses.replace(frame, positions=positions)


#: the ``kitti-lines`` data set: the SemanticKITTI frames (64 scan lines, about 0.4° apart)
#: keeping every k-th scan line, what a sparser lidar resolves vertically: 32 lines (~0.8°,
#: a 32-line sensor) and 16 lines (~1.6°, close to a 16-line sensor's 2°); "64" is the frame
#: as recorded
KITTI_LINES = {"64": 1, "32": 2, "16": 4}


def scan_lines(positions):
    """Scan-line index (0, 1, ...) of each point of a spinning-lidar frame stored line by line,
    as the SemanticKITTI ``.bin`` files are: each line sweeps the azimuth from about 0° to
    360° and the next one starts again near 0°, so a new line begins where the azimuth in
    [0°, 360°) drops by more than 180° from one point to the next."""
    import numpy as np

    p = np.asarray(positions, dtype=np.float64)
    if len(p) == 0:
        return np.zeros(0, np.int64)
    azimuth = np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360.0
    return np.concatenate([[0], np.cumsum(np.diff(azimuth) < -180.0)]).astype(np.int64)


def line_frame(frame, every: int):
    """A copy of a labelled frame with only every ``every``-th scan line (:func:`scan_lines`,
    lines 0, every, 2 every, ...); every mask is subset alike."""
    import dataclasses

    import numpy as np

    keep = scan_lines(frame.positions) % int(every) == 0
    return dataclasses.replace(
        frame, positions=np.ascontiguousarray(frame.positions[keep]),
        is_ground=frame.is_ground[keep], scored=frame.scored[keep],
        obstacle=None if frame.obstacle is None else frame.obstacle[keep])


#: the ``kitti-fov`` data set: the SemanticKITTI frames cropped to a forward field of view,
#: the points within this many degrees of the +x axis (x forward) in azimuth: a half-scan
#: (180°), a camera's (90°, as the frames are often cropped to the front camera's view) and a
#: forward-looking solid-state lidar's (60°); "360" is the frame as recorded
KITTI_FOVS = {"360": 180.0, "180": 90.0, "90": 45.0, "60": 30.0}


def fov_frame(frame, half_angle_deg: float):
    """A copy of a labelled frame with only the points whose azimuth about the sensor origin
    lies within ``half_angle_deg`` of the +x axis (all of them at 180); every mask is subset
    alike."""
    import dataclasses

    import numpy as np

    p = frame.positions
    keep = np.abs(np.degrees(np.arctan2(p[:, 1], p[:, 0]))) <= float(half_angle_deg)
    return dataclasses.replace(
        frame, positions=np.ascontiguousarray(p[keep]), is_ground=frame.is_ground[keep],
        scored=frame.scored[keep],
        obstacle=None if frame.obstacle is None else frame.obstacle[keep])


#: the ``kitti-low`` data set: the SemanticKITTI frames with this share of their points moved
#: 0.5-3 m straight down (returns from below the ground: multipath off a wet road, glass);
#: "0" is the frame as recorded
KITTI_LOW = {"0": 0.0, "0.5": 0.005, "1": 0.01, "2": 0.02}


def low_frame(frame, share: float, seed: int = 0):
    """A copy of a labelled frame with ``share`` of its points (drawn with ``seed``) moved
    0.5-3 m down (uniform); the moved points are not scored (labels of the others kept)."""
    import dataclasses

    import numpy as np

    rng = np.random.default_rng(seed)
    p = frame.positions.copy()
    moved = rng.random(len(p)) < float(share)
    p[moved, 2] -= rng.uniform(0.5, 3.0, int(moved.sum()))
    return dataclasses.replace(frame, positions=p, scored=frame.scored & ~moved)


#: the ``kitti-noise`` data set: the SemanticKITTI frames with N(0, sigma) added to every
#: point's z, sigma in metres by the variant's name in centimetres: what a noisier sensor (a
#: low-cost lidar, photogrammetry) or rough ground scatters; "0" is the frame as recorded
KITTI_NOISE = {"0": 0.0, "3": 0.03, "5": 0.05, "8": 0.08}


def noise_frame(frame, sigma: float, seed: int = 0):
    """A copy of a labelled frame with N(0, ``sigma``) added to every point's z (drawn with
    ``seed``); labels and masks unchanged."""
    import dataclasses

    import numpy as np

    p = frame.positions.copy()
    p[:, 2] += np.random.default_rng(seed).normal(0.0, float(sigma), len(p))
    return dataclasses.replace(frame, positions=p)


#: the data-set families of SemanticKITTI variants: family -> (its variants, what a variant
#: is called in an error, make(frame, variants[variant])); each variant is a task of its own
KITTI_FAMILIES = {
    "kitti-tilt": (KITTI_TILTS, "tilt", lambda frame, tilt: tilt_frame(frame, *tilt)),
    "kitti-lines": (KITTI_LINES, "line count", line_frame),
    "kitti-fov": (KITTI_FOVS, "field of view", fov_frame),
    "kitti-low": (KITTI_LOW, "share of low returns", low_frame),
    "kitti-noise": (KITTI_NOISE, "noise", noise_frame),
}


def _standard_frame(spec: str, seed: int):
    """Synthetic frames at the standard sizes (offroad scene)."""
    import numpy as np
    from o3d_terrain import synthetic
    from o3d_terrain.evaluation.datasets import LabelledFrame, _sensor_height

    scene = synthetic.make_scene("offroad", seed=seed)
    if spec == "lidar120k":  # a 64-beam 360° frame
        cloud = synthetic.sample_lidar(scene, beams=64, azimuth_steps=3200, seed=seed)
        kind = "vehicle_lidar"
    elif spec == "stereo300k":
        cloud = synthetic.sample_stereo(scene, width=800, height=600, seed=seed)
        kind = "stereo"
    else:  # the paper's 640x480 stereo camera
        cloud = synthetic.sample_stereo(scene, width=640, height=480, seed=seed)
        kind = "stereo"
    positions = np.asarray(cloud.positions, dtype=np.float64)
    obstacle = np.asarray(cloud.is_obstacle, dtype=bool)
    return LabelledFrame(name=spec, positions=positions, is_ground=~obstacle,
                         scored=~np.asarray(cloud.is_outlier, dtype=bool), obstacle=obstacle,
                         terrain=cloud.terrain_height, kind=kind, source="synthetic offroad",
                         sensor_height=_sensor_height(cloud))


def _ours_options(spec: str) -> dict:
    if spec == "paper34x22":  # Broggi et al. 2013: 34 m x 22 m ahead, 25 x 25, degree 3
        return {"region": (0.0, 34.0, -11.0, 11.0), "control_points": (25, 25), "degree": 3}
    return {}


def _rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _method(name: str, frame, spec: str):
    from o3d_terrain.evaluation.segmentation import ours, resolve_method

    if name == OURS:
        return ours(**_ours_options(spec))
    if name == OURS_STREET:
        return ours(**_ours_options(spec), **STREET_OPTIONS)
    return resolve_method(name, kind=frame.kind, sensor_height=frame.sensor_height)


def work_segment(task: dict) -> dict:
    """Accuracy, median time and memory of one method over one data set."""
    import statistics
    import tracemalloc

    import numpy as np
    from o3d_terrain.evaluation.metrics import segmentation_counts
    from o3d_terrain.evaluation.segmentation import run_method

    frames, failures = load_frames(task["dataset"], task.get("seed", 0))
    rss_loaded = _rss_mb()
    out = {"frames": [], "failures": [vars(f) for f in failures], "rss_after_load_mb": rss_loaded}
    for frame in frames:
        try:
            run = _method(task["method"], frame, task["dataset"])
            mask = run_method(run, frame)  # warm-up (numba compilation, caches)
            times = []
            for _ in range(task.get("repeats", 3)):
                start = time.perf_counter()
                mask = run_method(run, frame)
                times.append(time.perf_counter() - start)
            record = {"name": frame.name, "points": len(frame), "seconds": statistics.median(times),
                      "all_seconds": times}
            if task.get("memory"):
                tracemalloc.start()
                run_method(run, frame)
                record["tracemalloc_peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
                tracemalloc.stop()
            counts = segmentation_counts(np.asarray(mask, dtype=bool), frame.is_ground,
                                         scored=frame.scored, obstacle=frame.obstacle)
            record.update(counts.to_dict())
            record["notes"] = list(frame.notes)
            out["frames"].append(record)
        except Exception as exc:  # report the frame, keep going
            out["failures"].append({"name": frame.name, "reason": f"{type(exc).__name__}: {exc}"})
    out["rss_peak_mb"] = _rss_mb()
    return out


def work_stages(task: dict) -> dict:
    """Median time of each stage of ours on one standard frame."""
    import statistics

    import numpy as np
    from o3d_terrain.grid import quantize_points, region_of
    from o3d_terrain.segment import segment_points
    from o3d_terrain.terrain import fit_grid_detailed

    frame = load_frames(task["dataset"], task.get("seed", 0))[0][0]
    options = _ours_options(task["dataset"])
    positions = frame.positions
    cell = 0.5
    region = options.get("region") or region_of(positions)
    control = options.get("control_points")
    stages = {}

    def timed(name, fn):
        fn()  # warm-up
        times = []
        for _ in range(task.get("repeats", 3)):
            start = time.perf_counter()
            value = fn()
            times.append(time.perf_counter() - start)
        stages[name] = statistics.median(times)
        return value

    grid = timed("grid quantization", lambda: quantize_points(positions, cell_size=cell,
                                                              region=region))
    fit = timed("B-spline fit", lambda: fit_grid_detailed(grid, control_points=control, degree=3))
    surface = fit.surface
    timed("segmentation", lambda: segment_points(surface, positions))
    xs = np.arange(region[0] + cell / 2, region[1], cell)
    ys = np.arange(region[2] + cell / 2, region[3], cell)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    timed("slope map (grid)", lambda: surface.slope_deg(gx, gy))
    return {"points": len(positions), "grid": list(grid.shape),
            "control_points": list(surface.shape), "stages": stages,
            "rss_peak_mb": _rss_mb()}


def work_terrain(task: dict) -> dict:
    """Terrain height/slope accuracy of ours on synthetic scenes and the DEM."""
    from o3d_terrain.evaluation.datasets import synthetic_scene_names
    from o3d_terrain.evaluation.terrain import (evaluate_dem_terrain, evaluate_synthetic_terrain,
                                                write_error_map)

    out = {}
    names = [n for n in synthetic_scene_names() if n != "crossing"]
    report = evaluate_synthetic_terrain(names, sensor="lidar", seed=0)
    out["synthetic"] = report.to_dict()
    root = _data_root()
    dem = root / "dem_1m" / "dem.tif" if root else None
    if dem is not None and dem.exists():
        runs = {}
        for label, obstacles in (("bare", 0), ("obstacles", 10)):
            r = evaluate_dem_terrain(dem, window=40.0, max_windows=task.get("dem_windows", 16),
                                     density=4.0, noise=0.02, obstacles=obstacles, seed=0)
            runs[label] = r.to_dict()
            if label == "obstacles" and task.get("figures"):
                FIGURES.mkdir(parents=True, exist_ok=True)
                write_error_map(FIGURES / "benchmarks_dem_error_map.png",
                                r.maps["height_error"], r.maps["slope_error"],
                                height_limit=0.5, slope_limit=10.0, grid_is_xy=False)
        out["dem"] = runs
    else:
        out["dem_missing"] = "no ../shared/data/dem_1m/dem.tif"
    return out


WORKERS = {"segment": work_segment, "stages": work_stages, "terrain": work_terrain}


def worker_main(task_json: str) -> int:
    task = json.loads(task_json)
    try:
        try:
            from threadpoolctl import threadpool_limits as limits
            # applied when made; they hold until the worker exits
            _limits = limits(limits=int(os.environ.get("OMP_NUM_THREADS", "1")))
        except ImportError:
            pass
        result = WORKERS[task["task"]](task)
        print("@@RESULT@@" + json.dumps(result, default=float))
    except Exception as exc:
        print("@@RESULT@@" + json.dumps({"error": f"{type(exc).__name__}: {exc}"}))
    return 0


# =============================================================================================
# driver side


def run_task(task: dict, *, threads: int, timeout: float) -> dict:
    """Run one measurement in a fresh interpreter with pinned threads; never raises."""
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
        env[var] = str(threads)
    env.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".venv" / "numba_cache"))
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(task),
               "--threads", str(threads)]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout: no result within {timeout:.0f} s"}
    for line in done.stdout.splitlines()[::-1]:
        if line.startswith("@@RESULT@@"):
            result = json.loads(line[len("@@RESULT@@"):])
            result["wall_seconds"] = time.perf_counter() - start
            return result
    tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
    return {"error": f"worker exited {done.returncode}: {' | '.join(tail)}"}


def machine() -> dict:
    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory = ""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                memory = f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    versions = {}
    from importlib import metadata

    for package in ("o3d_terrain", "numpy", "scipy", "numba", "open3d", "pypatchworkpp",
                    "cloth-simulation-filter", "pysmrf"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return {"cpu": cpu, "cores": os.cpu_count(), "memory": memory,
            "system": f"{platform.system()} {platform.release()}",
            "python": platform.python_version(), "versions": versions}


def collect(args) -> dict:
    """Run every measurement; returns the results tree written to docs."""
    results = {"machine": machine(), "date": _dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
               "threads": args.threads, "repeats": args.repeats,
               "command": "python benchmarks/run_all.py --write-docs"
                          + (f" --threads {args.threads}" if args.threads != 1 else "")
                          + (f" --repeats {args.repeats}" if args.repeats != 5 else "")
                          + (f" --timeout {args.timeout:g}" if args.timeout != 240 else ""),
               "segment": {}, "stages": {}, "terrain": None}
    methods = [OURS, *PEER_NAMES]
    plan = [("kitti", True), ("kitti-tilt", False), ("kitti-lines", False),
            ("kitti-fov", False), ("kitti-low", False), ("kitti-noise", False),
            ("las", False), ("synthetic", False), ("synthetic-solid", False),
            ("dem-sites", False), ("forest", False), ("pit", False), ("overhead", False),
            ("lidar120k", True),
            ("stereo300k", True),
            ("paper34x22", False), ("las700k", True)]
    if args.only:
        plan = [p for p in plan if p[0] in args.only]
    expanded = []
    for dataset, memory in plan:
        if dataset == "las":  # one task per tile: a slow peer on one tile cannot hide the others
            root = _data_root_for_driver()
            tiles = sorted(p.name for p in (root / "las").iterdir()
                           if p.suffix.lower() in (".las", ".laz")) if root else []
            expanded += [(f"las:{t}", memory) for t in tiles] or [("las", memory)]
        elif dataset in KITTI_FAMILIES:  # one task per variant of the same frames
            expanded += [(f"{dataset}:{v}", memory) for v in KITTI_FAMILIES[dataset][0]]
        elif dataset == "dem-sites":  # one task per sensor over the same sites
            expanded += [(f"dem-sites:{s}", memory) for s in DEM_SENSORS]
        elif dataset == "forest":  # one task per density over the same sites
            expanded += [(f"forest:{d}", memory) for d in FOREST_DENSITIES]
        else:
            expanded.append((dataset, memory))
    for dataset, memory in expanded:
        street = [OURS_STREET] if dataset.startswith("kitti-fov:") else []
        for method in [*methods, *street]:
            variant = dataset.startswith(("las", "dem-sites", "forest", "pit", "overhead",
                                          *KITTI_FAMILIES))
            repeats = max(1, args.repeats // 2) if variant else args.repeats
            if dataset == "paper34x22" and method != OURS:
                continue  # the region-limited configuration is ours only
            task = {"task": "segment", "dataset": dataset, "method": method,
                    "repeats": repeats, "memory": memory}
            _log(f"segment {method} on {dataset} ...")
            result = run_task(task, threads=args.threads, timeout=args.timeout)
            results["segment"][f"{dataset}/{method}"] = result
            _log(_short(result))
    for dataset in ("lidar120k", "stereo300k", "paper34x22", "las700k", "kitti1"):
        if args.only and dataset not in args.only:
            continue
        _log(f"stages on {dataset} ...")
        results["stages"][dataset] = run_task(
            {"task": "stages", "dataset": dataset, "repeats": args.repeats},
            threads=args.threads, timeout=args.timeout)
        _log(_short(results["stages"][dataset]))
    if not args.only or "terrain" in args.only:
        _log("terrain accuracy ...")
        results["terrain"] = run_task({"task": "terrain", "figures": args.write_docs,
                                       "dem_windows": 16},
                                      threads=args.threads, timeout=max(args.timeout, 600))
        _log(_short(results["terrain"]))
    return results


def _data_root_for_driver() -> Path | None:
    env = os.environ.get("O3D_TERRAIN_DATA")
    if env:
        return Path(env) if Path(env).is_dir() else None
    candidate = ROOT.parent / "shared" / "data"
    return candidate if candidate.is_dir() else None


def _short(result: dict) -> str:
    if "error" in result:
        return "  n/a: " + result["error"]
    return f"  done in {result.get('wall_seconds', 0):.1f} s"


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-docs", action="store_true", help=f"write {DOCS.relative_to(ROOT)}")
    parser.add_argument("--threads", type=int, default=1, help="threads for every method (1)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per frame (median)")
    parser.add_argument("--timeout", type=float, default=240.0, help="seconds per measurement")
    parser.add_argument("--quick", action="store_true", help="2 repeats")
    parser.add_argument("--only", nargs="*", help="only these data sets (kitti, kitti-tilt, "
                        "kitti-lines, kitti-fov, kitti-low, kitti-noise, las, synthetic, "
                        "synthetic-solid, dem-sites, forest, pit, overhead, lidar120k, stereo300k, "
                        "paper34x22, las700k, kitti1, terrain)")
    parser.add_argument("--json", metavar="PATH", help="also write the raw results as JSON")
    parser.add_argument("--from-json", metavar="PATH", help="render docs from saved results")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    _pin_threads(args.threads)
    if args.worker:
        return worker_main(args.worker)
    if args.quick:
        args.repeats = 2
    if args.from_json:
        results = json.loads(Path(args.from_json).read_text())
    else:
        results = collect(args)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    text = render(results, figures=FIGURES if args.write_docs else None)
    if args.write_docs:
        DOCS.write_text(text)
        _log(f"wrote {DOCS}")
    else:
        print(text)
    return 0




# =============================================================================================
# rendering docs/benchmarks.md


METHOD_LABELS = {OURS: "**o3d_terrain** (`segment_terrain`)",
                 OURS_STREET: "o3d_terrain, `max_slope_deg=30`", "patchworkpp": "Patchwork++",
                 "csf": "CSF", "smrf": "SMRF", "ransac_plane": "Open3D RANSAC plane"}


def _pct(value) -> str:
    return "n/a" if value is None or value != value else f"{100 * value:.1f}"


def _ms(seconds) -> str:
    if seconds is None or seconds != seconds:
        return "n/a"
    return f"{1000 * seconds:,.0f}" if seconds >= 0.1 else f"{1000 * seconds:.1f}"


def _entries(results, dataset, method) -> list[tuple[str, dict]]:
    """Result entries of a data set; 'las' gathers the per-tile entries 'las:TILE'."""
    if dataset == "las":
        return [(k.split("/")[0][4:], e) for k, e in sorted(results["segment"].items())
                if k.startswith("las:") and k.endswith("/" + method)]
    entry = results["segment"].get(f"{dataset}/{method}")
    return [(dataset, entry)] if entry is not None else []


def _merged(results, dataset, method) -> dict | None:
    entries = _entries(results, dataset, method)
    if not entries:
        return None
    if dataset != "las":
        return entries[0][1]
    merged = {"frames": [], "failures": []}
    for tile, entry in entries:
        if "error" in entry:
            merged["failures"].append({"name": tile, "reason": entry["error"]})
        else:
            merged["frames"] += entry["frames"]
            merged["failures"] += entry.get("failures", [])
    return merged


def _frames(results, dataset, method) -> tuple[list, str | None]:
    entry = _merged(results, dataset, method)
    if entry is None:
        return [], "not run"
    if "error" in entry:
        return [], entry["error"]
    return entry["frames"], None


def _median(values):
    values = sorted(v for v in values if v is not None)
    if not values:
        return None
    mid = len(values) // 2
    return values[mid] if len(values) % 2 else (values[mid - 1] + values[mid]) / 2


def _mean(values):
    values = [v for v in values if v is not None and v == v]
    return sum(values) / len(values) if values else None


def _methods(results, dataset):
    return [m for m in (OURS, *PEER_NAMES) if _entries(results, dataset, m)]


def _summary_table(results, dataset, title) -> list[str]:
    if not _methods(results, dataset):
        return []
    lines = [f"### {title}", "",
             "| method | precision | recall | F1 | obstacle recall | median time (ms) | "
             "time / ours |", "|---|---:|---:|---:|---:|---:|---:|"]
    ours_frames, _ = _frames(results, dataset, OURS)
    ours_time = _median([f["seconds"] for f in ours_frames])
    notes = []
    for method in _methods(results, dataset):
        frames, error = _frames(results, dataset, method)
        if error:
            lines.append(f"| {METHOD_LABELS[method]} | n/a | n/a | n/a | n/a | n/a | n/a |")
            notes.append(f"- {METHOD_LABELS[method]}: n/a ({error})")
            continue
        t = _median([f["seconds"] for f in frames])
        ratio = f"{t / ours_time:.2f}" if ours_time and t else "n/a"
        lines.append(
            f"| {METHOD_LABELS[method]} | {_pct(_mean([f['precision'] for f in frames]))} | "
            f"{_pct(_mean([f['recall'] for f in frames]))} | {_pct(_mean([f['f1'] for f in frames]))} | "
            f"{_pct(_mean([f['obstacle_recall'] for f in frames]))} | {_ms(t)} | {ratio} |")
        entry = _merged(results, dataset, method)
        for failure in entry.get("failures", []):
            notes.append(f"- {METHOD_LABELS[method]} skipped `{failure['name']}`: {failure['reason']}")
    return lines + [""] + notes + ([""] if notes else [])


def _per_frame_table(results, dataset, title, key="f1", label="F1 (%)") -> list[str]:
    methods = _methods(results, dataset)
    if not methods:
        return []
    names: list[str] = []
    points: dict[str, int] = {}
    cells: dict[tuple[str, str], str] = {}
    times: dict[tuple[str, str], str] = {}
    for method in methods:
        frames, error = _frames(results, dataset, method)
        for f in frames:
            if f["name"] not in names:
                names.append(f["name"])
            points[f["name"]] = f["points"]
            cells[(f["name"], method)] = _pct(f[key])
            times[(f["name"], method)] = _ms(f["seconds"])
        if not error:
            for failure in _merged(results, dataset, method).get("failures", []):
                if failure["name"] not in names:
                    names.append(failure["name"])
                cells[(failure["name"], method)] = "failed"
                times[(failure["name"], method)] = "failed"
    # frames where the score is undefined for every method (obstacle recall on a scene
    # without obstacles) are left out of the table
    undefined = [n for n in names if all(cells.get((n, m), "n/a") == "n/a" for m in methods)]
    names = [n for n in names if n not in undefined]
    if not names:
        return [f"### {title}", "", "n/a: no frame was evaluated (see the notes).", ""]
    head = "| frame | points | " + " | ".join(METHOD_LABELS[m] for m in methods) + " |"
    rule = "|---|---:|" + "---:|" * len(methods)
    lines = [f"### {title}", "", f"{label}, then median time (ms) after the slash.", "", head, rule]
    for name in names:
        row = [f"{cells.get((name, m), 'n/a')} / {times.get((name, m), 'n/a')}" for m in methods]
        lines.append(f"| {name} | {points.get(name, 0):,} | " + " | ".join(row) + " |")
    if undefined:
        lines += ["", f"Left out (the score is undefined there for every method, e.g. obstacle "
                      f"recall without obstacle points): {', '.join(undefined)}."]
    return lines + [""]


def _tilt_label(tilt: str) -> str:
    roll, pitch = KITTI_TILTS[tilt]
    parts = ([f"pitch {pitch:g}°"] if pitch else []) + ([f"roll {roll:g}°"] if roll else [])
    return ", ".join(parts) or "level"


def _lines_label(lines: str) -> str:
    return f"{lines} lines" + (" (as recorded)" if KITTI_LINES[lines] == 1 else "")


def _fov_label(fov: str) -> str:
    return f"{fov}°" + (" (as recorded)" if fov == "360" else "")


def _low_label(share: str) -> str:
    return f"{share} %" + (" (as recorded)" if share == "0" else "")


def _noise_label(sigma_cm: str) -> str:
    return "as recorded" if sigma_cm == "0" else f"σ {sigma_cm} cm"


def _variant_f1(results, prefix, variants, method) -> dict[str, tuple[float | None, str | None,
                                                                       int]]:
    """Mean F1 over the frames, the error (or None) and the frame count of each variant of a
    data-set family (``prefix``:variant, e.g. kitti-tilt:pitch5)."""
    out = {}
    for variant in variants:
        frames, error = _frames(results, f"{prefix}:{variant}", method)
        out[variant] = (_mean([f["f1"] for f in frames]), error, len(frames))
    return out


def _variant_methods(results, prefix, variants) -> list[str]:
    return [m for m in (OURS, OURS_STREET, *PEER_NAMES)
            if any(f"{prefix}:{v}/{m}" in results["segment"] for v in variants)]


def _variant_table(results, prefix, variants, label, title, text) -> list[str]:
    """A method x variant table of mean ground F1 (%) for a data-set family; [] when none of
    its variants ran."""
    methods = _variant_methods(results, prefix, variants)
    if not methods:
        return []
    lines = [f"### {title}", "", text, "",
             "| method | " + " | ".join(label(v) for v in variants) + " |",
             "|---|" + "---:|" * len(variants)]
    notes = []
    for method in methods:
        cells = []
        for variant, (f1, error, count) in _variant_f1(results, prefix, variants,
                                                        method).items():
            if error:
                cells.append("n/a")
                notes.append(f"- {METHOD_LABELS[method]}, {label(variant)}: n/a ({error})")
                continue
            failures = _merged(results, f"{prefix}:{variant}", method).get("failures", [])
            cells.append(_pct(f1) + (f" ({count} of {count + len(failures)} frames)"
                                     if failures else ""))
            for failure in failures:
                notes.append(f"- {METHOD_LABELS[method]}, {label(variant)}: skipped "
                             f"`{failure['name']}`: {failure['reason']}")
        lines.append(f"| {METHOD_LABELS[method]} | " + " | ".join(cells) + " |")
    return lines + [""] + notes + ([""] if notes else [])


def _tilt_table(results) -> list[str]:
    return _variant_table(
        results, "kitti-tilt", KITTI_TILTS, _tilt_label,
        "SemanticKITTI frames with a tilted sensor",
        "The same three frames with every point rotated about the sensor origin (0, 0, 0) "
        "by a fixed angle: pitch about the y axis (the ground ahead appears lower by "
        "x sin θ, as seen by a sensor pitched nose-up), roll about the x axis (the ground on "
        "the left appears higher by y sin θ); labels unchanged. Every method runs with the "
        "defaults of the level case (the peer settings below), none is told about the "
        "tilt. Ground F1 (%), mean over the 3 frames. Open3D's seeded RANSAC does not "
        "repeat exactly from run to run (on frame 000000 it settles on one of two "
        "planes), so its differences of about half a point between columns are not the "
        "tilt.")


def _lines_table(results) -> list[str]:
    return _variant_table(
        results, "kitti-lines", KITTI_LINES, _lines_label,
        "SemanticKITTI frames seen by a sparser lidar",
        "The same three frames keeping every 2nd or 4th of the 64 scan lines (a new line "
        "starts where the azimuth wraps around; `benchmarks/run_all.py`: `scan_lines`, "
        "`line_frame`): 32 lines about 0.8° apart, as a 32-line sensor, and 16 lines about "
        "1.6° apart, close to a 16-line sensor's 2°, with the labels of the points kept. "
        "Every method runs with its defaults; Patchwork++ keeps the 64-line sensor's "
        "settings (the peer settings below). Ground F1 (%), mean over the 3 frames.")


def _fov_table(results) -> list[str]:
    return _variant_table(
        results, "kitti-fov", KITTI_FOVS, _fov_label,
        "SemanticKITTI frames cropped to a forward field of view",
        "The same three frames keeping only the points within half the angle of the +x axis "
        "(forward) in azimuth (`benchmarks/run_all.py`: `fov_frame`): the front half, a "
        "camera's 90° (frames are often cropped to the front camera's view) and a "
        "forward-looking solid-state lidar's 60°, with the labels of the points kept. Every "
        "method runs with its defaults on the cropped cloud; the row `max_slope_deg=30` is "
        "ours with the option the README gives for a street crop when the whole scan is not "
        "at hand (the terrain prior's slope limit 30° instead of 45°; docs/algorithm.md, \"A "
        "30° slope limit for a street crop\", has why it is not the default: off-road relief). "
        "Ground F1 (%), mean over the 3 frames; a crop scores lower than the whole frame for "
        "every method partly because the street ahead holds more of the frame's parked cars "
        "and walls.")


def _low_table(results) -> list[str]:
    return _variant_table(
        results, "kitti-low", KITTI_LOW, _low_label,
        "SemanticKITTI frames with returns from below the ground",
        "The same three frames with a share of their points (drawn with seed 0) moved 0.5-3 m "
        "straight down, as multipath off a wet road or a reflection in glass puts returns "
        "under the ground (`benchmarks/run_all.py`: `low_frame`); the moved points are not "
        "scored, the others keep their labels. Every method runs with its defaults. Ground "
        "F1 (%), mean over the 3 frames. Ours leaves isolated low returns out of the fit "
        "(docs/algorithm.md, \"Returns from below the ground\", with a second draw and "
        "higher shares).")


def _noise_table(results) -> list[str]:
    return _variant_table(
        results, "kitti-noise", KITTI_NOISE, _noise_label,
        "SemanticKITTI frames with a noisier sensor",
        "The same three frames with Gaussian noise of σ added to every point's z (drawn with "
        "seed 0; `benchmarks/run_all.py`: `noise_frame`), as a low-cost lidar, photogrammetry "
        "or rough ground scatters the returns; labels unchanged. Every method runs with its "
        "defaults. Ground F1 (%), mean over the 3 frames (docs/algorithm.md, \"The threshold "
        "on a noisy ground\").")


def _figure_tilt(results, figures) -> str | None:
    """Ground F1 against the tilt angle, pitch and roll side by side, drawn with OpenCV."""
    import cv2
    import numpy as np

    methods = _variant_methods(results, "kitti-tilt", KITTI_TILTS)
    series = {m: _variant_f1(results, "kitti-tilt", KITTI_TILTS, m) for m in methods}
    values = [v[0] for s in series.values() for v in s.values() if v[0] is not None]
    if figures is None or len(values) < 2:
        return None
    colours = {OURS: (0, 0, 200), "patchworkpp": (160, 90, 0), "csf": (0, 140, 0),
               "smrf": (140, 0, 140), "ransac_plane": (0, 140, 200)}
    w, h, top, bottom, left = 760, 420, 60, 60, 55
    panel_w = (w - left - 170) // 2 - 15
    image = np.full((h, w, 3), 255, np.uint8)
    # the scale covers the scores above 50 %; a collapse below is drawn at the bottom edge
    # with its value, so that it does not flatten the differences between the others
    on_scale = [v for v in values if v >= 0.5] or values
    f_lo = max(0.0, np.floor(20 * min(on_scale)) / 20)
    f_hi = min(1.0, np.ceil(20 * max(on_scale)) / 20)
    f_hi = f_hi if f_hi > f_lo else f_lo + 0.05
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(image, "SemanticKITTI seq. 00, tilted sensor: ground F1 (%) vs angle", (left, 30),
                font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    for k, axis in enumerate(("pitch", "roll")):
        angles = sorted({0.0} | {(p if axis == "pitch" else r) for r, p in KITTI_TILTS.values()})
        x0, a_hi = left + k * (panel_w + 30), max(angles)

        def xy(angle, f, x0=x0, a_hi=a_hi):
            return (int(x0 + angle / a_hi * panel_w),
                    int(h - bottom - (f - f_lo) / (f_hi - f_lo) * (h - top - bottom)))
        cv2.rectangle(image, (x0, top), (x0 + panel_w, h - bottom), (0, 0, 0), 1)
        for a in angles:
            x, _ = xy(a, f_lo)
            cv2.line(image, (x, h - bottom), (x, h - bottom + 5), (0, 0, 0), 1)
            cv2.putText(image, f"{a:g}", (x - 6, h - bottom + 20), font, 0.4, (0, 0, 0), 1,
                        cv2.LINE_AA)
        cv2.putText(image, f"{axis} (deg)", (x0 + panel_w // 2 - 30, h - 15), font, 0.45,
                    (0, 0, 0), 1, cv2.LINE_AA)
        for i in range(5):
            f = f_lo + i * (f_hi - f_lo) / 4
            _, y = xy(0.0, f)
            cv2.line(image, (x0, y), (x0 + panel_w, y), (225, 225, 225), 1)
            if k == 0:
                cv2.putText(image, f"{100 * f:.0f}", (left - 30, y + 4), font, 0.4, (0, 0, 0), 1,
                            cv2.LINE_AA)
        for method in methods:
            pts = []
            colour = colours.get(method, (80, 80, 80))
            for tilt, (f1, _, _) in series[method].items():
                roll, pitch = KITTI_TILTS[tilt]
                if f1 is None or (roll if axis == "pitch" else pitch):
                    continue
                pts.append(xy(pitch if axis == "pitch" else roll, max(f1, f_lo)))
                if f1 < f_lo:
                    cv2.putText(image, f"{100 * f1:.1f}", (pts[-1][0] - 34, pts[-1][1] - 6),
                                font, 0.4, colour, 1, cv2.LINE_AA)
            pts.sort()
            for a, b in itertools.pairwise(pts):
                cv2.line(image, a, b, colour, 2, cv2.LINE_AA)
            for p in pts:
                cv2.circle(image, p, 4, colour, -1, cv2.LINE_AA)
    for i, method in enumerate(methods):
        y = top + 15 + 22 * i
        x = w - 160
        colour = colours.get(method, (80, 80, 80))
        cv2.line(image, (x, y - 4), (x + 20, y - 4), colour, 2, cv2.LINE_AA)
        cv2.putText(image, method, (x + 26, y), font, 0.45, colour, 1, cv2.LINE_AA)
    figures.mkdir(parents=True, exist_ok=True)
    path = figures / "benchmarks_kitti_tilt_f1.png"
    cv2.imwrite(str(path), image)
    return "figures/" + path.name


def _speed_table(results) -> list[str]:
    sizes = [("kitti", "SemanticKITTI frames (HDL-64E, ~124.6k points)"),
             ("lidar120k", "synthetic 64-beam lidar frame"),
             ("stereo300k", "synthetic stereo cloud"),
             ("las700k", "LAS tile `las_with_several_extra_byte_bloc.laz`")]
    methods = (OURS, *PEER_NAMES)
    lines = ["| frame | points | " + " | ".join(METHOD_LABELS[m] for m in methods) + " |",
             "|---|---:|" + "---:|" * len(methods)]
    for dataset, label in sizes:
        row, n = [], 0
        ours_t = _median([f["seconds"] for f in _frames(results, dataset, OURS)[0]])
        for method in methods:
            frames, error = _frames(results, dataset, method)
            t = _median([f["seconds"] for f in frames])
            n = max(n, max((f["points"] for f in frames), default=0))
            if error or t is None:
                row.append("n/a")
            elif method == OURS or not ours_t:
                row.append(_ms(t))
            else:
                row.append(f"{_ms(t)} ({t / ours_t:.2f}×)")
        lines.append(f"| {label} | {n:,} | " + " | ".join(row) + " |")
    return lines + ["", "Median ms per frame; in brackets the peer's time divided by ours "
                    "(above 1: we are faster).", ""]


def _memory_table(results) -> list[str]:
    lines = ["| frame | method | peak RSS of the process (MiB) | RSS after loading the data "
             "(MiB) | tracemalloc peak of one run (MiB) |", "|---|---|---:|---:|---:|"]
    for dataset in ("las700k", "stereo300k", "kitti"):
        for method in (OURS, *PEER_NAMES):
            entry = results["segment"].get(f"{dataset}/{method}")
            if not entry or "error" in entry or not entry.get("frames"):
                continue
            peak = max((f.get("tracemalloc_peak_mb") or 0) for f in entry["frames"])
            lines.append(f"| {dataset} | {METHOD_LABELS[method]} | {entry['rss_peak_mb']:.0f} | "
                         f"{entry['rss_after_load_mb']:.0f} | {peak:.0f} |")
    return lines + ["", "Peak RSS is the whole interpreter (Python, NumPy, Open3D, the loaded "
                    "data, numba's compiled kernels) from `ru_maxrss`; the tracemalloc peak counts "
                    "the Python and NumPy allocations of one call only (not C++ peers' own "
                    "heaps).", ""]


def _stages_table(results) -> list[str]:
    order = ["grid quantization", "B-spline fit", "segmentation", "slope map (grid)"]
    labels = {"lidar120k": "synthetic lidar frame", "stereo300k": "synthetic stereo cloud",
              "paper34x22": "paper: 640×480 stereo, 34 × 22 m, 25 × 25 control points",
              "las700k": "LAS tile, 698k points", "kitti1": "SemanticKITTI frame 000000"}
    lines = ["| frame | points | grid cells | control points | " + " | ".join(order)
             + " | total |", "|---|---:|---:|---:|" + "---:|" * (len(order) + 1)]
    notes = []
    for dataset, label in labels.items():
        entry = results["stages"].get(dataset)
        if entry is None:
            continue
        if "error" in entry:
            lines.append(f"| {label} | n/a |" + " n/a |" * (len(order) + 3))
            notes.append(f"- {label}: n/a ({entry['error']})")
            continue
        st = entry["stages"]
        total = sum(st.get(k, 0) for k in order)
        lines.append(f"| {label} | {entry['points']:,} | {entry['grid'][0]}×{entry['grid'][1]} | "
                     f"{entry['control_points'][0]}×{entry['control_points'][1]} | "
                     + " | ".join(_ms(st.get(k)) for k in order) + f" | {_ms(total)} |")
    return lines + ["", "Milliseconds, median of the timed runs; cell size 0.5 m, degree 3."
                    " The paper reports 15 ms for terrain mapping on an i7-3720QM (4 cores).",
                    ""] + notes


def _terrain_section(results) -> list[str]:
    terrain = results.get("terrain")
    if not terrain:
        return ["n/a: not run", ""]
    if "error" in terrain:
        return [f"n/a: {terrain['error']}", ""]
    lines = []
    syn = terrain.get("synthetic")
    if syn:
        lines += ["### Synthetic scenes (lidar frame, sensor frame, exact terrain)", "",
                  "| scene | points | height RMSE (m) | height p95 (m) | slope MAE (°) | "
                  "slope p95 (°) | fit (ms) |", "|---|---:|---:|---:|---:|---:|---:|"]
        for r in syn["results"]:
            s = r["slope_error_deg"]
            lines.append(f"| {r['name']} | {r['points']:,} | {_num(r['height_rmse_m'], 3)} | "
                         f"{_num(r['height_p95_abs_m'], 3)} | {_num(s['mean_abs'], 2)} | "
                         f"{_num(s['p95_abs'], 2)} | {_ms(r['seconds'])} |")
        for f in syn["failures"]:
            lines.append(f"\n- skipped `{f['name']}`: {f['reason']}")
        lines += ["", "Scored on a 0.5 m grid over the cells that hold a terrain point (no "
                  "score for extrapolating into occlusion shadows). Obstacles are in the "
                  "clouds.", ""]
    dem = terrain.get("dem")
    if dem:
        lines += ["### DEM `dem_1m/dem.tif` (400 × 400 m, 1 m cells)", "",
                  "16 windows of 40 × 40 m spread over the raster, each sampled at 4 points/m² "
                  "(bilinear heights, 2 cm noise), fitted with the defaults of `fit_terrain`, "
                  "and compared with the DEM heights at the interior cell centres and the DEM's "
                  "slope (central differences).", "",
                  "| cloud | windows | height RMSE (m) | height p95 (m) | slope MAE (°) | "
                  "slope p95 (°) | median fit (ms) |", "|---|---:|---:|---:|---:|---:|---:|"]
        for label, run in dem.items():
            o = run["overall"]
            fit = _median([r["seconds"] for r in run["results"]])
            text = "bare earth" if label == "bare" else "with 10 box obstacles per window"
            lines.append(f"| {text} | {len(run['results'])} | {_num(o.get('height_rmse_m'), 3)} | "
                         f"{_num(o.get('height_p95_abs_m'), 3)} | "
                         f"{_num(o.get('slope_mean_abs_deg'), 2)} | "
                         f"{_num(o.get('slope_p95_abs_deg'), 2)} | {_ms(fit)} |")
            for f in run["failures"]:
                lines.append(f"\n- skipped window {f['name']}: {f['reason']}")
        lines.append("")
        if (FIGURES / "benchmarks_dem_error_map.png").exists():
            lines += ["![DEM error map](figures/benchmarks_dem_error_map.png)", "",
                      "Height error (left, ±0.5 m) and slope error (right, ±10°) of the windows "
                      "with obstacles; grey: not evaluated.", ""]
    elif terrain.get("dem_missing"):
        lines += [f"DEM: n/a ({terrain['dem_missing']})", ""]
    return lines


def _num(value, digits) -> str:
    return "n/a" if value is None or value != value else f"{value:.{digits}f}"


def _targets(results) -> list[str]:
    lines = ["| target | measured | met |", "|---|---|---|"]
    ours_f, e1 = _frames(results, "kitti", OURS)
    pw_f, e2 = _frames(results, "kitti", "patchworkpp")
    if ours_f and pw_f:
        t_ours = _median([f["seconds"] for f in ours_f])
        t_pw = _median([f["seconds"] for f in pw_f])
        f_ours = _mean([f["f1"] for f in ours_f])
        f_pw = _mean([f["f1"] for f in pw_f])
        lines.append(f"| `segment_terrain` ≤ 0.5 × Patchwork++ time on a KITTI frame | "
                     f"{_ms(t_ours)} ms vs {_ms(t_pw)} ms ({t_ours / t_pw:.2f}×) | "
                     f"{'yes' if t_ours <= 0.5 * t_pw else 'no'} |")
        lines.append(f"| higher F1 than Patchwork++ on the SemanticKITTI frames | "
                     f"{_pct(f_ours)} % vs {_pct(f_pw)} % | {'yes' if f_ours > f_pw else 'no'} |")
    else:
        lines.append(f"| KITTI speed and F1 vs Patchwork++ | n/a ({e1 or e2}) | n/a |")
    entry = results["segment"].get(f"las700k/{OURS}")
    if entry and "error" not in entry and entry.get("frames"):
        lines.append(f"| peak memory < 1 GB on the 700k-point LAS tile | "
                     f"{entry['rss_peak_mb']:.0f} MiB process peak RSS | "
                     f"{'yes' if entry['rss_peak_mb'] < 1024 else 'no'} |")
    else:
        lines.append(f"| peak memory < 1 GB on the 700k-point LAS tile | n/a "
                     f"({(entry or {}).get('error', 'not run')}) | n/a |")
    return lines + [""]


def _figure_kitti(results, figures) -> str | None:
    """F1 against time on the SemanticKITTI frames (log time axis), drawn with OpenCV."""
    import math

    import cv2
    import numpy as np

    points = []
    for method in _methods(results, "kitti"):
        frames, error = _frames(results, "kitti", method)
        if frames:
            points.append((method, _median([f["seconds"] for f in frames]),
                           _mean([f["f1"] for f in frames])))
    if len(points) < 2 or figures is None:
        return None
    w, h, m = 640, 400, 60
    image = np.full((h, w, 3), 255, np.uint8)
    t_lo = math.log10(min(p[1] for p in points) / 2)
    t_hi = math.log10(max(p[1] for p in points) * 2)
    f_lo = max(0.0, min(p[2] for p in points) - 0.05)
    f_hi = min(1.0, max(p[2] for p in points) + 0.02)
    def xy(t, f):
        x = m + (math.log10(t) - t_lo) / (t_hi - t_lo) * (w - 2 * m)
        y = h - m - (f - f_lo) / (f_hi - f_lo) * (h - 2 * m)
        return int(x), int(y)
    cv2.rectangle(image, (m, m), (w - m, h - m), (0, 0, 0), 1)
    for e in range(math.floor(t_lo), math.ceil(t_hi) + 1):
        for k in (1, 2, 5):
            t = k * 10.0**e
            if t_lo <= math.log10(t) <= t_hi:
                x, _ = xy(t, f_lo)
                cv2.line(image, (x, h - m), (x, h - m + 5), (0, 0, 0), 1)
                cv2.putText(image, f"{1000 * t:g}", (x - 12, h - m + 20),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    for i in range(5):
        f = f_lo + i * (f_hi - f_lo) / 4
        _, y = xy(10**t_lo, f)
        cv2.putText(image, f"{100 * f:.1f}", (8, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, "median time per frame (ms, log scale)", (m + 120, h - 15),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, "SemanticKITTI seq. 00: ground F1 (%) vs time", (m, 35),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    for method, t, f in points:
        x, y = xy(t, f)
        colour = (0, 0, 200) if method == OURS else (160, 90, 0)
        cv2.circle(image, (x, y), 6, colour, -1, cv2.LINE_AA)
        cv2.putText(image, method, (x + 8, y - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1,
                    cv2.LINE_AA)
    figures.mkdir(parents=True, exist_ok=True)
    path = figures / "benchmarks_kitti_f1_time.png"
    cv2.imwrite(str(path), image)
    return "figures/" + path.name


def render(results: dict, figures: Path | None = None) -> str:
    mach = results["machine"]
    v = mach["versions"]
    out = [
        "# Benchmarks: accuracy and speed against the peers",
        "",
        "<!-- generated by benchmarks/run_all.py; do not edit by hand -->",
        "",
        f"Regenerate every number and figure on this page with one command: "
        f"`{results['command']}` (or `make bench`, which first installs the peers with the "
        f"`bench` extra). Generated {results['date']}.",
        "",
        f"- **Machine**: {mach['cpu']}, {mach['cores']} cores visible, {mach['memory']} RAM, "
        f"{mach['system']}, Python {mach['python']}.",
        f"- **Threads**: every method pinned to {results['threads']} thread(s) "
        "(OMP/NUMBA/BLAS variables set before any import, threadpoolctl), each measurement in "
        f"its own process; times are medians of {results['repeats']} runs after one warm-up "
        "run (the warm-up also compiles our numba kernels, which are cached on disk).",
        "- **Versions**: " + ", ".join(f"{k} {val}" for k, val in v.items()) + ".",
        "- **Data**: the real scans of `../shared/data` (never copied into the repository) and "
        "the project's synthetic scenes (seed 0). Only summary figures are shown.",
        "",
        "## Targets", "",
        *_targets(results),
        "## Ground segmentation accuracy", "",
        "Ground is the positive class: precision = ground calls that are ground, recall = ground "
        "found, F1 their harmonic mean; obstacle recall = share of obstacle points (vehicles, "
        "people, buildings, poles, high vegetation, the synthetic objects) *not* called ground. "
        "Scores are means over frames. Ground sets: SemanticKITTI 40/44/48/49/60/72 (0 and 1 "
        "ignored); LAS class 2 (0, 7 and 18 ignored); synthetic: every point not on an obstacle.",
        "",
    ]
    out += _summary_table(results, "kitti", "SemanticKITTI sequence 00, frames 000000-000002")
    figure = _figure_kitti(results, figures)
    if figure:
        out += [f"![F1 against time on SemanticKITTI]({figure})", ""]
    out += _tilt_table(results)
    figure = _figure_tilt(results, figures) \
        if _variant_methods(results, "kitti-tilt", KITTI_TILTS) else None
    if figure:
        out += [f"![Ground F1 against the tilt angle]({figure})", "",
                "Ground F1 (%) against the pitch (left) and roll (right) angle; a score below "
                "the scale is drawn on its bottom edge with its value.", ""]
    out += _lines_table(results)
    out += _fov_table(results)
    out += _low_table(results)
    out += _noise_table(results)
    las_table = _per_frame_table(results, "las", "Airborne LAS/LAZ tiles (ASPRS class 2)")
    out += las_table
    out += [] if not las_table else ["Tiles in US feet (`4_6_crop.las`, `autzen_trim.laz`, "
            "`file_with_both_wkt_and_geotiff_vlrs.las`) are converted to metres on reading "
            "(unit from the GeoTIFF keys / WKT), so every metric parameter means metres. "
            "Every method's precision is low on `autzen_trim.laz`: much of "
            "what they call ground is labelled class 1 (unclassified) in that tile. Patchwork++ "
            "expects a scan centred on a vehicle "
            "sensor; on aerial tiles it runs with a virtual sensor above the tile centre (see "
            "the peer settings below) and is out of its design domain. Ours also reads the "
            "tiles' return numbers, as `o3d_terrain.read_cloud` gives them: a point that is "
            "not the last return of its pulse is never ground (Segmenter `ground_returns`, "
            "PDAL's ground filters' default); the peers get x, y, z.", ""]
    out += _summary_table(results, "las", "LAS tiles, means over tiles")
    out += _per_frame_table(results, "synthetic", "Synthetic scenes (lidar, obstacles in the "
                            "scene)")
    out += _per_frame_table(results, "synthetic", "Synthetic scenes: obstacle recall",
                            key="obstacle_recall", label="Obstacle recall (%)")
    out += _summary_table(results, "synthetic-solid", "Synthetic scenes, forward-looking "
                          "solid-state lidar (non-repetitive scan, 70° field of view, 100,000 "
                          "firings; means over the scenes)")
    out += _per_frame_table(results, "synthetic-solid", "Synthetic scenes, solid-state lidar: "
                            "obstacle recall", key="obstacle_recall", label="Obstacle recall (%)")
    for sensor, title in DEM_SENSORS.items():
        out += _summary_table(results, f"dem-sites:{sensor}", f"Real relief (8 sites of "
                              f"`dem_1m/dem.tif` with a forest and vehicles), {title}: means "
                              "over the sites")
    if any(k.startswith("dem-sites:") for k in results["segment"]):
        out += ["The sites: `benchmarks/bench_dem_sites.py` (the raster's relief as a smooth "
                "terrain, 30 trees, 8 rocks, pole, pedestrian, car, truck; the vehicle's lidar "
                "tilted with the slope under it, 9-18°); that script also scores ours on the "
                "cloud levelled with the IMU's up and at twice the relief (docs/algorithm.md, "
                "\"Real terrain under synthetic sensors\").", ""]
    for density in FOREST_DENSITIES:
        out += _summary_table(results, f"forest:{density}", f"Mountain forest from the air (4 "
                              f"sites of `dem_1m/dem.tif` under 300 conifers and 200 shrubs per "
                              f"hectare), {density} pulses per m², several returns per pulse: "
                              "means over the sites")
    if any(k.startswith("forest:") for k in results["segment"]):
        out += ["The forest: `benchmarks/bench_forest.py` with "
                "`o3d_terrain.synthetic.sample_forest_airborne` (conical crowns with returns "
                "inside them, shrubs, numbered returns; ground = a pulse that ended on the "
                "terrain, about 42 % of the points). Ours gets the return numbers, as "
                "`read_cloud` gives a LAS tile's; the peers get x, y, z. That script also "
                "scores ours on x, y, z alone and its height RMSE (docs/algorithm.md, \"Cells "
                "for a sparse top-down scan\").", ""]
    out += _per_frame_table(results, "pit", "An open pit's benches (four 6 m faces, 8 m berms, a "
                            "64-line lidar on the pit floor or on the first berm)")
    out += _per_frame_table(results, "pit", "An open pit's benches: obstacle recall",
                            key="obstacle_recall", label="Obstacle recall (%)")
    if "pit/" + OURS in results["segment"]:
        out += ["The pit: `benchmarks/bench_pit.py` (faces of 55°, 65° and 75°; a pole, a "
                "pedestrian, a car, a rock and a truck on the floor; ground = every point not "
                "on an object). The sensor on the floor does not see the berms above it: the "
                "faces are the scan's only relief. On the first berm it stands 4 m from the "
                "face above it, whose top it does not see, and looks down on the floor and its "
                "objects. Our slope limit rises to the faces' tilt + 5°, 60-70°, by itself "
                "(docs/algorithm.md, \"Bench faces\"); that script also scores fixed limits "
                "and the second berm.", ""]
    out += _per_frame_table(results, "overhead", "A lidar under a roof (mine drifts, tunnels, a "
                            "cavern, a hall; 64 channels 2 m over the floor)")
    if "overhead/" + OURS in results["segment"]:
        out += ["The scans: `benchmarks/bench_overhead.py` with "
                "`o3d_terrain.synthetic.sample_under_ceiling` (a flat floor, level or rising "
                "15 % along x, a flat roof over it, side walls in the drifts and tunnels; "
                "ground = a return from the floor). Where the floor's returns thin out with "
                "range, the roof's do not; ours leaves out of its fit the cells over where "
                "rays went on to farther returns (docs/algorithm.md, \"Free space under the "
                "rays\"); that script also scores ours with `free_space=False`.", ""]
    out += ["## Speed at the standard sizes", "", *_speed_table(results)]
    for dataset, title in (("lidar120k", "Synthetic lidar frame: accuracy"),
                           ("stereo300k", "Synthetic stereo cloud: accuracy"),
                           ("paper34x22", "Paper configuration (34 × 22 m, 25 × 25, 640×480 "
                                          "stereo): accuracy of ours")):
        out += _summary_table(results, dataset, title)
    out += ["## Per-stage timings of o3d_terrain", "", *_stages_table(results)]
    out += ["## Peak memory", "", *_memory_table(results)]
    out += ["## Terrain accuracy against exact terrain", "", *_terrain_section(results)]
    out += ["## Peer settings", "",
            "Each peer runs with its package defaults through the adapters in "
            "`o3d_terrain/evaluation/peers.py`; a parameter is set only where the peer needs to "
            "know the data:", "",
            "- **Patchwork++** (`pypatchworkpp`): defaults (KITTI: sensor height 1.723 m, range "
            "2.7-80 m); sensor height set to the synthetic sensor's; reflected-noise removal off "
            "(it needs intensities; every method gets positions only). Aerial tiles: virtual "
            "sensor at the tile centre, 1.723 m above the lowest 5 % of heights within 10 m, "
            "min range 0, max range the tile's half diagonal. Patchwork++ adapts its "
            "thresholds from frame to frame; the labels scored are those of its last run on "
            "the frame (after the warm-up and the timed runs), so it has adapted to that frame "
            "(on a SemanticKITTI sequence one engine over consecutive frames scores the same; "
            "on the synthetic scenes a fresh engine per frame scores lower: docs/algorithm.md, "
            "\"A solid-state lidar\").",
            "- **CSF** (`cloth-simulation-filter`): defaults (cloth resolution 1 m, class threshold "
            "0.5 m, rigidness 3, slope smoothing, 500 iterations); coordinates shifted to the "
            "minimum corner (CSF computes in single precision).",
            "- **SMRF** (`pysmrf.classify`): defaults (1 m cells, windows 1-5 cells, slope 0.15, "
            "elevation threshold 0.5 m, scaler 1.25), one worker.",
            "- **Open3D RANSAC plane**: `segment_plane(distance_threshold=0.2, ransac_n=3, "
            "num_iterations=1000)` after `open3d.utility.random.seed(0)`; the dominant "
            "plane's inliers are the ground. Open3D's RANSAC still varies from run to run "
            "(about 1.5 F1 points on a KITTI frame).",
            "- **o3d_terrain**: `segment_terrain` defaults (cell 0.5 m, degree 3, automatic "
            "control points, automatic threshold widened where the surface misfits) except the "
            "paper configuration row.", ""]
    return "\n".join(out) + "\n"



if __name__ == "__main__":
    sys.exit(main())
