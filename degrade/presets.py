"""The degradation presets of a sequence: ``none``, ``paper`` and ``physical``.

A sequence's degraded copy (``rgb_degraded``) is made by one of three presets, set by the
``degrade`` table of the scenario configuration (keys as in its TOML file; ``degrade = "paper"``
is the option ``--degrade paper``):

* ``none`` — no degraded copy;
* ``paper`` — the source paper's group (``paper_group``: D1 blur … D4 blur + Poisson + Gaussian,
  :mod:`degrade.paper`) applied to the clean 8-bit sRGB image;
* ``physical`` — the camera equation (:func:`degrade.exposure.physical_exposure`) on the linear
  radiance, then the imaging chain (:func:`degrade.chain.degrade`: optics PSF, RGGB mosaic,
  shot, dark and read noise, ADC, demosaic), the camera artefacts (:mod:`degrade.artefacts`:
  vignetting, PRNU/DSNU, hot pixels, smear, blooming, stray light and ghost, JPEG) and an
  8-bit sRGB encoding; only this preset can also give the photosites' electrons
  (``signal_e``) and saturation mask (``saturation``).

docs/degradation.md gives the maths of each stage.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CAMERA_OUTPUTS", "PRESETS", "WHITE_BALANCE_M", "artefact_config", "camera_seed", "degrade_frame",
           "degrade_outputs", "physical_config"]

PRESETS = ("none", "paper", "physical")
"""The presets, the first meaning no degraded copy."""

WHITE_BALANCE_M = 530e-9
"""Photon energy used for every channel in the camera equation: a white-balanced sensor (a grey
surface gives equal R, G, B signals) [m]."""


CAMERA_OUTPUTS = ("rgb_degraded", "signal_e", "saturation")
"""What :func:`degrade_outputs` makes: the degraded 8-bit RGB, the photosites' electrons
(float32, H×W mosaic) and the saturation mask (uint8, 255 where a photosite reached full well)."""

_CAMERA_SEED_TAG = 0x5EED
"""Mixed into the sequence's seed when the ``degrade`` table sets no ``camera_seed``."""


def artefact_config(d: dict):
    """The :class:`degrade.artefacts.ArtefactConfig` of the ``degrade`` table ``d`` (keys as
    the option table's; missing keys keep the defaults)."""
    from .artefacts import ArtefactConfig
    keys = {"vignetting": "vignetting", "mechanical_vignetting": "mechanical_vignetting", "prnu_sigma": "prnu_sigma",
            "dsnu_sigma_e": "dsnu_sigma_e", "hot_pixel_fraction": "hot_pixel_fraction",
            "hot_pixel_dark_e_s": "hot_pixel_dark_e_per_s", "blooming": "blooming", "blooming_spill": "blooming_spill", "smear_fraction": "smear_fraction",
            "stray_light": "stray_light", "pst_edge": "pst_edge", "pst_slope": "pst_slope",
            "sun_exclusion_deg": "sun_exclusion_deg", "glare_gradient": "glare_gradient",
            "ghost_reflectance": "ghost_reflectance", "ghost_radius_px": "ghost_radius_px",
            "ghost_magnification": "ghost_magnification", "jpeg_quality": "jpeg_quality"}
    return ArtefactConfig(**{field: d[key] for key, field in keys.items() if key in d})


def camera_seed(d: dict, sequence_seed: int) -> int:
    """The seed of the camera's fixed maps: the ``degrade`` table's ``camera_seed``, or one
    derived from the sequence's seed (the same camera over the sequence)."""
    if d.get("camera_seed") is not None:
        return int(d["camera_seed"])
    return int(np.random.SeedSequence([int(sequence_seed), _CAMERA_SEED_TAG]).generate_state(2, np.uint64)[0] >> 1)


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
    return DegradeConfig(optics=optics, sensor=sensor, encoding="srgb8", artefacts=artefact_config(d))


