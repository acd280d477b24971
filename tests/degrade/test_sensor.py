"""Bayer mosaic, OpenImageIO demosaic and the noise model against the formulas of
docs/degradation.md, "Sensor"."""

import dataclasses

import numpy as np
import OpenImageIO as oiio
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from degrade import SensorConfig, demosaic, mosaic_rggb, sensor_readout, simulate_sensor
from degrade.sensor import _demosaic


def test_mosaic_layout_rggb():
    img = np.zeros((4, 6, 3), np.float32)
    img[..., 0], img[..., 1], img[..., 2] = 1.0, 2.0 / 3, 1.0 / 3
    raw = mosaic_rggb(img)
    expected = np.tile(np.array([[1.0, 2 / 3], [2 / 3, 1 / 3]], np.float32), (2, 3))
    assert raw.dtype == np.float32
    assert_array_equal(raw, expected)


@pytest.mark.parametrize("algorithm", ["MHC", "linear"])
@pytest.mark.parametrize("shape", [(64, 96), (130, 70)])
def test_flat_colour_survives_mosaic_and_demosaic(algorithm, shape):
    colour = np.array([0.21, 0.55, 0.83], np.float32)
    img = np.broadcast_to(colour, (*shape, 3)).copy()
    out = demosaic(mosaic_rggb(img), algorithm=algorithm)
    assert out.dtype == np.float32 and out.shape == img.shape
    assert_allclose(out, img, atol=1e-6)  # the whole image, borders included


def test_linear_demosaic_is_spec_normalised_convolution():
    # reference bilinear demosaic: masked channel ⊛ kernel / mask ⊛ kernel. Compared 2 px away
    # from the borders, where no padding convention is involved.
    raw = np.random.default_rng(3).random((40, 52), dtype=np.float32)
    mask = np.zeros((40, 52, 3))
    mask[0::2, 0::2, 0] = mask[0::2, 1::2, 1] = mask[1::2, 0::2, 1] = mask[1::2, 1::2, 2] = 1
    k_g = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]]) / 4
    k_rb = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]]) / 4
    ref = np.stack([ndimage.convolve(raw * mask[..., c], k) / ndimage.convolve(mask[..., c], k)
                    for c, k in enumerate([k_rb, k_g, k_rb])], -1)
    out = demosaic(raw, algorithm="linear")
    assert_allclose(out[2:-2, 2:-2], ref[2:-2, 2:-2], atol=1e-6)


def test_demosaic_strips_equal_one_call():
    raw = np.random.default_rng(4).random((300, 90), dtype=np.float32)  # 300 rows → 2+ strips
    whole = oiio.ImageBufAlgo.demosaic(oiio.ImageBuf(raw[:, :, None].copy()), pattern="bayer",
                                       algorithm="MHC", layout="RGGB").get_pixels(oiio.FLOAT)
    assert_array_equal(_demosaic(raw, "MHC"), whole)


def dn(image, config):
    return image.astype(np.float64) * config.max_dn


def test_noise_mean_and_variance_spec_values():
    # docs/degradation.md, "Sensor": Φ = 5000 photons → mean DN = QE Φ/g = 1228.5,
    # std = sqrt(QEΦ + σr² + g²/12)/g = 22.52
    c = SensorConfig()
    phi = 5000.0
    img = np.full((400, 500), phi / c.photons_max, np.float32)
    out = dn(sensor_readout(img, c, rng=12345), c)
    n = out.size
    g = c.full_well_e / (2**12 - 1)
    mean = 0.6 * phi / g
    std = np.sqrt(0.6 * phi + 5.0**2 + g**2 / 12) / g
    assert_allclose([mean, std], [1228.5, 22.52], atol=0.01)
    assert abs(out.mean() - mean) < 5 * std / np.sqrt(n)
    assert abs(out.std() - std) < 5 * std / np.sqrt(2 * n)
    assert_allclose(out, np.rint(out), atol=1e-3)  # whole DN


def test_dark_current_and_offset_shift_the_mean():
    c = SensorConfig(dark_current_e_per_s=2000.0, exposure_s=0.5, offset_dn=100.0, read_noise_e=0.0)
    img = np.full((300, 300), 0.1, np.float32)
    out = dn(sensor_readout(img, c, rng=1), c)
    mean_e = 0.6 * 0.1 * c.photons_max + 1000.0
    var_dn = (mean_e + c.gain**2 / 12) / c.gain**2
    assert abs(out.mean() - (mean_e / c.gain + 100.0)) < 5 * np.sqrt(var_dn / out.size)


