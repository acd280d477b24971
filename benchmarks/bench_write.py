"""Writing a frame's files: time and bytes of each PNG / EXR setting, and of the whole frame as the
sequence folder's writer writes it, on the main job's frames.

    python benchmarks/bench_write.py choices [--frames 48] [--cache DIR]
    python benchmarks/bench_write.py frame   [--frames 48] [--cache DIR] [--old REF]

Plans the main job as a user runs it (``--target cassini --pattern spiral``: 1280×960, ``fast``,
the default modalities rgb, rgb_degraded (physical), mask, depth, normal) and renders its frames
on one numba thread, as a pool worker does; ``--cache DIR`` keeps the rendered images there
(``NNN.npz``) so that later runs only write. OpenImageIO runs on one thread (``threads`` and
``exr_threads`` 1: a worker shares the machine's cores with the others, so writer threads
gain nothing there).

``choices``: each image kind (rgb, rgb_degraded, mask, depth, normal) written with each
candidate setting (PNG filter × zlib level, EXR compression, half floats), the settings
interleaved (rotated each frame, so a shared machine's load falls on all alike). Prints per
setting the median wall time, the median CPU time (all threads) and the median bytes over the
frames, and checks that every file reads back (OpenImageIO ``ImageBuf``) to the same pixels
(half floats: within their rounding bound).

``frame``: the whole frame written by :func:`raytrace.dataset.folder.write_frame` (files,
checksums, manifest record) with ``--compression fast`` and ``compact``, and fast with
``--normal-format half``; with ``--old REF``
also by the writer of the git revision ``REF`` (a worktree of it, imported in a child
process), interleaved with the new one frame by frame. Prints medians (wall and CPU time) and ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MAIN_JOB = ["--target", "cassini", "--pattern", "spiral"]


def frames(n: int, cache: str | None):
    """(task, images) of the main job's first ``n`` frames (rendered, or read from ``cache``)."""
    import numba
    numba.set_num_threads(1)
    import cli
    from raytrace.dataset import folder
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(MAIN_JOB))
    plan = cli.plan_sequence(cfg, given)
    tasks, _ = folder.tasks_for(plan, "", None, write=False)
    for task in tasks[:n]:
        task = dict(task, modalities=list(cfg["output"]["modalities"]), want_rgb=False)
        path = os.path.join(cache, f"{task['frame']:03d}.npz") if cache else None
        if path and os.path.exists(path):
            with np.load(path) as z:
                images = {k: z[k] for k in z.files}
        else:
            images, _ = cli.render_frame_images(task)
            if path:
                os.makedirs(cache, exist_ok=True)
                np.savez(path + ".tmp.npz", **images)
                os.replace(path + ".tmp.npz", path)
        yield task, images


def _oiio_one_thread():
    import OpenImageIO as oiio
    oiio.attribute("threads", 1)
    oiio.attribute("exr_threads", 1)
    return oiio


# --------------------------------------------------------------------------- candidate settings
PNG_FILTERS = {"none": 8, "sub": 16, "up": 32, "avg": 64, "paeth": 128, "all": 248}


def _png(filt: str, level: int) -> dict:
    return {"png:filter": PNG_FILTERS[filt], "png:compressionLevel": level}


_OWN = [(f, z, st) for f in ("none", "sub", "up") for z, st in ((1, "default"), (1, "rle"), (1, "huffman"),
                                                                  (2, "default"), (3, "default"), (6, "default"))]
_EXR = ("none", "rle", "zips", "zip", "zip:1", "piz", "htj2k32")  # OpenImageIO's (OpenEXR's) writer
_OWN_EXR = (("zip", 1, "default"), ("zip", 1, "rle"), ("zip", 6, "default"), ("zips", 1, "default"))

