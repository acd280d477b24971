"""The radiance cache's build on meshes a user brings, two checkouts side by side.

    git worktree add /tmp/old <rev>
    python benchmarks/bench_cache_meshes.py /tmp/old . --scenes A.json B.json [--targets cassini]
        [--repeats 3]

``render-scene`` builds the target's radiance cache (``raytrace.cache.RadianceCache``) for every
call, so for a one-frame render of a user's mesh the build is most of the wall time. Per scene
file (its ``meshes``, or its ``target``) and per built-in target, each checkout builds the cache
in a fresh process (that checkout's ``raytrace`` first on ``sys.path``; Embree's BVH and the
scene built before the clock starts; numba's cache warmed by one build first), the two
checkouts alternated, the order swapped every repeat. Printed per model: the faces and parts,
each checkout's median seconds and peak resident memory of the process, their ratio (B / A),
and whether the two caches are the same bits (every array, sparse matrix and record; else how
many values differ, and by how much at most, relatively).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def _worker(model_spec: str, dump: str | None) -> None:
    """Build the cache of ``model_spec`` (a scene file or a built-in target) once and print
    JSON: seconds, faces, parts, peak RSS [MiB]; with ``dump``, pickle its arrays there."""
    import pickle
    import resource
    import time

    from raytrace.scene import Scene
    if model_spec.endswith(".json"):
        from raytrace.scenefile import load_scene_file
        model = load_scene_file(model_spec).model
    else:
        from raytrace.targets import load_target
        model = load_target(model_spec)
    scene = Scene(model)
    scene.embree, scene.direct
    t0 = time.perf_counter()
    cache = scene.radiance_cache()
    seconds = time.perf_counter() - t0
    if dump:
        import scipy.sparse as sp

        def plain(v):
            if sp.issparse(v):
                return ("csr", v.indptr, v.indices, v.data, v.shape)
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [plain(x) for x in v]
            return v

        state = {k: plain(v) for k, v in vars(cache).items() if k != "scene" and not callable(v)}
        with open(dump, "wb") as f:
            pickle.dump(state, f)
    print(json.dumps({"seconds": seconds, "faces": int(len(scene.faces)), "parts": len(model.components),
                      "rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}), flush=True)


def _diff(a, b) -> tuple[int, float]:
    """(values that differ, their largest relative difference) between two dumped caches;
    (-1, inf) where their structure, shapes or dtypes differ."""
    import numpy as np
    if isinstance(a, dict):
        if a.keys() != b.keys():
            return -1, np.inf
        parts = [_diff(a[k], b[k]) for k in a]
    elif isinstance(a, (list, tuple)):
        if len(a) != len(b):
            return -1, np.inf
        parts = [_diff(x, y) for x, y in zip(a, b)]
    elif isinstance(a, np.ndarray):
        if not isinstance(b, np.ndarray) or a.dtype != b.dtype or a.shape != b.shape:
            return -1, np.inf
        if a.size == 0:
            return 0, 0.0
        # value by value, bit for bit (NaN equals NaN, −0 differs from +0)
        bad = (a.reshape(a.size, -1).view(np.uint8) != b.reshape(b.size, -1).view(np.uint8)).any(axis=1)
        bad = bad.reshape(a.shape)
        n = int(np.count_nonzero(bad))
        if n == 0:
            return 0, 0.0
        x, y = a[bad].astype(np.float64), b[bad].astype(np.float64)
        return n, float(np.max(np.abs(x - y) / np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-300)))
    else:
        return (0, 0.0) if a == b else (-1, np.inf)
    if any(n < 0 for n, _ in parts):
        return -1, np.inf
    return sum(n for n, _ in parts), max([r for _, r in parts], default=0.0)


def _run(tree: str, spec: str, dump: str | None = None) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", spec] + (["--dump", dump] if dump else [])
    out = subprocess.run(cmd, cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("trees", nargs="*", help="checkout A (the reference), checkout B")
    ap.add_argument("--scenes", nargs="*", default=[], help="scene files (render-scene's JSON)")
    ap.add_argument("--targets", nargs="*", default=[], help="built-in targets")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--dump", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        sys.path.insert(0, os.getcwd())
        _worker(args.worker, args.dump)
        return
    if len(args.trees) != 2:
        ap.error("give two checkouts: A (the reference) and B")
    import pickle
    trees = [str(Path(t).resolve()) for t in args.trees]
    specs = [str(Path(s).resolve()) for s in args.scenes] + list(args.targets)
    if not specs:
        ap.error("give --scenes and/or --targets")
    print(f"# A: {trees[0]}\n# B: {trees[1]}")
    print("| model | faces | parts | A s | B s | B / A | A peak MiB | B peak MiB | same bits? |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for spec in specs:
            dumps = [os.path.join(tmp, f"{k}.pkl") for k in range(2)]
            first = [_run(t, spec, d) for t, d in zip(trees, dumps)]  # warms numba's cache; the bits
            with open(dumps[0], "rb") as fa, open(dumps[1], "rb") as fb:
                n_diff, rel = _diff(pickle.load(fa), pickle.load(fb))
            same = "yes" if n_diff == 0 else ("NO (structure)" if n_diff < 0 else f"{n_diff} values, ≤ {rel:.1e} rel.")
            runs = [[], []]
            for r in range(args.repeats):
                for k in ((0, 1) if r % 2 == 0 else (1, 0)):
                    runs[k].append(_run(trees[k], spec))
            sec = [statistics.median(x["seconds"] for x in rr) for rr in runs]
            rss = [statistics.median(x["rss_mib"] for x in rr) for rr in runs]
            name = Path(spec).stem if spec.endswith(".json") else spec
            print(f"| {name} | {first[0]['faces']:,} | {first[0]['parts']} | {sec[0]:.2f} | {sec[1]:.2f} | "
                  f"{sec[1] / sec[0]:.3f} | {rss[0]:.0f} | {rss[1]:.0f} | {same} |", flush=True)


if __name__ == "__main__":
    main()
