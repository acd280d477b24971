#!/usr/bin/env python3
"""The command line, and the one place that joins orbit → raytrace → degrade → files.

``python cli.py --target cassini --pattern spiral`` renders one sequence into
``output/cassini_spiral/`` (or ``--out``): clean and degraded RGB, instance masks, depth,
normals and per-frame labels. Other commands: ``dataset``, ``ablation``, ``render-scene``,
``preview``, ``snapshots`` (docs/cli.md; ``python cli.py COMMAND --help``).

This module holds the face — the options table, the parsers, the printing — and the
composition: :func:`plan_sequence` loads the target and hands the configuration to
:func:`orbit.plan.plan_orbit`; :func:`render_frame_images` renders a frame
(:func:`raytrace.shade.render`) and degrades it (:mod:`degrade.presets`); :func:`run_frame`
is the per-frame function that :mod:`raytrace.dataset` runs on its pool and writes into the
sequence folder. The three packages never import each other.

Errors in the arguments print one line naming the parameter and what is allowed, and exit
with status 2, leaving nothing behind.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import re
import sys
import time

# one BLAS thread (unless the user set one): nothing here needs a threaded BLAS, and OpenBLAS
# workers that spin after a product steal a core from the renderer's kernels (worker
# processes inherit it); set before NumPy loads OpenBLAS
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from degrade.paper import PAPER_GROUPS
from degrade.presets import PRESETS as DEGRADE_PRESETS
from degrade.sensor import DEMOSAIC_ALGORITHMS
from orbit.attitude import ATTITUDE_MODES
from orbit.patterns import PATTERNS
from raytrace.constants import EARTH_TEXTURES as EARTH_TEXTURE_NAMES
from raytrace.constants import SOLAR_CONSTANT_W_M2
from raytrace.dataset import UsageError as CLIError
from raytrace.dataset import folder, jit, pool, scenes, snapshots
from raytrace.dataset import options as opt
from raytrace.dataset import run as runner
from raytrace.dataset.camera_options import CAMERA_OPTIONS
from raytrace.dataset.modalities import MODALITIES as MODALITY, CAMERA as CAMERA_MODALITIES, preset_error
from raytrace.dataset.modalities import DEFAULT as DEFAULT_MODALITIES
from raytrace.dataset.modalities import NAMES as MODALITIES
from raytrace.presets import QUALITIES
from raytrace.targets import BUILTIN_TARGETS as TARGETS

PROG = "cli.py"

DEFAULT_EPOCH_UTC = "2026-06-21T12:00:00Z"
"""The main job's epoch: the June solstice, when the Sun stands 23.4° off the equator, so that for
the default 51.6° orbit a plane exists whose whole period is sunlit (|β| > 70°, needed by the
elliptical pattern's one-period window); the default phase (:mod:`orbit.viewing`) then keeps
every frame of every pattern lit and in view."""

DEFAULT_FRAMES = 48
"""Frames of the main job: it finishes in under a minute on 2 cores at 1280×960 (README, "The main job")."""
DATASET_FRAMES = 500
DATASET_MODALITIES = ("rgb", "mask", "depth", "normal")
EXPOSURE_MODES = ("fixed", "auto")
EARTH_TEXTURES = (*EARTH_TEXTURE_NAMES, "none")
PAPER_GROUP_NAMES = tuple(PAPER_GROUPS)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2; a flag must be spelled
    out (``--frame 3`` is an error, not ``--frames 3``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{PROG}: error: {message}\n")


# --------------------------------------------------------------------------- the options
def _utc(text: str) -> str:
    """``--epoch``: an ISO 8601 UTC time within the solar formulae's validity (the other value
    parsers: :mod:`raytrace.dataset.options`)."""
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


def _options() -> tuple:
    O = opt.Option
    deg = "deg"
    return (
        # [sequence]
        O("--target", "sequence", opt.choice(TARGETS), "cassini", "built-in target"),
        O("--mesh", "sequence", opt.path, None, "render this mesh file (glb/gltf/obj/ply/stl/off) instead of --target; "
          "body frame = the file's frame (raytrace.meshio.load_mesh)", "FILE"),
        O("--mesh-unit-m", "sequence", opt.float_in(0.0, 1e3, lo_open=True, unit="m"), 1.0,
          "metres per mesh-file unit (0.001 for millimetres)"),
        O("--mesh-crease-deg", "sequence", opt.float_in(0.0, 180.0, unit=deg), 30.0, "--mesh shading: smooth across edges "
          "below this angle (0 flat, 180 all) where the file has no normals of its own (raytrace.meshio.load_mesh)"),
        O("--keypoints", "sequence", opt.path, None, "the target's keypoints: JSON, model/keypoints.json's schema or a list "
          "of [x, y, z] [m] in the body frame (default: 11 by farthest-point sampling of its convex hull)", "FILE.json"),
        O("--pattern", "sequence", opt.choice(PATTERNS), "spiral", "relative-motion pattern"),
        O("--frames", "sequence", opt.int_in(1, 1_000_000), DEFAULT_FRAMES,
          "number of frames, evenly spaced over the window"),
        O("--seed", "sequence", opt.int_in(0, 2**63 - 1), 0,
          "seed of the pattern draw and of every frame's noise; same seed, same bytes"),
        O("--window-s", "sequence", opt.float_in(0.0, 1e7, lo_open=True, unit="s"), None,
          "window length [s] (default: one period for elliptical, half for spiral and drip-drop, "
          "80 m of drift for drift, scaled with the target)"),
        # [pattern]
        O("--amplitude-m", "pattern", opt.float_in(0.0, 1e6, lo_open=True, unit="m"), None,
          "radial semi-amplitude A [m]; with --kappa sets the pattern instead of drawing it from --seed"),
        O("--kappa", "pattern", opt.float_in(-1e3, 1e3), None, "kappa = x_l / A (0 elliptical, "
          "|kappa| < 0.2896 spiral, < 1 drip-drop, >= 1 drift)"),
        O("--gamma-m", "pattern", opt.float_in(-1e7, 1e7, unit="m"), None,
          "along-track position at the characteristic point [m] (default: centre the window on the target)"),
        O("--z-amp-m", "pattern", opt.float_in(0.0, 1e6, unit="m"), None, "out-of-plane amplitude [m] (default 0)"),
        O("--z-phase-deg", "pattern", opt.float_in(-360.0, 360.0, unit=deg), None,
          "out-of-plane phase at t = 0 [deg] (default 0)"),
        O("--tau0-deg", "pattern", opt.float_in(-360.0, 360.0, unit=deg), None,
          "in-plane phase after the characteristic point at t = 0 [deg] (default 0)"),
        # [orbit]
        O("--altitude-km", "orbit", opt.float_in(100.0, 1e6, unit="km"), 400.0, "altitude above the equatorial radius [km]"),
        O("--inclination-deg", "orbit", opt.float_in(0.0, 180.0, unit=deg), 51.6, "inclination [deg]"),
        O("--raan-deg", "orbit", opt.float_in(-360.0, 360.0, unit=deg), None,
          "right ascension of the ascending node [deg] (default: 0, or where no --arg-lat-deg alone keeps every "
          "frame lit and in view, the orbit plane that does best)"),
        O("--arg-lat-deg", "orbit", opt.float_in(-360.0, 360.0, unit=deg), None,
          "argument of latitude of the target at the epoch [deg] (default: the phase that keeps the target fully "
          "sunlit and in view in the most frames; give one to set it: 180 flies the default spiral through "
          "Earth's shadow)"),
        O("--epoch", "orbit", _utc, DEFAULT_EPOCH_UTC, "UTC epoch of frame 0, ISO 8601"),
        O("--sun-margin-deg", "orbit", opt.float_in(0.0, 90.0, unit=deg), 20.0,
          "stray-light margin added to the Sun's radius for the Sun-in-lens test [deg]"),
        # [attitude]
        O("--attitude", "attitude", opt.choice(ATTITUDE_MODES), "lvlh-fixed", "target attitude law (orbit.attitude)"),
        O("--attitude-ypr-deg", "attitude", opt.floats(3, -360.0, 360.0, unit=deg), [0.0, 0.0, 0.0],
          "initial attitude w.r.t. LVLH as z-y-x Euler angles yaw,pitch,roll [deg]", "Y,P,R"),
        O("--spin-axis", "attitude", opt.floats(3, -1e6, 1e6, nonzero=True), [0.0, 0.0, 1.0],
          "spin axis in body axes (spin mode)", "X,Y,Z"),
        O("--spin-rate-deg-s", "attitude", opt.float_in(-3600.0, 3600.0, unit="deg/s"), 0.0, "spin rate [deg/s]"),
        O("--omega0-deg-s", "attitude", opt.floats(3, -3600.0, 3600.0, unit="deg/s"), [0.0, 0.0, 0.0],
          "initial body rate for tumble [deg/s]", "X,Y,Z"),
        O("--inertia-kg-m2", "attitude", opt.floats(3, 1e-9, 1e12, unit="kg m2"), [1.0, 1.0, 1.0],
          "principal moments of inertia Jxx,Jyy,Jzz along the body axes for tumble [kg m^2]", "JX,JY,JZ"),
        # [camera]
        O("--width", "camera", opt.int_in(1, 65535), 1280, "image width [px]"),
        O("--height", "camera", opt.int_in(1, 65535), 960, "image height [px]"),
        O("--focal-length-mm", "camera", opt.float_in(1e-3, 1e4, unit="mm"), 4.0, "focal length [mm]"),
        O("--pixel-pitch-um", "camera", opt.float_in(0.1, 1e3, unit="um"), 3.45, "pixel pitch [um]"),
        O("--distortion", "camera", opt.floats(5, -1e3, 1e3), [0.0, 0.0, 0.0, 0.0, 0.0],
          "Brown-Conrady lens distortion, OpenCV order (zeros: a pinhole); every modality is cast through it",
          "K1,K2,P1,P2,K3"),
        O("--roll-deg", "camera", opt.float_in(-360.0, 360.0, unit="deg"), 0.0,
          "camera roll about its boresight, applied after the look-at pointing [deg]"),
        # [render]
        O("--quality", "render", opt.choice(QUALITIES), "fast", "shading preset (raytrace.shade)"),
        O("--samples", "render", opt.int_in(1, 1 << 20), None, "overrides the preset's sample count"),
        O("--exposure", "render", opt.choice(EXPOSURE_MODES), "fixed",
          "clean RGB exposure: fixed (a white Lambertian surface facing the Sun = 1.0) or auto (per frame)"),
        O("--earth-texture", "render", opt.choice(EARTH_TEXTURES), "bluemarble", "Earth as light and backdrop"),
        O("--earth-albedo", "render", opt.float_in(0.0, 1.0), 0.3, "Earth's mean albedo (bluemarble: x albedo/0.3)"),
        O("--ambient-W-m2-sr", "render", opt.float_in(0.0, 1e4, unit="W/(m2 sr)"), 0.0, "constant sky radiance"),
        O("--star-limit-mag", "render", opt.float_in(-1.5, 9.0, unit="mag"), None,
          "draw the stars brighter than this visual magnitude in the background (procedural sky from --seed, or "
          "--star-catalogue) (default: no stars)", "MAG"),
        O("--star-catalogue", "render", opt.path, None,
          "draw the stars of this CSV catalogue (columns ra_deg, dec_deg, v_mag; J2000) instead of a procedural "
          "sky", "FILE.csv"),
        # [degrade]
        O("--degrade", "degrade", opt.choice(DEGRADE_PRESETS), "physical",
          "degradation of rgb_degraded: none, paper (the source paper's groups D1-D4) or physical (optics + sensor "
          "chain)"),
        O("--paper-group", "degrade", opt.choice(PAPER_GROUP_NAMES), "D4", "paper preset: D1 blur ... D4 blur+Poisson+Gaussian"),
        O("--paper-blur-px", "degrade", opt.float_in(0.0, 1000.0, unit="px"), 15.0,
          "paper preset: motion-blur length L [px] (the paper's value: 15)"),
        O("--paper-angle-deg", "degrade", opt.float_in(-360.0, 360.0, unit="deg"), 30.0,
          "paper preset: motion-blur angle θ [deg] (the paper's value: 30)"),
        O("--paper-gaussian-var", "degrade", opt.float_in(0.0, 1.0), 0.01,
          "paper preset: variance of the Gaussian noise on [0, 1] values (the paper's value: 0.01)"),
        O("--f-number", "degrade", opt.float_in(0.5, 64.0), 4.0, "physical preset: f-number N (aperture = f / N)"),
        O("--exposure-us", "degrade", opt.float_in(0.0, 1e7, lo_open=True, unit="us"), 20.0,
          "physical preset: exposure time [us]"),
        O("--quantum-efficiency", "degrade", opt.float_in(0.0, 1.0, lo_open=True), 0.6, "physical preset: QE"),
        O("--full-well-e", "degrade", opt.float_in(1.0, 1e9, unit="e-"), 10000.0, "physical preset: full well"),
        O("--read-noise-e", "degrade", opt.float_in(0.0, 1e6, unit="e-"), 5.0, "physical preset: read noise sigma"),
        O("--bit-depth", "degrade", opt.int_in(1, 16), 12, "physical preset: ADC bits"),
        O("--aberration-sigma-px", "degrade", opt.float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: Gaussian aberration sigma [px]"),
        O("--motion-blur-px", "degrade", opt.float_in(0.0, 1000.0, unit="px"), 0.0,
          "physical preset: motion-blur length [px] (constant over the sequence)"),
        O("--motion-angle-deg", "degrade", opt.float_in(-360.0, 360.0, unit=deg), 0.0,
          "physical preset: motion-blur direction, counter-clockwise from +column [deg]"),
        O("--defocus-radius-px", "degrade", opt.float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: defocus blur-circle radius [px] (pillbox)"),
        O("--corner-sigma-px", "degrade", opt.float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: Gaussian aberration sigma reached in the image corners [px] (0: uniform)"),
        O("--offset-dn", "degrade", opt.float_in(0.0, 65535.0, unit="DN"), 0.0, "physical preset: ADC black level"),
        O("--dark-current-e-s", "degrade", opt.float_in(0.0, 1e9, unit="e-/s"), 0.0,
          "physical preset: dark current [e-/s]"),
        O("--demosaic", "degrade", opt.choice(DEMOSAIC_ALGORITHMS), "MHC",
          "physical preset: OpenImageIO demosaic algorithm of the RGGB mosaic"),
        O("--motion-blur", "degrade", opt.choice(("fixed", "auto")), "fixed",
          "physical preset: 'fixed' blurs every frame by --motion-blur-px at --motion-angle-deg; 'auto' takes "
          "each frame's blur from the target's own image motion during the exposure"),
        *CAMERA_OPTIONS,
        # [output]
        O("--modalities", "output", opt.subset(MODALITIES), None,
          f"files per frame, comma-separated (default: {','.join(DEFAULT_MODALITIES)}; no rgb_degraded with --degrade "
          "none)",
          "LIST"),
        O("--only-visible", "output", opt.boolean, False,
          "drop frames whose flags say the target cannot be seen (default: render them, flags in labels)",
          switch=True),
        *opt.OUTPUT_FILE_OPTIONS,
    )


OPTIONS = _options()
SECTIONS = tuple(dict.fromkeys(o.section for o in OPTIONS))


def _add_exec(p: argparse.ArgumentParser, *, out_help: str) -> None:
    g = p.add_argument_group("execution (not part of the scenario)")
    g.add_argument("--config", type=opt.path, default=None, metavar="FILE.toml",
                   help="options as TOML tables (as in a sequence's config.toml); flags override")
    g.add_argument("--out", type=opt.out_path, default=None, metavar="DIR", help=out_help)
    g.add_argument("--workers", type=opt.int_in(1, 4096), default=None,
                   help="worker processes (default: all cores of this machine)")
    g.add_argument("--shard", type=opt.shard, default=None, metavar="K/N",
                   help="render only frames i with i %% N == K - 1 (e.g. one task of a job array)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="render on a dask.distributed cluster (tcp://host:8786) instead of local processes")
    g.add_argument("--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the main job."""
    p = _Parser(prog=PROG, description="Relative-orbit image generator for spacecraft vision-based navigation: "
                "renders one sequence of the requested pattern around the target (clean and degraded RGB, "
                "mask, depth, normals, labels). Other commands: dataset, ablation, render-scene, preview, snapshots "
                "(`python cli.py COMMAND --help`).")
    opt.add_options(p, OPTIONS, {})
    p.add_argument("--dry-run", action="store_true", help="print the per-frame states and flags; render nothing")
    p.add_argument("--json", action="store_true", help="print the states and flags as one JSON document; render nothing")
    _add_exec(p, out_help="sequence folder (default: output/TARGET_PATTERN)")
    return p


