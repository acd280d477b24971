"""Compile the numba kernels into numba's on-disk cache on several processes at once.

On a fresh install the first frame of ``python cli.py --target … --pattern …`` waits for numba
to compile some eighty kernels, ~60 s on one core, and every worker process compiles all of
them; ``--quality balanced`` adds ~55 s of kernels on one core (the fused final gather and
lobe paths most of it), ``reference`` ~6 s (a 2-core AMD EPYC). :func:`precompile` compiles
the kernels of the requested groups on ``processes`` spawned processes, one entry per task,
each calling ``Dispatcher.compile`` with ``cache=True``, so the cache is written once, in
parallel; the workers then load every kernel from it. No two processes compile the same
helper (:func:`dependencies`), and a caller can follow the progress (``progress``). A kernel
whose recorded signature no longer matches the code is skipped (it compiles on first call, as
without this step). The kernels with parallel loops are built twice
(``raytrace._jit.ThreadedKernel``): ``serial=True`` compiles the builds that processes on one
numba thread each call (the CLI's pool workers when there are as many as cores: the first
command on two cores), in about half the time of the parallel builds, which the recorded
seconds measure.

Where the time goes (``fast``, one process, cold cache; BENCHMARKS.md, "Compiling the main
job's kernels on a fresh install"): ~40 % in LLVM (optimising and generating code: numba links
every callee's code into each caller and optimises and generates it again there, and a
``parallel=True`` loop goes through four such libraries: the loop body, two wrappers and the
kernel), ~a third in the parfor passes and the loop bodies typed and lowered a second time as
gufuncs, the rest in numba's other passes. Without ``parallel=True`` the group would compile
in about half the time, but the pixel loops need their threads. Measured and removed:
numba's comparison of compiler flags (``raytrace._jit.fast_flag_comparison``), parallel loops
that numba made of array initialisations (``np.zeros``, slice assignment) and reductions
inside kernels, numba's uncached generic sort in ``raytrace._kernels.cull_mask``, and
signatures compiled twice for one kernel.

The groups (``raytrace/_jit_signatures.py``): ``fast``, the kernels the frames of the main job
call (:data:`SIGNATURES`); then, each holding only what the one before did not compile,
``balanced`` (a ``--quality balanced`` frame), ``batched`` (the same frame through the
batched fallback, :data:`raytrace.presets.FUSED_GATHER` and
:data:`raytrace.presets.CAST_IN_ONE_KERNEL` False: what a machine whose embreex wheel has no
Embree 4 library runs) and ``reference``. Regenerate them after changing a
kernel's arguments::

    python benchmarks/record_kernel_signatures.py

which runs the groups' frames in a fresh process with an empty numba cache and writes each
kernel's signatures and its own compile time in CPU seconds (the time orders the compile and
measures its progress).
"""

from __future__ import annotations

import importlib
import os
import sys
import time
import types


def _namespace() -> dict:
    """Names of numba's types, for reading back the recorded signatures (``repr`` of each)."""
    from numba.core import types
    ns = {k: getattr(types, k) for k in dir(types) if not k.startswith("_")}
    ns["bool"] = types.boolean
    return ns


def signature_types(sig: str) -> tuple:
    """The tuple of numba types a recorded signature string stands for."""
    return eval(sig, {"__builtins__": {}}, _namespace())  # noqa: S307 (our own file's reprs)


def kernel(qualname: str):
    """The object ``module.function`` of a recorded entry: a numba dispatcher, or a kernel
    built twice (``raytrace._jit.ThreadedKernel`` and its mirror in ``degrade``)."""
    module, _, name = qualname.rpartition(".")
    return getattr(importlib.import_module(module), name)


def dispatcher(qualname: str, serial: bool = False):
    """The numba dispatcher of a recorded entry: of a kernel built twice, its serial build
    (``serial``: what a process whose numba threads are one calls) or its parallel one."""
    obj = kernel(qualname)
    return obj.build(serial) if _threaded(obj) else obj


def _threaded(obj) -> bool:
    """Whether ``obj`` is a kernel built twice (duck-typed: ``degrade`` has its own class)."""
    return callable(getattr(obj, "build", None)) and hasattr(obj, "serial") and hasattr(obj, "parallel")


