#!/usr/bin/env python3
"""Command line: ``python cli.py --target cassini --pattern spiral``.

``python cli.py render-scene SCENE.json --out DIR`` renders one frame of an explicit scene.
Until the sequence pipeline lands (issue 6), the main job samples a relative orbit of the
requested pattern around the target, propagates it with Clohessy–Wiltshire, places it on the reference orbit,
and prints per frame the relative state in LVLH and the visibility flags (line of sight,
Earth in the background, Sun clear of the lens, Earth shadow, illuminated fraction ν).
``--json`` prints the same as one JSON document (keys as in the dataset's scenario.json and
labels.json, SI units).

Errors in the arguments print one line naming the parameter and what is allowed, and exit
with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

from orbit.patterns import PATTERNS
from raytrace.targets import BUILTIN_TARGETS as TARGETS

PROG = "cli.py"


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{PROG}: error: {message}\n")


def _int_in(lo: int, hi: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}], got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}], got {value}")
        return value
    return parse


def _float_in(lo: float, hi: float, *, lo_open: bool = False, unit: str = ""):
    def parse(text: str) -> float:
        lo_txt = f"({lo:g}" if lo_open else f"[{lo:g}"
        allowed = f"a finite number in {lo_txt}, {hi:g}]{(' ' + unit) if unit else ''}"
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if not math.isfinite(value) or value < lo or value > hi or (lo_open and value == lo):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text}")
        return value
    return parse


def _utc(text: str) -> str:
    from orbit.epoch import to_unix_seconds
    from orbit.sun import VALID_UTC_RANGE_S
    try:
        unix_s = to_unix_seconds(text, name="--epoch")
    except ValueError:
        unix_s = math.nan
    if not VALID_UTC_RANGE_S[0] <= unix_s <= VALID_UTC_RANGE_S[1]:
        raise argparse.ArgumentTypeError(f"must be an ISO 8601 UTC time in 1950-2050 such as 2026-03-20T12:00:00Z, "
                                         f"got {text!r}")
    return text


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the main job."""
    p = _Parser(prog=PROG, description="Relative-orbit image generator for spacecraft vision-based navigation. "
                "Samples a relative orbit of the requested pattern around the target and prints the "
                "per-frame relative state and visibility flags.")
    p.add_argument("--target", choices=TARGETS, default="cassini", help="built-in target (default: cassini)")
    p.add_argument("--pattern", choices=PATTERNS, default="spiral",
                   help="relative-motion pattern (default: spiral)")
    p.add_argument("--frames", type=_int_in(1, 1_000_000), default=100,
                   help="number of frames, evenly spaced over the window (default: 100)")
    p.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0,
                   help="seed of the pattern draw; same seed, same output (default: 0)")
    p.add_argument("--window-s", type=_float_in(0.0, 1e7, lo_open=True, unit="s"), default=None,
                   help="window length [s] (default: one period for elliptical, half for spiral and "
                        "drip-drop, 80 m of drift for drift, scaled with the target)")
    g = p.add_argument_group("reference orbit (circular)")
    g.add_argument("--altitude-km", type=_float_in(100.0, 1e6, unit="km"), default=400.0,
                   help="altitude above the equatorial radius [km] (default: 400)")
    g.add_argument("--inclination-deg", type=_float_in(0.0, 180.0, unit="deg"),
                   default=51.6, help="inclination [deg] (default: 51.6)")
    g.add_argument("--raan-deg", type=_float_in(-360.0, 360.0, unit="deg"), default=0.0,
                   help="right ascension of the ascending node [deg] (default: 0)")
    g.add_argument("--arg-lat-deg", type=_float_in(-360.0, 360.0, unit="deg"), default=0.0,
                   help="argument of latitude at the epoch [deg] (default: 0)")
    g.add_argument("--epoch", type=_utc, default=None, help="UTC epoch of frame 0, ISO 8601 (default: 2026-03-20T12:00:00Z)")
    g.add_argument("--sun-margin-deg", type=_float_in(0.0, 90.0, unit="deg"), default=20.0,
                   help="stray-light margin added to the Sun's radius for the Sun-in-lens test [deg] (default: 20)")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of the table")
    return p


