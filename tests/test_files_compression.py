"""How a frame's files are stored (raytrace.files.write_image, ``--compression``, ``--normal-format``),
against readers other than the writer:

* every PNG setting (filter × zlib level × strategy, 8/16 bit, grey/RGB) decodes to the same
  pixels in libpng (OpenCV), Pillow and OpenImageIO; its chunks' CRCs are the PNG spec's
  (CRC-32 worked out here bit by bit);
* zlib-ng, where installed, writes zlib's own bytes for the strategies it is used for;
* ``fast`` and ``compact`` write the same pixels (PNG and EXR), compact fewer bytes on a frame;
* half-float normals are within the bound the docs state (2⁻¹¹ relative, 2⁻²⁵ absolute below
  2⁻¹⁴) and equal numpy's IEEE round-to-nearest half;
* a sequence written with fast, and one with compact and half normals: same decoded pixels in
  every file, config.toml records the choice, a resume with another choice is refused, bad
  values are one line; the exports of both are equal.
"""

import io
import json
import zlib

import numpy as np
import pytest

from raytrace import files as F
from tests.cli_helpers import run_main

SMALL = ["--target", "icesat", "--pattern", "spiral", "--frames", "3", "--width", "96", "--height", "72",
         "--focal-length-mm", "0.3", "--workers", "1", "--quiet"]
MODS = "rgb,rgb_degraded,mask,depth,normal,semantic"


def _crc32(data: bytes) -> int:
    """CRC-32 of the PNG spec (ISO 3309 polynomial, reflected 0xEDB88320), bit by bit."""
    c = 0xFFFFFFFF
    for byte in data:
        c ^= byte
        for _ in range(8):
            c = (c >> 1) ^ (0xEDB88320 if c & 1 else 0)
    return c ^ 0xFFFFFFFF


def _chunks(data: bytes) -> list:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    i, out = 8, []
    while i < len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        kind, body = data[i + 4:i + 8], data[i + 8:i + 8 + n]
        out.append((kind.decode("ascii"), body, int.from_bytes(data[i + 8 + n:i + 12 + n], "big")))
        i += 12 + n
    return out


def _decoders(data: bytes, tmp_path):
    """The pixels of a PNG as OpenCV (libpng), Pillow and OpenImageIO decode it."""
    import cv2
    from PIL import Image
    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if a.ndim == 3:
        a = a[:, :, ::-1]  # OpenCV's BGR
    path = tmp_path / "x.png"
    path.write_bytes(data)
    out = {"opencv": a, "oiio": F.read_image(str(path))}
    pil = Image.open(io.BytesIO(data))
    if not (pil.mode.startswith("RGB") and a.dtype == np.uint16):  # Pillow has no 16-bit RGB mode
        out["pillow"] = np.asarray(pil).astype(a.dtype)
    return out


