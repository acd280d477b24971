"""Side threads of the renderer: named thread pools whose tasks run with the caller's numba
thread count."""

from __future__ import annotations

import numba

_POOLS = {}


def submit(name: str, workers: int, fn, *args):
    """``fn(*args)`` on the thread pool ``name`` (``workers`` threads, made on first use), with
    the caller's numba thread count: it is thread-local, and a worker process of the CLI that
    shares the cores with others (``cli.py``'s pool initializer) must not run its kernels on
    more threads from a side thread. A task must not wait on tasks of its own pool."""
    pool = _POOLS.get(name)
    if pool is None:
        from concurrent.futures import ThreadPoolExecutor
        pool = _POOLS[name] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"raytrace-{name}")
    threads = numba.get_num_threads()

    def run():
        numba.set_num_threads(threads)
        return fn(*args)

    return pool.submit(run)
