"""The terrain fit runs its solves on one BLAS thread and leaves the caller's setting alone."""

from __future__ import annotations

import numpy as np
from threadpoolctl import ThreadpoolController

from o3d_terrain import threads
from o3d_terrain.grid import quantize_points
from o3d_terrain.spline import GridBasis
from o3d_terrain.terrain import fit_grid_detailed


def _blas_threads(controller):
    return [lib.num_threads for lib in controller.select(user_api="blas").lib_controllers]


def test_one_blas_thread_inside_the_fit_and_the_callers_count_restored(monkeypatch):
    controller = ThreadpoolController()
    assert _blas_threads(controller), "numpy/scipy load a BLAS that threadpoolctl sees"
    seen = []
    solve = GridBasis.solve_cells

    def watched(self, *args, **kwargs):
        seen.append(_blas_threads(ThreadpoolController()))
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(GridBasis, "solve_cells", watched)
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 20, 5000), rng.uniform(0, 20, 5000), rng.normal(0, 0.02, 5000)]
    grid = quantize_points(pts, cell_size=0.5)
    with controller.limit(limits=2, user_api="blas"):
        before = _blas_threads(controller)
        fit_grid_detailed(grid, positions=pts)
        after = _blas_threads(controller)
    assert seen and all(counts == [1] * len(counts) for counts in seen)
    assert after == before
    with threads.one_blas_thread():
        assert set(_blas_threads(controller)) == {1}