def run_orbit_job(args: argparse.Namespace) -> dict:
    """Sample, propagate and evaluate one sequence; returns plain-Python results."""
    from orbit import cw, pose, visibility
    from orbit.attitude import TargetAttitude
    from orbit.epoch import DEFAULT_EPOCH_UTC, to_iso_utc
    from orbit.reference import ReferenceOrbit
    from orbit.sampling import sample_pattern
    from orbit.sun import sun_position_eci
    from raytrace.targets import load_target

    radius_m = load_target(args.target).bounding_radius_m  # measured on the built-in mesh
    ref = ReferenceOrbit(altitude_m=args.altitude_km * 1e3, inclination_rad=math.radians(args.inclination_deg),
                         raan_rad=math.radians(args.raan_deg), arg_lat_rad=math.radians(args.arg_lat_deg),
                         epoch_utc=args.epoch if args.epoch is not None else DEFAULT_EPOCH_UTC)
    n = ref.n_rad_s
    sample = sample_pattern(args.pattern, n, target_radius_m=radius_m,
                            n_frames=args.frames, rng=args.seed, window_s=args.window_s)
    t_s = np.asarray(sample.t_s)
    s_lvlh = cw.propagate(sample.s0_lvlh, n, t_s)
    r_obs_eci, _ = ref.observer_state_eci(s_lvlh, t_s)
    r_tgt_eci, _ = ref.target_state_eci(t_s)
    unix_s = ref.unix_s(t_s)
    r_sun_eci = sun_position_eci(unix_s)
    vis = visibility.visibility(r_obs_eci, r_tgt_eci, r_sun_eci, sun_margin_rad=math.radians(args.sun_margin_deg))

    R_cam_from_lvlh = pose.look_at(s_lvlh[:, :3])
    R_lvlh_from_body = TargetAttitude(mode="lvlh-fixed").R_lvlh_from_body(t_s, n)
    R_cam_from_body, t_cam_m = pose.pose_from_relative(s_lvlh[:, :3], R_lvlh_from_body, R_cam_from_lvlh)
    labels = pose.pose_labels(R_cam_from_body, t_cam_m)
    R_cam_from_eci = R_cam_from_lvlh @ np.swapaxes(ref.R_eci_from_lvlh(t_s), -1, -2)
    sun_dir_cam = (R_cam_from_eci @ (r_sun_eci - r_obs_eci)[:, :, None])[:, :, 0]
    sun_dir_cam /= np.linalg.norm(sun_dir_cam, axis=1, keepdims=True)
    earth_dir_cam = (R_cam_from_eci @ -r_obs_eci[:, :, None])[:, :, 0]
    earth_dir_cam /= np.linalg.norm(earth_dir_cam, axis=1, keepdims=True)

    frames = []
    for i in range(t_s.size):
        frames.append({
            "frame": i,
            "t_s": float(t_s[i]),
            "utc": to_iso_utc(float(unix_s[i])),
            "r_lvlh": [float(v) for v in s_lvlh[i, :3]],
            "v_lvlh": [float(v) for v in s_lvlh[i, 3:]],
            "range_m": float(np.linalg.norm(s_lvlh[i, :3])),
            "q_cam_from_body": [float(v) for v in labels.q_cam_from_body[i]],
            "R_cam_from_body": [float(v) for v in R_cam_from_body[i].ravel()],
            "t_cam_m": [float(v) for v in t_cam_m[i]],
            "sun_dir_cam": [float(v) for v in sun_dir_cam[i]],
            "earth_dir_cam": [float(v) for v in earth_dir_cam[i]],
            "line_of_sight": bool(vis.line_of_sight[i]),
            "earth_in_background": bool(vis.earth_in_background[i]),
            "sun_angle_deg": float(np.degrees(vis.sun_angle_rad[i])),
            "sun_clear": bool(vis.sun_clear[i]),
            "shadow": ("sunlit", "penumbra", "umbra")[int(vis.shadow[i])],
            "shadow_fraction": float(vis.illuminated_fraction[i]),
            "visible": bool(vis.visible[i]),
        })
    return {
        "target": args.target,
        "target_bounding_radius_m": radius_m,
        "pattern": args.pattern,
        "seed": args.seed,
        "reference_orbit": {"altitude_m": ref.altitude_m, "inclination_rad": ref.inclination_rad,
                            "raan_rad": ref.raan_rad, "arg_lat_rad": ref.arg_lat_rad, "epoch_utc": ref.epoch_utc,
                            "a_m": ref.a_m, "period_s": ref.period_s},
        "n": n,
        "s0_lvlh": [float(v) for v in sample.s0_lvlh],
        "window_s": sample.window_s,
        "range_band_m": [sample.band.r_min_m, sample.band.r_max_m],
        "pattern_parameters": sample.params.to_dict(),
        "sampled": dict(sample.draws),
        "attempts": sample.attempts,
        "t_s": [float(v) for v in t_s],
        "frames": frames,
    }


