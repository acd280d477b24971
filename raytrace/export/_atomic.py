"""Resumable writing for the exports: every file goes to a temporary name in its folder and is
renamed into place, so a file present under its own name is complete (what a rerun after an
interruption relies on)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from ..files import _temporary

_DATA_PNG = {"png:filter": 8, "png:compressionLevel": 1, "oiio:ColorSpace": "Raw"}
"""One-channel data PNGs (depth codes, masks): no row filter, zlib level 1 — 3–4× faster than
level 6 on a 1280×960 16-bit depth image (about 12 ms), a few % more bytes on these mostly
empty images; no colour-space chunks (as bop_toolkit's ``inout.save_depth`` writes them)."""


def _commit(tmp: str, dst: Path) -> None:
    try:
        os.replace(tmp, dst)
    except BaseException:
        with _suppress():
            os.unlink(tmp)
        raise
    if os.path.lexists(tmp):  # rename(2) does nothing when both names are links of one file
        with _suppress():
            os.unlink(tmp)


class _suppress:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return exc[0] is not None and issubclass(exc[0], OSError)


def place(src: Path, dst: Path, link: bool) -> None:
    """Hard-link ``src`` to ``dst`` (or copy when linking is off or fails), atomically."""
    tmp = _temporary(str(dst))
    with _suppress():
        os.unlink(tmp)
    try:
        done = False
        if link:
            try:
                os.link(src, tmp)
                done = True
            except OSError:  # another file system, or links not supported
                pass
        if not done:
            shutil.copyfile(src, tmp)
    except BaseException:
        with _suppress():
            os.unlink(tmp)
        raise
    _commit(tmp, dst)


def write_bytes(path: Path, data: bytes) -> None:
    tmp = _temporary(str(path))
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
    except BaseException:
        with _suppress():
            os.unlink(tmp)
        raise
    _commit(tmp, path)


def write_json(path: Path, content, indent: int | None = 1) -> None:
    """JSON (finite numbers only), written atomically."""
    text = json.dumps(content, indent=indent, allow_nan=False)
    write_bytes(path, (text + "\n").encode("utf-8"))


def write_data_png(path: Path, pixels: np.ndarray) -> None:
    """A one-channel uint8/uint16 PNG with :data:`_DATA_PNG`'s settings, atomically."""
    import OpenImageIO as oiio

    pixels = np.ascontiguousarray(pixels)[:, :, None]  # (H, W, 1): a 2-D array would be taken column-major
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16}[pixels.dtype]
    tmp = _temporary(str(path))
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 1, fmt)
    for key, value in _DATA_PNG.items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(tmp)
    try:
        ok = out is not None and out.open(tmp, spec) and out.write_image(pixels)
        err = oiio.geterror() if out is None else out.geterror()
        if out is not None:
            out.close()
        if not ok:
            raise OSError(f"cannot write {path}: {err}")
    except BaseException:
        with _suppress():
            os.unlink(tmp)
        raise
    _commit(tmp, path)
