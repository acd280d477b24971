"""One process-wide thread pool for work that releases the GIL (OpenImageIO calls, NumPy
random sampling, Numba kernels). Created on first use and dropped in a forked child (whose
copy would have no live threads); threads never change results, only wall time."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

_POOL: ThreadPoolExecutor | None = None


def pool() -> ThreadPoolExecutor:
    """Return the shared pool (one worker per core, 2 to 8)."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(2, min(8, os.cpu_count() or 1)),
                                   thread_name_prefix="degrade")
    return _POOL


def _forget_after_fork() -> None:
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forget_after_fork)
