"""Paper-compatible degradation: motion blur, Poisson and Gaussian noise on 8-bit display
values, reproducing ``skimage.util.random_noise`` bit for bit (docs/degradation.md,
"Paper-compatible mode").

Groups (a composition, not the sum the paper's formula suggests):

* D1: B = round(255 · clip(I ⊛ h_motion(L = 15, θ = 30°)))/255 (blur, re-quantised to 8 bit)
* D2: clip(Poisson(B · vals)/vals), vals = 2^⌈log₂(number of distinct values of B)⌉
* D3: clip(B + N(0, 0.1²))
* D4: clip(clip(Poisson(B · vals)/vals) + N(0, 0.1²))

Random streams: ``rng`` is normalised with :func:`numpy.random.default_rng` and split with
``Generator.spawn(2)``; the Poisson step draws from child 0 and the Gaussian step from child
1, each exactly as ``random_noise(·, mode=…, rng=child)`` would (same calls, same order,
same float64 arithmetic). So with ``p, g = np.random.default_rng(seed).spawn(2)``:

    D4 == random_noise(random_noise(B, "poisson", rng=p), "gaussian", var=0.01, rng=g)
          .astype(np.float32)

with B in float64 (``random_noise`` of a float32 B rounds differently in about 10 % of pixels,
by one float32 ulp; this module computes in float64 as scikit-image does on float64 input)

and D2, D4 share their Poisson realisation for one seed, D3, D4 their Gaussian one. Two
streams let the Gaussian draws run concurrently with the Poisson draws (they do not depend
on each other).

Speed-ups that keep the numbers identical: the distinct values of B are counted in one pass
over its 8-bit codes (not with ``np.unique``); NumPy's Poisson sampler returns 0 for λ = 0
without consuming the stream, so only nonzero pixels are sampled; the Gaussian draws start
on a worker thread before the blur, as ``standard_normal`` (``Generator.normal(0, σ)`` is
0 + σ·z of the same draws z, so σ·z is formed in the final kernel instead of in an extra
pass); blur, look-ups, sums and clipping run in Numba kernels that perform exactly
random_noise's float64 operations (no fused multiply-add: no fastmath).

References
----------
scikit-image ``skimage/util/noise.py`` (``random_noise``), version 0.26; S. van der Walt et
al., "scikit-image: image processing in Python", PeerJ 2:e453 (2014),
doi:10.7717/peerj.453.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from . import _checks
from ._jit import jit_exact, pjit_exact
from ._pool import pool
from .convolve import convolve_image
from .psf import motion_psf

__all__ = [
    "PAPER_GROUPS",
    "PaperConfig",
    "gaussian_noise",
    "paper_blur",
    "paper_degrade",
    "poisson_noise",
]

PAPER_GROUPS = {"D1": ("blur",), "D2": ("blur", "poisson"), "D3": ("blur", "gaussian"),
                "D4": ("blur", "poisson", "gaussian")}
"""Degradation groups of the paper and their steps, in order."""

_LUT8 = np.arange(256) / 255.0  # float64 value of each 8-bit code, as img_as_float computes it


@dataclass(frozen=True, slots=True)
class PaperConfig:
    """Parameters of the paper's degradation (defaults: the paper's values).

    Attributes
    ----------
    length_px : float
        Motion-blur length L [px]. Default 15.
    angle_deg : float
        Motion-blur direction θ [deg], counter-clockwise from +column as displayed. Default 30.
    gaussian_var : float
        Variance of the additive Gaussian noise [1²] (σ = 0.1 for 0.01). Default 0.01.
    mode : {"reflect", "mirror"}
        Border extension of the blur (see :mod:`degrade.convolve`). Default "reflect".
    """

    length_px: float = 15.0
    angle_deg: float = 30.0
    gaussian_var: float = 0.01
    mode: str = "reflect"

    def __post_init__(self):
        object.__setattr__(self, "length_px", _checks.finite_scalar("length_px", self.length_px, nonnegative=True))
        object.__setattr__(self, "angle_deg", _checks.finite_scalar("angle_deg", self.angle_deg))
        object.__setattr__(self, "gaussian_var",
                           _checks.finite_scalar("gaussian_var", self.gaussian_var, nonnegative=True))
        _checks.one_of("mode", self.mode, ("reflect", "mirror"))


@pjit_exact
def _codes8(x, out):  # pragma: no cover - compiled
    """out = rint(255 · clip(x, 0, 1)) as uint8 (float64 product, round half to even)."""
    xf = x.ravel()
    of = out.ravel()
    for k in numba.prange(xf.size):
        v = min(max(np.float64(xf[k]), 0.0), 1.0)
        of[k] = np.uint8(np.rint(255.0 * v))


@jit_exact
def _code_census(codes):  # pragma: no cover - compiled
    """(number of nonzero codes, number of distinct codes) of a uint8 image, one pass."""
    cf = codes.ravel()
    seen = np.zeros(256, np.bool_)
    n = 0
    for k in range(cf.size):
        c = cf[k]
        seen[c] = True
        n += c != 0
    return n, np.count_nonzero(seen)


@jit_exact
def _nonzero_means(codes, lut, idx, lam):  # pragma: no cover - compiled
    """idx, lam = flat indices (C order) of the nonzero codes and lut[code] there (``lut``:
    float64 per code); both one longer than the count (each slot is written, the index
    advancing only past a nonzero code: no branch)."""
    cf = codes.ravel()
    n = 0
    for k in range(cf.size):
        c = cf[k]
        idx[n] = k
        lam[n] = lut[c]
        n += c != 0


@pjit_exact
def _requantise(x, out):  # pragma: no cover - compiled
    """out = float32(rint(255 · clip(x, 0, 1))/255): step 1 alone (equal to float32(_LUT8[codes]))."""
    xf = x.ravel()
    of = out.ravel()
    for k in numba.prange(xf.size):
        v = min(max(np.float64(xf[k]), 0.0), 1.0)
        of[k] = np.float32(np.rint(255.0 * v) / 255.0)


@jit_exact
def _scatter_counts(idx, counts, vals, out):  # pragma: no cover - compiled
    """out (zeros) [idx] = min(counts/vals, 1): the clipped Poisson step."""
    of = out.ravel()
    for n in range(idx.size):
        of[idx[n]] = min(counts[n] / vals, 1.0)


@pjit_exact
def _add_clip(base, lut, z, sigma, out):  # pragma: no cover - compiled
    """out = float32(clip(lut[base] + sigma·z, 0, 1)): random_noise's float64 sum with
    Generator.normal's noise 0.0 + sigma·z (z standard normal; adding 0.0 changes nothing)."""
    bf = base.ravel()
    zf = z.ravel()
    of = out.ravel()
    for k in numba.prange(bf.size):
        of[k] = np.float32(min(max(lut[bf[k]] + sigma * zf[k], 0.0), 1.0))


