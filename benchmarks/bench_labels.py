"""Cost of the labels beyond the default images: keypoint states and the ``coords``, ``flow``,
``light`` and ``semantic`` modalities, in the main job's frame.

    python benchmarks/bench_labels.py [--frames 8] [--target cassini] [--pattern spiral]

Plans the main job as a user runs it (1280×960, defaults) and renders each frame in this process
once per variant, the variants interleaved (rotated each frame, so a shared machine's load falls
on all alike): the default modalities without keypoints, the default modalities with the
keypoint states (what the main job writes), and each new modality added alone and all together.
Each time the frame's images are written as the sequence folder's writer writes them (EXR / PNG,
without the checksums) into a temporary folder. Prints per variant the median frame time and its
ratio to the default frame with keypoints; and the median of the keypoint states alone.
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

import cli  # noqa: E402
from raytrace import files as F  # noqa: E402
from raytrace.camera import Camera  # noqa: E402
from raytrace.dataset import folder, scenes  # noqa: E402
from raytrace.dataset.modalities import DEFAULT, MODALITIES, relpath  # noqa: E402

NEW = ("coords", "flow", "light", "semantic")


def frame_seconds(task: dict, out: str) -> float:
    t0 = time.perf_counter()
    images, _ = cli.render_frame_images(task)
    for m in task["modalities"]:
        F.write_image(os.path.join(out, relpath(m, task["frame"]).replace("/", "_")), images[m],
                      noisy=MODALITIES[m].noisy, channel_names=MODALITIES[m].channels)
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
    variants = {"default, no keypoints": (list(DEFAULT), False), "default": (list(DEFAULT), True),
                **{f"+{m}": ([*DEFAULT, m], True) for m in NEW},
                "+" + ",".join(NEW): ([*DEFAULT, *NEW], True)}
    times = {n: [] for n in variants}
    kp_s = []
    with tempfile.TemporaryDirectory() as out:
        names = list(variants)
        frame_seconds(dict(tasks[0], modalities=variants[names[-1]][0], want_rgb=False), out)  # warm-up
        for k, task in enumerate(tasks):
            for name in names[k % len(names):] + names[:k % len(names)]:
                mods, keypoints = variants[name]
                t = dict(task, modalities=mods, want_rgb=False)
                if not keypoints:
                    t["keypoints_body_m"] = None
                times[name].append(frame_seconds(t, out))
            scene = scenes.scene(task["model_spec"])
            R = np.reshape(task["R_cam_from_body"], (3, 3))
            t0 = time.perf_counter()
            scenes.keypoint_fields(task, scene, Camera(*task["camera"]), R, task["t_cam_m"])
            kp_s.append(time.perf_counter() - t0)
            print(f"frame {task['frame']}: " + ", ".join(f"{n} {v[-1]:.3f} s" for n, v in times.items()), flush=True)
    med = {n: statistics.median(v) for n, v in times.items()}
    ref = med["default"]
    print(f"{a.target} {a.pattern}, {len(tasks)} frames, medians (ratio to the default frame):")
    for n, v in med.items():
        print(f"  {n:32s} {v:.3f} s  x{v / ref:.3f}")
    print(f"  keypoint states alone            {statistics.median(kp_s) * 1e3:.2f} ms "
          f"({statistics.median(kp_s) / ref:.2%} of the default frame)")


if __name__ == "__main__":
    main()