def _image(rng, shape, dtype):
    hi = np.iinfo(dtype).max
    px = rng.integers(0, hi, size=shape, endpoint=True).astype(dtype)
    px[: shape[0] // 3] = 0  # flat space
    px[shape[0] // 3: shape[0] // 2] = np.linspace(0, hi, shape[1], dtype=dtype)[:, None] if len(shape) == 3 else \
        np.linspace(0, hi, shape[1], dtype=dtype)  # a ramp
    return px


@pytest.mark.parametrize("shape,dtype", [((23, 31, 3), np.uint8), ((23, 31), np.uint8), ((23, 31), np.uint16),
                                         ((17, 13, 3), np.uint16)])
def test_every_png_setting_decodes_to_the_same_pixels(tmp_path, shape, dtype):
    rng = np.random.default_rng(3)
    px = _image(rng, shape, dtype)
    for filt in F.PNG_FILTERS:
        for level, strategy in ((0, "default"), (1, "huffman"), (1, "rle"), (6, "default"), (9, "filtered")):
            data = F.png_bytes(px, srgb=len(shape) == 3, filter=filt, level=level, strategy=strategy)
            for name, got in _decoders(data, tmp_path).items():
                assert got.dtype == px.dtype and np.array_equal(got, px), (name, filt, level, strategy)
            chunks = _chunks(data)
            assert [c[0] for c in chunks] == (["IHDR", "sRGB", "gAMA", "cHRM"] if len(shape) == 3 else ["IHDR"]) + \
                ["IDAT", "IEND"]
            assert all(_crc32(kind.encode() + body) == crc for kind, body, crc in chunks)
            # the filter type byte of every row is the one asked for (PNG spec §9.2: 0 none, 1 sub, 2 up)
            rows = np.frombuffer(zlib.decompress(chunks[-2][1]), np.uint8).reshape(shape[0], -1)
            assert set(rows[:, 0]) == {F.PNG_FILTERS.index(filt)}


def test_png_settings_are_checked():
    px = np.zeros((4, 4, 3), np.uint8)
    for kwargs, match in (({"filter": "paeth"}, "filter must be one of none, sub, up"),
                          ({"strategy": "fixed"}, "strategy must be one of"),
                          ({"level": 10}, r"level must be .*\[0, 9\]")):
        with pytest.raises(ValueError, match=match):
            F.png_bytes(px, srgb=True, **kwargs)
    with pytest.raises(ValueError, match="uint8 or uint16 of shape"):
        F.png_bytes(np.zeros((4, 4, 2), np.uint8), srgb=False)
    with pytest.raises(ValueError, match="compression must be one of fast, compact"):
        F.write_image("a.png", px, compression="small")
    with pytest.raises(ValueError, match="half floats are for float32 pixels in an EXR"):
        F.write_image("a.png", px, half=True)


def test_zlib_ng_writes_zlibs_own_bytes(monkeypatch):
    """Where zlib-ng is installed, the ``huffman`` and ``rle`` streams it writes (levels 1–9) are
    zlib's byte for byte, on noise, on runs, on small and empty inputs and on whole files: a file
    is the same bytes with or without it."""
    pytest.importorskip("zlib_ng")
    from raytrace import imagecodec
    assert imagecodec._zlib_ng is not None
    rng = np.random.default_rng(5)
    inputs = [b"", b"a", rng.integers(0, 256, 300_000, dtype=np.uint8).tobytes(),
              np.repeat(rng.integers(0, 256, 4000, dtype=np.uint8), 150).tobytes(),
              rng.normal(128, 3, 400_000).clip(0, 255).astype(np.uint8).tobytes(), bytes(700_000)]
    for data in inputs:
        for strategy in ("huffman", "rle"):
            for level in range(1, 10):
                ours = imagecodec._compressor(level, strategy)
                ref = zlib.compressobj(level, zlib.DEFLATED, 15, 9, imagecodec.ZLIB_STRATEGIES[strategy])
                assert type(ours).__module__ == "zlib_ng"  # not zlib's own
                assert ours.compress(data) + ours.flush() == ref.compress(data) + ref.flush(), \
                    (len(data), strategy, level)
    frame = _frame_like(rng)
    with_ng = {k: F.png_bytes(frame[k], srgb=k != "mask", filter="up", level=1, strategy=s)
               for k, s in (("rgb", "rle"), ("rgb_degraded", "huffman"), ("mask", "rle"))}
    with_ng["normal"] = F.exr_bytes(frame["normal"], channel_names=("X", "Y", "Z"), level=1, strategy="rle")
    monkeypatch.setattr(imagecodec, "_zlib_ng", None)
    assert with_ng == {k: F.png_bytes(frame[k], srgb=k != "mask", filter="up", level=1, strategy=s)
                       for k, s in (("rgb", "rle"), ("rgb_degraded", "huffman"), ("mask", "rle"))} | \
        {"normal": F.exr_bytes(frame["normal"], channel_names=("X", "Y", "Z"), level=1, strategy="rle")}


def _frame_like(rng):
    """A 160×120 frame's images: a lit disc on a textured background, noise, ids, depth, normals."""
    h, w = 120, 160
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x - 80) ** 2 + (y - 60) ** 2) / 40.0 ** 2
    inside = r2 < 1
    z = np.where(inside, np.sqrt(np.clip(1 - r2, 0, 1)), 0)
    n = np.stack([(x - 80) / 40.0, (y - 60) / 40.0, -z], axis=-1) * inside[..., None]
    shade = (np.clip(-n[..., 2], 0, 1) * 230 + (20 * np.sin(x / 7.0) * np.cos(y / 5.0) + 30) * ~inside)
    rgb = np.repeat(shade[..., None], 3, axis=2).astype(np.uint8)
    noisy = np.clip(rgb + rng.normal(0, 6, rgb.shape), 0, 255).astype(np.uint8)
    return {"rgb": rgb, "rgb_degraded": noisy, "mask": (inside * 3).astype(np.uint16),
            "depth": np.where(inside, 10.0 - z, np.inf).astype(np.float32), "normal": n.astype(np.float32)}


