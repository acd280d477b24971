"""The README's first command, cold and warm: how long a newcomer waits after ``pip install``.

    python benchmarks/bench_first_run.py [--repeats 3] [--args "--target cassini --pattern spiral"]

Runs ``python cli.py --target cassini --pattern spiral`` (48 frames, 1280×960, defaults) as a
real process, alternating

* **cold**: numba's on-disk cache empty (a new ``NUMBA_CACHE_DIR`` per run), as after
  ``pip install -e .`` in a fresh clone: the kernels are compiled first;
* **warm**: the same command with the cache filled (one shared ``NUMBA_CACHE_DIR``, filled by
  an untimed run first),

round by round so that load on a shared machine hits both alike, and prints each run's wall
time, the medians and their ratio. Output goes to temporary folders.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(args: list, cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, str(ROOT / "cli.py"), *args, "--out", os.path.join(tmp, "o")],
                             capture_output=True, text=True, check=False, cwd=tmp, env=env)
        wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"cli.py {' '.join(args)} failed: {res.stderr.strip()[-400:]}")
    return {"wall_s": wall, "compiled": "compiling" in res.stderr, "summary": res.stdout.strip().splitlines()[-1]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--args", default="--target cassini --pattern spiral")
    a = p.parse_args()
    args = shlex.split(a.args)
    with tempfile.TemporaryDirectory() as root:
        warm_dir = os.path.join(root, "warm")
        print("filling the warm cache (untimed) ...", flush=True)
        run(args, warm_dir)
        cold, warm = [], []
        for k in range(a.repeats):
            c = run(args, os.path.join(root, f"cold{k}"))
            w = run(args, warm_dir)
            assert c["compiled"] and not w["compiled"], (c, w)
            cold.append(c["wall_s"])
            warm.append(w["wall_s"])
            print(f"round {k + 1}: cold {c['wall_s']:.1f} s, warm {w['wall_s']:.1f} s", flush=True)
    mc, mw = statistics.median(cold), statistics.median(warm)
    print(f"\ncli.py {a.args} ({os.cpu_count()} cores)")
    print("| run | " + " | ".join(f"round {k + 1}" for k in range(a.repeats)) + " | median |")
    print("|---|" + "---|" * (a.repeats + 1))
    print("| cold (empty numba cache), s | " + " | ".join(f"{v:.1f}" for v in cold) + f" | {mc:.1f} |")
    print("| warm, s | " + " | ".join(f"{v:.1f}" for v in warm) + f" | {mw:.1f} |")
    print(f"cold / warm = {mc / mw:.2f}; compiling costs {mc - mw:.1f} s")


if __name__ == "__main__":
    main()
