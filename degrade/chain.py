"""The physical imaging chain in one call: optics → sensor → encoding.

    I_lin ⊛ PSF_total → RGGB mosaic → photons → electrons (Poisson) → full-well clip
          → + read noise → ADC → demosaic → sRGB encode (8/16 bit)

PSF_total = PSF_diffraction ⊛ PSF_aberration ⊛ PSF_defocus ⊛ PSF_motion, per colour channel
(the Airy pattern scales with wavelength). A stage whose config is ``None`` (or whose
parameters make it the identity, e.g. zero motion) is skipped. Per-frame quantities (motion
length and angle from the image-plane velocity × exposure,
:func:`degrade.psf.motion_from_velocity`; defocus radius from the range,
:func:`degrade.psf.defocus_radius_px`) go into :class:`OpticsConfig` via
:func:`dataclasses.replace`; the PSF of each distinct configuration is built once and cached.
The chain and its defaults: docs/degradation.md, "Physical chain".
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from . import _checks
from .artefacts import ArtefactConfig
from .convolve import convolve_image
from .encode import srgb_encode
from .psf import airy_psf, compose, defocus_psf, gaussian_psf, motion_psf
from .sensor import SensorConfig, _simulate

__all__ = ["ENCODINGS", "DegradeConfig", "FrameOutput", "OpticsConfig", "apply_optics", "degrade", "optics_psf",
           "simulate_frame"]

ENCODINGS = ("srgb8", "srgb16", "srgb", "linear")
"""Output encodings: sRGB rounded to 8 or 16 bit levels, sRGB float, or linear float."""


@dataclass(frozen=True, slots=True)
class OpticsConfig:
    """Lens, aberration, defocus and motion blur of one frame.

    Attributes
    ----------
    focal_length_m : float
        Focal length f [m]. Default 4 mm (the default camera of ``raytrace``).
    aperture_m : float or None
        Entrance-pupil diameter D [m]; None: no diffraction. Default 1 mm (f/4: r₁ = 0.78 px at
        550 nm with 3.45 µm pixels).
    pixel_pitch_m : float
        Pixel pitch p [m]. Default 3.45 µm (IMX250 class).
    wavelengths_m : tuple of 3 float
        Centre wavelength of the R, G, B channels [m], used for the Airy pattern. Default
        (600, 530, 460) nm, near the transmission peaks of common Bayer dyes. A monochrome
        (H×W) image uses the G value.
    aberration_sigma_px : float
        σ of the Gaussian aberration PSF at the image centre [px]; 0: none.
    corner_sigma_px : float or None
        Optional field-dependent aberration: σ at the image corners [px]. The image is blurred
        with both the centre and the corner PSF and blended with weight ρ² (ρ = distance from
        the centre / half-diagonal), a cheap stand-in for off-axis blur. None: uniform PSF.
    defocus_radius_px : float
        Blur-circle radius R [px] (:func:`degrade.psf.defocus_radius_px`); 0: in focus.
    motion_length_px : float
        Motion-blur length L [px] (image-plane speed × exposure); 0: none.
    motion_angle_deg : float
        Motion direction θ [deg], counter-clockwise from +column as displayed.
    """

    focal_length_m: float = 4.0e-3
    aperture_m: float | None = 1.0e-3
    pixel_pitch_m: float = 3.45e-6
    wavelengths_m: tuple[float, float, float] = (600e-9, 530e-9, 460e-9)
    aberration_sigma_px: float = 0.0
    corner_sigma_px: float | None = None
    defocus_radius_px: float = 0.0
    motion_length_px: float = 0.0
    motion_angle_deg: float = 0.0

    def __post_init__(self):
        for name in ("focal_length_m", "pixel_pitch_m"):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), positive=True))
        if self.aperture_m is not None:
            object.__setattr__(self, "aperture_m", _checks.finite_scalar("aperture_m", self.aperture_m, positive=True))
        wl = self.wavelengths_m
        if isinstance(wl, (str, bytes)) or np.ndim(wl) != 1 or len(wl) != 3:
            raise ValueError(f"wavelengths_m must be 3 wavelengths (R, G, B) [m], got {wl!r}")
        object.__setattr__(self, "wavelengths_m", tuple(
            _checks.finite_scalar(f"wavelengths_m[{i}]", v, positive=True) for i, v in enumerate(wl)))
        for name in ("aberration_sigma_px", "defocus_radius_px", "motion_length_px"):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), nonnegative=True))
        if self.corner_sigma_px is not None:
            object.__setattr__(self, "corner_sigma_px",
                               _checks.finite_scalar("corner_sigma_px", self.corner_sigma_px, nonnegative=True))
        object.__setattr__(self, "motion_angle_deg", _checks.finite_scalar("motion_angle_deg", self.motion_angle_deg))


@dataclass(frozen=True, slots=True)
class DegradeConfig:
    """What the physical chain does to a frame.

    Attributes
    ----------
    optics : OpticsConfig or None
        Blur; None skips it.
    sensor : SensorConfig or None
        Mosaic, noise, ADC and demosaic; None skips them (the image stays noiseless).
    encoding : {"srgb8", "srgb16", "srgb", "linear"}
        Output: sRGB (IEC 61966-2-1) rounded to 8- or 16-bit levels, sRGB float, or linear.
    artefacts : ArtefactConfig or None
        Camera artefacts (:mod:`degrade.artefacts`: vignetting, fixed-pattern noise, hot
        pixels, smear, blooming, stray light, JPEG); None: none (the chain as before they
        existed). They need ``optics`` and ``sensor``; JPEG needs ``encoding="srgb8"``.
    """

    optics: OpticsConfig | None = field(default_factory=OpticsConfig)
    sensor: SensorConfig | None = field(default_factory=SensorConfig)
    encoding: str = "srgb8"
    artefacts: ArtefactConfig | None = None

    def __post_init__(self):
        if self.optics is not None:
            _checks.instance("optics", self.optics, OpticsConfig)
        if self.sensor is not None:
            _checks.instance("sensor", self.sensor, SensorConfig)
        _checks.one_of("encoding", self.encoding, ENCODINGS)
        if self.artefacts is not None:
            _checks.instance("artefacts", self.artefacts, ArtefactConfig)
            if self.optics is None or self.sensor is None:
                raise ValueError("artefacts need optics and sensor (the lens' focal length and pitch, the photosites), "
                                 "got optics or sensor None")
            if self.artefacts.jpeg_quality and self.encoding != "srgb8":
                raise ValueError(f"artefacts.jpeg_quality needs encoding='srgb8' (JPEG holds 8-bit codes), "
                                 f"got {self.encoding!r}")


def optics_psf(optics: OpticsConfig, channels: int = 3, *, corner: bool = False) -> np.ndarray:
    """Total PSF of the optics, one kernel per channel (docs/degradation.md, "Optics").

    Parameters
    ----------
    optics : OpticsConfig
        Optical parameters.
    channels : {3, 1}, optional
        3: R, G, B kernels from ``wavelengths_m``; 1: one kernel at the G wavelength.
    corner : bool, optional
        Use ``corner_sigma_px`` instead of ``aberration_sigma_px`` (field-dependent blur).

    Returns
    -------
    psf : ndarray of float64, shape (channels, K, K)
        Read-only; each kernel sums to 1 [1].
    """
    _checks.instance("optics", optics, OpticsConfig)
    _checks.one_of("channels", channels, (3, 1))
    if corner and optics.corner_sigma_px is None:
        raise ValueError("corner=True needs optics.corner_sigma_px, got None")
    return _optics_psf(optics, channels, bool(corner))


@functools.lru_cache(maxsize=128)
def _optics_psf(optics: OpticsConfig, channels: int, corner: bool) -> np.ndarray:
    sigma = optics.corner_sigma_px if corner else optics.aberration_sigma_px
    common = (gaussian_psf(sigma), defocus_psf(optics.defocus_radius_px),
              motion_psf(optics.motion_length_px, optics.motion_angle_deg))
    wavelengths = optics.wavelengths_m if channels == 3 else optics.wavelengths_m[1:2]
    kernels = []
    for lam in wavelengths:
        airy = () if optics.aperture_m is None else (
            airy_psf(optics.aperture_m, lam, optics.focal_length_m, optics.pixel_pitch_m),)
        kernels.append(compose(*airy, *common))
    size = max(k.shape[0] for k in kernels)
    stack = np.zeros((channels, size, size))
    for c, k in enumerate(kernels):  # centre smaller kernels (all sizes are odd)
        o = (size - k.shape[0]) // 2
        stack[c, o:o + k.shape[0], o:o + k.shape[1]] = k
    stack.flags.writeable = False
    return stack


def _radius2_weight(h: int, w: int) -> np.ndarray:
    """ρ² = squared distance from the image centre / squared half-diagonal, shape (H, W, 1)."""
    yy = ((np.arange(h, dtype=np.float32) - (h - 1) / 2) ** 2)[:, None]
    xx = ((np.arange(w, dtype=np.float32) - (w - 1) / 2) ** 2)[None, :]
    half_diag2 = ((h - 1) / 2) ** 2 + ((w - 1) / 2) ** 2
    return ((yy + xx) / np.float32(max(half_diag2, 1.0)))[:, :, None]


def apply_optics(image_linear, optics: OpticsConfig) -> np.ndarray:
    """Blur a linear image with the optics' PSF (mirror padding, see :mod:`degrade.convolve`).

    Parameters
    ----------
    image_linear : array_like of float, shape (H, W, 3) or (H, W)
        Linear intensity, ≥ 0 [1].
    optics : OpticsConfig
        Optical parameters.

    Returns
    -------
    blurred : ndarray of float32, shape like ``image_linear``
        Linear intensity [1].
    """
    return _apply_optics(_checks.image("image_linear", image_linear, channels=3), optics)


def _apply_optics(img: np.ndarray, optics: OpticsConfig) -> np.ndarray:
    channels = 3 if img.ndim == 3 else 1
    psf = optics_psf(optics, channels)
    centre = convolve_image(img, psf if channels == 3 else psf[0])
    if optics.corner_sigma_px is None:
        return centre
    psf_c = optics_psf(optics, channels, corner=True)
    corner = convolve_image(img, psf_c if channels == 3 else psf_c[0])
    weight = _radius2_weight(*img.shape[:2])
    if img.ndim == 2:
        weight = weight[:, :, 0]
    corner -= centre
    corner *= weight
    centre += corner
    return centre


def _optics_sites(img: np.ndarray, optics: OpticsConfig) -> np.ndarray:
    """``_mosaic(_apply_optics(img, optics))`` of an H×W×3 image, byte for byte: where the
    direct convolution applies, only the channel each RGGB photosite keeps is convolved
    (:func:`degrade.convolve._convolve_sites`), and the corner blend is taken at the sites."""
    from .convolve import _convolve_sites
    from .sensor import _mosaic
    centre = _convolve_sites(img, optics_psf(optics, 3))
    if centre is None:
        return _mosaic(_apply_optics(img, optics))
    if optics.corner_sigma_px is None:
        return centre
    corner = _convolve_sites(img, optics_psf(optics, 3, corner=True))
    if corner is None:
        return _mosaic(_apply_optics(img, optics))
    corner -= centre
    corner *= _radius2_weight(*img.shape[:2])[:, :, 0]
    centre += corner
    return centre


class FrameOutput(NamedTuple):
    """What :func:`simulate_frame` returns (one simulation, one set of random draws)."""

    image: np.ndarray
    """The degraded image, as :func:`degrade` returns it."""
    signal_e: np.ndarray | None
    """Electrons per photosite at the ADC's input (shot, dark and read noise, fixed-pattern
    noise, blooming, full-well clip), float32, shaped as the photosite array (H×W on the RGGB
    mosaic); None without ``config.artefacts``."""
    saturation: np.ndarray | None
    """bool, same shape: the photosite reached full well (``signal_e >= full_well_e``: the
    ADC's top code); None without ``config.artefacts``."""


def degrade(image_linear, config: DegradeConfig = DegradeConfig(), *, rng=None, sun_dir_cam=None,
            sun_fraction: float = 1.0, camera_seed: int = 0) -> np.ndarray:
    """Run the physical chain (docs/degradation.md, "Physical chain") on one linear frame.

    Parameters
    ----------
    image_linear : array_like of float, shape (H, W, 3) or (H, W)
        Linear intensity from the renderer, ≥ 0 and finite; 1 means Φ_max photons per pixel
        (by default just a full well). float32 is used as is, other floats are converted.
        H×W images are monochrome and need ``config.sensor.demosaic=None``.
    config : DegradeConfig, optional
        Optics, sensor, output encoding and camera artefacts.
    rng : numpy.random.Generator or int or None, keyword-only
        Random source (normalised with :func:`numpy.random.default_rng`); the same seed gives
        byte-identical output.
    sun_dir_cam : array_like of 3 float or None, keyword-only
        Direction to the Sun in the camera frame, for the stray light of ``config.artefacts``
        (None: no Sun).
    sun_fraction : float, keyword-only
        Visible fraction of the solar disc in [0, 1] (penumbra), scaling the stray light. Default 1.
    camera_seed : int, keyword-only
        Seed of the camera's fixed maps (PRNU, DSNU, hot pixels): :func:`degrade.artefacts.camera_maps`.

    Returns
    -------
    image : ndarray of float32, shape like ``image_linear``
        Encoded as ``config.encoding`` says: for "srgb8"/"srgb16" the values are exactly
        ``code/(2**bits − 1)`` (see :func:`degrade.encode.quantise`) [1].
    """
    return simulate_frame(image_linear, config, rng=rng, sun_dir_cam=sun_dir_cam, sun_fraction=sun_fraction,
                          camera_seed=camera_seed).image


def simulate_frame(image_linear, config: DegradeConfig = DegradeConfig(), *, rng=None, sun_dir_cam=None,
                   sun_fraction: float = 1.0, camera_seed: int = 0) -> FrameOutput:
    """:func:`degrade`, also returning the photosites' electrons and saturation mask.

    With ``config.artefacts`` the chain is: optics PSF → × relative illumination → + stray
    light and ghost (focal-plane irradiance, :func:`degrade.artefacts.stray_light`) → RGGB
    mosaic → :func:`degrade.sensor._signal_e` (PRNU, smear, dark and hot-pixel current, shot
    noise, DSNU, blooming, read noise, full well, ADC) → demosaic → encoding (→ JPEG).
    Parameters and result as :func:`degrade` (``image`` of the result is what it returns).
    """
    _checks.instance("config", config, DegradeConfig)
    img = _checks.image("image_linear", image_linear, channels=3)
    sun_fraction = _checks.fraction("sun_fraction", sun_fraction)
    return _simulate_frame(img, config, np.random.default_rng(rng), sun_dir_cam, sun_fraction, camera_seed,
                           image_linear)


def _simulate_frame(img: np.ndarray, config: DegradeConfig, rng, sun_dir_cam, sun_fraction: float, camera_seed: int,
                    caller=None, codes8: bool = False) -> FrameOutput:
    """:func:`simulate_frame` of a checked float32 image (``caller``: the array the caller
    passed, never returned); ``codes8`` (needs ``config.encoding == "srgb8"``): the image as
    its uint8 codes, ``quantise(simulate_frame(...).image, 8)`` byte for byte, without the
    float levels in between."""
    signal_e = saturation = None
    if config.optics is not None and config.artefacts is None:  # with artefacts: in _sensor_with_artefacts
        img = _apply_optics(img, config.optics)
    jpeg = config.artefacts.jpeg_quality if config.artefacts is not None else 0
    if config.artefacts is not None:
        img, signal_e, saturation = _sensor_with_artefacts(img, config, sun_dir_cam, sun_fraction, camera_seed, rng,
                                                           clip=not codes8)
    elif config.sensor is not None:
        img = _simulate(img, config.sensor, rng)
    if codes8:
        from .artefacts import jpeg_roundtrip
        from .encode import _encode_srgb8
        codes = _encode_srgb8(np.ascontiguousarray(img, dtype=np.float32))
        return FrameOutput(jpeg_roundtrip(codes, jpeg) if jpeg else codes, signal_e, saturation)
    if config.encoding == "linear":
        return FrameOutput(img.copy() if img is caller else img, signal_e, saturation)
    bits = {"srgb8": 8, "srgb16": 16, "srgb": None}[config.encoding]
    out = srgb_encode(img, bits=bits)
    if jpeg:
        from .artefacts import jpeg_roundtrip
        from .encode import dequantise, quantise
        out = dequantise(jpeg_roundtrip(quantise(out, 8), jpeg), 8)
    return FrameOutput(out, signal_e, saturation)


def _sensor_with_artefacts(img: np.ndarray, config: DegradeConfig, sun_dir_cam, sun_fraction, camera_seed, rng,
                           clip: bool = True):
    """(demosaiced DN/(2^b − 1), signal_e, saturation) of the chain with artefacts from the
    optics on (``img``: the linear image before the optics); ``clip``: the demosaiced image
    clipped to [0, 1] (the 8-bit encoder clips by itself)."""
    from .artefacts import (
        SOLAR_IRRADIANCE_W_M2,
        camera_maps,
        irradiance_to_signal,
        relative_illumination,
        stray_light,
    )
    from .sensor import _demosaic, _mosaic, _signal_e, _signal_e_rggb
    art, optics, c = config.artefacts, config.optics, config.sensor
    h, w = img.shape[:2]
    vig = e = None
    if art.vignetting:
        vig = relative_illumination(h, w, focal_length_m=optics.focal_length_m, pixel_pitch_m=optics.pixel_pitch_m,
                                    mechanical=art.mechanical_vignetting)
    if art.stray_light and sun_dir_cam is not None and sun_fraction > 0.0:
        e = stray_light(h, w, sun_dir_cam, focal_length_m=optics.focal_length_m, pixel_pitch_m=optics.pixel_pitch_m,
                        aperture_m=optics.aperture_m, config=art, sun_irradiance_W_m2=SOLAR_IRRADIANCE_W_M2 * sun_fraction)
        if e is not None:
            e *= np.float32(irradiance_to_signal(1.0, exposure_s=c.exposure_s, pixel_pitch_m=optics.pixel_pitch_m,
                                                 wavelength_m=art.wavelength_m, photons_at_one=c.photons_max))
    if c.demosaic is not None and img.ndim == 2:
        raise ValueError("image_linear is H×W (monochrome): it needs config.sensor.demosaic=None, "
                         f"got demosaic={c.demosaic!r}")
    if c.demosaic is not None and art.smear_fraction == 0.0:  # optics at the sites; illumination and mean in one pass
        maps = camera_maps((h, w), art, camera_seed)
        signal_e, dn = _signal_e_rggb(_optics_sites(img, optics), vig, e, c, art, maps, rng)
    else:
        img = np.array(_apply_optics(img, optics), dtype=np.float32)  # may be the caller's array
        if vig is not None:
            img *= vig if img.ndim == 2 else vig[:, :, None]
        if e is not None:
            img += e if img.ndim == 2 else e[:, :, None]
        sites = img if c.demosaic is None else _mosaic(img)
        maps = camera_maps(sites.shape, art, camera_seed)
        signal_e, dn = _signal_e(sites, c, art, maps, rng)
    if c.demosaic is not None:
        dn = _demosaic(dn, c.demosaic)
        if clip:
            np.clip(dn, 0.0, 1.0, out=dn)
    return dn, signal_e, signal_e >= np.float32(c.full_well_e)