def _num(value) -> str:
    return "undefined" if value is None else (value if isinstance(value, str) else f"{value:.8g}")


def _print_table(result: dict, out) -> None:
    pp = result["pattern_parameters"]
    ro = result["reference_orbit"]
    w = out.write
    w(f"# target {result['target']} (bounding radius {result['target_bounding_radius_m']:.2f} m), "
      f"pattern {result['pattern']} {pp['side']}, seed {result['seed']}\n")
    w(f"# reference orbit: altitude {ro['altitude_m'] / 1e3:g} km, i {math.degrees(ro['inclination_rad']):g} deg, "
      f"RAAN {math.degrees(ro['raan_rad']):g} deg, u0 {math.degrees(ro['arg_lat_rad']):g} deg, "
      f"epoch {ro['epoch_utc']}, n {result['n']:.10e} rad/s, T {ro['period_s']:.3f} s\n")
    w(f"# A {pp['A']:.4f} m, x_l {pp['x_l']:.4f} m, beta {pp['beta']:.6e} m/s, gamma {pp['gamma']:.4f} m, "
      f"sigma {_num(pp['sigma'])}, kappa {_num(pp['kappa'])}, t_p {pp['t_p']:.3f} s\n")
    w(f"# s0_lvlh [m, m/s] = {' '.join(f'{v:.9g}' for v in result['s0_lvlh'])}\n")
    w(f"# window {result['window_s']:.3f} s, {len(result['frames'])} frames, range band "
      f"{result['range_band_m'][0]:g}-{result['range_band_m'][1]:g} m\n")
    w(f"{'frame':>5} {'t_s':>10} {'x_m':>10} {'y_m':>10} {'z_m':>10} {'vx_m_s':>10} {'vy_m_s':>10} "
      f"{'vz_m_s':>10} {'range_m':>9} {'los':>3} {'earth_bg':>8} {'sun_deg':>7} {'sun_ok':>6} "
      f"{'shadow':>8} {'nu':>6} {'visible':>7}\n")
    yn = ("no", "yes")
    for f in result["frames"]:
        x, y, z = f["r_lvlh"]
        vx, vy, vz = f["v_lvlh"]
        w(f"{f['frame']:5d} {f['t_s']:10.3f} {x:10.4f} {y:10.4f} {z:10.4f} {vx:10.6f} {vy:10.6f} {vz:10.6f} "
          f"{f['range_m']:9.3f} {yn[f['line_of_sight']]:>3} {yn[f['earth_in_background']]:>8} "
          f"{f['sun_angle_deg']:7.2f} {yn[f['sun_clear']]:>6} {f['shadow']:>8} {f['shadow_fraction']:6.4f} "
          f"{yn[f['visible']]:>7}\n")
    n_vis = sum(f["visible"] for f in result["frames"])
    w(f"# {n_vis} of {len(result['frames'])} frames visible (line of sight, Sun clear of the lens, target lit)\n")


# --------------------------------------------------------------------------- render-scene
def _write_image(path: str, pixels: np.ndarray) -> None:
    """Write an image with OpenImageIO (format from the extension); raise OSError on failure."""
    import OpenImageIO as oiio
    out = oiio.ImageOutput.create(path)
    if out is None:
        raise OSError(f"cannot create {path}: {oiio.geterror()}")
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    h, w, c = pixels.shape
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16,
           np.dtype(np.float32): oiio.FLOAT}[pixels.dtype]
    spec = oiio.ImageSpec(w, h, c, fmt)
    if path.endswith(".exr"):
        spec.attribute("compression", "zip")
    ok = out.open(path, spec) and out.write_image(np.ascontiguousarray(pixels))
    out.close()
    if not ok:
        raise OSError(f"cannot write {path}: {out.geterror()}")


def frame_images(frame, *, name: str = "000000") -> dict:
    """The files of one rendered frame (relative path → pixels), as in a sequence folder:
    clean sRGB 8-bit ``rgb/`` (auto exposure), 16-bit instance ``mask/`` (0 background),
    float32 z-depth ``depth/`` (metres, inf on background), float32 camera-frame ``normal/``
    and linear radiance ``hdr/`` [W/(m²·sr)]. Also returns the exposure scale used."""
    from degrade.encode import srgb_encode
    from degrade.exposure import auto_exposure
    geo = frame.geometry
    linear, scale = auto_exposure(frame.radiance, geo.mask)
    rgb = srgb_encode(np.clip(linear, 0.0, 1.0), bits=8)
    return {f"rgb/{name}.png": rgb, f"mask/{name}.png": geo.instance.astype(np.uint16),
            f"depth/{name}.exr": geo.depth_m.astype(np.float32), f"normal/{name}.exr": geo.normal_cam,
            f"hdr/{name}.exr": frame.radiance.astype(np.float32)}, scale


