"""Numba policy for every kernel in :mod:`raytrace`, set once here.

``cache=True`` so CI and later runs skip compilation; ``nogil`` so threads can overlap
kernels with Embree calls; ``prange`` only on outer pixel/ray loops.

* ``pjit_exact`` / ``jit_exact``: no fastmath. Per-pixel geometry kernels use these so a
  pixel's result never depends on where it sits in the cast rectangle (SIMD body vs scalar
  remainder): culled and full-frame renders are identical bit for bit.
* ``inline``: helpers that kernels call per element with array arguments (a mesh, a cache
  table, the environment's parameters). Numba inlines them into the caller's IR, where
  they take the caller's flags. A compiled call instead increments and decrements the
  reference count of every array argument, atomically: on two threads contending for the
  same counters that cost far more than the helper's work (``interpolate_rows_into``,
  ~400 k sub-samples of a Tiangong frame: 46 ms as a call of ``_centre_on_surface``, 34 ms
  with LLVM's forceinline, 13 ms inlined by numba, same output).
* ``pjit`` / ``jit``: fastmath without ``nnan``/``ninf`` (misses are ``inf`` and must stay
  so), for shading kernels where the last bit does not matter. Not for kernels whose output
  feeds thresholds that amplify the last bit (the residual filter's edge-stopping weights):
  under fastmath the code numba caches can round differently from the code it has just
  compiled, and the first render after an install then differs from every later one.

Importing this module also makes numba's compiler-flag comparison cheap
(:func:`fast_flag_comparison`: the same results, a shorter compile).
"""

from __future__ import annotations

import os

# where numba runs on OpenMP (see prefer_tbb below), its threads that finish a kernel sleep
# instead of spinning, so the next Embree call or NumPy step gets both cores (set before numba
# loads libgomp; a value the user set wins):
# 12 scenes at 1280×960, median s / frame, ``fast`` 0.125 → 0.117 and ``balanced``-8 0.265
# → 0.243 (two interleaved runs each, benchmarks/bench_time_error.py scenes)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import contextlib
import ctypes
import sys
import threading

import numba


def prefer_tbb() -> bool:
    """Make Intel TBB numba's threading layer where the ``tbb`` wheel is installed (a
    dependency on x86-64) and the user has not chosen one (``NUMBA_THREADING_LAYER``). True
    if it made TBB the layer or numba's threads already run on TBB; False where the user chose
    a layer (whichever) or TBB cannot be loaded. Call before the first parallel kernel runs.

    Why: ``render`` runs the frame's lighting context on a side thread while the main
    thread's parallel kernels run, so on two cores a kernel's threads share them with a third.
    OpenMP hands each thread a fixed half of the loop, and the half whose thread waits for a
    core holds the whole kernel back; TBB's idle threads take over waiting work. Measured
    (``benchmarks/bench_interleaved.py . . --env-a NUMBA_THREADING_LAYER=omp --env-b
    NUMBA_THREADING_LAYER=tbb``, BENCHMARKS.md "numba on TBB"): one frame on both cores
    ``fast`` 0.908–0.949×, ``balanced``-8 0.955× and -16 0.940× the time (median per-scene
    ratio), one thread (a worker of a sequence) 1.006×; the same bits (each kernel's loop is
    split into numba's per-thread ranges under either layer, and none sums across them).
    Where numba's threads already run (a parallel kernel ran before ``raytrace`` was
    imported), their layer stays; the result says whether it is TBB.

    The wheel puts ``libtbb`` in ``sys.prefix/lib``, where the loader does not look; it is
    loaded here by path (RTLD_GLOBAL) so numba's ``tbbpool`` finds it by name, also when the
    user asks for ``tbb`` by name. Where it cannot be loaded, numba keeps its own choice
    (OpenMP, else its workqueue)."""
    name = {"linux": "libtbb.so.12", "darwin": "libtbb.12.dylib", "win32": "tbb12.dll"}.get(sys.platform)
    if name is None:
        return False
    # loaded even where the user chose a layer: "tbb" (or numba's "safe") then finds it too
    for folder in (os.path.join(sys.prefix, "lib"), os.path.join(sys.base_prefix, "lib")):
        path = os.path.join(folder, name)
        if sys.platform != "win32" and os.path.exists(path):
            try:
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
                break
            except OSError:
                pass
    try:
        return numba.threading_layer() == "tbb"  # launched already
    except ValueError:
        pass  # not yet
    if os.environ.get("NUMBA_THREADING_LAYER"):
        return False
    try:
        from numba.np.ufunc import tbbpool  # noqa: F401 (loads only if libtbb is found)
        # numba's own requirement (TBB 2021.6 or later); below it numba would refuse the layer
        version = ctypes.CDLL(name).TBB_runtime_interface_version
        version.restype = ctypes.c_int
        if version() < 12060:
            return False
    except (ImportError, OSError, AttributeError):
        return False
    numba.config.THREADING_LAYER = "tbb"
    return True


