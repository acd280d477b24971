"""Render snapshots: the small reference renders that guard the pixels, and their comparison.

A snapshot ``TARGET_PATTERN`` is a few frames of one built-in target on one pattern, rendered
small (:data:`SNAPSHOT_SETTINGS`) and kept side by side as strips: clean RGB, the two degraded
copies, the instance mask, depth, normals and the linear radiance the physical degradation
starts from. This module writes and reads the committed references (lossless: WebP, 16-bit PNG
and float32 byte planes in a compressed .npz) and compares a fresh render with them, within
tolerances that float rounding on another CPU stays inside and a real change does not, writing a
diff image for each failure. Rendering a snapshot is the command line's (``python cli.py
snapshots``), which joins the renderer and the degradation.
"""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np

from .. import files as F

SNAPSHOT_SETTINGS = {
    "width": 160, "height": 120, "focal_length_mm": 1.0, "pixel_pitch_um": 3.45,
    "frames": 5, "kept_frames": [1, 2, 3], "quality": "fast", "seed": 0, "degrade_presets": ["paper", "physical"],
    "epoch": "2026-03-20T12:00:00Z", "raan_deg": 0.0, "arg_lat_deg": 0.0,
}
"""What a snapshot renders: for each target × pattern, frames 1-3 of a 5-frame sequence at 160×120
(the default 3.45 µm pixels, so the physical exposure is the main job's, and a 1 mm lens: half
the default camera's field of view), clean RGB, mask, depth, normals and RGB degraded by both
presets (paper D4, physical), on a fixed orbit geometry (the equinox epoch, Ω = u₀ = 0: the
main job's automatic phase would move the references with any change to its search)."""

SNAPSHOT_MODALITIES = ("rgb", "rgb_paper", "rgb_physical", "mask", "depth", "normal")

SNAPSHOT_PSNR_DB = 45.0
"""RGB passes when its PSNR, over every frame and over the target's window in it, is at least this [dB]."""

SNAPSHOT_DEPTH_TOL = (1e-4, 1e-5)
"""Depth passes when |Δ| <= atol + rtol · depth (atol [m], rtol [-]) and misses stay misses."""

SNAPSHOT_NORMAL_ATOL = 1e-4
"""Normals pass when every component differs by at most this [-] (background stays 0)."""

SNAPSHOT_MASK_TIES = 0.01
"""Mask pixels may differ by ties between touching parts (:func:`_mask_ties`) on at most this
fraction of the target's pixels [-]; beyond it every differing pixel fails."""

_WINDOW_MARGIN_PX = 8


def _snapshot_files(folder: str, name: str) -> dict:
    base = os.path.join(folder, name)
    return {"rgb": f"{base}.rgb.webp", "rgb_paper": f"{base}.rgb_paper.webp", "rgb_physical": f"{base}.rgb_physical.webp",
            "mask": f"{base}.mask.png", "geometry": f"{base}.geometry.npz"}


def _write_lossless_webp(path: str, rgb: np.ndarray) -> None:
    """8-bit RGB as lossless WebP (a quarter smaller than PNG on the degraded images' noise),
    checked by reading it back."""
    import OpenImageIO as oiio

    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    tmp = f"{path}.tmp{os.getpid()}.webp"
    spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, oiio.UINT8)
    spec.attribute("compression", "lossless")
    out = oiio.ImageOutput.create(tmp)
    ok = out is not None and out.open(tmp, spec) and out.write_image(rgb)
    err = oiio.geterror() if out is None else out.geterror()
    if out is not None:
        out.close()
    if not ok or not np.array_equal(F.read_image(tmp), rgb):
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise OSError(f"cannot write {path} as lossless WebP ({err or 'pixels changed on reading back'})")
    os.replace(tmp, path)


def snapshot_radiance(radiance: np.ndarray) -> np.ndarray:
    """The linear radiance a snapshot keeps and degrades: float32 with the lowest 8 of its 23
    mantissa bits cleared (relative resolution 2⁻¹⁵). That byte is noise that no lossless coder
    compresses, a third of the references' size; the physical copy is made from this radiance,
    so the references still reproduce bit for bit."""
    bits = np.ascontiguousarray(radiance, dtype=np.float32).view(np.uint32)
    return (bits & np.uint32(0xFFFFFF00)).view(np.float32)