def test_fast_and_compact_store_the_same_pixels_compact_in_fewer_bytes(tmp_path):
    import OpenImageIO as oiio
    images = _frame_like(np.random.default_rng(5))
    sizes = {}
    for comp in F.COMPRESSIONS:
        for m, px in images.items():
            ext = ".exr" if px.dtype == np.float32 else ".png"
            path = str(tmp_path / f"{m}.{comp}{ext}")
            digest = F.atomic_write_image(path, px, noisy=m == "rgb_degraded", sparse=m == "normal", compression=comp)
            assert digest == F.sha256_file(path)
            buf = oiio.ImageBuf(path)  # a reader of its own, not raytrace.files.read_image
            back = buf.get_pixels(oiio.FLOAT if px.dtype == np.float32 else
                                  (oiio.UINT8 if px.dtype == np.uint8 else oiio.UINT16)).reshape(px.shape)
            assert np.array_equal(back, px), (m, comp)
            if ext == ".exr":
                assert buf.spec().get_string_attribute("compression") == "zip"
            sizes[m, comp] = (tmp_path / f"{m}.{comp}{ext}").stat().st_size
    total = {c: sum(v for (m, cc), v in sizes.items() if cc == c) for c in F.COMPRESSIONS}
    assert total["compact"] < total["fast"], sizes


def test_half_normals_within_the_stated_bound(tmp_path):
    rng = np.random.default_rng(11)
    v = rng.normal(size=(64, 80, 3))
    n = (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)
    n[:8] = 0.0  # background
    n[8, :6] = [[1e-6, 2e-5, -1.0], [6.2e-5, -6.0e-5, 1.0], [0.5, -0.25, 0.0], [2.0 ** -14, 0.0, 1.0],
                [1 - 2 ** -12, 0.0, 0.0], [0.1, 0.1, 0.1]]
    path = str(tmp_path / "n.exr")
    F.write_image(path, n, half=True)
    import OpenImageIO as oiio
    spec = oiio.ImageInput.open(path).spec()
    assert spec.format == oiio.HALF
    back = F.read_image(path)
    assert back.dtype == np.float32
    a = np.abs(n.astype(np.float64))
    err = np.abs(back - n.astype(np.float64))
    normal = a >= 2.0 ** -14
    assert np.all(err[normal] <= 2.0 ** -11 * a[normal])
    assert np.all(err[~normal] <= 2.0 ** -25)
    assert np.array_equal(back[:8], np.zeros((8, 80, 3)))
    assert np.array_equal(back, n.astype(np.float16).astype(np.float32))  # IEEE round to nearest, ties to even
    assert np.max(err[normal] / a[normal]) > 2.0 ** -12  # the bound is reached, not loose by orders


@pytest.fixture(scope="module")
def two_ways(tmp_path_factory):
    base = tmp_path_factory.mktemp("two_ways")
    assert run_main(*SMALL, "--modalities", MODS, "--out", base / "fast") == 0
    assert run_main(*SMALL, "--modalities", MODS, "--compression", "compact", "--normal-format", "half",
                    "--out", base / "compact") == 0
    return base / "fast", base / "compact"


def test_a_sequence_fast_or_compact_has_the_same_pixels(two_ways):
    fast, compact = two_ways
    labels = json.loads((fast / "labels.json").read_text())
    assert labels == json.loads((compact / "labels.json").read_text())
    n_diff = 0
    for lab in labels:
        for m, rel in lab["files"].items():
            a, b = F.read_image(str(fast / rel)), F.read_image(str(compact / rel))
            if m == "normal":
                assert np.array_equal(b, a.astype(np.float16).astype(np.float32)), rel
            else:
                assert np.array_equal(a, b, equal_nan=True), rel
            n_diff += (fast / rel).read_bytes() != (compact / rel).read_bytes()
    assert n_diff >= len(labels) * 4  # the files themselves differ
    toml = (compact / "config.toml").read_text()
    assert 'compression = "compact"' in toml and 'normal_format = "half"' in toml
    assert 'compression = "fast"' in (fast / "config.toml").read_text()


