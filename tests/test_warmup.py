"""``o3d-terrain warmup``: after it, the packaged pipelines and the drop-in calls find every
numba kernel they call ready (nothing left to compile or load on a vehicle's first frame)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from o3d_terrain.cli import main

ROOT = Path(__file__).resolve().parents[1]

#: in a fresh interpreter: warm up, note each kernel's machine code, then run what users run
#: (the packaged lidar and stereo pipelines, segment_terrain on another scene and sensor, on
#: every numba thread and on one, and on a scan in a map frame) and list the kernels that had to compile or load more code
#: after the warm-up
_PROBE = """
import json, sys
import numba
import numpy as np
from o3d_terrain.warmup import kernels, warm_up
from o3d_terrain import segment_terrain
from o3d_terrain.pipeline import load_pipeline
from o3d_terrain.synthetic import make_scene, sample_lidar
report = warm_up()
before = {name: len(k.overloads) for name, k in kernels().items()}
out = sys.argv[1]
for name in ("demo.yaml", "stereo_terrain.yaml"):
    load_pipeline("pipelines/" + name).run(output_dir=out + "/" + name)
cloud = sample_lidar(make_scene("hills", seed=3), tilt_deg=(4.0, -3.0), seed=3)
segment_terrain(np.asarray(cloud.positions, dtype=np.float64))
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
    done = subprocess.run([sys.executable, "-c", _PROBE, str(tmp_path)], cwd=ROOT, env=env,
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
