"""End-to-end speed of the pipeline: the main job, its stages, workers, and the paper dataset.

    python benchmarks/bench_pipeline.py [--frames 48] [--repeats 3] [--dataset-frames 25]

Every figure is the wall time of a real ``cli.py`` process (start-up, planning, rendering,
degradation, file writing; numba's on-disk cache warm from a first, untimed run), median of
``--repeats``, all configurations interleaved round by round so that load on this shared
machine hits them alike:

* the main job ``--target cassini --pattern spiral`` as a user runs it (1280×960, defaults),
  with 1 and 2 worker processes;
* its stages by difference, same frames, 2 workers: geometry only (mask, depth, normals),
  + shading (clean RGB), + the physical degradation (degraded RGB), + the paper degradation
  instead;
* ``cli.py dataset`` with ``--frames`` reduced to ``--dataset-frames`` per target, projected
  linearly to the paper's 4 × 500 frames (the per-run fixed cost measured separately and
  added once per target).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(args: list[str]) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, str(ROOT / "cli.py"), *args, "--out", tmp + "/o", "--quiet"],
                             capture_output=True, text=True, check=False, cwd=tmp)
        dt = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"cli.py {' '.join(args)} failed: {res.stderr.strip()[-300:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dataset-frames", type=int, default=25)
    a = ap.parse_args()
    base = ["--target", "cassini", "--pattern", "spiral", "--frames", str(a.frames)]
    geo = ["--modalities", "mask,depth,normal", "--degrade", "none"]
    configs = {
        "main job, 1 worker": base + ["--workers", "1"],
        "main job, 2 workers": base + ["--workers", "2"],
        "geometry only (mask, depth, normal)": base + geo,
        "+ shading (clean rgb)": base + ["--modalities", "rgb,mask,depth,normal", "--degrade", "none"],
        "+ physical degradation (rgb_degraded)": base + ["--modalities", "rgb,rgb_degraded,mask,depth,normal",
                                                         "--degrade", "physical"],
        "+ paper degradation instead": base + ["--modalities", "rgb,rgb_degraded,mask,depth,normal",
                                               "--degrade", "paper"],
        "dataset, 1 frame per target (fixed cost)": ["dataset", "--frames", "1"],
        f"dataset, {a.dataset_frames} frames per target": ["dataset", "--frames", str(a.dataset_frames)],
    }
    for args in configs.values():  # warm numba's cache and the OS file cache, untimed
        run(args)
    times = {k: [] for k in configs}
    for _ in range(a.repeats):
        for k, args in configs.items():
            times[k].append(run(args))
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"# {a.frames} frames of cassini/spiral at 1280x960; median of {a.repeats}; "
          f"{time.strftime('%Y-%m-%d %H:%M')}")
    print("| configuration | wall s (median) | frames / s | ratio to main job, 2 workers |")
    print("|---|---|---|---|")
    ref = med["main job, 2 workers"]
    for k, t in med.items():
        n = a.frames if not k.startswith("dataset") else 4 * (1 if "fixed" in k else a.dataset_frames)
        print(f"| {k} | {t:.1f} | {n / t:.2f} | {t / ref:.2f} |")
    fixed = med["dataset, 1 frame per target (fixed cost)"]
    per_frame = (med[f"dataset, {a.dataset_frames} frames per target"] - fixed) / (4 * (a.dataset_frames - 1))
    projected = fixed + per_frame * (4 * 500 - 4)
    print(f"\nPaper dataset (4 x 500 frames, rgb+mask+depth+normal, no degradation): projected "
          f"{projected / 60:.1f} min ({per_frame:.3f} s per frame + {fixed:.1f} s fixed)")


if __name__ == "__main__":
    main()
