"""The first run's kernel compilation: which numba kernels a frame calls, whether numba's
on-disk cache holds them, and compiling the missing ones on every core at once before the
frames start (instead of each worker compiling all of them on its first frame)."""

from __future__ import annotations

import os
import sys

from .._threads import available_cores

def precompile_groups(quality: str) -> list:
    """The kernel groups of raytrace._precompile a ``quality`` frame calls: the main job's, the
    preset's own, and for ``balanced`` on an embreex wheel without Embree 4 the batched
    fallback's."""
    groups = ["fast"]
    if quality == "balanced":
        from .. import _embree
        groups += ["balanced"] if _embree.available() else ["balanced", "batched"]
    elif quality == "reference":
        groups.append("reference")
    return groups


def kernels_not_compiled(quality: str = "fast", serial: bool = False) -> list:
    """The groups of :func:`precompile_groups` whose kernels numba's on-disk cache does not
    hold yet, in their serial builds (``serial``: for processes on one numba thread each) or
    their parallel ones (a fresh install, a new NUMBA_CACHE_DIR, a first ``balanced`` run):
    judged by the cache index of one kernel per group, where numba's own cache locator puts it
    (next to the source when writable, else the user's cache directory). Empty if numba's
    cache internals cannot be read (no guess then)."""
    try:
        from .._precompile import dispatcher, probe
        missing = []
        for group in precompile_groups(quality):
            name = probe(group)
            if name is not None and not os.path.exists(dispatcher(name, serial)._cache._cache_file._index_path):
                missing.append(group)
        return missing
    except Exception:  # noqa: BLE001 (numba internals of another version)
        return []


SERIAL_COMPILE_RATIO = 0.57
"""Compile time of the kernels' serial builds over their parallel builds' (which
``raytrace/_jit_signatures.py`` records): the ``fast`` group, CPU seconds of the two compiling
processes, 40.3 against 70.2 (``python -m raytrace._precompile --time-serial 2 fast`` and
``--time 2 fast``, medians of 3 alternated, 2-core AMD EPYC; BENCHMARKS.md)."""


def compile_kernels(groups: list, quiet: bool, serial: bool = False) -> None:
    """A fresh install (or a preset's first run): compile the numba kernels of ``groups``, in
    the builds the frames will call (``serial``: the pool's workers run one numba thread each),
    into numba's cache on all cores at once (:func:`raytrace._precompile.precompile`), before
    the workers start and would each compile all of them, under a progress bar: its unit is
    the kernels' recorded compile time, so its rate and remaining time are measured on this
    machine as it goes. A kernel this misses compiles on its first call, as it would anyway."""
    processes = max(1, min(available_cores(), 4))
    try:
        from .._precompile import group_signatures
        total = float(sum(c for c, _ in group_signatures(groups).values()))
    except Exception:  # noqa: BLE001 (the estimate only)
        total = 0.0
    if not quiet:
        seconds = total * (SERIAL_COMPILE_RATIO if serial else 1.0) / processes
        about = f"about {5 * max(1, round(seconds / 5))} s on idle cores" if total else "a minute or two"
        print(f"first run: compiling the ray-tracing kernels ({', '.join(groups)}) into numba's cache, once, on "
              f"{processes} core{'s' if processes > 1 else ''} ({about}; the bar measures it as it goes)",
              file=sys.stderr)
    from tqdm import tqdm
    bar = tqdm(total=total or None, desc="compiling", disable=quiet, file=sys.stderr, dynamic_ncols=True,
               mininterval=0.5, bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed} elapsed, {remaining} left")

    def progress(done: float, _total: float) -> None:
        bar.update(done - bar.n)

    try:
        from .._precompile import precompile
        precompile(processes, groups, progress=progress, serial=serial)
    except Exception:  # noqa: BLE001 (an optimisation: without it the kernels compile lazily)
        pass
    finally:
        bar.close()