TBB = prefer_tbb()

# glibc's malloc serves blocks above its mmap threshold (128 KiB, raised dynamically up to
# 32 MiB as such blocks are freed) by fresh mappings, and returns heap top beyond its trim
# threshold (twice that) to the system: the MB-sized arrays a frame allocates and frees by the
# hundred were then mapped and zero-filled by the kernel again on every frame, or not,
# depending on what the process had freed before. Fixed thresholds keep them in the heap,
# reused. Measured (BENCHMARKS.md, "Allocator"), ``balanced``-16 at 1280×960, each scene in a
# fresh process, two rounds alternated: Tiangong's three views 11–15 k page faults per frame
# → ~300, system time 44–76 → 14–25 ms per frame, min time 0.84× (``sunlit``) and 0.98–1.01×;
# the other nine had ≤ 400 faults already, 0.94–1.01×. MALLOC_MMAP_THRESHOLD_ /
# MALLOC_TRIM_THRESHOLD_ in the environment, or ORBITSYNTH_KEEP_MALLOC=1, keep the user's
# settings.
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD_BYTES = 512 << 20


def tune_allocator() -> bool:
    """Fix glibc's mmap and trim thresholds (see above); True if both were set. A no-op
    (False) off Linux/glibc, with ORBITSYNTH_KEEP_MALLOC set (other than 0), or where the
    environment already sets either threshold."""
    if os.environ.get("ORBITSYNTH_KEEP_MALLOC", "") not in ("", "0"):
        return False
    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):  # not glibc (musl has no libc.so.6)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
    # the mmap threshold first: setting the trim threshold alone would switch off the dynamic
    # raise of the mmap one and leave it at 128 KiB (tried: 92 k faults per frame)
    return mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1 and \
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1


ALLOCATOR_TUNED = tune_allocator()


def fast_flag_comparison() -> bool:
    """Make numba's comparison and hashing of compiler flags (``TargetConfig``) cheap, with the
    same results; True if it did (False where numba's internals are not the expected ones, and
    nothing changes).

    Why: numba keys the implementations of every ``@overload`` it has typed by the call's
    flags, and each lookup compares two flag objects through ``values()``, a dict of all ~20
    options read one property at a time (~13 µs a comparison). Compiling the ``fast`` group
    does ~470 k such comparisons: ~3.8 s of a ~70 s compile on one core (one process,
    ``raytrace._precompile``'s entries, two runs each; numba 0.68). Here ``values()`` merges
    the options' defaults (computed once per class) with the values set; ``==`` first compares
    the values set, and falls back to ``values()`` only where they differ (an option may be
    set to its default); ``hash`` is numba's own: the hash of the sorted option names, the same
    for every instance of a class. The machine code numba emits is the same (every cached
    kernel of the group compared)."""
    try:
        from numba.core.targetconfig import Option, TargetConfig
        if not (hasattr(TargetConfig, "values") and hasattr(TargetConfig, "options")
                and "_values" in getattr(TargetConfig, "__slots__", ()) and isinstance(Option.default, property)):
            return False
    except ImportError:
        return False
    if getattr(TargetConfig, "_orbitsynth_fast", False):
        return True
    defaults = {}

    def class_defaults(cls):
        d = defaults.get(cls)
        if d is None:
            d = defaults[cls] = ({k: o.default for k, o in cls.options.items()}, hash(tuple(sorted(cls.options))))
        return d

    def values(self):
        # the same keys, in the same (declaration) order, as numba's
        return {**class_defaults(type(self))[0], **self._values}

    def __eq__(self, other):
        if not isinstance(other, TargetConfig):
            return NotImplemented
        if type(self) is type(other) and self._values == other._values:
            return True
        return values(self) == values(other)

    def __hash__(self):
        return class_defaults(type(self))[1]

    TargetConfig.values = values
    TargetConfig.__eq__ = __eq__
    TargetConfig.__hash__ = __hash__
    TargetConfig._orbitsynth_fast = True
    return True


