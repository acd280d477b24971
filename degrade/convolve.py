"""Image convolution with mirror padding: direct for small kernels, FFT for large ones.

Both methods compute the same true convolution (the kernel is flipped, as in
:func:`scipy.ndimage.convolve`) of every channel, with the image extended by reflection:

* ``"reflect"`` (default): half-sample symmetric, ``d c b a | a b c d | d c b a`` (the edge
  pixel is repeated) — :func:`scipy.ndimage.convolve` ``mode="reflect"``, NumPy pad
  ``"symmetric"``.
* ``"mirror"``: whole-sample symmetric, ``d c b | a b c d | c b a`` —
  :func:`scipy.ndimage.convolve` ``mode="mirror"``, NumPy pad ``"reflect"``, OpenCV
  ``BORDER_REFLECT_101``.

``method="auto"`` picks by the number of nonzero kernel taps, from timings on a 1280×960×3
float32 frame on a 2-core machine (``benchmarks/bench_degrade.py``, BENCHMARKS.md):
the direct kernel's cost grows with the tap count, the FFT's hardly depends on the kernel
size, so direct wins up to ``DIRECT_MAX_TAPS`` taps. The direct kernel works on the
interleaved rows (W·C values) of a padded copy without transposing; per-channel weights are
laid out as a repeating pattern so the inner loop still vectorises. For the physical chain,
``_convolve_sites`` gives the RGGB mosaic of the direct convolution without a padded copy,
summing only the channel each photosite keeps (the same bits). Composite optical PSFs
(Airy ⊛ defocus ⊛ motion) are not
separable, so no separable path is offered. The choice never depends on the machine, so a
given input always takes the same code path (byte-reproducible output).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.fft

from . import _checks
from ._jit import pjit_exact

__all__ = ["DIRECT_MAX_TAPS", "PAD_MODES", "convolve_image"]

PAD_MODES = {"reflect": "symmetric", "mirror": "reflect"}
"""Padding modes (scipy.ndimage names) → :func:`numpy.pad` modes."""

DIRECT_MAX_TAPS = {"shared": 300, "per_channel": 150}
"""Largest number of nonzero taps convolved directly (else FFT), per kernel layout."""


@numba.njit(inline="always", cache=True)
def _four_rows(pad, di, dj, i, t, n):  # pragma: no cover - compiled
    """The padded rows (n values each) that taps t … t + 3 add into output row i."""
    return (pad[i + di[t], dj[t]:dj[t] + n], pad[i + di[t + 1], dj[t + 1]:dj[t + 1] + n],
            pad[i + di[t + 2], dj[t + 2]:dj[t + 2] + n], pad[i + di[t + 3], dj[t + 3]:dj[t + 3] + n])


@pjit_exact
def _convolve_shared(pad, di, dj, w, out):  # pragma: no cover - compiled
    """out[i, k] += Σ_t w[t] · pad[i + di[t], k + dj[t]]  (rows of W·C interleaved values), the
    taps added one after the other in their order, four per pass over the row (one load and
    store of ``out`` per four taps; the same sums, the same rounding)."""
    height, n = out.shape
    nt = di.size
    for i in numba.prange(height):
        o = out[i]
        t = 0
        while t + 4 <= nt:
            a0, a1, a2, a3 = _four_rows(pad, di, dj, i, t, n)
            w0, w1, w2, w3 = w[t], w[t + 1], w[t + 2], w[t + 3]
            for k in range(n):
                o[k] = (((o[k] + w0 * a0[k]) + w1 * a1[k]) + w2 * a2[k]) + w3 * a3[k]
            t += 4
        while t < nt:
            wt = w[t]
            a = pad[i + di[t], dj[t]:dj[t] + n]
            for k in range(n):
                o[k] += wt * a[k]
            t += 1


@pjit_exact
def _convolve_interleaved(pad, di, dj, wpat, out):  # pragma: no cover - compiled
    """As _convolve_shared with per-channel weights: wpat[t] repeats tap t's C weights, so the
    inner loop over a chunk of wpat.shape[1] values (a multiple of C) vectorises; four taps per
    pass, each added in its order (the same sums, the same rounding)."""
    height, n = out.shape
    m = wpat.shape[1]
    full = n - n % m
    nt = di.size
    for i in numba.prange(height):
        o = out[i]
        t = 0
        while t + 4 <= nt:
            a0, a1, a2, a3 = _four_rows(pad, di, dj, i, t, n)
            w0, w1, w2, w3 = wpat[t], wpat[t + 1], wpat[t + 2], wpat[t + 3]
            for c0 in range(0, full, m):
                oc = o[c0:c0 + m]
                b0, b1, b2, b3 = a0[c0:c0 + m], a1[c0:c0 + m], a2[c0:c0 + m], a3[c0:c0 + m]
                for k in range(m):
                    oc[k] = (((oc[k] + w0[k] * b0[k]) + w1[k] * b1[k]) + w2[k] * b2[k]) + w3[k] * b3[k]
            for k in range(full, n):
                q = k - full
                o[k] = (((o[k] + w0[q] * a0[k]) + w1[q] * a1[k]) + w2[q] * a2[k]) + w3[q] * a3[k]
            t += 4
        while t < nt:
            a = pad[i + di[t], dj[t]:dj[t] + n]
            wr = wpat[t]
            for c0 in range(0, full, m):
                oc = o[c0:c0 + m]
                ac = a[c0:c0 + m]
                for k in range(m):
                    oc[k] += wr[k] * ac[k]
            for k in range(full, n):
                o[k] += wr[k - full] * a[k]
            t += 1


@numba.njit(inline="always", cache=True)
def _site_run(planes, c, p, di, dj, i, t, n):  # pragma: no cover - compiled
    """The n values of channel c that tap t adds into the sites of column parity p of row i."""
    e = p + dj[t]
    s = e // 2
    return planes[c, e % 2, i + di[t], s:s + n]


@pjit_exact
def _convolve_rggb(planes, di, dj, w, nt, out):  # pragma: no cover - compiled
    """out[i, j] = Σ_t w[c, t]·x[i + di[c, t] − r1, j + dj[c, t] − r2, c] with c = i%2 + j%2
    (the channel an RGGB photosite keeps) over channel c's nt[c] taps, added one by one in
    their order from 0, in float32: the values of ``_convolve_interleaved`` at those sites (the
    same sums, the same rounding: the taps it adds with weight 0 for this channel add +0 to a
    sum that is never −0, and the image is finite) for a third of its work or less.
    ``planes``: :func:`_site_planes`; each row's sites of one column parity are summed in a
    contiguous buffer, four taps per pass."""
    height, width = out.shape
    for i in numba.prange(height):
        acc = np.empty((width + 1) // 2, np.float32)
        o = out[i]
        for p in range(2):
            c = i % 2 + p
            dic, djc, wc, ntc = di[c], dj[c], w[c], nt[c]
            n = (width - p + 1) // 2
            a = acc[:n]
            a[:] = 0.0
            t = 0
            while t + 4 <= ntc:
                a0 = _site_run(planes, c, p, dic, djc, i, t, n)
                a1 = _site_run(planes, c, p, dic, djc, i, t + 1, n)
                a2 = _site_run(planes, c, p, dic, djc, i, t + 2, n)
                a3 = _site_run(planes, c, p, dic, djc, i, t + 3, n)
                w0, w1, w2, w3 = wc[t], wc[t + 1], wc[t + 2], wc[t + 3]
                for m in range(n):
                    a[m] = (((a[m] + w0 * a0[m]) + w1 * a1[m]) + w2 * a2[m]) + w3 * a3[m]
                t += 4
            while t < ntc:
                a0 = _site_run(planes, c, p, dic, djc, i, t, n)
                w0 = wc[t]
                for m in range(n):
                    a[m] += w0 * a0[m]
                t += 1
            for m in range(n):
                o[2 * m + p] = a[m]


_CHUNK = 192  # values per vectorised chunk of the per-channel kernel (a multiple of 1, 2, 3, 4)


def _kernel_stack(kernel, channels: int) -> tuple[np.ndarray, bool]:
    """Validate ``kernel``; return it as (P, K1, K2) float64 and whether it is shared."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim == 2:
        k = k[None]
    elif k.ndim != 3 or k.shape[0] != channels:
        raise ValueError(f"kernel must have shape (K1, K2) or ({channels}, K1, K2) for this image, "
                         f"got {np.shape(kernel)}")
    if k.shape[1] % 2 == 0 or k.shape[2] % 2 == 0:
        raise ValueError(f"kernel sizes must be odd (centre pixel (K - 1)/2), got {k.shape[1:]}")
    if not np.all(np.isfinite(k)):
        raise ValueError("kernel must be finite, got NaN/inf value(s)")
    shared = k.shape[0] == 1 or bool(np.all(k == k[:1]))
    return (k[:1] if shared else k), shared


