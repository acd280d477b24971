"""The main job's fixed cost: its stages one by one, and whole runs of the main job, for this tree
and others (e.g. a worktree of an older commit), interleaved.

    python benchmarks/bench_fixed_cost.py [--repeats 5] [--trees . /tmp/base] [--frames 2 48]
                                          [--stages-only | --runs-only] [--shading]

Stages: each in a fresh process on one numba thread, as in a pool's worker, with the tree on
``PYTHONPATH`` and numba's cache warm: importing ``cli``; ``cli.plan_sequence`` of the main job
(``--target cassini --pattern spiral``); the scenes for the workers
(``raytrace.dataset.scenes.prebuild_scenes``, into a temporary folder; with the persistent cache
(``ORBITSYNTH_CACHE_DIR``, a folder of this run's) warm where the tree has one); a worker's start
(``cli._worker_ready``: imports, numba's kernels loaded, the split-sum table); its first and
second frame (``cli.render_frame_images`` of the planned tasks, images not written), the first
loading the scene another process built, as a pool's worker does. Runs:
``python cli.py --target cassini --pattern spiral --frames N --quiet`` into a temporary folder,
caches warm. ``--shading`` adds, in the same rounds, the shading alone of the same N frames
(``raytrace.shade.render`` on two forked processes of one numba thread each, warmed by one frame; no
degradation, encoding or files) and prints the marginal cost per frame of both (the two largest N)
and their ratio. Every repetition runs each tree once, in turn (rotated), so a shared machine's load
falls on all alike. Prints per stage and tree the median wall and CPU seconds, and per run the
median wall time and CPU time (the run's and its workers') with their ratios to the first tree's:
on a loaded machine the CPU times are the steadier figure.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

STAGES = r"""
import json, os, sys, time, tempfile
def clock():
    return time.perf_counter(), time.process_time()
out = {}
def lap(name, t):
    w, c = clock()
    out[name] = (w - t[0], c - t[1])
    return clock()
t = clock()
import numba
numba.set_num_threads(1)
import cli
t = lap("import cli", t)
from raytrace.dataset import folder, scenes
cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral",
                                                               "--frames", "48"]))
plan = cli.plan_sequence(cfg, given)
t = lap("plan_sequence", t)
tasks, _ = folder.tasks_for(plan, "", None, write=False)
with tempfile.TemporaryDirectory() as tmp:
    prebuilt = scenes.prebuild_scenes(tasks[:2], tmp)
t = lap("prebuild_scenes", t)
print(json.dumps(out))
"""

PREBUILD = r"""
import json, sys
import cli
from raytrace.dataset import folder, scenes
cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral",
                                                               "--frames", "48"]))
tasks, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)
print(json.dumps({"path": scenes.prebuild_scenes(tasks[:1], sys.argv[1])[tasks[0]["model_spec"]]}))
"""

# a pool's worker: it loads the scene a parent process built (PREBUILD, another process), as in a run
WORKER = r"""
import json, sys, time
t = time.perf_counter(), time.process_time()
import numba
numba.set_num_threads(1)
import cli
cli._worker_ready("fast")
out = {"worker start": (time.perf_counter() - t[0], time.process_time() - t[1])}
from raytrace.dataset import folder, scenes
cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral",
                                                               "--frames", "48"]))
plan = cli.plan_sequence(cfg, given)
tasks, _ = folder.tasks_for(plan, "", None, write=False)
for name, task in zip(("first frame", "second frame"), tasks[:2]):
    t = time.perf_counter(), time.process_time()
    cli.render_frame_images(dict(task, prebuilt=sys.argv[1]))
    out[name] = (time.perf_counter() - t[0], time.process_time() - t[1])
print(json.dumps(out))
"""


# the shading alone of the main job's first N frames: two forked processes on one numba thread
# each (as the CLI's two workers), each warmed by one frame, then the frames shared out one at a
# time; no degradation, no encoding, no files. Prints the wall seconds of the N frames.
SHADING = r"""
import json, multiprocessing as mp, sys, time
N, PREBUILT = int(sys.argv[1]), sys.argv[2]

def init(barrier):
    global TASKS, render
    import numba
    numba.set_num_threads(1)
    import numpy as np
    import cli
    from raytrace.camera import Camera
    from raytrace.dataset import folder, scenes
    from raytrace.shade import render as shade_render
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral",
                                                                   "--frames", str(max(N, 2))]))
    TASKS, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)

    def render(i):
        task = TASKS[i]
        c, r = task["cfg"], task["cfg"]["render"]
        seed, _ = folder.frame_seeds(c["sequence"]["seed"], task["frame"])
        shade_render(scenes.scene(task["model_spec"], PREBUILT), Camera(*task["camera"]),
                     np.reshape(task["R_cam_from_body"], (3, 3)), np.asarray(task["t_cam_m"], dtype=np.float64),
                     scenes.lighting_of(task["light"], r, scenes.star_field(c), c["sequence"]["seed"]),
                     quality=r["quality"], samples=r["samples"], seed=seed)
    render(0)  # numba's kernels, the scene, its tables
    barrier.wait()

