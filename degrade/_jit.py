"""Numba policy for every kernel in :mod:`degrade`, set once here.

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



class ThreadedKernel:
    """A kernel with ``prange`` loops, built twice: ``parallel`` (``parallel=True``) and
    ``serial`` (each ``prange`` a plain loop, under a cache name of its own); a call runs the
    serial build (with the parallel loop body's ``numpy`` error model) where the calling
    thread's numba thread count is 1, the parallel one elsewhere. The same bits either way; the
    serial build compiles in about half the time.
    As ``raytrace._jit.ThreadedKernel`` (which see), which this package does not import."""

    def __init__(self, py_func, **options):
        self.py_func = py_func
        self.parallel = numba.njit(parallel=True, **options)(py_func)
        self.serial = numba.njit(error_model="numpy", **options)(serial_copy(py_func))
        self.__name__, self.__qualname__ = py_func.__name__, py_func.__qualname__
        self.__module__, self.__doc__ = py_func.__module__, py_func.__doc__

    def build(self, serial: bool):
        """The serial or the parallel build (a numba dispatcher)."""
        return self.serial if serial else self.parallel

    def __call__(self, *args, **kwargs):
        return (self.serial if numba.get_num_threads() == 1 else self.parallel)(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<ThreadedKernel {self.__module__}.{self.__qualname__}>"


SERIAL_SUFFIX = ".serial"


def serial_copy(py_func):
    """``py_func`` again, qualified name ending in :data:`SERIAL_SUFFIX`: numba keys a cache
    entry by name and signature, not by ``parallel``."""
    import types
    copy = types.FunctionType(py_func.__code__, py_func.__globals__, py_func.__name__, py_func.__defaults__,
                              py_func.__closure__)
    copy.__kwdefaults__ = py_func.__kwdefaults__
    copy.__qualname__ = py_func.__qualname__ + SERIAL_SUFFIX
    copy.__module__, copy.__doc__ = py_func.__module__, py_func.__doc__
    return copy


def _threaded(**options):
    def decorate(py_func):
        return ThreadedKernel(py_func, **options)
    return decorate


pjit = _threaded(cache=True, fastmath=FASTMATH, nogil=True)
jit_exact = numba.njit(cache=True, nogil=True)
pjit_exact = _threaded(cache=True, nogil=True)
