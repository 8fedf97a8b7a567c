"""Keep freed memory in the process from one frame to the next (glibc's ``malloc``).

A frame's arrays (per point, per cell: 0.1-3 MB each on a lidar frame) are allocated and freed
every frame. With glibc's default settings a freed block of more than 128 kB (at first; the
threshold then follows the largest block freed) goes back to the system, and so does free
memory above 128 kB at the top of the heap (twice that threshold later): the next frame gets
fresh pages, and the kernel zeroes each one on its first write. On a SemanticKITTI frame that
was about 2,900 page faults per ``segment_terrain`` call, 12 MB of zeroed pages and about
15 % of the call's time (docs/performance.md, "Freed memory kept in the process").

:func:`keep_freed_memory` sets the two thresholds to the values glibc's own adaptive rule
reaches at most (``mallopt(3)``: 32 MB for ``M_MMAP_THRESHOLD`` on 64-bit systems, twice that
for ``M_TRIM_THRESHOLD``), from the start. The process then keeps up to 64 MB of freed memory
at the top of its heap, and blocks above 32 MB still go straight back to the system.

It is a setting of the whole process, so the library does not make it on import: a program
that runs frame after frame (a vehicle's perception node) calls
``o3d_terrain.keep_freed_memory()`` once at start-up, and the ``o3d-terrain`` command makes
the call for its own process. It does nothing (and returns False)

- off Linux or with another C library than glibc (no ``gnu_get_libc_version``);
- when the process set glibc's malloc itself: any of the ``MALLOC_*_`` environment variables
  of ``mallopt(3)`` that concern these thresholds, or ``glibc.malloc`` tunables in
  ``GLIBC_TUNABLES``;
- when ``O3D_TERRAIN_MALLOC=system`` is set (the allocator left as the process has it).
"""

from __future__ import annotations

import ctypes
import os
import sys
from typing import Mapping

__all__ = ["ENVIRONMENT", "keep_freed_memory"]

#: environment variable: "system" leaves the allocator's settings alone
ENVIRONMENT = "O3D_TERRAIN_MALLOC"

#: mallopt(3) parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: glibc's own upper limit of its adaptive mmap threshold on 64-bit systems, and the trim
#: threshold it pairs with it (twice)
MMAP_THRESHOLD = 32 * 2**20
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD

#: what a process sets glibc's malloc with itself (mallopt(3), tunables(7))
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_",
                  "MALLOC_MMAP_MAX_")


def keep_freed_memory(environ: Mapping[str, str] | None = None) -> bool:
    """Set glibc's mmap and trim thresholds to :data:`MMAP_THRESHOLD` and
    :data:`TRIM_THRESHOLD` unless the process (``environ``, default ``os.environ``) says
    otherwise (module docstring); True when they were set."""
    environ = os.environ if environ is None else environ
    if environ.get(ENVIRONMENT, "").strip().lower() == "system":
        return False
    if any(name in environ for name in _USER_SETTINGS) or \
            "glibc.malloc" in environ.get("GLIBC_TUNABLES", ""):
        return False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # glibc only (musl has a mallopt that does nothing)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and \
        bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
