#!/usr/bin/env python3
"""Benchmark: the geometry pass (depth, normals, ids) against the raw Embree call.

    python benchmarks/bench_geometry.py            # Markdown tables
    python benchmarks/bench_geometry.py --quick    # fewer repeats

For each built-in target at a typical range (the geometric mean of its range band, seen
obliquely), 1280×960, it times, interleaved round-robin in one run:
  geometry pass        raytrace.Scene.render_geometry (culling, rays, Embree, float64 refinement, AOVs)
  raw Embree, 1 call   one embreex ``run(..., output=1)`` on exactly the rays the pass casts
  raw Embree, threads  the same rays split into the same chunks on the same thread pool
The last is the floor for this design. Then how the pass scales with image size and with
triangle count (icospheres of 1.3k to 1.3M triangles filling the frame).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from orbit.pose import look_at  # noqa: E402
from orbit.sampling import range_band  # noqa: E402
from raytrace import _kernels  # noqa: E402
from raytrace.camera import Camera  # noqa: E402
from raytrace.model import Component, TargetModel  # noqa: E402
from raytrace.scene import _RAYS_PER_CHUNK, Scene, _pool, default_threads  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS, load_target  # noqa: E402

VIEW_DIR = np.array([1.0, -2.0, 0.7]) / np.linalg.norm([1.0, -2.0, 0.7])


def pose(distance_m: float):
    rho = VIEW_DIR * distance_m
    R = look_at(rho)
    return R, -R @ rho


def same_rays(scene: Scene, cam: Camera, R, t):
    (u0, v0, u1, v1), _ = scene.cast_rect(cam, R, t)
    w, h = u1 - u0, v1 - v0
    o = np.empty((w * h, 3), np.float32)
    d = np.empty((w * h, 3), np.float32)
    z0 = scene._near_plane(scene.hull_vertices @ R.T + t)  # rays start where the pass starts them
    _kernels.make_rays(-R.T @ t, np.ascontiguousarray(R.T), cam.fx, cam.fy, cam.cx, cam.cy, *cam.lens_arrays(), u0, v0,
                       w, h, z0, o, d)
    return o, d, w


def raw_threaded(scene: Scene, o, d, w):
    rows = max(1, _RAYS_PER_CHUNK // max(w, 1))
    step = rows * max(w, 1)
    futures = [_pool().submit(scene.embree.run, o[i:i + step], d[i:i + step], None, "INTERSECT", 1)
               for i in range(0, len(o), step)]
    for f in futures:
        f.result()


def interleaved(fns: dict, repeats: int) -> dict:
    for fn in fns.values():
        fn()  # warm-up
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=11)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    reps = 3 if args.quick else args.repeats
    cam = Camera()
    print(f"Geometry pass vs raw Embree, {cam.width}×{cam.height}, median of {reps} interleaved runs, "
          f"{default_threads()} threads; {platform.machine()}, Python {platform.python_version()}.")
    print(f"Command: `python benchmarks/bench_geometry.py{' --quick' if args.quick else ''}`\n")

    print("| target | triangles | range [m] | rays cast | hit pixels | geometry pass [s] | raw 1 call [s] | "
          "raw threaded [s] | pass / raw 1 call | pass / raw threaded |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in BUILTIN_TARGETS:
        model = load_target(name)
        scene = Scene(model)
        band = range_band(model.bounding_radius_m)
        dist = math.sqrt(band.r_min_m * band.r_max_m)
        R, t = pose(dist)
        o, d, w = same_rays(scene, cam, R, t)
        g = scene.render_geometry(cam, R, t)
        med = interleaved({"pass": lambda: scene.render_geometry(cam, R, t),
                           "raw1": lambda: scene.embree.run(o, d, query="INTERSECT", output=1),
                           "rawT": lambda: raw_threaded(scene, o, d, w)}, reps)
        print(f"| {name} | {model.n_triangles:,} | {dist:.0f} | {len(o):,} | {int(g.mask.sum()):,} | "
              f"{med['pass']:.4f} | {med['raw1']:.4f} | {med['rawT']:.4f} | {med['pass'] / med['raw1']:.2f}× | "
              f"{med['pass'] / med['rawT']:.2f}× |")

    print("\nScaling with image size (cassini at its typical range, same field of view):\n")
    print("| image | rays cast | geometry pass [s] | raw threaded [s] | ratio | ns per cast ray |")
    print("|---|---|---|---|---|---|")
    model = load_target("cassini")
    scene = Scene(model)
    band = range_band(model.bounding_radius_m)
    R, t = pose(math.sqrt(band.r_min_m * band.r_max_m))
    for W, H in ((320, 240), (640, 480), (1280, 960), (2560, 1920), (4096, 3072)):
        c = Camera.from_focal(4.0e-3 * W / 1280, 3.45e-6, W, H)
        o, d, w = same_rays(scene, c, R, t)
        med = interleaved({"pass": lambda: scene.render_geometry(c, R, t),
                           "rawT": lambda: raw_threaded(scene, o, d, w)}, max(3, reps // 2))
        print(f"| {W}×{H} | {len(o):,} | {med['pass']:.4f} | {med['rawT']:.4f} | {med['pass'] / med['rawT']:.2f}× | "
              f"{med['pass'] / len(o) * 1e9:.0f} |")

    print("\nScaling with triangle count (an icosphere of radius 2 m at 4.5 m filling the 1280×960 frame):\n")
    print("| triangles | scene build [s] | geometry pass [s] | raw threaded [s] | ratio |")
    print("|---|---|---|---|---|")
    import trimesh
    for sub in (3, 4, 5, 6, 7, 8):
        sphere = trimesh.creation.icosphere(subdivisions=sub, radius=2.0)
        t0 = time.perf_counter()
        scene = Scene(TargetModel("sphere", (Component("sphere", sphere, "white_paint", "bus", 1.0),)))
        _ = scene.embree
        build = time.perf_counter() - t0
        R, t = np.eye(3), np.array([0.0, 0.0, 4.5])
        o, d, w = same_rays(scene, cam, R, t)
        med = interleaved({"pass": lambda: scene.render_geometry(cam, R, t),
                           "rawT": lambda: raw_threaded(scene, o, d, w)}, max(3, reps // 2))
        print(f"| {len(sphere.faces):,} | {build:.2f} | {med['pass']:.4f} | {med['rawT']:.4f} | "
              f"{med['pass'] / med['rawT']:.2f}× |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
