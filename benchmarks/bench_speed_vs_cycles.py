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
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_time_error import add_scene_options, bpy_python, cycles, parse_presets, scene_frames  # noqa: E402

from raytrace.shade import render  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_scene_options(ap)
    ap.add_argument("--cycles-spp", type=int, nargs="*", default=[16, 64])
    args = ap.parse_args()
    py = bpy_python()
    if py is None and args.cycles_spp:
        sys.exit("bench_speed_vs_cycles: no .bpyenv/bin/python and BPY_PYTHON unset (benchmarks/README_cycles.md)")
    presets = parse_presets(args.presets)
    names = [f"{q}-{n}" if n else q for q, n in presets] + [f"cycles-{n}" for n in args.cycles_spp]
    per_scene = {k: [] for k in names}
    tmp = Path(args.scenes) / "_cycles_out.exr"
    print("scene".ljust(21) + "".join(f"{k:>14s}" for k in names), flush=True)
    for target, view, spath, frame in scene_frames(Path(args.scenes), args.width, args.targets, args.views):
        for q, n in presets:
            render(*frame, quality=q, samples=n, seed=0)  # warm-up: JIT, the cache's transfer
        times = {k: [] for k in names}
        for r in range(args.repeats):
            for (q, n), k in zip(presets, names):
                t0 = time.perf_counter()
                render(*frame, quality=q, samples=n, seed=r + 1)
                times[k].append(time.perf_counter() - t0)
            for n in args.cycles_spp:
                s, _img = cycles(spath, n, tmp, py)
                times[f"cycles-{n}"].append(s)
        row = {k: statistics.median(v) for k, v in times.items()}
        for k, v in row.items():
            per_scene[k].append(v)
        print(f"{target:12s} {view:8s}" + "".join(f"{row[k]:14.3f}" for k in names), flush=True)
    tmp.unlink(missing_ok=True)
    print("median".ljust(21) + "".join(f"{statistics.median(per_scene[k]):14.3f}" for k in names))
    for n in args.cycles_spp:
        c = per_scene[f"cycles-{n}"]
        for k in names[:len(presets)]:
            ratios = [a / b for a, b in zip(c, per_scene[k])]
            print(f"cycles-{n} / {k}: median of per-scene ratios {statistics.median(ratios):.2f} "
                  f"({min(ratios):.2f}-{max(ratios):.2f})")


if __name__ == "__main__":
    main()
