"""Point-spread functions on the pixel grid, each normalised to sum 1 (docs/degradation.md,
"Optics").

Every kernel is a float64 array of odd size whose centre pixel ``(K − 1)/2`` is the optical
axis of the blur, and a pure function of hashable parameters: it is built once per parameter
set and cached (:func:`functools.lru_cache`). Cached arrays are returned read-only; copy one
before modifying it.

Pixel coordinates: rows ``i`` grow downward, columns ``j`` to the right; angles are
counter-clockwise from the +column axis *as displayed*.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import special

from . import _checks

__all__ = [
    "AIRY_FIRST_ZERO",
    "airy_psf",
    "compose",
    "defocus_psf",
    "defocus_radius_px",
    "gaussian_psf",
    "motion_from_velocity",
    "motion_psf",
]

AIRY_FIRST_ZERO = 1.2196698912665045
"""First dark ring of the Airy pattern in units of λ f/D: j₁,₁/π (Born & Wolf §8.5.2)."""

_DELTA = np.ones((1, 1))
_DELTA.flags.writeable = False


def _frozen(kernel: np.ndarray) -> np.ndarray:
    kernel = kernel / kernel.sum()
    kernel.flags.writeable = False
    return kernel


def _subpixel_offsets(n: int) -> np.ndarray:
    """Centres of ``n`` equal sub-intervals of a pixel, relative to its centre [px]."""
    return (np.arange(n) + 0.5) / n - 0.5


def airy_psf(aperture_m: float, wavelength_m: float, focal_length_m: float, pixel_pitch_m: float,
             *, supersample: int = 9, radius_r1: float = 3.0) -> np.ndarray:
    """Diffraction PSF of a circular aperture (Airy pattern), integrated over each pixel.

    Parameters
    ----------
    aperture_m : float
        Entrance-pupil diameter D [m].
    wavelength_m : float
        Wavelength λ [m] (the chain uses one per colour channel, see
        :class:`degrade.chain.OpticsConfig`).
    focal_length_m : float
        Focal length f [m].
    pixel_pitch_m : float
        Pixel pitch p [m] (square pixels, 100 % fill factor).
    supersample : int, optional
        Samples per pixel side for the pixel integration (≥ 9). Odd values put a
        sample on each pixel centre.
    radius_r1 : float, optional
        Kernel half-width in units of the first-dark-ring radius r₁ (≥ 3). The
        kernel is at least 5×5 px.

    Returns
    -------
    psf : ndarray of float64, shape (K, K)
        Read-only kernel, sum 1, K = 2 max(2, ⌈radius_r1 · r₁/p⌉) + 1 [1].

    Notes
    -----
    Fraunhofer diffraction by a circular aperture (Born & Wolf, *Principles of Optics*,
    7th ed., §8.5.2, eq. 8.5(14)):

        I(r) ∝ [2 J₁(v)/v]²,  v = π D r/(λ f),  r₁ = 1.21967 λ f/D,

    with 83.8 % of the energy inside r₁. The kernel is the pixel-averaged intensity
    (``supersample²`` samples per pixel), truncated at ``radius_r1 · r₁`` and renormalised.
    Encircled energy (for tests): E(v) = 1 − J₀²(v) − J₁²(v) (Born & Wolf eq. 8.5(20)).

    References
    ----------
    M. Born, E. Wolf, Principles of Optics, 7th ed., Cambridge University Press, 1999,
    doi:10.1017/CBO9781139644181.
    """
    d = _checks.finite_scalar("aperture_m", aperture_m, positive=True)
    lam = _checks.finite_scalar("wavelength_m", wavelength_m, positive=True)
    f = _checks.finite_scalar("focal_length_m", focal_length_m, positive=True)
    p = _checks.finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    s = _checks.integer("supersample", supersample, 9, 101)
    rr = _checks.finite_scalar("radius_r1", radius_r1)
    if rr < 3.0:
        raise ValueError(f"radius_r1 must be >= 3, got {radius_r1!r}")
    return _airy(d, lam, f, p, s, rr)


@functools.lru_cache(maxsize=64)
def _airy(d: float, lam: float, f: float, p: float, s: int, rr: float) -> np.ndarray:
    r1_px = AIRY_FIRST_ZERO * lam * f / (d * p)
    half = max(2, math.ceil(rr * r1_px))
    if half > 512:
        raise ValueError(f"the Airy kernel would be {2 * half + 1} px wide (r1 = {r1_px:.1f} px); "
                         f"aperture_m/focal_length_m/pixel_pitch_m give an implausible blur")
    centres = np.arange(-half, half + 1, dtype=np.float64)
    x = (centres[:, None] + _subpixel_offsets(s)[None, :]).ravel()  # fine grid along one axis
    rho_px = np.hypot(x[:, None], x[None, :])
    v = (math.pi * d * p / (lam * f)) * rho_px
    amp = np.ones_like(v)
    np.divide(2.0 * special.j1(v), v, out=amp, where=v > 0.0)
    n = 2 * half + 1
    energy = (amp * amp).reshape(n, s, n, s).sum(axis=(1, 3))
    return _frozen(energy)


def gaussian_psf(sigma_px: float) -> np.ndarray:
    """Gaussian aberration PSF sampled at pixel centres (docs/degradation.md, "Optics").

    Parameters
    ----------
    sigma_px : float
        Standard deviation σ [px], ≥ 0; 0 gives the 1×1 identity kernel.

    Returns
    -------
    psf : ndarray of float64, shape (K, K)
        Read-only kernel h ∝ exp(−(i² + j²)/(2σ²)), K = 2⌈3σ⌉ + 1, sum 1 [1].
    """
    sigma = _checks.finite_scalar("sigma_px", sigma_px, nonnegative=True)
    return _gaussian(sigma)


@functools.lru_cache(maxsize=64)
def _gaussian(sigma: float) -> np.ndarray:
    if sigma == 0.0:
        return _DELTA
    half = math.ceil(3.0 * sigma)
    g = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    return _frozen(np.outer(g, g))


def defocus_radius_px(aperture_m: float, focal_length_m: float, pixel_pitch_m: float,
                      object_distance_m: float, focus_distance_m: float = math.inf) -> float:
    """Blur-circle radius of a thin lens for an object off the focus distance (R = c/(2p)).

    Parameters
    ----------
    aperture_m, focal_length_m, pixel_pitch_m : float
        Aperture diameter D, focal length f and pixel pitch p [m].
    object_distance_m : float
        Object distance s [m], > f.
    focus_distance_m : float, optional
        Focus distance s_f [m], > f; ``math.inf`` (default) focuses at infinity.

    Returns
    -------
    radius_px : float
        R = c/(2p) with c = D f |s − s_f| / (s (s_f − f)) the blur-circle diameter [px]
        (c → D f/s for s_f → ∞).
    """
    d = _checks.finite_scalar("aperture_m", aperture_m, positive=True)
    f = _checks.finite_scalar("focal_length_m", focal_length_m, positive=True)
    p = _checks.finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    s = _checks.finite_scalar("object_distance_m", object_distance_m, positive=True)
    if not s > f:
        raise ValueError(f"object_distance_m must be > focal_length_m = {f!r}, got {object_distance_m!r}")
    if focus_distance_m == math.inf:
        c = d * f / s
    else:
        sf = _checks.finite_scalar("focus_distance_m", focus_distance_m, positive=True)
        if not sf > f:
            raise ValueError(f"focus_distance_m must be > focal_length_m = {f!r} or math.inf, "
                             f"got {focus_distance_m!r}")
        c = d * f * abs(s - sf) / (s * (sf - f))
    return c / (2.0 * p)


def defocus_psf(radius_px: float, *, supersample: int = 16) -> np.ndarray:
    """Defocus PSF: a uniform disc (pillbox) integrated over each pixel.

    Parameters
    ----------
    radius_px : float
        Blur-circle radius R [px] (see :func:`defocus_radius_px`), ≥ 0; 0 gives the 1×1
        identity kernel.
    supersample : int, optional
        Samples per pixel side (≥ 16).

    Returns
    -------
    psf : ndarray of float64, shape (K, K)
        Read-only kernel ∝ fraction of each pixel inside the disc, K = 2⌈R⌉ + 1, sum 1 [1].
    """
    r = _checks.finite_scalar("radius_px", radius_px, nonnegative=True)
    s = _checks.integer("supersample", supersample, 16, 256)
    return _pillbox(r, s)


@functools.lru_cache(maxsize=64)
def _pillbox(r: float, s: int) -> np.ndarray:
    if r == 0.0:
        return _DELTA
    half = math.ceil(r)
    n = 2 * half + 1
    x = (np.arange(-half, half + 1, dtype=np.float64)[:, None] + _subpixel_offsets(s)[None, :]).ravel()
    inside = (x[:, None] ** 2 + x[None, :] ** 2) <= r * r
    frac = inside.reshape(n, s, n, s).sum(axis=(1, 3), dtype=np.float64)
    if frac.sum() == 0.0:  # disc smaller than one sub-sample: all light in the centre pixel
        return _DELTA
    return _frozen(frac)


def motion_psf(length_px: float, angle_deg: float, *, samples_per_px: int = 200) -> np.ndarray:
    """Linear motion-blur PSF: a uniform segment splatted bilinearly.

    Parameters
    ----------
    length_px : float
        Blur length L [px], ≥ 0 (image-plane speed × exposure time); 0 gives the 1×1
        identity kernel.
    angle_deg : float
        Direction θ [deg], counter-clockwise from the +column axis as displayed (rows grow
        downward).
    samples_per_px : int, optional
        Samples per pixel of length (≥ 200); at least 1000 samples in all.

    Returns
    -------
    psf : ndarray of float64, shape (K, K)
        Read-only kernel, K = 2⌈L/2⌉ + 3, centre c = (K − 1)/2, sum 1 [1].

    Notes
    -----
    h(i, j) = (1/L) ∫_{−L/2}^{L/2} Λ(j − c − s cos θ) Λ(i − c + s sin θ) ds with
    Λ(u) = max(0, 1 − |u|), evaluated by the midpoint rule. The kernel is point-symmetric, so
    convolution and correlation with it coincide.
    """
    length = _checks.finite_scalar("length_px", length_px, nonnegative=True)
    angle = _checks.finite_scalar("angle_deg", angle_deg)
    spp = _checks.integer("samples_per_px", samples_per_px, 200, 100_000)
    if length > 4096:
        raise ValueError(f"length_px must be <= 4096, got {length_px!r}")
    return _motion(length, angle, spp)


@functools.lru_cache(maxsize=64)
def _motion(length: float, angle_deg: float, spp: int) -> np.ndarray:
    if length == 0.0:
        return _DELTA
    k = 2 * math.ceil(length / 2.0) + 3
    c = (k - 1) / 2.0
    n = max(1000, math.ceil(spp * length))
    s = _subpixel_offsets(n) * length
    theta = math.radians(angle_deg)
    col = c + s * math.cos(theta)
    row = c - s * math.sin(theta)
    j0 = np.floor(col)
    i0 = np.floor(row)
    fj = col - j0
    fi = row - i0
    j0 = j0.astype(np.intp)
    i0 = i0.astype(np.intp)
    h = np.zeros(k * k)
    for di, wi in ((0, 1.0 - fi), (1, fi)):
        for dj, wj in ((0, 1.0 - fj), (1, fj)):
            h += np.bincount((i0 + di) * k + (j0 + dj), weights=wi * wj, minlength=k * k)
    return _frozen(h.reshape(k, k))


def motion_from_velocity(velocity_px_s, exposure_s: float) -> tuple[float, float]:
    """Motion-blur length and direction from the target's image-plane velocity.

    Parameters
    ----------
    velocity_px_s : array_like of float, shape (2,)
        (du/dt, dv/dt): the image velocity in pixel coordinates, u along columns (right) and
        v along rows (down) [px/s].
    exposure_s : float
        Exposure (integration) time t, ≥ 0 [s].

    Returns
    -------
    length_px : float
        L = |velocity| · t [px].
    angle_deg : float
        θ = atan2(−dv/dt, du/dt) in (−180, 180] [deg]: counter-clockwise from +u as displayed
        (docs/conventions.md), the convention of :func:`motion_psf` and
        :class:`degrade.chain.OpticsConfig` (rows grow downward, hence the minus sign).

    Notes
    -----
    A constant velocity during the exposure is assumed (the blur is a straight segment).
    The line PSF is point-symmetric, so the sign of the direction does not matter for the
    blur; θ is still reported as the direction of motion.
    """
    try:
        v = np.asarray(velocity_px_s, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.full(1, np.nan)
    if v.shape != (2,) or not np.all(np.isfinite(v)):
        raise ValueError(f"velocity_px_s must be 2 finite numbers (du/dt, dv/dt) [px/s], got {velocity_px_s!r}")
    t = _checks.finite_scalar("exposure_s", exposure_s, nonnegative=True)
    return float(math.hypot(v[0], v[1]) * t), float(math.degrees(math.atan2(-v[1], v[0])))


def compose(*kernels: np.ndarray) -> np.ndarray:
    """Convolve PSFs into one kernel (PSF_total = diffraction ⊛ aberration ⊛ …).

    Parameters
    ----------
    *kernels : ndarray, shape (K_i, L_i)
        Odd-sized, nonnegative, finite 2-D kernels.

    Returns
    -------
    psf : ndarray of float64, shape (Σ K_i − n + 1, Σ L_i − n + 1)
        Full linear convolution by FFT (the computation of :func:`scipy.signal.fftconvolve`
        without importing scipy.signal, ~0.5 s: :func:`_fftconvolve_full`), FFT round-off
        below 1e-12 of the peak set to 0, renormalised to sum 1 [1].
    """

    if not kernels:
        raise ValueError("compose needs at least one kernel, got none")
    out = None
    for idx, k in enumerate(kernels):
        k = np.asarray(k, dtype=np.float64)
        name = f"kernels[{idx}]"
        if k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0:
            raise ValueError(f"{name} must be a 2-D array of odd sizes, got shape {k.shape}")
        if not np.all(np.isfinite(k)) or k.min() < 0.0 or not k.sum() > 0.0:
            raise ValueError(f"{name} must be finite, >= 0 and have a positive sum")
        if k.size == 1:
            continue
        out = k if out is None else _fftconvolve_full(out, k)
    if out is None:
        return _DELTA
    out = np.where(out > 1e-12 * out.max(), out, 0.0)
    return out / out.sum()


def _fftconvolve_full(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Full 2-D linear convolution of real float64 arrays by FFT, the steps of
    ``scipy.signal.fftconvolve(a, b, mode="full")`` (SciPy 1.x ``_freq_domain_conv``: real FFTs
    of each padded to ``next_fast_len`` of the full size, product, inverse, crop; the same
    bits, tested) using only :mod:`scipy.fft`."""
    import scipy.fft
    shape = [a.shape[d] + b.shape[d] - 1 for d in (0, 1)]
    fshape = [scipy.fft.next_fast_len(n, True) for n in shape]
    spec = scipy.fft.rfftn(a, fshape, axes=(0, 1)) * scipy.fft.rfftn(b, fshape, axes=(0, 1))
    return scipy.fft.irfftn(spec, fshape, axes=(0, 1))[:shape[0], :shape[1]].copy()
