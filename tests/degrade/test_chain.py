"""The physical chain: dtype contract, errors, reproducibility, optics against its PSF."""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from degrade import (
    DegradeConfig,
    OpticsConfig,
    SensorConfig,
    apply_optics,
    convolve_image,
    degrade,
    dequantise,
    optics_psf,
    quantise,
    srgb_encode,
)

OPTICS = OpticsConfig(aberration_sigma_px=0.7, defocus_radius_px=1.2, motion_length_px=6.0, motion_angle_deg=25.0)


def scene(shape=(64, 80, 3), seed=0):
    """Random texture in the middle half of a black frame (linear)."""
    img = np.zeros(shape, np.float32)
    h, w = shape[0] // 2, shape[1] // 2
    img[h // 2:h // 2 + h, w // 2:w // 2 + w] = np.random.default_rng(seed).random((h, w, *shape[2:]))
    return img


def test_float32_in_float32_out_and_quantised_levels():
    out = degrade(scene(), rng=0)
    assert out.dtype == np.float32 and out.shape == (64, 80, 3)
    assert_array_equal(dequantise(quantise(out, 8), 8), out)  # exactly float32(code/255)
    out16 = degrade(scene(), dataclasses.replace(DegradeConfig(), encoding="srgb16"), rng=0)
    assert_array_equal(dequantise(quantise(out16, 16), 16), out16)


def test_float64_input_is_converted():
    img = scene().astype(np.float64)
    out = degrade(img, rng=1)
    assert out.dtype == np.float32
    assert out.tobytes() == degrade(img.astype(np.float32), rng=1).tobytes()


@pytest.mark.parametrize("bad, match", [
    (np.full((8, 8, 3), np.nan, np.float32), "image_linear must be finite"),
    (np.full((8, 8, 3), -np.inf, np.float32), "image_linear must be finite"),
    (np.full((8, 8, 3), -0.01, np.float32), "image_linear must be >= 0"),
    (np.ones((8, 8, 3), np.uint16), "image_linear must be a float array"),
    (np.ones((8, 8, 4), np.float32), "image_linear must have 3 channels"),
])
def test_bad_input_raises(bad, match):
    with pytest.raises(ValueError, match=match):
        degrade(bad, rng=0)


def test_same_seed_byte_identical():
    img = scene()
    cfg = DegradeConfig(optics=OPTICS)
    a = degrade(img, cfg, rng=42)
    assert a.tobytes() == degrade(img, cfg, rng=np.random.default_rng(42)).tobytes()
    assert a.tobytes() != degrade(img, cfg, rng=43).tobytes()


def test_optics_only_is_convolution_with_per_channel_psf():
    img = scene()
    cfg = DegradeConfig(optics=OPTICS, sensor=None, encoding="linear")
    out = degrade(img, cfg, rng=0)
    assert_allclose(out, convolve_image(img, optics_psf(OPTICS)), atol=1e-7)
    assert_allclose(apply_optics(img, OPTICS), out, atol=0)
    cfg_srgb = dataclasses.replace(cfg, encoding="srgb")
    assert_allclose(degrade(img, cfg_srgb, rng=0), srgb_encode(out), atol=0)


def test_delta_image_returns_each_channel_psf():
    img = np.zeros((61, 61, 3), np.float32)
    img[30, 30] = 1.0
    out = apply_optics(img, OPTICS)
    stack = optics_psf(OPTICS)
    r = stack.shape[1] // 2
    for c in range(3):
        assert_allclose(out[30 - r:31 + r, 30 - r:31 + r, c], stack[c], atol=1e-6)


def test_red_psf_wider_than_blue():
    stack = optics_psf(OpticsConfig())
    i = np.arange(stack.shape[1]) - stack.shape[1] // 2
    second = [(k * (i[:, None] ** 2 + i[None, :] ** 2)).sum() for k in stack]
    assert second[0] > second[1] > second[2]


def test_identity_optics_and_no_sensor_return_input_copy():
    img = scene()
    cfg = DegradeConfig(optics=OpticsConfig(aperture_m=None), sensor=None, encoding="linear")
    out = degrade(img, cfg, rng=0)
    assert_array_equal(out, img)
    assert out is not img


def test_field_dependent_blur_blends_centre_and_corner():
    img = np.random.default_rng(2).random((41, 61, 3), dtype=np.float32)
    optics = OpticsConfig(aperture_m=None, aberration_sigma_px=0.5, corner_sigma_px=2.5)
    out = apply_optics(img, optics)
    centre = convolve_image(img, optics_psf(optics))
    corner = convolve_image(img, optics_psf(optics, corner=True))
    assert_allclose(out[20, 30], centre[20, 30], atol=1e-6)  # image centre: weight 0
    assert_allclose(out[0, 0], corner[0, 0], atol=1e-6)  # corners: weight 1
    assert_allclose(out[-1, -1], corner[-1, -1], atol=1e-6)


def test_monochrome_chain():
    img = scene(shape=(40, 50))
    cfg = DegradeConfig(optics=OPTICS, sensor=SensorConfig(demosaic=None))
    out = degrade(img, cfg, rng=0)
    assert out.shape == img.shape and out.dtype == np.float32
    with pytest.raises(ValueError, match="demosaic=None"):
        degrade(img, rng=0)


def test_sensor_noise_statistics_survive_the_chain():
    # flat grey, no blur, no CFA: mean of the linear output = the input (Φ_max = FW/QE, below FW)
    img = np.full((200, 200, 3), 0.25, np.float32)
    cfg = DegradeConfig(optics=None, sensor=SensorConfig(demosaic=None), encoding="linear")
    out = degrade(img, cfg, rng=3).astype(np.float64)
    c = cfg.sensor
    std = np.sqrt(0.25 * c.full_well_e + c.read_noise_e**2 + c.gain**2 / 12) / c.full_well_e
    assert abs(out.mean() - 0.25) < 5 * std / np.sqrt(out.size)


@pytest.mark.parametrize("field, value, match", [
    ("aperture_m", -1.0, "aperture_m"), ("wavelengths_m", (500e-9, 600e-9), "wavelengths_m"),
    ("wavelengths_m", (500e-9, 0.0, 600e-9), r"wavelengths_m\[1\]"), ("motion_length_px", -2.0, "motion_length_px"),
    ("corner_sigma_px", float("nan"), "corner_sigma_px"), ("pixel_pitch_m", 0.0, "pixel_pitch_m"),
])
def test_invalid_optics(field, value, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(OpticsConfig(), **{field: value})


def test_invalid_degrade_config():
    with pytest.raises(ValueError, match="encoding must be one of"):
        DegradeConfig(encoding="jpeg")
    with pytest.raises(ValueError, match="sensor must be a SensorConfig"):
        DegradeConfig(sensor=OpticsConfig())
    with pytest.raises(ValueError, match="config must be a DegradeConfig"):
        degrade(scene(), OpticsConfig(), rng=0)


def test_codes_path_equals_quantised_image():
    """The presets' path straight to uint8 codes (no float levels between demosaic and codes) is
    quantise(simulate_frame(...).image, 8) byte for byte, with artefacts, JPEG and without."""
    from degrade import ArtefactConfig, simulate_frame
    from degrade.chain import _simulate_frame
    img = scene((48, 64, 3), seed=3) * np.float32(1.3)
    for art in (ArtefactConfig(), ArtefactConfig(jpeg_quality=80), None):
        cfg = DegradeConfig(optics=OPTICS, artefacts=art)
        ref = simulate_frame(img, cfg, rng=5, sun_dir_cam=[0.3, 0.1, 0.95], camera_seed=2)
        out = _simulate_frame(img, cfg, np.random.default_rng(5), [0.3, 0.1, 0.95], 1.0, 2, codes8=True)
        assert out.image.dtype == np.uint8
        assert_array_equal(out.image, quantise(ref.image, 8))
        if art is not None:
            assert_array_equal(out.signal_e, ref.signal_e)
            assert_array_equal(out.saturation, ref.saturation)


def test_optics_at_the_sites_equal_the_mosaic_of_the_blurred_image():
    """The optics evaluated only at the RGGB photosites (corner blend included, and the
    fallback of a kernel too large for the direct path): the mosaic of apply_optics, byte for byte."""
    from degrade.chain import _optics_sites
    from degrade.sensor import mosaic_rggb
    img = scene((48, 64, 3), seed=4)
    for optics in (OPTICS, OpticsConfig(aberration_sigma_px=0.5, corner_sigma_px=1.5),
                   OpticsConfig(motion_length_px=30.0, motion_angle_deg=20.0)):
        assert _optics_sites(img, optics).tobytes() == mosaic_rggb(apply_optics(img, optics)).tobytes()
