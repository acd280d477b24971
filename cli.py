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
import functools
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

from degrade.paper import PAPER_GROUPS
from degrade.presets import PRESETS as DEGRADE_PRESETS
from degrade.sensor import DEMOSAIC_ALGORITHMS
from orbit.attitude import ATTITUDE_MODES
from orbit.patterns import PATTERNS
from raytrace.constants import EARTH_TEXTURES as EARTH_TEXTURE_NAMES
from raytrace.constants import SOLAR_CONSTANT_W_M2
from raytrace.dataset import UsageError as CLIError
from raytrace.dataset import folder, jit, pool, scenes, snapshots
from raytrace.dataset import run as runner
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
        O("--demosaic", "degrade", _choice(DEMOSAIC_ALGORITHMS), "MHC",
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


def plan_sequence(cfg: dict, given: set = frozenset()) -> dict:
    """Load and check the target, then :func:`orbit.plan.plan_orbit`: everything but the pixels.

    Returns a dict: ``result`` (plain-Python scenario and per-frame labels without image
    quantities, the ``--json`` document), ``model``, ``model_spec``, ``camera`` and per-frame
    ``lights`` (Sun, Earth and ν in the body frame)."""
    from orbit.plan import PlanError, plan_orbit
    from raytrace.camera import Camera

    seq, cam = cfg["sequence"], cfg["camera"]
    if seq["mesh"] is not None:
        spec = ("mesh", seq["mesh"], seq["mesh_unit_m"])
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
        note = _mesh_unit_warning(0.5 * float(np.linalg.norm(hi - lo)), seq["mesh"])
        if note:
            sys.stderr.write(f"{PROG}: warning: {note}\n")
    camera = Camera.from_focal(cam["focal_length_mm"] * 1e-3, cam["pixel_pitch_um"] * 1e-6, cam["width"], cam["height"])
    points = None
    if cfg["degrade"].get("motion_blur") == "auto":
        points = np.concatenate([np.asarray(c.mesh.vertices, dtype=np.float64) for c in model.components])
    try:
        plan = plan_orbit(cfg, given, target=target, radius_m=model.bounding_radius_m, points_body_m=points,
                          intrinsics=(camera.fx, camera.fy, camera.width, camera.height))
    except PlanError as exc:
        raise CLIError(f"argument --{exc.key.replace('_', '-')}: {exc}") from None
    plan.update({"model": model, "model_spec": spec, "camera": camera, "cfg": cfg,
                 "name": f"{target}_{plan['result']['pattern']}"})
    return plan


# --------------------------------------------------------------------------- one frame (runs in a worker)


def _worker_ready(quality: str) -> None:
    """A first task for each worker, run while the parent builds the scenes: what a first
    ``quality`` frame would otherwise wait for — the imports (scipy.signal, ~0.6 s, for the
    optics' PSFs), numba's kernels loaded from its on-disk cache, the GGX split-sum table."""
    import scipy.signal  # noqa: F401
    import degrade.chain  # noqa: F401
    import raytrace.shade  # noqa: F401
    from raytrace import _precompile
    from raytrace.brdf import split_sum_table
    from raytrace.dataset.jit import precompile_groups
    _precompile.load_here(precompile_groups(quality))
    if quality != "reference":
        split_sum_table()


def frame_seeds(seed: int, frame: int) -> tuple:
    """(render seed, degradation SeedSequence) of a frame: child ``frame`` of
    ``SeedSequence(seed).spawn(...)``; the render seed is its first word mod 2³¹, the
    degradation stream its first child."""
    child = np.random.SeedSequence(seed, spawn_key=(frame,))
    return int(child.generate_state(1)[0] % 2**31), np.random.SeedSequence(seed, spawn_key=(frame, 0))


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


def degrade_frame(cfg: dict, task: dict, rgb8, radiance, degrade_seq) -> np.ndarray:
    """:func:`degrade.presets.degrade_frame` of one frame task, with its motion blur."""
    from degrade.presets import degrade_frame as degrade_one
    return degrade_one(cfg["degrade"], cfg["camera"], rgb8, radiance, degrade_seq, task["light"].get("motion"))


def render_frame_images(task: dict) -> tuple[dict, dict]:
    """Render one frame of a task and return (images, image-derived label fields).

    ``images`` maps a modality to its pixels (only the requested ones, plus ``rgb`` when
    ``task["want_rgb"]``)."""
    from degrade.encode import quantise, srgb_encode
    from raytrace.camera import Camera
    from raytrace.shade import render
    cfg = task["cfg"]
    mods = set(task["modalities"])
    scene = scenes.scene(task["model_spec"], task.get("prebuilt"))
    camera = Camera(*task["camera"])
    R = np.asarray(task["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
    t = np.asarray(task["t_cam_m"], dtype=np.float64)
    render_seed, degrade_seq = frame_seeds(cfg["sequence"]["seed"], task["frame"])
    d = cfg["degrade"]
    need_rgb = task.get("want_rgb") or "rgb" in mods or ("rgb_degraded" in mods and d["degrade"] == "paper")
    need_radiance = scenes.shades(task)
    images, info = {}, {}
    if need_radiance:
        r = cfg["render"]
        frame = render(scene, camera, R, t, _lighting(task["light"], r, scenes.star_field(cfg)), quality=r["quality"],
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
                            scheduler=args.scheduler, quiet=args.quiet, quality=getattr(args, "quality", "fast"),
                            desc=desc, ready=functools.partial(_worker_ready, quality))


# --------------------------------------------------------------------------- sequence folders


# --------------------------------------------------------------------------- execution


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
            for res in pool.execute(tasks, run_frame, workers=workers, progress=bar):
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
        info = {"scene": os.path.abspath(args.scene), "quality": frame.quality.name, "samples": samples,
                "seed": seed, "render_s": elapsed, "timings_s": frame.timings_s, "exposure_scale": scale,
                "width": spec.camera.width, "height": spec.camera.height, "K": spec.camera.K.tolist(),
                "R_cam_from_body": spec.R_cam_from_body.ravel().tolist(),
                "t_cam_m": spec.file_t_cam_m().tolist(), "body_offset_m": spec.body_offset_m.tolist(),
                "components": list(spec.model.component_names),
                "pixel_counts": geo.pixel_counts.tolist(), "bbox_xywh": geo.bbox_xywh,
                "visible_fraction": None if math.isnan(geo.visible_fraction) else geo.visible_fraction,
                "shadow_fraction": spec.lighting.shadow_fraction, "geometric_shadow_fraction": nu_geo}
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
    ``radiance``, the linear radiance the physical degradation starts from."""
    cfg, tasks = _snapshot_plan(name)
    presets = snapshots.SNAPSHOT_SETTINGS["degrade_presets"]
    out = {m: [] for m in snapshots.SNAPSHOT_MODALITIES + ("radiance",)}
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
    width = snapshots.SNAPSHOT_SETTINGS["width"]
    out = {}
    for preset in snapshots.SNAPSHOT_SETTINGS["degrade_presets"]:
        c = _with_preset(cfg, preset)
        strips = []
        for j, task in enumerate(tasks):
            cols = slice(j * width, (j + 1) * width)
            _render_seed, degrade_seq = frame_seeds(c["sequence"]["seed"], task["frame"])
            strips.append(degrade_frame(c, task, images["rgb"][:, cols], images["radiance"][:, cols], degrade_seq))
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
    """:func:`snapshots_main` after parsing: compare (or with --update write) the snapshots
    ``names``, diff images into ``diff_dir``."""
    t0 = time.perf_counter()
    failures, nbytes = [], 0
    try:
        stale = None if args.update else snapshots.snapshot_settings_message(args.dir)
        if stale:
            sys.stdout.write(f"FAIL {stale}\n")
            return 1
        for name in names:
            new = render_snapshot(name)
            if args.update:
                nbytes += sum(os.path.getsize(q) for q in snapshots.write_snapshot(args.dir, name, new))
                sys.stdout.write(f"{name}: reference written\n")
                continue
            ref = snapshots.read_snapshot(args.dir, name)
            msgs = (snapshots.compare_snapshot(name, ref, new, diff_dir=diff_dir)
                    + snapshots.check_snapshot_degradation(name, ref, degrade_snapshot(name, ref), diff_dir=diff_dir))
            failures += msgs
            sys.stdout.write("".join(f"FAIL {m}\n" for m in msgs) or f"{name}: ok\n")
        if args.update:
            from raytrace.files import atomic_write_text
            atomic_write_text(os.path.join(args.dir, "settings.json"), snapshots._snapshot_settings_json())
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
    sys.exit(cli.main())
