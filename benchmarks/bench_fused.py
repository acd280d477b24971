"""The fused path kernels (Embree called from numba, ``raytrace._paths``) against the batched
code they replaced (``embreex`` batches, a round of Python per bounce level), side by side.

    python benchmarks/bench_fused.py --scenes DIR [--samples 16] [--repeats 3]
        [--targets ...] [--views ...]

The scenes are those of ``benchmarks/bench_time_error.py`` (written to ``DIR`` if missing). Per
scene, the two paths alternate (``raytrace.presets.FUSED_GATHER``), each rendered ``--repeats``
times after a warm-up; prints the median time of each, their ratio and the largest difference
between the two frames relative to the frame's maximum (0: bit-identical), then the median
over scenes. Run nothing else meanwhile.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_time_error import scene_frames, viewpoints  # noqa: E402

from raytrace import presets, shade  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", required=True, help="folder of the bench_time_error.py scenes (written if missing)")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS))
    ap.add_argument("--views", nargs="*", default=[v[0] for v in viewpoints()])
    args = ap.parse_args()
    ratios, t_batched, t_fused = [], [], []
    for target, view, _spath, frame_args in scene_frames(Path(args.scenes), args.width, args.targets, args.views):
        times = {False: [], True: []}
        img = {}
        for r in range(args.repeats + 1):
            for fused in ((False, True) if r % 2 == 0 else (True, False)):
                presets.FUSED_GATHER = fused
                t0 = time.perf_counter()
                f = shade.render(*frame_args, quality="balanced", samples=args.samples, seed=3 + r)
                dt = time.perf_counter() - t0
                if r:  # the first round warms up (JIT, the direct Embree scene)
                    times[fused].append(dt)
                if r == 1:
                    img[fused] = f.radiance.astype(np.float64)
        tb, tf = statistics.median(times[False]), statistics.median(times[True])
        diff = float(np.abs(img[True] - img[False]).max() / max(img[False].max(), 1e-30))
        ratios.append(tf / tb)
        t_batched.append(tb)
        t_fused.append(tf)
        print(f"{target:12s} {view:8s} batched {tb:7.3f} s  fused {tf:7.3f} s  ratio {tf / tb:.3f}  "
              f"max difference {diff:.1e}", flush=True)
    presets.FUSED_GATHER = True
    print(f"median over scenes: batched {statistics.median(t_batched):.3f} s, fused {statistics.median(t_fused):.3f} s, "
          f"median ratio {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})")


if __name__ == "__main__":
    main()