def test_full_well_clips_and_output_is_in_range():
    c = SensorConfig()
    out = sensor_readout(np.full((200, 200), 3.0, np.float32), c, rng=2)
    assert out.max() == 1.0 and out.min() > 0.99
    # min(Poisson, FW) = FW exactly, then read noise: mean stays FW/g (clip at the top DN only
    # removes the upper half of the read noise)
    assert dn(out, c).mean() > c.max_dn - 5.0 / c.gain


def test_noiseless_unquantised_readout_is_identity():
    c = SensorConfig(shot_noise=False, read_noise_e=0.0, quantise=False)
    img = np.random.default_rng(5).random((30, 40), dtype=np.float32)
    assert_allclose(sensor_readout(img, c, rng=0), img, rtol=1e-6, atol=1e-7)


def test_gain_and_photons_defaults():
    c = SensorConfig()
    assert_allclose(c.gain, 10_000 / 4095)
    assert_allclose(c.photons_max, 10_000 / 0.6)
    c2 = SensorConfig(gain_e_per_dn=2.0, photons_at_one=5000.0)
    assert (c2.gain, c2.photons_max) == (2.0, 5000.0)


@pytest.mark.parametrize("algorithm", ["MHC", "linear", None])
def test_same_seed_same_bytes_and_float32(algorithm):
    c = SensorConfig(demosaic=algorithm)
    img = np.random.default_rng(6).random((48, 64, 3), dtype=np.float32)
    a = simulate_sensor(img, c, rng=99)
    b = simulate_sensor(img, c, rng=np.random.default_rng(99))
    assert a.dtype == np.float32 and a.shape == img.shape
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != simulate_sensor(img, c, rng=100).tobytes()
    assert 0.0 <= a.min() and a.max() <= 1.0


def test_monochrome_needs_no_cfa():
    img = np.full((20, 30), 0.5, np.float32)
    out = simulate_sensor(img, SensorConfig(demosaic=None), rng=0)
    assert out.shape == img.shape
    with pytest.raises(ValueError, match="demosaic=None"):
        simulate_sensor(img, SensorConfig(), rng=0)


@pytest.mark.parametrize("field, value", [
    ("quantum_efficiency", 1.5), ("quantum_efficiency", 0.0), ("full_well_e", -1.0),
    ("read_noise_e", float("nan")), ("bit_depth", 17), ("bit_depth", 12.0), ("offset_dn", -1.0),
    ("gain_e_per_dn", 0.0), ("photons_at_one", float("inf")), ("shot_noise", 1), ("demosaic", "AHD"),
])
def test_invalid_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(SensorConfig(), **{field: value})


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="image_linear must be finite"):
        sensor_readout(np.array([[np.nan]], np.float32), rng=0)
    with pytest.raises(ValueError, match="image_linear must be >= 0"):
        simulate_sensor(-np.ones((4, 4, 3), np.float32), rng=0)
    with pytest.raises(ValueError, match="config must be a SensorConfig"):
        sensor_readout(np.ones((4, 4), np.float32), {"read_noise_e": 1}, rng=0)
    with pytest.raises(ValueError, match="algorithm must be one of"):
        demosaic(np.ones((4, 4), np.float32), algorithm="VNG")


# --------------------------------------------------------------------------- Numba MHC and fused sensor path

# Malvar, He, Cutler (ICASSP 2004), fig. 2: the 5×5 filters (×1/8) of the missing colours
_G_AT_RB = np.array([[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]]) / 8
_ROW_AT_G = np.array([[0, 0, .5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, .5, 0, 0]]) / 8
_COL_AT_G = _ROW_AT_G.T
_RB_AT_BR = np.array([[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0],
                      [0, 0, -1.5, 0, 0]]) / 8


def test_mhc_is_the_published_filters():
    """The demosaic against Malvar–He–Cutler's published 5×5 filters, float64, 2 px from the borders."""
    raw = np.random.default_rng(11).random((38, 54), dtype=np.float32)
    f = {name: ndimage.correlate(raw.astype(np.float64), k, mode="mirror")
         for name, k in (("g", _G_AT_RB), ("row", _ROW_AT_G), ("col", _COL_AT_G), ("rb", _RB_AT_BR))}
    ref = np.empty((*raw.shape, 3))
    r, b = (slice(0, None, 2), slice(0, None, 2)), (slice(1, None, 2), slice(1, None, 2))
    gr, gb = (slice(0, None, 2), slice(1, None, 2)), (slice(1, None, 2), slice(0, None, 2))
    ref[r] = np.stack([raw[r], f["g"][r], f["rb"][r]], -1)
    ref[b] = np.stack([f["rb"][b], f["g"][b], raw[b]], -1)
    ref[gr] = np.stack([f["row"][gr], raw[gr], f["col"][gr]], -1)  # R left/right, B above/below
    ref[gb] = np.stack([f["col"][gb], raw[gb], f["row"][gb]], -1)
    out = demosaic(raw, algorithm="MHC")
    assert_allclose(out[2:-2, 2:-2], ref[2:-2, 2:-2], atol=2e-6)


