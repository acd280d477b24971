"""Numba policy for every kernel in :mod:`degrade` (DESIGN.md), set once here.

Mirrors ``raytrace/_jit.py`` without importing it (``degrade`` knows nothing of the other
packages), but leaves numba's threading layer alone: ``raytrace`` prefers TBB for its side
threads (``prefer_tbb``), which ``degrade`` has none of; in a process that imports ``raytrace``
first (``cli.py``) these kernels run on TBB too, with the same output. ``cache=True`` so CI
and later runs skip compilation; ``nogil`` so kernels can overlap NumPy random sampling
running in another thread; ``prange`` only on outer loops, each iteration writing only its
own rows.

* ``pjit_exact`` / ``jit_exact``: no fastmath. Every sum runs in a fixed order and a pixel's
  value never depends on whether it fell in a SIMD body or a scalar remainder, so outputs are
  byte-reproducible and equal to their NumPy definitions.
* ``pjit``: fastmath without ``nnan``/``ninf``, only for the sRGB transfer curve where the
  last float32 bit does not matter (it is tested against a float64 reference).
"""

from __future__ import annotations

import os

# OpenMP threads that finish a kernel sleep instead of spinning, so the next Embree call or
# NumPy step gets both cores (set before numba loads libgomp; a value the user set wins):
# 12 scenes at 1280×960, median s / frame, ``fast`` 0.125 → 0.117 and ``balanced``-8 0.265
# → 0.243 (two interleaved runs each, benchmarks/bench_time_error.py scenes)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

pjit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True, parallel=True)
jit_exact = numba.njit(cache=True, nogil=True)
pjit_exact = numba.njit(cache=True, nogil=True, parallel=True)
