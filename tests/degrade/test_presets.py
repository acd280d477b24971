"""The presets of a sequence's degraded copy against the public functions they shortcut."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from degrade import PaperConfig, paper_degrade, quantise, simulate_frame
from degrade.exposure import physical_exposure
from degrade.presets import (
    WHITE_BALANCE_M,
    camera_seed,
    degrade_outputs,
    physical_config,
)

# the [degrade] table of the main job (cli.py's defaults) and its camera
D = {"degrade": "physical", "paper_group": "D4", "paper_blur_px": 15.0, "paper_angle_deg": 30.0,
     "paper_gaussian_var": 0.01, "f_number": 4.0, "exposure_us": 20.0, "quantum_efficiency": 0.6,
     "full_well_e": 10000.0, "read_noise_e": 5.0, "bit_depth": 12, "aberration_sigma_px": 0.0, "motion_blur_px": 0.0,
     "motion_angle_deg": 0.0, "defocus_radius_px": 0.0, "corner_sigma_px": 0.0, "offset_dn": 0.0,
     "dark_current_e_s": 0.0, "demosaic": "MHC", "motion_blur": "fixed", "vignetting": True,
     "mechanical_vignetting": 0.0, "prnu_sigma": 0.01, "dsnu_sigma_e": 2.0, "hot_pixel_fraction": 0.0001,
     "hot_pixel_dark_e_s": 50000.0, "blooming": True, "blooming_spill": 1.0, "smear_fraction": 0.0,
     "stray_light": True, "pst_edge": 0.0001, "pst_slope": 3.0, "sun_exclusion_deg": 60.0, "glare_gradient": 0.5,
     "ghost_reflectance": 0.005, "ghost_radius_px": 20.0, "ghost_magnification": -0.5, "jpeg_quality": 0,
     "camera_seed": None}
CAM = {"focal_length_mm": 4.0, "pixel_pitch_um": 3.45}


def radiance(shape=(48, 64, 3)):
    """Sunlit panels up to 1.5 full wells, black around them [W/(m²·sr)]."""
    r = np.zeros(shape, np.float32)
    r[8:40, 10:54] = np.random.default_rng(4).uniform(0.0, 1400.0, (32, 44, 3))
    return r


@pytest.mark.parametrize("label", [None, {"sun_dir_cam": [0.3, 0.2, 0.93], "shadow_fraction": 0.6}])
@pytest.mark.parametrize("extra", [{}, {"jpeg_quality": 85, "smear_fraction": 0.05}])
def test_physical_preset_is_the_camera_equation_then_simulate_frame(label, extra):
    d = dict(D, **extra)
    rad = radiance()
    out = degrade_outputs(d, CAM, None, rad, np.random.SeedSequence(5), label=label, sequence_seed=11,
                          want=("rgb_degraded", "signal_e", "saturation"))
    signal = physical_exposure(rad, f_number=4.0, exposure_s=20e-6, pixel_pitch_m=3.45e-6, quantum_efficiency=0.6,
                               full_well_e=10000.0, wavelengths_m=(WHITE_BALANCE_M,) * 3)
    sun = None if label is None else label["sun_dir_cam"]
    ref = simulate_frame(signal, physical_config(d, CAM), rng=np.random.default_rng(np.random.SeedSequence(5)),
                         sun_dir_cam=sun, sun_fraction=1.0 if label is None else 0.6,
                         camera_seed=camera_seed(d, 11))
    assert out["rgb_degraded"].dtype == np.uint8
    assert_array_equal(out["rgb_degraded"], quantise(ref.image, 8))
    assert_array_equal(out["signal_e"], ref.signal_e)
    assert_array_equal(out["saturation"], np.where(ref.saturation, 255, 0).astype(np.uint8))
    assert ref.saturation.any()  # blooming had work


def test_paper_preset_is_paper_degrade_of_the_clean_codes():
    rgb8 = np.random.default_rng(6).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    d = dict(D, degrade="paper")
    out = degrade_outputs(d, CAM, rgb8, None, np.random.SeedSequence(9))
    ref = paper_degrade(rgb8.astype(np.float32) / np.float32(255.0), "D4", PaperConfig(),
                        rng=np.random.default_rng(np.random.SeedSequence(9)))
    assert list(out) == ["rgb_degraded"]
    assert_array_equal(out["rgb_degraded"], quantise(ref, 8))


def test_only_the_outputs_asked_for():
    out = degrade_outputs(D, CAM, None, radiance(), np.random.SeedSequence(1), want=("saturation",))
    assert list(out) == ["saturation"] and out["saturation"].dtype == np.uint8
    with pytest.raises(ValueError, match="signal_e needs degrade = 'physical'"):
        degrade_outputs(dict(D, degrade="paper"), CAM, np.zeros((4, 4, 3), np.uint8), None, np.random.SeedSequence(1),
                        want=("rgb_degraded", "signal_e"))
