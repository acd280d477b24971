#!/usr/bin/env python3
"""Command line and pipeline: orbit → pose → raytrace → degrade → files.

``python cli.py --target cassini --pattern spiral`` renders one sequence into
``output/cassini_spiral/`` (or ``--out``): clean and degraded RGB, instance masks, depth,
normals and per-frame labels, with a progress bar and a one-line summary. Every option of the
lower layers is a flag and a key of ``--config FILE.toml`` (flags override the file); the
resolved configuration is written with the output (``config.toml``, ``scenario.json``).
``--dry-run`` prints the per-frame states and visibility flags instead of rendering, ``--json``
prints them as one JSON document (keys as in ``scenario.json`` and ``labels.json``, SI units).

Other commands:

* ``python cli.py dataset`` — the paper's dataset in one command (4 targets × 500 frames,
  ``--patterns`` for all four patterns per target), one progress bar, a table of counts;
* ``python cli.py ablation --target T[,T..] --frames N`` — degradation ablation on clean renders;
* ``python cli.py render-scene SCENE.json --out DIR`` — one frame of an explicit scene;
* ``python cli.py preview --target T --pattern P [--out preview.png] [--all-patterns]`` — an
  off-screen pyvista picture of the trajectory, camera frusta, Sun and Earth, in seconds;
* ``python cli.py snapshots [--update]`` — compare (or deliberately refresh) the small render
  snapshots that CI guards pixels with.

Frames are independent and seeded per frame (``SeedSequence(seed).spawn``): the output is
byte-identical for 1 worker, N worker processes (``--workers``), shards (``--shard K/N``) or a
dask cluster (``--scheduler ADDRESS``). Files are written under temporary names and renamed;
a frame is complete when its manifest record (``.manifest/NNNNNN.json``, with checksums) is
written, and a rerun skips complete frames.

Errors in the arguments print one line naming the parameter and what is allowed, and exit
with status 2, leaving nothing behind.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass

# one BLAS thread (unless the user set one): nothing here needs a threaded BLAS, and OpenBLAS
# workers that spin after a product steal a core from the renderer's kernels (worker
# processes inherit it); set before NumPy loads OpenBLAS
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from orbit.attitude import ATTITUDE_MODES
from orbit.patterns import PATTERNS
from raytrace.constants import SOLAR_CONSTANT_W_M2
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
MODALITIES = ("rgb", "rgb_degraded", "mask", "depth", "normal", "hdr")
"""Per-frame image files a sequence can hold (folder names)."""
DATASET_MODALITIES = ("rgb", "mask", "depth", "normal")
DEGRADE_PRESETS = ("none", "paper", "physical")
EXPOSURE_MODES = ("fixed", "auto")
EARTH_TEXTURES = ("procedural", "uniform", "none")
QUALITIES = ("fast", "balanced", "reference")
PAPER_GROUP_NAMES = ("D1", "D2", "D3", "D4")
_WHITE_BALANCE_M = 530e-9
"""Photon energy used for every channel in the camera equation: a white-balanced sensor (a grey
surface gives equal R, G, B signals) [m]."""
_EXT = {"rgb": ".png", "rgb_degraded": ".png", "mask": ".png", "depth": ".exr", "normal": ".exr", "hdr": ".exr"}


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2; a flag must be spelled
    out (``--frame 3`` is an error, not ``--frames 3``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{PROG}: error: {message}\n")


# --------------------------------------------------------------------------- value parsers
def _int_in(lo: int, hi: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}], got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}], got {value}")
        return value
    parse.toml = "an integer"
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
    parse.toml = "a number"
    return parse


def _floats(n: int, lo: float, hi: float, *, unit: str = "", nonzero: bool = False):
    def parse(text: str) -> list:
        what = f"{n} comma-separated finite numbers in [{lo:g}, {hi:g}]{(' ' + unit) if unit else ''}"
        try:
            values = [float(v) for v in str(text).split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if len(values) != n or not all(math.isfinite(v) and lo <= v <= hi for v in values):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        if nonzero and not any(values):
            raise argparse.ArgumentTypeError(f"must be a non-zero vector, got {text!r}")
        return values
    parse.toml = f"an array of {n} numbers"
    return parse


def _choice(allowed):
    def parse(text: str) -> str:
        if text not in allowed:
            raise argparse.ArgumentTypeError(f"must be one of {', '.join(allowed)}; got {text!r}")
        return text
    parse.choices = tuple(allowed)
    return parse


def _subset(allowed, *, keep_order: bool = False):
    """A comma-separated list of names from ``allowed``, without repeats: in the canonical order
    of ``allowed``, or with ``keep_order`` in the order given."""
    def parse(text: str) -> list:
        items = [s.strip() for s in str(text).split(",") if s.strip()]
        bad = [s for s in items if s not in allowed]
        if not items or bad:
            raise argparse.ArgumentTypeError(f"must be a comma-separated list of {', '.join(allowed)}; "
                                             f"got {text!r}")
        return list(dict.fromkeys(items)) if keep_order else [a for a in allowed if a in items]
    parse.choices = tuple(allowed)
    return parse


def _choices_metavar(parse, many: bool = False) -> str | None:
    """``{a,b,c}`` (one of) or ``{a,b,c}[,..]`` (a list) for a parser of names."""
    choices = getattr(parse, "choices", None)
    if choices is None:
        return None
    return "{" + ",".join(choices) + "}" + ("[,...]" if many else "")


def _bool(text: str) -> bool:
    if str(text).lower() in ("true", "1", "yes"):
        return True
    if str(text).lower() in ("false", "0", "no"):
        return False
    raise argparse.ArgumentTypeError(f"must be true or false, got {text!r}")


_bool.toml = "true or false"


def _path(text: str) -> str:
    if not str(text):
        raise argparse.ArgumentTypeError("must be a file path, got ''")
    return str(text)


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _out_path(text: str) -> str:
    """A path to write to: not blank (``--out " "`` made a folder named by a space) and free of
    control characters (a pasted newline or tab)."""
    text = str(text)
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a folder or file, got {text!r}")
    if _CONTROL.search(text):
        raise argparse.ArgumentTypeError(f"must be a path without control characters (newline, tab, ...), got {text!r}")
    return text


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


def _shard(text: str) -> tuple:
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be K/N with integers 1 <= K <= N, got {text!r}") from None
    if not 1 <= k <= n:
        raise argparse.ArgumentTypeError(f"must be K/N with integers 1 <= K <= N, got {text!r}")
    return k, n


# --------------------------------------------------------------------------- the options
@dataclass(frozen=True, slots=True)
class _Opt:
    """One scenario option: a flag, a key of a TOML table, a parser and a default."""

    flag: str
    section: str
    parse: object
    default: object
    help: str
    metavar: str | None = None
    switch: bool = False  # a store_true flag

    @property
    def key(self) -> str:
        return self.flag[2:].replace("-", "_")


def _options() -> tuple:
    O = _Opt
    deg = "deg"
    return (
        # [sequence]
        O("--target", "sequence", _choice(TARGETS), "cassini", "built-in target"),
        O("--mesh", "sequence", _path, None, "render this mesh file (glb/gltf/obj/ply/stl/off) instead of --target; "
          "body frame = the file's frame (raytrace.meshio.load_mesh)", "FILE"),
        O("--mesh-unit-m", "sequence", _float_in(0.0, 1e3, lo_open=True, unit="m"), 1.0,
          "metres per mesh-file unit (0.001 for millimetres)"),
        O("--pattern", "sequence", _choice(PATTERNS), "spiral", "relative-motion pattern"),
        O("--frames", "sequence", _int_in(1, 1_000_000), DEFAULT_FRAMES,
          "number of frames, evenly spaced over the window"),
        O("--seed", "sequence", _int_in(0, 2**63 - 1), 0,
          "seed of the pattern draw and of every frame's noise; same seed, same bytes"),
        O("--window-s", "sequence", _float_in(0.0, 1e7, lo_open=True, unit="s"), None,
          "window length [s] (default: one period for elliptical, half for spiral and drip-drop, "
          "80 m of drift for drift, scaled with the target)"),
        # [pattern]
        O("--amplitude-m", "pattern", _float_in(0.0, 1e6, lo_open=True, unit="m"), None,
          "radial semi-amplitude A [m]; with --kappa sets the pattern instead of drawing it from --seed"),
        O("--kappa", "pattern", _float_in(-1e3, 1e3), None, "kappa = x_l / A (0 elliptical, "
          "|kappa| < 0.2896 spiral, < 1 drip-drop, >= 1 drift)"),
        O("--gamma-m", "pattern", _float_in(-1e7, 1e7, unit="m"), None,
          "along-track position at the characteristic point [m] (default: centre the window on the target)"),
        O("--z-amp-m", "pattern", _float_in(0.0, 1e6, unit="m"), None, "out-of-plane amplitude [m] (default 0)"),
        O("--z-phase-deg", "pattern", _float_in(-360.0, 360.0, unit=deg), None,
          "out-of-plane phase at t = 0 [deg] (default 0)"),
        O("--tau0-deg", "pattern", _float_in(-360.0, 360.0, unit=deg), None,
          "in-plane phase after the characteristic point at t = 0 [deg] (default 0)"),
        # [orbit]
        O("--altitude-km", "orbit", _float_in(100.0, 1e6, unit="km"), 400.0, "altitude above the equatorial radius [km]"),
        O("--inclination-deg", "orbit", _float_in(0.0, 180.0, unit=deg), 51.6, "inclination [deg]"),
        O("--raan-deg", "orbit", _float_in(-360.0, 360.0, unit=deg), None,
          "right ascension of the ascending node [deg] (default: 0, or where no --arg-lat-deg alone keeps every "
          "frame lit and in view, the orbit plane that does best)"),
        O("--arg-lat-deg", "orbit", _float_in(-360.0, 360.0, unit=deg), None,
          "argument of latitude of the target at the epoch [deg] (default: the phase that keeps the target fully "
          "sunlit and in view in the most frames; give one to set it: 180 flies the default spiral through "
          "Earth's shadow)"),
        O("--epoch", "orbit", _utc, DEFAULT_EPOCH_UTC, "UTC epoch of frame 0, ISO 8601"),
        O("--sun-margin-deg", "orbit", _float_in(0.0, 90.0, unit=deg), 20.0,
          "stray-light margin added to the Sun's radius for the Sun-in-lens test [deg]"),
        # [attitude]
        O("--attitude", "attitude", _choice(ATTITUDE_MODES), "lvlh-fixed", "target attitude law (orbit.attitude)"),
        O("--attitude-ypr-deg", "attitude", _floats(3, -360.0, 360.0, unit=deg), [0.0, 0.0, 0.0],
          "initial attitude w.r.t. LVLH as z-y-x Euler angles yaw,pitch,roll [deg]", "Y,P,R"),
        O("--spin-axis", "attitude", _floats(3, -1e6, 1e6, nonzero=True), [0.0, 0.0, 1.0],
          "spin axis in body axes (spin mode)", "X,Y,Z"),
        O("--spin-rate-deg-s", "attitude", _float_in(-3600.0, 3600.0, unit="deg/s"), 0.0, "spin rate [deg/s]"),
        O("--omega0-deg-s", "attitude", _floats(3, -3600.0, 3600.0, unit="deg/s"), [0.0, 0.0, 0.0],
          "initial body rate for tumble [deg/s]", "X,Y,Z"),
        O("--inertia-kg-m2", "attitude", _floats(3, 1e-9, 1e12, unit="kg m2"), [1.0, 1.0, 1.0],
          "principal moments of inertia Jxx,Jyy,Jzz along the body axes for tumble [kg m^2]", "JX,JY,JZ"),
        # [camera]
        O("--width", "camera", _int_in(1, 65535), 1280, "image width [px]"),
        O("--height", "camera", _int_in(1, 65535), 960, "image height [px]"),
        O("--focal-length-mm", "camera", _float_in(1e-3, 1e4, unit="mm"), 4.0, "focal length [mm]"),
        O("--pixel-pitch-um", "camera", _float_in(0.1, 1e3, unit="um"), 3.45, "pixel pitch [um]"),
        O("--roll-deg", "camera", _float_in(-360.0, 360.0, unit="deg"), 0.0,
          "camera roll about its boresight, applied after the look-at pointing [deg]"),
        # [render]
        O("--quality", "render", _choice(QUALITIES), "fast", "shading preset (raytrace.shade)"),
        O("--samples", "render", _int_in(1, 1 << 20), None, "overrides the preset's sample count"),
        O("--exposure", "render", _choice(EXPOSURE_MODES), "fixed",
          "clean RGB exposure: fixed (a white Lambertian surface facing the Sun = 1.0) or auto (per frame)"),
        O("--earth-texture", "render", _choice(EARTH_TEXTURES), "procedural", "Earth as light and backdrop"),
        O("--earth-albedo", "render", _float_in(0.0, 1.0), 0.3, "Earth's mean albedo"),
        O("--ambient-W-m2-sr", "render", _float_in(0.0, 1e4, unit="W/(m2 sr)"), 0.0, "constant sky radiance"),
        O("--star-limit-mag", "render", _float_in(-1.5, 9.0, unit="mag"), None,
          "draw the stars brighter than this visual magnitude in the background (procedural sky from --seed, or "
          "--star-catalogue) (default: no stars)", "MAG"),
        O("--star-catalogue", "render", _path, None,
          "draw the stars of this CSV catalogue (columns ra_deg, dec_deg, v_mag; J2000) instead of a procedural "
          "sky", "FILE.csv"),
        # [degrade]
        O("--degrade", "degrade", _choice(DEGRADE_PRESETS), "physical",
          "degradation of rgb_degraded: none, paper (the source paper's groups D1-D4) or physical (optics + sensor "
          "chain)"),
        O("--paper-group", "degrade", _choice(PAPER_GROUP_NAMES), "D4", "paper preset: D1 blur ... D4 blur+Poisson+Gaussian"),
        O("--paper-blur-px", "degrade", _float_in(0.0, 1000.0, unit="px"), 15.0,
          "paper preset: motion-blur length L [px] (the paper's value: 15)"),
        O("--paper-angle-deg", "degrade", _float_in(-360.0, 360.0, unit="deg"), 30.0,
          "paper preset: motion-blur angle θ [deg] (the paper's value: 30)"),
        O("--paper-gaussian-var", "degrade", _float_in(0.0, 1.0), 0.01,
          "paper preset: variance of the Gaussian noise on [0, 1] values (the paper's value: 0.01)"),
        O("--f-number", "degrade", _float_in(0.5, 64.0), 4.0, "physical preset: f-number N (aperture = f / N)"),
        O("--exposure-us", "degrade", _float_in(0.0, 1e7, lo_open=True, unit="us"), 20.0,
          "physical preset: exposure time [us]"),
        O("--quantum-efficiency", "degrade", _float_in(0.0, 1.0, lo_open=True), 0.6, "physical preset: QE"),
        O("--full-well-e", "degrade", _float_in(1.0, 1e9, unit="e-"), 10000.0, "physical preset: full well"),
        O("--read-noise-e", "degrade", _float_in(0.0, 1e6, unit="e-"), 5.0, "physical preset: read noise sigma"),
        O("--bit-depth", "degrade", _int_in(1, 16), 12, "physical preset: ADC bits"),
        O("--aberration-sigma-px", "degrade", _float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: Gaussian aberration sigma [px]"),
        O("--motion-blur-px", "degrade", _float_in(0.0, 1000.0, unit="px"), 0.0,
          "physical preset: motion-blur length [px] (constant over the sequence)"),
        O("--motion-angle-deg", "degrade", _float_in(-360.0, 360.0, unit=deg), 0.0,
          "physical preset: motion-blur direction, counter-clockwise from +column [deg]"),
        O("--defocus-radius-px", "degrade", _float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: defocus blur-circle radius [px] (pillbox)"),
        O("--corner-sigma-px", "degrade", _float_in(0.0, 100.0, unit="px"), 0.0,
          "physical preset: Gaussian aberration sigma reached in the image corners [px] (0: uniform)"),
        O("--offset-dn", "degrade", _float_in(0.0, 65535.0, unit="DN"), 0.0, "physical preset: ADC black level"),
        O("--dark-current-e-s", "degrade", _float_in(0.0, 1e9, unit="e-/s"), 0.0,
          "physical preset: dark current [e-/s]"),
        O("--demosaic", "degrade", _choice(("MHC", "linear")), "MHC",
          "physical preset: OpenImageIO demosaic algorithm of the RGGB mosaic"),
        O("--motion-blur", "degrade", _choice(("fixed", "auto")), "fixed",
          "physical preset: 'fixed' blurs every frame by --motion-blur-px at --motion-angle-deg; 'auto' takes "
          "each frame's blur from the target's own image motion during the exposure"),
        # [output]
        O("--modalities", "output", _subset(MODALITIES), None,
          "files per frame, comma-separated (default: all but hdr; no rgb_degraded with --degrade none)",
          "LIST"),
        O("--only-visible", "output", _bool, False,
          "drop frames whose flags say the target cannot be seen (default: render them, flags in labels)",
          switch=True),
    )


OPTIONS = _options()
SECTIONS = tuple(dict.fromkeys(o.section for o in OPTIONS))
_BY_KEY = {(o.section, o.key): o for o in OPTIONS}


def _add_options(p: argparse.ArgumentParser, defaults: dict, skip=()) -> None:
    groups = {}
    for o in OPTIONS:
        if o.key in skip:
            continue
        g = groups.get(o.section) or groups.setdefault(o.section, p.add_argument_group(f"[{o.section}]"))
        d = defaults.get(o.key, o.default)
        # the default once: from the help text where it says what an unset option does, else shown here
        shown = "" if o.switch or d is None or "(default" in o.help else f" (default: {_show(d)})"
        if o.switch:
            g.add_argument(o.flag, dest=o.key, action="store_true", default=None, help=o.help)
        else:
            metavar = o.metavar if o.metavar and getattr(o.parse, "choices", None) is None else (
                _choices_metavar(o.parse, many=o.metavar == "LIST") or o.metavar)
            g.add_argument(o.flag, dest=o.key, type=o.parse, default=None, metavar=metavar, help=o.help + shown)


def _show(value) -> str:
    if value is None:
        return "automatic"
    if isinstance(value, (list, tuple)):
        return ",".join(_show(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def _add_exec(p: argparse.ArgumentParser, *, out_help: str) -> None:
    g = p.add_argument_group("execution (not part of the scenario)")
    g.add_argument("--config", type=_path, default=None, metavar="FILE.toml",
                   help="options as TOML tables (as in a sequence's config.toml); flags override")
    g.add_argument("--out", type=_out_path, default=None, metavar="DIR", help=out_help)
    g.add_argument("--workers", type=_int_in(1, 4096), default=None,
                   help="worker processes (default: all cores of this machine)")
    g.add_argument("--shard", type=_shard, default=None, metavar="K/N",
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
    _add_options(p, {})
    p.add_argument("--dry-run", action="store_true", help="print the per-frame states and flags; render nothing")
    p.add_argument("--json", action="store_true", help="print the states and flags as one JSON document; render nothing")
    _add_exec(p, out_help="sequence folder (default: output/TARGET_PATTERN)")
    return p


# --------------------------------------------------------------------------- configuration
def _toml_text(value) -> str:
    """A TOML value as the text a flag would take (so one parser validates both)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return ",".join(_toml_text(v) for v in value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (int, str)):
        return str(value)
    if type(value).__name__ in ("datetime", "date", "time"):  # tomllib's bare date-times
        raise argparse.ArgumentTypeError("must be a quoted string (e.g. \"2026-03-20T12:00:00Z\"), got a bare TOML "
                                         f"{type(value).__name__}")
    raise argparse.ArgumentTypeError(f"has an unsupported TOML type {type(value).__name__}")


