"""Cost of the ``coords`` and ``flow`` modalities in the main job's frame.

    python benchmarks/bench_flow_coords.py [--frames 8] [--target cassini] [--pattern spiral]

Plans the main job as a user runs it (1280×960, defaults) and renders each frame in this process
twice, interleaved (same load on this shared machine for both): the default modalities, and the
default modalities plus ``coords`` and ``flow``; each time the frame's images are written as EXR /
PNG into a temporary folder (as the sequence folder's writer does, without the checksums).
Prints the median frame time of both, their ratio, the median of the two producers alone (hit
points, flow with its visibility rays) and of writing their two EXR files.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cli
from raytrace import files as F
from raytrace.camera import Camera
from raytrace.correspondence import FrameHits
from raytrace.dataset import folder, scenes
from raytrace.dataset.modalities import DEFAULT, MODALITIES, relpath


def frame_seconds(task: dict, out: str) -> float:
    t0 = time.perf_counter()
    images, _ = cli.render_frame_images(task)
    for m in task["modalities"]:
        F.write_image(os.path.join(out, relpath(m, task["frame"]).replace("/", "_")), images[m],
                      noisy=MODALITIES[m].noisy)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--target", default="cassini")
    ap.add_argument("--pattern", default="spiral")
    a = ap.parse_args()
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(
        ["--target", a.target, "--pattern", a.pattern, "--frames", str(a.frames)]))
    plan = cli.plan_sequence(cfg, given)
    tasks, _ = folder.tasks_for(plan, "", None, write=False)
    base, extra = list(DEFAULT), [*DEFAULT, "coords", "flow"]
    times = {"default": [], "+coords,flow": [], "producers": [], "their EXRs": []}
    with tempfile.TemporaryDirectory() as out:
        frame_seconds(dict(tasks[0], modalities=extra, want_rgb=False), out)  # warm: scene, kernels
        for k, task in enumerate(tasks):
            runs = [("default", base), ("+coords,flow", extra)]
            for name, mods in runs if k % 2 == 0 else runs[::-1]:
                times[name].append(frame_seconds(dict(task, modalities=mods, want_rgb=False), out))
            scene = scenes.scene(task["model_spec"])
            camera = Camera(*task["camera"])
            R = np.reshape(task["R_cam_from_body"], (3, 3))
            geo = scene.render_geometry(camera, R, task["t_cam_m"])
            t0 = time.perf_counter()
            hits = FrameHits(scene, camera, R, task["t_cam_m"], geo, task["next_pose"])
            coords, flow = hits.coords(), hits.flow()
            t1 = time.perf_counter()
            F.write_image(os.path.join(out, "c.exr"), coords)
            F.write_image(os.path.join(out, "f.exr"), flow)
            t2 = time.perf_counter()
            times["producers"].append(t1 - t0)
            times["their EXRs"].append(t2 - t1)
            print(f"frame {task['frame']}: " + ", ".join(f"{n} {v[-1]:.3f} s" for n, v in times.items())
                  + f", {int((geo.face_index >= 0).sum())} target pixels", flush=True)
    med = {n: statistics.median(v) for n, v in times.items()}
    print(f"{a.target} {a.pattern}, {camera.width}x{camera.height}, {len(tasks)} frames, medians: default "
          f"{med['default']:.3f} s, with coords+flow {med['+coords,flow']:.3f} s "
          f"(x{med['+coords,flow'] / med['default']:.3f}); producers alone {med['producers']:.3f} s "
          f"({med['producers'] / med['default']:.1%} of the default frame), writing their two EXRs "
          f"{med['their EXRs']:.3f} s ({med['their EXRs'] / med['default']:.1%})")


if __name__ == "__main__":
    main()
