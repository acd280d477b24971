"""What the ``bluemarble`` Earth costs the main job: whole ``cli.py`` runs, Earth textures alternated.

    python benchmarks/bench_earth.py [--repeats 3] [--frames 48] [--textures uniform,bluemarble]
        [--decode]

Runs the main job as a user types it (``python cli.py --target cassini --pattern spiral``, its
default modalities, workers and camera) once per texture per repeat, the order of the textures
swapped every repeat (a shared machine's speed drifts), numba's cache warmed by one untimed
short run of each first; prints each run's wall time, then per texture the median and the
median over repeats of its ratio to the first texture (the two ran side by side). ``--decode`` also times the Blue Marble's decode in fresh processes
(:func:`raytrace.lighting.bluemarble_texture`, what each worker process pays once).
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


def _run(texture: str, frames: int, out: str) -> float:
    cmd = [sys.executable, str(ROOT / "cli.py"), "--target", "cassini", "--pattern", "spiral", "--frames", str(frames),
           "--earth-texture", texture, "--out", out, "--quiet"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=str(ROOT), stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=48, help="frames of the main job (its default: 48)")
    ap.add_argument("--textures", default="uniform,bluemarble")
    ap.add_argument("--decode", action="store_true")
    args = ap.parse_args()
    textures = args.textures.split(",")
    if args.decode:
        code = ("import time; t = time.perf_counter(); from raytrace.lighting import bluemarble_texture; "
                "t1 = time.perf_counter(); a = bluemarble_texture(); "
                "print(time.perf_counter() - t1, a.nbytes)")
        runs = [subprocess.run([sys.executable, "-c", code], check=True, cwd=str(ROOT), capture_output=True, text=True)
                .stdout.split() for _ in range(5)]
        print(f"decode: median {1000 * statistics.median(float(r[0]) for r in runs):.0f} ms, "
              f"{int(runs[0][1]) / 2 ** 20:.1f} MiB")
    with tempfile.TemporaryDirectory(prefix="bench-earth-") as tmp:
        for tex in textures:  # warm numba's cache
            _run(tex, 2, f"{tmp}/warm-{tex}")
        times = {tex: [] for tex in textures}
        for r in range(args.repeats):
            for tex in (textures if r % 2 == 0 else textures[::-1]):
                dt = _run(tex, args.frames, f"{tmp}/{tex}-{r}")
                times[tex].append(dt)
                print(f"repeat {r}: --earth-texture {tex}: {dt:.1f} s", flush=True)
    base = times[textures[0]]
    for tex in textures:
        ratio = statistics.median(a / b for a, b in zip(times[tex], base))
        print(f"{tex}: median {statistics.median(times[tex]):.1f} s over {len(times[tex])} runs; median of the "
              f"repeats' ratios to {textures[0]} {ratio:.3f}x")


if __name__ == "__main__":
    main()