def _toml_type_ok(kind: str | None, value) -> bool:
    """Whether a TOML value has the type its option takes (a flag's text is parsed, but a file's
    ``frames = "2"`` or ``only_visible = "yes"`` is a type error in TOML terms)."""
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if type(value).__name__ in ("datetime", "date", "time"):
        return True  # _toml_text says how to write it
    if kind is None:  # names, lists of names, paths, times: a string (or a list of strings)
        return isinstance(value, str) or (isinstance(value, list) and all(isinstance(v, str) for v in value))
    if kind == "an integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "a number":
        return number(value)
    if kind == "true or false":
        return isinstance(value, bool)
    return isinstance(value, list) and all(number(v) for v in value)  # an array of n numbers


CONFIG_LIMIT_BYTES = 1 << 20
"""Largest ``--config`` file read [bytes]: a configuration is a few kB; anything else (a device,
a pipe, a wrong file) is refused instead of read without end."""


def read_config(path: str) -> dict:
    """Read a TOML configuration; returns {section: {key: value}} validated like the flags.

    Raises
    ------
    CLIError
        Unreadable or invalid TOML, an unknown table or key, or a value a flag would reject.
    """
    import tomllib

    from raytrace.files import read_regular_file
    try:
        raw = read_regular_file(path, limit_bytes=CONFIG_LIMIT_BYTES, what=f"--config {path}")
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CLIError(f"--config: {path} is not valid TOML ({exc})") from None
    out = {}
    for section, table in data.items():
        if section not in SECTIONS:
            raise CLIError(f"--config: {path}: unknown table [{section}]; allowed tables are "
                           f"{', '.join(f'[{s}]' for s in SECTIONS)}")
        if not isinstance(table, dict):
            raise CLIError(f"--config: {path}: {section} must be a table ([{section}] and its keys below), "
                           f"got a {type(table).__name__}")
        for key, value in table.items():
            opt = _BY_KEY.get((section, key))
            if opt is None:
                keys = ", ".join(o.key for o in OPTIONS if o.section == section)
                raise CLIError(f"--config: {path}: unknown key {key!r} in [{section}]; allowed: {keys}")
            if not _toml_type_ok(getattr(opt.parse, "toml", None), value):
                kind = getattr(opt.parse, "toml", "a string (or an array of strings)")
                raise CLIError(f"--config: {path}: [{section}] {key} must be {kind}, got {value!r}")
            try:
                out.setdefault(section, {})[key] = opt.parse(_toml_text(value))
            except argparse.ArgumentTypeError as exc:
                raise CLIError(f"--config: {path}: [{section}] {key} {exc}") from None
    return out


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
                                             if k not in ("target", "mesh", "mesh_unit_m")}}
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
        mods = defaults.get("modalities") or [m for m in MODALITIES if m != "hdr"]
        out["modalities"] = [m for m in mods if not (m == "rgb_degraded" and d["degrade"] == "none")]
    elif "rgb_degraded" in out["modalities"] and d["degrade"] == "none":
        raise CLIError("argument --modalities: rgb_degraded needs --degrade paper or physical, got --degrade none")
    if d["degrade"] == "physical":
        full_scale = 2 ** d["bit_depth"] - 1
        if d["offset_dn"] > full_scale / 2:
            raise CLIError(f"argument --offset-dn: must be at most half the ADC's full scale, {full_scale / 2:g} DN at "
                           f"--bit-depth {d['bit_depth']} (a black level above it leaves the signal no room), got "
                           f"{d['offset_dn']:g}")
    if cfg["sequence"]["mesh"] is not None:
        cfg["sequence"]["mesh"] = os.path.abspath(cfg["sequence"]["mesh"])
    return cfg, given


def config_toml(cfg: dict) -> str:
    """The resolved configuration as TOML (automatic values are comments)."""
    lines = ["# orbitsynth: resolved options of this sequence. `python cli.py --config config.toml --out DIR`",
             "# renders the same bytes (execution options such as --workers are not recorded).", ""]
    for section in SECTIONS:
        lines.append(f"[{section}]")
        for key, value in cfg[section].items():
            if value is None:
                lines.append(f"# {key} = automatic")
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


# --------------------------------------------------------------------------- planning (orbit → pose → light)
def _load_model(spec: tuple, warn: bool = False):
    """The target model of a model spec: ("builtin", name) or ("mesh", path, unit_scale_m);
    ``warn``: one line on stderr when the mesh file needed more than routine repair."""
    if spec[0] == "builtin":
        from raytrace.targets import load_target
        return load_target(spec[1])
    from raytrace.meshio import load_mesh
    model, report = load_mesh(spec[1], unit_scale_m=spec[2])
    if warn and report.non_finite_note():
        sys.stderr.write(f"{PROG}: warning: --mesh {report.non_finite_note()}\n")
    return model


_ATTITUDE_FLAGS = {"spin_axis_body": "--spin-axis", "omega0_body_rad_s": "--omega0-deg-s",
                   "inertia_body_kg_m2": "--inertia-kg-m2", "R0_lvlh_from_body": "--attitude-ypr-deg",
                   "spin_rate_rad_s": "--spin-rate-deg-s", "yaw_deg": "--attitude-ypr-deg",
                   "pitch_deg": "--attitude-ypr-deg", "roll_deg": "--attitude-ypr-deg"}


def _attitude_error(message: str) -> str:
    """An error of :class:`orbit.attitude.TargetAttitude` in the words of the command line: the
    field it names becomes the flag that set it."""
    for field, flag in _ATTITUDE_FLAGS.items():
        if message.startswith(field):
            return f"argument {flag}: {message[len(field):].strip()}"
    return f"argument --attitude: {message}"


MESH_RADIUS_PLAUSIBLE_M = (0.02, 200.0)
"""Bounding radii of real spacecraft [m]: from a 1U CubeSat's 0.087 m to the ISS's ~55 m, with room
on both sides. A user mesh outside the range was probably read in the wrong unit."""


def _mesh_unit_warning(radius_m: float, path: str) -> str | None:
    """A one-line warning when a mesh loaded with the default ``--mesh-unit-m 1`` has a size
    (``radius_m``: half its bounding-box diagonal) no spacecraft has (a 1 m cube drawn in
    millimetres reads as 866 m), naming the flag."""
    lo, hi = MESH_RADIUS_PLAUSIBLE_M
    if radius_m > hi:
        guess = "millimetres: --mesh-unit-m 0.001" if radius_m > 1000 * lo else "centimetres: --mesh-unit-m 0.01"
        return (f"--mesh {path}: it is {2 * radius_m:.4g} m across (a radius of {radius_m:.4g} m), larger than any "
                f"spacecraft, read as metres (--mesh-unit-m 1); if the file is in {guess}")
    if radius_m < lo:
        return (f"--mesh {path}: it is {2 * radius_m:.3g} m across, smaller than any spacecraft, read as metres "
                "(--mesh-unit-m 1); if the file is in kilometres: --mesh-unit-m 1000")
    return None


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _explicit_pattern(cfg: dict, given: set, n: float, band, radius_m: float):
    """Initial state from --amplitude-m/--kappa (and optional γ, B, phases) instead of a draw."""
    from dataclasses import replace

    from orbit import cw
    from orbit.patterns import parameters, state_from_kappa
    from orbit.sampling import default_window_s
    p, seq = cfg["pattern"], cfg["sequence"]
    if p["amplitude_m"] is None or p["kappa"] is None:
        missing = "--amplitude-m" if p["amplitude_m"] is None else "--kappa"
        raise CLIError(f"argument {missing}: explicit pattern parameters need both --amplitude-m and --kappa")
    A, kappa = p["amplitude_m"], p["kappa"]
    z_amp = p["z_amp_m"] or 0.0
    z_phase = math.radians(p["z_phase_deg"] or 0.0)
    tau0 = math.radians(p["tau0_deg"] or 0.0)
    x_l = kappa * A
    beta = 1.5 * n * x_l
    window = seq["window_s"] or default_window_s(_class_of(kappa), n, x_l_m=x_l, scale=band.scale)
    gamma = p["gamma_m"] if p["gamma_m"] is not None else beta * (window / 2.0 + tau0 / n)
    s0 = state_from_kappa(A, kappa, gamma, n, z_amp=z_amp, z_phase=z_phase, tau0=tau0)
    params = parameters(s0, n)
    # the class is that of the kappa given (|kappa| = kappa* is drip-drop, 1 drift: docs/orbit.md, "Patterns and
    # their thresholds"); kappa recomputed from the state can fall an ulp on the other side of a boundary
    # (kappa* gave "spiral")
    pattern = _class_of(kappa)
    if params.pattern != pattern and params.pattern in PATTERNS:
        params = replace(params, pattern=pattern)
    if "pattern" in given and pattern != seq["pattern"]:
        raise CLIError(f"argument --kappa: amplitude {A:g} m and kappa {kappa:g} make the pattern {pattern}, "
                       f"not {seq['pattern']} (spiral: 0 < |kappa| < 0.2896, drip-drop: < 1, drift: >= 1)")
    frames = seq["frames"]
    t_s = np.linspace(0.0, window, frames) if frames > 1 else np.zeros(1)
    r = np.linalg.norm(cw.propagate(s0, n, np.concatenate([t_s, np.linspace(0, window, 1024)]))[:, :3], axis=1)
    if r.min() <= radius_m:
        raise CLIError(f"argument --amplitude-m: with these pattern parameters the camera comes within {r.min():.3g} m "
                       f"of the target centre, inside its bounding radius {radius_m:.3g} m; use a larger amplitude, "
                       "|kappa| or --gamma-m")
    draws = {"A_m": A, "kappa": kappa, "x_l_m": x_l, "beta_m_s": beta, "gamma_m": gamma, "tau0_rad": tau0,
             "z_amp_m": z_amp, "z_phase_rad": z_phase}
    return s0, t_s, window, params, draws, 0, (float(r.min()), float(r.max()))


def _class_of(kappa: float) -> str:
    from orbit.patterns import classify
    c = classify(1.0, kappa)
    return c if c in PATTERNS else "elliptical"


