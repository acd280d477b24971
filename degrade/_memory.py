"""Process memory policy: freed heap memory is kept for the next frame, not handed back.

Every frame allocates and frees the same large arrays (the camera equation's image, the
mosaic's float64 means and charges, the read-noise draws, the paper preset's Gaussian draws
and Poisson means: 5–30 MB each). glibc's malloc serves a block above ``M_MMAP_THRESHOLD``
with a fresh ``mmap`` and gives the free top of the heap back to the system above
``M_TRIM_THRESHOLD``, so the next frame's arrays are new pages that the kernel faults in and
zero-fills: system CPU time that is neither computation nor random draws. On the main job's
frames (``benchmarks/bench_degrade.py --main-job``, one numba thread) that was 6 ms of system
time per frame for ``physical`` and 25 ms for ``paper``; with the thresholds below, under 1 ms.

:func:`keep_freed_memory` (called when :mod:`degrade` is imported) sets
``M_TRIM_THRESHOLD`` to 256 MB and ``M_MMAP_THRESHOLD`` to 32 MB (glibc's largest), fixed
(glibc otherwise adapts them), with ``mallopt(3)``. The cost: a process keeps up to 256 MB
of freed memory mapped instead of returning it. Nothing happens off glibc, or when the user
set one of glibc's own ``MALLOC_*_`` variables (their choice wins), or with
``ORBITSYNTH_KEEP_HEAP=0``.

Reference: mallopt(3), Linux man-pages, https://man7.org/linux/man-pages/man3/mallopt.3.html
"""

from __future__ import annotations

import ctypes
import os
import platform

__all__ = ["keep_freed_memory"]

TRIM_THRESHOLD_B = 256 << 20
MMAP_THRESHOLD_B = 32 << 20  # glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit systems
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # malloc.h
_GLIBC_VARIABLES = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def keep_freed_memory() -> bool:
    """Set glibc's trim and mmap thresholds as the module docstring says; returns whether they
    were set (False off glibc, when the user set glibc's variables, or ORBITSYNTH_KEEP_HEAP=0)."""
    if os.environ.get("ORBITSYNTH_KEEP_HEAP", "1") == "0" or any(v in os.environ for v in _GLIBC_VARIABLES):
        return False
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # pragma: no cover - glibc without the usual soname
        return False
    return bool(libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_B)) and bool(libc.mallopt(_M_MMAP_THRESHOLD,
                                                                                       MMAP_THRESHOLD_B))
