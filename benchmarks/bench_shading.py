"""Shading: time per frame against error, per quality preset, on the built-in targets with
their real materials (GGX foils, paint, solar cells).

    python benchmarks/bench_shading.py [--width 1280] [--ref-spp 256] [--targets ...]
        [--presets fast balanced:8 ...] [--ref-dir DIR]

For each target, a viewpoint at 1.1× the distance that fills a 40° field with the target
(Cassini at half that: its 11 m magnetometer boom sets its bounding radius; the same scenes as
tests/raytrace/test_presets_vs_reference.py), lit by the Sun (1361 W/m²), Earth below (albedo
0.3) and a 1 W/(m²·sr) ambient sky. The reference is the path tracer at ``--ref-spp`` samples
per pixel, rendered twice with two seeds (1, 2; kept in ``--ref-dir`` if given, and read back
from there). Error is the relative RMS over target pixels, ‖I − I_ref‖₂ / ‖I_ref‖₂ over all
channels. Each preset is rendered with two seeds (0, 7), x₁ and x₂, against the two references
A and B, which gives the error without the reference's own noise and splits it (per pixel,
summed over target pixels, relative to ‖I_ref‖²):

    bias² = Σ (x₁ − A)·(x₂ − B)   (unbiased: the four images are independent)
    noise² = Σ (x₁ − x₂)² / 2      (the variance of one render)
    error² = bias² + noise²

Times are medians of 3 runs after a warm-up (JIT compiled, radiance cache built), so they are
the per-frame cost of a sequence; the one-off cache build is reported separately.
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

PRESETS = ["fast", "balanced:4", "balanced:8", "balanced:16", "balanced:64"]
DISTANCE_FACTOR = {"cassini": 0.5}


def _preset(text: str) -> tuple[str, int | None]:
    name, _, n = text.partition(":")
    return name, (int(n) if n else None)


def _split(x1, x2, a, b, m) -> tuple[float, float, float]:
    """(error, bias, noise) of a preset from two renders x1, x2 against two references a, b,
    relative to the mean reference, without the references' noise (module notes); bias keeps
    the sign of its square's estimate."""
    den = (((a + b) / 2)[m] ** 2).sum()
    b2 = ((x1 - a) * (x2 - b)).sum(-1)[m].sum() / den
    n2 = ((x1 - x2) ** 2 / 2).sum(-1)[m].sum() / den
    return math.sqrt(max(b2 + n2, 0.0)), math.copysign(math.sqrt(abs(b2)), b2), math.sqrt(n2)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS))
    ap.add_argument("--presets", nargs="*", default=PRESETS, help="name or name:samples (default: %(default)s)")
    ap.add_argument("--ref-dir", default=None, help="folder that keeps the references between runs")
    args = ap.parse_args()
    W = args.width
    H = W * 3 // 4
    f = W / 1280 * 4e-3 / 3.45e-6
    cam = Camera(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
    light = Lighting(sun_dir_body=(0.5, -0.5, 0.70710678), earth=Earth((-1.0, 0.0, 0.0), 6.778e6, albedo=0.3),
                     ambient_radiance_W_m2_sr=1.0)
    print(f"# {W}x{H}, reference {args.ref_spp} spp x 2 seeds, presets 2 seeds")
    print("| target | preset | samples | s / frame (median) | error | bias | noise |")
    print("|---|---|---|---|---|---|---|")
    for name in args.targets:
        model = load_target(name)
        scene = Scene(model)
        t0 = time.perf_counter()
        scene.radiance_cache()
        build = time.perf_counter() - t0
        rho = np.array([0.4, -1.0, 0.3])
        rho = rho / np.linalg.norm(rho) * 1.1 * model.bounding_radius_m / math.tan(math.radians(20))
        rho *= DISTANCE_FACTOR.get(name, 1.0)
        R = look_at(rho)
        t = -R @ rho
        cached = Path(args.ref_dir) / f"{name}_{W}_{args.ref_spp}.npz" if args.ref_dir else None
        ref_s = float("nan")
        if cached is not None and cached.is_file():
            with np.load(cached) as z:
                a, b = z["a"].astype(np.float64), z["b"].astype(np.float64)
        else:
            t0 = time.perf_counter()
            a = render(scene, cam, R, t, light, quality="reference", samples=args.ref_spp, seed=1).radiance
            ref_s = time.perf_counter() - t0
            b = render(scene, cam, R, t, light, quality="reference", samples=args.ref_spp, seed=2).radiance
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.savez(cached, a=a, b=b)
            a, b = a.astype(np.float64), b.astype(np.float64)
        mask = render(scene, cam, R, t, light, quality="fast").geometry.mask
        for q, n in map(_preset, args.presets):
            x1 = render(scene, cam, R, t, light, quality=q, samples=n, seed=0).radiance.astype(np.float64)
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                x2 = render(scene, cam, R, t, light, quality=q, samples=n, seed=7).radiance.astype(np.float64)
                times.append(time.perf_counter() - t0)
            err, bias, noise = _split(x1, x2, a, b, mask)
            print(f"| {name} | {q} | {n or '-'} | {statistics.median(times):.3f} | {100 * err:.2f} % | "
                  f"{100 * bias:.2f} % | {100 * noise:.2f} % |", flush=True)
        print(f"| {name} | reference | {args.ref_spp} | {ref_s:.1f} | (yardstick) | | |")
        print(f"<!-- {name}: radiance cache build {build:.2f} s, target covers {100 * mask.mean():.1f} % "
              f"of the frame -->", flush=True)


if __name__ == "__main__":
    main()
