"""Exposure: from scene radiance [W/(m²·sr)] to the linear signal a sensor records.

* :func:`auto_exposure` scales so that a high percentile of the luminance over the pixels of
  interest maps to a chosen level (a photographer's "expose for the highlights"), the way an
  on-board auto-exposure loop would; the scale is returned so it can be recorded.
* :func:`physical_exposure` applies the camera equation: the irradiance on the sensor is
  E = π L / (4 N²) (on-axis, lens transmission 1, no vignetting; e.g. Jähne, *Digital Image
  Processing*, 6th ed., §3.3), a pixel of area p² collects E·p²·t_exp joules in the exposure,
  i.e. E·p²·t·λ/(h c) photons at the band's centre wavelength λ; the linear signal is the
  fraction of the full well those photons fill, QE·photons/FW (SPEC §10: 1.0 = full well).
"""

from __future__ import annotations

import math

import numpy as np

from ._checks import finite_scalar

__all__ = ["LIGHT_SPEED_M_S", "PLANCK_J_S", "auto_exposure", "physical_exposure"]

PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_M_S = 299792458.0
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def auto_exposure(radiance, mask=None, *, percentile: float = 99.5, level: float = 0.9) -> tuple[np.ndarray, float]:
    """Scale linear radiance so the ``percentile`` of luminance (Rec. 709 weights) over
    ``mask`` (default: every pixel with non-zero radiance) maps to ``level``.

    Returns
    -------
    image : ndarray, float32, same shape
        Linear signal, 1.0 = the top of the output range [-].
    scale : float
        The factor applied [1/(W/(m²·sr))] (1.0 for a black image).
    """
    img = np.asarray(radiance, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"radiance must have shape (H, W, 3), got {img.shape}")
    if not np.all(np.isfinite(img)) or img.min() < 0:
        raise ValueError("radiance must be finite and >= 0")
    percentile = finite_scalar("percentile", percentile)
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile}")
    level = finite_scalar("level", level, positive=True)
    luma = img @ _LUMA.astype(np.float32)
    sel = luma > 0 if mask is None else (np.asarray(mask, dtype=bool) & (luma > 0))
    if not np.any(sel):
        return img.copy(), 1.0
    ref = float(np.percentile(luma[sel], percentile))
    scale = level / ref if ref > 0 else 1.0
    return (img * np.float32(scale)).astype(np.float32), scale


def physical_exposure(radiance, *, f_number: float, exposure_s: float, pixel_pitch_m: float,
                      quantum_efficiency: float = 0.6, full_well_e: float = 10000.0,
                      wavelengths_m=(600e-9, 530e-9, 460e-9)) -> np.ndarray:
    """Linear sensor signal (1.0 = full well) of radiance through a lens of f-number N with
    exposure time t on pixels of pitch p (see module notes), per channel at its centre
    wavelength; float32, same shape. Values above 1 saturate later in the sensor model."""
    img = np.asarray(radiance, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"radiance must have shape (H, W, 3), got {img.shape}")
    if not np.all(np.isfinite(img)) or img.min() < 0:
        raise ValueError("radiance must be finite and >= 0")
    N = finite_scalar("f_number", f_number, positive=True)
    t = finite_scalar("exposure_s", exposure_s, positive=True)
    p = finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    qe = finite_scalar("quantum_efficiency", quantum_efficiency, positive=True)
    fw = finite_scalar("full_well_e", full_well_e, positive=True)
    lam = np.asarray(wavelengths_m, dtype=np.float64)
    if lam.shape != (3,) or not np.all(np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError(f"wavelengths_m must be 3 positive wavelengths, got {wavelengths_m!r}")
    joules = img * (math.pi / (4.0 * N * N)) * p * p * t
    photons = joules * lam / (PLANCK_J_S * LIGHT_SPEED_M_S)
    return (qe * photons / fw).astype(np.float32)
