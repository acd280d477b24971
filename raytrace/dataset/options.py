"""Options of a sequence: typed values with one-line errors, and the TOML configuration file.

An :class:`Option` is one flag of the command line and one key of a TOML table; its parser
turns the flag's text (or the file's value, written as that text) into the value, or raises
``argparse.ArgumentTypeError`` with a message that says what is allowed. A parser's ``toml``
attribute names the TOML type it takes, its ``choices`` the names it allows. A sequence folder
keeps its resolved configuration as ``config.toml`` (:func:`config_toml`), which
``--config`` reads back (:func:`read_config`): the same options render the same bytes.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import dataclass

import numpy as np

from . import UsageError

def int_in(lo: int, hi: int):
    """An integer in [lo, hi]."""
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


def float_in(lo: float, hi: float, *, lo_open: bool = False, unit: str = ""):
    """A finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""
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


def floats(n: int, lo: float, hi: float, *, unit: str = "", nonzero: bool = False):
    """``n`` comma-separated finite numbers in [lo, hi] (not all zero with ``nonzero``)."""
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


def choice(allowed):
    """One name of ``allowed``."""
    def parse(text: str) -> str:
        if text not in allowed:
            raise argparse.ArgumentTypeError(f"must be one of {', '.join(allowed)}; got {text!r}")
        return text
    parse.choices = tuple(allowed)
    return parse


def subset(allowed, *, keep_order: bool = False):
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


def choices_metavar(parse, many: bool = False) -> str | None:
    """``{a,b,c}`` (one of) or ``{a,b,c}[,..]`` (a list) for a parser of names."""
    choices = getattr(parse, "choices", None)
    if choices is None:
        return None
    return "{" + ",".join(choices) + "}" + ("[,...]" if many else "")


def boolean(text: str) -> bool:
    """true/false, 1/0, yes/no."""
    if str(text).lower() in ("true", "1", "yes"):
        return True
    if str(text).lower() in ("false", "0", "no"):
        return False
    raise argparse.ArgumentTypeError(f"must be true or false, got {text!r}")


boolean.toml = "true or false"


def path(text: str) -> str:
    """A file path (not empty)."""
    if not str(text):
        raise argparse.ArgumentTypeError("must be a file path, got ''")
    return str(text)


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def out_path(text: str) -> str:
    """A path to write to: not blank (``--out " "`` made a folder named by a space) and free of
    control characters (a pasted newline or tab)."""
    text = str(text)
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a folder or file, got {text!r}")
    if _CONTROL.search(text):
        raise argparse.ArgumentTypeError(f"must be a path without control characters (newline, tab, ...), got {text!r}")
    return text


def shard(text: str) -> tuple:
    """``K/N``: shard K of N (1 <= K <= N)."""
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be K/N with integers 1 <= K <= N, got {text!r}") from None
    if not 1 <= k <= n:
        raise argparse.ArgumentTypeError(f"must be K/N with integers 1 <= K <= N, got {text!r}")
    return k, n


