"""Numba policy for every kernel in :mod:`raytrace` (DESIGN.md), set once here.

``cache=True`` so CI and later runs skip compilation; ``nogil`` so threads can overlap
kernels with Embree calls; ``prange`` only on outer pixel/ray loops.

* ``pjit_exact`` / ``jit_exact``: no fastmath. Per-pixel geometry kernels use these so a
  pixel's result never depends on where it sits in the cast rectangle (SIMD body vs scalar
  remainder): culled and full-frame renders are identical bit for bit.
* ``inline``: helpers that kernels call per element with array arguments (a mesh, a cache
  table, the environment's parameters). Numba inlines them into the caller's IR, where
  they take the caller's flags. A compiled call instead increments and decrements the
  reference count of every array argument, atomically: on two threads contending for the
  same counters that cost far more than the helper's work (``add_interpolated_rows``,
  ~400 k sub-samples of a Tiangong frame: 46 ms as a call of ``_centre_on_surface``, 34 ms
  with LLVM's forceinline, 13 ms inlined by numba, same output).
* ``pjit`` / ``jit``: fastmath without ``nnan``/``ninf`` (misses are ``inf`` and must stay
  so), for shading kernels where the last bit does not matter. Not for kernels whose output
  feeds thresholds that amplify the last bit (the residual filter's edge-stopping weights):
  under fastmath the code numba caches can round differently from the code it has just
  compiled, and the first render after an install then differs from every later one.
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

jit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
pjit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True, parallel=True)
jit_exact = numba.njit(cache=True, nogil=True)
pjit_exact = numba.njit(cache=True, nogil=True, parallel=True)
inline = numba.njit(cache=True, nogil=True, inline="always")