# --------------------------------------------------------------------------- configuration


def read_config(path: str) -> dict:
    """:func:`raytrace.dataset.options.read_config` of the scenario options."""
    return opt.read_config(path, OPTIONS)


def config_toml(cfg: dict) -> str:
    """The resolved configuration as TOML (automatic values are comments)."""
    return opt.config_toml(cfg, SECTIONS)


def resolve_config(args: argparse.Namespace, defaults: dict | None = None) -> tuple[dict, set]:
    """Resolved scenario options {section: {key: value}}: flags, then the config file, then
    defaults. Also returns the keys set explicitly (by a flag or the file)."""
    defaults = defaults or {}
    file_cfg = read_config(args.config) if getattr(args, "config", None) else {}
    cfg, given = {s: {} for s in SECTIONS}, set()
    if getattr(args, "target", None) is not None and getattr(args, "mesh", None) is not None:
        sys.stderr.write(f"{PROG}: warning: --mesh {args.mesh} is rendered instead of --target {args.target} "
                         "(give one of them)\n")
    if getattr(args, "target", None) is not None or getattr(args, "mesh", None) is not None:
        # the flag chooses the model: a file's mesh (or target) gives way to it, as flags override the file
        file_cfg = {**file_cfg, "sequence": {k: v for k, v in file_cfg.get("sequence", {}).items()
                                             if k not in ("target", "mesh", "mesh_unit_m", "mesh_crease_deg", "keypoints")}}
    for o in OPTIONS:
        value = getattr(args, o.key, None)
        if value is None and o.key in file_cfg.get(o.section, {}):
            value = file_cfg[o.section][o.key]
        if value is not None:
            given.add(o.key)
        else:
            value = defaults.get(o.key, o.default)
        cfg[o.section][o.key] = list(value) if isinstance(value, (list, tuple)) else value
    d = cfg["degrade"]
    out = cfg["output"]
    if out["modalities"] is None:
        mods = defaults.get("modalities") or list(DEFAULT_MODALITIES)
        out["modalities"] = [m for m in mods if not (m == "rgb_degraded" and d["degrade"] == "none")]
    elif why := preset_error(out["modalities"], d["degrade"]):  # e.g. rgb_degraded with --degrade none
        raise CLIError(why)
    if d["degrade"] == "physical":
        full_scale = 2 ** d["bit_depth"] - 1
        if d["offset_dn"] > full_scale / 2:
            raise CLIError(f"argument --offset-dn: must be at most half the ADC's full scale, {full_scale / 2:g} DN at "
                           f"--bit-depth {d['bit_depth']} (a black level above it leaves the signal no room), got "
                           f"{d['offset_dn']:g}")
    if getattr(args, "mesh_crease_deg", None) is not None and cfg["sequence"]["mesh"] is None:
        raise CLIError("argument --mesh-crease-deg: only with --mesh (built-in targets have their own shading normals)")
    for key in ("mesh", "keypoints"):
        if cfg["sequence"][key] is not None:
            cfg["sequence"][key] = os.path.abspath(cfg["sequence"][key])
    return cfg, given


