"""Earth behind the target, :func:`raytrace._background.earth_background`, of this checkout against
another revision's on the same inputs: the same bytes, and the CPU time of both interleaved.

    python benchmarks/bench_earth_background.py [--ref ec82ff6] [--main-frames 0,3,6,...,45]
        [--targets tiangong,spacedragon,icesat,cassini] [--target-frames 0,125,250,375] [--repeats 3]
        [--threads 1]

The inputs are those of real frames: the main job (``cli.py --target cassini --pattern spiral``,
48 frames 1280×960, the Blue Marble behind the target) and the dataset's four targets on their
spiral (``--frames 500``, the listed frames). Each frame is planned and rendered as a worker
renders it (``cli.render_frame_images``) up to the kernel's call, whose arguments are kept (the
frame goes no further). The reference revision's kernel modules (``git archive`` of its
``raytrace`` package, unpacked into a temporary folder under another package name, so both
load in one process and numba caches each apart) then run on copies of the same arguments as
this checkout's, on ``--threads`` numba threads (1: the serial build, as a pool worker of the
main job), the two alternated frame by frame and their order swapped every round.

Prints per frame the share of the image that sees Earth, the median CPU time (``time.process_time``)
of each over ``--repeats`` rounds and their ratio, and whether ``earth_px`` and ``rad`` are the same
bytes; then the median ratio and the ratio of the summed medians. Exits 1 if any frame differs.
The machine may be shared: CPU time, medians and the interleaving keep the ratio fair, the
absolute times are not figures to quote.
"""

from __future__ import annotations

import argparse
import importlib
import io
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REF_PACKAGE = "raytrace_ref"


class _Stop(Exception):
    """Raised by the wrapped kernel once it has its arguments: the frame goes no further."""


def capture(argv: list[str], frames: list[int]) -> list[tuple[int, list]]:
    """The arguments of ``earth_background`` on the listed frames of the job ``argv`` (frames
    without Earth in view left out)."""
    import cli
    from raytrace import _background
    from raytrace.dataset import folder
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(argv))
    plan = cli.plan_sequence(cfg, given)
    tasks, _ = folder.tasks_for(plan, "", None, write=False)
    kernel = _background.earth_background
    got = []

    def keep(*args):
        got.append([a.copy() if isinstance(a, np.ndarray) else a for a in args])
        raise _Stop

    out = []
    _background.earth_background = keep
    try:
        for f in frames:
            got.clear()
            try:
                cli.render_frame_images(dict(tasks[f], modalities=["rgb"]))
            except _Stop:
                pass
            if got:
                out.append((f, got[0]))
    finally:
        _background.earth_background = kernel
    return out


def reference_package(ref: str, into: Path):
    """The ``raytrace`` package of revision ``ref`` unpacked into ``into`` as :data:`REF_PACKAGE`
    (an empty ``__init__``: the kernels' modules import only each other), its
    ``_background`` module imported."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", ref, "raytrace"], check=True,
                          capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    (into / "raytrace").rename(into / REF_PACKAGE)
    (into / REF_PACKAGE / "__init__.py").write_text("")
    sys.path.insert(0, str(into))
    return importlib.import_module(REF_PACKAGE + "._background")


def run(kernel, args: list):
    """One call of ``kernel`` on copies of the outputs: (CPU seconds, earth_px, rad)."""
    a = list(args)
    a[14] = a[14].copy()
    a[15] = a[15].copy()
    t0 = time.process_time()
    kernel(*a)
    return time.process_time() - t0, a[14], a[15]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref", default="ec82ff6", help="the revision to compare with (git)")
    ap.add_argument("--main-frames", default=",".join(str(f) for f in range(0, 48, 3)))
    ap.add_argument("--targets", default="tiangong,spacedragon,icesat,cassini")
    ap.add_argument("--target-frames", default="0,125,250,375")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    import numba
    numba.set_num_threads(args.threads)
    from raytrace import _background as new
    assert Path(new.__file__).resolve().is_relative_to(ROOT), new.__file__

    jobs = [("main", ["--target", "cassini", "--pattern", "spiral"], args.main_frames)]
    for target in filter(None, args.targets.split(",")):
        jobs.append((target, ["--target", target, "--pattern", "spiral", "--frames", "500"], args.target_frames))
    cases = []
    for name, argv, frames in jobs:
        for f, a in capture(argv, [int(x) for x in frames.split(",") if x]):
            cases.append((f"{name} {f}", a))
    print(f"{len(cases)} frames with Earth in view; reference {args.ref}, {args.threads} numba thread(s)", flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="bench_earth_ref_"))
    try:
        old = reference_package(args.ref, tmp)
        kernels = {"ref": old.earth_background, "new": new.earth_background}
        run(kernels["ref"], cases[0][1])  # compile or load both first
        run(kernels["new"], cases[0][1])
        times = {label: {"ref": [], "new": []} for label, _ in cases}
        same, share = {}, {}
        for r in range(args.repeats):
            for k, (label, a) in enumerate(cases):
                order = ("ref", "new") if (r + k) % 2 == 0 else ("new", "ref")
                res = {which: run(kernels[which], a) for which in order}
                for which in order:
                    times[label][which].append(res[which][0])
                if r == 0:
                    share[label] = float(np.mean(res["new"][1]))
                    same[label] = (res["ref"][1].tobytes() == res["new"][1].tobytes()
                                   and res["ref"][2].tobytes() == res["new"][2].tobytes())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    print(f"{'frame':18s} {'Earth':>6s} {'ref ms':>8s} {'new ms':>8s} {'ratio':>6s}  same bytes")
    ratios, sums = [], [0.0, 0.0]
    for label, _ in cases:
        t_ref = statistics.median(times[label]["ref"])
        t_new = statistics.median(times[label]["new"])
        ratios.append(t_new / t_ref)
        sums[0] += t_ref
        sums[1] += t_new
        print(f"{label:18s} {share[label]:6.0%} {t_ref * 1e3:8.1f} {t_new * 1e3:8.1f} {t_new / t_ref:6.3f}  {same[label]}")
    print(f"median ratio {statistics.median(ratios):.3f}, ratio of the summed medians {sums[1] / sums[0]:.3f}; "
          f"{'all the same bytes' if all(same.values()) else 'SOME FRAMES DIFFER'}")
    return 0 if all(same.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
