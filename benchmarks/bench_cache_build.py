"""Building the radiance cache (``raytrace.cache.RadianceCache``, once per target per process).

    python benchmarks/bench_cache_build.py [--repeats 5] [--targets tiangong cassini ...]

Per built-in target, the seconds of ``Scene.radiance_cache()`` (a fresh ``Scene`` each time,
Embree's BVH built before the clock starts, numba's cache warm), the median of ``--repeats``:

* *Chunks.* The cache rays' chunks two at a time on a side pool against one after the other
  (``raytrace.presets.CAST_CHUNKS_ON_TWO_THREADS``), alternated round by round so a slow spell of
  a shared machine hits both alike; and whether the two caches are the same bits (every
  array, sparse matrix and glossy record).
* ``--serial-builds``: every build on the kernels' serial builds, as a fresh install's first run
  builds the scenes its pool's workers wait for (``raytrace._jit.serial_builds``: the chunks
  two at a time each on one numba thread, against one after the other on one thread, what that
  run did before).
* *Lattice merge.* The merge of lattice points into samples (distinct rows of component, cell
  and normal cell), on the keys of that target's two lattices: ``raytrace.cache._row_ids`` (one
  int64 per row, a 1-d sort) against ``np.unique(key, axis=0, return_inverse=True)`` (what it
  replaced), and whether the ids are equal.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from raytrace import cache as cache_module, presets  # noqa: E402
from raytrace.scene import Scene  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS, load_target  # noqa: E402


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if sp.issparse(a):
        return all(np.array_equal(getattr(a, p), getattr(b, p)) for p in ("indptr", "indices", "data"))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    return a == b


def _members(c) -> list[str]:
    return [k for k in dir(c) if not k.startswith("__") and k != "scene" and not callable(getattr(c, k))]


SERIAL_BUILDS = False  # --serial-builds


def _build(model, two: bool):
    import contextlib

    from raytrace._jit import serial_builds
    presets.CAST_CHUNKS_ON_TWO_THREADS = two
    scene = Scene(model)
    scene.embree  # the BVH is not the cache's
    with serial_builds(2) if SERIAL_BUILDS else contextlib.nullcontext():
        t0 = time.perf_counter()
        cache = scene.radiance_cache()
        return time.perf_counter() - t0, cache


def _lattice_keys(model) -> list[np.ndarray]:
    keys = []
    original = cache_module._row_ids

    def record(key):
        keys.append(np.array(key))
        return original(key)

    cache_module._row_ids = record
    try:
        Scene(model).radiance_cache()
    finally:
        cache_module._row_ids = original
    return keys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--targets", nargs="+", default=list(BUILTIN_TARGETS), choices=list(BUILTIN_TARGETS))
    ap.add_argument("--serial-builds", action="store_true", help="the kernels' serial builds, as a fresh install's "
                    "first run builds its scenes")
    args = ap.parse_args(argv)
    global SERIAL_BUILDS
    SERIAL_BUILDS = args.serial_builds
    saved = presets.CAST_CHUNKS_ON_TWO_THREADS
    ratios = []
    print("| target | rows | one after the other, s | two at a time, s | ratio | same bits | merge, np.unique(axis=0) s"
          " | merge, packed s | same ids |")
    print("|---|---|---|---|---|---|---|---|---|")
    try:
        for name in args.targets:
            model = load_target(name)
            _build(model, True)  # warm-up: numba's cache, page faults
            times = {True: [], False: []}
            last = {}
            for r in range(args.repeats):
                for two in ((True, False) if r % 2 == 0 else (False, True)):
                    t, last[two] = _build(model, two)
                    times[two].append(t)
            same = all(_same(getattr(last[True], k), getattr(last[False], k)) for k in _members(last[False]))
            t1, t2 = statistics.median(times[False]), statistics.median(times[True])
            ratios.append(t2 / t1)
            t_np = t_pk = 0.0
            same_ids = True
            for key in _lattice_keys(model):
                t0 = time.perf_counter()
                ref = np.unique(key, axis=0, return_inverse=True)[1].ravel()
                t_np += time.perf_counter() - t0
                t0 = time.perf_counter()
                ids = cache_module._row_ids(key)
                t_pk += time.perf_counter() - t0
                same_ids &= bool(np.array_equal(ids, ref))
            print(f"| {name} | {last[True].n_rows} | {t1:.2f} | {t2:.2f} | {t2 / t1:.3f} | {same} | {t_np:.3f} | "
                  f"{t_pk:.3f} | {same_ids} |", flush=True)
    finally:
        presets.CAST_CHUNKS_ON_TWO_THREADS = saved
    print(f"\nmedian ratio two at a time / one after the other: {statistics.median(ratios):.3f} "
          f"({min(ratios):.3f}–{max(ratios):.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
