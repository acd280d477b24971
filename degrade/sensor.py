"""Bayer sensor: RGGB mosaic, photon shot noise, full well, read noise, ADC, demosaic.

    I_lin (H×W×3) → RGGB mosaic → Φ = I·Φ_max photons → e = min(Poisson(QE·Φ + D_c·t), FW)
        + N(0, σ_r²) → DN = clip(round(e/g + offset), 0, 2^b − 1) → DN/(2^b − 1) → demosaic

Default parameters (docs/degradation.md, "Sensor") describe a plausible space-grade
global-shutter CMOS camera of the Sony IMX250 class (3.45 µm pixels, 12-bit ADC). Published
EMVA 1288 measurements of IMX250 cameras report roughly QE ≈ 0.65 at 525 nm, saturation
≈ 10 500 e⁻ and temporal dark noise ≈ 2.3 e⁻; the defaults (QE 0.6, FW 10 000 e⁻, σ_r 5 e⁻)
are rounder and more conservative (a radiation-aged or faster-read-out detector). Check a
specific camera's data sheet before quoting these as its values.

Randomness: everything comes from the one ``rng`` passed in. The photosites (C order) are
cut into ``n = min(8, max(1, size // 65536))`` equal blocks; block k draws its Poisson
values and then its read-noise values from child k of ``rng.spawn(n)``. Blocks run on
parallel threads, and the split depends only on the image size, so a seed fixes the output
byte for byte on any machine and any number of cores. Where a tenth or more of a block's means
are 0 only the others are passed to NumPy's sampler (which draws nothing for λ = 0): the same
values, and the same stream for the read noise after them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numba
import numpy as np
import OpenImageIO as oiio

from . import _checks
from ._jit import jit_exact, pjit_exact
from ._pool import pool

__all__ = [
    "DEMOSAIC_ALGORITHMS",
    "SensorConfig",
    "demosaic",
    "mosaic_rggb",
    "sensor_readout",
    "simulate_sensor",
]

DEMOSAIC_ALGORITHMS = ("MHC", "linear")
"""OpenImageIO ``ImageBufAlgo.demosaic`` algorithms: Malvar–He–Cutler and bilinear."""


@dataclass(frozen=True, slots=True)
class SensorConfig:
    """Sensor and ADC parameters.

    Attributes
    ----------
    quantum_efficiency : float
        QE, electrons per photon, in (0, 1] [1]. Default 0.6.
    full_well_e : float
        Full-well capacity FW [e⁻]. Default 10 000.
    read_noise_e : float
        Read-noise standard deviation σ_r [e⁻], ≥ 0 (0: off). Default 5.
    bit_depth : int
        ADC resolution b [bit], 1…16. Default 12.
    offset_dn : float
        ADC offset (black level), kept in the output (not subtracted) [DN]. Default 0.
    dark_current_e_per_s : float
        Dark current D_c [e⁻/s], ≥ 0. Default 0.
    exposure_s : float
        Exposure time t_exp [s]; enters only through the dark signal D_c·t_exp (the light
        level is set by ``photons_at_one``). Default 0.01.
    gain_e_per_dn : float or None
        Conversion gain g [e⁻/DN]; None → FW/(2^b − 1), so a full well is full scale.
    photons_at_one : float or None
        Φ_max, mean photons per pixel for a linear value of 1 [photon]; None → FW/QE, so
        1.0 just fills the well.
    shot_noise : bool
        Draw the electron count from a Poisson distribution (False: use its mean).
    quantise : bool
        Round to whole DN in the ADC (False: keep the continuous value; for ablations).
    demosaic : {"MHC", "linear"} or None
        Colour filter array and OpenImageIO demosaic algorithm; None: no colour filter
        array (every pixel measures all channels, as a 3-chip camera; for ablations and
        monochrome H×W images).
    """

    quantum_efficiency: float = 0.6
    full_well_e: float = 10_000.0
    read_noise_e: float = 5.0
    bit_depth: int = 12
    offset_dn: float = 0.0
    dark_current_e_per_s: float = 0.0
    exposure_s: float = 0.01
    gain_e_per_dn: float | None = None
    photons_at_one: float | None = None
    shot_noise: bool = True
    quantise: bool = True
    demosaic: str | None = "MHC"

    def __post_init__(self):
        qe = _checks.finite_scalar("quantum_efficiency", self.quantum_efficiency, positive=True)
        if qe > 1.0:
            raise ValueError(f"quantum_efficiency must be in (0, 1], got {self.quantum_efficiency!r}")
        object.__setattr__(self, "quantum_efficiency", qe)
        for name in ("full_well_e",):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), positive=True))
        for name in ("read_noise_e", "offset_dn", "dark_current_e_per_s", "exposure_s"):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), nonnegative=True))
        object.__setattr__(self, "bit_depth", _checks.integer("bit_depth", self.bit_depth, 1, 16))
        for name in ("gain_e_per_dn", "photons_at_one"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), positive=True))
        for name in ("shot_noise", "quantise"):
            object.__setattr__(self, name, _checks.flag(name, getattr(self, name)))
        _checks.one_of("demosaic", self.demosaic, (*DEMOSAIC_ALGORITHMS, None))

    @property
    def max_dn(self) -> int:
        """Largest ADC code 2^b − 1 [DN]."""
        return 2 ** self.bit_depth - 1

    @property
    def gain(self) -> float:
        """Conversion gain g actually used [e⁻/DN]."""
        return self.full_well_e / self.max_dn if self.gain_e_per_dn is None else self.gain_e_per_dn

    @property
    def photons_max(self) -> float:
        """Φ_max actually used: mean photons per pixel for a linear value of 1 [photon]."""
        return self.full_well_e / self.quantum_efficiency if self.photons_at_one is None else self.photons_at_one


def mosaic_rggb(image_linear) -> np.ndarray:
    """Sample an RGB image through an RGGB colour filter array (top-left pixel red).

    Parameters
    ----------
    image_linear : array_like of float, shape (H, W, 3)
        Linear RGB intensity [1].

    Returns
    -------
    raw : ndarray of float32, shape (H, W)
        raw[2i, 2j] = R, raw[2i, 2j+1] = G, raw[2i+1, 2j] = G, raw[2i+1, 2j+1] = B
        (0-based; the top-left pixel is red) [1].
    """
    return _mosaic(_checks.image("image_linear", image_linear, ndim=(3,), channels=3))


def _mosaic(img: np.ndarray) -> np.ndarray:
    raw = np.empty(img.shape[:2], np.float32)
    raw[0::2, 0::2] = img[0::2, 0::2, 0]
    raw[0::2, 1::2] = img[0::2, 1::2, 1]
    raw[1::2, 0::2] = img[1::2, 0::2, 1]
    raw[1::2, 1::2] = img[1::2, 1::2, 2]
    return raw


def demosaic(raw, *, algorithm: str = "MHC") -> np.ndarray:
    """Reconstruct RGB from an RGGB mosaic (Malvar–He–Cutler or bilinear).

    Parameters
    ----------
    raw : array_like of float, shape (H, W)
        RGGB mosaic (see :func:`mosaic_rggb`), ≥ 0 [1].
    algorithm : {"MHC", "linear"}, optional
        ``"MHC"``: Malvar–He–Cutler gradient-corrected linear interpolation; ``"linear"``:
        bilinear (normalised convolution of each masked channel, G with [[0,1,0],[1,4,1],[0,1,0]]/4,
        R and B with [[1,2,1],[2,4,2],[1,2,1]]/4, divided by the same convolution of the mask).

    Returns
    -------
    image : ndarray of float32, shape (H, W, 3)
        Demosaiced linear RGB [1]. A flat colour is returned exactly (up to float32
        rounding), borders included.

    Notes
    -----
    ``"MHC"``: a Numba kernel (:func:`_mhc`) with the arithmetic of OpenImageIO 3.2's
    ``ImageBufAlgo.demosaic(algorithm="MHC", layout="RGGB")``, operation order and border rule
    included (a row or column off the edge is taken 2 back inside), so the result is the same
    bytes (tested against OpenImageIO on many sizes, and against the published 5×5 filters),
    in one pass on one thread. Images with a side of 1 px and
    ``"linear"`` call OpenImageIO (``pattern="bayer"``, ``layout="RGGB"``, no white balance),
    its rows split into strips (one per core) written into one destination buffer; each output
    pixel reads the whole source, so the result does not depend on the split (tested).

    References
    ----------
    H. S. Malvar, L.-W. He, R. Cutler, "High-quality linear interpolation for demosaicing of
    Bayer-patterned color images", Proc. IEEE ICASSP 2004, vol. 3, pp. 485–488,
    doi:10.1109/ICASSP.2004.1326587.
    """
    return _demosaic(_checks.image("raw", raw, ndim=(2,)),
                     _checks.one_of("algorithm", algorithm, DEMOSAIC_ALGORITHMS))


def _demosaic(arr: np.ndarray, alg: str) -> np.ndarray:
    if alg == "MHC" and min(arr.shape) >= 2:
        out = np.empty((*arr.shape, 3), np.float32)
        _mhc(arr, out)
        return out
    return _demosaic_oiio(arr, alg)


@numba.njit(inline="always", cache=True)
def _mirror2(k, n):  # pragma: no cover - compiled
    """Index k of a row or column outside [0, n) moved back by the Bayer period (2), as
    OpenImageIO's demosaic window does: −2 → 0, −1 → 1, n → n − 2, n + 1 → n − 1."""
    while k < 0:
        k += 2
    while k > n - 1:
        k -= 2
    return k


