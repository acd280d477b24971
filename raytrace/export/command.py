"""``cli.py export``: many sequence folders to one dataset (BOP, SPEED+, COCO), split into
train/val/test, all or nothing, resumable.

The export is written into a staging folder beside ``--out`` (``.{name}.export-partial``) and
renamed to ``--out`` at the end. The staging folder holds ``.export.json``: the export's
arguments and the SHA-256 of each input sequence's ``labels.json``, ``camera.json``,
``manifest.json`` (when there is one) and model PLY. Interrupted (Ctrl-C, SIGTERM, a crash), the
staging folder stays; rerunning the same command on unchanged inputs continues in it (the
format writers skip what is complete, every file being written under a temporary name and
renamed), and anything else starts afresh (the stale staging folder is removed). The finished
dataset keeps ``.export.json``: rerunning a finished export says so and exits 0. Bad input (an
unknown format, a folder that is no finished sequence, a sequence given twice, a bad split)
is one line and exit status 2, with nothing written.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

from ..dataset import PROG, UsageError
from ..dataset import options as opt
from ..files import remove_stale_temporaries, sha256_file
from ._atomic import write_json
from ._read import _IMAGE_MODALITIES, _read_sequence
from .splits import SPLIT_BY, assign, parse_split_spec

__all__ = ["FORMATS", "export_main", "plan_export", "run_export"]

FORMATS = {
    # format: (module, writer, modalities every exported frame needs besides the image)
    "bop": ("bop", "write_bop", ("mask", "depth")),
    "speedplus": ("speedplus", "write_speedplus", ()),
    "coco": ("coco", "write_coco", ("mask",)),
}
ONE_CAMERA = {"speedplus"}
"""Formats with one camera.json for the whole dataset: every sequence must share K, size and distortion."""
RECORD = ".export.json"
RECORD_VERSION = 1


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors, exit status 2, no abbreviated flags."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{PROG}: error: {message}\n")


def _split_arg(text: str):
    try:
        return parse_split_spec(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=f"{PROG} export", description="Export finished sequence folders to one dataset (BOP, SPEED+ "
                "or COCO), split into subsets, all or nothing; rerunning an interrupted export continues it.")
    p.add_argument("sequences", nargs="+", type=opt.out_path, metavar="SEQ_DIR", help="sequence folders (labels.json written)")
    p.add_argument("--format", required=True, type=opt.choice(tuple(FORMATS)),
                   metavar=opt.choices_metavar(opt.choice(tuple(FORMATS))), help="dataset format")
    p.add_argument("--out", required=True, type=opt.out_path, metavar="DIR", help="new (or empty) dataset folder")
    p.add_argument("--split", type=_split_arg, default=(("train", 1.0),), metavar="NAME=SHARE[,...]",
                   help="subsets: fractions summing to 1 (train=0.8,val=0.2) or whole counts (train=90,test=10); "
                        "default train=1")
    p.add_argument("--split-by", type=opt.choice(SPLIT_BY), default="frame", metavar=opt.choices_metavar(opt.choice(SPLIT_BY)),
                   help="shuffle frames of all sequences together, or whole sequences (default: frame)")
    p.add_argument("--seed", type=opt.int_in(0, 2**63 - 1), default=0, help="seed of the shuffle (default: 0)")
    p.add_argument("--modality", type=opt.choice(_IMAGE_MODALITIES), default="rgb",
                   metavar=opt.choices_metavar(opt.choice(_IMAGE_MODALITIES)), help="which image is exported (default: rgb)")
    p.add_argument("--copy", action="store_true", help="copy the images (default: hard links where possible)")
    p.add_argument("--workers", type=opt.int_in(1, 1024), default=None,
                   help="processes writing frames (BOP; default: the usable cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _input_hashes(seq) -> dict:
    out = {}
    for name in ("labels.json", "camera.json", "manifest.json"):
        if (seq.root / name).is_file():
            out[name] = sha256_file(seq.root / name)
    out["model"] = sha256_file(seq.model_path)
    return out


def _same_camera(a, b) -> bool:
    return (a.width, a.height) == (b.width, b.height) and (a.K == b.K).all() and \
        list(a.camera.get("distCoeffs") or [0.0] * 5) == list(b.camera.get("distCoeffs") or [0.0] * 5)


def plan_export(args: argparse.Namespace) -> dict:
    """Read and check the sequences and split their frames; UsageError (one line) on bad input."""
    _, _, needs = FORMATS[args.format]
    needed = (args.modality, *needs)
    seqs, seen = [], {}
    for text in args.sequences:
        root = Path(text)
        if not root.is_dir():
            raise UsageError(f"argument SEQ_DIR: {text} is not a folder")
        if not (root / "labels.json").is_file():
            raise UsageError(f"argument SEQ_DIR: {text} is not a finished sequence folder (no labels.json: "
                             "still rendering, or interrupted; rerun its render to finish it)")
        real = os.path.realpath(root)
        if real in seen:
            raise UsageError(f"argument SEQ_DIR: {text} is given twice (also as {seen[real]})")
        seen[real] = text
        try:
            seq = _read_sequence(root)
        except ValueError as exc:
            raise UsageError(f"argument SEQ_DIR: {text}: {exc}") from None
        frames = [f for f in seq.frames if all(f.files.get(m) is not None for m in needed)]
        if not frames:
            raise UsageError(f"argument SEQ_DIR: {text}: no frame has the files {args.format} needs "
                             f"({', '.join(needed)}; rendered with --modalities including them?)")
        seqs.append((seq, frames))
    if args.format in ONE_CAMERA:
        odd = [s.root for s, _ in seqs if not _same_camera(s, seqs[0][0])]
        if odd:
            raise UsageError(f"argument SEQ_DIR: {odd[0]} has another camera (K, size or distCoeffs) than "
                             f"{seqs[0][0].root}; {args.format} has one camera.json for the whole dataset")
    if args.format == "bop":
        from .bop import _check_camera
        for seq, _ in seqs:
            try:
                _check_camera(seq)
            except ValueError as exc:
                raise UsageError(f"argument SEQ_DIR: {exc}") from None
    try:
        splits = assign([[(s, f) for f in frames] for s, frames in seqs], args.split, by=args.split_by, seed=args.seed)
    except ValueError as exc:
        raise UsageError(f"argument --split: {exc}") from None
    record = {"version": RECORD_VERSION, "format": args.format,
              "sequences": [str(Path(os.path.realpath(s.root))) for s, _ in seqs],
              "inputs": [_input_hashes(s) for s, _ in seqs],
              "split": [[name, share] for name, share in args.split], "split_by": args.split_by, "seed": args.seed,
              "modality": args.modality, "link": not args.copy}
    return {"sequences": [s for s, _ in seqs], "splits": splits, "record": record}


def _read_record(folder: Path):
    try:
        with open(folder / RECORD, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def _same(record, other) -> bool:
    return other is not None and json.loads(json.dumps(record)) == other


def _staging_path(out: Path) -> Path:
    return out.parent / f".{out.name}.export-partial"


def _writer(fmt: str):
    module, name, _ = FORMATS[fmt]
    try:
        return getattr(importlib.import_module(f"{__package__}.{module}"), name)
    except (ImportError, AttributeError):
        raise UsageError(f"argument --format: {fmt} has no writer in this installation "
                         f"(raytrace.export.{module}.{name})") from None


def run_export(args: argparse.Namespace, plan: dict, *, progress=None) -> Path | None:
    """Write the planned export: None if ``--out`` already is that finished export."""
    out = Path(args.out).absolute()
    record = plan["record"]
    if out.exists():
        if not out.is_dir():
            raise UsageError(f"argument --out: {args.out} exists and is not a folder")
        if _same(record, _read_record(out)):
            return None
        if any(out.iterdir()):
            raise UsageError(f"argument --out: {args.out} exists and is not empty (and is not this export, "
                             "finished)")
    writer = _writer(args.format)
    staging = _staging_path(out)
    created = []
    parent = out.parent
    while not parent.exists():
        created.append(parent)
        parent = parent.parent
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        lock = _lock(out)
    except OSError as exc:
        _remove(created)
        raise UsageError(f"argument --out: cannot create a folder beside {args.out} ({exc.strerror})") from None
    try:
        return _run_locked(args, plan, writer, out, staging, created, progress)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock[1])
        os.close(lock[0])


def _remove(folders: list) -> None:
    for d in folders:  # deepest first
        shutil.rmtree(d, ignore_errors=True)


def _lock(out: Path) -> tuple:
    """An exclusive ``flock`` on ``.NAME.export-lock`` beside ``out``: (fd, path); UsageError if
    another export holds it."""
    import fcntl

    path = out.parent / f".{out.name}.export-lock"
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise UsageError(f"argument --out: {out} is being exported by another run") from None
    return fd, path


def _run_locked(args, plan, writer, out: Path, staging: Path, created: list, progress) -> Path:
    record = plan["record"]
    try:
        if staging.exists() and not _same(record, _read_record(staging)):
            shutil.rmtree(staging)  # another export's, or of inputs since changed: start afresh
        staging.mkdir(exist_ok=True)
        remove_stale_temporaries(str(staging))  # of an interrupted run's processes
        write_json(staging / RECORD, record)
    except OSError as exc:
        _remove(created)
        raise UsageError(f"argument --out: cannot create {staging} ({exc.strerror})") from None
    kwargs = {}
    if args.format == "bop":
        kwargs = {"workers": args.workers, "sequences": plan["sequences"], "name": out.name}
    try:
        writer(staging, plan["splits"], modality=args.modality, link=not args.copy, progress=progress, **kwargs)
    except ValueError:  # bad input found while writing: nothing is left
        shutil.rmtree(staging, ignore_errors=True)
        _remove(created)
        raise
    remove_stale_temporaries(str(staging))  # the workers are gone: any temporary left is debris
    if out.exists():
        out.rmdir()  # empty (checked above)
    os.rename(staging, out)
    return out


def export_main(argv: list) -> int:
    """``cli.py export``: returns the exit status (0, 1 failure, 2 bad input, 128 + signal when interrupted)."""
    args = build_parser().parse_args(argv)
    t0 = time.perf_counter()
    try:
        plan = plan_export(args)
    except UsageError as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    n = sum(len(v) for v in plan["splits"].values())
    bar = None
    if not args.quiet:
        from tqdm import tqdm
        bar = tqdm(total=n, unit="frame", desc=f"export {args.format}", file=sys.stderr, leave=False)
    try:
        try:
            done = run_export(args, plan, progress=None if bar is None else bar.update)
        finally:  # the bar's line cleared before any message below
            if bar is not None:
                bar.close()
    except (UsageError, ValueError) as exc:
        sys.stderr.write(f"{PROG}: error: {exc}\n")
        return 2
    except KeyboardInterrupt as exc:
        how = f"terminated by {exc}" if getattr(exc, "signum", None) else "interrupted"
        sys.stderr.write(f"{PROG}: {how}; the finished part is kept in {_staging_path(Path(args.out).absolute())}, "
                         "rerun the same command to continue\n")
        return 128 + getattr(exc, "signum", 2)
    except Exception as exc:  # noqa: BLE001 - a failure while writing (disk full, ...): one line
        msg = " ".join(str(exc).split()) or type(exc).__name__
        sys.stderr.write(f"{PROG}: error: export failed ({type(exc).__name__}: {msg}); the finished part is kept, "
                         "rerun the same command to continue\n")
        return 1
    if done is None:
        sys.stdout.write(f"{args.out}: already this export, finished; nothing to do\n")
        return 0
    counts = ", ".join(f"{name} {len(items)}" for name, items in plan["splits"].items())
    sys.stdout.write(f"export {args.format}: {len(plan['sequences'])} sequence(s), {n} frames ({counts}) in "
                     f"{time.perf_counter() - t0:.1f} s -> {args.out}\n")
    return 0
