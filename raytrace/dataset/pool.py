"""The worker pool: frames on a pool of processes (or a dask cluster), its workers' stop on a
signal or when their parent dies, the termination signals of the parent, and the worker count
that fits in memory.

Frames are independent and seeded per frame, so the output is the same for one worker, many,
or a cluster. The pool's processes are spawned; each shares the cores with the others
(:func:`frame_threads`). On Ctrl-C, SIGTERM or SIGHUP (:class:`Terminated`) the workers are
stopped, their frames in flight abandoned without leaving temporary files.
"""

from __future__ import annotations

import contextlib
import functools
import os
import time

from . import UsageError, jit, scenes, warn
from .._threads import available_cores

# A pool's workers load the scenes (BVH aside) and radiance caches this process built once on
# every core (scenes.prebuild_scenes) rather than each building its own; False: each builds its own.
PREBUILD_SCENES = True

_IN_POOL_WORKER = False  # set in the pool's worker processes
_IN_FRAME = False  # run_frame is running (in a worker: what _abandon_frame waits for)
_WORKER_STOPPING = False
_PARENT_POLL_S = 0.5
_STOP_GRACE_S = 30.0  # a worker whose parent died exits by then even if its frame has not let go


def _worker_init(threads: int) -> None:
    """Process-pool initializer: share the cores between the workers; stop on SIGINT or
    SIGTERM (:func:`_worker_stop`) and when the parent is gone (:func:`_abandon_frame`); at the
    pool's shutdown, end without the interpreter's teardown (:func:`raytrace._threads.skip_teardown`)."""
    import signal
    global _IN_POOL_WORKER
    _IN_POOL_WORKER = True
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _worker_stop)
    from .._threads import exit_with_parent, skip_teardown
    exit_with_parent(os.getppid(), _PARENT_POLL_S, _abandon_frame)
    skip_teardown()
    try:
        import numba
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    except Exception as exc:  # noqa: BLE001 - a thread count is an optimisation, never an error
        warn(f"could not set the worker's thread count ({exc})")


def _worker_stop(signum, frame) -> None:
    """A pool worker's SIGINT or SIGTERM (Ctrl-C reaches the whole process group; the parent
    stops its pool on SIGTERM; a batch scheduler may signal every process): the frame in flight
    is abandoned where it stands, its temporary files removed on the way out
    (:func:`raytrace.files.atomic_write_image`), then :func:`run_frame` exits the worker. Once:
    a second signal must not interrupt that clean-up (it stays handled, as a no-op: a handler
    set to SIG_IGN while the signal is pending makes Python raise OSError)."""
    global _WORKER_STOPPING
    if _WORKER_STOPPING:
        return
    _WORKER_STOPPING = True
    raise KeyboardInterrupt


def _abandon_frame() -> None:
    """In a pool worker whose parent is gone (killed with SIGKILL, crashed; run by
    :func:`raytrace._threads.exit_with_parent` before the worker exits, instead of its waiting
    for its next task for ever with the target's scene in memory): stop as on SIGTERM and wait
    until the frame in flight has removed its temporaries."""
    import signal
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + _STOP_GRACE_S
    time.sleep(0.05)  # the main thread takes the signal at its next bytecode
    while _IN_FRAME and time.monotonic() < deadline:  # the abandoned frame removes its temporaries
        time.sleep(0.05)


def run_frame(frame_fn, task: dict):
    """``frame_fn(task)``, in a pool worker or this process. A pool worker told to stop
    (:func:`_worker_stop`) abandons its frame, and exits rather than start the frame already
    queued for it."""
    global _IN_FRAME
    if _IN_POOL_WORKER and _WORKER_STOPPING:
        os._exit(1)
    _IN_FRAME = True
    try:
        return frame_fn(task)
    finally:
        _IN_FRAME = False


def default_workers() -> int:
    """All cores this process may use."""
    return available_cores()


