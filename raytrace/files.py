"""Files of a rendered sequence: images (PNG and EXR encoded in memory by :mod:`.imagecodec`,
other layouts through OpenImageIO), atomic writes, the model as PLY, and the per-frame manifest
that makes an interrupted run resumable.

Atomicity
    Every file is written under a hidden temporary name in its destination folder
    (``.NAME.HOST.PID.tmpEXT``: same file system, same extension so OpenImageIO picks the
    format) and then renamed into place with :func:`os.replace`, which is atomic on POSIX. A
    killed writer leaves at most a hidden temporary file, never a truncated file under a real
    name; :func:`remove_stale_temporaries` deletes those whose writer (same host) has exited.
Manifest
    A frame is *complete* when its record ``.manifest/NNNNNN.json`` exists and every file it
    lists exists with the SHA-256 recorded there. The record is written last, after the
    frame's files, so a frame whose record is missing (or whose files were deleted or
    altered) is simply rendered again. Records hold the frame's label as well, so the
    sequence's ``labels.json`` and ``manifest.json`` can be assembled from them by whichever
    run (or shard) finds the sequence complete.
Ownership
    :class:`FolderLock` is an advisory lock (``flock``) on ``.orbitsynth.lock`` in a sequence
    folder, held by every run that writes into it and released by the kernel when the process
    ends however it ends: exclusive for a whole run, shared for shards of one sequence. A run
    that cannot take it is refused before it writes anything.
User files
    :func:`read_regular_file` and :func:`check_regular_file` accept only regular files of a
    bounded size, so that ``/dev/zero``, a FIFO or a terminal given as an input file is refused
    in one line instead of read without end.
Model
    :func:`write_model_ply` writes the rendered mesh as one binary little-endian PLY: float64
    vertices in metres (body frame), triangles, and a per-face ``ushort component`` property
    holding the instance id (component k → k + 1, as in the masks). trimesh reads it (the
    ids are in ``mesh.metadata["_ply_raw"]``); :func:`read_model_ply` reads it back exactly.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import signal
import socket
import stat
import threading

import numpy as np

from .imagecodec import PNG_FILTERS, exr_bytes, png_bytes  # encoders; re-exported

__all__ = [
    "COMPRESSIONS",
    "LOCK_NAME",
    "MANIFEST_DIR",
    "PNG_FILTERS",
    "FolderLock",
    "FolderLockBusy",
    "atomic_write_bytes",
    "atomic_write_image",
    "atomic_write_text",
    "check_regular_file",
    "create_new_text",
    "exr_bytes",
    "frame_complete",
    "image_settings",
    "is_temporary",
    "model_ply_bytes",
    "png_bytes",
    "process_folder",
    "read_frame_record",
    "read_image",
    "read_model_ply",
    "read_regular_file",
    "remove_stale_process_folders",
    "remove_stale_temporaries",
    "sha256_file",
    "write_files_atomically",
    "write_frame_record",
    "write_image",
]

MANIFEST_DIR = ".manifest"
"""Sub-folder of a sequence holding one JSON record per complete frame."""
LOCK_NAME = ".orbitsynth.lock"
"""The lock file of a sequence folder (:class:`FolderLock`)."""

_HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname()) or "host"
_PARTIAL = ".partial-"  # write_files_atomically's temporary folders: .partial-{host}.{pid}-XXXXXXXX
_TMP_RE = re.compile(r"^\.(?P<name>.+)\.(?P<host>[A-Za-z0-9_-]+)\.(?P<pid>\d+)\.tmp(?P<ext>\.[A-Za-z0-9]+)?$")


# --------------------------------------------------------------------------- images
# How each kind of image is stored, chosen by measurement on the main job's 48 frames
# (1280×960, one thread; benchmarks/bench_write.py, docs/formats.md "Compression"). Both choices
# are lossless. PNG: one filter for every row (PNG spec §9.2), zlib's level and strategy; EXR:
# ZIP (16 scan lines a chunk) at a zlib level. Each file is encoded here in memory (numpy and
# zlib: :func:`png_bytes`, :func:`exr_bytes`), written in one call and hashed from memory.
# "fast", medians per 1280×960 frame against OpenImageIO's writers before (CPU ms on a loaded
# 2-core machine, kB):
# * rgb (the Earth fills the background): Up, level 1, Z_RLE: 40.5 → 16.3 ms, 445 → 327 kB;
# * rgb_degraded (noise): Up, level 1, Huffman only: 43.9 → 28.2 ms, 1458 → 1300 kB; no setting
#   measured was smaller (libpng's default, every filter tried per row at level 6: 1304 kB, 17×
#   the time);
# * mask (data): Up, level 1, Z_RLE: 8.7 → 5.0 ms, 4 → 7 kB;
# * depth (EXR ZIP at level 1): 20.3 → 3.9 ms, 31 → 48 kB;
# * normal (zero on the background: ZIP at level 1 with Z_RLE): 59.0 → 13.3 ms, 80 → 87 kB (the
#   default strategy: 13.7 ms, 132 kB; on depth, whose background is inf, Z_RLE gave 495 kB).
# "compact" trades time for bytes where that buys some: EXR ZIP at level 6 (OpenEXR's own ZIP
# size, ~1.5× fast's time), masks unfiltered at level 6; rgb and rgb_degraded as fast (level 6
# saved 3 % of rgb at 5.6× the time, and nothing on the degraded frames).
COMPRESSIONS = ("fast", "compact")
"""The ``--compression`` choices: how a frame's files are compressed (both lossless)."""
# kind -> compression -> ("png" or "exr", filter (PNG), zlib level, zlib strategy)
_SETTINGS = {
    "picture": {"fast": ("png", "up", 1, "rle"), "compact": ("png", "up", 1, "rle")},
    "noisy": {"fast": ("png", "up", 1, "huffman"), "compact": ("png", "up", 1, "huffman")},
    "data": {"fast": ("png", "up", 1, "rle"), "compact": ("png", "none", 6, "default")},
    "float": {"fast": ("exr", "zip", 1, "default"), "compact": ("exr", "zip", 6, "default")},
    "sparse": {"fast": ("exr", "zip", 1, "rle"), "compact": ("exr", "zip", 6, "default")},
}


