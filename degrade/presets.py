"""The degradation presets of a sequence: ``none``, ``paper`` and ``physical``.

A sequence's degraded copy (``rgb_degraded``) is made by one of three presets, set by the
``degrade`` table of the scenario configuration (keys as in its TOML file; ``degrade = "paper"``
is the option ``--degrade paper``):

* ``none`` — no degraded copy;
* ``paper`` — the source paper's group (``paper_group``: D1 blur … D4 blur + Poisson + Gaussian,
  :mod:`degrade.paper`) applied to the clean 8-bit sRGB image;
* ``physical`` — the camera equation (:func:`degrade.exposure.physical_exposure`) on the linear
  radiance, then the imaging chain (:func:`degrade.chain.degrade`: optics PSF, RGGB mosaic,
  shot, dark and read noise, ADC, demosaic) and an 8-bit sRGB encoding.

docs/degradation.md gives the maths of each stage.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PRESETS", "WHITE_BALANCE_M", "physical_config", "degrade_frame"]

PRESETS = ("none", "paper", "physical")
"""The presets, the first meaning no degraded copy."""

WHITE_BALANCE_M = 530e-9
"""Photon energy used for every channel in the camera equation: a white-balanced sensor (a grey
surface gives equal R, G, B signals) [m]."""


def physical_config(d: dict, cam: dict, motion=None):
    """The :class:`degrade.chain.DegradeConfig` of the ``physical`` preset from the ``degrade``
    table ``d`` and the ``camera`` table ``cam``; ``motion`` = (L [px], θ [deg]) of the frame
    overrides the constant blur when ``d["motion_blur"] == "auto"``."""
    from .chain import DegradeConfig, OpticsConfig
    from .sensor import SensorConfig
    f_m = cam["focal_length_mm"] * 1e-3
    length, angle = d["motion_blur_px"], d["motion_angle_deg"]
    if d.get("motion_blur") == "auto" and motion is not None:
        length, angle = motion
    optics = OpticsConfig(focal_length_m=f_m, aperture_m=f_m / d["f_number"], pixel_pitch_m=cam["pixel_pitch_um"] * 1e-6,
                          aberration_sigma_px=d["aberration_sigma_px"], motion_length_px=length,
                          motion_angle_deg=angle, defocus_radius_px=d["defocus_radius_px"],
                          corner_sigma_px=d["corner_sigma_px"] or None)
    sensor = SensorConfig(quantum_efficiency=d["quantum_efficiency"], full_well_e=d["full_well_e"],
                          read_noise_e=d["read_noise_e"], bit_depth=d["bit_depth"], exposure_s=d["exposure_us"] * 1e-6,
                          offset_dn=d["offset_dn"], dark_current_e_per_s=d["dark_current_e_s"], demosaic=d["demosaic"])
    return DegradeConfig(optics=optics, sensor=sensor, encoding="srgb8")


def degrade_frame(d: dict, cam: dict, rgb8, radiance, seed_seq, motion=None) -> np.ndarray:
    """The degraded 8-bit RGB of one frame (``d["degrade"]`` is ``paper`` or ``physical``): the
    paper's group applied to the clean 8-bit image ``rgb8``, or the camera equation and imaging
    chain applied to the linear ``radiance`` [W/(m²·sr)], drawing from
    ``numpy.random.default_rng(seed_seq)``; ``motion``: the frame's (L [px], θ [deg]) for the
    ``auto`` motion blur."""
    from .encode import quantise
    rng = np.random.default_rng(seed_seq)
    if d["degrade"] == "paper":
        from .paper import PaperConfig, paper_degrade
        paper = PaperConfig(length_px=d["paper_blur_px"], angle_deg=d["paper_angle_deg"],
                            gaussian_var=d["paper_gaussian_var"])
        out = paper_degrade(np.asarray(rgb8).astype(np.float32) / np.float32(255.0), d["paper_group"], paper, rng=rng)
    else:
        from .chain import degrade
        from .exposure import physical_exposure
        signal = physical_exposure(radiance, f_number=d["f_number"], exposure_s=d["exposure_us"] * 1e-6,
                                   pixel_pitch_m=cam["pixel_pitch_um"] * 1e-6,
                                   quantum_efficiency=d["quantum_efficiency"], full_well_e=d["full_well_e"],
                                   wavelengths_m=(WHITE_BALANCE_M,) * 3)
        out = degrade(signal, physical_config(d, cam, motion), rng=rng)
    return quantise(out, 8)
