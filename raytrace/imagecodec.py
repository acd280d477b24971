"""Image files encoded in memory, for speed: PNG (8/16-bit grey or RGB) and OpenEXR (float32 or
half, scan lines, uncompressed or ZIP), with numpy and zlib (zlib-ng where it writes the same
bytes). :func:`raytrace.files.write_image` writes a frame's files with them (one write, the
checksum taken from memory); OpenImageIO reads them, and writes what they do not cover.
tests/test_files_compression.py reads every setting back with other decoders (libpng through
OpenCV, Pillow, OpenEXR through OpenImageIO).
"""

from __future__ import annotations

import zlib

import numpy as np

try:  # zlib-ng's binding (python-zlib-ng): the same streams for the strategies below, faster
    from zlib_ng import zlib_ng as _zlib_ng
except ImportError:  # pragma: no cover - a platform without its wheel: zlib itself, the same bytes
    _zlib_ng = None

__all__ = ["PNG_FILTERS", "ZLIB_STRATEGIES", "exr_bytes", "png_bytes"]

PNG_FILTERS = ("none", "sub", "up")
"""The PNG row filters :func:`png_bytes` applies (PNG spec §9.2, filter types 0, 1, 2)."""
ZLIB_STRATEGIES = {"default": 0, "filtered": 1, "huffman": 2, "rle": 3}
"""zlib's strategies by name (Z_DEFAULT_STRATEGY, Z_FILTERED, Z_HUFFMAN_ONLY, Z_RLE)."""


def _compressor(level: int, strategy: str):
    """A deflate compressor (zlib format, 32 KiB window, memLevel 9) at ``level`` with
    ``strategy``. zlib-ng, where installed, for ``huffman`` and ``rle`` at levels 1–9: it writes
    zlib's own stream for them, byte for byte (tests/test_files_compression.py checks it), in
    about half the time (a main-job frame's five files 97 → 53 ms, BENCHMARKS.md "Writing the
    frames"). Other strategies and level 0 take zlib itself: zlib-ng's ``default`` level 1 is
    another, larger stream."""
    if _zlib_ng is not None and strategy in ("huffman", "rle") and level >= 1:
        return _zlib_ng.compressobj(int(level), _zlib_ng.DEFLATED, 15, 9, ZLIB_STRATEGIES[strategy])
    return zlib.compressobj(int(level), zlib.DEFLATED, 15, 9, ZLIB_STRATEGIES[strategy])


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")


# the colour chunks of an sRGB image (PNG spec §11.3.3.5: with sRGB, a gAMA of 1/2.2 and the
# sRGB primaries' cHRM for decoders that do not know sRGB), as OpenImageIO writes them
_SRGB_CHUNKS = (_png_chunk(b"sRGB", b"\x03") + _png_chunk(b"gAMA", (45455).to_bytes(4, "big"))
                + _png_chunk(b"cHRM", b"".join(int(v).to_bytes(4, "big") for v in
                                               (31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))))


