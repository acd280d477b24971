"""Memory of a long main job: resident memory sampled over a run, every ``--every`` frames.

    python benchmarks/bench_memory.py [--frames 2000] [--every 100] [--target cassini] [--pattern spiral]
                                      [--out DIR] [-- extra cli.py options]

Runs ``cli.py --target … --pattern … --frames N`` (the main job as a user types it, 1280×960,
defaults) into ``--out`` (a temporary folder by default, removed afterwards) and, while it runs,
reads Linux's ``/proc`` twice a second: the frames done (the sequence's manifest records,
``.manifest/``), and for the CLI process and each of its children (the pool's workers) the
resident set (``VmRSS``) and the proportional set (``Pss`` of ``smaps_rollup``: shared pages such
as numba's and numpy's libraries divided among the processes that map them, so the processes'
sum is the job's real footprint). At every ``--every`` frames done it prints the largest
process's RSS, the processes' summed RSS and their summed PSS [MiB]; at the end the peaks, and
the growth of the summed PSS from the first printed row to the last (a leak shows as a steady
rise; allocator noise as a few MiB either way).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _children(pid: int) -> list:
    out = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children", encoding="ascii") as fh:
                out += [int(c) for c in fh.read().split()]
    except OSError:
        pass
    return out


def _tree(pid: int) -> list:
    pids, todo = [], [pid]
    while todo:
        p = todo.pop()
        pids.append(p)
        todo += _children(p)
    return pids


def _kib(path: str, key: str) -> int:
    try:
        with open(path, encoding="ascii") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def sample(pid: int) -> tuple:
    """(largest process RSS, summed RSS, summed PSS) of the process tree of ``pid`` [MiB]."""
    rss = [_kib(f"/proc/{p}/status", "VmRSS") for p in _tree(pid)]
    pss = [_kib(f"/proc/{p}/smaps_rollup", "Pss") for p in _tree(pid)]
    return max(rss, default=0) / 1024.0, sum(rss) / 1024.0, sum(pss) / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--target", default="cassini")
    ap.add_argument("--pattern", default="spiral")
    ap.add_argument("--out", default=None, help="sequence folder (kept); default: a temporary one, removed")
    ap.add_argument("extra", nargs="*", help="more cli.py options (after --)")
    a = ap.parse_args()
    tmp = None if a.out else tempfile.mkdtemp(prefix="bench_memory_")
    out = a.out or os.path.join(tmp, "seq")
    cmd = [sys.executable, str(ROOT / "cli.py"), "--target", a.target, "--pattern", a.pattern, "--frames",
           str(a.frames), "--out", out, "--quiet", *a.extra]
    print("#", " ".join(cmd[1:]), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), flush=True)
    print("| frames done | largest process RSS [MiB] | summed RSS [MiB] | summed PSS [MiB] | wall [s] |")
    print("|---|---|---|---|---|", flush=True)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    manifest = os.path.join(out, ".manifest")
    peak = [0.0, 0.0, 0.0]
    rows = []
    next_row = a.every
    try:
        while proc.poll() is None:
            s = sample(proc.pid)
            peak = [max(p, v) for p, v in zip(peak, s)]
            try:
                done = len(os.listdir(manifest))
            except OSError:
                done = 0
            if done >= next_row:
                rows.append((done, *s))
                print(f"| {done} | {s[0]:.0f} | {s[1]:.0f} | {s[2]:.0f} | {time.perf_counter() - t0:.0f} |", flush=True)
                while next_row <= done:
                    next_row += a.every
            time.sleep(0.5)
        err = proc.stderr.read()
        if proc.returncode != 0:
            raise SystemExit(f"cli.py failed ({proc.returncode}): {err.strip()[-400:]}")
    finally:
        if proc.poll() is None:
            proc.terminate()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    wall = time.perf_counter() - t0
    print(f"\npeaks: largest process RSS {peak[0]:.0f} MiB, summed RSS {peak[1]:.0f} MiB, summed PSS {peak[2]:.0f} MiB; "
          f"{a.frames} frames in {wall:.0f} s")
    if len(rows) >= 2:
        (f0, *_, p0), (f1, *_, p1) = rows[0], rows[-1]
        print(f"summed PSS from {f0} to {f1} frames: {p1 - p0:+.0f} MiB ({(p1 - p0) / max(f1 - f0, 1) * 1000:+.1f} MiB "
              "per 1000 frames)")


if __name__ == "__main__":
    main()
