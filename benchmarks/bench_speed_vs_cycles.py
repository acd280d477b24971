"""Seconds per frame of our presets and of Blender Cycles, side by side, without references.

    python benchmarks/bench_speed_vs_cycles.py --scenes DIR [--width 1280] [--repeats 3]
        [--presets fast balanced:16 balanced:64] [--cycles-spp 16 64] [--targets ...] [--views ...]

The scenes of ``benchmarks/bench_time_error.py`` (written to ``DIR`` if missing). Per scene, our
presets and Cycles run one after the other, ``--repeats`` times each after a warm-up (ours) in
rounds, so a slow spell of a shared machine hits both; the median per scene, then the median
over scenes and the median of the per-scene ratios Cycles / ours.

What it is for: the time goals of the shading issue are seconds on "this 2-core machine", and
the machines here differ by 2× in speed. The error of each preset does not depend on the
machine (``bench_time_error.py`` measures it); its time does, and the ratio to Cycles on the
same machine says whether a change of machine moved both renderers alike. Cycles needs bpy in
``.bpyenv`` (``benchmarks/README_cycles.md``) or ``BPY_PYTHON``.

    python benchmarks/bench_speed_vs_cycles.py --scenes DIR --concurrent 2
        [--errors results.json] [--out DIR] ...

``--concurrent K``: the cost per frame in a sequence, as the CLI renders one (its K worker
processes, one thread each, one frame each at a time; ``cli.py --workers``). K worker processes
hold the scene; each frame of each configuration starts in all of them at once (a barrier), ours
with one numba thread, Cycles with ``--threads 1``; the seconds per frame are the slowest
worker's time / K. ``--errors`` takes the errors of a ``bench_time_error.py`` run
(``results.json``: they do not depend on the thread count) and adds the table of speed-ups at
equal error with these times; ``--out`` writes ``results.json`` (its rows with these times) and
``table.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_time_error import (add_scene_options, bpy_python, cycles, parse_presets, scene_frames,  # noqa: E402
                              write_scene, write_table)

from raytrace.shade import render  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_scene_options(ap)
    ap.add_argument("--cycles-spp", type=int, nargs="*", default=[16, 64])
    ap.add_argument("--concurrent", type=int, default=1,
                    help="K > 1: K processes of one thread, one frame each at a time (cost per frame in a sequence)")
    ap.add_argument("--cycles-repeats", type=int, help="repeats of Cycles (default: --repeats)")
    ap.add_argument("--errors", help="results.json of bench_time_error.py: adds the speed-ups at equal error")
    ap.add_argument("--out", help="folder for results.json and table.md")
    args = ap.parse_args()
    py = bpy_python()
    if py is None and args.cycles_spp:
        sys.exit("bench_speed_vs_cycles: no .bpyenv/bin/python and BPY_PYTHON unset (benchmarks/README_cycles.md)")
    if args.concurrent < 1:
        sys.exit("bench_speed_vs_cycles: --concurrent must be at least 1")
    presets = parse_presets(args.presets)
    names = [f"{q}-{n}" if n else q for q, n in presets] + [f"cycles-{n}" for n in args.cycles_spp]
    per_scene = {k: [] for k in names}
    rows = []  # one per scene and configuration, in bench_time_error.py's layout
    if args.concurrent > 1:
        scenes = _concurrent_times(args, presets, names, py)
    else:
        scenes = _times(args, presets, names, py)
    print("scene".ljust(21) + "".join(f"{k:>14s}" for k in names), flush=True)
    for target, view, row in scenes:
        for k, v in row.items():
            per_scene[k].append(v)
            ren, q, n = _config(k)
            rows.append({"target": target, "view": view, "renderer": ren, "preset": q, "samples": n, "s_per_frame": v})
        print(f"{target:12s} {view:8s}" + "".join(f"{row[k]:14.3f}" for k in names), flush=True)
    print("median".ljust(21) + "".join(f"{statistics.median(per_scene[k]):14.3f}" for k in names))
    for n in args.cycles_spp:
        c = per_scene[f"cycles-{n}"]
        for k in names[:len(presets)]:
            ratios = [a / b for a, b in zip(c, per_scene[k])]
            print(f"cycles-{n} / {k}: median of per-scene ratios {statistics.median(ratios):.2f} "
                  f"({min(ratios):.2f}-{max(ratios):.2f})")
    if args.errors:
        err = {(r["target"], r["view"], r["renderer"], r["preset"], r["samples"]): r
               for r in json.loads(Path(args.errors).read_text())}
        missing = [r for r in rows if (r["target"], r["view"], r["renderer"], r["preset"], r["samples"]) not in err]
        if missing:
            sys.exit(f"bench_speed_vs_cycles: {args.errors} has no error for {len(missing)} of the timed rows "
                     f"(first: {missing[0]})")
        for r in rows:
            e = err[(r["target"], r["view"], r["renderer"], r["preset"], r["samples"])]
            r["err"], r["err_corrected"] = e["err"], e["err_corrected"]
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        for r in rows:
            r["concurrent"] = args.concurrent
        (out / "results.json").write_text(json.dumps(rows, indent=1) + "\n")
        if args.errors:
            write_table(rows, out / "table.md")
            print((out / "table.md").read_text())
    elif args.errors:
        table = Path(args.scenes) / "_table.md"
        write_table(rows, table)
        print(table.read_text())
        table.unlink()


def _cycles_repeats(args) -> int:
    return args.repeats if args.cycles_repeats is None else max(1, args.cycles_repeats)


def _config(name: str) -> tuple[str, str, int | None]:
    """(renderer, preset, samples) of a column name: ``fast``, ``balanced-16``, ``cycles-64``."""
    q, _, n = name.partition("-")
    return ("cycles" if q == "cycles" else "orbitsynth"), q, (int(n) if n else None)


def _times(args, presets, names, py):
    """Per scene (target, view, {column: median seconds}), one process on all its threads."""
    tmp = Path(args.scenes) / "_cycles_out.exr"
    for target, view, spath, frame in scene_frames(Path(args.scenes), args.width, args.targets, args.views):
        for q, n in presets:
            render(*frame, quality=q, samples=n, seed=0)  # warm-up: JIT, the cache's transfer
        times = {k: [] for k in names}
        for r in range(args.repeats):
            for (q, n), k in zip(presets, names):
                t0 = time.perf_counter()
                render(*frame, quality=q, samples=n, seed=r + 1)
                times[k].append(time.perf_counter() - t0)
            for n in args.cycles_spp if r < _cycles_repeats(args) else ():
                s, _img = cycles(spath, n, tmp, py)
                times[f"cycles-{n}"].append(s)
        yield target, view, {k: statistics.median(v) for k, v in times.items()}
    tmp.unlink(missing_ok=True)


def _concurrent_times(args, presets, names, py):
    """Per scene (target, view, {column: median seconds per frame}) with ``args.concurrent``
    worker processes of one thread rendering the same frame at once: the slowest worker's
    time / K per frame (:func:`_worker`)."""
    K = args.concurrent
    # the scene files, written once before the workers read them
    files = [(target, view, spath) for target in args.targets
             for view, spath in write_scene(target, Path(args.scenes) / target, args.width) if view in args.views]
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as cli.py: inherited by the workers
    mp = multiprocessing.get_context("spawn")
    barrier = mp.Barrier(K)
    links = [mp.Pipe() for _ in range(K)]
    procs = [mp.Process(target=_worker, args=(i, child, barrier, str(args.scenes), py), daemon=True)
             for i, (_, child) in enumerate(links)]
    for p in procs:
        p.start()
    conns = [parent for parent, _ in links]

    def ask(msg):
        for c in conns:
            c.send(msg)
        answers = [c.recv() for c in conns]
        for a in answers:
            if isinstance(a, str) and a.startswith("error"):
                raise RuntimeError(a)
        return answers

    try:
        for target, view, spath in files:
            ask(("load", str(spath), presets))
            times = {k: [] for k in names}
            for r in range(args.repeats):
                for k in names:
                    if k.startswith("cycles-") and r >= _cycles_repeats(args):
                        continue
                    times[k].append(max(ask(("run", k, r + 1))) / K)
            yield target, view, {k: statistics.median(v) for k, v in times.items()}
    finally:
        for c in conns:
            with contextlib.suppress(OSError):  # a worker that died has closed its end
                c.send(("stop",))
        for p in procs:
            p.join(timeout=60)


_BARRIER_TIMEOUT_S = 600.0  # a worker that never arrives (it failed) breaks the barrier instead of hanging


def _worker(i: int, conn, barrier, folder: str, py) -> None:
    """One worker of :func:`_concurrent_times`: one numba thread (as ``cli.py``'s workers);
    "load" builds a scene (radiance cache included) and warms the presets up; "run" waits for
    the other workers, renders one frame and answers its seconds (Cycles: its render call)."""
    import numba

    from raytrace.scene import Scene
    from raytrace.scenefile import load_scene_file

    numba.set_num_threads(1)
    frame = spath = None
    tmp = Path(folder) / f"_cycles_out_{i}.exr"
    while True:
        msg = conn.recv()
        try:
            if msg[0] == "stop":
                break
            if msg[0] == "load":
                spath = Path(msg[1])
                spec = load_scene_file(str(spath))
                scene = Scene(spec.model)
                scene.radiance_cache()
                frame = (scene, spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting)
                for q, n in msg[2]:
                    render(*frame, quality=q, samples=n, seed=0)  # warm-up: JIT, the cache's transfer
                conn.send("ready")
            elif msg[0] == "run":
                ren, q, n = _config(msg[1])
                barrier.wait(timeout=_BARRIER_TIMEOUT_S)
                if ren == "cycles":
                    s, _img = cycles(spath, n, tmp, py, threads=1)
                else:
                    t0 = time.perf_counter()
                    render(*frame, quality=q, samples=n, seed=msg[2])
                    s = time.perf_counter() - t0
                conn.send(s)
        except Exception as exc:  # noqa: BLE001 - reported to the coordinator, which stops
            conn.send(f"error in worker {i}: {type(exc).__name__}: {exc}")
    tmp.unlink(missing_ok=True)


if __name__ == "__main__":
    main()
