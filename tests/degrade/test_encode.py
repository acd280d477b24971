"""sRGB curve against the float64 IEC 61966-2-1 formulas; quantisation round trips."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from degrade import dequantise, encode_srgb8, quantise, srgb_decode, srgb_encode


def iec_encode(x):
    """IEC 61966-2-1:1999 §5.2 in float64."""
    x = np.minimum(np.asarray(x, np.float64), 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def iec_decode(v):
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


X = np.concatenate([np.linspace(0, 1, 100_001), np.geomspace(1e-8, 1, 5001), [0.0031308, 1.5, 7.0]])


def test_encode_matches_iec_formula():
    out = srgb_encode(X.astype(np.float32))
    assert out.dtype == np.float32
    assert_allclose(out, iec_encode(X.astype(np.float32)), rtol=0, atol=1e-6)
    assert out[-1] == 1.0 and out[0] == 0.0


def test_decode_matches_iec_formula_and_round_trips():
    v = np.linspace(0, 1, 100_001).astype(np.float32)
    lin = srgb_decode(v)
    assert lin.dtype == np.float32
    assert_allclose(lin, iec_decode(v), rtol=2e-6, atol=1e-9)
    assert_allclose(srgb_encode(lin), v, atol=2e-6)


def test_known_points():
    assert_allclose(srgb_encode(np.array([0.0031308, 0.18, 1.0], np.float32)),
                    [0.04045, 0.46135612, 1.0], atol=2e-6)  # 18 % grey → 0.4614 (IEC curve)


@pytest.mark.parametrize("bits", [8, 16])
def test_encode_with_bits_equals_quantise_dequantise(bits):
    x = np.random.default_rng(1).random((64, 80, 3), dtype=np.float32)
    enc = srgb_encode(x, bits=bits)
    assert_array_equal(enc, dequantise(quantise(srgb_encode(x), bits), bits))
    codes = quantise(enc, bits)
    assert codes.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert_array_equal(dequantise(codes, bits), enc)


def test_8bit_table_path_at_every_code_boundary():
    # the 8-bit encode looks most values up in a table; around each code boundary (where the
    # float64 IEC curve crosses (k − 1/2)/255) it must agree with the curve + quantise, ulp by ulp
    edges = iec_decode((np.arange(1, 256) - 0.5) / 255).astype(np.float32)
    steps = np.arange(-6, 7)
    x = (edges.view(np.int32)[:, None] + steps[None, :]).astype(np.int32).view(np.float32).ravel()
    x = np.concatenate([x, [0.0, -0.0, 1e-30, 1.0, np.nextafter(np.float32(1), np.float32(0)), 1.5, 7.0]])
    x = x.astype(np.float32)
    enc = srgb_encode(x, bits=8)
    assert_array_equal(enc, dequantise(quantise(srgb_encode(x), 8), 8))
    codes = quantise(enc, 8).astype(np.int64)
    scaled = 255 * iec_encode(x)  # float64 curve: may differ only within float32 rounding of an edge
    near_edge = np.abs(scaled - np.floor(scaled) - 0.5) < 1e-4
    assert np.all((codes == np.rint(scaled)) | near_edge)
    assert np.count_nonzero(codes != np.rint(scaled)) < 0.1 * x.size
    assert codes[-7] == 0 and codes[-6] == 0 and codes[-4] == 255 and codes[-2] == 255  # 0, −0, 1, >1


def test_encode_srgb8_is_encode_then_quantise():
    """One pass to uint8 codes: the codes of the curve + quantise, at every code boundary ± 6 ulp,
    on random values, 0, −0, 1 and above."""
    edges = iec_decode((np.arange(1, 256) - 0.5) / 255).astype(np.float32)
    x = (edges.view(np.int32)[:, None] + np.arange(-6, 7)[None, :]).astype(np.int32).view(np.float32).ravel()
    x = np.concatenate([x, np.random.default_rng(2).random(20_000, dtype=np.float32) ** 3,
                        [0.0, -0.0, 1e-30, 1.0, 1.5, 7.0]]).astype(np.float32)
    codes = encode_srgb8(x)
    assert codes.dtype == np.uint8 and codes.shape == x.shape
    assert_array_equal(codes, quantise(srgb_encode(np.minimum(x, np.float32(1.0))), 8))
    scaled = 255 * iec_encode(np.maximum(x, 0.0))
    clear = np.abs(scaled - np.floor(scaled) - 0.5) >= 1e-4  # not within float32 rounding of an edge
    assert_array_equal(codes[clear], np.rint(scaled[clear]))
    img = np.random.default_rng(3).random((48, 64, 3), dtype=np.float32) * 1.2
    assert_array_equal(encode_srgb8(img), quantise(srgb_encode(img, bits=8), 8))
    with pytest.raises(ValueError, match="image_linear must be >= 0"):
        encode_srgb8(np.array([-0.5], np.float32))


def test_quantise_rounds_and_saturates():
    assert_array_equal(quantise(np.array([0.0, 0.25, 0.5, 0.75, 1.0, 3.0]), 1), [0, 0, 0, 1, 1, 1])  # half to even
    assert_array_equal(quantise(np.array([0.5, 0.999]), 2), [2, 3])
    assert_array_equal(quantise(np.array([0.0, 1.0, 3.0]), 8), [0, 255, 255])
    assert quantise(np.array([1.0]), 12)[0] == 4095


def test_errors_name_the_parameter():
    with pytest.raises(ValueError, match="image_linear must be >= 0"):
        srgb_encode(np.array([-0.1], np.float32))
    with pytest.raises(ValueError, match="image_srgb must be <= 1"):
        srgb_decode(np.array([1.1], np.float32))
    with pytest.raises(ValueError, match="bits"):
        srgb_encode(np.zeros(3, np.float32).reshape(1, 3), bits=17)
    with pytest.raises(ValueError, match="codes must lie in"):
        dequantise(np.array([300]), 8)
    with pytest.raises(ValueError, match="codes must be an integer array"):
        dequantise(np.array([0.5]), 8)