IN_PROCESS_FRAMES = 8
"""At most this many frames (and no ``--workers`` given) render in this process on numba's
threads rather than on a pool: each of a pool's workers first spends ~2 CPU s importing the
libraries and loading numba's kernels, which this process does once. The main job's Cassini
frames on 2 cores, this process against 2 workers: 4 frames 4.9 / 6.0 s, 8 frames 5.8 / 7.2 s,
16 frames 10.2 / 10.3 s (even), 48 frames 24.5 / 20.5 s (2026-12-06, docs/performance.md,
"Fixed cost")."""


def in_process(tasks: list, workers: int, quality: str) -> bool:
    """Whether ``tasks`` render faster in this process than on ``workers`` pool processes: few
    frames (:data:`IN_PROCESS_FRAMES`) and numba's cache already holding the kernels' parallel
    builds this process calls (else compiling them would cost more than the pool saves). The
    frames are the same bytes either way."""
    if workers <= 1 or len(tasks) <= 1:
        return True
    return len(tasks) <= IN_PROCESS_FRAMES and not jit.kernels_not_compiled(quality, serial=False)


def frame_threads(workers: int, tasks: int) -> int:
    """The numba threads each frame of :func:`execute` runs on: the pool's workers share the
    cores; one worker (or one frame) renders in this process, on numba's threads."""
    import numba
    if workers <= 1 or tasks <= 1:
        return numba.config.NUMBA_NUM_THREADS
    return max(1, min(default_workers() // min(workers, tasks), numba.config.NUMBA_NUM_THREADS))


@contextlib.contextmanager
def _prebuild_threads(threads: int, quality: str):
    """The threads :func:`raytrace.dataset.scenes.prebuild_scenes` runs on here: all of numba's, unless the workers run
    one each (the kernels' serial builds) and numba's cache lacks the parallel builds (a fresh
    install): then the serial builds the workers use, rather than compiling the parallel ones
    for this alone (their recorded compile times, ``_jit_signatures.py``, add up to over 10 CPU
    s), with the cache's chunks of rays and the split-sum table's halves side by side on the
    cores (``raytrace._jit.serial_builds``; the built-in targets' caches 0.61× the time on one
    thread, BENCHMARKS.md "Building the radiance cache"). The same scene and cache either way
    (``raytrace._jit.ThreadedKernel``)."""
    if threads != 1 or not jit.kernels_not_compiled(quality, serial=False):
        yield
        return
    from .._jit import serial_builds
    with serial_builds(default_workers()):
        yield


SCHEDULER_TIMEOUT_S = 10.0
"""How long :func:`connect_scheduler` tries to reach ``--scheduler`` before giving up."""


def connect_scheduler(scheduler: str):
    """A dask.distributed client of ``--scheduler``, connected before anything is written (a
    scheduler that cannot be reached within :data:`SCHEDULER_TIMEOUT_S` leaves no folder behind)."""
    try:
        from distributed import Client
    except ImportError:
        raise UsageError("--scheduler needs dask.distributed: pip install 'orbitsynth[dask]'") from None
    try:
        return Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--scheduler: cannot connect to {scheduler} ({exc})") from None


def execute(tasks: list, frame_fn, *, workers: int, progress=None, client=None, ready=None):
    """Run ``frame_fn`` on every task (:func:`run_frame`): in this process (1 worker), on a pool
    of ``workers`` spawned processes, or on a dask.distributed cluster (``client``, connected by
    :func:`connect_scheduler`); yields results as they complete and advances ``progress`` (a
    tqdm bar) by one per frame. ``frame_fn`` must be picklable (a module-level function); so
    must ``ready``, queued once per pool worker ahead of the frames while this process builds
    the scenes (:data:`PREBUILD_SCENES`), to load what a first frame would otherwise wait for."""
    if not tasks:
        return
    if client is not None:
        from distributed import as_completed
        for fut in as_completed(client.map(functools.partial(run_frame, frame_fn), tasks, pure=False)):
            res = fut.result()
            if progress is not None:
                progress.update(1)
            yield res
        return
    if workers <= 1 or len(tasks) == 1:
        if PREBUILD_SCENES:  # the persistent cache's scenes (or this process's, stored there)
            prebuilt = scenes.prebuild_scenes(tasks, None)
            tasks = [dict(t, prebuilt=prebuilt.get(t["model_spec"])) for t in tasks]
        for task in tasks:
            res = run_frame(frame_fn, task)
            if progress is not None:
                progress.update(1)
            yield res
        return
    import multiprocessing
    import shutil
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    n = min(workers, len(tasks))
    threads = frame_threads(workers, len(tasks))
    pool = ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(threads,))
    folder = None
    try:
        # the workers start and import while this process builds the scenes they will load
        readied = [pool.submit(ready) for _ in range(n)] if ready is not None else []
        if PREBUILD_SCENES:
            import pickle
            from ..files import process_folder
            try:
                folder = process_folder(_SCENES_FOLDER)
                with _prebuild_threads(threads, tasks[0]["cfg"]["render"]["quality"]):
                    prebuilt = scenes.prebuild_scenes(tasks, folder)
            except (OSError, pickle.PicklingError) as exc:  # e.g. no room in the temporary folder
                warn(f"the workers build their own scenes ({exc})")
                prebuilt = {}
            tasks = [dict(t, prebuilt=prebuilt.get(t["model_spec"])) for t in tasks]
        # the frames queued behind the ready calls, not after them all: a worker that is ready
        # starts rendering while the other still loads (a failed ready call raises as it ends)
        frames = {pool.submit(run_frame, frame_fn, t) for t in tasks}
        pending = frames | set(readied)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                res = fut.result()
                if fut not in frames:
                    continue
                if progress is not None:
                    progress.update(1)
                yield res
    except BaseException as exc:  # Ctrl-C or Terminated, or what failed as it unwound the wait
        if interruption(exc) is not None:
            _stop_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)