def size_wxh(text: str) -> tuple:
    """``WIDTHxHEIGHT`` in pixels, 64..16384 per side (the preview's ``--size``)."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels (e.g. 1600x1000), got {text!r}") from None
    if not (64 <= w <= 16384 and 64 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT with 64..16384 px per side, got {text!r}")
    return w, h


@dataclass(frozen=True, slots=True)
class Option:
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


def show(value) -> str:
    """A default as ``--help`` shows it (None: automatic)."""
    if value is None:
        return "automatic"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return ",".join(show(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


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

def read_config(path: str, options) -> dict:
    """Read a TOML configuration of the :class:`Option` s ``options``; returns {section: {key:
    value}} validated like the flags.

    Raises
    ------
    UsageError
        Unreadable or invalid TOML, an unknown table or key, or a value a flag would reject.
    """
    import tomllib

    from ..files import read_regular_file
    sections = tuple(dict.fromkeys(o.section for o in options))
    by_key = {(o.section, o.key): o for o in options}
    try:
        raw = read_regular_file(path, limit_bytes=CONFIG_LIMIT_BYTES, what=f"--config {path}")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"--config: {path} is not valid TOML ({exc})") from None
    out = {}
    for section, table in data.items():
        if section not in sections:
            raise UsageError(f"--config: {path}: unknown table [{section}]; allowed tables are "
                             f"{', '.join(f'[{s}]' for s in sections)}")
        if not isinstance(table, dict):
            raise UsageError(f"--config: {path}: {section} must be a table ([{section}] and its keys below), "
                             f"got a {type(table).__name__}")
        for key, value in table.items():
            opt = by_key.get((section, key))
            if opt is None:
                keys = ", ".join(o.key for o in options if o.section == section)
                raise UsageError(f"--config: {path}: unknown key {key!r} in [{section}]; allowed: {keys}")
            if not _toml_type_ok(getattr(opt.parse, "toml", None), value):
                kind = getattr(opt.parse, "toml", "a string (or an array of strings)")
                raise UsageError(f"--config: {path}: [{section}] {key} must be {kind}, got {value!r}")
            try:
                out.setdefault(section, {})[key] = opt.parse(_toml_text(value))
            except argparse.ArgumentTypeError as exc:
                raise UsageError(f"--config: {path}: [{section}] {key} {exc}") from None
    return out


def config_toml(cfg: dict, sections) -> str:
    """The resolved configuration ``cfg`` ({section: {key: value}}) of the tables ``sections``
    as TOML (automatic values, None, are comments)."""
    lines = ["# orbitsynth: resolved options of this sequence. `python cli.py --config config.toml --out DIR`",
             "# renders the same bytes (execution options such as --workers are not recorded).", ""]
    for section in sections:
        lines.append(f"[{section}]")
        for key, value in cfg[section].items():
            if value is None:
                lines.append(f"# {key} = automatic")
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def add_options(p: argparse.ArgumentParser, options, defaults: dict, skip=()) -> None:
    """Add the :class:`Option` s ``options`` (but ``skip``) to the parser ``p``, one argument
    group per TOML table, each help text ending with its default (from ``defaults`` where it
    has the key) unless the help says what an unset option does."""
    groups = {}
    for o in options:
        if o.key in skip:
            continue
        g = groups.get(o.section) or groups.setdefault(o.section, p.add_argument_group(f"[{o.section}]"))
        d = defaults.get(o.key, o.default)
        # the default once: from the help text where it says what an unset option does, else shown here
        shown = "" if o.switch or d is None or "(default" in o.help else f" (default: {show(d)})"
        if o.switch:
            g.add_argument(o.flag, dest=o.key, action="store_true", default=None, help=o.help)
        else:
            metavar = o.metavar if o.metavar and getattr(o.parse, "choices", None) is None else (
                choices_metavar(o.parse, many=o.metavar == "LIST") or o.metavar)
            g.add_argument(o.flag, dest=o.key, type=o.parse, default=None, metavar=metavar, help=o.help + shown)


NORMAL_FORMATS = ("float32", "half")
"""The ``--normal-format`` choices: the normal maps' floats."""


def _output_file_options() -> tuple:
    from ..files import COMPRESSIONS
    return (
        Option("--compression", "output", choice(COMPRESSIONS), "fast",
               "how the frame's files are compressed, both lossless (the same pixels): fast (zlib level 1) or "
               "compact (float maps and masks at zlib level 6: fewer bytes, more time); docs/formats.md"),
        Option("--normal-format", "output", choice(NORMAL_FORMATS), "float32",
               "the normal maps' floats: float32, or half (16-bit, each component within 2^-11 relative of "
               "float32's)"),
    )


OUTPUT_FILE_OPTIONS = _output_file_options()
"""The ``[output]`` options of how a frame's files are stored (raytrace.files.write_image)."""