def degrade_frame(d: dict, cam: dict, rgb8, radiance, seed_seq, motion=None, *, label=None,
                  sequence_seed: int = 0) -> np.ndarray:
    """The degraded 8-bit RGB of one frame: ``degrade_outputs(...)["rgb_degraded"]``."""
    return degrade_outputs(d, cam, rgb8, radiance, seed_seq, motion, label=label,
                           sequence_seed=sequence_seed)["rgb_degraded"]


def degrade_outputs(d: dict, cam: dict, rgb8, radiance, seed_seq, motion=None, *, label=None,
                    sequence_seed: int = 0, want=("rgb_degraded",)) -> dict:
    """The camera outputs ``want`` (of :data:`CAMERA_OUTPUTS`) of one frame, from one
    simulation (``d["degrade"]`` is ``paper`` or ``physical``): the paper's group applied to
    the clean 8-bit image ``rgb8``, or the camera equation and imaging chain applied to the
    linear ``radiance`` [W/(m²·sr)], drawing from ``numpy.random.default_rng(seed_seq)``;
    ``motion``: the frame's (L [px], θ [deg]) for the ``auto`` motion blur; ``label``: the
    frame's label, whose ``sun_dir_cam`` (the Sun's direction in the camera frame) and
    ``shadow_fraction`` (the visible fraction of the solar disc: none in Earth's umbra) set the
    stray light (None: no Sun); ``sequence_seed``: the camera's fixed maps' seed unless ``d``
    sets ``camera_seed`` (:func:`camera_seed`).

    Raises
    ------
    ValueError
        ``signal_e`` or ``saturation`` asked of another preset than ``physical``.
    """
    extra = [w for w in want if w != "rgb_degraded"]
    if extra and d["degrade"] != "physical":
        raise ValueError(f"{extra[0]} needs degrade = 'physical', got {d['degrade']!r}")
    rng = np.random.default_rng(seed_seq)
    if d["degrade"] == "paper":
        from .paper import PaperConfig, paper_degrade
        paper = PaperConfig(length_px=d["paper_blur_px"], angle_deg=d["paper_angle_deg"],
                            gaussian_var=d["paper_gaussian_var"])
        from .paper import _codes8
        levels = np.asarray(rgb8).astype(np.float32)  # float32(code)/255 in float32, as a vectorised division
        levels /= np.float32(255.0)
        out = paper_degrade(levels, d["paper_group"], paper, rng=rng)
        rgb_degraded = np.empty(out.shape, np.uint8)
        _codes8(out, rgb_degraded)  # quantise(out, 8) in one pass (out is in [0, 1])
        return {"rgb_degraded": rgb_degraded}
    from . import _checks
    from .chain import _simulate_frame
    from .exposure import physical_exposure
    signal = physical_exposure(radiance, f_number=d["f_number"], exposure_s=d["exposure_us"] * 1e-6,
                               pixel_pitch_m=cam["pixel_pitch_um"] * 1e-6,
                               quantum_efficiency=d["quantum_efficiency"], full_well_e=d["full_well_e"],
                               wavelengths_m=(WHITE_BALANCE_M,) * 3)
    sun = None if label is None else label.get("sun_dir_cam")
    visible = 1.0 if label is None else float(label.get("shadow_fraction", 1.0))
    visible = _checks.fraction("sun_fraction", visible)
    # simulate_frame without re-checking the signal the camera equation just made; the codes
    # straight from the demosaiced image (quantise(simulate_frame(...).image, 8) byte for byte)
    res = _simulate_frame(signal, physical_config(d, cam, motion), rng, sun if visible > 0 else None, visible,
                          camera_seed(d, sequence_seed), codes8=True)
    out = {"rgb_degraded": lambda: res.image, "signal_e": lambda: res.signal_e,
           "saturation": lambda: np.ascontiguousarray(res.saturation).view(np.uint8) * np.uint8(255)}  # True: 1
    return {w: out[w]() for w in want}
