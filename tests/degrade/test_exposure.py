"""Exposure: the camera equation by hand (CODATA constants from scipy), auto exposure by its
definition."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import constants

from degrade import SensorConfig
from degrade.exposure import auto_exposure, physical_exposure


def test_physical_exposure_by_hand():
    # L = 100 W/(m² sr) through f/4 for 10 ms onto 3.45 µm pixels, green at 530 nm:
    # E = π L/(4 N²) = 4.9087 W/m²; E p² t = 5.8426e-13 J; / (h c/λ = 3.7481e-19 J) = 1.5588e6
    # photons; × QE 0.6 / FW 10 000 e⁻ = 93.53 (the well is full 93 times over)
    radiance = np.zeros((2, 3, 3), np.float32)
    radiance[..., 1] = 100.0
    radiance[1, 2] = [50.0, 0.0, 25.0]
    out = physical_exposure(radiance, f_number=4.0, exposure_s=0.01, pixel_pitch_m=3.45e-6)
    assert out.dtype == np.float32 and out.shape == radiance.shape
    photon_j = constants.h * constants.c / np.array([600e-9, 530e-9, 460e-9])
    joules = radiance.astype(np.float64) * math.pi / 64 * (3.45e-6) ** 2 * 0.01
    assert_allclose(out, 0.6 * joules / photon_j / 1e4, rtol=1e-6)
    assert_allclose(out[0, 0, 1], 93.53, rtol=1e-3)
    # consistent with the sensor: signal 1 ↔ SensorConfig's photons_at_one photons
    assert_allclose(out[0, 0, 1] * SensorConfig().photons_max, joules[0, 0, 1] / photon_j[1], rtol=1e-6)


def test_physical_exposure_is_numpys_float64_expression_bit_for_bit():
    """The one-pass kernel runs NumPy's float64 operations in NumPy's order: the same bits."""
    radiance = np.random.default_rng(5).uniform(0.0, 900.0, (30, 41, 3)).astype(np.float32)
    lam = np.array([610e-9, 530e-9, 455e-9])
    out = physical_exposure(radiance, f_number=2.8, exposure_s=2e-5, pixel_pitch_m=3.45e-6, quantum_efficiency=0.55,
                            full_well_e=9000.0, wavelengths_m=tuple(lam))
    joules = radiance.astype(np.float64) * (math.pi / (4.0 * 2.8 * 2.8)) * 3.45e-6 * 3.45e-6 * 2e-5
    ref = (0.55 * (joules * lam / (6.62607015e-34 * 299792458.0)) / 9000.0).astype(np.float32)
    assert out.tobytes() == ref.tobytes()


def test_auto_exposure_maps_the_percentile_of_the_masked_luminance():
    rng = np.random.default_rng(0)
    radiance = rng.random((40, 50, 3), dtype=np.float32) * 20
    mask = np.zeros((40, 50), bool)
    mask[10:30, 5:25] = True
    radiance[~mask] *= 100  # bright pixels outside the mask must not matter
    out, scale = auto_exposure(radiance, mask, percentile=90.0, level=0.8)
    luma = 0.2126 * radiance[..., 0] + 0.7152 * radiance[..., 1] + 0.0722 * radiance[..., 2]
    assert_allclose(scale, 0.8 / np.percentile(luma[mask], 90.0), rtol=1e-5)
    assert out.dtype == np.float32
    assert_allclose(out, radiance * np.float32(scale), rtol=1e-6)
    dark, s = auto_exposure(np.zeros((4, 4, 3), np.float32))
    assert s == 1.0 and not dark.any()


@pytest.mark.parametrize("call, match", [
    (lambda: auto_exposure(np.full((4, 4, 3), -1.0, np.float32)), "radiance must be >= 0"),
    (lambda: auto_exposure(np.ones((4, 4), np.float32)), "radiance must have 3 dimensions"),
    (lambda: auto_exposure(np.ones((4, 4, 3), np.float32), np.ones((3, 3), bool)), "mask must have shape"),
    (lambda: auto_exposure(np.ones((4, 4, 3), np.float32), percentile=0), "percentile"),
    (lambda: physical_exposure(np.ones((2, 2, 3)), f_number=0, exposure_s=1, pixel_pitch_m=1e-6), "f_number"),
    (lambda: physical_exposure(np.ones((2, 2, 3)), f_number=2, exposure_s=1, pixel_pitch_m=1e-6,
                               quantum_efficiency=1.2), "quantum_efficiency"),
    (lambda: physical_exposure(np.ones((2, 2, 3)), f_number=2, exposure_s=1, pixel_pitch_m=1e-6,
                               wavelengths_m=(5e-7, 5e-7)), "wavelengths_m"),
])
def test_errors_name_the_parameter(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("bad, match", [(-1e-3, "radiance must be >= 0 everywhere, got minimum -0.001"),
                                        (np.nan, "radiance must be finite, got 1 NaN/inf"),
                                        (np.inf, "radiance must be finite, got 1 NaN/inf")])
def test_camera_equation_finds_a_bad_radiance_value(bad, match):
    """The camera equation's kernel scans the values as it goes: one bad value anywhere raises
    the same one-line error as the up-front check."""
    radiance = np.ones((5, 7, 3), np.float32)
    radiance[3, 6, 2] = bad
    with pytest.raises(ValueError, match=match):
        physical_exposure(radiance, f_number=2.0, exposure_s=1e-3, pixel_pitch_m=3.45e-6)
    radiance[3, 6, 2] = -0.0  # −0 is ≥ 0: accepted, as by the up-front check
    assert physical_exposure(radiance, f_number=2.0, exposure_s=1e-3, pixel_pitch_m=3.45e-6)[3, 6, 2] == 0.0