def convolve_image(image, kernel, *, mode: str = "reflect", method: str = "auto") -> np.ndarray:
    """Convolve every channel of an image with a PSF, mirror-padded at the borders.

    Parameters
    ----------
    image : array_like of float, shape (H, W) or (H, W, C)
        Nonnegative, finite image (float32 is used as is; other floats are converted) [any].
    kernel : array_like of float, shape (K1, K2) or (C, K1, K2)
        One kernel for all channels, or one per channel; odd sizes, centre at (K − 1)/2.
    mode : {"reflect", "mirror"}, optional
        Border extension (scipy.ndimage names; see the module docstring). The chain uses
        mirror ("reflect") padding; ``"reflect"`` repeats the edge pixel.
    method : {"auto", "direct", "fft"}, optional
        ``"auto"`` picks by nonzero tap count (:data:`DIRECT_MAX_TAPS`).

    Returns
    -------
    out : ndarray of float32, shape like ``image``
        ``image ⊛ kernel`` [unit of ``image``]. When the kernel is nonnegative, FFT round-off
        below 0 is clamped to 0 so positivity is preserved as in exact arithmetic.
    """
    img = _checks.image("image", image)
    pad_mode = PAD_MODES[_checks.one_of("mode", mode, PAD_MODES)]
    _checks.one_of("method", method, ("auto", "direct", "fft"))
    channels = img.shape[2] if img.ndim == 3 else 1
    k, shared = _kernel_stack(kernel, channels)
    if k.shape[1:] == (1, 1):  # a scale per channel (or one for all)
        return img * k[:, 0, 0].astype(np.float32)
    kf = k[:, ::-1, ::-1].reshape(k.shape[0], -1)  # flipped: convolution, not correlation
    taps = np.flatnonzero(np.any(kf != 0.0, axis=0))  # nonzero taps of the *flipped* kernel
    if method == "auto":
        method = "direct" if taps.size <= DIRECT_MAX_TAPS["shared" if shared else "per_channel"] else "fft"
    r1, r2 = k.shape[1] // 2, k.shape[2] // 2
    h, w = img.shape[:2]
    if method == "direct":
        di, dj = np.divmod(taps, k.shape[2])
        weights = np.ascontiguousarray(kf[:, taps].T, dtype=np.float32)  # (T, 1 or C)
        pad = np.pad(img.reshape(h, w, channels), ((r1, r1), (r2, r2), (0, 0)), mode=pad_mode)
        pad = pad.reshape(h + 2 * r1, -1)  # rows of (W + 2 r2)·C interleaved values
        out = np.zeros((h, w * channels), np.float32)
        if shared:
            _convolve_shared(pad, di, dj * channels, weights[:, 0].copy(), out)
        else:
            _convolve_interleaved(pad, di, dj * channels, np.tile(weights, (1, _CHUNK // channels)), out)
        return out.reshape(img.shape)
    planes = img[None] if img.ndim == 2 else img.transpose(2, 0, 1)
    planes = np.pad(planes, ((0, 0), (r1, r1), (r2, r2)), mode=pad_mode)
    shape = (scipy.fft.next_fast_len(planes.shape[1], real=True),
             scipy.fft.next_fast_len(planes.shape[2], real=True))
    spec = scipy.fft.rfft2(planes, s=shape, workers=-1)
    spec *= scipy.fft.rfft2(k.astype(np.float32), s=shape, workers=-1)
    full = scipy.fft.irfft2(spec, s=shape, workers=-1)
    out = full[:, 2 * r1:2 * r1 + h, 2 * r2:2 * r2 + w]
    if k.min() >= 0.0:
        np.maximum(out, 0.0, out=out)
    out = out[0] if img.ndim == 2 else out.transpose(1, 2, 0)
    return np.ascontiguousarray(out, dtype=np.float32)


def _reflected(k: int, n: int, whole: int) -> int:
    """Index k of a row or column extended by one reflection into [0, n): half-sample
    (``"reflect"``, edge repeated) or, with ``whole``, whole-sample (``"mirror"``)."""
    return -k - 1 + whole if k < 0 else 2 * n - 1 - k - whole if k >= n else k


def _site_planes(img: np.ndarray, r1: int, r2: int, whole: int) -> np.ndarray:
    """planes[c, q, r, u] = the H×W×3 ``img`` extended by reflection (:func:`_reflected`; H > r1,
    W > r2) at row r − r1, column 2u + q − r2, channel c (0 past the padded width): each channel's
    padded columns split by parity, so the sites of one colour and column parity read contiguous
    runs. Strided copies of the image; the border columns and rows copied from their mirror."""
    h, w = img.shape[:2]
    wp = w + 2 * r2
    nu = (wp + 1) // 2
    planes = np.empty((3, 2, h + 2 * r1, nu), np.float32)
    inside = planes[:, :, r1:r1 + h]
    for q in range(2):
        lo, hi = (r2 - q + 1) // 2, (w + r2 - q + 1) // 2  # u of the columns 2u + q − r2 in [0, W)
        inside[:, q, :, lo:hi] = img[:, 2 * lo + q - r2:2 * hi + q - r2:2].transpose(2, 0, 1)
        for u in (*range(lo), *range(hi, nu)):
            col = 2 * u + q
            inside[:, q, :, u] = img[:, _reflected(col - r2, w, whole)].T if col < wp else 0.0
    for r in (*range(r1), *range(r1 + h, h + 2 * r1)):
        planes[:, :, r] = inside[:, :, _reflected(r - r1, h, whole)]
    return planes


def _convolve_sites(img: np.ndarray, kernel, mode: str = "reflect") -> np.ndarray | None:
    """The RGGB mosaic (:func:`degrade.sensor.mosaic_rggb`) of ``convolve_image(img, kernel,
    mode=mode)`` for a checked H×W×3 float32 ``img``, byte for byte, computing only the
    channel each photosite keeps (a third of the direct kernel's work, no padded copy of the
    image); None where ``convolve_image`` would not take the direct path (FFT, a 1×1 kernel)
    or a side of the image does not exceed the kernel's radius (repeated reflection)."""
    k, shared = _kernel_stack(kernel, 3)
    if k.shape[1:] == (1, 1):
        return None
    kf = k[:, ::-1, ::-1].reshape(k.shape[0], -1)
    taps = np.flatnonzero(np.any(kf != 0.0, axis=0))
    r1, r2 = k.shape[1] // 2, k.shape[2] // 2
    h, w = img.shape[:2]
    if taps.size > DIRECT_MAX_TAPS["shared" if shared else "per_channel"] or h <= r1 or w <= r2:
        return None
    weights = np.broadcast_to(kf[:, taps], (3, taps.size)).astype(np.float32)
    nt = np.count_nonzero(weights, axis=1)
    di, dj = np.zeros((3, taps.size), np.int64), np.zeros((3, taps.size), np.int64)
    w3 = np.zeros((3, taps.size), np.float32)
    for c in range(3):  # each channel's nonzero taps, in the order of ``taps``
        keep = weights[c] != 0.0
        di[c, :nt[c]], dj[c, :nt[c]] = np.divmod(taps[keep], k.shape[2])
        w3[c, :nt[c]] = weights[c, keep]
    planes = _site_planes(img, r1, r2, int(PAD_MODES[mode] == "reflect"))
    out = np.empty((h, w), np.float32)
    _convolve_rggb(planes, di, dj, w3, nt.astype(np.int64), out)
    return out
