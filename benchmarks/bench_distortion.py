"""Time of a frame through a distorted camera against the same frame through the pinhole.

    python benchmarks/bench_distortion.py [--width 1280] [--repeats 7] [--targets icesat cassini]

For each benchmark scene (``benchmarks/bench_time_error.py``'s, ``sunlit`` and ``earth``
views) renders the ``fast`` preset through the scene's pinhole camera and through the same
camera with Brown–Conrady coefficients (k1, k2, p1, p2, k3) = (−0.2, 0.05, 1e-3, −1e-3, 0),
interleaved (pinhole, lens, pinhole, …) after one warm-up each (numba's kernels and the
lens's table built), and prints the median seconds of each and their ratio, and of the
geometry pass alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_time_error import scene_frames
from raytrace.shade import render

DIST = (-0.2, 0.05, 1e-3, -1e-3, 0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--targets", nargs="+", default=["icesat", "cassini", "tiangong", "spacedragon"])
    ap.add_argument("--views", nargs="+", default=["sunlit", "earth"])
    ap.add_argument("--folder", default="/tmp/bench_distortion_scenes")
    args = ap.parse_args()
    ratios, geo_ratios = [], []
    for target, view, _, (scene, cam, R, t, light) in scene_frames(args.folder, args.width, args.targets, args.views):
        cams = {"pinhole": cam, "lens": dataclasses.replace(cam, dist_coeffs=DIST)}
        times = {k: [] for k in cams}
        geo = {k: [] for k in cams}
        for k, c in cams.items():  # warm-up: compile, the lens's table
            render(scene, c, R, t, light, quality="fast")
        for _ in range(args.repeats):
            for k, c in cams.items():
                t0 = time.perf_counter()
                f = render(scene, c, R, t, light, quality="fast")
                times[k].append(time.perf_counter() - t0)
                geo[k].append(f.timings_s["geometry"])
        m = {k: statistics.median(v) for k, v in times.items()}
        g = {k: statistics.median(v) for k, v in geo.items()}
        ratios.append(m["lens"] / m["pinhole"])
        geo_ratios.append(g["lens"] / g["pinhole"])
        print(f"{target:12s} {view:7s} frame pinhole {m['pinhole']:.3f} s, lens {m['lens']:.3f} s "
              f"(×{ratios[-1]:.3f}, {m['lens'] - m['pinhole']:+.3f} s); geometry pass {g['pinhole']:.3f} → "
              f"{g['lens']:.3f} s (×{geo_ratios[-1]:.3f})", flush=True)
    print(f"median ratio lens / pinhole: frame ×{statistics.median(ratios):.3f}, "
          f"geometry pass ×{statistics.median(geo_ratios):.3f}")


if __name__ == "__main__":
    main()