_SCENES_FOLDER = "orbitsynth-scenes-"  # + host.pid-XXXXXXXX in the temporary directory


def remove_stale_scene_folders() -> None:
    """Delete the pools' scene folders (:func:`execute`) of runs that were killed before they
    could (SIGKILL, a crash): every run does it as it starts, whatever it renders and on how
    many workers, so a killed run's ~100 MB never outlive the next run."""
    try:
        from ..files import remove_stale_process_folders
        remove_stale_process_folders(_SCENES_FOLDER)
    except OSError:
        pass


def _stop_workers(pool) -> None:
    """Stop the pool's workers now (an interrupt): pending frames cancelled,
    each worker sent SIGTERM (it abandons its frame, removes that frame's temporary files and
    exits: :func:`_worker_stop`), and killed if it has not exited within _STOP_GRACE_S."""
    import signal
    from .._threads import pool_processes
    # the pool's own processes, not multiprocessing.active_children(): cli.main may run inside a
    # program with children of its own
    procs = pool_processes(pool)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            os.kill(p.pid, signal.SIGTERM)
        except OSError:
            pass
    deadline = time.monotonic() + _STOP_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()


FRAME_BYTES_PER_PIXEL = 160
"""Peak memory of one worker per pixel of its frame [bytes]: measured 137–139 B/px (peak RSS of a
one-frame run with one worker, 320×240 to 2560×1920, ``fast`` and ``balanced``, default
modalities and ``physical`` degradation), with room on top."""

WORKER_BASE_BYTES = 700 << 20
"""Peak memory of one worker besides its frame's pixels (libraries, scene, radiance cache) [bytes]."""


def memory_bytes() -> tuple:
    """(physical memory, memory available now) of this machine [bytes], from /proc/meminfo or
    sysconf; (None, None) where neither tells."""
    try:
        info = {}
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                key, _, rest = line.partition(":")
                info[key] = int(rest.split()[0]) * 1024
        return info["MemTotal"], info.get("MemAvailable", info["MemTotal"])
    except (OSError, KeyError, ValueError, IndexError):
        pass
    try:
        page = os.sysconf("SC_PAGE_SIZE")
        total = os.sysconf("SC_PHYS_PAGES") * page
        try:
            return total, os.sysconf("SC_AVPHYS_PAGES") * page
        except (ValueError, OSError):
            return total, total
    except (ValueError, OSError, AttributeError):
        return None, None