def _byte_planes(a: np.ndarray) -> np.ndarray:
    """float32 → its four little-endian byte planes, shape (4, *a.shape): zlib finds the
    runs in the sign/exponent bytes (a sixth smaller than plain float32)."""
    return np.moveaxis(np.ascontiguousarray(a, dtype="<f4").view(np.uint8).reshape(a.shape + (4,)), -1, 0).copy()


def _from_byte_planes(planes: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.moveaxis(planes, 0, -1)).view("<f4")[..., 0].astype(np.float32)


def write_snapshot(folder: str, name: str, images: dict) -> list:
    """Write one snapshot's references: the RGB strips as lossless 8-bit WebP, the mask strip as
    16-bit PNG, depth, normals and the linear radiance as float32 byte planes in a compressed
    .npz (all lossless); returns the paths."""
    import io

    paths = _snapshot_files(folder, name)
    os.makedirs(folder, exist_ok=True)
    for m in ("rgb", "rgb_paper", "rgb_physical"):
        _write_lossless_webp(paths[m], images[m])
    F.atomic_write_image(paths["mask"], images["mask"])
    buf = io.BytesIO()
    np.savez_compressed(buf, depth=_byte_planes(images["depth"]), normal=_byte_planes(images["normal"]),
                        radiance=_byte_planes(images["radiance"]))
    F.atomic_write_bytes(paths["geometry"], buf.getvalue())
    return list(paths.values())


def read_snapshot(folder: str, name: str) -> dict:
    """The references of one snapshot, as :func:`render_snapshot` returns them.

    Raises
    ------
    FileNotFoundError
        A reference file is missing (its path in the message).
    """
    paths = _snapshot_files(folder, name)
    missing = [p for p in paths.values() if not os.path.isfile(p)]
    if missing:
        raise FileNotFoundError(f"snapshot {name}: missing reference {missing[0]} (python cli.py snapshots --update "
                                "writes the references)")
    out = {m: F.read_image(paths[m]) for m in ("rgb", "rgb_paper", "rgb_physical", "mask")}
    with np.load(paths["geometry"]) as z:
        if "radiance" not in z.files:
            raise FileNotFoundError(f"snapshot {name}: {paths['geometry']} holds no radiance (references of an older "
                                    "format: python cli.py snapshots --update)")
        for key in ("depth", "normal", "radiance"):
            out[key] = _from_byte_planes(z[key])
    return out


def _psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def snapshot_image(modality: str, a: np.ndarray) -> np.ndarray:
    """A uint8 RGB picture of a modality: RGB as is; mask ids in distinct colours (0 black);
    depth near bright, far dark (misses black); normals as (n + 1)/2 (background black)."""
    a = np.asarray(a)
    if modality.startswith("rgb"):
        return a.astype(np.uint8)
    if modality == "mask":
        ids = a.astype(np.int64)
        golden = (ids[..., None] * np.array([0.618034, 0.381966, 0.7548777])) % 1.0
        rgb = (55 + 200 * golden).astype(np.uint8)
        rgb[ids == 0] = 0
        return rgb
    if modality == "depth":
        hit = np.isfinite(a)
        out = np.zeros(a.shape + (3,), np.uint8)
        if hit.any():
            lo, hi = float(a[hit].min()), float(a[hit].max())
            v = 1.0 - (a[hit] - lo) / max(hi - lo, 1e-9)
            out[hit] = (40 + 215 * v)[:, None].astype(np.uint8)
        return out
    if modality == "normal":
        out = np.round((a + 1.0) * 127.5).clip(0, 255).astype(np.uint8)
        out[np.all(a == 0, axis=-1)] = 0
        return out
    raise ValueError(f"modality must be one of {', '.join(SNAPSHOT_MODALITIES)}; got {modality!r}")