def png_bytes(pixels: np.ndarray, *, srgb: bool, filter: str = "up", level: int = 6,
              strategy: str = "default") -> bytes:
    """A PNG file's bytes (PNG spec, ISO/IEC 15948:2004 / W3C PNG 3rd ed., https://www.w3.org/TR/png-3/):
    8- or 16-bit greyscale or RGB, not interlaced, every row filtered with ``filter`` and the
    whole deflated by zlib at ``level`` with ``strategy``.

    Parameters
    ----------
    pixels : ndarray, shape (H, W) or (H, W, 3), uint8 or uint16
        Row 0 at the top.
    srgb : bool
        Write the sRGB, gAMA and cHRM chunks (a colour picture); without them the samples are data.
    filter : {"none", "sub", "up"}
        PNG filter type 0, 1 or 2 for every row (§9.2), applied to the bytes of the big-endian
        samples as the spec defines it.
    level : int, 0–9
        zlib compression level.
    strategy : {"default", "filtered", "huffman", "rle"}
        zlib's strategy (Z_DEFAULT_STRATEGY, Z_FILTERED, Z_HUFFMAN_ONLY, Z_RLE): ``huffman``
        codes the bytes without matches, ``rle`` with matches at distance one only; both are
        faster than ``default`` and lose little on noise or on rows predicted by ``up``.

    Raises
    ------
    ValueError
        Another dtype, shape, filter, level or strategy.
    """
    px = np.asarray(pixels)
    if px.ndim == 3 and px.shape[2] == 1:
        px = px[:, :, 0]
    if px.dtype not in (np.uint8, np.uint16) or not (px.ndim == 2 or (px.ndim == 3 and px.shape[2] == 3)):
        raise ValueError(f"pixels must be uint8 or uint16 of shape (H, W) or (H, W, 3), got {px.dtype} {px.shape}")
    if filter not in PNG_FILTERS:
        raise ValueError(f"filter must be one of {', '.join(PNG_FILTERS)}, got {filter!r}")
    if strategy not in ZLIB_STRATEGIES:
        raise ValueError(f"strategy must be one of {', '.join(ZLIB_STRATEGIES)}, got {strategy!r}")
    if not (isinstance(level, (int, np.integer)) and 0 <= level <= 9):
        raise ValueError(f"level must be an integer in [0, 9], got {level!r}")
    h, w = px.shape[:2]
    channels = 1 if px.ndim == 2 else 3
    depth = 8 * px.dtype.itemsize
    raw = np.ascontiguousarray(px, dtype=px.dtype.newbyteorder(">")).view(np.uint8).reshape(h, -1)
    rows = np.empty((h, raw.shape[1] + 1), np.uint8)
    rows[:, 0] = PNG_FILTERS.index(filter)
    if filter == "none":
        rows[:, 1:] = raw
    elif filter == "up":  # Up(x) = Raw(x) - Prior(x) mod 256; the row above row 0 is zeros
        rows[0, 1:] = raw[0]
        np.subtract(raw[1:], raw[:-1], out=rows[1:, 1:])
    else:  # sub: Sub(x) = Raw(x) - Raw(x - bpp) mod 256, bpp bytes per pixel; zeros left of the row
        bpp = channels * px.dtype.itemsize
        rows[:, 1:bpp + 1] = raw[:, :bpp]
        np.subtract(raw[:, bpp:], raw[:, :-bpp], out=rows[:, bpp + 1:])
    z = _compressor(level, strategy)
    idat = z.compress(rows.data) + z.flush()
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes((depth, 0 if channels == 1 else 2, 0, 0, 0))
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + (_SRGB_CHUNKS if srgb else b"")
            + _png_chunk(b"IDAT", idat) + _png_chunk(b"IEND", b""))


_EXR_COMPRESSIONS = {"none": (0, 1), "zips": (2, 1), "zip": (3, 16)}  # OpenEXR's code, scan lines per chunk


def _exr_names(c: int) -> list:
    """Default channel names, as OpenImageIO gives them: Y; R, G; R, G, B; R, G, B, A, channel4, …"""
    return ["Y"] if c == 1 else ["R", "G", "B", "A"][:c] + [f"channel{i}" for i in range(4, c)]