def test_resume_with_other_file_settings_is_refused_and_bad_values_are_one_line(two_ways, tmp_path, capsys):
    fast, _ = two_ways
    assert run_main(*SMALL, "--modalities", MODS, "--out", fast) == 0  # the same options resume (all done)
    capsys.readouterr()
    assert run_main(*SMALL, "--modalities", MODS, "--compression", "compact", "--out", fast) == 2
    assert "holds another sequence" in capsys.readouterr().err
    for flag, value, allowed in (("--compression", "small", "fast, compact"), ("--normal-format", "float16",
                                                                             "float32, half")):
        assert run_main(*SMALL, flag, value, "--out", tmp_path / "x") == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"argument {flag}: must be one of {allowed}" in err, err
        assert not (tmp_path / "x").exists()
    cfg = tmp_path / "c.toml"
    cfg.write_text('[output]\ncompression = "tiny"\n')
    assert run_main(*SMALL, "--config", cfg, "--out", tmp_path / "x") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "[output] compression must be one of fast, compact" in err, err


def test_exports_of_fast_and_compact_sequences_are_equal(two_ways, tmp_path):
    from raytrace.export.command import export_main
    outs = []
    for seq in two_ways:
        out = tmp_path / seq.name / "bop"  # the same name: the export names its dataset after it
        assert export_main(["--format", "bop", str(seq), "--out", str(out), "--workers", "1", "--quiet"]) == 0
        outs.append(out)
    files = [sorted(p.relative_to(o) for p in o.rglob("*") if p.is_file()) for o in outs]
    assert files[0] == files[1]
    for rel in files[0]:
        a, b = (outs[0] / rel), (outs[1] / rel)
        if rel.suffix == ".png" and rel.parts[-2] == "rgb":  # the frames themselves, linked or copied
            assert np.array_equal(F.read_image(str(a)), F.read_image(str(b))), rel
        elif rel.name != ".export.json":  # that one names the source folders
            assert a.read_bytes() == b.read_bytes(), rel


@pytest.mark.parametrize("compression", ["none", "zips", "zip"])
def test_exr_reads_as_openexrs_own_file_of_the_same_pixels(tmp_path, compression):
    """The EXR encoder against OpenEXR's writer (through OpenImageIO): the same channels, in the same
    order, and the same values bit for bit when read back, special floats and heights that are no
    multiple of a chunk's 16 lines included."""
    import OpenImageIO as oiio
    rng = np.random.default_rng(2)
    light = rng.normal(size=(21, 9, 12)).astype(np.float32)
    light[:5] = 0.0
    special = np.array([0.0, -0.0, np.inf, -np.inf, 1e-40, -1e-45, 3.4e38, 65504.0, 7e4], np.float32)
    light[5, :, :] = special[:, None]
    cases = {"light": (light, ("earth.R", "earth.G", "earth.B", "inter.R", "inter.G", "inter.B", "sky.R",
                               "sky.G", "sky.B", "sun.R", "sun.G", "sun.B")),
             "depth": (np.where(rng.random((33, 17)) < 0.5, np.inf, rng.random((33, 17)) * 50).astype(np.float32),
                       None),
             "normal": (rng.normal(size=(40, 24, 3)).astype(np.float32), None)}
    for name, (px, names) in cases.items():
        for half in (False, True):
            ours, theirs = tmp_path / f"{name}.ours.exr", tmp_path / f"{name}.theirs.exr"
            ours.write_bytes(F.exr_bytes(px, channel_names=names, half=half, compression=compression, level=1))
            F._write_oiio(str(theirs), px if px.ndim == 3 else px[:, :, None], ("exr", compression, 4, "default"),
                          names, half)
            a, b = oiio.ImageBuf(str(ours)), oiio.ImageBuf(str(theirs))
            assert not a.has_error, a.geterror()
            assert a.spec().channelnames == b.spec().channelnames
            assert a.spec().format == b.spec().format == (oiio.HALF if half else oiio.FLOAT)
            assert a.spec().get_string_attribute("compression") == compression
            pa, pb = a.get_pixels(oiio.FLOAT), b.get_pixels(oiio.FLOAT)
            assert np.array_equal(pa.view(np.uint32), pb.view(np.uint32)), (name, half)
    with pytest.raises(ValueError, match="channel_names must name the 3 channels"):
        F.exr_bytes(np.zeros((2, 2, 3), np.float32), channel_names=("R", "R", "G"))