@pjit_exact
def _add_clip_sparse(idx, counts, vals, z, sigma, out):  # pragma: no cover - compiled
    """D4: the clipped Poisson image is 0 except at idx, where it is min(counts/vals, 1); add
    the noise sigma·z (float64) and clip. Equal to _add_clip on the dense image."""
    zf = z.ravel()
    of = out.ravel()
    for k in numba.prange(zf.size):
        of[k] = np.float32(min(max(0.0 + sigma * zf[k], 0.0), 1.0))
    for n in numba.prange(idx.size):
        k = idx[n]
        of[k] = np.float32(min(max(min(counts[n] / vals, 1.0) + sigma * zf[k], 0.0), 1.0))


def _vals(n_distinct: int) -> np.float64:
    """random_noise's scale: 2^⌈log₂ n⌉ as a NumPy float64 (same expression)."""
    return 2 ** np.ceil(np.log2(n_distinct))


def _distinct_count(img: np.ndarray) -> int:
    """len(np.unique(img)), via a histogram of 8-bit codes when img lies on that grid."""
    codes = np.rint(img.astype(np.float64) * 255.0)
    if np.array_equal((codes / 255.0).astype(img.dtype), img):
        return int(np.count_nonzero(np.bincount(codes.astype(np.intp).ravel(), minlength=256)))
    return int(np.unique(img).size)


def paper_blur(image, config: PaperConfig = PaperConfig()) -> np.ndarray:
    """Step 1 (group D1): motion blur, clip, re-quantise to 8 bits.

    Parameters
    ----------
    image : array_like of float, shape (H, W, C) or (H, W)
        Display-encoded (8-bit render as float) values in [0, 1] [1].
    config : PaperConfig, optional
        Blur length, angle and border mode.

    Returns
    -------
    blurred : ndarray of float32, shape like ``image``
        round(255 · clip(image ⊛ h_motion, 0, 1))/255 [1].
    """
    blurred = _blur(_paper_input(image), config)
    _requantise(blurred, blurred)
    return blurred


def _paper_input(image) -> np.ndarray:
    return _checks.image("image", image, max_value=1.0)


def _blur(img: np.ndarray, config: PaperConfig) -> np.ndarray:
    _checks.instance("config", config, PaperConfig)
    return convolve_image(img, motion_psf(config.length_px, config.angle_deg), mode=config.mode)


