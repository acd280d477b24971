#!/usr/bin/env python3
"""Benchmark: ``cli.py export`` of a long sequence at the main job's 1280×960.

    python cli.py --target cassini --pattern spiral --frames 40 --out /tmp/exp_seq   # once
    python benchmarks/bench_export.py /tmp/exp_seq [--frames 2000] [--repeats 3] [--formats bop]

Builds a sequence of ``--frames`` frames from the rendered one by hard-linking its files in
turn (frame k uses the files and pose of rendered frame k mod n; no pixels are copied), then
exports it with ``--workers`` processes (default: the usable cores) and prints, per format, the
median wall time of the repeats, the frames per second and the CPU time per frame (this
process and its workers; on a busy machine the wall time says little, the CPU time divided by
the cores is what an idle machine's wall time approaches). Each export goes into a new folder
under a temporary directory (removed at the end). The goal: 2000 frames at
1280×960 in ≤ 60 s on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from raytrace._threads import available_cores
from raytrace.export.command import export_main


def long_sequence(src: Path, dst: Path, frames: int) -> None:
    """``dst``: ``frames`` frames made of ``src``'s rendered frames by hard links."""
    labels = json.loads((src / "labels.json").read_text())
    labels = labels["frames"] if isinstance(labels, dict) else labels
    rendered = [r for r in labels if r.get("files")]
    dst.mkdir(parents=True)
    for name in ("camera.json", "scenario.json"):
        if (src / name).is_file():
            shutil.copyfile(src / name, dst / name)
    shutil.copytree(src / "model", dst / "model")
    out = []
    for k in range(frames):
        rec = dict(rendered[k % len(rendered)])
        rec["frame"] = k
        files = {}
        for modality, rel in rec["files"].items():
            new = f"{modality}/{k:06d}{Path(rel).suffix}"
            (dst / modality).mkdir(exist_ok=True)
            os.link(src / rel, dst / new)
            files[modality] = new
        rec["files"] = files
        out.append(rec)
    (dst / "labels.json").write_text(json.dumps(out))


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (the pool's workers)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("sequence", type=Path, help="a rendered sequence folder (1280×960)")
    p.add_argument("--frames", type=int, default=2000)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--workers", type=int, default=available_cores())
    p.add_argument("--formats", default="bop", help="comma-separated (bop, speedplus, coco)")
    args = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-export-"))
    try:
        seq = work / "seq"
        long_sequence(args.sequence, seq, args.frames)
        cam = json.loads((seq / "camera.json").read_text())
        print(f"{platform.processor() or platform.machine()}, {available_cores()} usable cores, "
              f"{args.workers} workers; {args.frames} frames of {cam['width']}×{cam['height']} "
              f"(from {args.sequence})")
        print("\n| format | runs [s] | median [s] | frames/s | s per 2000 frames | CPU per frame [ms] |\n"
              "|---|---|---|---|---|---|")
        for fmt in args.formats.split(","):
            times, cpus = [], []
            for r in range(args.repeats):
                out = work / f"{fmt}_{r}"
                cpu0 = _cpu_s()
                t0 = time.perf_counter()
                status = export_main(["--format", fmt, str(seq), "--out", str(out), "--workers", str(args.workers),
                                      "--quiet"])
                times.append(time.perf_counter() - t0)
                cpus.append(_cpu_s() - cpu0)
                if status != 0:
                    print(f"{fmt}: exit status {status}", file=sys.stderr)
                    break
                shutil.rmtree(out)
            if len(times) == args.repeats:
                med = statistics.median(times)
                print(f"| {fmt} | {', '.join(f'{t:.1f}' for t in times)} | {med:.1f} | {args.frames / med:.1f} | "
                      f"{med * 2000 / args.frames:.1f} | {1000 * statistics.median(cpus) / args.frames:.0f} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