def _write_diff(diff_dir: str, name: str, modality: str, ref: np.ndarray, new: np.ndarray,
                bad: np.ndarray) -> str:
    """Reference, candidate and failing pixels (red on grey, in a yellow box) stacked, at twice
    the size, as one PNG; returns its path."""
    a, b = snapshot_image(modality, ref), snapshot_image(modality, new)
    grey = (0.3 * (a.astype(np.float32).mean(-1) + b.astype(np.float32).mean(-1)) / 2).astype(np.uint8)
    d = np.repeat(grey[..., None], 3, axis=-1)
    rows, cols = np.nonzero(bad)
    if rows.size:  # a yellow box around the failing pixels, so a single one is found at a glance
        y0, y1 = max(rows.min() - 3, 0), min(rows.max() + 3, bad.shape[0] - 1)
        x0, x1 = max(cols.min() - 3, 0), min(cols.max() + 3, bad.shape[1] - 1)
        d[[y0, y1], x0:x1 + 1] = (255, 220, 0)
        d[y0:y1 + 1, [x0, x1]] = (255, 220, 0)
    d[bad] = (255, 0, 0)
    os.makedirs(diff_dir, exist_ok=True)
    path = os.path.join(diff_dir, f"{name}.{modality}.diff.png")
    F.write_image(path, np.concatenate([a, b, d], axis=0).repeat(2, axis=0).repeat(2, axis=1))
    return path


def compare_snapshot(name: str, ref: dict, new: dict, *, diff_dir: str) -> list:
    """Compare a fresh snapshot with its references; returns one readable message per failing
    modality (empty: identical within the tolerances) and writes a diff image for each into
    ``diff_dir`` (reference above candidate above the failing pixels in red).

    Masks (instance ids) must match exactly, but for ties between touching parts
    (:func:`_mask_ties`, on at most :data:`SNAPSHOT_MASK_TIES` of the target); depth within
    :data:`SNAPSHOT_DEPTH_TOL` with misses in the same pixels; normals within
    :data:`SNAPSHOT_NORMAL_ATOL`; each RGB image must reach :data:`SNAPSHOT_PSNR_DB` in every
    frame, over the whole frame and over the target's window (its mask's box grown by 8 px), so
    a few changed pixels on a small target cannot hide in the black sky. The degraded images
    are compared when their input (clean RGB for ``paper``, radiance for ``physical``) is the
    reference's bit for bit: otherwise their noise is another draw."""
    msgs = []
    shapes = {m: (ref[m].shape, new[m].shape) for m in SNAPSHOT_MODALITIES if ref[m].shape != new[m].shape}
    if shapes:
        return [f"{name}: {m}: shape {b} differs from the reference's {a} (snapshot settings changed? "
                "python cli.py snapshots --update)" for m, (a, b) in shapes.items()]

    def fail(modality: str, text: str, bad: np.ndarray) -> None:
        path = _write_diff(diff_dir, name, modality, ref[modality], new[modality], bad)
        msgs.append(f"{name}: {modality}: {text}; diff image {path}")

    d0, d1 = ref["depth"].astype(np.float64), new["depth"].astype(np.float64)
    f0, f1 = np.isfinite(d0), np.isfinite(d1)
    both = f0 & f1
    err = np.zeros_like(d0)
    err[both] = np.abs(d1[both] - d0[both])
    atol, rtol = SNAPSHOT_DEPTH_TOL
    depth_bad = (f0 != f1) | (both & (err > atol + rtol * np.where(both, np.abs(d0), 0.0)))
    m0, m1 = ref["mask"], new["mask"]
    bad = m0 != m1
    if bad.any():
        tie = _mask_ties(m0, m1, both & ~depth_bad) & bad
        n_target = max(int(np.count_nonzero(m0 > 0)), 1)
        if np.count_nonzero(tie) <= SNAPSHOT_MASK_TIES * n_target:
            bad &= ~tie  # a tie between two parts at the same depth, decided otherwise here
    if bad.any():
        ious = []
        for k in np.union1d(np.unique(m0), np.unique(m1)):
            if k:
                a, b = m0 == k, m1 == k
                ious.append((np.count_nonzero(a & b) / np.count_nonzero(a | b), int(k)))
        iou, k = min(ious) if ious else (1.0, 0)
        fail("mask", f"{np.count_nonzero(bad)} of {bad.size} pixels have other instance ids (must match exactly "
             f"but for ties between touching parts; lowest instance IoU {iou:.4f}, id {k})", bad)
    bad = depth_bad
    if bad.any():
        fail("depth", f"{np.count_nonzero(bad)} pixels outside |Δ| <= {atol:g} m + {rtol:g}·depth or hit/miss "
             f"changed ({np.count_nonzero(f0 != f1)}); max |Δ| {err.max():.3g} m", bad)
    n0, n1 = ref["normal"].astype(np.float64), new["normal"].astype(np.float64)
    nerr = np.abs(n1 - n0).max(axis=-1)
    bad = nerr > SNAPSHOT_NORMAL_ATOL
    if bad.any():
        fail("normal", f"{np.count_nonzero(bad)} pixels differ by more than {SNAPSHOT_NORMAL_ATOL:g}; "
             f"max |Δ| {nerr.max():.3g}", bad)
    # the degraded copies draw their noise from the clean image (paper) or the radiance
    # (physical): where those moved at all, even by float rounding on another CPU, the
    # draws run out of step and the noise is another realisation, so they are compared only
    # when their input is the reference's bit for bit (check_snapshot_degradation checks the
    # chain itself from the reference's inputs)
    same_input = {"rgb_paper": np.array_equal(ref["rgb"], new["rgb"]),
                  "rgb_physical": np.array_equal(ref["radiance"], new["radiance"])}
    for m in ("rgb", "rgb_paper", "rgb_physical"):
        if same_input.get(m, True):
            _compare_rgb(m, ref[m], new[m], m0, m1, fail)
    return msgs