@numba.njit(inline="always", cache=True)
def _mhc_pixel(rm2, rm1, r0, rp1, rp2, jm2, jm1, j, jp1, jp2, odd_row, rb, o):  # pragma: no cover - compiled
    """One pixel of :func:`_mhc`: rows i−2 … i+2 and columns j−2 … j+2 (already mirrored); ``rb``:
    a red or blue site, else green."""
    f2, f4, f8, f16 = np.float32(2.0), np.float32(4.0), np.float32(8.0), np.float32(16.0)
    c = r0[j]
    if rb:  # R (even row) or B (odd row) site
        tmp = rm2[j] + rp2[j] + r0[jm2] + r0[jp2]
        v1 = (f8 * c + f4 * (rm1[j] + rp1[j] + r0[jm1] + r0[jp1]) - f2 * tmp) / f16
        v2 = (np.float32(12.0) * c + f4 * (rm1[jm1] + rm1[jp1] + rp1[jm1] + rp1[jp1])
              - np.float32(3.0) * tmp) / f16
        o[j, 1] = v1
        if odd_row:
            o[j, 0], o[j, 2] = v2, c
        else:
            o[j, 0], o[j, 2] = c, v2
    else:  # G site
        tmp = rm1[jm1] + rm1[jp1] + rp1[jm1] + rp1[jp1]
        v1 = (np.float32(10.0) * c + f8 * (r0[jm1] + r0[jp1]) - f2 * (tmp + r0[jm2] + r0[jp2])
              + np.float32(1.0) * (rm2[j] + rp2[j])) / f16
        v2 = (np.float32(10.0) * c + f8 * (rm1[j] + rp1[j]) - f2 * (tmp + rm2[j] + rp2[j])
              + np.float32(1.0) * (r0[jm2] + r0[jp2])) / f16
        o[j, 1] = c
        if odd_row:
            o[j, 0], o[j, 2] = v2, v1
        else:
            o[j, 0], o[j, 2] = v1, v2


