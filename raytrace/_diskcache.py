"""A persistent on-disk cache of what does not change between runs (a target's scene with its
radiance cache, the GGX split-sum table), so that a run does not rebuild it.

Location: ``$ORBITSYNTH_CACHE_DIR`` if set (set and empty: no cache), else the platform's cache
folder (``$XDG_CACHE_HOME/orbitsynth``, ``~/.cache/orbitsynth``; ``~/Library/Caches/orbitsynth`` on
macOS, ``%LOCALAPPDATA%/orbitsynth/Cache`` on Windows). A folder that cannot be created or
written only disables the cache: nothing here raises.

Never stale: an entry's name is a digest of its key, and every key includes :func:`code_version`
— the source of every module of :mod:`raytrace`, the versions of the libraries whose results or
pickles it holds (NumPy, numba, llvmlite, embreex, trimesh, Python) and this machine's CPU as
numba compiles for it. Each file carries its key's digest, its length and the SHA-256 of its
payload: a truncated, corrupt or foreign file reads as absent and is written anew. Writes go to
a temporary name in the same folder and are renamed into place (atomic), so processes that
write the same entry at once each leave a complete file and readers never see half of one.
The cache keeps the :data:`KEEP` most recently used entries of each kind. A scene (gigabytes for
a user's CAD mesh) is stored with its arrays out of band (:func:`dump_buffers`) and mapped, not
read (:func:`read_mapped`, :func:`load_buffers`): the processes that load it share its pages.
Entries are never rewritten in place, only replaced, so a mapped file never changes under a reader.
"""

from __future__ import annotations

import functools
import hashlib
import os
import struct
import sys

MAGIC = b"orbitsynth-cache-1\n"
_HEADER = struct.Struct("<32sQ32s")  # key digest, payload length, payload SHA-256
KEEP = 6
"""Entries of each kind kept (the most recently used): a scene of a built-in target is ~100 MB."""


def cache_dir() -> str | None:
    """The cache folder (created), or None when caching is off or the folder is unusable."""
    env = os.environ.get("ORBITSYNTH_CACHE_DIR")
    if env is not None:
        path = env
    elif sys.platform == "darwin":
        path = os.path.join(os.path.expanduser("~"), "Library", "Caches", "orbitsynth")
    elif os.name == "nt":
        base = os.environ.get("LOCALAPPDATA") or os.path.join(os.path.expanduser("~"), "AppData", "Local")
        path = os.path.join(base, "orbitsynth", "Cache")
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "orbitsynth")
    if not path:
        return None
    try:
        os.makedirs(path, exist_ok=True)
        return path if os.access(path, os.W_OK | os.X_OK) else None
    except OSError:
        return None


@functools.cache
def code_version() -> bytes:
    """Digest of what a cached entry's bytes depend on besides its own key: the source of every
    module of :mod:`raytrace`, the library versions and the CPU numba compiles for."""
    h = hashlib.sha256(MAGIC)
    root = os.path.dirname(os.path.abspath(__file__))
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in sorted(filenames):
            if name.endswith(".py"):
                path = os.path.join(dirpath, name)
                with open(path, "rb") as fh:
                    h.update(os.path.relpath(path, root).encode() + b"\0" + fh.read() + b"\0")
    versions = [sys.version, sys.byteorder]
    for mod in ("numpy", "numba", "llvmlite", "embreex", "trimesh"):
        try:  # the loaded module's own, else the installed distribution's (without importing it)
            version = getattr(sys.modules.get(mod), "__version__", None)
            if version is None:
                from importlib.metadata import version as dist_version
                version = dist_version(mod)
        except Exception:  # noqa: BLE001 - not installed
            version = "-"
        versions.append(f"{mod} {version}")
    try:  # the CPU numba compiles for (its import initialises LLVM; NUMBA_CPU_NAME may override it)
        import llvmlite.binding as ll
        from numba.core import config
        versions.append(f"{config.CPU_NAME} {config.CPU_FEATURES} {ll.get_host_cpu_name()} "
                        f"{ll.get_host_cpu_features().flatten()}")
    except Exception:  # noqa: BLE001 - numba's internals: without them, the machine's name
        import platform
        versions.append(f"{platform.machine()} {platform.processor()}")
    h.update("\n".join(versions).encode())
    return h.digest()