def _compare_rgb(modality: str, a_strip: np.ndarray, b_strip: np.ndarray, m0: np.ndarray, m1: np.ndarray,
                 fail) -> None:
    """Call ``fail(modality, text, bad)`` when the 8-bit strips ``a_strip`` (reference) and
    ``b_strip`` fall below :data:`SNAPSHOT_PSNR_DB` in a frame or in a frame's target window
    (the box of the masks ``m0``, ``m1`` grown by 8 px)."""
    width = SNAPSHOT_SETTINGS["width"]
    n_frames = m0.shape[1] // width
    worst = []
    for j in range(n_frames):
        cols = slice(j * width, (j + 1) * width)
        a, b = a_strip[:, cols], b_strip[:, cols]
        worst.append((_psnr_db(a, b), f"frame {j + 1} of {n_frames}"))
        support = (m0[:, cols] > 0) | (m1[:, cols] > 0)
        if support.any():
            rows, cs = np.flatnonzero(support.any(axis=1)), np.flatnonzero(support.any(axis=0))
            y0, y1 = max(rows[0] - _WINDOW_MARGIN_PX, 0), rows[-1] + _WINDOW_MARGIN_PX + 1
            x0, x1 = max(cs[0] - _WINDOW_MARGIN_PX, 0), cs[-1] + _WINDOW_MARGIN_PX + 1
            worst.append((_psnr_db(a[y0:y1, x0:x1], b[y0:y1, x0:x1]),
                          f"frame {j + 1} of {n_frames}, target window rows {y0}:{y1} cols {x0}:{x1}"))
    psnr, where = min(worst)
    if psnr < SNAPSHOT_PSNR_DB:
        bad = np.any(a_strip != b_strip, axis=-1)
        fail(modality, f"PSNR {psnr:.1f} dB < {SNAPSHOT_PSNR_DB:g} dB ({where}); {np.count_nonzero(bad)} pixels "
             f"differ, max |Δ| {int(np.abs(a_strip.astype(int) - b_strip.astype(int)).max())} DN", bad)


def check_snapshot_degradation(name: str, ref: dict, again: dict, *, diff_dir: str) -> list:
    """The degradation chain against a snapshot's references: ``again``, both presets applied
    (by the main job's degradation, each frame's own random stream) to the reference's own
    clean RGB and radiance, must give its degraded strips (within :data:`SNAPSHOT_PSNR_DB`, as :func:`compare_snapshot` compares RGB).
    The inputs are the stored ones, so this holds on any CPU, whatever float rounding does to a
    fresh render; returns one message per failing preset (a diff image each in ``diff_dir``)."""
    msgs = []

    def fail(modality: str, text: str, bad: np.ndarray) -> None:
        path = _write_diff(diff_dir, name, modality, ref[modality], again[modality], bad)
        msgs.append(f"{name}: {modality}: degrading the reference's own input: {text}; diff image {path}")

    for m, img in again.items():
        if img.shape != ref[m].shape:
            msgs.append(f"{name}: {m}: shape {img.shape} differs from the reference's {ref[m].shape} (snapshot "
                        "settings changed? python cli.py snapshots --update)")
        else:
            _compare_rgb(m, ref[m], img, ref["mask"], ref["mask"], fail)
    return msgs