def image_settings(pixels: np.ndarray, ext: str, *, noisy: bool = False, sparse: bool = False,
                   compression: str = "fast") -> tuple:
    """How :func:`write_image` stores ``pixels`` in a ``ext`` file with ``compression``:
    ``("png", filter, level, strategy)`` (see :func:`png_bytes`) or ``("exr", compression,
    level, strategy)`` (see :func:`exr_bytes`)."""
    if compression not in COMPRESSIONS:
        raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
    if ext == ".exr":
        return _SETTINGS["sparse" if sparse else "float"][compression]
    kind = "noisy" if noisy else ("picture" if np.ndim(pixels) == 3 and np.shape(pixels)[2] == 3 else "data")
    return _SETTINGS[kind][compression]


def write_image(path: str, pixels: np.ndarray, *, noisy: bool = False, sparse: bool = False, channel_names=None,
                compression: str = "fast", half: bool = False) -> str | None:
    """Write an image, format from the extension: PNG (8/16 bit, grey or RGB) with
    :func:`png_bytes`, anything else (EXR: float32 or half) with OpenImageIO.

    Parameters
    ----------
    path : str
        Destination; its extension picks the format.
    pixels : ndarray, shape (H, W) or (H, W, C), uint8, uint16 or float32
        Pixel values, row 0 at the top. A one-channel PNG is data (instance ids) and is written
        without colour-space chunks; a three-channel one is sRGB.
    noisy : bool, keyword-only
        The image is mostly noise (a degraded camera frame): a PNG is deflated with settings
        for noise (:func:`image_settings`). The pixels are the same.
    sparse : bool, keyword-only
        The image is zero on most pixels (the normals' background): an EXR is deflated with
        zlib's Z_RLE strategy, fewer bytes in the same time. The pixels are the same.
    channel_names : sequence of str, optional, keyword-only
        The channels' names (one per channel; OpenEXR layers as ``layer.R``); default
        OpenImageIO's (R, G, B, A, …).
    compression : {"fast", "compact"}, keyword-only
        Both lossless: ``fast`` for the time of a frame, ``compact`` for bytes
        (:func:`image_settings`; docs/formats.md, "Compression").
    half : bool, keyword-only
        Store float32 pixels as 16-bit half floats (EXR only): each value rounded to the
        nearest half, a relative error of at most 2⁻¹¹ in the normal range of half (magnitudes
        6.1e-5 … 65504; below, an absolute error of at most 2⁻²⁵).

    Returns
    -------
    str or None
        The SHA-256 of the file's bytes where they were made in memory (PNG, float EXR), else
        None (the others are written by OpenImageIO).

    Notes
    -----
    No time stamp is written (OpenEXR would store the capture date), so equal pixels give
    byte-identical files.

    Raises
    ------
    OSError
        If the file cannot be created or written.
    ValueError
        If ``pixels`` has another dtype or shape, or an option another value.
    """
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.ndim != 3:
        raise ValueError(f"pixels must have shape (H, W) or (H, W, C), got {pixels.shape}")
    if pixels.dtype not in (np.uint8, np.uint16, np.float32):
        raise ValueError(f"pixels must be uint8, uint16 or float32, got {pixels.dtype}")
    ext = os.path.splitext(path)[1].lower()
    settings = image_settings(pixels, ext, noisy=noisy, sparse=sparse, compression=compression)
    if half and (ext != ".exr" or pixels.dtype != np.float32):
        raise ValueError(f"half floats are for float32 pixels in an EXR file, got {pixels.dtype} in {ext or path}")
    data = None
    if ext == ".png" and pixels.dtype != np.float32 and pixels.shape[2] in (1, 3):
        _, filt, level, strategy = settings
        data = png_bytes(pixels, srgb=pixels.shape[2] == 3, filter=filt, level=level, strategy=strategy)
    elif ext == ".exr" and pixels.dtype == np.float32:
        _, comp, level, strategy = settings
        data = exr_bytes(pixels, channel_names=channel_names, half=half, compression=comp, level=level,
                         strategy=strategy)
    if data is not None:
        try:
            with open(path, "wb") as fh:
                fh.write(data)
        except OSError as exc:
            raise OSError(f"cannot write {path}: {exc.strerror or exc}") from None
        return hashlib.sha256(data).hexdigest()
    _write_oiio(path, pixels, settings, channel_names, half)
    return None


