"""Shading: time per frame against error, per quality preset, on the built-in targets.

    python benchmarks/bench_shading.py [--width 1280] [--ref-spp 256] [--targets ...]

For each target, a viewpoint at 1.1× the distance that fills a 40° field with the target,
lit by the Sun (1361 W/m²), Earth below (albedo 0.3) and a 1 W/(m²·sr) ambient sky. The
reference is the path tracer at ``--ref-spp`` samples per pixel, rendered twice with two
seeds: their mean is the yardstick and half their difference estimates its own noise, which
is subtracted in quadrature from each preset's measured error ("corrected" column). Error is
the relative RMS over target pixels: ‖I − I_ref‖₂ / ‖I_ref‖₂ over all channels. Times are
medians of 3 runs after a warm-up (JIT compiled, radiance cache built), so they are the
per-frame cost of a sequence; the one-off cache build is reported separately.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from orbit.pose import look_at  # noqa: E402
from raytrace.camera import Camera  # noqa: E402
from raytrace.lighting import Earth, Lighting  # noqa: E402
from raytrace.scene import Scene  # noqa: E402
from raytrace.shade import render  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS, load_target  # noqa: E402

PRESETS = [("fast", None), ("balanced", 4), ("balanced", 8), ("balanced", 16), ("balanced", 64)]


def _err(a, b, m):
    return float(np.sqrt(((a[m] - b[m]) ** 2).sum() / (b[m] ** 2).sum()))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS))
    args = ap.parse_args()
    W = args.width
    H = W * 3 // 4
    f = W / 1280 * 4e-3 / 3.45e-6
    cam = Camera(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
    light = Lighting(sun_dir_body=(0.5, -0.5, 0.70710678), earth=Earth((-1.0, 0.0, 0.0), 6.778e6, albedo=0.3),
                     ambient_radiance_W_m2_sr=1.0)
    print(f"# {W}x{H}, reference {args.ref_spp} spp x 2 seeds")
    print("| target | preset | samples | s / frame (median) | rel. RMS error | corrected | ref noise |")
    print("|---|---|---|---|---|---|---|")
    for name in args.targets:
        model = load_target(name)
        scene = Scene(model)
        t0 = time.perf_counter()
        scene.radiance_cache()
        build = time.perf_counter() - t0
        rho = np.array([0.4, -1.0, 0.3])
        rho = rho / np.linalg.norm(rho) * 1.1 * model.bounding_radius_m / math.tan(math.radians(20))
        R = look_at(rho)
        t = -R @ rho
        t0 = time.perf_counter()
        r1 = render(scene, cam, R, t, light, quality="reference", samples=args.ref_spp, seed=1).radiance
        ref_s = time.perf_counter() - t0
        r2 = render(scene, cam, R, t, light, quality="reference", samples=args.ref_spp, seed=2).radiance
        ref = (r1.astype(np.float64) + r2) / 2
        mask = render(scene, cam, R, t, light, quality="fast").geometry.mask
        noise = _err(r1.astype(np.float64), r2.astype(np.float64), mask) / 2  # of the mean of two
        for q, n in PRESETS:
            render(scene, cam, R, t, light, quality=q, samples=n)  # warm-up
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                img = render(scene, cam, R, t, light, quality=q, samples=n).radiance
                times.append(time.perf_counter() - t0)
            e = _err(img.astype(np.float64), ref, mask)
            corr = math.sqrt(max(e * e - noise * noise, 0.0))
            print(f"| {name} | {q} | {n or '-'} | {statistics.median(times):.3f} | {100 * e:.1f} % | "
                  f"{100 * corr:.1f} % | {100 * noise:.1f} % |", flush=True)
        print(f"| {name} | reference | {args.ref_spp} | {ref_s:.1f} | (yardstick) | | |")
        print(f"<!-- {name}: radiance cache build {build:.2f} s, target covers {100 * mask.mean():.1f} % "
              f"of the frame -->", flush=True)


if __name__ == "__main__":
    main()