def _compile_share(items: list, serial: bool = False) -> list:
    """Compile (into the on-disk cache) the recorded signatures of ``items`` = [(qualname,
    signatures)], of the kernels' serial or parallel builds; returns the entries that could
    not be compiled, with the reason."""
    from . import _jit  # noqa: F401 (numba's faster flag comparison, also for degrade's kernels)
    failed = []
    for qualname, sigs in items:
        for sig in sigs:
            try:
                dispatcher(qualname, serial).compile(signature_types(sig))
            except Exception as exc:  # a stale entry: it compiles on first call instead
                failed.append(f"{qualname}{sig}: {type(exc).__name__}")
    return failed


def _code_objects(code):
    """``code`` and the code objects nested in it (comprehensions, closures)."""
    yield code
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            yield from _code_objects(c)


def _named_dispatchers(disp, seen: set) -> set:
    """qualnames of the numba dispatchers the Python source of ``disp`` names (as globals or
    as attributes of modules it names), and recursively those they name: what compiling
    ``disp`` compiles too (or loads from the cache), the inlined helpers' callees included. A
    static reading (a name that is never called counts too): good enough for a schedule."""
    from numba.core.registry import CPUDispatcher
    out = set()
    glob = disp.py_func.__globals__
    names = {n for code in _code_objects(disp.py_func.__code__) for n in code.co_names}
    found = [glob[n] for n in names if n in glob]
    found += [getattr(m, n) for m in found if isinstance(m, types.ModuleType) for n in names
              if isinstance(getattr(m, n, None), CPUDispatcher)]
    for obj in found:
        if isinstance(obj, CPUDispatcher) and id(obj) not in seen:
            seen.add(id(obj))
            out.add(f"{obj.py_func.__module__}.{obj.py_func.__name__}")
            out |= _named_dispatchers(obj, seen)
    return out


def dependencies(entries: dict) -> dict:
    """{qualname: the other entries of ``entries`` that compiling it would compile too}: the
    helpers (``brdf_cos``, ``procedural_albedo`` …) that kernels call. :func:`precompile` keeps
    two processes from compiling the same helper at once: shares fixed ahead had both compile
    the helpers their kernels call, ~2 s of the ``fast`` group twice over."""
    deps = {}
    for qualname in entries:
        try:
            named = _named_dispatchers(dispatcher(qualname), set())
        except (ImportError, AttributeError):  # a stale entry: it fails in its worker
            named = set()
        deps[qualname] = named & set(entries) - {qualname}
    return deps


GROUPS = ("fast", "balanced", "batched", "reference")


def group_signatures(groups=("fast",)) -> dict:
    """{qualname: (seconds, [signatures])} of the kernels of ``groups`` (names in
    :data:`GROUPS`), merged: a kernel in several groups gets the union of its signatures and
    the sum of their compile times."""
    from ._jit_signatures import EXTRA_SIGNATURES, SIGNATURES
    out = {}
    for g in groups:
        if g not in GROUPS:
            raise ValueError(f"precompile group must be one of {', '.join(GROUPS)}, got {g!r}")
        for qualname, (cost, sigs) in (SIGNATURES if g == "fast" else EXTRA_SIGNATURES[g]).items():
            c0, s0 = out.get(qualname, (0.0, []))
            out[qualname] = (round(c0 + cost, 2), s0 + [x for x in sigs if x not in s0])
    return out


# modules whose kernels call Embree themselves: they cannot compile (link) where the embreex
# wheel has no Embree 4 library, so none of them may stand for a group (it would never be
# found in the cache, and every run would compile the group again)
_DIRECT_EMBREE = ("raytrace._paths.", "raytrace._embree.")


def probe(group: str) -> str | None:
    """The kernel whose presence in numba's cache stands for ``group`` being compiled: its
    costliest kernel that no earlier group holds and that does not call Embree itself (None if
    it has none such)."""
    earlier = set(group_signatures(GROUPS[:GROUPS.index(group)]))
    own = [(c, q) for q, (c, _) in group_signatures([group]).items()
           if q not in earlier and not q.startswith(_DIRECT_EMBREE)]
    # built twice where it can be: its serial and its parallel build then tell apart
    threaded = [(c, q) for c, q in own if _threaded(kernel(q))]
    own = threaded or own
    return max(own)[1] if own else None


def entries_to_compile(groups=("fast",)) -> dict:
    """:func:`group_signatures` of ``groups``, without the kernels that call Embree themselves
    where the embreex wheel has no Embree 4 library (they could not link; the batched fallback
    runs instead)."""
    from . import _embree
    entries = group_signatures(groups)
    if not _embree.available():
        entries = {q: e for q, e in entries.items() if not q.startswith(_DIRECT_EMBREE)}
    return entries