def frame(i):
    render(i)

if __name__ == "__main__":
    ctx = mp.get_context("fork")
    barrier = ctx.Barrier(3)
    with ctx.Pool(2, initializer=init, initargs=(barrier,)) as pool:
        barrier.wait()
        t0 = time.perf_counter()
        pool.map(frame, range(N), chunksize=1)
        print(json.dumps({"wall": time.perf_counter() - t0}))
"""


def run_python(tree: str, code: str, env: dict, *args) -> dict:
    res = subprocess.run([sys.executable, "-c", code, *args], cwd=tree, env=dict(env, PYTHONPATH=tree),
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def run_job(tree: str, frames: int, env: dict) -> tuple:
    """(wall seconds, CPU seconds of the run and its workers) of one main job."""
    import resource
    out = tempfile.mkdtemp(prefix="bench-fixed-")
    try:
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "cli.py", "--target", "cassini", "--pattern", "spiral", "--frames", str(frames),
                        "--quiet", "--out", out], cwd=tree, env=dict(env, PYTHONPATH=tree), check=True,
                       stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    finally:
        shutil.rmtree(out, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--trees", nargs="+", default=[str(ROOT)])
    ap.add_argument("--frames", type=int, nargs="+", default=[2, 48])
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--stages-only", action="store_true")
    group.add_argument("--runs-only", action="store_true")
    ap.add_argument("--shading", action="store_true",
                    help="with the runs: also the shading alone of the same frames on two processes, and the "
                         "marginal cost per frame of the runs (the two largest --frames) over it")
    a = ap.parse_args()
    trees = [str(Path(t).resolve()) for t in a.trees]
    cache = tempfile.mkdtemp(prefix="bench-fixed-cache-")
    env = dict(os.environ, ORBITSYNTH_CACHE_DIR=cache, OPENBLAS_NUM_THREADS="1")
    stages = {t: {} for t in trees}
    runs = {t: {f: [] for f in a.frames} for t in trees}
    shading = {t: {f: [] for f in a.frames} for t in trees}
    try:
        for tree in trees:  # warm-up: numba's cache, the persistent cache, the page cache
            run_python(tree, STAGES, env)
            if not a.stages_only:
                run_job(tree, 2, env)
        for k in range(a.repeats):
            order = trees[k % len(trees):] + trees[:k % len(trees)]
            for tree in order:
                if not a.runs_only:
                    with tempfile.TemporaryDirectory() as tmp:
                        path = run_python(tree, PREBUILD, env, tmp)["path"]
                        for part in (run_python(tree, STAGES, env), run_python(tree, WORKER, env, path)):
                            for name, v in part.items():
                                stages[tree].setdefault(name, []).append(v)
                if not a.stages_only:
                    for f in a.frames:
                        runs[tree][f].append(run_job(tree, f, env))
                    if a.shading:
                        with tempfile.TemporaryDirectory() as tmp:
                            path = run_python(tree, PREBUILD, env, tmp)["path"]
                            for f in a.frames:
                                shading[tree][f].append(run_python(tree, SHADING, env, str(f), path)["wall"])
            print(f"repeat {k + 1}/{a.repeats} done", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    if not a.runs_only:
        names = list(next(iter(stages.values())))
        print("stage (median wall / CPU s) | " + " | ".join(trees))
        for name in names:
            cells = []
            for tree in trees:
                v = stages[tree].get(name, [])
                cells.append(f"{statistics.median(w for w, _ in v):.3f} / {statistics.median(c for _, c in v):.3f}"
                             if v else "-")
            print(f"{name} | " + " | ".join(cells))
    if not a.stages_only:
        for f in a.frames:
            wall = [statistics.median(w for w, _ in runs[t][f]) for t in trees]
            cpu = [statistics.median(c for _, c in runs[t][f]) for t in trees]
            print(f"main job, {f} frames (median wall s, its ratio; median CPU s, its ratio; runs' wall): " + " | ".join(
                f"{t}: {w:.2f} s ({w / wall[0]:.2f}x), CPU {c:.2f} s ({c / cpu[0]:.2f}x); "
                f"{', '.join(f'{x:.1f}' for x, _ in runs[t][f])}" for t, w, c in zip(trees, wall, cpu)))
        if a.shading and len(a.frames) > 1:
            f0, f1 = sorted(a.frames)[-2:]
            for t in trees:
                job = (statistics.median(w for w, _ in runs[t][f1]) - statistics.median(w for w, _ in runs[t][f0])) / (f1 - f0)
                sh = {f: statistics.median(shading[t][f]) for f in (f0, f1)}
                per = (sh[f1] - sh[f0]) / (f1 - f0)
                print(f"{t}: shading alone of {f0} / {f1} frames on two processes {sh[f0]:.2f} / {sh[f1]:.2f} s "
                      f"(runs: {', '.join(f'{x:.2f}' for x in shading[t][f1])}); marginal per frame: "
                      f"main job {job:.3f} s, shading {per:.3f} s, ratio {job / per:.2f}")


if __name__ == "__main__":
    main()