def plan_sequence(cfg: dict, given: set = frozenset()) -> dict:
    """Sample (or set), propagate and evaluate one sequence: everything but the pixels.

    Returns a dict: ``result`` (plain-Python scenario and per-frame labels without image
    quantities, the ``--json`` document), ``model``, ``model_spec``, ``camera`` and per-frame
    ``lights`` (Sun, Earth and ν in the body frame)."""
    from orbit import cw, pose, visibility
    from orbit.attitude import TargetAttitude
    from orbit.epoch import gmst_rad, to_iso_utc
    from orbit.reference import ReferenceOrbit
    from orbit.rotations import rot_z
    from orbit.sampling import range_band, sample_pattern
    from orbit.sun import sun_position_eci
    from raytrace.camera import Camera

    seq, orb, att, cam = cfg["sequence"], cfg["orbit"], cfg["attitude"], cfg["camera"]
    if seq["mesh"] is not None:
        spec = ("mesh", seq["mesh"], seq["mesh_unit_m"])
        try:
            model = _load_model(spec, warn=True)
        except ValueError as exc:
            raise CLIError(f"argument --mesh: {exc}") from None
        target = model.name
    else:
        spec = ("builtin", seq["target"])
        model = _load_model(spec)
        target = seq["target"]
    try:
        _scene_of(model, warn=True)  # validates the mesh (e.g. zero-area triangles) before anything is written
    except ValueError as exc:
        raise CLIError(f"argument --mesh: {exc}") from None
    _star_field(cfg)  # validates the star catalogue before anything is written
    radius_m = model.bounding_radius_m
    if seq["mesh"] is not None and "mesh_unit_m" not in given:
        lo, hi = model.bounds_m  # the mesh's own size, wherever its origin lies
        note = _mesh_unit_warning(0.5 * float(np.linalg.norm(hi - lo)), seq["mesh"])
        if note:
            sys.stderr.write(f"{PROG}: warning: {note}\n")
    camera = Camera.from_focal(cam["focal_length_mm"] * 1e-3, cam["pixel_pitch_um"] * 1e-6, cam["width"], cam["height"])
    n = ReferenceOrbit(altitude_m=orb["altitude_km"] * 1e3).n_rad_s
    band = range_band(radius_m)
    explicit = cfg["pattern"]["amplitude_m"] is not None or cfg["pattern"]["kappa"] is not None
    if explicit:
        s0, t_s, window_s, params, draws, attempts, range_m = _explicit_pattern(cfg, given, n, band, radius_m)
        pattern = params.pattern
    else:
        sample = sample_pattern(seq["pattern"], n, target_radius_m=radius_m, n_frames=seq["frames"],
                                rng=seq["seed"], window_s=seq["window_s"])
        s0, t_s, window_s, params = sample.s0_lvlh, np.asarray(sample.t_s), sample.window_s, sample.params
        draws, attempts, range_m, pattern = dict(sample.draws), sample.attempts, sample.range_m, seq["pattern"]
    from orbit.epoch import to_unix_seconds
    from orbit.sun import VALID_UTC_RANGE_S
    if len(t_s) and to_unix_seconds(orb["epoch"]) + float(np.max(t_s)) > VALID_UTC_RANGE_S[1]:
        raise CLIError(f"argument --epoch: the sequence ends {float(np.max(t_s)):.0f} s after {orb['epoch']}, past "
                       "2051-01-01T00:00:00Z (the validity of the solar formulae); choose an earlier --epoch")
    s_lvlh = cw.propagate(s0, n, t_s)
    ref, chosen = _reference_orbit(orb, s_lvlh, t_s)
    r_obs_eci, _ = ref.observer_state_eci(s_lvlh, t_s)
    r_tgt_eci, _ = ref.target_state_eci(t_s)
    unix_s = ref.unix_s(t_s)
    r_sun_eci = sun_position_eci(unix_s)
    vis = visibility.visibility(r_obs_eci, r_tgt_eci, r_sun_eci, sun_margin_rad=math.radians(orb["sun_margin_deg"]))

    try:
        attitude = TargetAttitude.from_euler_zyx_deg(
            att["attitude"], *att["attitude_ypr_deg"], spin_axis_body=att["spin_axis"],
            spin_rate_rad_s=math.radians(att["spin_rate_deg_s"]), omega0_body_rad_s=np.radians(att["omega0_deg_s"]),
            inertia_body_kg_m2=np.diag(att["inertia_kg_m2"]))
    except ValueError as exc:
        raise CLIError(_attitude_error(str(exc))) from None
    R_lvlh_from_body = attitude.R_lvlh_from_body(t_s, n)
    R_cam_from_lvlh = pose.look_at(s_lvlh[:, :3], roll_rad=math.radians(cam["roll_deg"]))
    R_cam_from_body, t_cam_m = pose.pose_from_relative(s_lvlh[:, :3], R_lvlh_from_body, R_cam_from_lvlh)
    labels = pose.pose_labels(R_cam_from_body, t_cam_m)
    R_lvlh_from_eci = np.swapaxes(ref.R_eci_from_lvlh(t_s), -1, -2)
    R_cam_from_eci = R_cam_from_lvlh @ R_lvlh_from_eci
    # directions seen from the camera (labels) ...
    sun_dir_cam = _unit_rows((R_cam_from_eci @ (r_sun_eci - r_obs_eci)[:, :, None])[:, :, 0])
    earth_dir_cam = _unit_rows((R_cam_from_eci @ -r_obs_eci[:, :, None])[:, :, 0])
    # ... and from the target, in its body frame (the renderer's light)
    R_body_from_eci = np.swapaxes(R_lvlh_from_body, -1, -2) @ R_lvlh_from_eci
    sun_dir_body = _unit_rows((R_body_from_eci @ (r_sun_eci - r_tgt_eci)[:, :, None])[:, :, 0])
    earth_dir_body = _unit_rows((R_body_from_eci @ -r_tgt_eci[:, :, None])[:, :, 0])
    earth_distance_m = np.linalg.norm(r_tgt_eci, axis=1)
    R_body_from_earth = R_body_from_eci @ rot_z(gmst_rad(unix_s))  # Earth-fixed axes (texture)

    motion = None
    if cfg["degrade"].get("motion_blur") == "auto":
        motion = _image_motion(model, camera, cfg["degrade"]["exposure_us"] * 1e-6, s0, n, t_s, attitude,
                               math.radians(cam["roll_deg"]))
    frames, lights = [], []
    visible = vis.visible  # a property that builds the whole array: once, not per frame (a million frames)
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
            "R_cam_from_eci": [float(v) for v in R_cam_from_eci[i].ravel()],
            "sun_dir_cam": [float(v) for v in sun_dir_cam[i]],
            "earth_dir_cam": [float(v) for v in earth_dir_cam[i]],
            "sun_dir_body": [float(v) for v in sun_dir_body[i]],
            "earth_dir_body": [float(v) for v in earth_dir_body[i]],
            "line_of_sight": bool(vis.line_of_sight[i]),
            "earth_in_background": bool(vis.earth_in_background[i]),
            "sun_angle_deg": float(np.degrees(vis.sun_angle_rad[i])),
            "sun_clear": bool(vis.sun_clear[i]),
            "shadow": ("sunlit", "penumbra", "umbra")[int(vis.shadow[i])],
            "shadow_fraction": float(vis.illuminated_fraction[i]),
            "visible": bool(visible[i]),
            "not_visible_because": [why for why, bad in (
                ("earth_blocks_line_of_sight", not vis.line_of_sight[i]), ("sun_in_lens", not vis.sun_clear[i]),
                ("earth_shadow", not vis.illuminated_fraction[i] > 0.0)) if bad],
        })
        lights.append({"sun_dir_body": sun_dir_body[i].tolist(), "shadow_fraction": float(vis.illuminated_fraction[i]),
                       "earth_dir_body": earth_dir_body[i].tolist(), "earth_distance_m": float(earth_distance_m[i]),
                       "R_body_from_earth": R_body_from_earth[i].tolist(),
                       "R_body_from_eci": R_body_from_eci[i].tolist()})
        if motion is not None:
            lights[-1]["motion"] = [float(motion["length_px"][i]), float(motion["angle_deg"][i])]
            frames[-1]["motion_blur_px"], frames[-1]["motion_angle_deg"] = lights[-1]["motion"]
            frames[-1]["motion_path_px"] = float(motion["path_px"][i])
            frames[-1]["motion_blur_bounded"] = bool(motion["bounded"][i])
    result = {
        "target": target,
        "target_bounding_radius_m": radius_m,
        "pattern": pattern,
        "seed": seq["seed"],
        "reference_orbit": {"altitude_m": ref.altitude_m, "inclination_rad": ref.inclination_rad,
                            "raan_rad": ref.raan_rad, "arg_lat_rad": ref.arg_lat_rad, "epoch_utc": ref.epoch_utc,
                            "a_m": ref.a_m, "period_s": ref.period_s, "chosen": chosen},
        "n": n,
        "s0_lvlh": [float(v) for v in s0],
        "window_s": float(window_s),
        "range_band_m": [band.r_min_m, band.r_max_m],
        "range_m": [float(v) for v in range_m],
        "pattern_parameters": params.to_dict(),
        "pattern_source": "explicit" if explicit else "sampled",
        "sampled": draws,
        "attempts": attempts,
        "t_s": [float(v) for v in t_s],
        "frames": frames,
    }
    return {"result": result, "model": model, "model_spec": spec, "camera": camera, "lights": lights,
            "cfg": cfg, "name": f"{target}_{pattern}"}


MOTION_SAMPLES = (16, 4096)
"""Instants per exposure at which ``--motion-blur auto`` samples the image path: doubled from the
first until the blur changes by less than :data:`MOTION_TOL_PX` or :data:`MOTION_TOL_REL` of it,
at most the second."""
MOTION_TOL_PX = 1e-3
MOTION_TOL_REL = 1e-5


def _reference_orbit(orb: dict, s_lvlh: np.ndarray, t_s: np.ndarray) -> tuple:
    """(the sequence's :class:`orbit.reference.ReferenceOrbit`, the names of the options chosen
    for it): ``--raan-deg`` and ``--arg-lat-deg`` as given, or where unset the geometry of
    :func:`orbit.viewing.sunlit_geometry` (target fully sunlit and in view in the most frames)."""
    from orbit.reference import ReferenceOrbit
    from orbit.viewing import sunlit_geometry
    raan = None if orb["raan_deg"] is None else math.radians(orb["raan_deg"])
    u0 = None if orb["arg_lat_deg"] is None else math.radians(orb["arg_lat_deg"])
    chosen = []
    if u0 is None:
        g = sunlit_geometry(s_lvlh, t_s, altitude_m=orb["altitude_km"] * 1e3,
                            inclination_rad=math.radians(orb["inclination_deg"]), epoch_utc=orb["epoch"],
                            raan_rad=raan, sun_margin_rad=math.radians(orb["sun_margin_deg"]))
        chosen = ["arg_lat_deg"] + (["raan_deg"] if raan is None and g.plane_searched else [])
        raan, u0 = g.raan_rad, g.arg_lat_rad
    ref = ReferenceOrbit(altitude_m=orb["altitude_km"] * 1e3, inclination_rad=math.radians(orb["inclination_deg"]),
                         raan_rad=0.0 if raan is None else raan, arg_lat_rad=u0, epoch_utc=orb["epoch"])
    return ref, chosen