def load_here(groups=("fast",)) -> list:
    """The kernels of ``groups`` (:func:`entries_to_compile`) in this process, from numba's
    on-disk cache where it holds them (compiled where not), in the build this thread's kernel
    calls run (serial where its numba thread count is 1); returns the entries that failed.
    What a first call would do, done ahead (the CLI's pool workers, while their scenes are
    built)."""
    import numba
    serial = numba.get_num_threads() == 1
    return _compile_share([(qualname, sigs) for qualname, (_, sigs) in entries_to_compile(groups).items()], serial)


def _next_tasks(waiting: list, deps: dict, compiled: set, busy: set, free: int) -> list:
    """[(entry, the entries its task compiles)] to start now, at most ``free``: the first of
    ``waiting`` (in order) none of whose uncompiled entries (itself and what it calls,
    ``deps``) is ``busy`` in a running task, nor taken by one started before it here."""
    out, taken = [], set(busy)
    for q in waiting:
        if len(out) >= free:
            break
        need = ({q} | deps[q]) - compiled
        if not need & taken:
            out.append((q, need))
            taken |= need
    return out


def precompile(processes: int, groups=("fast",), progress=None, serial: bool = False) -> list:
    """Compile the kernels of ``groups`` (see the module notes; :func:`entries_to_compile`) on
    ``processes`` spawned processes, of the kernels built twice the serial builds (``serial``:
    for processes that run one numba thread each) or the parallel ones; returns the entries
    that failed (empty when all compiled).

    One entry per task, the longest first (recorded seconds), as a process frees up; an entry
    waits while a running task compiles one of the helpers it calls (:func:`dependencies`), so
    that each helper is compiled once, within the first kernel that calls it, and the other
    kernels read it from the cache. Within its caller, as a first call compiles it, not on its
    own: numba compiles a helper under flags it partly takes from the kernel calling it (a
    parallel loop's body sets NumPy's error model), and a helper compiled on its own first
    made other code, which gave one pixel of a ``balanced`` frame another last bit.

    ``progress``, if given, is called in this process as each entry finishes, compiled or not,
    with ``(done, total)``: the recorded compile seconds (:mod:`raytrace._jit_signatures`) of
    the entries compiled so far, the helpers a kernel compiled counted with it, and of all of
    them; the last call has ``done == total``."""
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    import multiprocessing
    from ._threads import compile_worker_init, pool_processes
    entries = entries_to_compile(groups)
    if not entries:
        return []
    deps = dependencies(entries)
    total = sum(cost for cost, _ in entries.values())
    workers = max(1, min(processes, len(entries)))
    waiting = sorted(entries, key=lambda q: (-entries[q][0], q))
    compiled, busy, running, failed = set(), set(), {}, []  # running: {future: entries it compiles}
    done_s = 0.0
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=compile_worker_init, initargs=(os.getpid(),))
    try:
        while waiting or running:
            for q, need in _next_tasks(waiting, deps, compiled, busy, workers - len(running)):
                waiting.remove(q)
                running[pool.submit(_compile_share, [(q, entries[q][1])], serial)] = need
                busy |= need
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in finished:
                need = running.pop(fut)
                failed += fut.result()
                busy -= need
                compiled |= need
                done_s += sum(entries[q][0] for q in need)
                if progress is not None:
                    progress(total if not (waiting or running) else min(done_s, total), total)
        return failed
    except KeyboardInterrupt:  # Ctrl-C, or the CLI's SIGTERM: stop compiling now, not in a minute
        # numba writes each cache file under a temporary name and renames it: a compiler killed
        # mid-write leaves no broken entry
        for proc in pool_processes(pool):
            proc.kill()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


if __name__ == "__main__":
    if sys.argv[1:2] in (["--time"], ["--time-serial"]):
        t0 = time.perf_counter()
        bad = precompile(int(sys.argv[2]) if len(sys.argv) > 2 else 2, sys.argv[3:] or ("fast",),
                         serial=sys.argv[1] == "--time-serial")
        print(f"{time.perf_counter() - t0:.1f} s, failed: {bad}")
    else:
        sys.exit("usage: python -m raytrace._precompile --time[-serial] [processes [group ...]] "
                 "(recording: python benchmarks/record_kernel_signatures.py)")