@pytest.mark.parametrize("shape", [(2, 2), (3, 5), (4, 4), (5, 6), (7, 9), (33, 20), (1, 4), (6, 1)])
def test_mhc_equals_openimageio_borders_included(shape):
    """Byte for byte as OpenImageIO's MHC, whose border rule (an index off the edge moves back by
    the Bayer period) the Numba kernel copies."""
    for scale in (1.0, 3e-4):
        raw = (np.random.default_rng(shape[0] * 100 + shape[1]).random(shape) * scale).astype(np.float32)
        ref = oiio.ImageBufAlgo.demosaic(oiio.ImageBuf(raw[:, :, None].copy()), pattern="bayer",
                                         algorithm="MHC", layout="RGGB").get_pixels(oiio.FLOAT)
        assert_array_equal(_demosaic(raw, "MHC"), ref)


def test_fused_rggb_path_equals_the_general_path():
    """Illumination, stray light and mean electrons of the mosaic in one kernel: the same bits as
    the NumPy path (vignetting, + stray light, mosaic, _signal_e), for every output."""
    from degrade import ArtefactConfig
    from degrade.artefacts import camera_maps
    from degrade.sensor import _mosaic, _signal_e, _signal_e_rggb
    rng = np.random.default_rng(5)
    img = rng.uniform(0.0, 1.4, (40, 56, 3)).astype(np.float32)
    img[:, :20] = 0.0  # dark columns: the sparse Poisson draws
    vig = rng.uniform(0.5, 1.0, (40, 56)).astype(np.float32)
    stray = rng.uniform(0.0, 0.01, (40, 56)).astype(np.float32)
    c = SensorConfig(dark_current_e_per_s=300.0)
    for art in (ArtefactConfig(hot_pixel_fraction=0.02), ArtefactConfig(prnu_sigma=0.0, dsnu_sigma_e=0.0,
                                                                       hot_pixel_fraction=0.0, blooming=False)):
        maps = camera_maps((40, 56), art, 3)
        fused = _signal_e_rggb(_mosaic(img), vig, stray, c, art, maps, np.random.default_rng(8))
        general = _signal_e(_mosaic(img * vig[:, :, None] + stray[:, :, None]), c, art, maps, np.random.default_rng(8))
        for a, b in zip(fused, general):
            assert a.dtype == b.dtype == np.float32
            assert_array_equal(a, b)
        assert (fused[0] >= c.full_well_e).any()  # blooming had work


def test_sparse_poisson_draws_what_numpy_draws():
    from degrade.sensor import _poisson_sparse
    mean = np.zeros(5000)
    mean[::7] = np.linspace(0.1, 3000.0, mean[::7].size)
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    assert_array_equal(_poisson_sparse(a, mean), b.poisson(mean))
    assert a.random() == b.random()  # and leaves the stream where NumPy leaves it


def test_read_noise_is_generator_normal_and_adc_is_the_formula():
    """The fused read-out (standard normal draws z, 0 + σ·z in the kernel) against
    ``Generator.normal(0, σ)`` of the same child stream and the ADC formula in NumPy."""
    from degrade.artefacts import ARTEFACTS_OFF, CameraMaps
    from degrade.sensor import _signal_from_mean
    c = SensorConfig(shot_noise=False, read_noise_e=7.5, offset_dn=3.0)
    mean = np.random.default_rng(1).uniform(0.0, 1.1 * c.full_well_e, (40, 56))
    signal, dn_out = _signal_from_mean(mean, c, ARTEFACTS_OFF, CameraMaps(None, None, None), np.random.default_rng(3))
    (child,) = np.random.default_rng(3).spawn(1)  # 2240 photosites: one block
    s = np.minimum(np.minimum(mean, c.full_well_e) + child.normal(0.0, 7.5, mean.size).reshape(mean.shape),
                   c.full_well_e)
    assert_array_equal(signal, s.astype(np.float32))
    ref = np.clip(np.rint(s / c.gain + 3.0), 0.0, c.max_dn) / c.max_dn
    assert_array_equal(dn_out, ref.astype(np.float32))
