"""Earth behind the target: the procedural albedo interpolated on cells against every pixel.

    python benchmarks/bench_background.py [--target cassini] [--pattern spiral] [--frames 16]
        [--repeats 3]

The frames are those of the main job (``cli.py --target … --pattern …`` with ``--frames``
frames, its default camera, 1280×960). For every frame with Earth in view,
:func:`raytrace._background.earth_background` runs twice on the frame's geometry: with
``raytrace.shade._BACKGROUND_STEP`` (the albedo interpolated on step × step cells where that
is safe) and with step 1 (the texture evaluated at every pixel, the independent answer). Prints
per frame the share of the image that is Earth and lit Earth behind the target, the kernel's
time both ways (min of ``--repeats``, the two alternated), and the largest and RMS relative
difference of the radiance over the lit Earth pixels; the Earth mask must be identical.
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

import cli  # noqa: E402
from raytrace import _background, _context, shade  # noqa: E402
from raytrace.camera import Camera  # noqa: E402
from raytrace.dataset.scenes import lighting_of, load_model  # noqa: E402
from raytrace.scene import Scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--target", default="cassini")
    ap.add_argument("--pattern", default="spiral")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cargs = cli.build_parser().parse_args(["--target", args.target, "--pattern", args.pattern,
                                           "--frames", str(args.frames)])
    cfg, given = cli.resolve_config(cargs)
    plan = cli.plan_sequence(cfg, given)
    scene = Scene(load_model(plan["model_spec"]))
    cam = plan["camera"]
    cam = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    times = {1: [], shade._BACKGROUND_STEP: []}
    worst = 0.0
    for i, label in enumerate(plan["result"]["frames"]):
        light = lighting_of(plan["lights"][i], cfg["render"])
        R = np.asarray(label["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
        t = np.asarray(label["t_cam_m"], dtype=np.float64)
        if light.earth is None or not shade._earth_may_be_in_view(cam, R, light):
            continue
        geo = scene.render_geometry(cam, R, t)
        R_bc = np.ascontiguousarray(R.T)
        o_body = -R_bc @ t
        p, tex = _context._background_params(light)
        out = {}
        for r in range(args.repeats):
            for step in ((1, shade._BACKGROUND_STEP) if r % 2 == 0 else (shade._BACKGROUND_STEP, 1)):
                earth = np.zeros((cam.height, cam.width), dtype=bool)
                rad = np.zeros((cam.height, cam.width, 3), dtype=np.float32)
                t0 = time.perf_counter()
                _background.earth_background(geo.instance, o_body, R_bc, cam.fx, cam.fy, cam.cx, cam.cy,
                                             *cam.lens_arrays(), p, tex, step,
                                             shade._BACKGROUND_TOL, shade._BACKGROUND_CHORD, earth, rad)
                dt = time.perf_counter() - t0
                out[step] = (rad, earth, min(dt, out.get(step, (None, None, np.inf))[2]))
        (exact, earth1, t1), (fast, earth2, t2) = out[1], out[shade._BACKGROUND_STEP]
        if not np.array_equal(earth1, earth2):
            raise AssertionError(f"frame {i}: the Earth masks differ")
        lit = earth1 & (geo.instance == 0) & (exact.sum(-1) > 0)
        rel = np.abs(fast[lit].astype(np.float64) - exact[lit]) / exact[lit] if lit.any() else np.zeros(1)
        worst = max(worst, float(rel.max()))
        times[1].append(t1)
        times[shade._BACKGROUND_STEP].append(t2)
        print(f"frame {i:3d}: Earth {100 * earth1.mean():5.1f} % of the image, lit behind the target "
              f"{100 * lit.mean():5.1f} %; per pixel {1000 * t1:6.1f} ms, cells {1000 * t2:6.1f} ms "
              f"({t2 / t1:.2f}x); difference max {100 * rel.max():.3f} %, RMS {100 * np.sqrt((rel ** 2).mean()):.4f} %",
              flush=True)
    if times[1]:
        print(f"== {len(times[1])} frames with Earth in view: median per pixel {1000 * statistics.median(times[1]):.1f} "
              f"ms, cells {1000 * statistics.median(times[shade._BACKGROUND_STEP]):.1f} ms; largest difference "
              f"{100 * worst:.3f} %")


if __name__ == "__main__":
    main()
