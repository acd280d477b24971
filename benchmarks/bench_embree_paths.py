"""Scene.intersect / occluded through embreex against raytrace._embree's numba kernels, side by side.

    python benchmarks/bench_embree_paths.py --scenes DIR [--width 1280] [--repeats 3]
        [--presets fast balanced:16 balanced:64] [--targets ...] [--views ...]

Two parts, both alternating the two paths (``raytrace.presets.DIRECT_BATCHES`` False / True) so a
slow spell of a shared machine hits both alike, both through Embree's robust mode (the script
turns off ``raytrace.presets.FAST_TRAVERSAL``):

* *Rays.* Per scene, 36 jittered sub-pixel rays through every target pixel (the anti-aliasing
  stage's kind of batch, ~1 M rays): seconds of one ``Scene.intersect`` call each way, and
  whether the hit arrays are equal bit for bit (misses included).
* *Frames.* The scenes of ``benchmarks/bench_time_error.py`` (written to ``DIR`` if missing),
  each preset rendered ``--repeats`` times each way after a warm-up, in rounds whose order
  alternates; the median per scene, then the median over scenes and the median (and range)
  of the per-scene ratios direct / embreex; and whether the radiance and the ids are equal bit
  for bit.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_time_error import add_scene_options, parse_presets, scene_frames  # noqa: E402

from raytrace import presets  # noqa: E402
from raytrace.shade import render  # noqa: E402


def _paths(flag: bool) -> None:
    presets.DIRECT_BATCHES = flag


# both paths through Embree's robust mode, as embreex builds its scenes: the comparison is of
# the two ways of calling Embree, not of the faster scene the shading rays take by default
# (raytrace.presets.FAST_TRAVERSAL; BENCHMARKS.md, "Embree's robust flag where it matters only")
presets.FAST_TRAVERSAL = False


def subpixel_batch(scene, camera, R, t, per_pixel: int = 36, seed: int = 0):
    """Origins and directions (float32, body frame) of ``per_pixel`` jittered rays through each
    target pixel of the pose."""
    geo = scene.render_geometry(camera, R, t)
    pix = np.flatnonzero(geo.instance.ravel() > 0)
    rng = np.random.default_rng(seed)
    u = np.repeat(pix % camera.width, per_pixel) + rng.random(len(pix) * per_pixel)
    v = np.repeat(pix // camera.width, per_pixel) + rng.random(len(pix) * per_pixel)
    d_cam = np.column_stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(len(u))])
    R = np.asarray(R, dtype=np.float64)
    D = (d_cam @ R).astype(np.float32)  # rows R^T d
    O = np.broadcast_to((-R.T @ np.asarray(t, dtype=np.float64)).astype(np.float32), D.shape).copy()
    return O, D


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_scene_options(ap)
    args = ap.parse_args()
    presets = parse_presets(args.presets)
    rays, frames = [], {p: [] for p in presets}
    same_rays = same_frames = True
    for target, view, _, rargs in scene_frames(Path(args.scenes), args.width, args.targets, args.views):
        scene, camera, R, t, _light = rargs
        O, D = subpixel_batch(scene, camera, R, t)
        got, times = {}, {False: [], True: []}
        for flag in (False, True):
            _paths(flag)
            got[flag] = scene.intersect(O, D)
        for r in range(args.repeats):
            for flag in ((False, True) if r % 2 == 0 else (True, False)):
                _paths(flag)
                t0 = time.perf_counter()
                scene.intersect(O, D)
                times[flag].append(time.perf_counter() - t0)
        same = all(np.array_equal(got[False][k], got[True][k]) for k in got[False])
        same_rays &= same
        a, b = statistics.median(times[False]), statistics.median(times[True])
        rays.append((len(O), a, b))
        print(f"{target:12s} {view:8s} rays {len(O):8d}: embreex {1e3 * a:6.1f} ms, direct {1e3 * b:6.1f} ms "
              f"({b / a:.3f}x){'' if same else '  HITS DIFFER'}", flush=True)
        for quality, samples in presets:
            out, times = {}, {False: [], True: []}
            for flag in (False, True):
                _paths(flag)
                out[flag] = render(*rargs, quality=quality, samples=samples, seed=0)
            for r in range(args.repeats):
                for flag in ((False, True) if r % 2 == 0 else (True, False)):
                    _paths(flag)
                    t0 = time.perf_counter()
                    render(*rargs, quality=quality, samples=samples, seed=r + 1)
                    times[flag].append(time.perf_counter() - t0)
            same = (np.array_equal(out[False].radiance, out[True].radiance)
                    and np.array_equal(out[False].geometry.instance, out[True].geometry.instance))
            same_frames &= same
            a, b = statistics.median(times[False]), statistics.median(times[True])
            frames[(quality, samples)].append((a, b))
            print(f"{target:12s} {view:8s} {quality}{'' if samples is None else '-' + str(samples)}: embreex {a:.3f} s, "
                  f"direct {b:.3f} s ({b / a:.3f}x){'' if same else '  FRAMES DIFFER'}", flush=True)
    _paths(True)
    print(f"\nrays: {sum(n for n, _, _ in rays) / len(rays) / 1e6:.2f} M per scene; median per-scene ratio direct / "
          f"embreex {statistics.median(b / a for _, a, b in rays):.3f} (range {min(b / a for _, a, b in rays):.3f}–"
          f"{max(b / a for _, a, b in rays):.3f}); hits bit-identical: {same_rays}")
    for (quality, samples), r in frames.items():
        name = quality if samples is None else f"{quality}-{samples}"
        ratios = [b / a for a, b in r]
        print(f"{name}: median s / frame embreex {statistics.median(a for a, _ in r):.3f}, direct "
              f"{statistics.median(b for _, b in r):.3f}; median per-scene ratio {statistics.median(ratios):.3f} "
              f"(range {min(ratios):.3f}–{max(ratios):.3f})")
    print(f"frames bit-identical: {same_frames}")


if __name__ == "__main__":
    main()
