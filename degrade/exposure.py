"""Exposure: from scene radiance [W/(m²·sr)] to the linear signal a sensor records.

* :func:`auto_exposure` scales so that a high percentile of the luminance over the pixels of
  interest maps to a chosen level (a photographer's "expose for the highlights"), the way an
  on-board auto-exposure loop would; the scale is returned so it can be recorded.
* :func:`physical_exposure` applies the camera equation: the irradiance on the sensor is
  E = π L / (4 N²) (on-axis, lens transmission 1, no vignetting; e.g. Jähne, *Digital Image
  Processing*, 6th ed., §3.3), a pixel of area p² collects E·p²·t_exp joules in the exposure,
  i.e. E·p²·t·λ/(h c) photons at the band's centre wavelength λ; the linear signal is the
  fraction of the full well those photons fill, QE·photons/FW (1.0 = full well).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import _checks
from ._jit import pjit_exact

__all__ = ["LIGHT_SPEED_M_S", "PLANCK_J_S", "auto_exposure", "physical_exposure"]

PLANCK_J_S = 6.62607015e-34
"""Planck constant h [J·s] (exact, SI 2019)."""
LIGHT_SPEED_M_S = 299792458.0
"""Speed of light in vacuum c [m/s] (exact)."""
_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 / sRGB luminance weights


def auto_exposure(radiance, mask=None, *, percentile: float = 99.5,
                  level: float = 0.9) -> tuple[np.ndarray, float]:
    """Scale linear radiance so a high percentile of its luminance maps to ``level``.

    Parameters
    ----------
    radiance : array_like of float, shape (H, W, 3)
        Linear radiance, finite and ≥ 0 [W/(m²·sr)].
    mask : array_like of bool, shape (H, W), optional
        Pixels that set the exposure (e.g. the target's mask); default: every pixel. Only
        pixels with non-zero luminance count.
    percentile : float, keyword-only
        Percentile of the luminance (Rec. 709 weights) that is mapped to ``level``, in
        (0, 100]. Default 99.5.
    level : float, keyword-only
        Linear signal the percentile maps to, > 0 (values above 1 saturate later). Default 0.9.

    Returns
    -------
    image : ndarray of float32, shape (H, W, 3)
        ``radiance · scale``; 1.0 is the top of the output range [1].
    scale : float
        The factor applied [1/(W/(m²·sr))]; 1.0 when no selected pixel has light.
    """
    img = _checks.image("radiance", radiance, ndim=(3,), channels=3)
    percentile = _checks.finite_scalar("percentile", percentile)
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile!r}")
    level = _checks.finite_scalar("level", level, positive=True)
    # elementwise, not ``img @ _LUMA``: a threaded BLAS product leaves its workers spinning,
    # which slows the next parallel kernel on a 2-core machine
    luma = img[..., 0] * _LUMA[0] + img[..., 1] * _LUMA[1] + img[..., 2] * _LUMA[2]
    sel = luma > 0
    if mask is not None:
        m = np.asarray(mask)
        if m.shape != luma.shape:
            raise ValueError(f"mask must have shape {luma.shape} (H, W), got {m.shape}")
        sel &= m.astype(bool)
    if not np.any(sel):
        return img.copy(), 1.0
    ref = float(np.percentile(luma[sel], percentile))
    scale = level / ref if ref > 0 else 1.0
    return img * np.float32(scale), scale


def physical_exposure(radiance, *, f_number: float, exposure_s: float, pixel_pitch_m: float,
                      quantum_efficiency: float = 0.6, full_well_e: float = 10000.0,
                      wavelengths_m=(600e-9, 530e-9, 460e-9)) -> np.ndarray:
    """Linear sensor signal of a radiance image through a lens (camera equation).

    Parameters
    ----------
    radiance : array_like of float, shape (H, W, 3)
        Linear radiance per colour channel, finite and ≥ 0 [W/(m²·sr)].
    f_number : float, keyword-only
        Lens f-number N = f/D, > 0 [1].
    exposure_s : float, keyword-only
        Exposure time t, > 0 [s].
    pixel_pitch_m : float, keyword-only
        Pixel pitch p (square pixels, 100 % fill factor), > 0 [m].
    quantum_efficiency : float, keyword-only
        QE in (0, 1] [e⁻/photon]. Default 0.6 (as :class:`degrade.sensor.SensorConfig`).
    full_well_e : float, keyword-only
        Full-well capacity, > 0 [e⁻]. Default 10 000.
    wavelengths_m : sequence of 3 float, keyword-only
        Centre wavelength of the R, G, B bands, > 0 [m]; each channel's energy is turned
        into photons at its wavelength. Default (600, 530, 460) nm.

    Returns
    -------
    signal : ndarray of float32, shape (H, W, 3)
        QE·photons/FW: 1.0 fills the well; values above 1 saturate in the sensor model [1].

    Notes
    -----
    E = π L/(4 N²) [W/m²] on axis (lens transmission 1, no cos⁴ fall-off);
    photons = E p² t λ/(h c); signal = QE · photons / FW. Matches
    ``SensorConfig(quantum_efficiency=QE, full_well_e=FW)`` with its default
    ``photons_at_one`` = FW/QE.
    """
    img = _checks.image("radiance", radiance, ndim=(3,), channels=3, values=False)  # values: in the kernel
    n = _checks.finite_scalar("f_number", f_number, positive=True)
    t = _checks.finite_scalar("exposure_s", exposure_s, positive=True)
    p = _checks.finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    qe = _checks.finite_scalar("quantum_efficiency", quantum_efficiency, positive=True)
    if qe > 1.0:
        raise ValueError(f"quantum_efficiency must be in (0, 1], got {quantum_efficiency!r}")
    fw = _checks.finite_scalar("full_well_e", full_well_e, positive=True)
    if isinstance(wavelengths_m, (str, bytes)) or np.ndim(wavelengths_m) != 1 or len(wavelengths_m) != 3:
        raise ValueError(f"wavelengths_m must be 3 wavelengths (R, G, B) [m], got {wavelengths_m!r}")
    lam = np.array([_checks.finite_scalar(f"wavelengths_m[{i}]", v, positive=True)
                    for i, v in enumerate(wavelengths_m)])
    out = np.empty(img.shape, np.float32)
    if _camera_equation(img, math.pi / (4.0 * n * n), p, t, np.tile(lam, img.shape[1]), PLANCK_J_S * LIGHT_SPEED_M_S,
                        qe, fw, out):
        _checks.image("radiance", img, ndim=(3,), channels=3)  # raises: a value is negative, NaN or inf
    return out


@pjit_exact
def _camera_equation(img, a, p, t, lam_row, hc, qe, fw, out):  # pragma: no cover - compiled
    """out = float32(qe·(((((L·a)·p)·p)·t)·λ/hc)/fw), one pass, the float64 operations in the
    order NumPy runs ``qe * (img * a * p * p * t * lam / hc) / fw`` (the same bits); rows of
    W·3 interleaved values, ``lam_row`` the wavelengths repeated W times (a loop that vectorises).
    Returns the number of values of ``img`` that are not in [0, inf) (negative, NaN or inf)."""
    h = img.shape[0]
    n = lam_row.size
    src = img.reshape(h, n)
    dst = out.reshape(h, n)
    bad = 0
    for i in numba.prange(h):
        s = src[i]
        d = dst[i]
        row_bad = 0
        for k in range(n):
            row_bad += not (s[k] >= 0.0 and s[k] < np.inf)
            x = np.float64(s[k]) * a
            x = x * p
            x = x * p
            x = x * t
            x = x * lam_row[k]
            x = x / hc
            d[k] = np.float32(qe * x / fw)
        bad += row_bad
    return bad
