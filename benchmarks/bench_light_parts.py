"""Frame time with and without the radiance split by source (``render(..., parts=True)``,
the ``light`` modality), side by side on the benchmark scenes at 1280×960.

    PYTHONPATH=. python benchmarks/bench_light_parts.py [--targets tiangong cassini] [--reps 5]

Each scene renders ``--reps`` times each way, interleaved (plain, parts, plain, …) after a
warm-up of both; prints the median seconds per preset and their ratio, and the median of the
split's own steps (``timings_s["light_parts"]``) as a fraction of the plain frame's median: on a
shared machine the frames' times wander by more than the split costs, its own steps less.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_time_error import scene_frames  # noqa: E402

from raytrace.shade import render  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", nargs="+", default=["tiangong", "cassini"])
    ap.add_argument("--views", nargs="+", default=["sunlit", "earth"])
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced:8"])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--folder", default=None)
    args = ap.parse_args()
    folder = Path(args.folder or tempfile.mkdtemp(prefix="bench_light_"))
    presets = [(p.split(":")[0], int(p.split(":")[1]) if ":" in p else None) for p in args.presets]
    print(f"{'scene':24s} {'preset':12s} {'plain s':>8s} {'parts s':>8s} {'ratio':>6s} {'split s':>8s} {'/plain':>6s}  max rel |Σ parts − hdr|")
    for target, view, _, pose in scene_frames(folder, args.width, args.targets, args.views):
        for quality, samples in presets:
            kw = dict(quality=quality, samples=samples, seed=0)
            render(*pose, **kw)
            render(*pose, **kw, parts=True)
            plain, parts, own = [], [], []
            for _ in range(args.reps):
                t0 = time.perf_counter()
                a = render(*pose, **kw)
                plain.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                b = render(*pose, **kw, parts=True)
                parts.append(time.perf_counter() - t0)
                own.append(b.timings_s["light_parts"])
            assert np.array_equal(a.radiance, b.radiance)
            rad = b.radiance.astype(np.float64)
            total = b.light_parts.reshape(*rad.shape[:2], 4, 3).astype(np.float64).sum(axis=2)
            pos = rad > 0
            rel = float(np.max(np.abs(total - rad)[pos] / rad[pos])) if pos.any() else 0.0
            mp, mq, mo = float(np.median(plain)), float(np.median(parts)), float(np.median(own))
            name = f"{quality}" + (f"-{samples}" if samples else "")
            print(f"{target + ' ' + view:24s} {name:12s} {mp:8.3f} {mq:8.3f} {mq / mp:6.3f} {mo:8.4f} {mo / mp:6.3f}  {rel:.2e}", flush=True)


if __name__ == "__main__":
    main()