def _mask_ties(m0: np.ndarray, m1: np.ndarray, same_depth: np.ndarray) -> np.ndarray:
    """Pixels where two masks may differ by a tie: both hit, at the same depth (``same_depth``:
    both depths finite and within :data:`SNAPSHOT_DEPTH_TOL`), and each one's id is found among
    the other mask's 3×3 neighbours there. Where two parts touch or overlap in one plane (a mounting face sunk a few
    millimetres into its mount), a pixel centre on the shared strip hits both at one distance,
    and which of the two Embree reports depends on its traversal order, i.e. on the CPU's
    vector width (AVX2 and AVX-512 differ)."""
    h, w = m0.shape
    p0 = np.pad(m0, 1)
    p1 = np.pad(m1, 1)
    in0 = np.zeros((h, w), dtype=bool)  # m1's id among m0's neighbours
    in1 = np.zeros((h, w), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            in0 |= p0[dy:dy + h, dx:dx + w] == m1
            in1 |= p1[dy:dy + h, dx:dx + w] == m0
    return same_depth & (m0 > 0) & (m1 > 0) & in0 & in1


def _snapshot_settings_json() -> str:
    return json.dumps({"format": "orbitsynth snapshots 2", **SNAPSHOT_SETTINGS,
                       "psnr_db": SNAPSHOT_PSNR_DB, "depth_atol_m_rtol": list(SNAPSHOT_DEPTH_TOL),
                       "normal_atol": SNAPSHOT_NORMAL_ATOL, "mask_ties": SNAPSHOT_MASK_TIES}, indent=1) + "\n"


def snapshot_settings_message(folder: str) -> str | None:
    """None when ``folder``'s ``settings.json`` records the current snapshot settings and
    tolerances, else a message saying what to do."""
    path = os.path.join(folder, "settings.json")
    try:
        with open(path, encoding="utf-8") as fh:
            stored = fh.read()
    except OSError:
        return f"snapshots: missing {path} (python cli.py snapshots --update writes the references)"
    if stored != _snapshot_settings_json():
        return (f"snapshots: {path} records other snapshot settings or tolerances than raytrace.dataset.snapshots.SNAPSHOT_SETTINGS; "
                "the references are stale: python cli.py snapshots --update")
    return None


def run_snapshots(names: list, folder: str, diff_dir: str, *, update: bool, render, degrade, out) -> int:
    """Compare the snapshots ``names`` with their references in ``folder`` (or with ``update``
    write them), a line per snapshot and a summary to the text stream ``out``, diff images into
    ``diff_dir``; returns the exit status (1: something moved). ``render(name)`` renders a
    snapshot (:func:`read_snapshot`'s dict); ``degrade(name, images)`` degrades a snapshot's
    clean RGB and radiance as the main job does (:func:`check_snapshot_degradation`).

    Raises
    ------
    ValueError, FileNotFoundError, OSError
        A bad name, a missing reference, a folder that cannot be written.
    """
    t0 = time.perf_counter()
    failures, nbytes = [], 0
    stale = None if update else snapshot_settings_message(folder)
    if stale:
        out.write(f"FAIL {stale}\n")
        return 1
    for name in names:
        new = render(name)
        if update:
            nbytes += sum(os.path.getsize(q) for q in write_snapshot(folder, name, new))
            out.write(f"{name}: reference written\n")
            continue
        ref = read_snapshot(folder, name)
        msgs = (compare_snapshot(name, ref, new, diff_dir=diff_dir)
                + check_snapshot_degradation(name, ref, degrade(name, ref), diff_dir=diff_dir))
        failures += msgs
        out.write("".join(f"FAIL {m}\n" for m in msgs) or f"{name}: ok\n")
    if update:
        F.atomic_write_text(os.path.join(folder, "settings.json"), _snapshot_settings_json())
    elapsed = time.perf_counter() - t0
    if update:
        out.write(f"{len(names)} snapshots written to {folder} ({nbytes / 1e6:.2f} MB) in {elapsed:.1f} s; "
                  "review them (git diff) before committing\n")
        return 0
    if failures:
        out.write(f"{len(failures)} failure(s) in {len(names)} snapshots ({elapsed:.1f} s); diff images in "
                  f"{diff_dir}; if the change is intended: python cli.py snapshots --update\n")
        return 1
    out.write(f"{len(names)} snapshots match the references in {elapsed:.1f} s\n")
    return 0