def fit_workers(cameras: list, workers: int) -> int:
    """The worker count whose frames (of the largest of ``cameras``) fit in this machine's
    memory: refuses up front (one line naming --width/--height) a frame that one worker could
    not render in all of it, and lowers ``workers`` (with a warning) where their frames would
    not fit in the memory available now. Frames are byte-identical whatever the worker count."""
    total, available = memory_bytes()
    if total is None or not cameras:
        return workers
    cam = max(cameras, key=lambda c: c.width * c.height)
    # (a distorted camera's table of pixel rays: 16 bytes a pixel more, raytrace.camera.Camera.lens_arrays)
    need = WORKER_BASE_BYTES + (FRAME_BYTES_PER_PIXEL + 16 * cam.distorted) * cam.width * cam.height
    if need > total:
        raise UsageError(f"argument --width/--height: a {cam.width}x{cam.height} frame needs about "
                       f"{need / 2**30:.1f} GiB "
                       f"of memory to render, more than this machine's {total / 2**30:.1f} GiB; render a smaller image "
                       "(or crop it: a longer --focal-length-mm at a smaller size)")
    fit = max(1, int(available // need))
    if fit < workers:
        warn(f"rendering on {fit} worker{'s' if fit > 1 else ''} instead of {workers}: each needs about "
             f"{need / 2**30:.1f} GiB for a {cam.width}x{cam.height} frame and {available / 2**30:.1f} GiB is available")
        return fit
    return workers


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``kill``, a batch scheduler's time limit, a closed terminal), raised in
    the main thread where Ctrl-C raises KeyboardInterrupt, so that the same clean-up runs: the
    pool's workers stopped (:func:`_stop_workers`), frames in flight abandoned without leaving
    temporary files, the pool's temporary scenes deleted. Exit status 128 + the signal."""

    def __init__(self, signum: int):
        import signal
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def _termination_signals() -> list:
    import signal
    return [sig for sig in (getattr(signal, name, None) for name in ("SIGTERM", "SIGHUP")) if sig is not None]


_TERMINATING = False


def _on_termination(signum, frame) -> None:
    global _TERMINATING
    if _TERMINATING:  # once: a second signal must not interrupt the clean-up
        return
    _TERMINATING = True
    raise Terminated(signum)


def install_termination_handlers() -> None:
    """SIGTERM and SIGHUP raise :class:`Terminated` in the main thread (``cli.py`` as a
    program), unless the process was started with them ignored (``nohup``)."""
    import signal
    for sig in _termination_signals():
        if signal.getsignal(sig) == signal.SIG_DFL:
            signal.signal(sig, _on_termination)


def exit_without_teardown(status: int) -> None:
    """End the CLI's process with ``status`` once its command (``cli.main``) has returned: the
    exit handlers run (multiprocessing's among them: its children joined, its semaphores
    released), the standard streams are flushed, then ``os._exit`` skips the interpreter's
    teardown, whose garbage collections over numba's compiled objects were ~0.4 s of every
    command (of a 2-frame main job's ~2.8 s; docs/performance.md, "Fixed cost"). Nothing is left
    to write by then: every file is written and closed, every thread pool idle."""
    import atexit
    from .._threads import exit_now
    atexit._run_exitfuncs()
    exit_now(0 if status is None else int(status))


def interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or :class:`Terminated` behind ``exc``, if any: itself, or one it was raised
    while handling (``__context__``). The signal's exception lands wherever the main thread is,
    and code it interrupts can fail in turn as it unwinds (a lock released twice in
    ``threading``: "release unlocked lock"); that failure is the signal's doing, not the
    render's."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
