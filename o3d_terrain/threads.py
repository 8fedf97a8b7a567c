"""One BLAS thread for the terrain fit's small linear solves.

The fit makes about a dozen banded Cholesky solves (LAPACK ``dpbsv``) of 1,000-10,000 unknowns,
with numba kernels in between. A multi-threaded OpenBLAS wakes its threads for each solve and
puts them to sleep again in the kernels between, which on a machine with other work (a vehicle
computer, a benchmark beside it) cost more than the solves: ``segment_terrain`` on a KITTI
frame took 32 ms with OpenBLAS's default threads against 20 ms with one (docs/performance.md).
:func:`one_blas_thread` limits every loaded BLAS to one thread for the duration of a ``with``
block and restores the caller's setting afterwards (``threadpoolctl``, the library
scikit-learn uses for the same purpose).
"""

from __future__ import annotations

import contextlib

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread"]

_CONTROLLER: ThreadpoolController | None = None


def one_blas_thread() -> contextlib.AbstractContextManager:
    """A context manager: one thread for every BLAS library loaded in the process (numpy's and
    scipy's OpenBLAS) inside it, the previous counts restored on exit."""
    global _CONTROLLER
    if _CONTROLLER is None:  # finds the loaded libraries once (~3 ms)
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")
