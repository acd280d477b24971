"""CPU time of a frame's anti-aliasing (the edge pixels' sub-samples) on the main job's frames and
the dataset targets' frames, as a worker renders them (one numba thread), two checkouts side by
side, and whether their outputs are the same bytes.

    python benchmarks/bench_antialias.py --other /path/to/other/checkout [--rounds 3]
        [--frames 0,4,8,12,16,20,24,28,32,36,40,44] [--targets tiangong,spacedragon,icesat]
        [--target-frames 0,24,47]

Plans the main job as a user runs it (``--target cassini --pattern spiral``: 1280×960, ``fast``,
the Blue Marble Earth behind the target) and renders the listed frames, then the listed frames of
each ``--targets`` entry planned the same way (``--target X --pattern spiral``; the main job is
Cassini's), in a child
process per round and checkout, alternating the two checkouts and swapping their order every
round (a shared machine's load then falls on both alike), after one warm-up frame per target.
Per frame the process CPU seconds of ``shade.render`` and of the anti-aliasing's stages:
``_antialias._aa_pixels`` (which pixels), ``_trace_chunk`` (their sub-samples' rays, hits, Sun,
mirror rays, Earth along the misses) and ``_supersample`` (their shading). Prints per checkout
the median over frames and rounds, the ratio of the medians (this / other), the median of the
per-frame ratios of the three stages' sum per target, and whether the radiance and the ``rgb``, ``mask``,
``depth`` and ``normal`` images of every frame are the same bytes in both checkouts. Run it once
after editing a kernel before reading that last line: a fastmath kernel compiled in the process
can round differently from its cached build (raytrace/_jit.py), so a checkout's first run after
an edit may differ from every later one.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("render", "aa_pixels", "trace_chunk", "supersample")
AA = ("aa_pixels", "trace_chunk", "supersample")
MODALITIES = ["rgb", "mask", "depth", "normal"]


def _child(root: str, jobs: list, out: str) -> None:
    """Render the (target, frames) ``jobs`` with the checkout at ``root``; write the per-frame
    CPU seconds {stage: {key: s}} and each frame's arrays into the folder ``out``."""
    sys.path.insert(0, root)
    import numba
    import numpy as np
    numba.set_num_threads(1)  # as a worker of the main job
    import cli
    from raytrace import _antialias, shade
    from raytrace.dataset import folder
    assert Path(shade.__file__).resolve().is_relative_to(Path(root).resolve()), shade.__file__
    acc = {}

    def wrap(mod, name, key):
        f = getattr(mod, name)

        @functools.wraps(f)
        def g(*a, **k):
            c = time.process_time()
            r = f(*a, **k)
            acc[key] = acc.get(key, 0.0) + time.process_time() - c
            return r
        setattr(mod, name, g)

    wrap(_antialias, "_aa_pixels", "aa_pixels")
    wrap(_antialias, "_trace_chunk", "trace_chunk")
    wrap(_antialias, "_supersample", "supersample")
    wrap(shade, "render", "render")
    last = {}
    render = shade.render

    def keep(*a, **k):
        frame = render(*a, **k)
        last["radiance"] = frame.radiance
        return frame
    shade.render = keep
    times = {s: {} for s in STAGES}
    for target, frames in jobs:
        cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", target, "--pattern", "spiral"]))
        tasks, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)
        cli.render_frame_images(dict(tasks[frames[0]], modalities=["rgb"]))  # warm-up: scene, caches, kernels
        for f in frames:
            acc.clear()
            images, _ = cli.render_frame_images(dict(tasks[f], modalities=MODALITIES))
            key = f"{target}_{f}"
            for s in STAGES:
                times[s][key] = acc.get(s, 0.0)
            np.savez(os.path.join(out, key + ".npz"), radiance=last["radiance"],
                     **{m: np.asarray(images[m]) for m in MODALITIES})
    with open(os.path.join(out, "times.json"), "w") as fh:
        json.dump(times, fh)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", required=True, help="another checkout of the project to compare with")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", default="0,4,8,12,16,20,24,28,32,36,40,44", help="frames of the main job")
    ap.add_argument("--targets", default="tiangong,spacedragon,icesat",
                    help="dataset targets besides the main job's (cassini)")
    ap.add_argument("--target-frames", default="0,24,47", help="frames of each --targets entry")
    ap.add_argument("--child", nargs=2, metavar=("ROOT", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--jobs", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        _child(a.child[0], json.loads(a.jobs), a.child[1])
        return
    main_frames = [int(x) for x in a.frames.split(",") if x]
    tf = [int(x) for x in a.target_frames.split(",") if x]
    jobs = ([["cassini", main_frames]] if main_frames else []) + \
        [[t, tf] for t in a.targets.split(",") if t and tf]
    roots = {"this": str(ROOT), "other": str(Path(a.other).resolve())}
    times = {n: {s: {} for s in STAGES} for n in roots}
    differ = []
    import numpy as np
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.rounds):
            for n in (["this", "other"] if k % 2 == 0 else ["other", "this"]):
                out = os.path.join(tmp, f"{n}_{k}")
                os.makedirs(out)
                env = dict(os.environ, PYTHONPATH=roots[n])
                subprocess.run([sys.executable, __file__, "--other", a.other, "--jobs", json.dumps(jobs),
                                "--child", roots[n], out], check=True, env=env)
                with open(os.path.join(out, "times.json")) as fh:
                    for s, v in json.load(fh).items():
                        for key, x in v.items():
                            times[n][s].setdefault(key, []).append(x)
            for name in sorted(os.listdir(os.path.join(tmp, f"this_{k}"))):
                if not name.endswith(".npz"):
                    continue
                x = np.load(os.path.join(tmp, f"this_{k}", name))
                y = np.load(os.path.join(tmp, f"other_{k}", name))
                for m in ["radiance"] + MODALITIES:
                    if x[m].dtype != y[m].dtype or x[m].shape != y[m].shape or x[m].tobytes() != y[m].tobytes():
                        differ.append(f"round {k + 1} {name[:-4]} {m}")
            print(f"round {k + 1}/{a.rounds} done", flush=True)
    keys = sorted(times["this"]["render"])
    print(f"{len(keys)} frames ({', '.join(t for t, _ in jobs)}), {a.rounds} rounds, one numba thread; "
          "CPU ms per frame, median over frames and rounds")
    for s in STAGES:
        m = {n: statistics.median(x for key in keys for x in times[n][s][key]) for n in roots}
        print(f"  {s:12s} this {1e3 * m['this']:8.1f}  other {1e3 * m['other']:8.1f}  "
              f"ratio {m['this'] / max(m['other'], 1e-12):.3f}")
    for target, _ in jobs:
        ks = [key for key in keys if key.startswith(target + "_")]
        aa = {n: [statistics.median(sum(times[n][s][key][r] for s in AA) for r in range(a.rounds)) for key in ks]
              for n in roots}
        ratios = [t / max(o, 1e-12) for t, o in zip(aa["this"], aa["other"])]
        print(f"  {target:12s} anti-aliasing (3 stages) this {1e3 * statistics.median(aa['this']):7.1f}  "
              f"other {1e3 * statistics.median(aa['other']):7.1f}  median per-frame ratio "
              f"{statistics.median(ratios):.3f} (range {min(ratios):.3f}–{max(ratios):.3f})")
    print("radiance, rgb, mask, depth, normal the same bytes:", "yes" if not differ else "NO: " + "; ".join(differ[:20]))


if __name__ == "__main__":
    main()
