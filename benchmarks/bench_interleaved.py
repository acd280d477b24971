"""Two versions of the renderer timed side by side, their renders interleaved.

    git worktree add /tmp/old <rev>
    python benchmarks/bench_interleaved.py /tmp/old . [--preset fast] [--samples N]
        [--threads N] [--repeats 7] [--targets ...] [--views ...] [--width 1280]
    python benchmarks/bench_interleaved.py . . --env-a NUMBA_THREADING_LAYER=omp
        --env-b NUMBA_THREADING_LAYER=tbb      (two settings of one checkout)

One worker process per checkout (this interpreter, with that checkout's ``raytrace`` first on
``sys.path``) loads the 12 scenes of ``benchmarks/bench_time_error.py`` (this script's, written
with the checkout's targets) and renders one frame when asked. The driver asks them in turn, one render at a time, the order swapped every
repeat, so the two versions see the same load: on a shared machine whose speed drifts by tens
of per cent within an hour, runs of one version after the other compare the hours, not the
code. Per scene it prints the faster render of each version and their ratio (B / A), then the
median of the per-scene ratios, and the medians over the scenes of each version's fastest and
median renders. ``--threads 1`` times a frame as one worker of a sequence renders it; the
default is numba's thread count (one frame on every core).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _worker(args) -> None:
    """Load the scenes, say ``ready``, where ``raytrace`` comes from and numba's threading
    layer, then render ``target view`` per line of stdin and print the seconds."""
    import numba

    from bench_time_error import scene_frames
    from raytrace.shade import render
    if args.threads:
        numba.set_num_threads(args.threads)
    poses = {}
    for target, view, _path, pose in scene_frames(Path(args.scenes), args.width, args.targets, args.views,
                                                        per_target=True):
        poses[target, view] = pose
        render(*pose, quality=args.preset, samples=args.samples, seed=1)  # warm-up
    import raytrace
    layer = numba.threading_layer()
    print(f"ready {Path(raytrace.__file__).parent} (numba's {layer} threading layer)", flush=True)
    for line in sys.stdin:
        target, view = line.split()
        t0 = time.perf_counter()
        render(*poses[target, view], quality=args.preset, samples=args.samples, seed=1)
        print(f"{time.perf_counter() - t0:.6f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("trees", nargs="*", help="checkout A (the reference), checkout B")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--samples", type=int, default=None)
    ap.add_argument("--threads", type=int, default=0, help="numba threads per render (0: numba's default)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--targets", nargs="*", default=None, help="default: the four built-in targets")
    ap.add_argument("--views", nargs="*", default=None, help="default: the three views of bench_time_error.py")
    ap.add_argument("--scenes", default=None, help="folder for the scene files (default: a temporary one)")
    ap.add_argument("--env-a", nargs="*", default=[], metavar="KEY=VALUE",
                    help="environment variables of A's worker (e.g. NUMBA_THREADING_LAYER=omp)")
    ap.add_argument("--env-b", nargs="*", default=[], metavar="KEY=VALUE", help="and of B's")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    # before anything of raytrace is imported: a worker's working directory is its checkout,
    # whose raytrace comes first; the scenes are this script's (bench_time_error.py beside it)
    here = Path(__file__).resolve().parent
    sys.path[:0] = [os.getcwd() if args.worker else str(here.parent), str(here)]
    import raytrace  # noqa: F401 (bound to that checkout before bench_time_error puts its own first)
    from bench_time_error import viewpoints

    from raytrace.targets import BUILTIN_TARGETS
    args.targets = args.targets or list(BUILTIN_TARGETS)
    args.views = args.views or [v[0] for v in viewpoints()]
    if args.worker:
        _worker(args)
        return
    if len(args.trees) != 2:
        ap.error("give two checkouts: A (the reference) and B")
    import tempfile
    scenes = args.scenes or tempfile.mkdtemp(prefix="interleaved-")
    opts = ["--preset", args.preset, "--threads", str(args.threads), "--width", str(args.width),
            "--targets", *args.targets, "--views", *args.views]
    if args.samples is not None:
        opts += ["--samples", str(args.samples)]
    # each worker writes its checkout's scenes into a folder of its own (write_scene rewrites
    # the files: two workers on one folder would read each other's half-written meshes)
    def env(pairs):
        e = dict(os.environ)
        for kv in pairs:
            key, sep, value = kv.partition("=")
            if not sep or not key:
                ap.error(f"--env-a/--env-b take KEY=VALUE, got {kv!r}")
            e[key] = value
        return e

    procs = [subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", *opts, "--scenes",
                               str(Path(scenes).resolve() / name)],
                              cwd=str(Path(tree).resolve()), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env=env(pairs))
             for name, tree, pairs in zip("AB", args.trees, (args.env_a, args.env_b))]
    for p, name, tree in zip(procs, "AB", args.trees):
        said = p.stdout.readline().split()
        if not said or said[0] != "ready":
            sys.exit(f"the worker of {tree} did not start")
        print(f"# {name}: {' '.join(said[1:])}", flush=True)
    times = {}
    for target in args.targets:
        for view in args.views:
            times[target, view] = ([], [])
            for r in range(args.repeats):
                for i in ((0, 1) if r % 2 == 0 else (1, 0)):
                    procs[i].stdin.write(f"{target} {view}\n")
                    procs[i].stdin.flush()
                    times[target, view][i].append(float(procs[i].stdout.readline()))
    for p in procs:
        p.stdin.close()
        p.wait()
    ratios = []
    for (target, view), (a, b) in times.items():
        ratios.append(min(b) / min(a))
        print(f"{target:12s} {view:8s} A {1e3 * min(a):8.1f} ms  B {1e3 * min(b):8.1f} ms  B/A {ratios[-1]:.3f}"
              f"  (medians {1e3 * statistics.median(a):.1f} / {1e3 * statistics.median(b):.1f} ms)")
    fastest = [statistics.median(min(t[i]) for t in times.values()) for i in (0, 1)]
    medians = [statistics.median(statistics.median(t[i]) for t in times.values()) for i in (0, 1)]
    print(f"{args.preset}{'' if args.samples is None else f'-{args.samples}'}: median of the per-scene ratios B/A "
          f"{statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}); over the scenes, fastest renders "
          f"A {1e3 * fastest[0]:.1f} / B {1e3 * fastest[1]:.1f} ms, median renders A {1e3 * medians[0]:.1f} / "
          f"B {1e3 * medians[1]:.1f} ms")


if __name__ == "__main__":
    main()
