"""The README's first command, cold and warm: how long a newcomer waits after ``pip install``.

    python benchmarks/bench_first_run.py [--repeats 3] [--args "--target cassini --pattern spiral"]

Runs ``python cli.py --target cassini --pattern spiral`` (48 frames, 1280×960, defaults) as a
real process, alternating

* **cold**: numba's on-disk cache and the tool's own (``ORBITSYNTH_CACHE_DIR``: scenes, radiance
  caches, tables) empty, a new pair of folders per run, as after ``pip install -e .`` in a fresh
  clone: the kernels are compiled and the radiance cache built first;
* **warm**: the same command with both caches filled (one shared pair of folders, filled by an
  untimed run first),

round by round so that load on a shared machine hits both alike, and prints each run's wall
time, the medians and their ratio. Output goes to temporary folders.

``--tree DIR`` (repeatable) runs the ``cli.py`` of each checkout in turn within every round
(its packages are imported from that checkout), each with a warm cache of its own, and adds
the ratios of each tree's medians to the first's::

    git worktree add /tmp/before <commit>
    python benchmarks/bench_first_run.py --tree /tmp/before --tree .

``--new-model`` times instead the first run of a model whose scene is not stored yet (a user's
mesh: ``--args "--mesh FILE --frames 10"``): numba's cache warm, the persistent cache empty;
with the peak resident memory of the command's largest process (its workers included) and the
peak of the processes' summed PSS (shared pages counted once). ``--stored-model``: the same for a
later run, the scene stored by an untimed first run.
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
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_memory import sample as tree_memory  # noqa: E402  ((largest RSS, summed RSS, summed PSS) [MiB])


def run(args: list, cache_dir: str, tree: Path = ROOT, scene_dir: str | None = None, sample: bool = False) -> dict:
    """One ``cli.py`` process: numba's cache in ``cache_dir``, the persistent cache in
    ``scene_dir`` (default ``cache_dir`` + ``-orbitsynth``); its wall time, peak RSS (the
    largest of the process and the children it waited for, as Linux's wait4 reports it) and, with
    ``sample``, the peak of the processes' summed PSS (read every 0.2 s: the end is then seen up
    to 0.05 s late)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, ORBITSYNTH_CACHE_DIR=scene_dir or cache_dir + "-orbitsynth")
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, str(tree / "cli.py"), *args, "--out", os.path.join(tmp, "o")],
                                stdout=subprocess.DEVNULL, stderr=err, cwd=tmp, env=env)
        pss, last = 0.0, 0.0
        while True:
            pid, status, usage = os.wait4(proc.pid, 0 if not sample else os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - last >= 0.2:
                pss, last = max(pss, tree_memory(proc.pid)[2]), time.perf_counter()
            time.sleep(0.05)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read()
    if proc.returncode != 0:
        raise RuntimeError(f"{tree}/cli.py {' '.join(args)} failed: {stderr.strip()[-400:]}")
    return {"wall_s": wall, "compiled": "compiling" in stderr, "peak_gib": usage.ru_maxrss / 2 ** 20,
            "pss_gib": pss / 1024 if sample else None}


def new_model(args: list, trees: list, repeats: int, stored: bool = False) -> None:
    """``--new-model``: each tree's first run of a model with numba's cache warm and the
    persistent cache empty, alternated; ``--stored-model`` (``stored``): a later run, the model's
    scene stored by an untimed first run. Wall time, peak RSS of the largest process and peak of
    the processes' summed PSS."""
    out = {t: [] for t in trees}
    with tempfile.TemporaryDirectory() as root:
        numba_dirs = {t: os.path.join(root, f"numba{i}") for i, t in enumerate(trees)}
        print("filling numba's caches (untimed) ...", flush=True)
        for i, t in enumerate(trees):
            run(args, numba_dirs[t], t, os.path.join(root, f"fill{i}"))
        for k in range(repeats):
            for i, t in enumerate(trees if k % 2 == 0 else trees[::-1]):
                scene_dir = os.path.join(root, f"fill{trees.index(t)}" if stored else f"scene-{t.name}-{k}")
                r = run(args, numba_dirs[t], t, scene_dir, sample=True)
                assert not r["compiled"], r
                out[t].append(r)
                print(f"round {k + 1} {t}: {r['wall_s']:.1f} s, peak {r['peak_gib']:.2f} GiB, summed PSS "
                      f"{r['pss_gib']:.2f} GiB", flush=True)
    print(f"\ncli.py {' '.join(args)}: numba's cache warm, the persistent cache "
          f"{'holding the scene' if stored else 'empty'}")
    print("| tree | " + " | ".join(f"round {k + 1}, s / GiB / GiB" for k in range(repeats))
          + " | median s | median peak RSS, GiB | median peak summed PSS, GiB |")
    print("|---|" + "---|" * (repeats + 3))
    for t in trees:
        print(f"| {t.name} | " + " | ".join(f"{r['wall_s']:.1f} / {r['peak_gib']:.2f} / {r['pss_gib']:.2f}"
                                            for r in out[t])
              + f" | {statistics.median(r['wall_s'] for r in out[t]):.1f}"
              + f" | {statistics.median(r['peak_gib'] for r in out[t]):.2f}"
              + f" | {statistics.median(r['pss_gib'] for r in out[t]):.2f} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--args", default="--target cassini --pattern spiral")
    p.add_argument("--tree", action="append", type=Path, help="a checkout whose cli.py to run (repeatable; "
                   "default: this one)")
    p.add_argument("--new-model", action="store_true", help="the first run of a model not stored yet: numba's "
                   "cache warm, the persistent cache empty")
    p.add_argument("--stored-model", action="store_true", help="a later run of a model: numba's cache warm, "
                   "its scene stored by a first run")
    a = p.parse_args()
    args = shlex.split(a.args)
    trees = [t.resolve() for t in a.tree] if a.tree else [ROOT]
    if a.new_model or a.stored_model:
        new_model(args, trees, a.repeats, stored=a.stored_model)
        return
    cold = {t: [] for t in trees}
    warm = {t: [] for t in trees}
    with tempfile.TemporaryDirectory() as root:
        warm_dirs = {t: os.path.join(root, f"warm{i}") for i, t in enumerate(trees)}
        print("filling the warm caches (untimed) ...", flush=True)
        for t in trees:
            run(args, warm_dirs[t], t)
        for k in range(a.repeats):
            for i, t in enumerate(trees):
                c = run(args, os.path.join(root, f"cold{i}-{k}"), t)
                w = run(args, warm_dirs[t], t)
                assert c["compiled"] and not w["compiled"], (c, w)
                cold[t].append(c["wall_s"])
                warm[t].append(w["wall_s"])
                print(f"round {k + 1} {t}: cold {c['wall_s']:.1f} s, warm {w['wall_s']:.1f} s", flush=True)
    print(f"\ncli.py {a.args} ({os.cpu_count()} cores)")
    print("| tree | run | " + " | ".join(f"round {k + 1}" for k in range(a.repeats)) + " | median |")
    print("|---|---|" + "---|" * (a.repeats + 1))
    for t in trees:
        for name, runs in (("cold (empty caches), s", cold[t]), ("warm, s", warm[t])):
            print(f"| {t.name} | {name} | " + " | ".join(f"{v:.1f}" for v in runs)
                  + f" | {statistics.median(runs):.1f} |")
    for t in trees:
        mc, mw = statistics.median(cold[t]), statistics.median(warm[t])
        line = f"{t.name}: cold / warm = {mc / mw:.2f}; compiling costs {mc - mw:.1f} s"
        if t != trees[0]:
            c0, w0 = statistics.median(cold[trees[0]]), statistics.median(warm[trees[0]])
            line += f"; against {trees[0].name}: cold {mc / c0:.2f}x, warm {mw / w0:.2f}x"
        print(line)


if __name__ == "__main__":
    main()