CANDIDATES = {  # image kind -> setting -> (writer, attributes)
    "rgb": {"oiio none z6 (the old rgb)": ("png", _png("none", 6)),
            "oiio all z6 (libpng default)": ("png", _png("all", 6)),
            "oiio up z1": ("png", _png("up", 1))}
           | {f"png {f} z{z} {st}": ("png-own", (f, z, st)) for f, z, st in _OWN},
    "rgb_degraded": {"oiio avg z1 (the old rgb_degraded)": ("png", _png("avg", 1)),
                     "oiio up z1": ("png", _png("up", 1))}
                    | {f"png {f} z{z} {st}": ("png-own", (f, z, st)) for f, z, st in _OWN},
    "mask": {"oiio none z6 (the old mask)": ("png", _png("none", 6))}
            | {f"png {f} z{z} {st}": ("png-own", (f, z, st)) for f, z, st in _OWN},
    "depth": {f"oiio exr {c}": ("exr", {"compression": c}) for c in _EXR}
             | {f"exr {c} z{z} {st}": ("exr-own", (c, z, st, False)) for c, z, st in _OWN_EXR},
    "normal": {f"oiio exr {c}": ("exr", {"compression": c}) for c in _EXR}
              | {f"oiio exr half {c}": ("exr-half", {"compression": c}) for c in ("zip", "htj2k32")}
              | {f"exr {c} z{z} {st}": ("exr-own", (c, z, st, False)) for c, z, st in _OWN_EXR}
              | {f"exr half {c} z{z} {st}": ("exr-own", (c, z, st, True)) for c, z, st in _OWN_EXR},
}


def _write(oiio, path: str, pixels: np.ndarray, kind: str, attrs) -> None:
    if kind == "png-own":
        from raytrace.files import png_bytes
        f, z, st = attrs
        with open(path, "wb") as fh:
            fh.write(png_bytes(pixels, srgb=pixels.ndim == 3, filter=f, level=z, strategy=st))
        return
    if kind == "exr-own":
        from raytrace.files import exr_bytes
        c, z, st, half = attrs
        with open(path, "wb") as fh:
            fh.write(exr_bytes(pixels, compression=c, level=z, strategy=st, half=half))
        return
    px = pixels if pixels.ndim == 3 else pixels[:, :, None]
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16,
           np.dtype(np.float32): oiio.FLOAT}[px.dtype]
    spec = oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], oiio.HALF if kind == "exr-half" else fmt)
    for k, v in attrs.items():
        spec.attribute(k, v)
    if kind.startswith("exr"):
        spec.attribute("DateTime", "")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, spec) and out.write_image(np.ascontiguousarray(px)), out.geterror()
    out.close()


def _check(oiio, path: str, pixels: np.ndarray, kind: str, attrs) -> None:
    buf = oiio.ImageBuf(path)
    back = buf.get_pixels(oiio.FLOAT if pixels.dtype == np.float32 else
                          {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16}[pixels.dtype])
    assert not buf.has_error, buf.geterror()
    back = back.reshape(pixels.shape)
    if kind == "exr-half" or (kind == "exr-own" and attrs[3]):
        assert np.array_equal(back, pixels.astype(np.float16).astype(np.float32)), path
    else:
        assert np.array_equal(back, pixels, equal_nan=True), path


def choices(a) -> None:
    oiio = _oiio_one_thread()
    rows = {(m, name): ([], [], []) for m, c in CANDIDATES.items() for name in c}
    keys = list(rows)
    with tempfile.TemporaryDirectory() as tmp:
        for k, (task, images) in enumerate(frames(a.frames, a.cache)):
            for m, name in keys[k % len(keys):] + keys[:k % len(keys)]:
                kind, attrs = CANDIDATES[m][name]
                path = os.path.join(tmp, f"x.{'exr' if kind.startswith('exr') else 'png'}")
                w0, c0 = time.perf_counter(), time.process_time()
                _write(oiio, path, images[m], kind, attrs)
                w1, c1 = time.perf_counter(), time.process_time()
                if k < a.check_frames:
                    _check(oiio, path, images[m], kind, attrs)
                wall, cpu, size = rows[(m, name)]
                wall.append(w1 - w0)
                cpu.append(c1 - c0)
                size.append(os.path.getsize(path))
            print(f"frame {task['frame']} written {len(keys)} ways", flush=True)
    print(f"\n{' '.join(MAIN_JOB)}, {len(rows[keys[0]][0])} frames, 1 thread: medians per file")
    print("| image | setting | wall ms | CPU ms | KB |\n|---|---|---|---|---|")
    for (m, name), (wall, cpu, size) in rows.items():
        print(f"| {m} | {name} | {statistics.median(wall) * 1e3:.1f} | {statistics.median(cpu) * 1e3:.1f} | "
              f"{statistics.median(size) / 1e3:.0f} |")


