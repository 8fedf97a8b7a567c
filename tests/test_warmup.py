"""``o3d-terrain warmup``: after it, the packaged pipelines and the drop-in calls find every
numba kernel they call ready (nothing left to compile or load on a vehicle's first frame)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from o3d_terrain.cli import main
from o3d_terrain.evaluation.datasets import data_root

ROOT = Path(__file__).resolve().parents[1]

#: the real LAS tiles the probe also runs the LAS pipeline on, when the data are there
LAS_TILES = ("las/4_6_crop.las", "las/autzen_trim.laz", "las/hexbin-crop.las")

#: in a fresh interpreter: warm up, note each kernel's machine code, then run what users run
#: (the packaged lidar and stereo pipelines, segment_terrain on another scene and sensor, also
#: as float32 rows, on every numba thread and on one, and on a scan in a map frame; the
#: packaged LAS pipeline on a generated airborne tile with two returns per pulse here and
#: there, written as LAS, and on the real tiles given after the output folder, and
#: segment_terrain on the tile as read) and list the kernels that had to compile or load more
#: code after the warm-up
_PROBE = """
import json, sys
import numba
import numpy as np
from o3d_terrain.warmup import kernels, warm_up
from o3d_terrain import read_cloud, segment_terrain
from o3d_terrain.pipeline import load_pipeline
from o3d_terrain.synthetic import make_scene, sample_airborne, sample_lidar
report = warm_up()
before = {name: len(k.overloads) for name, k in kernels().items()}
out = sys.argv[1]
for name in ("demo.yaml", "stereo_terrain.yaml"):
    load_pipeline("pipelines/" + name).run(output_dir=out + "/" + name)
# an airborne tile of another scene, in other projected coordinates, as a LAS file (the
# las extra: laspy)
scene = make_scene("offroad", seed=5, region=(-50.0, 70.0, -40.0, 60.0))
p = sample_airborne(scene, density=4.0, offset=(3.1e5, 5.2e6, 240.0), seed=5).positions
n = len(p)
try:
    import laspy
except ImportError:
    laspy, tiles = None, []
else:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.full(3, 0.001), np.floor(p.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
    las.number_of_returns = np.where(np.arange(n) % 7 == 0, 2, 1)
    las.return_number = np.where(np.arange(n) % 14 == 0, 2, 1)
    las.write(out + "/tile.las")
    tiles = [out + "/tile.las"] + sys.argv[2:]
for tile in tiles:
    load_pipeline("pipelines/las_terrain.yaml", input_path=tile).run(output_dir=out + "/las")
    segment_terrain(read_cloud(tile))
segment_terrain(np.asarray(p, dtype=np.float64))
cloud = sample_lidar(make_scene("hills", seed=3), tilt_deg=(4.0, -3.0), seed=3)
segment_terrain(np.asarray(cloud.positions, dtype=np.float64))
# a lidar's float32 (x, y, z, intensity) rows, as KITTI stores them
segment_terrain(np.c_[cloud.positions, np.ones(len(cloud.positions))].astype(np.float32))
numba.set_num_threads(1)  # one thread takes the serial twins of the parallel kernels
segment_terrain(np.asarray(cloud.positions, dtype=np.float64))
# a scan in a map frame, its sensor found from the scan
cloud = sample_lidar(make_scene("valley", seed=3), beams=64, seed=3)
segment_terrain(np.asarray(cloud.positions, dtype=np.float64) + (2.0e5, 3.0e6, 50.0))
grown = sorted(n for n, k in kernels().items() if len(k.overloads) != before.get(n, 0))
print(json.dumps({"grown": grown, "ready": len(report.ready), "cache": report.cache_dir}))
"""


def test_after_warm_up_the_default_paths_need_no_new_kernel_code(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    root = data_root()
    tiles = [str(root / name) for name in LAS_TILES
             if root is not None and (root / name).is_file()]
    done = subprocess.run([sys.executable, "-c", _PROBE, str(tmp_path), *tiles], cwd=ROOT,
                          env=env,
                          capture_output=True, text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["grown"] == [], f"kernels warm_up does not reach: {result['grown']}"
    assert result["ready"] >= 40
    assert result["cache"], "the kernels should be cached on disk"


def test_warmup_command_reports_the_kernels_and_the_cache(capsys):
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "numba kernel(s) ready" in out and "cache: " in out


def test_the_top_down_warm_up_runs_the_las_pipelines_stages():
    import yaml

    from o3d_terrain.warmup import _TOP_DOWN_STAGES

    stages = yaml.safe_load((ROOT / "pipelines" / "las_terrain.yaml").read_text())["stages"]
    assert list(_TOP_DOWN_STAGES) == stages
