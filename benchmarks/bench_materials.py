"""The cost of the procedural materials (crinkled MLI, solar-cell grid) on the main job.

    python benchmarks/bench_materials.py [--target cassini] [--frames 48] [--repeats 3]

Wall time of whole ``cli.py --target T --pattern spiral`` processes (1280×960, ``fast``, the
defaults otherwise), numba's cache warm from a first, untimed run of each configuration, the
two configurations interleaved round by round: the presets' procedural materials (the default)
and the same presets uniform (:attr:`raytrace.scene.Scene.procedural_materials` set False in
every process, the workers too, through a ``sitecustomize`` module on the path).
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
_OFF = "import raytrace.scene\nraytrace.scene.Scene.procedural_materials = False\n"


def run(args: list[str], procedural: bool) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ)
        path = [str(ROOT)]
        if not procedural:
            (Path(tmp) / "site").mkdir()
            (Path(tmp) / "site" / "sitecustomize.py").write_text(_OFF)
            path.insert(0, str(Path(tmp) / "site"))
        env["PYTHONPATH"] = os.pathsep.join(path + [env.get("PYTHONPATH", "")])
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, str(ROOT / "cli.py"), *args, "--out", tmp + "/o", "--quiet"],
                             capture_output=True, text=True, check=False, cwd=tmp, env=env)
        dt = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"cli.py {' '.join(args)} failed: {res.stderr.strip()[-300:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", default="cassini")
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    args = ["--target", a.target, "--pattern", "spiral", "--frames", str(a.frames)]
    configs = {"procedural (default)": True, "uniform presets": False}
    for on in configs.values():  # warm numba's cache for both
        run(args, on)
    times = {k: [] for k in configs}
    for _ in range(a.repeats):
        for k, on in configs.items():
            times[k].append(run(args, on))
    base = statistics.median(times["uniform presets"])
    print(f"| {a.target}, {a.frames} frames | wall s (median of {a.repeats}) | frames / s | ratio |")
    print("|---|---|---|---|")
    for k, ts in times.items():
        m = statistics.median(ts)
        print(f"| {k} | {m:.1f} | {a.frames / m:.2f} | {m / base:.2f} |")


if __name__ == "__main__":
    main()