# --------------------------------------------------------------------------- planning (orbit → pose → light)


def plan_sequence(cfg: dict, given: set = frozenset()) -> dict:
    """Load and check the target, then :func:`orbit.plan.plan_orbit`: everything but the pixels.

    Returns a dict: ``result`` (plain-Python scenario and per-frame labels without image
    quantities, the ``--json`` document), ``model``, ``model_spec``, ``camera``, ``keypoints`` (the
    model/keypoints.json document) and per-frame ``lights`` (Sun, Earth and ν in the body frame)."""
    from orbit.plan import PlanError, plan_orbit
    from raytrace.camera import Camera

    seq, cam = cfg["sequence"], cfg["camera"]
    if seq["mesh"] is not None:
        spec = ("mesh", seq["mesh"], seq["mesh_unit_m"], seq["mesh_crease_deg"])
        try:
            model = scenes.load_model(spec, warn_repair=True)
        except ValueError as exc:
            raise CLIError(f"argument --mesh: {exc}") from None
        target = model.name
    else:
        spec = ("builtin", seq["target"])
        model = scenes.load_model(spec)
        target = seq["target"]
    try:
        scenes.scene_of(model, warn_model=True)  # validates the mesh (e.g. zero-area triangles) before anything is written
    except ValueError as exc:
        raise CLIError(f"argument --mesh: {exc}") from None
    scenes.star_field(cfg)  # validates the star catalogue before anything is written
    if seq["mesh"] is not None and "mesh_unit_m" not in given:
        lo, hi = model.bounds_m  # the mesh's own size, wherever its origin lies
        note = scenes.mesh_unit_warning(0.5 * float(np.linalg.norm(hi - lo)), seq["mesh"])
        if note:
            sys.stderr.write(f"{PROG}: warning: {note}\n")
    try:
        camera = Camera.from_focal(cam["focal_length_mm"] * 1e-3, cam["pixel_pitch_um"] * 1e-6, cam["width"],
                                   cam["height"], dist_coeffs=cam["distortion"])
    except ValueError as exc:
        raise CLIError(f"argument --distortion: {exc}") from None
    points = None
    if cfg["degrade"].get("motion_blur") == "auto":
        points = np.concatenate([np.asarray(c.mesh.vertices, dtype=np.float64) for c in model.components])
    try:
        plan = plan_orbit(cfg, given, target=target, radius_m=model.bounding_radius_m, points_body_m=points,
                          intrinsics=(camera.fx, camera.fy, camera.width, camera.height))
    except PlanError as exc:
        raise CLIError(f"argument --{exc.key.replace('_', '-')}: {exc}") from None
    plan.update({"model": model, "model_spec": spec, "camera": camera, "cfg": cfg,
                 "keypoints": scenes.keypoints_of(model, seq["keypoints"]),
                 "name": f"{target}_{plan['result']['pattern']}"})
    return plan