def _write_oiio(path: str, pixels: np.ndarray, settings: tuple, channel_names, half: bool) -> None:
    import OpenImageIO as oiio
    formats = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16, np.dtype(np.float32): oiio.FLOAT}
    out = oiio.ImageOutput.create(path)
    if out is None:
        raise OSError(f"cannot create {path}: {oiio.geterror()}")
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else formats[pixels.dtype])
    if channel_names is not None:
        names = [str(n) for n in channel_names]
        if len(names) != c:
            raise ValueError(f"channel_names must name the {c} channels, got {len(names)} names")
        spec.channelnames = names
    if path.endswith(".png") and c == 1:  # data (instance ids): no sRGB/gAMA/cHRM chunks a viewer would apply
        spec.attribute("oiio:ColorSpace", "Raw")
    if settings[0] == "exr":
        spec.attribute("compression", f"{settings[1]}:{settings[2]}")
        spec.attribute("DateTime", "")  # no capture date: the same pixels give the same bytes
    pixels = np.ascontiguousarray(pixels)
    with _signals_deferred():
        ok = out.open(path, spec) and out.write_image(pixels)
        err = out.geterror()
        out.close()
    if not ok:
        raise OSError(f"cannot write {path}: {err}")


@contextlib.contextmanager
def _signals_deferred():
    """The Python handlers of SIGINT, SIGTERM and SIGHUP held back until the block ends. An
    OpenImageIO writer interrupted between ``open`` and ``write_image`` (a pool worker's
    SIGTERM raises there, ``raytrace.dataset.pool._worker_stop``) is closed by its destructor
    with no pixels written, and libpng then prints "No IDATs written into file" on stderr: a second line
    beside the CLI's one-line message. Held back, a signal that arrives meanwhile is raised
    again as the block ends, after ``close`` (the caller then removes the complete temporary
    file as it would a partial one). Python runs handlers in the main thread only, so
    elsewhere there is nothing to hold back; nor for a signal without a Python handler (its
    default action does not run Python code)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []
    held = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None and callable(signal.getsignal(sig)):
            held[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(pending):
            signal.raise_signal(sig)


def read_image(path: str) -> np.ndarray:
    """Read an image with OpenImageIO in its stored data type (uint8, uint16 or float32):
    shape (H, W) for one channel, (H, W, C) otherwise. Raises OSError if unreadable."""
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise OSError(f"cannot read {path}: {buf.geterror()}")
    fmt = buf.spec().format.basetype
    oiio_fmt = {oiio.UINT8: oiio.UINT8, oiio.UINT16: oiio.UINT16}.get(fmt, oiio.FLOAT)
    pixels = buf.get_pixels(oiio_fmt)
    if buf.has_error or pixels is None:
        raise OSError(f"cannot read {path}: {buf.geterror()}")
    return pixels[..., 0] if pixels.shape[-1] == 1 else pixels


# --------------------------------------------------------------------------- atomic writes
def _temporary(path: str) -> str:
    folder, name = os.path.split(path)
    stem, ext = os.path.splitext(name)
    return os.path.join(folder, f".{stem}.{_HOST}.{os.getpid()}.tmp{ext}")


def _replace(tmp: str, path: str) -> None:
    try:
        os.replace(tmp, path)
    except BaseException:
        _unlink(tmp)
        raise


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def atomic_write_image(path: str, pixels: np.ndarray, **options) -> str:
    """:func:`write_image` (with its keyword ``options``) to a temporary name in the same folder,
    then rename into place; returns the SHA-256 of the file's bytes."""
    tmp = _temporary(path)
    try:
        digest = write_image(tmp, pixels, **options)
        if digest is None:
            digest = sha256_file(tmp)
    except BaseException:
        _unlink(tmp)
        raise
    _replace(tmp, path)
    return digest


