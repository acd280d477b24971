"""A frame's lighting context (``raytrace._context._Context``: the environment's tables and the
radiance cache's solve) in two checkouts: the same bits, and the CPU time of each.

    git worktree add /tmp/old <rev>
    python benchmarks/bench_frame_context.py /tmp/old . [--rounds 7] [--frames 12]
        [--others 3] [--quality fast] [--keep DIR]

One worker process per checkout (this interpreter, that checkout's ``raytrace`` first on
``sys.path``, one numba thread as a worker of a sequence), with the same
``ORBITSYNTH_CACHE_DIR``. Each plans the main job (``--target cassini --pattern spiral``, 48
frames, 1280×960) and the spiral of each other built-in target as ``cli.py`` does, renders
``--frames`` frames of the main job (spread over the sequence) and ``--others`` of each other
target (``cli.render_frame_images``, ``rgb``), and keeps the context of each frame and the
arguments it was built from. The driver then compares, frame by frame and bit for bit, the
rendered radiance (the linear ``rgb`` floats), the cache's solution (``cf``: irradiance, sunlight,
indirect irradiance, outgoing radiance, sweeps) and the environment's tables of the two
checkouts, and times the contexts: per round every frame's context is built once in each
worker (``time.process_time`` around ``_Context(...)``), the two workers one after the other,
the order swapped every frame and round, so both see the same load on a shared machine. Prints
per target the median CPU time of each checkout over its frames and rounds and the median of
the per-frame ratios (B / A), then the same over the main job's frames.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

MAIN = "cassini"


def _frames(target: str, count: int):
    """The tasks of ``count`` frames spread over ``target``'s spiral (the main job's plan)."""
    import cli
    from raytrace.dataset import folder
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(
        ["--target", target, "--pattern", "spiral", "--frames", "48", *QUALITY]))
    tasks, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)
    step = max(1, len(tasks) // count)
    return tasks[::step][:count]


QUALITY: list = []


def _worker(args) -> None:
    """Render the frames, save what the driver compares into ``args.out``, say ``ready``, then
    build frame k's context per line ``k`` of stdin and print its CPU seconds."""
    import time

    import numba
    import numpy as np
    numba.set_num_threads(1)
    import cli
    from raytrace import shade
    from raytrace.targets import BUILTIN_TARGETS
    made, cur = [], {}
    ctx_class, render = shade._Context, shade.render

    def context(*a, **k):
        cur["args"] = (a, k)
        cur["ctx"] = ctx_class(*a, **k)
        return cur["ctx"]

    def rendered(*a, **k):
        frame = render(*a, **k)
        cur["radiance"] = frame.radiance
        return frame

    shade._Context, shade.render = context, rendered
    targets = [MAIN] + [t for t in BUILTIN_TARGETS if t != MAIN]
    for target in targets:
        for task in _frames(target, args.frames if target == MAIN else args.others):
            cur.clear()
            cli.render_frame_images(dict(task, modalities=["rgb"]))
            ctx = cur["ctx"]
            cf = ctx.cf
            np.savez(os.path.join(args.out, f"{len(made):03d}.npz"), radiance=cur["radiance"],
                     irradiance=cf.irradiance_W_m2, sun=cf.sun_irradiance_W_m2, indirect=cf.indirect_W_m2,
                     radiance_out=cf.radiance_out, iterations=cf.iterations, env_irradiance=ctx.env_irradiance,
                     glossy_env=ctx.glossy_env)
            made.append((target, cur["args"]))
    shade._Context, shade.render = ctx_class, render
    import raytrace
    print("ready", Path(raytrace.__file__).parent, " ".join(t for t, _ in made), flush=True)
    for line in sys.stdin:
        a, k = made[int(line)][1]
        t0 = time.process_time()
        ctx_class(*a, **k)
        print(f"{time.process_time() - t0:.6f}", flush=True)


def _identical(a: Path, b: Path) -> list:
    """The arrays of two workers' frame files that differ in any bit."""
    import numpy as np
    with np.load(a) as x, np.load(b) as y:
        return [k for k in x.files if x[k].shape != y[k].shape or x[k].dtype != y[k].dtype
                or x[k].tobytes() != y[k].tobytes()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("trees", nargs="*", help="checkout A (the reference), checkout B")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--frames", type=int, default=12, help="frames of the main job")
    ap.add_argument("--others", type=int, default=3, help="frames of each other built-in target")
    ap.add_argument("--quality", default="fast")
    ap.add_argument("--keep", default=None, help="folder for the frames' arrays (default: a temporary one)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    QUALITY[:] = ["--quality", args.quality]
    if args.worker:
        sys.path.insert(0, os.getcwd())
        _worker(args)
        return
    if len(args.trees) != 2:
        ap.error("give two checkouts: A (the reference) and B")
    base = Path(args.keep or tempfile.mkdtemp(prefix="bench-context-"))
    workers, outs = [], []
    for name, tree in zip("AB", args.trees):
        out = base / name
        out.mkdir(parents=True, exist_ok=True)
        outs.append(out)
        env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
        workers.append(subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--worker", "--out", str(out), "--frames",
             str(args.frames), "--others", str(args.others), "--quality", args.quality],
            cwd=str(Path(tree).resolve()), env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True))
    names = None
    for name, w in zip("AB", workers):
        line = w.stdout.readline().split()
        if not line or line[0] != "ready":
            sys.exit(f"worker {name} failed")
        print(f"{name}: {line[1]}")
        names = line[2:]
    files = sorted(p.name for p in outs[0].glob("*.npz"))
    differ = {f: _identical(outs[0] / f, outs[1] / f) for f in files}
    same = sum(not d for d in differ.values())
    print(f"bit for bit: {same} of {len(files)} frames identical (radiance, cache solution, environment tables)")
    for f, d in differ.items():
        if d:
            print(f"  frame {f} ({names[int(f[:3])]}): {', '.join(d)} differ")
    times = {k: ([], []) for k in range(len(names))}
    for r in range(args.rounds):
        for k in range(len(names)):
            order = (0, 1) if (r + k) % 2 == 0 else (1, 0)
            for i in order:
                workers[i].stdin.write(f"{k}\n")
                workers[i].stdin.flush()
                times[k][i].append(float(workers[i].stdout.readline()))
    for w in workers:
        w.stdin.close()
        w.wait()
    print(f"CPU time of _Context per frame, one numba thread, {args.quality}, {args.rounds} rounds interleaved:")
    print(f"{'target':12s} {'frames':>6s} {'A ms':>8s} {'B ms':>8s} {'B/A (median of frames)':>24s}")
    for target in dict.fromkeys(names):
        ks = [k for k in range(len(names)) if names[k] == target]
        a = statistics.median(t for k in ks for t in times[k][0]) * 1e3
        b = statistics.median(t for k in ks for t in times[k][1]) * 1e3
        ratio = statistics.median(statistics.median(times[k][1]) / statistics.median(times[k][0]) for k in ks)
        print(f"{target:12s} {len(ks):6d} {a:8.1f} {b:8.1f} {ratio:24.3f}")


if __name__ == "__main__":
    main()