@pjit_exact
def _mhc(raw, out):  # pragma: no cover - compiled
    """Malvar–He–Cutler demosaic of an RGGB mosaic (H, W ≥ 2), float32, with the arithmetic
    (operation order included) of OpenImageIO 3.2's ``ImageBufAlgo.demosaic(algorithm="MHC")``:
    at a red or blue site the green is (8c + 4·Σ₄ cross − 2·Σ₄ axis-2)/16 and the other colour
    (12c + 4·Σ₄ diagonal − 3·Σ₄ axis-2)/16; at a green site the colour of the row neighbours is
    (10c + 8·Σ₂ row − 2·(Σ₄ diagonal + Σ₂ row±2) + Σ₂ column±2)/16, the column's the same
    transposed (Malvar, He, Cutler 2004, fig. 2); borders as :func:`_mirror2`."""
    h, w = raw.shape
    for i in numba.prange(h):
        rm2, rm1, r0 = raw[_mirror2(i - 2, h)], raw[_mirror2(i - 1, h)], raw[i]
        rp1, rp2 = raw[_mirror2(i + 1, h)], raw[_mirror2(i + 2, h)]
        o = out[i]
        odd = i % 2 == 1
        end = 2 + 2 * max(0, (w - 4) // 2)  # the interior [2, end): pairs of sites, no index checks
        for j in range(2, end, 2):
            _mhc_pixel(rm2, rm1, r0, rp1, rp2, j - 2, j - 1, j, j + 1, j + 2, odd, not odd, o)
            _mhc_pixel(rm2, rm1, r0, rp1, rp2, j - 1, j, j + 1, j + 2, j + 3, odd, odd, o)
        for j in range(w):
            if 2 <= j < end:
                continue
            _mhc_pixel(rm2, rm1, r0, rp1, rp2, _mirror2(j - 2, w), _mirror2(j - 1, w), j,
                       _mirror2(j + 1, w), _mirror2(j + 2, w), odd, (j % 2 == 1) == odd, o)


def _demosaic_oiio(arr: np.ndarray, alg: str) -> np.ndarray:
    h, w = arr.shape
    src = oiio.ImageBuf(arr[:, :, None])
    dst = oiio.ImageBuf(oiio.ImageSpec(w, h, 3, oiio.FLOAT))
    strips = max(1, min(os.cpu_count() or 1, h // 64))
    edges = [round(k * h / strips) for k in range(strips + 1)]

    def run(y0: int, y1: int) -> bool:
        return oiio.ImageBufAlgo.demosaic(dst, src, pattern="bayer", algorithm=alg, layout="RGGB",
                                          roi=oiio.ROI(0, w, y0, y1, 0, 1, 0, 3), nthreads=1)

    if strips == 1:
        ok = [run(0, h)]
    else:
        ok = list(pool().map(run, edges[:-1], edges[1:]))
    if not all(ok):  # pragma: no cover - OpenImageIO failure
        raise RuntimeError(f"OpenImageIO demosaic failed: {dst.geterror() or oiio.geterror()}")
    return np.ascontiguousarray(dst.get_pixels(oiio.FLOAT), dtype=np.float32)


@jit_exact
def _adc(signal_e, noise_e, full_well_e, gain, offset_dn, max_dn, rounding, out):  # pragma: no cover
    """out = clip(round((min(signal, FW) + noise)/g + offset), 0, max)/max, 1-D;
    an empty ``noise_e`` means no read noise."""
    have_noise = noise_e.size == signal_e.size
    for k in range(signal_e.size):
        e = min(np.float64(signal_e[k]), full_well_e)
        if have_noise:
            e += noise_e[k]
        dn = e / gain + offset_dn
        if rounding:
            dn = np.rint(dn)
        dn = min(max(dn, 0.0), max_dn)
        out[k] = np.float32(dn / max_dn)


def sensor_readout(image_linear, config: SensorConfig = SensorConfig(), *, rng=None) -> np.ndarray:
    """Photons → electrons → ADC for every element of a linear image (no colour filter).

    Parameters
    ----------
    image_linear : array_like of float, shape (H, W) or (H, W, C)
        Linear intensity at each photosite, ≥ 0 (1 = Φ_max photons) [1].
    config : SensorConfig, optional
        Sensor parameters.
    rng : numpy.random.Generator or int or None, keyword-only
        Random source, normalised with :func:`numpy.random.default_rng`.

    Returns
    -------
    image : ndarray of float32, shape like ``image_linear``
        DN/(2^b − 1) in [0, 1] [1].

    Notes
    -----
    docs/degradation.md, "Sensor": e = min(Poisson(QE·Φ + D_c·t_exp), FW) + N(0, σ_r²) [e⁻];
    DN = clip(round(e/g + offset), 0, 2^b − 1); mean DN = QE Φ/g and
    var DN = (QE Φ + σ_r² + g²/12)/g² below saturation. Random streams: see the module
    docstring (blocks of photosites, one child of ``rng.spawn`` each).
    """
    img = _checks.image("image_linear", image_linear)
    _check_config(config)
    return _readout(img, config, np.random.default_rng(rng))


def _check_config(config) -> None:
    _checks.instance("config", config, SensorConfig)


_MAX_BLOCKS = 8
_MIN_BLOCK = 65_536


def _readout(img: np.ndarray, c: SensorConfig, rng: np.random.Generator) -> np.ndarray:
    flat = img.ravel()
    n_blocks = max(1, min(_MAX_BLOCKS, flat.size // _MIN_BLOCK))
    edges = [flat.size * k // n_blocks for k in range(n_blocks + 1)]
    out = np.empty(flat.size, np.float32)
    gain_e = c.quantum_efficiency * c.photons_max
    dark_e = c.dark_current_e_per_s * c.exposure_s

    def block(k: int, stream: np.random.Generator) -> None:
        lo, hi = edges[k], edges[k + 1]
        mean_e = flat[lo:hi].astype(np.float64)
        mean_e *= gain_e
        if dark_e > 0.0:
            mean_e += dark_e
        signal_e = stream.poisson(mean_e) if c.shot_noise else mean_e
        noise_e = stream.normal(0.0, c.read_noise_e, hi - lo) if c.read_noise_e > 0.0 else _NO_NOISE
        _adc(signal_e, noise_e, c.full_well_e, c.gain, c.offset_dn, float(c.max_dn), c.quantise, out[lo:hi])

    streams = rng.spawn(n_blocks)
    if n_blocks == 1:
        block(0, streams[0])
    else:
        for f in [pool().submit(block, k, s) for k, s in enumerate(streams)]:
            f.result()
    return out.reshape(img.shape)


_NO_NOISE = np.empty(0)


def simulate_sensor(image_linear, config: SensorConfig = SensorConfig(), *, rng=None) -> np.ndarray:
    """Full sensor model: RGGB mosaic → :func:`sensor_readout` → demosaic.

    Parameters
    ----------
    image_linear : array_like of float, shape (H, W, 3) or (H, W)
        Linear intensity reaching the sensor, ≥ 0 (1 = Φ_max photons) [1]. An H×W image is
        a monochrome sensor and needs ``config.demosaic=None``.
    config : SensorConfig, optional
        Sensor parameters; ``config.demosaic=None`` skips the colour filter array.
    rng : numpy.random.Generator or int or None, keyword-only
        Random source, normalised with :func:`numpy.random.default_rng`.

    Returns
    -------
    image : ndarray of float32, shape like ``image_linear``
        Linear DN/(2^b − 1) [1]; after demosaicing clipped to [0, 1], the ADC range
        (Malvar–He–Cutler's gradient correction over- and undershoots at sharp edges).
    """
    img = _checks.image("image_linear", image_linear, channels=3)
    _check_config(config)
    return _simulate(img, config, np.random.default_rng(rng))


def _simulate(img: np.ndarray, c: SensorConfig, rng: np.random.Generator) -> np.ndarray:
    if c.demosaic is None:
        return _readout(img, c, rng)
    if img.ndim == 2:
        raise ValueError("image_linear is H×W (monochrome): it needs config.demosaic=None, "
                         f"got demosaic={c.demosaic!r}")
    out = _demosaic(_readout(_mosaic(img), c, rng), c.demosaic)
    return np.clip(out, 0.0, 1.0, out=out)  # MHC over/undershoots at edges: back to ADC range


def _signal_e(img: np.ndarray, c: SensorConfig, art, maps, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The photosites' electrons at the ADC's input and the ADC's output, with the camera
    artefacts ``art`` (:class:`degrade.artefacts.ArtefactConfig`) and fixed maps ``maps``
    (:class:`degrade.artefacts.CameraMaps`) on the photosite array ``img`` (1 = Φ_max photons):

        μ = QE·Φ·gain (+ smear) + (D_c + D_hot)·t;  q = max(Poisson(μ) + DSNU, 0);
        q → bloom (or min(q, FW));  signal_e = min(q + N(0, σ_r²), FW);
        DN = clip(round(signal_e/g + offset), 0, 2^b − 1)

    The random streams are those of :func:`sensor_readout` (block k: its Poisson values, then
    its read noise, from child k of ``rng.spawn``). Returns (signal_e float32 [e⁻], DN/(2^b − 1)
    float32), both shaped like ``img``."""
    from .artefacts import smear
    mean_e = img.astype(np.float64) * (c.quantum_efficiency * c.photons_max)
    if maps.gain is not None:
        mean_e *= maps.gain
    if art.smear_fraction > 0.0:
        mean_e = smear(mean_e, art.smear_fraction)
    dark_e = c.dark_current_e_per_s * c.exposure_s
    if dark_e > 0.0:
        mean_e += dark_e
    if maps.hot_dark_e_per_s is not None:
        mean_e += maps.hot_dark_e_per_s * c.exposure_s
    return _signal_from_mean(mean_e, c, art, maps, rng)


_NONE2 = np.empty((0, 0), np.float32)  # an absent map (one kernel signature for present and absent)
_NONE2.flags.writeable = False


def _frozen(a):
    """``a`` (float32, 2-D) read-only, or the absent map for None: the kernels' argument types."""
    if a is None:
        return _NONE2
    a = a.view()
    a.flags.writeable = False
    return a


def _signal_e_rggb(sites: np.ndarray, vig, stray, c: SensorConfig, art, maps,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_signal_e` of the RGGB mosaic ``sites`` (H×W, :func:`_mosaic` of the focal-plane
    image) times the relative illumination ``vig`` (H×W or None) plus the stray light ``stray``
    (H×W or None), without smear: the same float operations in the same order (the same bits),
    illumination and mean in one pass."""
    if art.smear_fraction > 0.0:
        raise ValueError("smear needs the general path (_signal_e)")
    mean_e = np.empty(sites.shape, np.float64)
    _site_mean(sites, _frozen(vig), _frozen(stray), c.quantum_efficiency * c.photons_max, _frozen(maps.gain),
               c.dark_current_e_per_s * c.exposure_s, _frozen(maps.hot_dark_e_per_s), np.float32(c.exposure_s),
               mean_e)
    return _signal_from_mean(mean_e, c, art, maps, rng)


@pjit_exact
def _site_mean(sites, vig, stray, k_e, prnu, dark_e, hot, t32, out):  # pragma: no cover - compiled
    """out[i, j] = mean electrons of RGGB photosite (i, j): v = sites[i, j] (·vig) (+ stray) in
    float32, then float64(v)·k_e (·prnu) (+ dark_e) (+ float64(float32(hot·t32))): NumPy's
    operations of the general path, in its order; an empty map is absent."""
    h, w = out.shape
    for i in numba.prange(h):
        for j in range(w):
            v = sites[i, j]
            if vig.size:
                v = v * vig[i, j]
            if stray.size:
                v = v + stray[i, j]
            m = np.float64(v) * k_e
            if prnu.size:
                m = m * np.float64(prnu[i, j])
            if dark_e > 0.0:
                m = m + dark_e
            if hot.size:
                m = m + np.float64(hot[i, j] * t32)
            out[i, j] = m


@jit_exact
def _dsnu_clip(charge, offset, fw):  # pragma: no cover - compiled
    """charge = max(charge + float64(offset), 0) in place where ``offset`` is not empty (1-D
    both); returns whether any photosite holds more than ``fw``."""
    over = False
    for k in range(charge.size):
        x = charge[k]
        if offset.size:
            x = max(x + np.float64(offset[k]), 0.0)
            charge[k] = x
        over |= x > fw
    return over


@jit_exact
def _read_adc(charge, z, sigma, fw, gain, offset_dn, max_dn, rounding, signal, dn):  # pragma: no cover - compiled
    """signal = float32(min(min(charge, fw) + (0 + sigma·z), fw)); dn = float32(clip(rint(s/gain
    + offset_dn), 0, max_dn)/max_dn) (rint only if ``rounding``): the float64 steps of NumPy's
    general path, its read noise ``Generator.normal(0, sigma)`` being 0 + sigma·z of the
    standard normal draws z; ``z`` empty: no read noise."""
    cf, nf, sf, df = charge.ravel(), z.ravel(), signal.ravel(), dn.ravel()
    for k in range(cf.size):
        s = min(cf[k], fw)
        if nf.size:
            s = s + (0.0 + sigma * nf[k])
        s = min(s, fw)
        sf[k] = np.float32(s)
        d = s / gain + offset_dn
        if rounding:
            d = np.rint(d)
        df[k] = np.float32(min(max(d, 0.0), max_dn) / max_dn)


def _poisson_sparse(stream: np.random.Generator, mean: np.ndarray) -> np.ndarray:
    """``stream.poisson(mean)``, the same values and the same stream afterwards, drawing only
    where mean > 0 when at least a tenth of ``mean`` is 0: NumPy's sampler returns 0 for λ = 0
    without a draw, and its per-element cost on a dark frame is mostly that loop."""
    nz = np.flatnonzero(mean)
    if nz.size >= 0.9 * mean.size:
        return stream.poisson(mean)
    out = np.zeros(mean.size, np.int64)
    out[nz] = stream.poisson(mean[nz])
    return out


def _signal_from_mean(mean_e: np.ndarray, c: SensorConfig, art, maps, rng: np.random.Generator):
    """Shot noise, DSNU, blooming, read noise and ADC of the mean electrons ``mean_e`` (float64,
    the photosite array): see :func:`_signal_e`."""
    from .artefacts import _bloom
    shape = mean_e.shape
    mean_flat = mean_e.ravel()
    n_blocks = max(1, min(_MAX_BLOCKS, mean_flat.size // _MIN_BLOCK))
    edges = [mean_flat.size * k // n_blocks for k in range(n_blocks + 1)]
    charge = np.empty(mean_flat.size, np.float64)
    noise = np.empty(mean_flat.size if c.read_noise_e > 0.0 else 0, np.float64)
    streams = rng.spawn(n_blocks)

    def run(step, k: int) -> None:
        lo, hi = edges[k], edges[k + 1]
        if step == "shot":
            charge[lo:hi] = _poisson_sparse(streams[k], mean_flat[lo:hi]) if c.shot_noise else mean_flat[lo:hi]
        else:
            noise[lo:hi] = streams[k].standard_normal(hi - lo)  # normal(0, σ)'s draws z: 0 + σ·z below

    for step in ("shot", "read") if c.read_noise_e > 0.0 else ("shot",):
        if n_blocks == 1:
            run(step, 0)
        else:
            for f in [pool().submit(run, step, k) for k in range(n_blocks)]:
                f.result()
    fw = float(c.full_well_e)
    offset = _NONE2 if maps.offset_e is None else maps.offset_e
    over = _dsnu_clip(charge, offset.reshape(-1), fw)
    charge = charge.reshape(shape)
    if over and art.blooming:
        charge = _bloom(charge, fw, float(art.blooming_spill))  # in place: charge is ours
    signal = np.empty(shape, np.float32)
    dn = np.empty(shape, np.float32)
    _read_adc(charge.reshape(-1), noise, float(c.read_noise_e), fw, float(c.gain), float(c.offset_dn),
              float(c.max_dn), c.quantise, signal.reshape(-1), dn.reshape(-1))
    return signal, dn