def _image_motion(model, camera, exposure_s: float, s0, n: float, t_s, attitude, roll_rad: float = 0.0) -> dict:
    """Per frame, the straight-line blur that the target's own image motion makes during an
    exposure of ``exposure_s`` centred on the frame time (``--motion-blur auto``).

    The target's convex-hull vertices are projected at instants spread over the exposure (same
    CW state, attitude law and look-at pointing as the frame; doubled until the blur settles,
    :data:`MOTION_SAMPLES`), so the path each vertex sweeps is followed however it turns; each
    is taken as moving uniformly along straight pieces between instants. A camera integrates
    the image along those paths. The blur applied is a straight segment along the principal
    axis v of the vertices' positions about their own means (the larger eigenvector of their
    mean covariance), as long as the paths' spread along v allows: L = min(√(12 λ), E), with λ
    the mean variance of the positions along v (a uniform segment of length L has L²/12) and E
    the RMS over the vertices of each path's extent along v (a point that slows at the ends of
    its swing would otherwise be given a blur longer than the swing). For a straight path at
    constant speed both are its length; a target that turns a whole revolution in the
    exposure blurs over its ring instead of (comparing the end poses alone) not at all. The
    largest L of any centred part of the exposure is taken, so the blur never shrinks as the
    exposure grows (a path that turns back on itself spreads less over a longer time). L is at
    most the image diagonal (``bounded``).

    Returns
    -------
    dict of ndarray, shape (N,)
        ``length_px`` and ``angle_deg`` (the blur applied; angle counter-clockwise from +column
        as :func:`degrade.psf.motion_from_velocity` reports it), ``path_px`` (RMS over the hull
        vertices of the image path length swept during the exposure), ``bounded`` (bool: L
        capped) and ``samples`` (instants used).
    """
    from scipy.spatial import ConvexHull

    from orbit import cw, pose
    pts = np.concatenate([np.asarray(c.mesh.vertices, dtype=np.float64) for c in model.components])
    try:
        hull = ConvexHull(pts).vertices
    except Exception:  # noqa: BLE001 - flat or tiny point sets: use every vertex
        hull = np.arange(len(pts))
    pts = pts[hull]
    t_s = np.asarray(t_s, dtype=np.float64)
    nf = t_s.size
    out = {"length_px": np.zeros(nf), "angle_deg": np.zeros(nf), "path_px": np.zeros(nf),
           "bounded": np.zeros(nf, dtype=bool), "samples": np.zeros(nf, dtype=np.int64)}
    if not exposure_s > 0 or nf == 0:
        return out
    diagonal = math.hypot(camera.width, camera.height)

    def blur(frames: np.ndarray, m: int) -> tuple:
        """(L, θ, path) of ``frames`` from m + 1 instants (m even) over the exposure."""
        tau = np.linspace(-0.5 * exposure_s, 0.5 * exposure_s, m + 1)
        tt = (t_s[frames, None] + tau[None, :]).ravel()
        s = cw.propagate(s0, n, tt)
        R, t = pose.pose_from_relative(s[:, :3], attitude.R_lvlh_from_body(tt, n),
                                       pose.look_at(s[:, :3], roll_rad=roll_rad))
        p = pts[None] @ np.swapaxes(R, -1, -2) + t[:, None, :]          # (F·(m+1), K, 3)
        z = np.where(p[..., 2] > 1e-9, p[..., 2], np.nan)
        uv = np.stack([camera.fx * p[..., 0] / z, camera.fy * p[..., 1] / z], -1)
        uv = uv.reshape(len(frames), m + 1, len(pts), 2)               # (F, instants, K, 2)
        seen = np.all(np.isfinite(uv), axis=(1, 3))                     # in front all along
        uv = np.where(seen[:, None, :, None], uv, 0.0)
        w = seen / np.maximum(seen.sum(axis=1, keepdims=True), 1)       # (F, K): mean over the seen vertices
        a, b = uv[:, :-1], uv[:, 1:]                                    # the m straight pieces
        path = np.sqrt(np.einsum("fk,fk->f", w, np.linalg.norm(b - a, axis=-1).sum(axis=1) ** 2))
        # the whole exposure's covariance (uniform motion on each piece) gives the axis v
        m1 = 0.5 * (a + b).mean(axis=1)                                 # (F, K, 2)
        m2 = ((a[..., :, None] * a[..., None, :] + b[..., :, None] * b[..., None, :]) / 3.0
              + (a[..., :, None] * b[..., None, :] + b[..., :, None] * a[..., None, :]) / 6.0).mean(axis=1)
        cov = np.einsum("fk,fkij->fij", w, m2 - m1[..., :, None] * m1[..., None, :])
        v = np.linalg.eigh(cov)[1][..., -1]                             # (F, 2)
        q = np.einsum("fikc,fc->fik", uv, v)                            # positions along v
        # centred parts j = 1 .. m/2 of the exposure: the pieces c-j .. c+j-1 about the centre c
        c = m // 2
        qa, qb = q[:, :-1], q[:, 1:]
        e1 = 0.5 * (qa + qb)
        e2 = (qa * qa + qb * qb + qa * qb) / 3.0
        j = np.arange(1, c + 1, dtype=np.float64)[None, :, None]
        s1 = (np.cumsum(e1[:, c - 1::-1] + e1[:, c:], axis=1)) / (2 * j)  # (F, m/2, K)
        s2 = (np.cumsum(e2[:, c - 1::-1] + e2[:, c:], axis=1)) / (2 * j)
        lam = np.einsum("fk,fjk->fj", w, np.maximum(s2 - s1 * s1, 0.0))
        hi = np.maximum(np.maximum.accumulate(q[:, c - 1::-1], axis=1), np.maximum.accumulate(q[:, c + 1:], axis=1))
        lo = np.minimum(np.minimum.accumulate(q[:, c - 1::-1], axis=1), np.minimum.accumulate(q[:, c + 1:], axis=1))
        ext = np.maximum(hi, q[:, c:c + 1]) - np.minimum(lo, q[:, c:c + 1])
        E = np.sqrt(np.einsum("fk,fjk->fj", w, ext * ext))
        L = np.minimum(np.sqrt(12.0 * lam), E).max(axis=1)
        theta = np.degrees(np.arctan2(-v[:, 1], v[:, 0]))             # rows grow downward
        theta = np.where(theta <= -90.0, theta + 180.0, np.where(theta > 90.0, theta - 180.0, theta))
        return L, theta, path

    chunk = max(1, int(4_000_000 // (len(pts) * (MOTION_SAMPLES[1] + 1))))
    for a0 in range(0, nf, chunk):
        frames = np.arange(a0, min(nf, a0 + chunk))
        m = MOTION_SAMPLES[0]
        L, theta, path = blur(frames, m)
        while m < MOTION_SAMPLES[1]:
            L2, theta2, path2 = blur(frames, 2 * m)
            m *= 2
            settled = np.all(np.abs(L2 - L) <= np.maximum(MOTION_TOL_PX, MOTION_TOL_REL * L2))
            L, theta, path = L2, theta2, path2
            if settled:
                break
        out["length_px"][frames] = np.minimum(L, diagonal)
        out["bounded"][frames] = L > diagonal
        out["angle_deg"][frames] = np.where(L > 0, theta, 0.0)
        out["path_px"][frames] = path
        out["samples"][frames] = m + 1
    return out


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


# --------------------------------------------------------------------------- one frame (runs in a worker)
_SCENES: dict = {}
_STARS: dict = {}
_SCENE_LOCK = None
# A pool's workers load the scenes (BVH aside) and radiance caches this process built once on
# every core (_prebuild_scenes) rather than each building its own; False: each builds its own.
_PREBUILD_SCENES = True


def _scene(spec: tuple, prebuilt: str | None = None):
    """The Scene of a model spec, built once per process (Embree BVH and radiance cache);
    ``prebuilt``: a file of :func:`_prebuild_scenes` holding it with its radiance cache."""
    global _SCENE_LOCK
    import threading
    if _SCENE_LOCK is None:
        _SCENE_LOCK = threading.Lock()
    with _SCENE_LOCK:
        scene = _SCENES.get(spec)
        if scene is None:
            scene = _load_prebuilt(prebuilt) if prebuilt else None
            if scene is None:
                scene = _scene_of(_load_model(spec), warn=False)
            scene.embree  # noqa: B018 - build now, under the lock
            _SCENES[spec] = scene
        return scene


def _load_prebuilt(path: str):
    """The Scene pickled by :func:`_prebuild_scenes` at ``path``, its radiance cache attached;
    None (and the worker builds its own) if the file cannot be read."""
    import pickle
    try:
        with open(path, "rb") as fh:
            scene, cache, options = pickle.load(fh)  # noqa: S301 - our own file, in our own private folder
        scene.adopt_radiance_cache(cache, **options)
        return scene
    except (OSError, pickle.UnpicklingError, EOFError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: warning: building the scene in the worker ({exc})\n")
        return None


def _prebuild_scenes(tasks: list, folder: str) -> dict:
    """Build each target's Scene and radiance cache once, here, on every core, and pickle them
    into ``folder`` for the pool's workers: {model spec: file}. Each worker would otherwise
    build its own on its share of the cores (Cassini: ~5 s on one core, 2–3.5 s on two; the
    same cache bit for bit, tests/raytrace/test_cache_solve.py). Only for tasks that shade (the
    ``fast`` and ``balanced`` presets with an image modality); nothing is built for the others."""
    import pickle
    out = {}
    for task in tasks:
        spec = task["model_spec"]
        if spec in out or task["cfg"]["render"]["quality"] == "reference":
            continue
        if not _shades(task):
            continue
        from raytrace.presets import preset_cache_options, quality_preset
        scene = _scene_of(_load_model(spec), warn=False)  # not kept here: only the workers render
        r = task["cfg"]["render"]
        # the cache the preset's frames ask for (balanced from 12 rays: a finer lattice)
        options = preset_cache_options(quality_preset(r["quality"], r.get("samples")), scene.scale_m)
        cache = scene.radiance_cache(**options)
        path = os.path.join(folder, f"scene{len(out)}.pickle")
        with open(path, "wb") as fh:
            pickle.dump((scene, cache, options), fh, protocol=pickle.HIGHEST_PROTOCOL)
        out[spec] = path
        del scene, cache
    return out


def _shades(task: dict) -> bool:
    """Whether a frame task needs the radiance (an image modality), not the geometry alone."""
    return bool(task.get("want_rgb")) or bool(set(task["modalities"]) & {"rgb", "rgb_degraded", "hdr"})


def _worker_ready(quality: str) -> None:
    """A first task for each worker, run while the parent builds the scenes: what a first
    ``quality`` frame would otherwise wait for — the imports (scipy.signal, ~0.6 s, for the
    optics' PSFs), numba's kernels loaded from its on-disk cache, the GGX split-sum table."""
    import scipy.signal  # noqa: F401
    import degrade.chain  # noqa: F401
    import raytrace.shade  # noqa: F401
    from raytrace import _precompile
    from raytrace.brdf import split_sum_table
    _precompile.load_here(_precompile_groups(quality))
    if quality != "reference":
        split_sum_table()


def _scene_of(model, warn: bool):
    """``raytrace.scene.Scene(model)``; its warnings about the model (a mesh far from its origin)
    as one line each on stderr when ``warn`` (planning, once), else dropped (the workers, which
    build the scene the plan already built)."""
    import warnings
    from raytrace.scene import Scene
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = Scene(model)
    for w in caught if warn else ():
        sys.stderr.write(f"{PROG}: warning: {' '.join(str(w.message).split())}\n")
    return scene


def _worker_init(threads: int) -> None:
    """Process-pool initializer: share the cores between the workers; stop on SIGINT or
    SIGTERM (:func:`_worker_stop`) and when the parent is gone (:func:`_abandon_frame`)."""
    import signal
    global _IN_POOL_WORKER
    _IN_POOL_WORKER = True
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _worker_stop)
    from raytrace._threads import exit_with_parent
    exit_with_parent(os.getppid(), _PARENT_POLL_S, _abandon_frame)
    try:
        import numba
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    except Exception as exc:  # noqa: BLE001 - a thread count is an optimisation, never an error
        sys.stderr.write(f"{PROG}: warning: could not set the worker's thread count ({exc})\n")


_IN_POOL_WORKER = False  # set in the pool's worker processes
_IN_FRAME = False  # run_frame is running (in a worker: what _abandon_frame waits for)
_WORKER_STOPPING = False
_PARENT_POLL_S = 0.5
_STOP_GRACE_S = 30.0  # a worker whose parent died exits by then even if its frame has not let go


def _worker_stop(signum, frame) -> None:
    """A pool worker's SIGINT or SIGTERM (Ctrl-C reaches the whole process group; the parent
    stops its pool on SIGTERM; a batch scheduler may signal every process): the frame in flight
    is abandoned where it stands, its temporary files removed on the way out
    (:func:`raytrace.files.atomic_write_image`), then :func:`run_frame` exits the worker. Once:
    a second signal must not interrupt that clean-up (it stays handled, as a no-op: a handler
    set to SIG_IGN while the signal is pending makes Python raise OSError)."""
    global _WORKER_STOPPING
    if _WORKER_STOPPING:
        return
    _WORKER_STOPPING = True
    raise KeyboardInterrupt


def _abandon_frame() -> None:
    """In a pool worker whose parent is gone (killed with SIGKILL, crashed; run by
    :func:`raytrace._threads.exit_with_parent` before the worker exits, instead of its waiting
    for its next task for ever with the target's scene in memory): stop as on SIGTERM and wait
    until the frame in flight has removed its temporaries."""
    import signal
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + _STOP_GRACE_S
    time.sleep(0.05)  # the main thread takes the signal at its next bytecode
    while _IN_FRAME and time.monotonic() < deadline:  # the abandoned frame removes its temporaries
        time.sleep(0.05)


def frame_seeds(seed: int, frame: int) -> tuple:
    """(render seed, degradation SeedSequence) of a frame: child ``frame`` of
    ``SeedSequence(seed).spawn(...)``; the render seed is its first word mod 2³¹, the
    degradation stream its first child."""
    child = np.random.SeedSequence(seed, spawn_key=(frame,))
    return int(child.generate_state(1)[0] % 2**31), np.random.SeedSequence(seed, spawn_key=(frame, 0))


def _star_field(cfg: dict):
    """The sequence's star field (None without stars), read or drawn once per process."""
    r = cfg["render"]
    key = (r.get("star_catalogue"), r.get("star_limit_mag"), cfg["sequence"]["seed"])
    if key[0] is None and key[1] is None:
        return None
    if key not in _STARS:
        from raytrace.stars import StarField
        if key[0] is not None:
            try:
                _STARS[key] = StarField.from_csv(key[0], math.inf if key[1] is None else key[1])
            except ValueError as exc:
                raise CLIError(f"argument --star-catalogue: {exc}") from None
        else:  # one sky per seed: the same stars in every frame
            _STARS[key] = StarField.procedural(key[1], key[2])
    return _STARS[key]


def _lighting(light: dict, r: dict, stars=None):
    from raytrace.lighting import Earth, Lighting
    earth = None
    if r["earth_texture"] != "none":
        earth = Earth(light["earth_dir_body"], light["earth_distance_m"], albedo=r["earth_albedo"],
                      texture=r["earth_texture"], R_body_from_earth=light["R_body_from_earth"])
    return Lighting(sun_dir_body=light["sun_dir_body"], sun_irradiance_W_m2=SOLAR_CONSTANT_W_M2,
                    shadow_fraction=light["shadow_fraction"], earth=earth,
                    ambient_radiance_W_m2_sr=r["ambient_W_m2_sr"], stars=stars,
                    R_body_from_eci=None if stars is None else light["R_body_from_eci"])


def _physical_config(d: dict, cam: dict, motion=None):
    """The physical chain's settings; ``motion`` = (L [px], θ [deg]) of the frame overrides the
    constant blur when ``--motion-blur auto``."""
    from degrade.chain import DegradeConfig, OpticsConfig
    from degrade.sensor import SensorConfig
    f_m = cam["focal_length_mm"] * 1e-3
    length, angle = d["motion_blur_px"], d["motion_angle_deg"]
    if d.get("motion_blur") == "auto" and motion is not None:
        length, angle = motion
    optics = OpticsConfig(focal_length_m=f_m, aperture_m=f_m / d["f_number"], pixel_pitch_m=cam["pixel_pitch_um"] * 1e-6,
                          aberration_sigma_px=d["aberration_sigma_px"], motion_length_px=length,
                          motion_angle_deg=angle, defocus_radius_px=d["defocus_radius_px"],
                          corner_sigma_px=d["corner_sigma_px"] or None)
    sensor = SensorConfig(quantum_efficiency=d["quantum_efficiency"], full_well_e=d["full_well_e"],
                          read_noise_e=d["read_noise_e"], bit_depth=d["bit_depth"], exposure_s=d["exposure_us"] * 1e-6,
                          offset_dn=d["offset_dn"], dark_current_e_per_s=d["dark_current_e_s"], demosaic=d["demosaic"])
    return DegradeConfig(optics=optics, sensor=sensor, encoding="srgb8")


def degrade_frame(cfg: dict, task: dict, rgb8, radiance, degrade_seq) -> np.ndarray:
    """The degraded 8-bit RGB of one frame (``cfg["degrade"]["degrade"]`` is ``paper`` or
    ``physical``): the paper's group applied to the clean 8-bit image ``rgb8``, or the camera
    equation and imaging chain applied to the linear ``radiance`` [W/(m²·sr)], with the random
    stream ``degrade_seq`` (:func:`frame_seeds`); ``task`` gives the frame's motion (the
    ``auto`` motion blur)."""
    from degrade.encode import quantise
    d = cfg["degrade"]
    rng = np.random.default_rng(degrade_seq)
    if d["degrade"] == "paper":
        from degrade.paper import PaperConfig, paper_degrade
        paper = PaperConfig(length_px=d["paper_blur_px"], angle_deg=d["paper_angle_deg"],
                            gaussian_var=d["paper_gaussian_var"])
        out = paper_degrade(np.asarray(rgb8).astype(np.float32) / np.float32(255.0), d["paper_group"], paper, rng=rng)
    else:
        from degrade.chain import degrade
        from degrade.exposure import physical_exposure
        cam = cfg["camera"]
        signal = physical_exposure(radiance, f_number=d["f_number"], exposure_s=d["exposure_us"] * 1e-6,
                                   pixel_pitch_m=cam["pixel_pitch_um"] * 1e-6,
                                   quantum_efficiency=d["quantum_efficiency"], full_well_e=d["full_well_e"],
                                   wavelengths_m=(_WHITE_BALANCE_M,) * 3)
        out = degrade(signal, _physical_config(d, cam, task["light"].get("motion")), rng=rng)
    return quantise(out, 8)


def render_frame_images(task: dict) -> tuple[dict, dict]:
    """Render one frame of a task and return (images, image-derived label fields).

    ``images`` maps a modality to its pixels (only the requested ones, plus ``rgb`` when
    ``task["want_rgb"]``)."""
    from degrade.encode import quantise, srgb_encode
    from raytrace.camera import Camera
    from raytrace.shade import render
    cfg = task["cfg"]
    mods = set(task["modalities"])
    scene = _scene(task["model_spec"], task.get("prebuilt"))
    camera = Camera(*task["camera"])
    R = np.asarray(task["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
    t = np.asarray(task["t_cam_m"], dtype=np.float64)
    render_seed, degrade_seq = frame_seeds(cfg["sequence"]["seed"], task["frame"])
    d = cfg["degrade"]
    need_rgb = task.get("want_rgb") or "rgb" in mods or ("rgb_degraded" in mods and d["degrade"] == "paper")
    need_radiance = _shades(task)
    images, info = {}, {}
    if need_radiance:
        r = cfg["render"]
        frame = render(scene, camera, R, t, _lighting(task["light"], r, _star_field(cfg)), quality=r["quality"],
                       samples=r["samples"], seed=render_seed)
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
        images["rgb"] = quantise(srgb_encode(np.minimum(linear, np.float32(1.0))), 8)
        info["exposure_scale"] = float(scale)
    if "rgb_degraded" in mods:
        images["rgb_degraded"] = degrade_frame(cfg, task, images.get("rgb"), radiance, degrade_seq)
    if "mask" in mods:
        images["mask"] = geo.instance.astype(np.uint16)
    if "depth" in mods:
        images["depth"] = geo.depth_m.astype(np.float32)
    if "normal" in mods:
        images["normal"] = geo.normal_cam.astype(np.float32)
    if "hdr" in mods:
        images["hdr"] = radiance.astype(np.float32)
    bbox = geo.bbox_xywh
    vf = geo.visible_fraction
    info.update({"bbox": None if bbox is None else [int(v) for v in bbox],
                 "visible_fraction": None if math.isnan(vf) else float(vf),
                 "pixel_counts": [int(v) for v in geo.pixel_counts]})
    return images, info


def run_frame(task: dict) -> dict:
    """Render, degrade and write one frame (files atomically, then its manifest record);
    returns the frame's label. With ``task["write"]`` false, returns the images instead.

    A pool worker told to stop (:func:`_worker_stop`) abandons its frame, and exits rather than
    start the frame already queued for it."""
    global _IN_FRAME
    if _IN_POOL_WORKER and _WORKER_STOPPING:
        os._exit(1)
    _IN_FRAME = True
    try:
        return _run_frame(task)
    finally:
        _IN_FRAME = False


def _run_frame(task: dict) -> dict:
    from raytrace import files as F
    images, info = render_frame_images(task)
    if not task.get("write", True):
        return {"frame": task["frame"], "index": task.get("index"), "images": images, "info": info}
    seq_dir, name = task["out"], f"{task['frame']:06d}"
    rel = {m: f"{m}/{name}{_EXT[m]}" for m in task["modalities"]}
    digests = {}
    for m in task["modalities"]:
        path = os.path.join(seq_dir, rel[m])
        F.atomic_write_image(path, images[m], noisy=m == "rgb_degraded")
        digests[rel[m]] = F.sha256_file(path)
    label = dict(task["label"])
    label.update(info)
    label["files"] = rel
    F.write_frame_record(seq_dir, task["frame"], {"frame": task["frame"], "label": label, "files": digests})
    return label


# --------------------------------------------------------------------------- sequence folders
def _versions() -> dict:
    import platform
    from importlib import metadata
    out = {"python": platform.python_version()}
    for dist in ("orbitsynth", "numpy", "scipy", "numba", "embreex", "trimesh", "OpenImageIO", "scikit-image"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _camera_json(camera, cfg: dict) -> dict:
    K = camera.K.tolist()
    cam = cfg["camera"]
    return {"K": K, "width": camera.width, "height": camera.height,
            "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
            "focal_length_m": cam["focal_length_mm"] * 1e-3, "pixel_pitch_m": cam["pixel_pitch_um"] * 1e-6,
            "convention": "OpenCV: x right, y down, z forward; integer pixel coordinates are pixel centres",
            # SPEED+-style keys
            "cameraMatrix": K, "distCoeffs": [0.0, 0.0, 0.0, 0.0, 0.0], "Nu": camera.width, "Nv": camera.height,
            "ppx": cam["pixel_pitch_um"] * 1e-6, "ppy": cam["pixel_pitch_um"] * 1e-6}


def _frames_to_write(plan: dict) -> list:
    frames = plan["result"]["frames"]
    only = plan["cfg"]["output"]["only_visible"]
    return [f["frame"] for f in frames if f["visible"] or not only]


def _scenario(plan: dict) -> dict:
    res, cfg, model = plan["result"], plan["cfg"], plan["model"]
    scen = {"format": "orbitsynth sequence 1", "config": cfg, "seed": cfg["sequence"]["seed"],
            "versions": _versions()}
    scen.update({k: v for k, v in res.items() if k != "frames"})
    scen["target_model"] = {
        "file": f"model/{res['target']}.ply",
        "n_triangles": model.n_triangles,
        "components": [{"id": k + 1, "name": c.name, "material": c.material, "semantic": c.semantic}
                       for k, c in enumerate(model.components)]}
    scen["visible"] = [f["visible"] for f in res["frames"]]
    scen["frames_written"] = _frames_to_write(plan)
    scen["exposure"] = ("fixed: linear = radiance * pi / 1361 W/m2 (a white Lambertian surface facing the Sun "
                        "is 1.0), sRGB 8-bit" if cfg["render"]["exposure"] == "fixed" else
                        "auto: per frame, 99.5th luminance percentile of the target -> 0.9 (exposure_scale in labels)")
    if cfg["degrade"]["degrade"] == "physical" and cfg["degrade"]["motion_blur"] == "auto":
        scen["motion_blur"] = ("auto: per frame, a straight line along the principal axis v of the target's hull "
                               "vertices' image positions over the exposure, of length min(sqrt(12 lambda), E) "
                               "(lambda: their mean variance along v; E: the RMS of their paths' extents along v), the "
                               "largest over centred parts of the exposure, at most the image diagonal; "
                               "motion_blur_px and motion_angle_deg in labels")
    scen["random_streams"] = ("frame i: SeedSequence(seed).spawn(n)[i]; render seed = generate_state(1)[0] mod 2^31, "
                              "degradation rng = its first spawned child")
    return scen


def _json(obj) -> str:
    return json.dumps(obj, indent=1, allow_nan=False) + "\n"


def _first_missing(path: str) -> str | None:
    path = os.path.abspath(path)
    missing = None
    while not os.path.exists(path):
        missing = path
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return missing


def _read_bytes(path: str) -> bytes:
    with open(path, "rb") as fh:
        return fh.read()


SCENARIO_FORMAT = "orbitsynth sequence 1"
_SCENARIO_LIMIT = 256 << 20  # bytes; a million frames' scenario.json is ~30 MB


def _own_entry(name: str, path: str) -> bool:
    """Whether ``name`` in a folder without ``scenario.json`` may be left by this tool: its lock
    file, a temporary file of an interrupted write, or one of its sub-folders, empty."""
    from raytrace import files as F
    if name == F.LOCK_NAME or F.is_temporary(name):
        return True
    if name in MODALITIES or name in ("model", F.MANIFEST_DIR):
        try:
            return os.path.isdir(path) and not os.path.islink(path) and not os.listdir(path)
        except OSError:
            return False
    return False


def judge_sequence_folder(seq_dir: str, scenario: str) -> bool:
    """Decide, before anything is written, whether the main job may write the sequence whose
    ``scenario.json`` text is ``scenario`` into ``seq_dir``: True if the folder holds that very
    sequence (it is resumed), False if it is missing or empty (or holds only this tool's
    leftovers of an interrupted start).

    Raises
    ------
    CLIError
        The path is not a writable folder; the folder holds another sequence, a
        ``scenario.json`` that is not one of this tool's, or other files.
    """
    from raytrace import files as F
    if not os.path.lexists(seq_dir):
        return False
    if not os.path.isdir(seq_dir):
        raise CLIError(f"--out: {seq_dir} exists and is not a folder")
    if not os.access(seq_dir, os.W_OK | os.X_OK):
        raise CLIError(f"--out: {seq_dir} is not writable")
    scen_path = os.path.join(seq_dir, "scenario.json")
    foreign = f"--out: {seq_dir} holds something that is not a sequence of this tool"
    if os.path.lexists(scen_path):
        try:
            data = F.read_regular_file(scen_path, limit_bytes=_SCENARIO_LIMIT, what="scenario.json")
        except ValueError as exc:
            raise CLIError(f"{foreign} ({exc}); choose another --out") from None
        try:
            doc = json.loads(data.decode("utf-8"))
        except ValueError:  # UnicodeDecodeError too
            doc = None
        if not isinstance(doc, dict) or doc.get("format") != SCENARIO_FORMAT:
            raise CLIError(f"{foreign} (its scenario.json is not an orbitsynth scenario); choose another --out")
        if data.decode("utf-8") != scenario:
            raise CLIError(f"--out: {seq_dir} holds another sequence (its scenario.json differs from these "
                           "options); choose another --out or delete it")
        return True
    try:
        names = sorted(os.listdir(seq_dir))
    except OSError as exc:
        raise CLIError(f"--out: cannot read {seq_dir} ({exc.strerror or exc})") from None
    other = [n for n in names if not _own_entry(n, os.path.join(seq_dir, n))]
    if other:
        shown = ", ".join(other[:3]) + (f" and {len(other) - 3} more" if len(other) > 3 else "")
        raise CLIError(f"--out: {seq_dir} is not empty and holds no sequence of this tool ({shown}); give a new or "
                       "empty folder, or a sequence folder this tool wrote")
    return False


class SequenceClaim:
    """A sequence folder this run writes into: its lock (:class:`raytrace.files.FolderLock`,
    held until :meth:`release`) and what this run created in preparing it, which
    :meth:`undo` removes when the run is refused or fails before any frame."""

    def __init__(self, seq_dir: str, lock, created_dir: str | None):
        self.seq_dir = seq_dir
        self.lock = lock
        self.created_dir = created_dir  # the outermost folder this run made (the sequence folder or a parent)
        self.created: list = []  # files and folders this run made inside an existing sequence folder

    def undo(self) -> None:
        """Remove what this run created, where no other run shares the folder (a shard of the
        same sequence may have started on it), and release the lock: a refused run leaves the
        folder as it found it."""
        import shutil
        alone = self.lock.fd is None or self.lock.try_exclusive()
        if alone:
            for path in reversed(self.created):
                try:
                    os.rmdir(path) if os.path.isdir(path) and not os.path.islink(path) else os.unlink(path)
                except OSError:
                    pass
        self.lock.release(remove=alone and self.lock.created)
        if alone and self.created_dir is not None:
            shutil.rmtree(self.created_dir, ignore_errors=True)

    def release(self) -> None:
        """Release the lock at the end of the run; its file goes with it where no other run
        holds it."""
        self.lock.release(remove=True)


def prepare_sequence(plan: dict, seq_dir: str, *, shared: bool = False) -> SequenceClaim:
    """Claim the sequence folder: judge it before writing anything
    (:func:`judge_sequence_folder`), take its lock (exclusive for a whole run, ``shared`` for a
    shard), then create ``scenario.json`` (atomically: of shards starting at once, one creates
    it and the others must find the same text), ``camera.json``, ``config.toml``, ``model/``
    and the modality folders. Returns the claim; the caller releases it when the run ends.

    Raises
    ------
    CLIError
        The folder is refused (another sequence, foreign files, in use by another run, not
        writable); whatever this call created is removed first.
    """
    from raytrace import files as F
    scenario = _json(_scenario(plan))
    judge_sequence_folder(seq_dir, scenario)
    created_dir = _first_missing(seq_dir)
    try:
        os.makedirs(seq_dir, exist_ok=True)
    except OSError as exc:
        if created_dir is not None and os.path.isdir(created_dir):
            import shutil
            shutil.rmtree(created_dir, ignore_errors=True)
        raise CLIError(f"--out: cannot create {seq_dir} ({exc.strerror or exc})") from None
    lock = F.FolderLock(seq_dir, shared=shared)
    try:
        lock.acquire()
    except F.FolderLockBusy:
        # another run owns the folder now (even if this one made it a moment ago): touch nothing
        raise CLIError(f"--out: {seq_dir} is in use by another run writing into it (it holds the folder's lock "
                       f"{F.LOCK_NAME}); wait for it to end or choose another --out") from None
    except OSError as exc:
        if created_dir is not None:
            import shutil
            shutil.rmtree(created_dir, ignore_errors=True)
        raise CLIError(f"--out: cannot write into {seq_dir} ({exc.strerror or exc})") from None
    if lock.unsupported:
        sys.stderr.write(f"{PROG}: warning: --out: {seq_dir} cannot be locked ({lock.unsupported}); another run "
                         "writing into it at the same time would not be refused\n")
    claim = SequenceClaim(seq_dir, lock, created_dir)
    try:
        judge_sequence_folder(seq_dir, scenario)  # again, under the lock: another run may have prepared it
        F.remove_stale_temporaries(seq_dir)

        def made(path: str) -> None:
            if created_dir is None:
                claim.created.append(path)

        scen_path = os.path.join(seq_dir, "scenario.json")
        if not os.path.exists(scen_path):
            if F.create_new_text(scen_path, scenario):
                made(scen_path)
            else:  # a shard of another run created it first: it must be this sequence
                judge_sequence_folder(seq_dir, scenario)
        for rel in [*plan["cfg"]["output"]["modalities"], "model"]:
            path = os.path.join(seq_dir, rel)
            if not os.path.isdir(path):
                os.makedirs(path, exist_ok=True)
                made(path)
        scen = json.loads(scenario)
        blobs = {scen["target_model"]["file"]: F.model_ply_bytes(plan["model"]),
                 "camera.json": _json(_camera_json(plan["camera"], plan["cfg"])).encode("utf-8"),
                 "config.toml": config_toml(plan["cfg"]).encode("utf-8")}
        for rel, data in blobs.items():
            path = os.path.join(seq_dir, rel)
            if not (os.path.isfile(path) and _read_bytes(path) == data):
                existed = os.path.lexists(path)
                F.atomic_write_bytes(path, data)
                if not existed:
                    made(path)
    except BaseException as exc:
        claim.undo()
        if isinstance(exc, OSError):
            raise CLIError(f"--out: cannot write into {seq_dir} ({exc.strerror or exc})") from None
        raise
    return claim


def _frame_files(seq_dir: str, frame: int, modalities) -> list:
    return [os.path.join(seq_dir, m, f"{frame:06d}{_EXT[m]}") for m in modalities]


def remove_incomplete_frames(tasks: list) -> int:
    """After a failed or interrupted run: delete the image files of this run's frames that have
    no manifest record (written before the failure; a rerun renders them again), so that no
    half-written frame stays. Returns how many files were removed."""
    from raytrace import files as F
    removed = 0
    for task in tasks:
        if not task.get("write", True) or F.read_frame_record(task["out"], task["frame"]) is not None:
            continue
        for path in _frame_files(task["out"], task["frame"], task["modalities"]):
            try:
                os.unlink(path)
                removed += 1
            except OSError:
                pass
    return removed


def finish_sequence(plan: dict, seq_dir: str, verified=frozenset()) -> dict:
    """Write labels.json and manifest.json if every frame of the sequence is complete (from
    any run or shard). Frames not in ``verified`` (those this run neither rendered nor checked
    before skipping: other shards') are checked against their records' SHA-256 first; a frame
    whose files do not match is not complete. Where the sequence is not complete, a
    labels.json and manifest.json left from an earlier state are removed: they would disagree
    with the files. Returns counts and the frames found corrupt."""
    from raytrace import files as F
    wanted = _frames_to_write(plan)
    records, corrupt = {}, []
    for i in wanted:
        rec = F.read_frame_record(seq_dir, i)
        if rec is None:
            continue
        bad = [rel for rel, digest in rec["files"].items()
               if not os.path.isfile(os.path.join(seq_dir, rel))
               or (i not in verified and F.sha256_file(os.path.join(seq_dir, rel)) != digest)]
        if bad:
            corrupt.append((i, bad[0]))
        else:
            records[i] = rec
    done = len(records) == len(wanted)
    if done:
        labels = [records[i]["label"] for i in wanted]
        files = {}
        for rel in ("scenario.json", "camera.json", "config.toml", _scenario(plan)["target_model"]["file"]):
            files[rel] = F.sha256_file(os.path.join(seq_dir, rel))
        for i in wanted:
            files.update(records[i]["files"])
        labels_text = _json(labels)
        F.atomic_write_text(os.path.join(seq_dir, "labels.json"), labels_text)
        files["labels.json"] = F.sha256_file(os.path.join(seq_dir, "labels.json"))
        F.atomic_write_text(os.path.join(seq_dir, "manifest.json"),
                            _json({"format": "orbitsynth manifest 1", "algorithm": "sha256", "files": files}))
    else:
        for rel in ("manifest.json", "labels.json"):
            try:
                os.unlink(os.path.join(seq_dir, rel))
            except FileNotFoundError:
                pass
    return {"complete": done, "present": len(records), "wanted": len(wanted), "corrupt": corrupt}


def _tasks_for(plan: dict, seq_dir: str, shard: tuple | None, *, write: bool = True, frames=None) -> tuple:
    """(tasks to run, frames skipped as complete) for the frames of this shard."""
    from raytrace import files as F
    cfg, cam = plan["cfg"], plan["camera"]
    wanted = _frames_to_write(plan) if frames is None else list(frames)
    if shard is not None:
        k, n = shard
        wanted = [i for i in wanted if i % n == k - 1]
    tasks, skipped = [], 0
    for i in wanted:
        if write and F.frame_complete(seq_dir, i) is not None:
            skipped += 1
            continue
        label = plan["result"]["frames"][i]
        tasks.append({"frame": i, "out": seq_dir, "write": write, "cfg": cfg, "model_spec": plan["model_spec"],
                      "camera": (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy),
                      "R_cam_from_body": label["R_cam_from_body"], "t_cam_m": label["t_cam_m"],
                      "light": plan["lights"][i], "label": label,
                      "modalities": cfg["output"]["modalities"] if write else [], "want_rgb": not write})
    return tasks, skipped


# --------------------------------------------------------------------------- execution
def default_workers() -> int:
    """All cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def frame_threads(workers: int, tasks: int) -> int:
    """The numba threads each frame of :func:`execute` runs on: the pool's workers share the
    cores; one worker (or one frame) renders in this process, on numba's threads."""
    import numba
    if workers <= 1 or tasks <= 1:
        return numba.config.NUMBA_NUM_THREADS
    return max(1, min(default_workers() // min(workers, tasks), numba.config.NUMBA_NUM_THREADS))


@contextlib.contextmanager
def _prebuild_threads(threads: int, quality: str):
    """The threads :func:`_prebuild_scenes` runs on here: all of numba's, unless the workers run
    one each (the kernels' serial builds) and numba's cache lacks the parallel builds (a fresh
    install): then one thread, on the serial builds the workers use, rather than compiling
    the parallel ones for this alone (their recorded compile times, ``_jit_signatures.py``, add
    up to over 10 CPU s; a Cassini cache takes ~4.5 s on one thread, ~2.4 s on two). The same
    scene and cache either way (``raytrace._jit.ThreadedKernel``)."""
    if threads != 1 or not _kernels_not_compiled(quality, serial=False):
        yield
        return
    import numba
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def connect_scheduler(scheduler: str):
    """A dask.distributed client of ``--scheduler``, connected before anything is written (a
    scheduler that cannot be reached leaves no folder behind)."""
    try:
        from distributed import Client
    except ImportError:
        raise CLIError("--scheduler needs dask.distributed: pip install 'orbitsynth[dask]'") from None
    try:
        return Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise CLIError(f"--scheduler: cannot connect to {scheduler} ({exc})") from None


def execute(tasks: list, *, workers: int, progress=None, client=None):
    """Run :func:`run_frame` on every task: in this process (1 worker), on a pool of
    ``workers`` spawned processes, or on a dask.distributed cluster (``client``, connected by
    :func:`connect_scheduler`); yields results as they complete and advances ``progress`` (a
    tqdm bar) by one per frame."""
    if not tasks:
        return
    if client is not None:
        from distributed import as_completed
        for fut in as_completed(client.map(run_frame, tasks, pure=False)):
            res = fut.result()
            if progress is not None:
                progress.update(1)
            yield res
        return
    if workers <= 1 or len(tasks) == 1:
        for task in tasks:
            res = run_frame(task)
            if progress is not None:
                progress.update(1)
            yield res
        return
    import multiprocessing
    import shutil
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    n = min(workers, len(tasks))
    threads = frame_threads(workers, len(tasks))
    pool = ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(threads,))
    folder = None
    try:
        # the workers start and import while this process builds the scenes they will load
        ready = [pool.submit(_worker_ready, tasks[0]["cfg"]["render"]["quality"]) for _ in range(n)]
        if _PREBUILD_SCENES:
            import pickle
            from raytrace.files import process_folder
            try:
                folder = process_folder(_SCENES_FOLDER)
                with _prebuild_threads(threads, tasks[0]["cfg"]["render"]["quality"]):
                    prebuilt = _prebuild_scenes(tasks, folder)
            except (OSError, pickle.PicklingError) as exc:  # e.g. no room in the temporary folder
                sys.stderr.write(f"{PROG}: warning: the workers build their own scenes ({exc})\n")
                prebuilt = {}
            tasks = [dict(t, prebuilt=prebuilt.get(t["model_spec"])) for t in tasks]
        for fut in ready:
            fut.result()
        pending = {pool.submit(run_frame, t) for t in tasks}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                res = fut.result()
                if progress is not None:
                    progress.update(1)
                yield res
    except BaseException as exc:  # Ctrl-C or Terminated, or what failed as it unwound the wait
        if _interruption(exc) is not None:
            _stop_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)


_SCENES_FOLDER = "orbitsynth-scenes-"  # + host.pid-XXXXXXXX in the temporary directory


def _remove_stale_scene_folders() -> None:
    """Delete the pools' scene folders (:func:`execute`) of runs that were killed before they
    could (SIGKILL, a crash): every run does it as it starts, whatever it renders and on how
    many workers, so a killed run's ~100 MB never outlive the next run."""
    try:
        from raytrace.files import remove_stale_process_folders
        remove_stale_process_folders(_SCENES_FOLDER)
    except OSError:
        pass


def _stop_workers(pool) -> None:
    """Stop the pool's workers now (an interrupt): pending frames cancelled,
    each worker sent SIGTERM (it abandons its frame, removes that frame's temporary files and
    exits: :func:`_worker_stop`), and killed if it has not exited within _STOP_GRACE_S."""
    import signal
    from raytrace._threads import pool_processes
    # the pool's own processes, not multiprocessing.active_children(): cli.main may run inside a
    # program with children of its own
    procs = pool_processes(pool)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            os.kill(p.pid, signal.SIGTERM)
        except OSError:
            pass
    deadline = time.monotonic() + _STOP_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()


def _progress(total: int, initial: int, desc: str, quiet: bool):
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit="frame", disable=quiet, file=sys.stderr,
                dynamic_ncols=True, smoothing=0.1, mininterval=0.5)


def _precompile_groups(quality: str) -> list:
    """The kernel groups of raytrace._precompile a ``quality`` frame calls: the main job's, the
    preset's own, and for ``balanced`` on an embreex wheel without Embree 4 the batched
    fallback's."""
    groups = ["fast"]
    if quality == "balanced":
        from raytrace import _embree
        groups += ["balanced"] if _embree.available() else ["balanced", "batched"]
    elif quality == "reference":
        groups.append("reference")
    return groups


def _kernels_not_compiled(quality: str = "fast", serial: bool = False) -> list:
    """The groups of :func:`_precompile_groups` whose kernels numba's on-disk cache does not
    hold yet, in their serial builds (``serial``: for processes on one numba thread each) or
    their parallel ones (a fresh install, a new NUMBA_CACHE_DIR, a first ``balanced`` run):
    judged by the cache index of one kernel per group, where numba's own cache locator puts it
    (next to the source when writable, else the user's cache directory). Empty if numba's
    cache internals cannot be read (no guess then)."""
    try:
        from raytrace._precompile import dispatcher, probe
        missing = []
        for group in _precompile_groups(quality):
            name = probe(group)
            if name is not None and not os.path.exists(dispatcher(name, serial)._cache._cache_file._index_path):
                missing.append(group)
        return missing
    except Exception:  # noqa: BLE001 (numba internals of another version)
        return []


SERIAL_COMPILE_RATIO = 0.57
"""Compile time of the kernels' serial builds over their parallel builds' (which
``raytrace/_jit_signatures.py`` records): the ``fast`` group, CPU seconds of the two compiling
processes, 40.3 against 70.2 (``python -m raytrace._precompile --time-serial 2 fast`` and
``--time 2 fast``, medians of 3 alternated, 2-core AMD EPYC; BENCHMARKS.md)."""


def _compile_kernels(groups: list, quiet: bool, serial: bool = False) -> None:
    """A fresh install (or a preset's first run): compile the numba kernels of ``groups``, in
    the builds the frames will call (``serial``: the pool's workers run one numba thread each),
    into numba's cache on all cores at once (:func:`raytrace._precompile.precompile`), before
    the workers start and would each compile all of them, under a progress bar: its unit is
    the kernels' recorded compile time, so its rate and remaining time are measured on this
    machine as it goes. A kernel this misses compiles on its first call, as it would anyway."""
    processes = max(1, min(default_workers(), 4))
    try:
        from raytrace._precompile import group_signatures
        total = float(sum(c for c, _ in group_signatures(groups).values()))
    except Exception:  # noqa: BLE001 (the estimate only)
        total = 0.0
    if not quiet:
        seconds = total * (SERIAL_COMPILE_RATIO if serial else 1.0) / processes
        about = f"about {5 * max(1, round(seconds / 5))} s on idle cores" if total else "a minute or two"
        print(f"first run: compiling the ray-tracing kernels ({', '.join(groups)}) into numba's cache, once, on "
              f"{processes} core{'s' if processes > 1 else ''} ({about}; the bar measures it as it goes)",
              file=sys.stderr)
    from tqdm import tqdm
    bar = tqdm(total=total or None, desc="compiling", disable=quiet, file=sys.stderr, dynamic_ncols=True,
               mininterval=0.5, bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed} elapsed, {remaining} left")

    def progress(done: float, _total: float) -> None:
        bar.update(done - bar.n)

    try:
        from raytrace._precompile import precompile
        precompile(processes, groups, progress=progress, serial=serial)
    except Exception:  # noqa: BLE001 (an optimisation: without it the kernels compile lazily)
        pass
    finally:
        bar.close()


FRAME_BYTES_PER_PIXEL = 160
"""Peak memory of one worker per pixel of its frame [bytes]: measured 137–139 B/px (peak RSS of a
one-frame run with one worker, 320×240 to 2560×1920, ``fast`` and ``balanced``, default
modalities and ``physical`` degradation), with room on top."""
WORKER_BASE_BYTES = 700 << 20
"""Peak memory of one worker besides its frame's pixels (libraries, scene, radiance cache) [bytes]."""


def memory_bytes() -> tuple:
    """(physical memory, memory available now) of this machine [bytes], from /proc/meminfo or
    sysconf; (None, None) where neither tells."""
    try:
        info = {}
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                key, _, rest = line.partition(":")
                info[key] = int(rest.split()[0]) * 1024
        return info["MemTotal"], info.get("MemAvailable", info["MemTotal"])
    except (OSError, KeyError, ValueError, IndexError):
        pass
    try:
        page = os.sysconf("SC_PAGE_SIZE")
        total = os.sysconf("SC_PHYS_PAGES") * page
        try:
            return total, os.sysconf("SC_AVPHYS_PAGES") * page
        except (ValueError, OSError):
            return total, total
    except (ValueError, OSError, AttributeError):
        return None, None


def fit_workers(cameras: list, workers: int) -> int:
    """The worker count whose frames (of the largest of ``cameras``) fit in this machine's
    memory: refuses up front (one line naming --width/--height) a frame that one worker could
    not render in all of it, and lowers ``workers`` (with a warning) where their frames would
    not fit in the memory available now. Frames are byte-identical whatever the worker count."""
    total, available = memory_bytes()
    if total is None or not cameras:
        return workers
    cam = max(cameras, key=lambda c: c.width * c.height)
    need = WORKER_BASE_BYTES + FRAME_BYTES_PER_PIXEL * cam.width * cam.height
    if need > total:
        raise CLIError(f"argument --width/--height: a {cam.width}x{cam.height} frame needs about "
                       f"{need / 2**30:.1f} GiB "
                       f"of memory to render, more than this machine's {total / 2**30:.1f} GiB; render a smaller image "
                       "(or crop it: a longer --focal-length-mm at a smaller size)")
    fit = max(1, int(available // need))
    if fit < workers:
        sys.stderr.write(f"{PROG}: warning: rendering on {fit} worker{'s' if fit > 1 else ''} instead of {workers}: "
                         f"each needs about {need / 2**30:.1f} GiB for a {cam.width}x{cam.height} frame and "
                         f"{available / 2**30:.1f} GiB is available\n")
        return fit
    return workers


def run_plans(jobs: list, args: argparse.Namespace, *, desc: str | None = None) -> list:
    """Render the (plan, sequence folder) pairs: prepare folders, run every missing frame of
    this shard on the chosen backend (one progress bar), then assemble labels and manifests.
    Returns one stats dict per sequence."""
    workers = args.workers or default_workers()
    if args.scheduler is None:
        workers = fit_workers([plan["camera"] for plan, _ in jobs], workers)
    client = connect_scheduler(args.scheduler) if args.scheduler is not None else None
    try:
        return _run_plans(jobs, args, desc, workers, client)
    finally:
        if client is not None:
            client.close()


def _run_plans(jobs: list, args: argparse.Namespace, desc: str | None, workers: int, client) -> list:
    claims = []
    try:
        for plan, seq_dir in jobs:
            claims.append(prepare_sequence(plan, seq_dir, shared=args.shard is not None))
    except BaseException:
        for claim in reversed(claims):  # a refused dataset leaves none of its other folders behind
            claim.undo()
        raise
    try:
        return _render_claimed(jobs, args, desc, workers, client)
    finally:
        for claim in claims:
            claim.release()


def _shard_frames(plan: dict, shard: tuple | None) -> set:
    wanted = _frames_to_write(plan)
    return set(wanted) if shard is None else {i for i in wanted if i % shard[1] == shard[0] - 1}


def _render_claimed(jobs: list, args: argparse.Namespace, desc: str | None, workers: int, client) -> list:
    all_tasks, stats = [], []
    for plan, seq_dir in jobs:
        tasks, skipped = _tasks_for(plan, seq_dir, args.shard)
        all_tasks += tasks
        stats.append({"name": plan["name"], "dir": seq_dir, "rendered": len(tasks), "skipped": skipped,
                      "frames": len(plan["result"]["frames"]),
                      "visible": sum(f["visible"] for f in plan["result"]["frames"])})
    skipped = sum(s["skipped"] for s in stats)
    t0 = time.perf_counter()
    serial = frame_threads(workers, len(all_tasks)) == 1
    missing = (_kernels_not_compiled(getattr(args, "quality", "fast"), serial)
               if all_tasks and args.scheduler is None else [])
    if missing:
        _compile_kernels(missing, quiet=args.quiet, serial=serial)
    bar = _progress(len(all_tasks) + skipped, skipped, desc or jobs[0][0]["name"], args.quiet)
    try:
        for _ in execute(all_tasks, workers=workers, client=client, progress=bar):
            pass
    except BaseException:
        remove_incomplete_frames(all_tasks)  # the workers have stopped: no frame is written any more
        raise
    finally:
        bar.close()
    elapsed = time.perf_counter() - t0
    for (plan, seq_dir), s in zip(jobs, stats):
        # this run rendered its frames or checked their files before skipping them
        s.update(finish_sequence(plan, seq_dir, verified=_shard_frames(plan, args.shard)))
        s["seconds"] = elapsed
        s["shard"] = args.shard
    return stats


def _summary_line(s: dict, elapsed: float) -> str:
    rate = f", {s['rendered'] / elapsed:.2f} frames/s" if s["rendered"] and elapsed > 0 else ""
    if s["complete"]:
        state = "labels.json and manifest.json written"
    elif s.get("corrupt"):
        frame, rel = s["corrupt"][0]
        more = f" and {len(s['corrupt']) - 1} more" if len(s["corrupt"]) > 1 else ""
        state = (f"{s['present']} of {s['wanted']} frames complete; frame {frame}{more} does not match its manifest "
                 f"record ({rel}): rerun without --shard, or its shard, to render it again")
    else:
        state = (f"{s['present']} of {s['wanted']} frames present; labels.json is written when all are "
                 "(run the other shards, or rerun without --shard)")
    return (f"{s['name']}: {s['frames']} frames, {s['visible']} visible; rendered {s['rendered']}, "
            f"skipped {s['skipped']} complete, in {elapsed:.1f} s{rate} -> {s['dir']}/ ({state})\n")


# --------------------------------------------------------------------------- termination
class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``kill``, a batch scheduler's time limit, a closed terminal), raised in
    the main thread where Ctrl-C raises KeyboardInterrupt, so that the same clean-up runs: the
    pool's workers stopped (:func:`_stop_workers`), frames in flight abandoned without leaving
    temporary files, the pool's temporary scenes deleted. Exit status 128 + the signal."""

    def __init__(self, signum: int):
        import signal
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def _termination_signals() -> list:
    import signal
    return [sig for sig in (getattr(signal, name, None) for name in ("SIGTERM", "SIGHUP")) if sig is not None]


_TERMINATING = False


def _on_termination(signum, frame) -> None:
    global _TERMINATING
    if _TERMINATING:  # once: a second signal must not interrupt the clean-up
        return
    _TERMINATING = True
    raise Terminated(signum)


def install_termination_handlers() -> None:
    """SIGTERM and SIGHUP raise :class:`Terminated` in the main thread (``cli.py`` as a
    program), unless the process was started with them ignored (``nohup``)."""
    import signal
    for sig in _termination_signals():
        if signal.getsignal(sig) == signal.SIG_DFL:
            signal.signal(sig, _on_termination)


def _interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or :class:`Terminated` behind ``exc``, if any: itself, or one it was raised
    while handling (``__context__``). The signal's exception lands wherever the main thread is,
    and code it interrupts can fail in turn as it unwinds (a lock released twice in
    ``threading``: "release unlocked lock"); that failure is the signal's doing, not the
    render's."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _interrupted(exc: KeyboardInterrupt, after: str) -> int:
    """One line for Ctrl-C or :class:`Terminated`; the exit status, 128 + the signal."""
    how = f"terminated by {exc}" if isinstance(exc, Terminated) else "interrupted"
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
        signal_exc = _interruption(exc)  # Ctrl-C or Terminated, or a failure raised as it unwound the job
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
                _print_table(plan["result"], sys.stdout)
            sys.stdout.flush()
        except BrokenPipeError:  # e.g. `python cli.py --dry-run | head`: the reader left, not an error
            sys.stdout = None
        return 0
    seq_dir = args.out or os.path.join("output", plan["name"])
    t0 = time.perf_counter()
    stats, status = _guarded(lambda: run_plans([(plan, seq_dir)], args))
    if status is not None:
        return status
    sys.stdout.write(_summary_line(stats[0], time.perf_counter() - t0))
    return 0


def dataset_main(argv: list) -> int:
    """``cli.py dataset``: the paper's dataset (targets × patterns) in one command."""
    p = _Parser(prog=f"{PROG} dataset", description="Render the paper's dataset: every target (and with --patterns "
                "every pattern) as one sequence folder each, with one progress bar and a final table of counts.")
    p.add_argument("--targets", type=_subset(TARGETS, keep_order=True), default=list(TARGETS),
                   metavar=_choices_metavar(_subset(TARGETS), many=True),
                   help="built-in targets, comma-separated, in the order of the table (default: all)")
    p.add_argument("--patterns", action="store_true", help="all four patterns per target (default: --pattern only)")
    defaults = {"frames": DATASET_FRAMES, "degrade": "none", "modalities": list(DATASET_MODALITIES)}
    _add_options(p, defaults, skip=("target", "mesh", "mesh_unit_m"))
    _add_exec(p, out_help="dataset folder; one sub-folder TARGET_PATTERN per sequence (default: output/dataset)")
    args = p.parse_args(argv)
    for key in ("target", "mesh", "mesh_unit_m"):
        setattr(args, key, None)
    t0 = time.perf_counter()

    def plan_and_run():
        cfg, given = resolve_config(args, defaults)
        if cfg["sequence"]["mesh"] is not None:
            raise CLIError("--config: [sequence] mesh is not used by the dataset command (built-in targets only)")
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
    elapsed = time.perf_counter() - t0
    w = sys.stdout.write
    w(f"{'sequence':<26} {'frames':>6} {'visible':>7} {'rendered':>8} {'skipped':>7} {'complete':>8}\n")
    for s in stats:
        w(f"{s['name']:<26} {s['frames']:6d} {s['visible']:7d} {s['rendered']:8d} {s['skipped']:7d} "
          f"{'yes' if s['complete'] else 'no':>8}\n")
    tot = {k: sum(s[k] for s in stats) for k in ("frames", "visible", "rendered", "skipped")}
    w(f"{'total':<26} {tot['frames']:6d} {tot['visible']:7d} {tot['rendered']:8d} {tot['skipped']:7d}\n")
    w(f"{len(stats)} sequences x {len(modalities)} modalities ({','.join(modalities)}) in {elapsed:.1f} s "
      f"-> {root}/\n")
    return 0


def ablation_main(argv: list) -> int:
    """``cli.py ablation``: degradation ablation (degrade.ablation) on clean renders."""
    p = _Parser(prog=f"{PROG} ablation", description="Render N clean frames per target through the pipeline and "
                "measure what each degradation costs (PSNR, SSIM; LPIPS when installed).")
    p.add_argument("--targets", type=_subset(TARGETS, keep_order=True), default=["cassini"],
                   metavar=_choices_metavar(_subset(TARGETS), many=True),
                   help="built-in targets, comma-separated (default: cassini)")
    p.add_argument("--frames", type=_int_in(1, 10_000), default=4, help="clean frames per target (default: 4)")
    p.add_argument("--mode", type=_choice(("paper", "physical", "both")), default="both",
                   metavar=_choices_metavar(_choice(("paper", "physical", "both"))),
                   help="which study to report (default: both)")
    p.add_argument("--pattern", type=_choice(PATTERNS), default="spiral", metavar=_choices_metavar(_choice(PATTERNS)),
                   help="pattern (default: spiral)")
    # SSIM's 7 × 7 window (skimage.metrics.structural_similarity) needs images of at least 7 px a side
    p.add_argument("--width", type=_int_in(7, 65535), default=640, help="image width [px], >= 7 (default: 640)")
    p.add_argument("--height", type=_int_in(7, 65535), default=480, help="image height [px], >= 7 (default: 480)")
    p.add_argument("--focal-length-mm", type=_float_in(1e-3, 1e4, unit="mm"), default=2.0,
                   help="focal length [mm] (default: 2, the field of view of the full-size default camera)")
    p.add_argument("--quality", type=_choice(QUALITIES), default="fast", metavar=_choices_metavar(_choice(QUALITIES)),
                   help="shading preset (default: fast)")
    p.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0, help="seed (default: 0)")
    p.add_argument("--workers", type=_int_in(1, 4096), default=None, help="worker processes (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    from degrade.ablation import format_ablation, run_ablation
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
            t, _ = _tasks_for(plan, "", None, write=False, frames=pick)
            for task in t:
                task["index"] = len(tasks)
                tasks.append(task)
            labels += [target] * len(t)
        workers = fit_workers([Camera(*tasks[0]["camera"])], args.workers or default_workers())
        bar = _progress(len(tasks), 0, "ablation", args.quiet)
        rgb = [None] * len(tasks)
        try:
            for res in execute(tasks, workers=workers, progress=bar):
                rgb[res["index"]] = res["images"]["rgb"]  # results arrive as they complete
        finally:
            bar.close()
        imgs = [im.astype(np.float32) / np.float32(255.0) for im in rgb]
        physical = None if args.mode == "paper" else _physical_config(cfg["degrade"], cfg["camera"])
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
    """:func:`raytrace.files.write_files_atomically`, failures as a one-line CLIError naming --out."""
    from raytrace.files import write_files_atomically as write
    try:
        write(out_dir, files, texts)
    except OSError as exc:
        raise CLIError(f"--out: {exc}") from None


def geometric_shadow_fraction(lighting) -> float | None:
    """The fraction of the solar disc that a :class:`raytrace.lighting.Lighting`'s Earth leaves
    visible at the target (:func:`orbit.visibility.illuminated_fraction`, with that Earth's
    radius and the Sun's angular diameter), or None without Earth. ``shadow_fraction`` is what
    the renderer uses (the Earth does not shadow the Sun by itself); this tells whether the
    two agree. Here, not in ``raytrace``, which knows nothing of orbits."""
    e = lighting.earth
    if e is None:
        return None
    from orbit.constants import R_EARTH_M, R_SUN_M
    from orbit.visibility import illuminated_fraction
    # the same angles in a frame scaled to orbit's Earth radius: target at −ê·d, Sun at the
    # distance where its disc has the scene's angular diameter
    k = R_EARTH_M / e.radius_m
    r_target = -k * e.distance_m * np.asarray(e.earth_dir_body)
    half = max(0.5 * lighting.sun_angular_diameter_rad, 1e-7)
    r_sun = r_target + R_SUN_M / math.sin(half) * np.asarray(lighting.sun_dir_body)
    return float(illuminated_fraction(r_target, r_sun))


def check_out_folder(out_dir: str, option: str = "--out") -> None:
    """Fail before any work when ``option`` (``--out``) cannot become a writable folder: it exists
    and is not a folder or not writable, or its nearest existing parent is not a writable folder."""
    if not str(out_dir).strip():
        raise CLIError(f"{option} must name a folder, got an empty string")
    path = os.path.abspath(out_dir)
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise CLIError(f"{option}: {out_dir} exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise CLIError(f"{option}: {out_dir} is not writable")
        return
    parent = os.path.dirname(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
        raise CLIError(f"{option}: cannot create {out_dir} ({parent} is not a writable folder)")
    # os.access says yes to root everywhere, /proc and /sys included: make (and remove) a
    # folder there to be sure before the render
    import tempfile
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".probe-", dir=parent))
    except OSError as exc:
        raise CLIError(f"{option}: cannot create {out_dir} ({parent}: {exc.strerror})") from None


_SCENE_DIRS = ("rgb", "mask", "depth", "normal", "hdr")


def check_scene_out(out_dir: str) -> None:
    """``render-scene`` writes frame 000000's five modality files and ``frame.json`` into a new folder, a
    folder without them, or over its own earlier frame. A folder holding a sequence (its
    ``scenario.json``, ``labels.json`` or ``manifest.json``), modality folders with other files, or
    those files without a ``frame.json`` is refused before the render, so nothing of it is
    overwritten or mixed with this frame. Unrelated files beside them are left alone."""
    path = os.path.abspath(out_dir)
    if not os.path.isdir(path):
        return
    own = {f"{d}/000000.{'png' if d in ('rgb', 'mask') else 'exr'}" for d in _SCENE_DIRS}
    found, other = set(), []
    for name in ("scenario.json", "labels.json", "manifest.json"):
        if os.path.exists(os.path.join(path, name)):
            other.append(name)
    for d in _SCENE_DIRS:
        if not os.path.isdir(os.path.join(path, d)):
            continue
        for sub in os.scandir(os.path.join(path, d)):
            name = f"{d}/{sub.name}"
            if name in own and sub.is_file():
                found.add(name)
            else:
                other.append(name)
            if len(other) >= 3:
                break
    if other or (found and not os.path.isfile(os.path.join(path, "frame.json"))):
        what = ", ".join(sorted(other)[:3]) if other else f"{', '.join(sorted(found)[:2])} without a frame.json"
        raise CLIError(f"--out: {out_dir} holds files render-scene did not write ({what}); give a new folder, or "
                       "one holding an earlier render-scene frame")


def render_scene_main(argv: list[str]) -> int:
    """``cli.py render-scene SCENE.json --out DIR``: render one frame of an explicit scene."""
    parser = _Parser(prog=f"{PROG} render-scene",
                     description="Render one frame of the scene described by a JSON file (schema in docs/shading.md).")
    parser.add_argument("scene", help="scene file (JSON)")
    parser.add_argument("--out", type=_out_path, required=True, help="output folder (created if missing)")
    parser.add_argument("--quality", type=_choice(QUALITIES), default=None,
                        metavar=_choices_metavar(_choice(QUALITIES)),
                        help="overrides the file's quality preset (default: the file's)")
    parser.add_argument("--samples", type=_int_in(1, 1 << 20), default=None,
                        help="overrides the preset's sample count")
    parser.add_argument("--seed", type=_int_in(0, 2**31 - 1), default=None, help="overrides the file's seed")
    args = parser.parse_args(argv)
    from raytrace.scene import Scene
    from raytrace.scenefile import load_scene_file
    from raytrace.shade import render
    try:
        spec = load_scene_file(args.scene)
        fit_workers([spec.camera], 1)
        check_out_folder(args.out)
        check_scene_out(args.out)
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
        serial = frame_threads(1, 1) == 1
        missing = _kernels_not_compiled(quality, serial)
        if missing:
            _compile_kernels(missing, quiet=False, serial=serial)
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
        info = {"scene": os.path.abspath(args.scene), "quality": frame.quality.name, "samples": samples,
                "seed": seed, "render_s": elapsed, "timings_s": frame.timings_s, "exposure_scale": scale,
                "width": spec.camera.width, "height": spec.camera.height, "K": spec.camera.K.tolist(),
                "R_cam_from_body": spec.R_cam_from_body.ravel().tolist(),
                "t_cam_m": spec.file_t_cam_m().tolist(), "body_offset_m": spec.body_offset_m.tolist(),
                "components": list(spec.model.component_names),
                "pixel_counts": geo.pixel_counts.tolist(), "bbox_xywh": geo.bbox_xywh,
                "visible_fraction": None if math.isnan(geo.visible_fraction) else geo.visible_fraction,
                "shadow_fraction": spec.lighting.shadow_fraction, "geometric_shadow_fraction": nu_geo}
        write_files_atomically(args.out, files, {"frame.json": json.dumps(info, indent=1) + "\n"})
    except (CLIError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    except FloatingPointError as exc:  # a renderer bug, not the input's: say so in one line
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 1
    except Exception as exc:  # noqa: BLE001 - any other failure: one line, nothing written (as the main job)
        signal_exc = _interruption(exc)
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


def _size(text: str) -> tuple:
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels (e.g. 1600x1000), got {text!r}") from None
    if not (64 <= w <= 16384 and 64 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT with 64..16384 px per side, got {text!r}")
    return w, h


def preview_track(plan: dict):
    """The :class:`raytrace.preview.PreviewTrack` of a planned sequence: the frames' states,
    camera poses, visibility flags, start-frame Sun and Earth and the target mesh, in LVLH.

    The camera axes come from the renderer's pose (``R_cam_from_body`` of every frame) and
    the look-at pointing of :func:`plan_sequence`; the target is drawn at the start frame's
    attitude ``R_lvlh_from_body = R_lvlh_from_cam @ R_cam_from_body``."""
    from orbit.pose import look_at
    from raytrace.preview import PreviewTrack
    res, model, cam = plan["result"], plan["model"], plan["camera"]
    frames = res["frames"]
    r_lvlh = np.array([f["r_lvlh"] for f in frames], dtype=np.float64)
    R_cam_from_body = np.array([f["R_cam_from_body"] for f in frames], dtype=np.float64).reshape(-1, 3, 3)
    R_lvlh_from_cam = np.swapaxes(look_at(r_lvlh), -1, -2)  # as plan_sequence points the camera
    R_lvlh_from_body0 = R_lvlh_from_cam[0] @ R_cam_from_body[0]
    verts, faces, ids, base = [], [], [], 0
    for k, comp in enumerate(model.components):
        v = np.asarray(comp.mesh.vertices, dtype=np.float64)
        f = np.asarray(comp.mesh.faces, dtype=np.int64)
        verts.append(v @ R_lvlh_from_body0.T)
        faces.append(f + base)
        ids.append(np.full(len(f), k + 1, dtype=np.int64))
        base += len(v)
    l0 = plan["lights"][0]
    sun = R_lvlh_from_body0 @ np.asarray(l0["sun_dir_body"])
    earth = R_lvlh_from_body0 @ np.asarray(l0["earth_dir_body"])
    return PreviewTrack(title=f"{res['target']} {res['pattern']}", r_lvlh_m=r_lvlh, t_s=np.asarray(res["t_s"]),
                        visible=np.array([f["visible"] for f in frames], dtype=bool),
                        R_lvlh_from_cam=R_lvlh_from_cam, K=cam.K, width=cam.width, height=cam.height,
                        vertices_lvlh_m=np.vstack(verts), faces=np.vstack(faces), face_ids=np.concatenate(ids),
                        sun_dir_lvlh=sun / np.linalg.norm(sun), earth_dir_lvlh=earth / np.linalg.norm(earth))


def preview_main(argv: list) -> int:
    """``cli.py preview``: an off-screen PNG of the sequence the same options would render."""
    p = _Parser(prog=f"{PROG} preview", description="Draw, without rendering it, the sequence that the main job "
                "would render with the same options: the target at true scale in LVLH axes, the observer "
                "trajectory coloured by time (start and end marked), camera frusta, the Sun and Earth directions "
                "at the start frame, frames failing visibility in red; below, the in-plane x-y projection. "
                "Off-screen (no display needed); seconds, not minutes.")
    _add_options(p, {})
    g = p.add_argument_group("preview (not part of the scenario)")
    g.add_argument("--config", type=_path, default=None, metavar="FILE.toml",
                   help="options as TOML tables (a sequence's config.toml previews that sequence); flags override")
    g.add_argument("--out", type=_out_path, default=None, metavar="FILE.png",
                   help="PNG to write (default: output/TARGET_PATTERN_preview.png, "
                        "output/TARGET_all-patterns_preview.png)")
    g.add_argument("--all-patterns", action="store_true", help="the four patterns side by side for one target")
    g.add_argument("--size", type=_size, default=None, metavar="WxH",
                   help=f"PNG size [px] (default: {PREVIEW_SIZE[0]}x{PREVIEW_SIZE[1]}, "
                        f"{PREVIEW_SIZE_ALL[0]}x{PREVIEW_SIZE_ALL[1]} with --all-patterns)")
    g.add_argument("--frusta-every", type=_int_in(1, 1_000_000), default=None, metavar="K",
                   help="a camera frustum every K frames (default: about 12 per sequence)")
    g.add_argument("--interactive", action="store_true", help="also open a window (needs a display)")
    g.add_argument("--html", type=_out_path, default=None, metavar="FILE.html",
                   help="also export an interactive scene (needs pyvista's exporter: "
                        "pip install trame-pyvista nest_asyncio2)")
    args = p.parse_args(argv)
    from raytrace import preview
    t0 = time.perf_counter()
    try:
        for option, path, ext in (("--out", args.out, ".png"), ("--html", args.html, ".html")):
            # a folder or a name without the extension had the file written elsewhere (name + ext)
            if path is not None and os.path.isdir(path):
                raise CLIError(f"{option}: {path} is a folder; give the file's name (e.g. "
                               f"{os.path.join(path, 'preview' + ext)})")
            if path is not None and not str(path).endswith(ext):
                raise CLIError(f"{option} must be a {ext} file name, got {path!r}")
        if args.interactive and not preview.has_display():
            raise CLIError("argument --interactive: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
                           "drop --interactive to write the PNG off-screen")
        if args.html is not None and not preview.html_export_available():
            raise CLIError("argument --html: pyvista's HTML exporter is not installed "
                           f"(pip install {' '.join(preview.HTML_EXPORT_PACKAGES)})")
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
        for path in (out, args.html):
            if path is not None and os.path.dirname(os.path.abspath(path)):
                try:
                    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
                except OSError as exc:
                    raise CLIError(f"--out: cannot create the folder of {path} ({exc.strerror or exc})") from None
        try:
            preview.write_preview(tracks, out, size=size, frusta_every=args.frusta_every, html_path=args.html)
        except OSError as exc:
            raise CLIError(f"--out: cannot write {out} ({exc.strerror or exc})") from None
        except RuntimeError as exc:
            raise CLIError(f"argument --html: {exc}; the PNG {out} is written") from None
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


def snapshot_cases(targets=None, patterns=None) -> list:
    """Snapshot names ``TARGET_PATTERN`` for every built-in target × pattern (or the given ones)."""
    return [f"{t}_{p}" for t in (targets or TARGETS) for p in (patterns or PATTERNS)]


def _snapshot_plan(name: str) -> tuple:
    """(resolved config, tasks of the kept frames) of the snapshot ``TARGET_PATTERN``."""
    target, _, pattern = name.partition("_")
    if target not in TARGETS or pattern not in PATTERNS:
        raise ValueError(f"snapshot name must be TARGET_PATTERN with a target of {', '.join(TARGETS)} and a pattern "
                         f"of {', '.join(PATTERNS)}; got {name!r}")
    s = SNAPSHOT_SETTINGS
    ns = argparse.Namespace(**{o.key: None for o in OPTIONS}, config=None)
    ns.target, ns.pattern, ns.frames, ns.seed, ns.quality = target, pattern, s["frames"], s["seed"], s["quality"]
    ns.width, ns.height = s["width"], s["height"]
    ns.focal_length_mm, ns.pixel_pitch_um = s["focal_length_mm"], s["pixel_pitch_um"]
    ns.epoch, ns.raan_deg, ns.arg_lat_deg = s["epoch"], s["raan_deg"], s["arg_lat_deg"]  # a fixed orbit geometry
    cfg, given = resolve_config(ns)
    plan = plan_sequence(cfg, given)
    tasks, _ = _tasks_for(plan, "", None, write=False, frames=s["kept_frames"])
    return cfg, tasks


def _with_preset(cfg: dict, preset: str) -> dict:
    c = json.loads(json.dumps(cfg))
    c["degrade"]["degrade"] = preset
    return c


def render_snapshot(name: str) -> dict:
    """Render the snapshot ``TARGET_PATTERN`` with :func:`plan_sequence` and
    :func:`render_frame_images`: modality → the kept frames side by side (one strip), and
    ``radiance``, the linear radiance the physical degradation starts from."""
    cfg, tasks = _snapshot_plan(name)
    presets = SNAPSHOT_SETTINGS["degrade_presets"]
    out = {m: [] for m in SNAPSHOT_MODALITIES + ("radiance",)}
    for task in tasks:
        for preset in presets:
            t = dict(task)
            t["cfg"] = _with_preset(cfg, preset)
            first = preset == presets[0]
            t["modalities"] = ["rgb", "rgb_degraded", "mask", "depth", "normal", "hdr"] if first else ["rgb_degraded"]
            images, _info = render_frame_images(t)
            out[f"rgb_{preset}"].append(images["rgb_degraded"])
            if first:
                for m in ("rgb", "mask", "depth", "normal"):
                    out[m].append(images[m])
                out["radiance"].append(images["hdr"])
    return {m: np.concatenate(v, axis=1) for m, v in out.items()}


def degrade_snapshot(name: str, images: dict) -> dict:
    """The degraded strips (``rgb_paper``, ``rgb_physical``) that the main job's degradation
    (:func:`degrade_frame`, each frame's own random stream) makes of the clean ``rgb`` and
    ``radiance`` strips in ``images`` (a snapshot's references, say)."""
    cfg, tasks = _snapshot_plan(name)
    width = SNAPSHOT_SETTINGS["width"]
    out = {}
    for preset in SNAPSHOT_SETTINGS["degrade_presets"]:
        c = _with_preset(cfg, preset)
        strips = []
        for j, task in enumerate(tasks):
            cols = slice(j * width, (j + 1) * width)
            _render_seed, degrade_seq = frame_seeds(c["sequence"]["seed"], task["frame"])
            strips.append(degrade_frame(c, task, images["rgb"][:, cols], images["radiance"][:, cols], degrade_seq))
        out[f"rgb_{preset}"] = np.concatenate(strips, axis=1)
    return out


def _snapshot_files(folder: str, name: str) -> dict:
    base = os.path.join(folder, name)
    return {"rgb": f"{base}.rgb.webp", "rgb_paper": f"{base}.rgb_paper.webp", "rgb_physical": f"{base}.rgb_physical.webp",
            "mask": f"{base}.mask.png", "geometry": f"{base}.geometry.npz"}


def _write_lossless_webp(path: str, rgb: np.ndarray) -> None:
    """8-bit RGB as lossless WebP (a quarter smaller than PNG on the degraded images' noise),
    checked by reading it back."""
    import OpenImageIO as oiio

    from raytrace import files as F
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

    from raytrace import files as F
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
    from raytrace import files as F
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
    from raytrace import files as F
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


def check_snapshot_degradation(name: str, ref: dict, *, diff_dir: str) -> list:
    """The degradation chain against a snapshot's references: both presets applied by
    :func:`degrade_snapshot` to the reference's own clean RGB and radiance must give its
    degraded strips (within :data:`SNAPSHOT_PSNR_DB`, as :func:`compare_snapshot` compares RGB).
    The inputs are the stored ones, so this holds on any CPU, whatever float rounding does to a
    fresh render; returns one message per failing preset (a diff image each in ``diff_dir``)."""
    again = degrade_snapshot(name, ref)
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
        return (f"snapshots: {path} records other snapshot settings or tolerances than cli.SNAPSHOT_SETTINGS; "
                "the references are stale: python cli.py snapshots --update")
    return None


def snapshots_main(argv: list) -> int:
    """``cli.py snapshots [--update]``: compare small renders with the committed references."""
    import tempfile
    p = _Parser(prog=f"{PROG} snapshots", description="Render every built-in target x pattern small (160x120, three "
                "frames, clean RGB, both degradation presets, mask, depth, normals) and compare with the references "
                "in tests/snapshots/: masks exactly, depth and normals within tight tolerances, RGB by PSNR >= 45 dB. "
                "Exit status 1 when something moved (a diff image per failure). --update rewrites the references.")
    p.add_argument("--update", action="store_true", help="rewrite the references instead of comparing (deliberate)")
    p.add_argument("--targets", type=_subset(TARGETS), default=None,
                   metavar=_choices_metavar(_subset(TARGETS), True),
                   help="only these targets, comma-separated (default: all)")
    p.add_argument("--patterns", type=_subset(PATTERNS), default=None,
                   metavar=_choices_metavar(_subset(PATTERNS), True),
                   help="only these patterns, comma-separated (default: all)")
    p.add_argument("--dir", type=_out_path, default=SNAPSHOT_DIR, metavar="DIR",
                   help="reference folder (default: tests/snapshots)")
    p.add_argument("--diff-dir", type=_out_path, default=None, metavar="DIR",
                   help="where diff images go (default: a new temporary folder)")
    args = p.parse_args(argv)
    names = snapshot_cases(args.targets, args.patterns)
    try:  # the folders are checked before the renders (a bad one failed after them, blamed on --dir)
        if args.update:
            check_out_folder(args.dir, option="--dir")
        elif not os.path.isdir(args.dir):
            raise CLIError(f"--dir: {args.dir} is not a folder of snapshot references (python cli.py snapshots "
                           "--update --dir DIR writes them)")
        if args.diff_dir:
            check_out_folder(args.diff_dir, option="--diff-dir")
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
    """:func:`snapshots_main` after parsing: compare (or with --update write) the snapshots
    ``names``, diff images into ``diff_dir``."""
    t0 = time.perf_counter()
    failures, nbytes = [], 0
    try:
        stale = None if args.update else snapshot_settings_message(args.dir)
        if stale:
            sys.stdout.write(f"FAIL {stale}\n")
            return 1
        for name in names:
            new = render_snapshot(name)
            if args.update:
                nbytes += sum(os.path.getsize(q) for q in write_snapshot(args.dir, name, new))
                sys.stdout.write(f"{name}: reference written\n")
                continue
            ref = read_snapshot(args.dir, name)
            msgs = (compare_snapshot(name, ref, new, diff_dir=diff_dir)
                    + check_snapshot_degradation(name, ref, diff_dir=diff_dir))
            failures += msgs
            sys.stdout.write("".join(f"FAIL {m}\n" for m in msgs) or f"{name}: ok\n")
        if args.update:
            from raytrace.files import atomic_write_text
            atomic_write_text(os.path.join(args.dir, "settings.json"), _snapshot_settings_json())
    except (CLIError, ValueError, FileNotFoundError) as exc:
        return _fail(exc)
    except OSError as exc:
        return _fail(CLIError(f"--dir: {exc}"))
    elapsed = time.perf_counter() - t0
    if args.update:
        sys.stdout.write(f"{len(names)} snapshots written to {args.dir} ({nbytes / 1e6:.2f} MB) in {elapsed:.1f} s; "
                         "review them (git diff) before committing\n")
        return 0
    if failures:
        sys.stdout.write(f"{len(failures)} failure(s) in {len(names)} snapshots ({elapsed:.1f} s); diff images in "
                         f"{diff_dir}; if the change is intended: python cli.py snapshots --update\n")
        return 1
    sys.stdout.write(f"{len(names)} snapshots match the references in {elapsed:.1f} s\n")
    return 0


COMMANDS = {"render-scene": render_scene_main, "dataset": dataset_main, "ablation": ablation_main,
            "preview": preview_main, "snapshots": snapshots_main}


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
    _remove_stale_scene_folders()
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
    cli.install_termination_handlers()
    sys.exit(cli.main())