def _write_synced(fh, data: bytes) -> None:
    """Write ``data`` to the open binary file ``fh`` and have it on disk before returning."""
    fh.write(data)
    fh.flush()
    os.fsync(fh.fileno())


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to a temporary name in the same folder, fsync, then rename into place."""
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as fh:
            _write_synced(fh, data)
    except BaseException:
        _unlink(tmp)
        raise
    _replace(tmp, path)


def atomic_write_text(path: str, text: str) -> None:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))


def create_new_text(path: str, text: str) -> bool:
    """Create ``path`` holding the UTF-8 ``text`` only if no file of that name exists, in one
    step: written (and fsynced) under a temporary name, then hard-linked into place, which fails
    if the name is taken, so of several processes creating it at once exactly one does and the
    others find its complete content. Returns True if this call created it, False if it
    existed. Where the file system has no hard links, ``O_EXCL`` creation decides instead.

    Raises
    ------
    OSError
        If the file cannot be written.
    """
    data = text.encode("utf-8")
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as fh:
            _write_synced(fh, data)
        try:
            os.link(tmp, path)
            return True
        except FileExistsError:
            return False
        except OSError:  # no hard links here
            pass
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            return False
        try:
            with os.fdopen(fd, "wb") as fh:
                _write_synced(fh, data)
        except BaseException:
            _unlink(path)
            raise
        return True
    finally:
        _unlink(tmp)


def is_temporary(name: str) -> bool:
    """Whether a file name is one of this module's temporary names (``.NAME.HOST.PID.tmpEXT``)."""
    return _TMP_RE.match(name) is not None


def remove_stale_temporaries(folder: str) -> int:
    """Delete temporary files left under ``folder`` (recursively) by writers on this host that
    are no longer running; returns how many were removed. Temporaries of live processes and
    of other hosts are kept (another shard may be writing them)."""
    removed = 0
    for root, _dirs, names in os.walk(folder):
        for name in names:
            m = _TMP_RE.match(name)
            if m is None or m["host"] != _HOST or _alive(int(m["pid"])):
                continue
            _unlink(os.path.join(root, name))
            removed += 1
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _stale_owner(name: str, prefix: str) -> bool:
    """Whether ``name`` is ``{prefix}{host}.{pid}-…`` of a process on this host that is no
    longer running."""
    if not name.startswith(prefix):
        return False
    m = re.match(r"(?P<host>[A-Za-z0-9_-]+)\.(?P<pid>\d+)-", name[len(prefix):])
    return m is not None and m["host"] == _HOST and not _alive(int(m["pid"]))