def key_digest(kind: str, *parts: bytes) -> bytes:
    """SHA-256 of an entry's kind, :func:`code_version` and ``parts``."""
    h = hashlib.sha256(kind.encode() + b"\0" + code_version())
    for p in parts:
        h.update(struct.pack("<Q", len(p)) + p)
    return h.digest()


def entry_path(kind: str, key: bytes, folder: str | None = None) -> str | None:
    """The file of the entry ``kind`` (a name: letters and ``_``) with key digest ``key`` in
    ``folder`` (default :func:`cache_dir`); None without a cache."""
    folder = folder or cache_dir()
    return None if folder is None else os.path.join(folder, f"{kind}-{key.hex()[:40]}.bin")


def _header_ok(fh, key: bytes | None) -> tuple | None:
    head = fh.read(len(MAGIC) + _HEADER.size)
    if len(head) != len(MAGIC) + _HEADER.size or not head.startswith(MAGIC):
        return None
    digest, length, payload_sha = _HEADER.unpack(head[len(MAGIC):])
    if key is not None and digest != key:
        return None
    return length, payload_sha


def present(path: str, key: bytes) -> bool:
    """Whether ``path`` holds an entry of key digest ``key`` of its full length (its payload's
    checksum is verified by :func:`read`); marks it used."""
    try:
        with open(path, "rb") as fh:
            head = _header_ok(fh, key)
            if head is None or os.fstat(fh.fileno()).st_size != fh.tell() + head[0]:
                return False
        os.utime(path)
        return True
    except OSError:
        return False


def read(path: str, key: bytes | None = None) -> bytes | None:
    """The payload of the entry at ``path`` if it is one of key digest ``key`` (None: any key),
    complete and intact; None otherwise (absent, truncated, corrupt, another key's or not ours)."""
    try:
        with open(path, "rb") as fh:
            head = _header_ok(fh, key)
            if head is None:
                return None
            payload = fh.read(head[0] + 1)
    except OSError:
        return None
    if len(payload) != head[0] or hashlib.sha256(payload).digest() != head[1]:
        return None
    try:
        os.utime(path)
    except OSError:
        pass
    return payload


def read_mapped(path: str, key: bytes | None = None) -> memoryview | None:
    """:func:`read` without copying the payload: a view of the file mapped into memory privately
    (copy-on-write: writable, and its pages shared with the operating system's file cache, so
    with every process that maps the same file, until one writes to them); None where
    :func:`read` would return None. For one large entry (:func:`load_buffers`)."""
    import mmap
    try:
        with open(path, "rb") as fh:
            head = _header_ok(fh, key)
            if head is None:
                return None
            start = fh.tell()
            if os.fstat(fh.fileno()).st_size != start + head[0] or head[0] == 0:
                return None
            view = memoryview(mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_COPY))[start:]
    except (OSError, ValueError):
        return None
    if hashlib.sha256(view).digest() != head[1]:
        return None
    return view


PAYLOAD_AT = len(MAGIC) + _HEADER.size
"""Where an entry's payload starts in its file [bytes]."""
ALIGN = 64
"""Alignment of the arrays :func:`dump_buffers` stores, in the file [bytes]."""
_COUNTS = struct.Struct("<QQ")  # length of the pickle stream, number of buffers; also (offset, length)


def dump_buffers(obj, fh) -> None:
    """Write ``obj`` to the payload stream ``fh`` (:func:`write_stream`'s ``dump``) as a pickle
    (protocol 5) whose contiguous NumPy arrays are stored out of band, each at an offset of the
    file that is a multiple of :data:`ALIGN`, so that :func:`load_buffers` places them on the
    mapped file without copying. Layout of the payload: the pickle stream's length and the number
    of buffers (two little-endian uint64), the stream, a table of (offset in the payload, length)
    per buffer, then the buffers (zeros between them)."""
    import pickle
    buffers = []
    stream = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    views = [b.raw() for b in buffers]
    pos = _COUNTS.size + len(stream) + _COUNTS.size * len(views)
    table = []
    for v in views:
        pos += -(PAYLOAD_AT + pos) % ALIGN
        table.append((pos, v.nbytes))
        pos += v.nbytes
    fh.write(_COUNTS.pack(len(stream), len(views)))
    fh.write(stream)
    fh.write(b"".join(_COUNTS.pack(*t) for t in table))
    at = _COUNTS.size + len(stream) + _COUNTS.size * len(views)
    for (offset, n), v in zip(table, views):
        fh.write(bytes(offset - at))
        fh.write(v)
        at = offset + n