def poisson_noise(image, *, rng=None) -> np.ndarray:
    """Poisson noise exactly as ``skimage.util.random_noise(image, mode="poisson", rng=rng)``.

    Parameters
    ----------
    image : array_like of float32 or float64
        Values in [0, 1] [1].
    rng : numpy.random.Generator or int or None, keyword-only
        Random source, normalised with :func:`numpy.random.default_rng`.

    Returns
    -------
    out : ndarray of float32, shape like ``image``
        clip(Poisson(image · vals)/vals, 0, 1), vals = 2^⌈log₂(number of distinct values)⌉;
        equal to ``random_noise(...).astype(np.float32)`` [1].
    """
    img = _checks.image("image", image, ndim=tuple(range(1, 5)), max_value=1.0, keep_float64=True)
    rng = np.random.default_rng(rng)
    vals = _vals(_distinct_count(img))
    out = rng.poisson(img.astype(np.float64) * vals) / float(vals)
    return np.minimum(out, 1.0).astype(np.float32)


def gaussian_noise(image, *, var: float = 0.01, mean: float = 0.0, rng=None) -> np.ndarray:
    """Additive Gaussian noise exactly as ``random_noise(image, mode="gaussian", …)``.

    Parameters
    ----------
    image : array_like of float32 or float64
        Values in [0, 1] [1].
    var, mean : float, optional
        Noise variance [1²] and mean [1] (defaults 0.01 and 0, as in scikit-image).
    rng : numpy.random.Generator or int or None, keyword-only
        Random source, normalised with :func:`numpy.random.default_rng`.

    Returns
    -------
    out : ndarray of float32, shape like ``image``
        clip(image + N(mean, var), 0, 1), the sum taken in float64; equal to
        ``random_noise(...).astype(np.float32)`` [1].
    """
    img = _checks.image("image", image, ndim=tuple(range(1, 5)), max_value=1.0, keep_float64=True)
    var = _checks.finite_scalar("var", var, nonnegative=True)
    mean = _checks.finite_scalar("mean", mean)
    noise = np.random.default_rng(rng).normal(mean, var ** 0.5, img.shape)
    return np.clip(img.astype(np.float64) + noise, 0.0, 1.0).astype(np.float32)


def paper_degrade(image, group: str = "D4", config: PaperConfig = PaperConfig(), *, rng=None) -> np.ndarray:
    """Degrade a display-encoded image as the paper did (groups D1–D4; docs/degradation.md,
    "Paper-compatible mode").

    Parameters
    ----------
    image : array_like of float, shape (H, W, C) or (H, W)
        The 8-bit render as float in [0, 1] (float32; other floats are converted) [1].
    group : {"D1", "D2", "D3", "D4"}, optional
        Blur; blur + Poisson; blur + Gaussian; all three (:data:`PAPER_GROUPS`).
    config : PaperConfig, optional
        Blur and noise parameters.
    rng : numpy.random.Generator or int or None, keyword-only
        Random source; split with ``spawn(2)`` into the Poisson and Gaussian streams (see
        the module docstring).

    Returns
    -------
    out : ndarray of float32, shape like ``image``
        Degraded values in [0, 1] [1].
    """
    steps = PAPER_GROUPS[_checks.one_of("group", group, PAPER_GROUPS)]
    img = _paper_input(image)
    _checks.instance("config", config, PaperConfig)
    rng = np.random.default_rng(rng)
    if steps == ("blur",):  # deterministic: no streams spawned
        blurred = _blur(img, config)
        _requantise(blurred, blurred)
        return blurred
    rng_poisson, rng_gauss = rng.spawn(2)
    noise, sigma = None, config.gaussian_var ** 0.5  # as random_noise: var ** 0.5
    if "gaussian" in steps:  # independent of everything else: sample while we blur
        noise = pool().submit(rng_gauss.standard_normal, img.shape)  # the draws of rng.normal(0, σ)
    blurred = _blur(img, config)
    codes = np.empty(img.shape, np.uint8)
    _codes8(blurred, codes)
    out = blurred  # reused as the output buffer
    if "poisson" in steps:
        n_nonzero, n_distinct = _code_census(codes)
        vals = _vals(n_distinct)
        idx, lam = np.empty(n_nonzero + 1, np.int64), np.empty(n_nonzero + 1, np.float64)
        _nonzero_means(codes, _LUT8 * vals, idx, lam)
        idx, lam = idx[:n_nonzero], lam[:n_nonzero]
        counts = rng_poisson.poisson(lam)  # (B·vals at the nonzero pixels) λ = 0 elsewhere: no draws
        if noise is None:
            out.fill(0.0)
            _scatter_counts(idx, counts, float(vals), out)
        else:
            _add_clip_sparse(idx, counts, float(vals), noise.result(), sigma, out)
    else:
        _add_clip(codes, _LUT8, noise.result(), sigma, out)
    return out