def process_folder(prefix: str, dir: str | None = None) -> str:
    """A new private folder ``{prefix}{host}.{pid}-XXXXXXXX`` in ``dir`` (default: the
    temporary directory), named after this host and process so that
    :func:`remove_stale_process_folders` can tell when its owner is gone (killed before it could
    remove it)."""
    import tempfile
    return tempfile.mkdtemp(prefix=f"{prefix}{_HOST}.{os.getpid()}-", dir=dir)


def remove_stale_process_folders(prefix: str, dir: str | None = None) -> int:
    """Delete this user's folders of :func:`process_folder` in ``dir`` (default: the temporary
    directory) whose process, on this host, is no longer running; returns how many. Folders of
    live processes and of other hosts are kept."""
    import shutil
    import tempfile
    parent = tempfile.gettempdir() if dir is None else dir
    try:
        names = os.listdir(parent)
    except OSError:
        return 0
    uid = getattr(os, "getuid", lambda: None)()
    removed = 0
    for name in names:
        path = os.path.join(parent, name)
        if not _stale_owner(name, prefix):
            continue
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if not stat.S_ISDIR(st.st_mode) or (uid is not None and st.st_uid != uid):
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed += not os.path.exists(path)
    return removed


def write_files_atomically(out_dir: str, files: dict, texts: dict) -> None:
    """Write every file into ``out_dir`` or none: all go to a hidden temporary folder first,
    then are moved into place; on any failure the temporary folder is removed.

    Parameters
    ----------
    out_dir : str
        Destination folder, created if missing.
    files : dict of str to ndarray
        Relative path → pixels (see :func:`write_image`).
    texts : dict of str to str
        Relative path → UTF-8 text.

    Raises
    ------
    OSError
        With a one-line message naming the folder.
    """
    import shutil
    try:
        os.makedirs(out_dir, exist_ok=True)
        remove_stale_process_folders(_PARTIAL, out_dir)  # left by a writer that was killed
        tmp = process_folder(_PARTIAL, out_dir)
    except OSError as exc:
        raise OSError(f"cannot create {out_dir} ({exc.strerror})") from None
    try:
        for rel, pixels in files.items():
            os.makedirs(os.path.join(tmp, os.path.dirname(rel)), exist_ok=True)
            write_image(os.path.join(tmp, rel), pixels)
        for rel, text in texts.items():
            with open(os.path.join(tmp, rel), "w", encoding="utf-8") as fh:
                fh.write(text)
        # every destination's folder made, and checked, before the first file moves: a file
        # where a folder must go (or a folder where a file must go) fails here, with nothing
        # moved into place yet
        names = list(files) + list(texts)
        for rel in names:
            dst = os.path.join(out_dir, rel)
            if os.path.isdir(dst):
                raise OSError(f"{dst} is a folder")
            folder = os.path.dirname(dst) or out_dir
            while not os.path.exists(folder):  # to be made: its nearest existing parent must be a folder
                folder = os.path.dirname(folder)
            if not os.path.isdir(folder):
                raise OSError(f"{folder} is in the way of a folder")
            if not os.access(folder, os.W_OK | os.X_OK):
                raise OSError(f"{folder} is not writable")
        for rel in names:
            os.makedirs(os.path.dirname(os.path.join(out_dir, rel)) or out_dir, exist_ok=True)
        for rel in names:
            os.replace(os.path.join(tmp, rel), os.path.join(out_dir, rel))
    except OSError as exc:
        raise OSError(f"cannot write into {out_dir} ({exc})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------- user files
_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _size_text(n: int) -> str:
    return f"{n / 2**20:g} MiB" if n < 2**30 else f"{n / 2**30:g} GiB"


def check_regular_file(path, *, limit_bytes: int, what: str) -> int:
    """Check that ``path`` is a regular file (a symbolic link to one is fine) of at most
    ``limit_bytes``, without opening it (a FIFO would block); returns its size.

    Raises
    ------
    ValueError
        One line starting with ``what`` (e.g. ``"--config /dev/zero"``): missing, unreadable,
        not a regular file, or too large.
    """
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ValueError(f"{what}: cannot read it ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{what}: must be a regular file, but it is {_kind(st.st_mode)}")
    if st.st_size > limit_bytes:
        raise ValueError(f"{what}: must be at most {_size_text(limit_bytes)}, but it holds {st.st_size} bytes")
    return int(st.st_size)


def read_regular_file(path, *, limit_bytes: int, what: str) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit_bytes`` (checked on the
    open file too, and no more than ``limit_bytes + 1`` bytes are read: a file that grows, or
    a path swapped for a device after :func:`check_regular_file`, cannot make it read without
    end). Opened non-blocking, so a FIFO without a writer does not hang the caller.

    Raises
    ------
    ValueError
        One line starting with ``what``, as :func:`check_regular_file`.
    """
    check_regular_file(path, limit_bytes=limit_bytes, what=what)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise ValueError(f"{what}: cannot read it ({exc.strerror or exc})") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ValueError(f"{what}: must be a regular file, but it is {_kind(mode)}")
        chunks, size = [], 0
        while size <= limit_bytes:
            block = os.read(fd, min(1 << 20, limit_bytes + 1 - size))
            if not block:
                break
            chunks.append(block)
            size += len(block)
    except OSError as exc:
        raise ValueError(f"{what}: cannot read it ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if size > limit_bytes:
        raise ValueError(f"{what}: must be at most {_size_text(limit_bytes)}, but it holds more")
    return b"".join(chunks)


# --------------------------------------------------------------------------- folder ownership
class FolderLockBusy(Exception):
    """Another process holds the lock of the folder."""


class FolderLock:
    """An advisory lock on ``folder/.orbitsynth.lock`` (``fcntl.flock``): the kernel releases
    it when the process ends, however it ends (SIGKILL included), so it never goes stale.

    ``shared=False`` (a whole run): no other holder at all. ``shared=True`` (one shard of a
    sequence): other shared holders are allowed, an exclusive one is not.

    The lock file is created if missing. :meth:`release` with ``remove=True`` deletes it where
    this process can hold the lock alone (never from under another holder); a process that
    locked the file just before it was deleted sees that the path no longer names the file it
    locked and locks the new one instead (:meth:`acquire`), so a deleted lock file cannot let
    two runs in.

    On file systems without ``flock`` (some cluster file systems mount without it) the lock
    cannot be taken: :attr:`unsupported` then holds the reason and the run goes on unguarded.
    NFS clients on Linux map ``flock`` to the server's byte-range locks, which hold across
    hosts.
    """

    def __init__(self, folder: str, *, shared: bool):
        self.path = os.path.join(folder, LOCK_NAME)
        self.shared = bool(shared)
        self.fd: int | None = None
        self.created = False
        self.unsupported: str | None = None

    def acquire(self) -> None:
        """Take the lock without waiting.

        Raises
        ------
        FolderLockBusy
            Another process holds it (exclusively, or at all when this one is exclusive).
        OSError
            The lock file cannot be created or opened.
        """
        import errno
        import fcntl
        mode = (fcntl.LOCK_SH if self.shared else fcntl.LOCK_EX) | fcntl.LOCK_NB
        for _ in range(100):  # the file replaced between open and lock: open the new one
            created = False
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
                created = True
            except FileExistsError:
                fd = os.open(self.path, os.O_RDWR)
            try:
                fcntl.flock(fd, mode)
            except OSError as exc:
                os.close(fd)  # a file this process created stays: another may have opened it since
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise FolderLockBusy(self.path) from None
                if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                    if created:  # nobody can hold it: leave no file behind
                        _unlink(self.path)
                    self.unsupported = exc.strerror or str(exc)
                    return
                raise
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self.fd, self.created = fd, created
                return
            os.close(fd)  # deleted by its last holder after this process opened it
        raise FolderLockBusy(self.path)

    def try_exclusive(self) -> bool:
        """Whether this shared lock could be made exclusive at once (no other process holds
        it); True if already exclusive. If not, the lock may be lost (``flock`` converts by
        releasing first), so only for a process about to let go of the folder."""
        import fcntl
        if self.fd is None:
            return False
        if not self.shared:
            return True
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False
        self.shared = False
        return True

    def release(self, *, remove: bool = False) -> None:
        """Release the lock; with ``remove``, delete the lock file first if no other process
        holds it (a shared holder tries to take it alone, without waiting). Idempotent."""
        if self.fd is None:
            return
        try:
            if remove and self.try_exclusive():
                _unlink(self.path)
        finally:
            os.close(self.fd)  # releases the lock
            self.fd = None


# --------------------------------------------------------------------------- checksums and manifest
def sha256_file(path: str) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _record_path(seq_dir: str, frame: int) -> str:
    return os.path.join(seq_dir, MANIFEST_DIR, f"{frame:06d}.json")


def write_frame_record(seq_dir: str, frame: int, record: dict) -> None:
    """Atomically write the manifest record of a frame whose files are all in place.

    ``record`` must hold ``"files"``: relative path → SHA-256 (see :func:`sha256_file`)."""
    if not isinstance(record.get("files"), dict):
        raise TypeError("record must hold 'files': a dict of relative path -> sha256")
    os.makedirs(os.path.join(seq_dir, MANIFEST_DIR), exist_ok=True)
    atomic_write_text(_record_path(seq_dir, frame), json.dumps(record, indent=1, allow_nan=False) + "\n")


def read_frame_record(seq_dir: str, frame: int) -> dict | None:
    """The manifest record of a frame, or None if it is missing or unreadable."""
    try:
        with open(_record_path(seq_dir, frame), encoding="utf-8") as fh:
            record = json.load(fh)
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("files"), dict) else None


def frame_complete(seq_dir: str, frame: int, *, verify: bool = True) -> dict | None:
    """The frame's record if the frame is complete (every listed file present and, with
    ``verify``, with the recorded SHA-256), else None."""
    record = read_frame_record(seq_dir, frame)
    if record is None:
        return None
    for rel, digest in record["files"].items():
        path = os.path.join(seq_dir, rel)
        if not os.path.isfile(path):
            return None
        if verify and sha256_file(path) != digest:
            return None
    return record


# --------------------------------------------------------------------------- model
_PLY_FACE = np.dtype([("n", "u1"), ("i", "<i4", (3,)), ("c", "<u2")])


def model_ply_bytes(model) -> bytes:
    """The target's mesh as binary PLY bytes: float64 vertices [m] in the body frame,
    triangles, and a per-face ``component`` property (instance id, component k → k + 1)."""
    verts, faces, comp = [], [], []
    base = 0
    for k, c in enumerate(model.components):
        v = np.asarray(c.mesh.vertices, dtype=np.float64)
        f = np.asarray(c.mesh.faces, dtype=np.int64)
        verts.append(v)
        faces.append(f + base)
        comp.append(np.full(len(f), k + 1, dtype=np.uint16))
        base += len(v)
    V = np.concatenate(verts)
    F = np.concatenate(faces)
    names = " ".join(c.name for c in model.components)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"comment orbitsynth target {model.name}: body frame, metres; face property component = "
              "instance id (component k -> k + 1)\n"
              f"comment components {names}\n"
              f"element vertex {len(V)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nproperty ushort component\n"
              "end_header\n").encode("ascii")
    rec = np.zeros(len(F), dtype=_PLY_FACE)
    rec["n"] = 3
    rec["i"] = F
    rec["c"] = np.concatenate(comp)
    return header + V.astype("<f8").tobytes() + rec.tobytes()


def read_model_ply(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a PLY written by :func:`model_ply_bytes`: vertices (n, 3) float64 [m], faces
    (m, 3) int64 and component ids (m,) uint16. Raises ValueError on another layout."""
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    counts = {ln.split()[1]: int(ln.split()[2]) for ln in header if ln.startswith("element ")}
    if "property ushort component" not in header or "property double x" not in header:
        raise ValueError(f"{path}: not an orbitsynth model PLY (double vertices, ushort component)")
    body = data[end + len(b"end_header\n"):]
    nv, nf = counts["vertex"], counts["face"]
    V = np.frombuffer(body, dtype="<f8", count=3 * nv).reshape(nv, 3).astype(np.float64)
    rec = np.frombuffer(body, dtype=_PLY_FACE, count=nf, offset=24 * nv)
    return V, rec["i"].astype(np.int64), rec["c"].astype(np.uint16)