def load_buffers(payload: memoryview):
    """The object :func:`dump_buffers` wrote, from its payload (:func:`read_mapped`'s view): its
    arrays are views of the payload's memory, not copies (writable where the view is). Raises
    ValueError where the layout does not fit the payload."""
    import pickle
    n_stream, n_buf = _COUNTS.unpack_from(payload, 0)
    table_at = _COUNTS.size + n_stream
    end = table_at + _COUNTS.size * n_buf
    if end > len(payload):
        raise ValueError("the payload is shorter than its pickle stream and buffer table")
    buffers = []
    for k in range(n_buf):
        offset, n = _COUNTS.unpack_from(payload, table_at + _COUNTS.size * k)
        if offset < end or offset + n > len(payload):
            raise ValueError(f"buffer {k} lies outside the payload")
        buffers.append(payload[offset:offset + n])
    return pickle.loads(payload[_COUNTS.size:table_at], buffers=buffers)


def write(path: str, key: bytes, payload: bytes) -> bool:
    """Store ``payload`` as the entry of key digest ``key`` at ``path`` (atomic: a temporary file
    in the same folder, renamed into place), then drop the kind's least recently used entries
    beyond :data:`KEEP`. False, leaving nothing behind, if it cannot be written."""
    return write_stream(path, key, lambda fh: fh.write(payload))


class _Hashed:
    """A file's ``write`` that also counts the bytes and takes their SHA-256."""

    def __init__(self, fh):
        self.fh, self.sha, self.n = fh, hashlib.sha256(), 0

    def write(self, data) -> int:
        self.sha.update(data)
        self.n += memoryview(data).nbytes
        return self.fh.write(data)


def write_stream(path: str, key: bytes, dump) -> bool:
    """:func:`write` of the payload that ``dump(file)`` writes (``pickle.dump``'s way): streamed to
    the file, its length and SHA-256 taken as it goes, so the payload is never whole in memory
    (a scene of a user's CAD mesh: gigabytes). False, leaving nothing behind, if it cannot be
    written; what ``dump`` raises otherwise is raised, leaving nothing behind either."""
    import tempfile
    folder, name = os.path.split(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=folder)
        with os.fdopen(fd, "wb") as fh:
            fh.write(MAGIC + _HEADER.pack(key, 0, bytes(32)))  # the header once the payload is known
            out = _Hashed(fh)
            dump(out)
            fh.seek(len(MAGIC))
            fh.write(_HEADER.pack(key, out.n, out.sha.digest()))
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        if isinstance(exc, OSError):
            return False
        raise
    _evict(folder, name.partition("-")[0])
    return True


def memoised(kind: str, parts: tuple, build, dump, load):
    """``build()``, or what an earlier process stored for the same ``kind`` and key ``parts``
    (bytes, :func:`key_digest`): ``load(payload)`` of the entry (None or an exception: unusable,
    built again); a built value is stored as ``dump(value)``. Without a cache, ``build()``."""
    key = key_digest(kind, *parts)
    path = entry_path(kind, key)
    payload = None if path is None else read(path, key)
    if payload is not None:
        try:
            value = load(payload)
        except Exception:  # noqa: BLE001 - an entry that does not decode: built again below
            value = None
        if value is not None:
            return value
    value = build()
    if path is not None:
        write(path, key, dump(value))
    return value


def discard(path: str) -> None:
    """Remove the entry at ``path`` (found broken), if it can be."""
    try:
        os.unlink(path)
    except OSError:
        pass


STALE_TEMPORARY_S = 3600.0
"""A temporary file older than this [s] is a killed writer's and is removed."""


def _evict(folder: str, kind: str) -> None:
    import time
    entries = []
    try:
        for entry in os.scandir(folder):
            if entry.name.startswith(f".{kind}-") and entry.name.endswith(".tmp"):
                try:
                    if time.time() - entry.stat().st_mtime > STALE_TEMPORARY_S:
                        os.unlink(entry.path)
                except OSError:
                    pass
            elif entry.name.startswith(kind + "-") and entry.name.endswith(".bin"):
                try:
                    entries.append((entry.stat().st_mtime, entry.path))
                except OSError:
                    pass
        for _, path in sorted(entries, reverse=True)[KEEP:]:
            os.unlink(path)
    except OSError:
        pass
