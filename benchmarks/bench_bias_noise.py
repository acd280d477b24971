"""Error of ``balanced`` split into bias and noise on the 12 scenes of bench_time_error.py.

    python benchmarks/bench_bias_noise.py --ref-dir DIR [--width 1280] [--ref-spp 256]
        [--presets balanced:8 balanced:16 fast] [--targets ...] [--views ...] [--threads N]

The scenes are those of ``benchmarks/bench_time_error.py`` (Lambertian stand-ins, three views
per built-in target). The reference is our path tracer at ``--ref-spp`` samples per pixel with
two seeds (kept in ``--ref-dir`` and reused); each preset is rendered with two seeds of its
own. Per pixel class (edge: the 3×3 neighbourhood holds another id or space — split further
into silhouette, where it holds space, and part boundary, where it holds only other parts;
interior: the rest), over the target's pixels, relative to Σ I_ref²:

* noise² of one render: ‖x₁ − x₂‖² / 2;
* bias²: ‖(x₁ + x₂)/2 − I_ref‖² − noise²/2 − (the reference's own noise², ‖a − b‖²/4);
* error = √(bias² + noise²), the expected error of one render against the exact image.

Prints one row per scene and preset and, per preset, the median error and time over the
scenes (time: the faster of the two renders, after a warm-up; run nothing else meanwhile), and
where the time goes: the stages of that render (``RenderFrame.timings_s``: geometry, the
lighting context — built in line on one thread, else waited for from its side thread —, direct
light, indirect light, anti-aliasing), median over the scenes. ``--threads 1`` times a frame as one worker of a sequence renders it (numba on one
thread; ``cli.py`` runs one such worker per core).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_time_error import reference_renders, scene_frames, viewpoints  # noqa: E402

from raytrace.shade import render  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref-dir", required=True)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--presets", nargs="*", default=["balanced:8", "balanced:16"])
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS))
    ap.add_argument("--views", nargs="*", default=[v[0] for v in viewpoints()])
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0: numba's default)")
    args = ap.parse_args()
    if args.threads:
        import numba
        numba.set_num_threads(args.threads)
    folder = Path(args.ref_dir) / f"w{args.width}"
    rows = {p: [] for p in args.presets}
    stages = {p: [] for p in args.presets}
    for tg, view, _path, pose in scene_frames(folder, args.width, args.targets, args.views, per_target=True):
        a, b, m, inst, _ = reference_renders(pose, args.ref_spp, folder / f"ref_{tg}_{view}_{args.ref_spp}.npz")
        inst = inst.astype(np.int64)
        ref = (a + b) / 2
        edge = (maximum_filter(inst, 3) != minimum_filter(inst, 3)) & m
        silhouette = (minimum_filter(inst, 3) == 0) & m
        den = (ref[m] ** 2).sum()
        for p in args.presets:
            name, _, n = p.partition(":")
            n = int(n) if n else None
            render(*pose, quality=name, samples=n, seed=7)
            xs, ts, tms = [], [], []
            for s in (11, 12):
                t0 = time.perf_counter()
                frame = render(*pose, quality=name, samples=n, seed=s)
                ts.append(time.perf_counter() - t0)
                xs.append(frame.radiance.astype(float))
                tms.append(frame.timings_s)
            stages[p].append(tms[int(np.argmin(ts))])
            split = {}
            for cls, mk in (("all", m), ("edge", edge), ("interior", m & ~edge), ("silhouette", silhouette),
                            ("boundary", edge & ~silhouette)):
                n2 = ((xs[0] - xs[1])[mk] ** 2).sum() / 2 / den
                d2 = (((xs[0] + xs[1]) / 2 - ref)[mk] ** 2).sum() / den
                b2 = d2 - n2 / 2 - ((a - b)[mk] ** 2).sum() / 4 / den
                split[cls] = (b2, n2)
            b2, n2 = split["all"]
            err = float(np.sqrt(max(b2 + n2, 0.0)))
            rows[p].append((min(ts), err))
            print(f"{tg:11s} {view:7s} {p:12s} {min(ts):6.3f} s  error {100 * err:5.2f} %  "
                  f"bias {100 * np.sqrt(max(b2, 0)):5.2f} %  noise {100 * np.sqrt(n2):5.2f} %  | edge bias² "
                  f"{1e4 * split['edge'][0]:6.2f} noise² {1e4 * split['edge'][1]:6.2f}  interior bias² "
                  f"{1e4 * split['interior'][0]:6.2f} noise² {1e4 * split['interior'][1]:6.2f} (×1e-4; edge = "
                  f"silhouette {1e4 * split['silhouette'][0]:.2f} / {1e4 * split['silhouette'][1]:.2f} + part "
                  f"boundary {1e4 * split['boundary'][0]:.2f} / {1e4 * split['boundary'][1]:.2f})  stages "
                  + " ".join(f"{k} {v:.3f}" for k, v in stages[p][-1].items()), flush=True)
    for p, r in rows.items():
        print(f"== {p}: median {statistics.median(t for t, _ in r):.3f} s, median error "
              f"{100 * statistics.median(e for _, e in r):.2f} %; stages (median s): "
              + " ".join(f"{k} {statistics.median(st[k] for st in stages[p]):.3f}" for k in stages[p][0]))


if __name__ == "__main__":
    main()