# --------------------------------------------------------------------------- one frame (runs in a worker)
def _worker_ready(quality: str) -> None:
    """A first task for each worker, run while the parent builds the scenes: what a first
    ``quality`` frame would otherwise wait for — the imports (the degradation chain's, scipy.fft
    and scipy.special for the PSFs), numba's kernels loaded from its on-disk cache, the GGX
    split-sum table."""
    import degrade.chain  # noqa: F401
    import raytrace.shade  # noqa: F401
    from raytrace import _precompile
    from raytrace.brdf import split_sum_table
    from raytrace.dataset.jit import precompile_groups
    _precompile.load_here(precompile_groups(quality))
    if quality != "reference":
        split_sum_table()


def degrade_frame(cfg: dict, task: dict, rgb8, radiance, degrade_seq, want=("rgb_degraded",)) -> dict:
    """:func:`degrade.presets.degrade_outputs` ``want`` of one frame task, with its motion blur and Sun."""
    from degrade.presets import degrade_outputs
    return degrade_outputs(cfg["degrade"], cfg["camera"], rgb8, radiance, degrade_seq, task["light"].get("motion"),
                           label=task["label"], sequence_seed=cfg["sequence"]["seed"], want=want)


def render_frame_images(task: dict) -> tuple[dict, dict]:
    """Render one frame of a task and return (images, image-derived label fields).

    ``images`` maps a modality to its pixels (only the requested ones, plus ``rgb`` when
    ``task["want_rgb"]``)."""
    from degrade.encode import encode_srgb8
    from raytrace.camera import Camera
    from raytrace.correspondence import FrameHits
    from raytrace.shade import render
    cfg = task["cfg"]
    mods = set(task["modalities"])
    scene = scenes.scene(task["model_spec"], task.get("prebuilt"))
    camera = Camera(*task["camera"])
    R = np.asarray(task["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
    t = np.asarray(task["t_cam_m"], dtype=np.float64)
    render_seed, degrade_seq = folder.frame_seeds(cfg["sequence"]["seed"], task["frame"])
    d = cfg["degrade"]
    need_rgb = task.get("want_rgb") or "rgb" in mods or ("rgb_degraded" in mods and d["degrade"] == "paper")
    need_radiance = scenes.shades(task)
    images, info = {}, {}
    if need_radiance:
        r = cfg["render"]
        lighting = scenes.lighting_of(task["light"], r, scenes.star_field(cfg), cfg["sequence"]["seed"])
        frame = render(scene, camera, R, t, lighting, quality=r["quality"], samples=r["samples"], seed=render_seed,
                       parts=any(MODALITY[m].light_parts for m in mods))
        geo, radiance = frame.geometry, frame.radiance
    else:  # geometry-only modalities: no shading at all
        geo, radiance = scene.render_geometry(camera, R, t), None
    if need_rgb:
        if cfg["render"]["exposure"] == "auto":
            from degrade.exposure import auto_exposure
            linear, scale = auto_exposure(radiance, geo.mask)
        else:  # fixed: a white Lambertian surface facing the Sun (L = E/π) maps to 1.0
            scale = math.pi / SOLAR_CONSTANT_W_M2
            linear = radiance * np.float32(scale)
        images["rgb"] = encode_srgb8(linear)
        info["exposure_scale"] = float(scale)
    if mods.intersection(CAMERA_MODALITIES):  # one simulation for rgb_degraded, signal_e, saturation
        images.update(degrade_frame(cfg, task, images.get("rgb"), radiance, degrade_seq, sorted(mods.intersection(CAMERA_MODALITIES))))
    hits = FrameHits(scene, camera, R, t, geo, task.get("next_pose"))  # hit points made on first use
    for m in task["modalities"]:  # the rest from the geometry and radiance (raytrace.dataset.modalities)
        if MODALITY[m].produce is not None:
            source = frame.light_parts if MODALITY[m].light_parts else radiance
            images[m] = MODALITY[m].produce(geo, source, *([hits] if MODALITY[m].hits else []))
    bbox = geo.bbox_xywh
    vf = geo.visible_fraction
    info.update({"bbox": None if bbox is None else [int(v) for v in bbox],
                 "visible_fraction": None if math.isnan(vf) else float(vf),
                 "pixel_counts": [int(v) for v in geo.pixel_counts]})
    info.update(scenes.keypoint_fields(task, scene, camera, R, t))
    return images, info


def run_frame(task: dict) -> dict:
    """Render, degrade and write one frame (files atomically, then its manifest record:
    :func:`raytrace.dataset.folder.write_frame`); returns the frame's label. With
    ``task["write"]`` false, returns the images instead."""
    images, info = render_frame_images(task)
    if not task.get("write", True):
        return {"frame": task["frame"], "index": task.get("index"), "images": images, "info": info}
    return folder.write_frame(task, images, info)


def run_plans(jobs: list, args: argparse.Namespace, *, desc: str | None = None) -> list:
    """:func:`raytrace.dataset.run.run_plans` of the (plan, sequence folder) pairs with
    :func:`run_frame`, as the parsed ``args`` ask (workers, shard, scheduler, quiet)."""
    quality = jobs[0][0]["cfg"]["render"]["quality"] if jobs else "fast"
    return runner.run_plans(jobs, run_frame, config_text=config_toml, workers=args.workers, shard=args.shard,
                            scheduler=args.scheduler, quiet=args.quiet, quality=quality,
                            desc=desc, ready=functools.partial(_worker_ready, quality))


def _interrupted(exc: KeyboardInterrupt, after: str) -> int:
    """One line for Ctrl-C or :class:`Terminated`; the exit status, 128 + the signal."""
    how = f"terminated by {exc}" if isinstance(exc, pool.Terminated) else "interrupted"
    sys.stderr.write(f"{PROG}: {how}; {after}\n")
    return 128 + getattr(exc, "signum", 2)  # Ctrl-C: SIGINT


# --------------------------------------------------------------------------- commands
def _fail(exc: BaseException) -> int:
    sys.stderr.write(f"{PROG}: error: {exc}\n")
    return 2


def _render_failed(exc: BaseException) -> int:
    msg = " ".join(str(exc).split()) or type(exc).__name__
    sys.stderr.write(f"{PROG}: error: rendering failed ({type(exc).__name__}: {msg}); complete frames are kept, "
                     "rerun the same command to resume\n")
    return 1


def _guarded(run, usage_errors=(CLIError,)) -> tuple:
    """``run()`` under the rendering commands' error policy: (its result, None), or (None, exit
    status) after one line on stderr: 2 for a usage error, 130 on Ctrl-C (143 on SIGTERM, 129 on
    SIGHUP: :class:`Terminated`), 1 for a failure while rendering (complete frames are kept either
    way)."""
    try:
        return run(), None
    except usage_errors as exc:
        return None, _fail(exc)
    except (KeyboardInterrupt, Exception) as exc:  # noqa: BLE001 - a failure while rendering: one line
        signal_exc = pool.interruption(exc)  # Ctrl-C or Terminated, or a failure raised as it unwound the job
        if signal_exc is not None:
            return None, _interrupted(signal_exc, "complete frames are kept, rerun the same command to resume")
        return None, _render_failed(exc)


def main_job(argv: list) -> int:
    """``cli.py [options]``: render one sequence (or print its states with --dry-run/--json)."""
    args = build_parser().parse_args(argv)
    try:
        cfg, given = resolve_config(args)
        plan = plan_sequence(cfg, given)
    except (CLIError, ValueError) as exc:
        return _fail(exc)
    if args.json or args.dry_run:
        try:
            if args.json:
                json.dump(plan["result"], sys.stdout, indent=1, allow_nan=False)
                sys.stdout.write("\n")
            else:
                from orbit.plan import plan_table
                plan_table(plan["result"], sys.stdout)
            sys.stdout.flush()
        except BrokenPipeError:  # e.g. `python cli.py --dry-run | head`: the reader left, not an error
            sys.stdout = None
        except OSError as exc:  # e.g. a full disk
            sys.stdout = None
            sys.stderr.write(f"{PROG}: error: cannot write the plan to standard output ({exc.strerror or exc})\n")
            return 1
        return 0
    seq_dir = args.out or os.path.join("output", plan["name"])
    t0 = time.perf_counter()
    stats, status = _guarded(lambda: run_plans([(plan, seq_dir)], args))
    if status is not None:
        return status
    sys.stdout.write(runner.summary_line(stats[0], time.perf_counter() - t0))
    return 0


def dataset_main(argv: list) -> int:
    """``cli.py dataset``: the paper's dataset (targets × patterns) in one command."""
    p = _Parser(prog=f"{PROG} dataset", description="Render the paper's dataset: every target (and with --patterns "
                "every pattern) as one sequence folder each, with one progress bar and a final table of counts.")
    p.add_argument("--targets", type=opt.subset(TARGETS, keep_order=True), default=list(TARGETS),
                   metavar=opt.choices_metavar(opt.subset(TARGETS), many=True),
                   help="built-in targets, comma-separated, in the order of the table (default: all)")
    p.add_argument("--patterns", action="store_true", help="all four patterns per target (default: --pattern only)")
    defaults = {"frames": DATASET_FRAMES, "degrade": "none", "modalities": list(DATASET_MODALITIES)}
    opt.add_options(p, OPTIONS, defaults, skip=("target", "mesh", "mesh_unit_m", "mesh_crease_deg", "keypoints"))
    _add_exec(p, out_help="dataset folder; one sub-folder TARGET_PATTERN per sequence (default: output/dataset)")
    args = p.parse_args(argv)
    for key in ("target", "mesh", "mesh_unit_m", "mesh_crease_deg", "keypoints"):
        setattr(args, key, None)
    t0 = time.perf_counter()

    def plan_and_run():
        cfg, given = resolve_config(args, defaults)
        for key in ("mesh", "keypoints"):
            if cfg["sequence"][key] is not None:
                raise CLIError(f"--config: [sequence] {key} is not used by the dataset command (built-in targets only)")
        if args.patterns and (cfg["pattern"]["amplitude_m"] is not None or cfg["pattern"]["kappa"] is not None):
            # one (A, kappa) is one pattern: the four would all be it, in one folder
            raise CLIError("argument --patterns: draws each pattern from --seed; drop --amplitude-m/--kappa")
        jobs = []
        patterns = list(PATTERNS) if args.patterns else [cfg["sequence"]["pattern"]]
        root = args.out or os.path.join("output", "dataset")
        for target in args.targets:
            for pattern in patterns:
                c = json.loads(json.dumps(cfg))
                c["sequence"]["target"], c["sequence"]["pattern"] = target, pattern
                plan = plan_sequence(c, given - {"pattern"})
                jobs.append((plan, os.path.join(root, plan["name"])))
        return run_plans(jobs, args, desc="dataset"), cfg["output"]["modalities"], root

    done, status = _guarded(plan_and_run, (CLIError, ValueError))
    if status is not None:
        return status
    stats, modalities, root = done
    sys.stdout.write(runner.stats_table(stats, modalities, time.perf_counter() - t0, root))
    return 0


def ablation_main(argv: list) -> int:
    """``cli.py ablation``: degradation ablation (degrade.ablation) on clean renders."""
    p = _Parser(prog=f"{PROG} ablation", description="Render N clean frames per target through the pipeline and "
                "measure what each degradation costs (PSNR, SSIM; LPIPS when installed).")
    p.add_argument("--targets", type=opt.subset(TARGETS, keep_order=True), default=["cassini"],
                   metavar=opt.choices_metavar(opt.subset(TARGETS), many=True),
                   help="built-in targets, comma-separated (default: cassini)")
    p.add_argument("--frames", type=opt.int_in(1, 10_000), default=4, help="clean frames per target (default: 4)")
    p.add_argument("--mode", type=opt.choice(("paper", "physical", "both")), default="both",
                   metavar=opt.choices_metavar(opt.choice(("paper", "physical", "both"))),
                   help="which study to report (default: both)")
    p.add_argument("--pattern", type=opt.choice(PATTERNS), default="spiral", metavar=opt.choices_metavar(opt.choice(PATTERNS)),
                   help="pattern (default: spiral)")
    # SSIM's 7 × 7 window (skimage.metrics.structural_similarity) needs images of at least 7 px a side
    p.add_argument("--width", type=opt.int_in(7, 65535), default=640, help="image width [px], >= 7 (default: 640)")
    p.add_argument("--height", type=opt.int_in(7, 65535), default=480, help="image height [px], >= 7 (default: 480)")
    p.add_argument("--focal-length-mm", type=opt.float_in(1e-3, 1e4, unit="mm"), default=2.0,
                   help="focal length [mm] (default: 2, the field of view of the full-size default camera)")
    p.add_argument("--quality", type=opt.choice(QUALITIES), default="fast", metavar=opt.choices_metavar(opt.choice(QUALITIES)),
                   help="shading preset (default: fast)")
    p.add_argument("--seed", type=opt.int_in(0, 2**63 - 1), default=0, help="seed (default: 0)")
    p.add_argument("--workers", type=opt.int_in(1, 4096), default=None, help="worker processes (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    from degrade.ablation import format_ablation, run_ablation
    from degrade.presets import physical_config
    from raytrace.camera import Camera
    try:
        tasks, labels = [], []
        for target in args.targets:
            ns = argparse.Namespace(**{o.key: None for o in OPTIONS})
            ns.target, ns.pattern, ns.seed, ns.quality = target, args.pattern, args.seed, args.quality
            ns.width, ns.height, ns.focal_length_mm = args.width, args.height, args.focal_length_mm
            ns.frames = 4 * args.frames
            cfg, given = resolve_config(ns)
            plan = plan_sequence(cfg, given)
            visible = [f["frame"] for f in plan["result"]["frames"] if f["visible"]] or [0]
            pick = sorted({visible[round(j)] for j in np.linspace(0, len(visible) - 1, args.frames)})
            t, _ = folder.tasks_for(plan, "", None, write=False, frames=pick)
            for task in t:
                task["index"] = len(tasks)
                tasks.append(task)
            labels += [target] * len(t)
        workers = pool.fit_workers([Camera(*tasks[0]["camera"])], args.workers or pool.default_workers())
        bar = runner.progress_bar(len(tasks), 0, "ablation", args.quiet)
        rgb = [None] * len(tasks)
        try:
            for res in pool.execute(tasks, run_frame, workers=workers, progress=bar,
                                    ready=functools.partial(_worker_ready, args.quality)):
                rgb[res["index"]] = res["images"]["rgb"]  # results arrive as they complete
        finally:
            bar.close()
        imgs = [im.astype(np.float32) / np.float32(255.0) for im in rgb]
        physical = None if args.mode == "paper" else physical_config(cfg["degrade"], cfg["camera"])
        report = run_ablation(imgs, labels, seed=args.seed, physical=physical)
        if args.mode == "physical":
            import dataclasses
            report = dataclasses.replace(report, rows=tuple(r for r in report.rows if r.mode == "physical"))
    except (CLIError, ValueError) as exc:
        return _fail(exc)
    sys.stdout.write(format_ablation(report) + "\n")
    return 0


# --------------------------------------------------------------------------- render-scene
def frame_images(frame, *, name: str = "000000") -> dict:
    """The files of one rendered frame (relative path → pixels) of the modalities ``render-scene``
    writes (:data:`raytrace.dataset.folder.SCENE_MODALITIES`), as in a sequence folder, ``rgb``
    with auto exposure. Also returns the exposure scale used."""
    from degrade.encode import srgb_encode
    from degrade.exposure import auto_exposure
    from raytrace.dataset.modalities import relpath
    geo = frame.geometry
    linear, scale = auto_exposure(frame.radiance, geo.mask)
    files = {relpath("rgb", name): srgb_encode(np.clip(linear, 0.0, 1.0), bits=8)}
    files.update({relpath(m, name): MODALITY[m].produce(geo, frame.radiance)
                  for m in folder.SCENE_MODALITIES if m != "rgb"})
    return files, scale


def geometric_shadow_fraction(lighting) -> float | None:
    """The fraction of the solar disc that a :class:`raytrace.lighting.Lighting`'s Earth leaves
    visible at the target (:func:`orbit.visibility.illuminated_fraction_seen`), or None without
    Earth. ``shadow_fraction`` is what the renderer uses (the Earth does not shadow the Sun by
    itself); this tells whether the two agree."""
    e = lighting.earth
    if e is None:
        return None
    from orbit.visibility import illuminated_fraction_seen
    return float(illuminated_fraction_seen(e.earth_dir_body, e.distance_m, lighting.sun_dir_body, earth_radius_m=e.radius_m,
                                           sun_angular_diameter_rad=lighting.sun_angular_diameter_rad))


def render_scene_main(argv: list[str]) -> int:
    """``cli.py render-scene SCENE.json --out DIR``: render one frame of an explicit scene."""
    parser = _Parser(prog=f"{PROG} render-scene",
                     description="Render one frame of the scene described by a JSON file (schema in docs/shading.md).")
    parser.add_argument("scene", help="scene file (JSON)")
    parser.add_argument("--out", type=opt.out_path, required=True, help="output folder (created if missing)")
    parser.add_argument("--quality", type=opt.choice(QUALITIES), default=None,
                        metavar=opt.choices_metavar(opt.choice(QUALITIES)),
                        help="overrides the file's quality preset (default: the file's)")
    parser.add_argument("--samples", type=opt.int_in(1, 1 << 20), default=None,
                        help="overrides the preset's sample count")
    parser.add_argument("--seed", type=opt.int_in(0, 2**31 - 1), default=None, help="overrides the file's seed")
    args = parser.parse_args(argv)
    from raytrace.scene import Scene
    from raytrace.scenefile import load_scene_file
    from raytrace.shade import render
    try:
        spec = load_scene_file(args.scene)
        pool.fit_workers([spec.camera], 1)
        folder.check_out_folder(args.out)
        folder.check_scene_out(args.out)
        for note in spec.notes:
            sys.stderr.write(f"{PROG}: warning: {note}\n")
        quality = args.quality or spec.quality
        samples = args.samples if args.samples is not None else (spec.samples if args.quality is None else None)
        seed = args.seed if args.seed is not None else spec.seed
        nu_geo = geometric_shadow_fraction(spec.lighting)
        if nu_geo is not None and abs(nu_geo - spec.lighting.shadow_fraction) > 0.01:
            sys.stderr.write(f"{PROG}: warning: sun.shadow_fraction is {spec.lighting.shadow_fraction:g} but the "
                             f"scene's Earth leaves {nu_geo:.3g} of the solar disc visible from the target; the "
                             "render uses shadow_fraction (set it to match if the eclipse is meant)\n")
        serial = pool.frame_threads(1, 1) == 1
        missing = jit.kernels_not_compiled(quality, serial)
        if missing:
            jit.compile_kernels(missing, quiet=False, serial=serial)
        t0 = time.perf_counter()
        frame = render(Scene(spec.model), spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting,
                       quality=quality, samples=samples, seed=seed)
        elapsed = time.perf_counter() - t0
        files, scale = frame_images(frame)
        geo = frame.geometry
        if not geo.mask.any():
            sys.stderr.write(f"{PROG}: warning: no pixel sees the target (it is behind the camera or outside the "
                             "field of view: check camera.R_cam_from_body and t_cam_m); the frame holds only the "
                             "background\n")
        info = spec.frame_record(frame, scene_path=os.path.abspath(args.scene), samples=samples, seed=seed,
                                 render_s=elapsed, exposure_scale=scale, geometric_shadow_fraction=nu_geo)
        folder.write_files_atomically(args.out, files, {"frame.json": json.dumps(info, indent=1) + "\n"})
    except (CLIError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    except FloatingPointError as exc:  # a renderer bug, not the input's: say so in one line
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 1
    except Exception as exc:  # noqa: BLE001 - any other failure: one line, nothing written (as the main job)
        signal_exc = pool.interruption(exc)
        if signal_exc is not None:  # raised as a signal's exception unwound the render: main() reports it
            raise signal_exc from None
        msg = " ".join(str(exc).split()) or type(exc).__name__
        sys.stderr.write(f"{PROG}: error: rendering {args.scene} failed ({type(exc).__name__}: {msg}); "
                         f"nothing was written to {args.out}\n")
        return 1
    sys.stdout.write(f"rendered {args.scene} ({frame.quality.name}) in {elapsed:.2f} s -> {args.out}\n")
    return 0


# --------------------------------------------------------------------------- preview
PREVIEW_SIZE = (1600, 1000)
"""Preview PNG size of one sequence, width × height [px]; ``--all-patterns`` uses 2800 × 1100."""
PREVIEW_SIZE_ALL = (2800, 1100)


def preview_track(plan: dict):
    """The :class:`raytrace.preview.PreviewTrack` of a planned sequence
    (:func:`raytrace.preview.model_track`): the camera axes from the renderer's pose and the
    look-at pointing of :func:`orbit.plan.plan_orbit`; the target at the start frame's attitude."""
    from orbit.pose import look_at
    from raytrace.preview import model_track
    res = plan["result"]
    r_lvlh = np.array([f["r_lvlh"] for f in res["frames"]], dtype=np.float64)
    R_cam_from_body = np.array([f["R_cam_from_body"] for f in res["frames"]], dtype=np.float64).reshape(-1, 3, 3)
    return model_track(f"{res['target']} {res['pattern']}", plan["model"], plan["camera"], r_lvlh, res["t_s"],
                       [f["visible"] for f in res["frames"]], np.swapaxes(look_at(r_lvlh), -1, -2), R_cam_from_body,
                       plan["lights"][0])


def preview_main(argv: list) -> int:
    """``cli.py preview``: an off-screen PNG of the sequence the same options would render."""
    p = _Parser(prog=f"{PROG} preview", description="Draw, without rendering it, the sequence that the main job "
                "would render with the same options: the target at true scale in LVLH axes, the observer "
                "trajectory coloured by time (start and end marked), camera frusta, the Sun and Earth directions "
                "at the start frame, frames failing visibility in red; below, the in-plane x-y projection. "
                "Off-screen (no display needed); seconds, not minutes.")
    opt.add_options(p, OPTIONS, {})
    g = p.add_argument_group("preview (not part of the scenario)")
    g.add_argument("--config", type=opt.path, default=None, metavar="FILE.toml",
                   help="options as TOML tables (a sequence's config.toml previews that sequence); flags override")
    g.add_argument("--out", type=opt.out_path, default=None, metavar="FILE.png",
                   help="PNG to write (default: output/TARGET_PATTERN_preview.png, "
                        "output/TARGET_all-patterns_preview.png)")
    g.add_argument("--all-patterns", action="store_true", help="the four patterns side by side for one target")
    g.add_argument("--size", type=opt.size_wxh, default=None, metavar="WxH",
                   help=f"PNG size [px] (default: {PREVIEW_SIZE[0]}x{PREVIEW_SIZE[1]}, "
                        f"{PREVIEW_SIZE_ALL[0]}x{PREVIEW_SIZE_ALL[1]} with --all-patterns)")
    g.add_argument("--frusta-every", type=opt.int_in(1, 1_000_000), default=None, metavar="K",
                   help="a camera frustum every K frames (default: about 12 per sequence)")
    g.add_argument("--interactive", action="store_true", help="also open a window (needs a display)")
    g.add_argument("--html", type=opt.out_path, default=None, metavar="FILE.html",
                   help="also export an interactive scene (needs pyvista's exporter: "
                        "pip install trame-pyvista nest_asyncio2)")
    args = p.parse_args(argv)
    from raytrace import preview
    t0 = time.perf_counter()
    try:
        preview.check_outputs(args.out, args.html, args.interactive)
        cfg, given = resolve_config(args)
        if args.all_patterns:
            if cfg["pattern"]["amplitude_m"] is not None or cfg["pattern"]["kappa"] is not None:
                raise CLIError("argument --all-patterns: draws each pattern from --seed; drop --amplitude-m/--kappa")
            plans = []
            for pattern in PATTERNS:
                c = json.loads(json.dumps(cfg))
                c["sequence"]["pattern"] = pattern
                plans.append(plan_sequence(c, given - {"pattern"}))
            name = f"{plans[0]['result']['target']}_all-patterns"
        else:
            plans = [plan_sequence(cfg, given)]
            name = plans[0]["name"]
        tracks = [preview_track(plan) for plan in plans]
        size = args.size or (PREVIEW_SIZE_ALL if args.all_patterns else PREVIEW_SIZE)
        out = args.out or os.path.join("output", f"{name}_preview.png")
        preview.write_preview_files(tracks, out, size=size, frusta_every=args.frusta_every, html_path=args.html)
    except (CLIError, ValueError) as exc:
        return _fail(exc)
    elapsed = time.perf_counter() - t0
    for t in tracks:
        sys.stdout.write(f"{t.title}: {t.n_frames} frames, {int(t.visible.sum())} visible, "
                         f"range {np.linalg.norm(t.r_lvlh_m, axis=1).min():.1f}-"
                         f"{np.linalg.norm(t.r_lvlh_m, axis=1).max():.1f} m\n")
    extra = f" and {args.html}" if args.html else ""
    sys.stdout.write(f"preview {size[0]}x{size[1]} in {elapsed:.1f} s -> {out}{extra}\n")
    if args.interactive:
        preview.build_plotter(tracks, size=size, frusta_every=args.frusta_every, off_screen=False).show()
    return 0


# --------------------------------------------------------------------------- render snapshots
SNAPSHOT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "tests", "snapshots")
"""Committed reference renders (``python cli.py snapshots --update`` rewrites them)."""


def snapshot_cases(targets=None, patterns=None) -> list:
    """Snapshot names ``TARGET_PATTERN`` for every built-in target × pattern (or the given ones)."""
    return [f"{t}_{p}" for t in (targets or TARGETS) for p in (patterns or PATTERNS)]


def _snapshot_plan(name: str) -> tuple:
    """(resolved config, tasks of the kept frames) of the snapshot ``TARGET_PATTERN``."""
    target, _, pattern = name.partition("_")
    if target not in TARGETS or pattern not in PATTERNS:
        raise ValueError(f"snapshot name must be TARGET_PATTERN with a target of {', '.join(TARGETS)} and a pattern "
                         f"of {', '.join(PATTERNS)}; got {name!r}")
    s = snapshots.SNAPSHOT_SETTINGS
    ns = argparse.Namespace(**{o.key: None for o in OPTIONS}, config=None)
    ns.target, ns.pattern, ns.frames, ns.seed, ns.quality = target, pattern, s["frames"], s["seed"], s["quality"]
    ns.width, ns.height = s["width"], s["height"]
    ns.focal_length_mm, ns.pixel_pitch_um = s["focal_length_mm"], s["pixel_pitch_um"]
    ns.epoch, ns.raan_deg, ns.arg_lat_deg = s["epoch"], s["raan_deg"], s["arg_lat_deg"]  # a fixed orbit geometry
    cfg, given = resolve_config(ns)
    plan = plan_sequence(cfg, given)
    tasks, _ = folder.tasks_for(plan, "", None, write=False, frames=s["kept_frames"])
    return cfg, tasks


def _with_preset(cfg: dict, preset: str) -> dict:
    c = json.loads(json.dumps(cfg))
    c["degrade"]["degrade"] = preset
    return c


def render_snapshot(name: str) -> dict:
    """Render the snapshot ``TARGET_PATTERN`` with :func:`plan_sequence` and
    :func:`render_frame_images`: modality → the kept frames side by side (one strip), and
    ``radiance`` (:func:`raytrace.dataset.snapshots.snapshot_radiance`), from which
    :func:`degrade_snapshot` makes the degraded strips."""
    cfg, tasks = _snapshot_plan(name)
    out = {m: [] for m in ("rgb", "mask", "depth", "normal", "radiance")}
    for task in tasks:
        t = dict(task, cfg=_with_preset(cfg, snapshots.SNAPSHOT_SETTINGS["degrade_presets"][0]),
                 modalities=["rgb", "mask", "depth", "normal", "hdr"])
        images, _info = render_frame_images(t)
        for m in ("rgb", "mask", "depth", "normal"):
            out[m].append(images[m])
        out["radiance"].append(snapshots.snapshot_radiance(images["hdr"]))
    strips = {m: np.concatenate(v, axis=1) for m, v in out.items()}
    return {**strips, **degrade_snapshot(name, strips)}


def degrade_snapshot(name: str, images: dict) -> dict:
    """The degraded strips (``rgb_paper``, ``rgb_physical``) that the main job's degradation
    (:func:`degrade_frame`, each frame's own random stream) makes of the clean ``rgb`` and
    ``radiance`` strips in ``images`` (a snapshot's references, say)."""
    cfg, tasks = _snapshot_plan(name)
    width = snapshots.SNAPSHOT_SETTINGS["width"]
    out = {}
    for preset in snapshots.SNAPSHOT_SETTINGS["degrade_presets"]:
        c = _with_preset(cfg, preset)
        strips = []
        for j, task in enumerate(tasks):
            cols = slice(j * width, (j + 1) * width)
            _render_seed, degrade_seq = folder.frame_seeds(c["sequence"]["seed"], task["frame"])
            strips.append(degrade_frame(c, task, images["rgb"][:, cols], images["radiance"][:, cols], degrade_seq)["rgb_degraded"])
        out[f"rgb_{preset}"] = np.concatenate(strips, axis=1)
    return out


def snapshots_main(argv: list) -> int:
    """``cli.py snapshots [--update]``: compare small renders with the committed references."""
    import tempfile
    p = _Parser(prog=f"{PROG} snapshots", description="Render every built-in target x pattern small (160x120, three "
                "frames, clean RGB, both degradation presets, mask, depth, normals) and compare with the references "
                "in tests/snapshots/: masks exactly, depth and normals within tight tolerances, RGB by PSNR >= 45 dB. "
                "Exit status 1 when something moved (a diff image per failure). --update rewrites the references.")
    p.add_argument("--update", action="store_true", help="rewrite the references instead of comparing (deliberate)")
    p.add_argument("--targets", type=opt.subset(TARGETS), default=None,
                   metavar=opt.choices_metavar(opt.subset(TARGETS), True),
                   help="only these targets, comma-separated (default: all)")
    p.add_argument("--patterns", type=opt.subset(PATTERNS), default=None,
                   metavar=opt.choices_metavar(opt.subset(PATTERNS), True),
                   help="only these patterns, comma-separated (default: all)")
    p.add_argument("--dir", type=opt.out_path, default=SNAPSHOT_DIR, metavar="DIR",
                   help="reference folder (default: tests/snapshots)")
    p.add_argument("--diff-dir", type=opt.out_path, default=None, metavar="DIR",
                   help="where diff images go (default: a new temporary folder)")
    args = p.parse_args(argv)
    names = snapshot_cases(args.targets, args.patterns)
    try:  # the folders are checked before the renders (a bad one failed after them, blamed on --dir)
        if args.update:
            folder.check_out_folder(args.dir, option="--dir")
        elif not os.path.isdir(args.dir):
            raise CLIError(f"--dir: {args.dir} is not a folder of snapshot references (python cli.py snapshots "
                           "--update --dir DIR writes them)")
        if args.diff_dir:
            folder.check_out_folder(args.diff_dir, option="--diff-dir")
    except CLIError as exc:
        return _fail(exc)
    diff_dir = args.diff_dir or tempfile.mkdtemp(prefix="orbitsynth-snapshots-")
    try:
        return _snapshots_run(args, names, diff_dir)
    finally:
        # a temporary folder of our own stays only if it holds diff images
        if not args.diff_dir and os.path.isdir(diff_dir) and not os.listdir(diff_dir):
            os.rmdir(diff_dir)


def _snapshots_run(args, names: list, diff_dir: str) -> int:
    """:func:`snapshots_main` after parsing: :func:`raytrace.dataset.snapshots.run_snapshots`
    with the main job's render and degradation."""
    try:
        return snapshots.run_snapshots(names, args.dir, diff_dir, update=args.update, render=render_snapshot,
                                       degrade=degrade_snapshot, out=sys.stdout)
    except (CLIError, ValueError, FileNotFoundError) as exc:
        return _fail(exc)
    except OSError as exc:
        return _fail(CLIError(f"--dir: {exc}"))


def export_main(argv: list) -> int:
    """``cli.py export``: sequence folders to BOP, SPEED+ or COCO (:mod:`raytrace.export.command`)."""
    from raytrace.export.command import export_main as run
    return run(argv)


COMMANDS = {"render-scene": render_scene_main, "dataset": dataset_main, "ablation": ablation_main,
            "preview": preview_main, "snapshots": snapshots_main, "export": export_main}


def _unknown_command(word: str) -> int:
    """One line for ``cli.py WORD`` where WORD is no command: the nearest command, if any, and
    the list (the main job takes options only)."""
    import difflib
    near = difflib.get_close_matches(word, list(COMMANDS), n=1, cutoff=0.6)
    hint = f"; did you mean {near[0]!r}?" if near else ""
    sys.stderr.write(f"{PROG}: error: unknown command {word!r}{hint} (commands: {', '.join(COMMANDS)}; the main job "
                     "takes options only, e.g. --target cassini --pattern spiral)\n")
    return 2


_NEGATIVE_VALUE = re.compile(r"-(?:\d|\.\d|inf|nan)", re.IGNORECASE)


def _attach_negative_values(argv: list) -> list:
    """argparse takes a value that starts with '-' only when it looks like a plain negative number ('-15',
    '-.5'): `--attitude-ypr-deg -40,5,60` or `--roll-deg -1e-3` stopped with "expected one argument". Such a value
    is joined to the long option before it (`--attitude-ypr-deg=-40,5,60`), which argparse reads as that option's
    value and its check then judges like any other."""
    out = []
    for tok in argv:
        prev = str(out[-1]) if out else ""
        if _NEGATIVE_VALUE.match(str(tok)) and prev.startswith("--") and "=" not in prev:
            out[-1] = f"{prev}={tok}"
        else:
            out.append(tok)
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    argv = _attach_negative_values(sys.argv[1:] if argv is None else list(argv))
    pool.remove_stale_scene_folders()
    try:
        if argv and argv[0] in COMMANDS:
            return COMMANDS[argv[0]](argv[1:])
        if argv and not str(argv[0]).startswith("-"):
            return _unknown_command(str(argv[0]))
        return main_job(argv)
    except KeyboardInterrupt as exc:  # a command without its own message (render-scene, preview, …)
        return _interrupted(exc, "nothing half-written is left")


if __name__ == "__main__":
    # run as the module `cli`, so worker processes (spawned, or dask) find run_frame by name
    import cli
    pool.install_termination_handlers()
    pool.exit_without_teardown(cli.main())
