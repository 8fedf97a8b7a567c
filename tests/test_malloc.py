"""The allocator setting of ``o3d_terrain.keep_freed_memory`` (o3d_terrain/_malloc.py)."""

import ctypes
import os
import subprocess
import sys

import pytest

from o3d_terrain._malloc import ENVIRONMENT, keep_freed_memory


def _glibc() -> bool:
    try:
        ctypes.CDLL(None).gnu_get_libc_version
    except (OSError, AttributeError):
        return False
    return sys.platform.startswith("linux")


def test_the_process_own_settings_are_left_alone():
    assert keep_freed_memory({ENVIRONMENT: "system"}) is False
    assert keep_freed_memory({ENVIRONMENT: " System "}) is False
    assert keep_freed_memory({"MALLOC_TRIM_THRESHOLD_": "131072"}) is False
    assert keep_freed_memory({"MALLOC_MMAP_THRESHOLD_": "131072"}) is False
    assert keep_freed_memory({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"}) is False


# a frame's pattern: six 2.5 MB arrays alive together, then freed, five times; page faults of
# the last four (the first takes fresh pages either way); argv[1] "keep": after the call
_CHILD = """
import resource
import sys
import numpy as np
import o3d_terrain
applied = sys.argv[1] == "keep" and o3d_terrain.keep_freed_memory()
def frame():
    arrays = [np.ones(5 << 16) for _ in range(6)]
    return sum(a.sum() for a in arrays)
frame()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(4):
    frame()
print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(keep: bool, **env) -> tuple[bool, int]:
    environ = {k: v for k, v in os.environ.items() if k not in (ENVIRONMENT, "GLIBC_TUNABLES")
               and not k.startswith("MALLOC_")}
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", _CHILD, "keep" if keep else "import"],
                         env=environ, capture_output=True, text=True, check=True)
    applied, faults = out.stdout.split()[-2:]
    return applied == "True", int(faults)


@pytest.mark.skipif(not _glibc(), reason="glibc's malloc only")
def test_freed_blocks_are_reused_without_fresh_pages():
    # 15 MB are 3,840 pages of 4 kB: fresh pages each frame without the setting, which
    # importing the library does not make
    applied, faults = _faults(True)
    assert applied and faults < 400
    applied, faults = _faults(True, **{ENVIRONMENT: "system"})
    assert not applied and faults > 4 * 3000
    applied, faults = _faults(False)
    assert not applied and faults > 4 * 3000
