"""Time :func:`raytrace.shade.render` and its stages on the main job's frames, as a worker renders
them (one numba thread), and compare two checkouts side by side.

    python benchmarks/bench_render_frame.py [--frames 0,6,12,18,24,30,36,42] [--rounds 3]
    python benchmarks/bench_render_frame.py --other /path/to/other/checkout [--rounds 3]

Plans the main job as a user runs it (``--target cassini --pattern spiral``: 48 frames, 1280×960,
``fast``, the Blue Marble Earth behind the target) and renders the listed frames in a child process
per round and checkout (``--other``: this checkout and the other alternate, the order swapped every
round, so a shared machine's load falls on both alike), each frame once after one warm-up frame.
Per stage the wall and CPU seconds: the whole ``render``, Earth behind the target
(``_background.earth_background``), the lighting context (``_Context``: the radiance cache's solve,
the environment's tables), the edge sub-samples' trace and shading (``_antialias._trace_chunk``,
``_supersample``). Prints per checkout the median over frames and rounds of each, the ratio of the
medians (this / other) and whether the two checkouts' radiance images are the same bytes.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("render", "earth_background", "context", "trace_chunk", "supersample")


def _child(root: str, frames: list[int], out: str) -> None:
    """Render ``frames`` with the checkout at ``root``; write {stage: [(wall, cpu), ...]} and the
    radiance images into the folder ``out``."""
    sys.path.insert(0, root)
    import numba
    import numpy as np
    numba.set_num_threads(1)  # as a worker of the main job
    import cli
    from raytrace import _antialias, _background, shade
    from raytrace.camera import Camera
    from raytrace.dataset import folder, scenes
    assert Path(shade.__file__).resolve().is_relative_to(Path(root).resolve()), shade.__file__
    times = {s: [] for s in STAGES}
    acc = {}

    def wrap(mod, name, key):
        f = getattr(mod, name)

        @functools.wraps(f)
        def g(*a, **k):
            w, c = time.perf_counter(), time.process_time()
            r = f(*a, **k)
            dw, dc = acc.get(key, (0.0, 0.0))
            acc[key] = (dw + time.perf_counter() - w, dc + time.process_time() - c)
            return r
        setattr(mod, name, g)

    wrap(_background, "earth_background", "earth_background")
    wrap(shade, "_Context", "context")
    wrap(_antialias, "_trace_chunk", "trace_chunk")
    wrap(_antialias, "_supersample", "supersample")
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral"]))
    tasks, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)

    def render(task):
        c, r = task["cfg"], task["cfg"]["render"]
        scene = scenes.scene(task["model_spec"], task.get("prebuilt"))
        seed, _ = folder.frame_seeds(c["sequence"]["seed"], task["frame"])
        lighting = scenes.lighting_of(task["light"], r, scenes.star_field(c), c["sequence"]["seed"])
        acc.clear()
        w, cpu = time.perf_counter(), time.process_time()
        frame = shade.render(scene, Camera(*task["camera"]), np.reshape(task["R_cam_from_body"], (3, 3)),
                             np.asarray(task["t_cam_m"], dtype=np.float64), lighting, quality=r["quality"],
                             samples=r["samples"], seed=seed)
        acc["render"] = (time.perf_counter() - w, time.process_time() - cpu)
        return frame

    render(tasks[frames[0]])  # warm-up: the scene, its cache, numba's kernels loaded
    for f in frames:
        frame = render(tasks[f])
        for s in STAGES:
            times[s].append(acc.get(s, (0.0, 0.0)))
        np.save(os.path.join(out, f"radiance_{f}.npy"), frame.radiance)
    with open(os.path.join(out, "times.json"), "w") as fh:
        json.dump(times, fh)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="0,6,12,18,24,30,36,42")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--other", help="another checkout of the project to compare with")
    ap.add_argument("--child", nargs=2, metavar=("ROOT", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    frames = [int(x) for x in a.frames.split(",")]
    if a.child:
        _child(a.child[0], frames, a.child[1])
        return
    roots = [str(ROOT)] + ([str(Path(a.other).resolve())] if a.other else [])
    names = ["this"] + (["other"] if a.other else [])
    times = {n: {s: [] for s in STAGES} for n in names}
    same = True
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.rounds):
            order = list(range(len(roots)))[::(-1 if k % 2 else 1)]
            for i in order:
                out = os.path.join(tmp, f"{names[i]}_{k}")
                os.makedirs(out)
                env = dict(os.environ, PYTHONPATH=roots[i])
                subprocess.run([sys.executable, __file__, "--frames", a.frames, "--child", roots[i], out], check=True,
                               env=env)
                with open(os.path.join(out, "times.json")) as fh:
                    for s, v in json.load(fh).items():
                        times[names[i]][s] += v
            if a.other:
                import numpy as np
                same &= all(np.load(os.path.join(tmp, f"this_{k}", f"radiance_{f}.npy")).tobytes()
                            == np.load(os.path.join(tmp, f"other_{k}", f"radiance_{f}.npy")).tobytes() for f in frames)
            print(f"round {k + 1}/{a.rounds} done", flush=True)
    med = {n: {s: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for s, v in t.items()}
           for n, t in times.items()}
    print(f"frames {frames}, {a.rounds} rounds, one numba thread; median per frame, wall / CPU [ms]")
    for s in STAGES:
        row = "  ".join(f"{n} {1e3 * med[n][s][0]:7.1f} / {1e3 * med[n][s][1]:7.1f}" for n in names)
        if a.other and med["other"][s][0] > 0:
            row += (f"  ratio {med['this'][s][0] / med['other'][s][0]:.3f} / "
                    f"{med['this'][s][1] / max(med['other'][s][1], 1e-12):.3f}")
        print(f"{s:18s} {row}")
    if a.other:
        print("radiance images the same bytes:", "yes" if same else "NO")


if __name__ == "__main__":
    main()