def write_files_atomically(out_dir: str, files: dict, texts: dict) -> None:
    """Write every file into ``out_dir`` or none: all go to a hidden temporary folder first,
    then are moved into place; on any failure the temporary folder is removed."""
    import shutil
    import tempfile
    try:
        os.makedirs(out_dir, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=".partial-", dir=out_dir)
    except OSError as exc:
        raise CLIError(f"--out: cannot create {out_dir} ({exc.strerror})") from None
    try:
        for rel, pixels in files.items():
            os.makedirs(os.path.join(tmp, os.path.dirname(rel)), exist_ok=True)
            _write_image(os.path.join(tmp, rel), pixels)
        for rel, text in texts.items():
            with open(os.path.join(tmp, rel), "w", encoding="utf-8") as fh:
                fh.write(text)
        for rel in list(files) + list(texts):
            dst = os.path.join(out_dir, rel)
            os.makedirs(os.path.dirname(dst) or out_dir, exist_ok=True)
            os.replace(os.path.join(tmp, rel), dst)
    except OSError as exc:
        raise CLIError(f"--out: cannot write into {out_dir} ({exc})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def render_scene_main(argv: list[str]) -> int:
    """``cli.py render-scene SCENE.json --out DIR``: render one frame of an explicit scene."""
    parser = _Parser(prog=f"{PROG} render-scene",
                     description="Render one frame of the scene described by a JSON file (schema in README).")
    parser.add_argument("scene", help="scene file (JSON)")
    parser.add_argument("--out", required=True, help="output folder (created if missing)")
    parser.add_argument("--quality", choices=("fast", "balanced", "reference"), default=None,
                        help="overrides the file's quality preset")
    parser.add_argument("--samples", type=_int_in(1, 1 << 20), default=None,
                        help="overrides the preset's sample count")
    parser.add_argument("--seed", type=_int_in(0, 2**31 - 1), default=None, help="overrides the file's seed")
    args = parser.parse_args(argv)
    from raytrace.scene import Scene
    from raytrace.scenefile import load_scene_file
    from raytrace.shade import render
    try:
        spec = load_scene_file(args.scene)
        quality = args.quality or spec.quality
        samples = args.samples if args.samples is not None else (spec.samples if args.quality is None else None)
        seed = args.seed if args.seed is not None else spec.seed
        t0 = time.perf_counter()
        frame = render(Scene(spec.model), spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting,
                       quality=quality, samples=samples, seed=seed)
        elapsed = time.perf_counter() - t0
        files, scale = frame_images(frame)
        geo = frame.geometry
        info = {"scene": os.path.abspath(args.scene), "quality": frame.quality.name, "samples": samples,
                "seed": seed, "render_s": elapsed, "timings_s": frame.timings_s, "exposure_scale": scale,
                "width": spec.camera.width, "height": spec.camera.height, "K": spec.camera.K.tolist(),
                "R_cam_from_body": spec.R_cam_from_body.ravel().tolist(), "t_cam_m": spec.t_cam_m.tolist(),
                "components": list(spec.model.component_names),
                "pixel_counts": geo.pixel_counts.tolist(), "bbox_xywh": geo.bbox_xywh,
                "visible_fraction": None if math.isnan(geo.visible_fraction) else geo.visible_fraction}
        write_files_atomically(args.out, files, {"frame.json": json.dumps(info, indent=1) + "\n"})
    except (CLIError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    sys.stdout.write(f"rendered {args.scene} ({frame.quality.name}) in {elapsed:.2f} s -> {args.out}\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "render-scene":
        return render_scene_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        result = run_orbit_job(args)
    except (CLIError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    try:
        if args.json:
            json.dump(result, sys.stdout, indent=1, allow_nan=False)
            sys.stdout.write("\n")
        else:
            _print_table(result, sys.stdout)
        sys.stdout.flush()
    except BrokenPipeError:  # e.g. `python cli.py | head`: the reader left, not an error
        sys.stdout = None
    return 0


if __name__ == "__main__":
    sys.exit(main())