def _exr_attr(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + len(value).to_bytes(4, "little") + value


def exr_bytes(pixels: np.ndarray, *, channel_names=None, half: bool = False, compression: str = "zip",
              level: int = 4, strategy: str = "default") -> bytes:
    """An OpenEXR file's bytes: one part, scan lines, float32 or half channels, ``none``, ``zips``
    (one scan line per chunk) or ``zip`` (16) compression (OpenEXR file layout,
    https://openexr.com/en/latest/OpenEXRFileLayout.html; ZIP: the bytes of a chunk split into
    even and odd ones, each byte stored as its difference to the previous one plus 128 mod 256,
    deflated; a chunk stored raw where that is no smaller, as OpenEXR's ``ImfZip.cpp`` does).

    Parameters
    ----------
    pixels : ndarray, shape (H, W) or (H, W, C), float32
        Row 0 at the top.
    channel_names : sequence of str, optional
        One name per channel (stored in the sorted order OpenEXR requires); default
        :func:`_exr_names`, as OpenImageIO names them.
    half : bool
        Store 16-bit half floats (each value rounded to the nearest half, ties to even).
    compression : {"none", "zips", "zip"}
    level : int, 0–9, and strategy : {"default", "filtered", "huffman", "rle"}
        zlib's, as in :func:`png_bytes`.

    Raises
    ------
    ValueError
        Another dtype or shape, names or option.
    """
    px = np.asarray(pixels)
    if px.ndim == 2:
        px = px[:, :, None]
    if px.dtype != np.float32 or px.ndim != 3:
        raise ValueError(f"pixels must be float32 of shape (H, W) or (H, W, C), got {px.dtype} {px.shape}")
    h, w, c = px.shape
    names = [str(n) for n in channel_names] if channel_names is not None else _exr_names(c)
    if len(names) != c:
        raise ValueError(f"channel_names must name the {c} channels, got {len(names)} names")
    if len(set(names)) != c or not all(0 < len(n) <= 31 for n in names):
        raise ValueError(f"channel_names must name the {c} channels with distinct names of 1-31 characters, "
                         f"got {names}")
    if compression not in _EXR_COMPRESSIONS:
        raise ValueError(f"compression must be one of {', '.join(_EXR_COMPRESSIONS)}, got {compression!r}")
    if strategy not in ZLIB_STRATEGIES or not (isinstance(level, (int, np.integer)) and 0 <= level <= 9):
        raise ValueError(f"level must be in [0, 9] and strategy one of {', '.join(ZLIB_STRATEGIES)}, "
                         f"got {level!r}, {strategy!r}")
    code, lines = _EXR_COMPRESSIONS[compression]
    order = sorted(range(c), key=lambda i: names[i].encode())
    planar = np.empty((h, c, w), np.dtype("<f2") if half else np.dtype("<f4"))  # a scan line: channel by channel
    with np.errstate(over="ignore"):  # to half: beyond ±65504 is ±inf, as IEEE rounding makes it
        for k, i in enumerate(order):
            planar[:, k, :] = px[:, :, i]
    bits = planar.view(np.uint16 if half else np.uint32)
    raw = planar.view(np.uint8).reshape(h, -1)
    chunks, uniform = [], {}
    for y0 in range(0, h, lines):
        block = raw[y0:y0 + lines].reshape(-1)
        if code == 0:
            chunks.append(block.tobytes())
            continue
        b = bits[y0:y0 + lines]
        key = None
        if (b == b[:1, :, :1]).all():  # every channel one value in the chunk (the background): deflated once
            key = (b.shape[0], b[0, :, 0].tobytes())
            if key in uniform:
                chunks.append(uniform[key])
                continue
        half_n = (block.size + 1) // 2
        t = np.empty_like(block)
        t[:half_n] = block[0::2]
        t[half_n:] = block[1::2]
        t[1:] = np.subtract(t[1:], t[:-1]) + np.uint8(128)  # mod 256
        z = _compressor(level, strategy)
        data = z.compress(t.data) + z.flush()
        chunks.append(data if len(data) < block.size else block.tobytes())
        if key is not None:
            uniform[key] = chunks[-1]
    box = b"".join(int(v).to_bytes(4, "little", signed=True) for v in (0, 0, w - 1, h - 1))
    chlist = b"".join(names[i].encode() + b"\0" + (1 if half else 2).to_bytes(4, "little") + bytes(4)
                      + (1).to_bytes(4, "little") * 2 for i in order) + b"\0"
    header = (b"v/1\x01" + (2).to_bytes(4, "little") + _exr_attr("channels", "chlist", chlist)
              + _exr_attr("compression", "compression", bytes((code,))) + _exr_attr("dataWindow", "box2i", box)
              + _exr_attr("displayWindow", "box2i", box) + _exr_attr("lineOrder", "lineOrder", b"\0")
              + _exr_attr("pixelAspectRatio", "float", np.float32(1).tobytes())
              + _exr_attr("screenWindowCenter", "v2f", bytes(8))
              + _exr_attr("screenWindowWidth", "float", np.float32(1).tobytes()) + b"\0")
    offsets, pos = [], len(header) + 8 * len(chunks)
    for k, data in enumerate(chunks):
        offsets.append(pos)
        pos += 8 + len(data)
    body = b"".join((k * lines).to_bytes(4, "little") + len(data).to_bytes(4, "little") + data
                    for k, data in enumerate(chunks))
    return header + np.asarray(offsets, "<u8").tobytes() + body
