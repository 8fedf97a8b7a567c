"""Private numba kernels: NumPy in, NumPy out. They import only numpy, numba and math.

Public, validating wrappers live in the modules above (``o3d_terrain.grid``,
``o3d_terrain.spline``, ...). Kernels are compiled with ``cache=True``.
"""

import os as _os

import numba as _numba

if "NUMBA_THREADING_LAYER" not in _os.environ:
    # Prefer OpenMP over TBB: an old TBB on the machine makes numba warn on the first
    # threaded kernel before it falls back. Set NUMBA_THREADING_LAYER to choose another.
    _numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
