"""Side threads of the renderer: named thread pools whose tasks run with the caller's numba
thread count; and for process pools, a worker's watch on its parent and the pool's own
processes."""

from __future__ import annotations

import contextlib
import os

import numba

_POOLS = {}


def available_cores() -> int:
    """The CPUs this process may use (its CPU affinity where the system has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


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


@contextlib.contextmanager
def parallel_chunksize(n: int):
    """numba's parallel loops launched inside hand out ``n`` iterations at a time (0: numba's
    static split); the calling thread's previous setting is restored on the way out."""
    old = numba.set_parallel_chunksize(n)
    try:
        yield
    finally:
        numba.set_parallel_chunksize(old)


def exit_with_parent(ppid: int, poll_s: float = 0.5, before_exit=None) -> None:
    """Process-pool initializer (or part of one): a daemon thread ends this worker process when
    its parent ``ppid`` is gone (killed with SIGKILL, crashed), instead of its waiting for tasks
    for ever; ``before_exit()`` runs first (on that thread)."""
    import os
    import threading
    import time

    def watch():
        while os.getppid() == ppid:
            time.sleep(poll_s)
        if before_exit is not None:
            before_exit()
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def exit_now(status: int = 0) -> None:
    """Flush the standard streams that are still open and end this process with ``status``,
    without the interpreter's teardown: its garbage collections over numba's compiled objects
    take ~0.4 s, which a parent waiting for its pool's processes waits for too. For a process
    whose work is done and whose exit handlers have run (status 120 if a stream cannot be
    flushed, as Python's own exit reports it)."""
    import sys
    for stream in (sys.stdout, sys.stderr):  # None where a reader left early (the CLI's dry run)
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # a closed pipe
            status = status or 120
    os._exit(status)


def skip_teardown() -> None:
    """Process-pool initializer (or part of one): once this worker's task loop has returned and
    multiprocessing has cleaned up (its process bootstrap does, before the interpreter exits),
    an exit handler registered after the libraries' own, so run before them, ends it at once
    (:func:`exit_now`)."""
    import atexit
    atexit.register(exit_now)


def compile_worker_init(ppid: int) -> None:
    """The initializer of :func:`raytrace._precompile.precompile`'s processes: they end with
    their parent (:func:`exit_with_parent`) and without the interpreter's teardown."""
    exit_with_parent(ppid)
    skip_teardown()


def pool_processes(pool) -> list:
    """The worker processes of a ``concurrent.futures.ProcessPoolExecutor`` (CPython keeps them
    in ``_processes``; empty where it does not, and the caller's shutdown then waits for them)."""
    return list((getattr(pool, "_processes", None) or {}).values())
