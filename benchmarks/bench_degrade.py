#!/usr/bin/env python3
"""Benchmark: the degradation chain on a 1280×960 RGB float32 frame, stage by stage.

    python benchmarks/bench_degrade.py            # prints Markdown tables
    python benchmarks/bench_degrade.py --quick    # fewer repeats

Three tables, every entry the median of interleaved repeats (round-robin, so machine noise
hits all methods alike); wall time and process CPU time (all threads) where it helps:

1. Physical chain (degrade.degrade, default configs) per stage and whole, on two frames:
   a textured target on black covering 25 % of the frame (the usual render) and the same
   texture over the whole frame (worst case for the Poisson sampler).
2. Paper mode D1–D4 (degrade.paper_degrade) side by side with the straightforward
   implementation of the same chain: scipy.ndimage.convolve (float64, mode "reflect"),
   np.round to 8 bits, skimage.util.random_noise for the Poisson and Gaussian steps. Also
   checks that both give identical noise on the same blurred image.
3. convolve_image: direct vs FFT by kernel size, one kernel for all channels and one per
   channel (the measurement behind degrade.convolve.DIRECT_MAX_TAPS).
4. Camera artefacts (degrade.artefacts): the whole chain with them off and with the physical
   preset's defaults side by side, and each artefact alone on top of the chain, on the
   textured target at 1.3× exposure (its brightest panels saturate, so blooming has work)
   with the Sun 40° off-axis (glare and ghost in the frame), exposure 20 µs as in the main
   job. ``--artefacts`` prints only this table.
5. ``--main-job [--base DIR] [--frames N]`` (only this table): the main job's own frames
   (``python cli.py --target cassini --pattern spiral``, 1280×960, planned as the command line
   plans them, N of its 48 frames spread over the orbit, rendered once), each process on one
   numba thread as a worker is: ``degrade.presets.degrade_outputs`` with the ``physical`` preset
   (rgb_degraded, signal_e, saturation) and the ``paper`` preset, and the clean RGB's encoding
   (``encode_srgb8``). With ``--base DIR`` (a checkout of another commit, e.g.
   ``git worktree add /tmp/base 84ef6eb``) its ``degrade`` package is loaded alongside as
   ``degrade_base`` and run on the same inputs, interleaved (the order alternating), every
   output compared byte for byte; medians and ratios new/base of the process CPU time, the
   main thread's CPU time (everything but the random draws, which run on the pool's threads)
   and wall time.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np
import OpenImageIO as oiio
import scipy
import skimage
from scipy import ndimage
from skimage.util import random_noise

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from degrade import (
    DegradeConfig,
    OpticsConfig,
    convolve_image,
    degrade,
    motion_psf,
    optics_psf,
    paper_blur,
    paper_degrade,
    srgb_encode,
)
from degrade.chain import _apply_optics
from degrade.convolve import DIRECT_MAX_TAPS
from degrade.sensor import _demosaic, _demosaic_oiio, _mosaic, _readout

H, W = 960, 1280
MOTION = OpticsConfig(motion_length_px=15.0, motion_angle_deg=30.0)


def frame(fraction: float, seed: int = 0) -> np.ndarray:
    """Linear float32 frame: shaded panels with fine detail, on black outside ``fraction``."""
    rng = np.random.default_rng(seed)
    th, tw = round(H * fraction**0.5), round(W * fraction**0.5)
    y, x = np.mgrid[:th, :tw].astype(np.float32)
    panels = 0.55 + 0.25 * np.sign(np.sin(x / 23.0)) * np.sign(np.sin(y / 31.0))
    detail = 0.1 * rng.random((th, tw), dtype=np.float32)
    tint = np.array([0.95, 0.85, 0.7], np.float32)
    img = np.zeros((H, W, 3), np.float32)
    y0, x0 = (H - th) // 2, (W - tw) // 2
    img[y0:y0 + th, x0:x0 + tw] = ((panels + detail) * (0.8 + 0.2 * np.cos(x / 60.0)))[..., None] * tint
    return img


def reference_paper(img8: np.ndarray, group: str, seed: int) -> np.ndarray:
    """The paper chain written directly with scipy.ndimage and skimage.util.random_noise."""
    blurred = ndimage.convolve(img8.astype(np.float64), motion_psf(15.0, 30.0)[:, :, None], mode="reflect")
    out = np.round(np.clip(blurred, 0.0, 1.0) * 255) / 255
    if group == "D1":
        return out
    rng_poisson, rng_gauss = np.random.default_rng(seed).spawn(2)
    if group in ("D2", "D4"):
        out = random_noise(out, mode="poisson", rng=rng_poisson)
    if group in ("D3", "D4"):
        out = random_noise(out, mode="gaussian", mean=0.0, var=0.01, rng=rng_gauss)
    return out


def run_interleaved(cases: dict, repeats: int) -> dict[str, tuple[float, float]]:
    """Median wall time and median process CPU time (all threads) [s] of each zero-argument
    callable, run round-robin. On a busy machine the CPU time is the steadier figure."""
    for fn in cases.values():  # warm-up: JIT caches, page faults, lru caches
        fn()
    wall = {name: [] for name in cases}
    cpu = {name: [] for name in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return {name: (statistics.median(wall[name]), statistics.median(cpu[name])) for name in cases}


def physical_table(repeats: int) -> list[str]:
    frames = {"target on black (25 %)": frame(0.25), "full-frame texture": frame(1.0)}
    cfg = DegradeConfig()
    sensor = cfg.sensor
    rows = {}
    for img in frames.values():
        blurred = _apply_optics(img, cfg.optics)
        raw = _mosaic(blurred)
        read = _readout(raw, sensor, np.random.default_rng(0))
        rgb = np.clip(_demosaic(read, "MHC"), 0.0, 1.0)
        cases = {
            "optics ⊛ PSF (Airy per channel, 7×7)": lambda img=img: _apply_optics(img, cfg.optics),
            "optics ⊛ PSF + motion L = 15 px (25×25)": lambda img=img: _apply_optics(img, MOTION),
            "RGGB mosaic": lambda b=blurred: _mosaic(b),
            "readout: Poisson, full well, read noise, ADC": lambda r=raw: _readout(r, sensor, np.random.default_rng(1)),
            "demosaic MHC (Numba)": lambda r=read: _demosaic(r, "MHC"),
            "demosaic MHC (OpenImageIO)": lambda r=read: _demosaic_oiio(r, "MHC"),
            "demosaic linear (OpenImageIO)": lambda r=read: _demosaic(r, "linear"),
            "sRGB encode, 8 bit": lambda x=rgb: srgb_encode(x, bits=8),
            "**whole chain** `degrade(img)`": lambda img=img: degrade(img, cfg, rng=2),
            "**whole chain** with motion L = 15 px": lambda img=img: degrade(img, dataclasses.replace(cfg, optics=MOTION),
                                                                             rng=2),
        }
        for name, t in run_interleaved(cases, repeats).items():
            rows.setdefault(name, []).append(t)
    head = " | ".join(f"{k}: wall / CPU [ms]" for k in frames)
    lines = [f"| stage | {head} |", "|---|" + "---:|" * len(frames)]
    lines += [f"| {name} | {' | '.join(f'{1e3 * w:.1f} / {1e3 * c:.1f}' for w, c in ts)} |"
              for name, ts in rows.items()]
    return lines


def paper_table(repeats: int) -> list[str]:
    img8 = np.rint(srgb_encode(frame(0.25), bits=8) * 255).astype(np.float32) / 255  # an 8-bit render
    lines = ["| group | ours: wall / CPU [ms] | ndimage + random_noise: wall / CPU [ms] | speed-up (wall) |",
             "|---|---:|---:|---:|"]
    cases = {}
    for group in ("D1", "D2", "D3", "D4"):
        cases[f"ours {group}"] = lambda g=group: paper_degrade(img8, g, rng=5)
        cases[f"ref {group}"] = lambda g=group: reference_paper(img8, g, 5)
    t = run_interleaved(cases, repeats)
    for group in ("D1", "D2", "D3", "D4"):
        (ours, ours_cpu), (ref, ref_cpu) = t[f"ours {group}"], t[f"ref {group}"]
        lines.append(f"| {group} | {1e3 * ours:.1f} / {1e3 * ours_cpu:.1f} | {1e3 * ref:.1f} / {1e3 * ref_cpu:.1f} | "
                     f"{ref / ours:.1f}× |")

    # identity: the noise steps on the same 8-bit blurred image, and the blur itself
    ours_b = paper_blur(img8)
    b64 = np.rint(ours_b.astype(np.float64) * 255) / 255
    rng_poisson, rng_gauss = np.random.default_rng(5).spawn(2)
    ref_d4 = random_noise(random_noise(b64, mode="poisson", rng=rng_poisson), mode="gaussian", var=0.01,
                          rng=rng_gauss)
    same_noise = np.array_equal(paper_degrade(img8, "D4", rng=5), ref_d4.astype(np.float32))
    ref_codes = np.rint(reference_paper(img8, "D1", 0) * 255)
    our_codes = np.rint(ours_b.astype(np.float64) * 255)
    lines += ["", (f"D4 noise on the same blurred image bit-identical to `random_noise`: **{same_noise}**. "
                  f"Blur: {np.mean(our_codes == ref_codes):.6%} of 8-bit codes equal to the float64 "
                  f"ndimage result, max difference {int(np.abs(our_codes - ref_codes).max())} code "
                  f"(float32 accumulation flips exact .5 ties).")]
    return lines


def convolution_table(repeats: int) -> list[str]:
    img = frame(1.0)
    rng = np.random.default_rng(3)
    lines = [("| kernel | taps | shared: direct [ms] | shared: FFT [ms] | per channel: direct [ms] | "
             "per channel: FFT [ms] |"), "|---|---:|---:|---:|---:|---:|"]
    for k in (3, 5, 7, 9, 11, 13, 15, 19, 25):
        shared = rng.random((k, k))
        per_channel = rng.random((3, k, k))
        cases = {
            "sd": lambda s=shared: convolve_image(img, s, method="direct"),
            "sf": lambda s=shared: convolve_image(img, s, method="fft"),
            "pd": lambda p=per_channel: convolve_image(img, p, method="direct"),
            "pf": lambda p=per_channel: convolve_image(img, p, method="fft"),
        }
        t = {name: wall for name, (wall, _) in run_interleaved(cases, repeats).items()}
        lines.append(f"| {k}×{k} | {k * k} | {1e3 * t['sd']:.1f} | {1e3 * t['sf']:.1f} | "
                     f"{1e3 * t['pd']:.1f} | {1e3 * t['pf']:.1f} |")
    lines += ["", (f"`method=\"auto\"` convolves directly up to {DIRECT_MAX_TAPS['shared']} nonzero taps "
                  f"(one kernel) or {DIRECT_MAX_TAPS['per_channel']} (one per channel), else by FFT. "
                  f"The default optics PSF is {optics_psf(OpticsConfig()).shape[1]}² taps per channel; "
                  f"the paper's motion kernel (L = 15, θ = 30°) has "
                  f"{np.count_nonzero(motion_psf(15.0, 30.0))} nonzero taps of 19².")]
    return lines


def artefacts_table(repeats: int) -> list[str]:
    from degrade.artefacts import ARTEFACTS_OFF, ArtefactConfig
    from degrade.chain import simulate_frame
    img = frame(0.25) * np.float32(1.3)
    sun = [math.sin(math.radians(40.0)), 0.0, math.cos(math.radians(40.0))]
    # the main job's exposure (20 µs): the stray light's photons are counted over the sensor's exposure
    base = DegradeConfig(sensor=dataclasses.replace(DegradeConfig().sensor, exposure_s=20e-6))
    off = dataclasses.replace(base, artefacts=ARTEFACTS_OFF)
    alone = {
        "vignetting (cos⁴)": {"vignetting": True},
        "PRNU + DSNU + hot pixels (maps cached per camera)": {"prnu_sigma": 0.01, "dsnu_sigma_e": 2.0,
                                                              "hot_pixel_fraction": 1e-4},
        "blooming": {"blooming": True},
        "stray light + ghost (Sun 40° off-axis)": {"stray_light": True},
        "JPEG quality 90 (OpenImageIO)": {"jpeg_quality": 90},
    }
    cases = {
        "chain without artefacts `degrade(img)`": lambda: degrade(img, base, rng=2),
        "chain, artefacts all off (`ARTEFACTS_OFF`: + signal_e, saturation)": lambda: simulate_frame(img, off, rng=2),
        "**chain, preset defaults** (vignetting, PRNU/DSNU, hot pixels, blooming, stray light)":
            lambda: simulate_frame(img, dataclasses.replace(base, artefacts=ArtefactConfig()), rng=2, sun_dir_cam=sun),
    }
    for name, kw in alone.items():
        cfg = dataclasses.replace(base, artefacts=dataclasses.replace(ARTEFACTS_OFF, **kw))
        cases[f"+ {name} alone"] = lambda c=cfg: simulate_frame(img, c, rng=2, sun_dir_cam=sun)
    t = run_interleaved(cases, repeats)
    lines = ["| chain | wall / CPU [ms] |", "|---|---:|"]
    lines += [f"| {name} | {1e3 * w:.1f} / {1e3 * c:.1f} |" for name, (w, c) in t.items()]
    return lines


def _load_base(base: Path):
    """The ``degrade`` package of the checkout ``base``, imported as ``degrade_base`` from a
    temporary copy: numba caches its kernels next to their source under the module's name, and
    a cache entry written as ``degrade_base`` would break that checkout's own runs."""
    import atexit
    import importlib.util
    import shutil
    import tempfile
    tmp = tempfile.mkdtemp(prefix="bench-degrade-base-")
    atexit.register(shutil.rmtree, tmp, True)
    copy = Path(tmp) / "degrade_base"
    shutil.copytree(base / "degrade", copy, ignore=shutil.ignore_patterns("__pycache__"))
    spec = importlib.util.spec_from_file_location("degrade_base", copy / "__init__.py",
                                                  submodule_search_locations=[str(copy)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["degrade_base"] = mod
    spec.loader.exec_module(mod)
    import degrade_base.encode
    import degrade_base.presets  # noqa: F401
    return mod


def _main_job_inputs(n_frames: int) -> list[dict]:
    """The degrade_outputs arguments of ``n_frames`` frames of the main job, rendered here."""
    import cli
    from degrade import presets
    from raytrace.dataset import folder
    from raytrace.dataset.modalities import DEFAULT
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral"]))
    tasks, _ = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)
    picks = sorted({round(k * (len(tasks) - 1) / max(1, n_frames - 1)) for k in range(n_frames)})
    captured, real = [], presets.degrade_outputs

    def spy(d, cam, rgb8, radiance, seed_seq, motion=None, **kw):
        captured.append({"d": d, "cam": cam, "radiance": np.array(radiance), "motion": motion, "kw": kw,
                         "seed": (seed_seq.entropy, seed_seq.spawn_key)})
        return real(d, cam, rgb8, radiance, seed_seq, motion, **kw)

    presets.degrade_outputs = spy
    try:
        for i in picks:
            images, _ = cli.render_frame_images(dict(tasks[i], modalities=list(DEFAULT), want_rgb=False))
            captured[-1].update(rgb8=images["rgb"], frame=i,
                                linear=captured[-1]["radiance"] * np.float32(math.pi / cli.SOLAR_CONSTANT_W_M2))
    finally:
        presets.degrade_outputs = real
    return captured


def main_job_table(repeats: int, base: Path | None, n_frames: int) -> list[str]:
    numba.set_num_threads(1)  # as a worker of the main job
    import degrade.encode as enc_new
    import degrade.presets as new
    impl = {"new": (new, enc_new)}
    if base is not None:
        b = _load_base(base.resolve())
        impl["base"] = (b.presets, b.encode)
    inputs = _main_job_inputs(n_frames)
    want = {"physical": ("rgb_degraded", "signal_e", "saturation"), "paper": ("rgb_degraded",)}

    def run(which: str, task: str, f: dict):
        presets, enc = impl[which]
        if task == "rgb encoding":
            if which == "new":
                return {"rgb": enc.encode_srgb8(f["linear"])}
            return {"rgb": enc.quantise(enc.srgb_encode(np.minimum(f["linear"], np.float32(1.0))), 8)}
        d = dict(f["d"], degrade=task)
        return presets.degrade_outputs(d, f["cam"], f["rgb8"], f["radiance"], np.random.SeedSequence(
            f["seed"][0], spawn_key=f["seed"][1]), f["motion"], **dict(f["kw"], want=want[task]))

    tasks = ("physical", "paper", "rgb encoding")
    differ = {t: 0 for t in tasks}
    for f in inputs:  # warm-up and byte comparison
        for t in tasks:
            outs = {w: run(w, t, f) for w in impl}
            if "base" in outs:
                differ[t] += sum(not np.array_equal(outs["new"][k], outs["base"][k]) or
                                 outs["new"][k].dtype != outs["base"][k].dtype for k in outs["new"])
    times = {(w, t, c): [] for w in impl for t in tasks for c in ("cpu", "main", "wall")}
    for r in range(repeats):
        for i, f in enumerate(inputs):
            for t in tasks:
                order = list(impl) if (r + i) % 2 == 0 else list(impl)[::-1]
                for w in order:
                    t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
                    run(w, t, f)
                    times[w, t, "main"].append(time.thread_time() - m0)
                    times[w, t, "cpu"].append(time.process_time() - c0)
                    times[w, t, "wall"].append(time.perf_counter() - t0)
    clocks = {"cpu": "process CPU", "main": "main thread CPU (not the pool's random draws)", "wall": "wall"}
    lines = ["| per frame, median [ms] | " + " | ".join(impl) + (" | new/base | outputs equal |" if base else " |"),
             "|---|" + "---:|" * len(impl) + ("---:|---|" if base else "")]
    for t in tasks:
        for c, label in clocks.items():
            med = {w: statistics.median(times[w, t, c]) for w in impl}
            row = f"| {t}, {label} | " + " | ".join(f"{1e3 * med[w]:.1f}" for w in impl)
            if base is not None:
                row += f" | {med['new'] / med['base']:.2f} | {'yes' if differ[t] == 0 else f'NO ({differ[t]} arrays differ)'}"
            lines.append(row + " |")
    lines.append(f"\nframes {[f['frame'] for f in inputs]} of the main job, {repeats} rounds each.")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--quick", action="store_true", help="3 repeats")
    ap.add_argument("--artefacts", action="store_true", help="only the camera-artefacts table")
    ap.add_argument("--main-job", action="store_true", help="only the main job's frames (table 5)")
    ap.add_argument("--base", type=Path, help="with --main-job: a checkout to compare with")
    ap.add_argument("--frames", type=int, default=6, help="with --main-job: frames of the 48")
    args = ap.parse_args(argv)
    repeats = 3 if args.quick else args.repeats
    if args.main_job:
        load = os.getloadavg()[0]
        table = main_job_table(repeats, args.base, args.frames)
        print(f"The main job's frames (cassini spiral, 1280×960), one numba thread; {os.cpu_count()} cores "
              f"({platform.machine()}), 1-minute load average {load:.1f} at the start, "
              f"{os.getloadavg()[0]:.1f} at the end.")
        print(f"Command: `python benchmarks/bench_degrade.py --main-job"
              f"{' --base ' + str(args.base) if args.base else ''} --frames {args.frames}"
              f"{' --quick' if args.quick else ' --repeats ' + str(repeats)}`\n")
        print("\n".join(table))
        return 0
    if args.artefacts:
        table = artefacts_table(repeats)
        print(f"1280×960 RGB float32, median of {repeats} interleaved runs; {os.cpu_count()} cores "
              f"({platform.machine()}), NumPy {np.__version__}, OpenImageIO {oiio.__version__}; 1-minute load "
              f"average {os.getloadavg()[0]:.1f} after the runs.")
        print(f"Command: `python benchmarks/bench_degrade.py --artefacts{' --quick' if args.quick else ''}`\n")
        print("\n".join(table))
        return 0
    load_start = os.getloadavg()[0]
    physical = physical_table(repeats)  # runs the parallel kernels: threading layer known
    paper = paper_table(repeats)
    print(f"1280×960 RGB float32, median of {repeats} interleaved runs; {os.cpu_count()} cores "
          f"({platform.machine()}), Python {platform.python_version()}, NumPy {np.__version__}, "
          f"SciPy {scipy.__version__}, scikit-image {skimage.__version__}, OpenImageIO {oiio.__version__}, "
          f"Numba {numba.__version__} ({numba.threading_layer()} threading layer); 1-minute load average "
          f"{load_start:.1f} at the start, {os.getloadavg()[0]:.1f} after the physical and paper tables.")
    print(f"Command: `python benchmarks/bench_degrade.py{' --quick' if args.quick else ''}`\n")
    print("### Physical chain per stage\n")
    print("\n".join(physical))
    print("\n### Paper mode against scipy.ndimage + skimage.util.random_noise\n")
    print("\n".join(paper))
    print("\n### Convolution: direct vs FFT (1280×960×3 float32)\n")
    print("\n".join(convolution_table(max(3, repeats // 2))))
    print("\n### Camera artefacts (degrade.artefacts)\n")
    print("\n".join(artefacts_table(repeats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