FAST_FLAG_COMPARISON = fast_flag_comparison()

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

class ThreadedKernel:
    """A kernel with ``prange`` loops, built twice by numba: ``parallel`` (``parallel=True``:
    the loops run on numba's threads) and ``serial`` (the same code, each ``prange`` a plain
    loop, under a name of its own in numba's cache). A call runs the serial build where the
    calling thread's numba thread count is 1 (the CLI's pool workers when there are as many
    as cores, a one-core machine), the parallel one elsewhere. The serial build takes the
    parallel loop body's error model (``numpy``: a division by zero gives inf, as in the
    parallel build, instead of raising). Both compute every output element by the same code
    and no kernel sums across loop iterations, so their results are the same bits, checked on
    whole sequences (``tests/golden_set.py`` against the parallel builds: every file of four
    targets × three presets byte for byte); a kernel whose fastmath sums LLVM vectorises
    differently in the two builds is ``pjit_parallel_only`` instead
    (``environment._direction_cells``: a last bit of a few ``balanced`` pixels). The serial
    build compiles in about half the time (numba's parfor passes and the loop body's gufunc
    wrappers are what ``parallel=True`` adds), which is most of a fresh install's first run
    (BENCHMARKS.md, "Compiling the main job's kernels on a fresh install"), and a process
    compiles or loads only the build its threads call.

    Called from Python only: a numba kernel cannot call it (none does; it would call a
    ``jit`` helper instead)."""

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


_LOCAL = threading.local()  # .cores: set by serial_builds on the thread that runs under it


@contextlib.contextmanager
def serial_builds(cores: int):
    """This thread's kernels on their serial builds (numba's thread count 1: see
    :class:`ThreadedKernel`) while it has ``cores`` cores to itself: work split into independent
    pieces (:func:`side_cores`) then runs them side by side on side threads, each piece on the
    serial builds too. For a process whose numba cache holds the serial builds only (a fresh
    install's first run compiles those) and whose cores are free (the CLI building the scenes
    its pool's workers wait for). The previous thread count is restored."""
    before, before_cores = numba.get_num_threads(), getattr(_LOCAL, "cores", 1)
    numba.set_num_threads(1)
    _LOCAL.cores = max(1, int(cores))
    try:
        yield
    finally:
        _LOCAL.cores = before_cores
        numba.set_num_threads(before)


def side_cores() -> int:
    """The cores the calling thread's work may spread over: numba's thread count, or the
    ``cores`` of :func:`serial_builds` where that is more."""
    return max(numba.get_num_threads(), getattr(_LOCAL, "cores", 1))


SERIAL_SUFFIX = ".serial"


def serial_copy(py_func):
    """``py_func`` again, qualified name ending in :data:`SERIAL_SUFFIX`: numba names a cache
    entry after the function's module, qualified name and first line and keys it by signature
    alone, not by ``parallel``, so both builds under one name would overwrite each other's."""
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


jit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
pjit = _threaded(cache=True, fastmath=FASTMATH, nogil=True)
jit_exact = numba.njit(cache=True, nogil=True)
pjit_exact = _threaded(cache=True, nogil=True)
pjit_parallel_only = numba.njit(cache=True, fastmath=FASTMATH, nogil=True, parallel=True)
"""``pjit`` without the serial build, for a kernel whose fastmath sums LLVM vectorises one way in
the parallel loop's body and another in a plain loop (a last bit of difference): one build, the
same bits in every process whatever its thread count."""
inline = numba.njit(cache=True, nogil=True, inline="always")
