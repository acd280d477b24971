"""What the realistic Earth and the procedural materials cost the main job, side by side.

    python benchmarks/bench_realism.py [--target cassini] [--frames 48] [--repeats 3] [--decode]

Wall time of whole ``cli.py --target T --pattern spiral`` processes (1280×960, ``fast``, the
defaults otherwise; numba's cache warmed by one untimed short run of each configuration), the
configurations interleaved round by round, their order reversed every other round (a shared
machine's speed drifts):

* ``plain``: ``--earth-texture procedural`` and the material presets uniform
  (:attr:`raytrace.scene.Scene.procedural_materials` set False in every process, the workers
  too, through a ``sitecustomize`` module on the path) — the look without either;
* ``bluemarble Earth``: the default Earth, uniform presets;
* ``default``: the main job as a user types it (Blue Marble Earth, crinkled MLI, solar-cell grids).

Prints a Markdown table: medians, and per configuration the median over rounds of its ratio to
``plain`` in the same round. ``--decode`` also times the Blue Marble image's decode in fresh
processes (:func:`raytrace.lighting.bluemarble_texture`, what each worker process pays once).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_UNIFORM = "import raytrace.scene\nraytrace.scene.Scene.procedural_materials = False\n"
CONFIGS = {"plain": ("procedural", False), "bluemarble Earth": ("bluemarble", False), "default": ("bluemarble", True)}


def run(args: list[str], texture: str, procedural: bool) -> float:
    with tempfile.TemporaryDirectory(prefix="bench-realism-") as tmp:
        env = dict(os.environ)
        path = [str(ROOT)]
        if not procedural:
            (Path(tmp) / "site").mkdir()
            (Path(tmp) / "site" / "sitecustomize.py").write_text(_UNIFORM)
            path.insert(0, str(Path(tmp) / "site"))
        env["PYTHONPATH"] = os.pathsep.join(path + [env.get("PYTHONPATH", "")])
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, str(ROOT / "cli.py"), *args, "--earth-texture", texture,
                              "--out", tmp + "/o", "--quiet"], capture_output=True, text=True, check=False, cwd=tmp,
                             env=env)
        dt = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"cli.py {' '.join(args)} failed: {res.stderr.strip()[-300:]}")
    return dt


def decode_ms() -> tuple[float, float]:
    """(median decode time [ms], texture size [MiB]) of the Blue Marble image in 5 fresh processes."""
    code = ("import time; from raytrace.lighting import bluemarble_texture; t = time.perf_counter(); "
            "a = bluemarble_texture(); print(time.perf_counter() - t, a.nbytes)")
    runs = [subprocess.run([sys.executable, "-c", code], check=True, cwd=str(ROOT), capture_output=True, text=True)
            .stdout.split() for _ in range(5)]
    return 1000 * statistics.median(float(r[0]) for r in runs), int(runs[0][1]) / 2 ** 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", default="cassini")
    ap.add_argument("--frames", type=int, default=48, help="frames of the main job (its default: 48)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--decode", action="store_true")
    a = ap.parse_args()
    if a.decode:
        ms, mib = decode_ms()
        print(f"Blue Marble decode: median {ms:.0f} ms, {mib:.1f} MiB")
    args = ["--target", a.target, "--pattern", "spiral"]
    for texture, procedural in CONFIGS.values():  # warm numba's cache for each
        run(args + ["--frames", "2"], texture, procedural)
    times = {k: [] for k in CONFIGS}
    for r in range(a.repeats):
        for k in (list(CONFIGS) if r % 2 == 0 else list(CONFIGS)[::-1]):
            times[k].append(run(args + ["--frames", str(a.frames)], *CONFIGS[k]))
            print(f"round {r}: {k}: {times[k][-1]:.1f} s", file=sys.stderr, flush=True)
    print(f"| {a.target}, {a.frames} frames | wall s (median of {a.repeats}) | frames / s | ratio to plain |")
    print("|---|---|---|---|")
    for k, ts in times.items():
        ratio = statistics.median(x / b for x, b in zip(ts, times["plain"]))
        print(f"| {k} | {statistics.median(ts):.1f} | {a.frames / statistics.median(ts):.2f} | {ratio:.3f} |")


if __name__ == "__main__":
    main()