# --------------------------------------------------------------------------- whole frame
_CHILD = r"""
import json, os, sys, time, numpy as np
sys.path.insert(0, sys.argv[1])
import OpenImageIO as oiio
oiio.attribute("threads", 1); oiio.attribute("exr_threads", 1)
from raytrace.dataset import folder
for line in sys.stdin:
    job = json.loads(line)
    with np.load(job["npz"]) as z:
        images = {k: z[k] for k in z.files}
    task = {"out": job["out"], "frame": job["frame"], "modalities": job["modalities"], "label": {},
            "cfg": {"output": {"modalities": job["modalities"]}}}
    t0, c0 = time.perf_counter(), time.process_time()
    folder.write_frame(task, images, {})
    print(json.dumps([time.perf_counter() - t0, time.process_time() - c0]), flush=True)
"""


def frame(a) -> None:
    import shutil
    _oiio_one_thread()
    from raytrace.dataset import folder
    cache = a.cache or tempfile.mkdtemp(prefix="bench_write_cache_")
    old = None
    if a.old:
        wt = tempfile.mkdtemp(prefix="bench_write_old_")
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", wt, a.old], check=True,
                       capture_output=True)
        old = subprocess.Popen([sys.executable, "-c", _CHILD, wt], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    variants = ["fast", "compact", "fast+half"] + (["old"] if old else [])
    times = {v: [] for v in variants}
    cpus = {v: [] for v in variants}
    sizes = {v: [] for v in variants}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for k, (task, images) in enumerate(frames(a.frames, cache)):
                npz = os.path.join(cache, f"{task['frame']:03d}.npz")
                for v in variants[k % len(variants):] + variants[:k % len(variants)]:
                    out = os.path.join(tmp, v)
                    shutil.rmtree(out, ignore_errors=True)
                    for m in task["modalities"]:
                        os.makedirs(os.path.join(out, m), exist_ok=True)
                    if v == "old":
                        old.stdin.write(json.dumps({"npz": npz, "out": out, "frame": task["frame"],
                                                    "modalities": task["modalities"]}) + "\n")
                        old.stdin.flush()
                        wall, cpu = json.loads(old.stdout.readline())
                        times[v].append(wall)
                        cpus[v].append(cpu)
                    else:
                        cfg = {"output": {"modalities": task["modalities"], "compression": v.split("+")[0],
                                          "normal_format": "half" if v.endswith("+half") else "float32"}}
                        t = {"out": out, "frame": task["frame"], "modalities": task["modalities"], "label": {},
                             "cfg": cfg}
                        t0, c0 = time.perf_counter(), time.process_time()
                        folder.write_frame(t, images, {})
                        times[v].append(time.perf_counter() - t0)
                        cpus[v].append(time.process_time() - c0)
                    sizes[v].append(sum(os.path.getsize(os.path.join(out, m, f)) for m in task["modalities"]
                                        for f in os.listdir(os.path.join(out, m))))
                print(f"frame {task['frame']}: " + ", ".join(f"{v} {times[v][-1] * 1e3:.1f} ms" for v in variants),
                      flush=True)
    finally:
        if old:
            old.stdin.close()
            old.wait()
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", wt], capture_output=True,
                           check=False)
    ref = statistics.median(times["old"]) if old else None
    ref_cpu = statistics.median(cpus["old"]) if old else None
    print(f"\n{' '.join(MAIN_JOB)}, {len(times['fast'])} frames, 1 thread: write_frame (files, checksums, record), "
          "medians")
    for v in variants:
        med, cpu = statistics.median(times[v]), statistics.median(cpus[v])
        ratio = f"  x{med / ref:.2f} (CPU x{cpu / ref_cpu:.2f}) of old" if ref else ""
        size = statistics.median(sizes[v]) / 1e6
        print(f"  {v:9s} wall {med * 1e3:6.1f} ms  CPU {cpu * 1e3:6.1f} ms  bytes {size:.2f} MB{ratio}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("choices", "frame"))
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--cache", default=None, help="folder keeping the rendered images between runs")
    ap.add_argument("--check-frames", type=int, default=4, help="frames whose files are read back and compared")
    ap.add_argument("--old", default=None, help="git revision whose writer is timed beside this one (frame)")
    a = ap.parse_args()
    choices(a) if a.what == "choices" else frame(a)


if __name__ == "__main__":
    main()
