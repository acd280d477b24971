"""Flight-camera artefacts: vignetting, fixed-pattern noise, hot pixels, blooming, smear,
stray light and ghosts, on-board JPEG.

Each artefact is one parameter group of :class:`ArtefactConfig` (docs/degradation.md,
"Camera artefacts", gives the model, default and source of each) and is switched off by a
zero (or False) parameter:

* **Vignetting** — relative illumination of the lens, cos⁴θ of the field angle θ
  (tan θ = r·p/f at a distance r [px] from the principal point, pitch p, focal length f;
  the cosine-fourth law of illumination, W. J. Smith, *Modern Optical Engineering*, 4th ed.,
  McGraw-Hill 2008), optionally times a mechanical term 1 − α·ρ (ρ = r / half-diagonal, α the
  loss in the corners; the geometric factor of Kang & Weiss, "Can we calibrate a camera using
  an image of a flat, textureless Lambertian surface?", ECCV 2000).
* **PRNU / DSNU** — a gain map 1 + σ_PRNU·N(0, 1) on the photo-electrons and an offset map
  σ_DSNU·N(0, 1) [e⁻] (EMVA Standard 1288, Release 4.0, 2021: PRNU in % of the signal,
  DSNU in e⁻).
* **Hot pixels** — a fraction of the photosites with an extra dark current drawn from an
  exponential distribution of mean ``hot_pixel_dark_e_per_s``.
* **Frame-transfer smear** — each photosite gets ``smear_fraction`` × its column's mean
  photo-signal (the charge collected while the rows shift under the light; off for CMOS).
* **Blooming** — the charge above the full well of a run of full photosites spills half
  up, half down the column into the nearest photosites with room (runs whose spills meet
  join and spill again), conserving charge until it leaves the array.
* **Stray light and ghost** — a veiling glare E = PST(θ_sun)·E_sun with a point-source
  transmittance PST falling as a power of the Sun's off-axis angle, a linear gradient
  toward the Sun's side, and a ghost: a uniform disc holding the fraction R² (two surface
  reflections) of the solar power entering the pupil, centred on the line through the image
  centre at ``ghost_magnification`` × the Sun's pinhole position.
* **JPEG** — the degraded 8-bit image compressed and decoded by OpenImageIO's JPEG codec
  (libjpeg) at a quality 1–100.

The fixed maps (PRNU, DSNU, hot pixels) are drawn from a *camera* seed, not the frame's: the
same for every frame of a sequence (:func:`camera_maps`).
"""

from __future__ import annotations

import functools
import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np

from . import _checks

__all__ = ["ARTEFACTS_OFF", "SOLAR_IRRADIANCE_W_M2", "ArtefactConfig", "CameraMaps", "bloom", "camera_maps",
           "irradiance_to_signal", "jpeg_bytes", "jpeg_roundtrip", "relative_illumination", "smear", "stray_light"]

SOLAR_IRRADIANCE_W_M2 = 1361.0
"""Total solar irradiance at 1 au [W/m²] (G. Kopp, J. L. Lean, "A new, lower value of total
solar irradiance", Geophys. Res. Lett. 38, L01706, 2011)."""

_CAMERA_TAG = 0x43414D  # "CAM": the camera maps' stream, apart from every frame's


@dataclass(frozen=True, slots=True)
class ArtefactConfig:
    """The camera artefacts of the physical chain (zero or False: off).

    Attributes
    ----------
    vignetting : bool
        Multiply the image by the cos⁴ relative illumination. Default True.
    mechanical_vignetting : float
        α in [0, 1): extra loss 1 − α·ρ of the mechanical (pupil-clipping) vignetting, α the
        loss in the image corners. Default 0.
    prnu_sigma : float
        σ of the photo-response non-uniformity, a fraction of the signal, in [0, 0.2].
        Default 0.01 (1 %: a round value of the order EMVA 1288 data sheets of industrial
        global-shutter CMOS cameras give; check a specific camera's data sheet).
    dsnu_sigma_e : float
        σ of the dark-signal non-uniformity [e⁻], ≥ 0. Default 2.
    hot_pixel_fraction : float
        Fraction of hot photosites in [0, 0.1]. Default 1e-4.
    hot_pixel_dark_e_per_s : float
        Mean extra dark current of a hot photosite [e⁻/s] (exponentially distributed), ≥ 0.
        Default 5e4.
    blooming : bool
        Spill charge above the full well along the column. Default True.
    blooming_spill : float
        Fraction of a run's excess charge that spills at each step, in [0, 1]; the rest is
        drained (an anti-blooming gate). Default 1 (all of it: charge conserved).
    smear_fraction : float
        Frame-transfer smear: transfer time / exposure time, in [0, 1]. Default 0 (CMOS).
    stray_light : bool
        Veiling glare and ghost from the Sun outside the field. Default True.
    pst_edge : float
        Point-source transmittance at the field edge (half-diagonal angle) [1], in [0, 1].
        Default 1e-4 (a baffled camera; an unbaffled lens is nearer 1e-3).
    pst_slope : float
        n of PST(θ) = pst_edge·(θ_edge/θ)ⁿ, ≥ 0. Default 3.
    sun_exclusion_deg : float
        Off-axis angle beyond which the baffle blocks the Sun (no glare, no ghost) [deg],
        in (0, 90]. Default 60.
    glare_gradient : float
        Relative glare gradient toward the Sun across the half-diagonal, in [0, 1]. Default 0.5.
    ghost_reflectance : float
        Residual reflectance R of the two lens surfaces that make the ghost (fraction R²), in
        [0, 1]. Default 0.005 (a broadband anti-reflection coating).
    ghost_radius_px : float
        Radius of the defocused ghost disc [px], > 0. Default 20.
    ghost_magnification : float
        Ghost position = centre + m·(Sun's pinhole position − centre); m in [−10, 10].
        Default −0.5 (on the far side of the centre).
    jpeg_quality : int
        On-board JPEG compression of the 8-bit image, 1–100; 0: off. Default 0.
    wavelength_m : float
        Wavelength at which stray-light power becomes photons [m]. Default 530 nm.
    """

    vignetting: bool = True
    mechanical_vignetting: float = 0.0
    prnu_sigma: float = 0.01
    dsnu_sigma_e: float = 2.0
    hot_pixel_fraction: float = 1e-4
    hot_pixel_dark_e_per_s: float = 5e4
    blooming: bool = True
    blooming_spill: float = 1.0
    smear_fraction: float = 0.0
    stray_light: bool = True
    pst_edge: float = 1e-4
    pst_slope: float = 3.0
    sun_exclusion_deg: float = 60.0
    glare_gradient: float = 0.5
    ghost_reflectance: float = 0.005
    ghost_radius_px: float = 20.0
    ghost_magnification: float = -0.5
    jpeg_quality: int = 0
    wavelength_m: float = 530e-9

    def __post_init__(self):
        for name in ("vignetting", "blooming", "stray_light"):
            object.__setattr__(self, name, _checks.flag(name, getattr(self, name)))
        ranges = {"mechanical_vignetting": (0.0, 0.99), "prnu_sigma": (0.0, 0.2), "hot_pixel_fraction": (0.0, 0.1),
                  "blooming_spill": (0.0, 1.0),
                  "smear_fraction": (0.0, 1.0), "pst_edge": (0.0, 1.0), "pst_slope": (0.0, 10.0),
                  "sun_exclusion_deg": (0.0, 90.0), "glare_gradient": (0.0, 1.0), "ghost_reflectance": (0.0, 1.0),
                  "ghost_magnification": (-10.0, 10.0)}
        for name, (lo, hi) in ranges.items():
            v = _checks.finite_scalar(name, getattr(self, name))
            lo_open = name == "sun_exclusion_deg"
            if not (lo < v if lo_open else lo <= v) or v > hi:
                raise ValueError(f"{name} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        for name in ("dsnu_sigma_e", "hot_pixel_dark_e_per_s"):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), nonnegative=True))
        for name in ("ghost_radius_px", "wavelength_m"):
            object.__setattr__(self, name, _checks.finite_scalar(name, getattr(self, name), positive=True))
        object.__setattr__(self, "jpeg_quality", _checks.integer("jpeg_quality", self.jpeg_quality, 0, 100))

    @property
    def fixed_pattern(self) -> bool:
        """Whether any fixed map (PRNU, DSNU, hot pixels) is drawn."""
        return self.prnu_sigma > 0 or self.dsnu_sigma_e > 0 or (
            self.hot_pixel_fraction > 0 and self.hot_pixel_dark_e_per_s > 0)


ARTEFACTS_OFF = ArtefactConfig(vignetting=False, prnu_sigma=0.0, dsnu_sigma_e=0.0, hot_pixel_fraction=0.0,
                               blooming=False, stray_light=False)
"""Every artefact off: the chain as without artefacts, but with ``signal_e`` and ``saturation``."""


# --------------------------------------------------------------------------- vignetting


def _centred_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Column and row offsets from the image centre ((W − 1)/2, (H − 1)/2: pixel centres are
    integers) [px], shapes (1, W) and (H, 1)."""
    x = np.arange(w, dtype=np.float64) - (w - 1) / 2
    y = np.arange(h, dtype=np.float64) - (h - 1) / 2
    return x[None, :], y[:, None]


def relative_illumination(h: int, w: int, *, focal_length_m: float, pixel_pitch_m: float,
                          mechanical: float = 0.0) -> np.ndarray:
    """Relative illumination of the lens over an H×W image: cos⁴θ · (1 − α·ρ).

    Parameters
    ----------
    h, w : int
        Image height and width [px].
    focal_length_m, pixel_pitch_m : float, keyword-only
        Focal length f and pixel pitch p [m]; tan θ = r·p/f at r [px] from the image centre.
    mechanical : float, keyword-only
        α in [0, 1): mechanical vignetting, the loss at the corners (ρ = r / half-diagonal).

    Returns
    -------
    factor : ndarray of float32, shape (H, W)
        1 at the centre, falling toward the corners [1].
    """
    h = _checks.integer("h", h, 1, 1 << 20)
    w = _checks.integer("w", w, 1, 1 << 20)
    f = _checks.finite_scalar("focal_length_m", focal_length_m, positive=True)
    p = _checks.finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    alpha = _checks.finite_scalar("mechanical", mechanical, nonnegative=True)
    if alpha >= 1.0:
        raise ValueError(f"mechanical must be in [0, 1), got {mechanical!r}")
    return _relative_illumination(h, w, f, p, alpha)


@functools.lru_cache(maxsize=8)
def _relative_illumination(h: int, w: int, f: float, p: float, alpha: float) -> np.ndarray:
    x, y = _centred_grid(h, w)
    r2 = x * x + y * y
    tan2 = r2 * (p / f) ** 2
    out = 1.0 / (1.0 + tan2) ** 2  # cos⁴θ = 1/(1 + tan²θ)²
    if alpha > 0.0:
        half_diag = math.hypot((w - 1) / 2, (h - 1) / 2) or 1.0
        out = out * (1.0 - alpha * np.sqrt(r2) / half_diag)
    out = out.astype(np.float32)
    out.flags.writeable = False
    return out


# --------------------------------------------------------------------------- fixed-pattern maps


@dataclass(frozen=True)
class CameraMaps:
    """The fixed maps of one camera, on the photosites (read-only).

    Attributes
    ----------
    gain : ndarray of float32 or None
        PRNU gain 1 + σ·N(0, 1), clipped at 0 [1]; None without PRNU.
    offset_e : ndarray of float32 or None
        DSNU offset σ·N(0, 1) [e⁻]; None without DSNU.
    hot_dark_e_per_s : ndarray of float32 or None
        Extra dark current, 0 except at hot photosites [e⁻/s]; None without hot pixels.
    """

    gain: np.ndarray | None
    offset_e: np.ndarray | None
    hot_dark_e_per_s: np.ndarray | None


def camera_maps(shape, config: ArtefactConfig, camera_seed: int) -> CameraMaps:
    """PRNU, DSNU and hot-pixel maps of a camera: drawn from ``camera_seed`` alone (the same for
    every frame of a sequence; another seed, another camera).

    Parameters
    ----------
    shape : tuple of int
        Shape of the photosite array ((H, W) mosaic, or (H, W, C)).
    config : ArtefactConfig
        ``prnu_sigma``, ``dsnu_sigma_e``, ``hot_pixel_fraction``, ``hot_pixel_dark_e_per_s``.
    camera_seed : int
        The camera's seed, ≥ 0. The standard normal, uniform and exponential fields are drawn
        in this order from ``SeedSequence([camera_seed, tag])`` whatever the parameters, so a
        parameter scales a map without moving its pattern.

    Returns
    -------
    maps : CameraMaps
    """
    _checks.instance("config", config, ArtefactConfig)
    seed = _checks.integer("camera_seed", camera_seed, 0, 2**63 - 1)
    shape = tuple(_checks.integer("shape", s, 1, 1 << 20) for s in shape)
    if not config.fixed_pattern:
        return CameraMaps(None, None, None)
    return _camera_maps(shape, config.prnu_sigma, config.dsnu_sigma_e, config.hot_pixel_fraction,
                        config.hot_pixel_dark_e_per_s, seed)


@functools.lru_cache(maxsize=4)
def _camera_maps(shape, prnu, dsnu, fraction, hot_e_s, seed) -> CameraMaps:
    rng = np.random.default_rng(np.random.SeedSequence([seed, _CAMERA_TAG]))
    z_gain = rng.standard_normal(shape, dtype=np.float32)
    z_offset = rng.standard_normal(shape, dtype=np.float32)
    u_hot = rng.random(shape, dtype=np.float32)
    x_hot = rng.standard_exponential(shape, dtype=np.float32)
    gain = offset = hot = None
    if prnu > 0:
        gain = np.maximum(np.float32(1.0) + np.float32(prnu) * z_gain, np.float32(0.0))
    if dsnu > 0:
        offset = np.float32(dsnu) * z_offset
    if fraction > 0 and hot_e_s > 0:
        hot = np.where(u_hot < np.float32(fraction), np.float32(hot_e_s) * x_hot, np.float32(0.0))
    for a in (gain, offset, hot):
        if a is not None:
            a.flags.writeable = False
    return CameraMaps(gain, offset, hot)


# --------------------------------------------------------------------------- smear and blooming


def smear(mean_e, fraction: float) -> np.ndarray:
    """Frame-transfer smear of mean photo-electrons ``mean_e`` (H×W, rows shift along axis 0):
    each photosite gains ``fraction`` × its column's mean [e⁻] (a row passes under every other
    row for transfer time / rows; fraction = t_transfer / t_exp)."""
    e = np.asarray(mean_e, dtype=np.float64)
    fraction = _checks.finite_scalar("fraction", fraction, nonnegative=True)
    return e + fraction * e.mean(axis=0, keepdims=True)


def bloom(electrons, full_well_e: float, spill: float = 1.0) -> np.ndarray:
    """Blooming: the charge above the full well spills along the column (axis 0).

    Parameters
    ----------
    electrons : array_like of float, shape (H, W) or (H, W, C)
        Charge per photosite before the full-well limit [e⁻].
    full_well_e : float
        Full-well capacity FW, > 0 [e⁻].
    spill : float, optional
        Fraction s in [0, 1] of a run's excess that flows out at each step; the rest is drained
        (an anti-blooming gate). Default 1: charge is conserved. 0: a plain clip at FW.

    Returns
    -------
    electrons : ndarray of float64, shape like ``electrons``
        Every photosite ≤ FW; with ``spill=1`` each column holds the charge it held, less what
        ran off its top or bottom end.

    Notes
    -----
    Each run of full photosites (≥ FW) of a column is set to FW and its excess
    X = s·Σ(e − FW) flows out, X/2 up and X/2 down, into the gaps next to it; a gap is filled
    from its top by the run above and from its bottom by the run below, nearest photosites
    first. A gap given more than its room fills up and joins the runs on either side into one
    run whose excess is what the gap could not hold; that run spills again, half each way,
    until every excess has found room or left the array (every column at once, one pass per
    round of joins). Symmetric: a lone run's trail is centred on it.
    """
    e = np.array(electrons, dtype=np.float64)
    fw = _checks.finite_scalar("full_well_e", full_well_e, positive=True)
    spill = _checks.fraction("spill", spill)
    return _bloom(e, fw, spill)


def _bloom(e: np.ndarray, fw: float, spill: float) -> np.ndarray:
    """:func:`bloom` in place on a C-contiguous float64 array ``e`` (returned), checked arguments."""
    flat = e.reshape(e.shape[0], -1)  # columns (and channels) side by side
    hot = np.flatnonzero((flat > fw).any(axis=0))
    if hot.size == 0:
        return e
    cols = np.ascontiguousarray(flat[:, hot].T)  # (n, H): one column per row
    active = np.arange(hot.size)
    while active.size:
        cols[active] = _bloom_pass(cols[active], fw, spill)
        active = active[(cols[active] > fw).any(axis=1)]
    flat[:, hot] = cols.T
    return e


def _bloom_pass(cols: np.ndarray, fw: float, spill: float) -> np.ndarray:
    """One round of :func:`bloom` on columns laid out as rows, shape (n, H)."""
    n, h = cols.shape
    full = cols >= fw
    room = np.where(full, 0.0, fw - cols)
    f, v, r = full.ravel(), cols.ravel(), room.ravel()
    start = np.ones(f.size, dtype=bool)
    start[1:] = f[1:] != f[:-1]
    start[::h] = True  # a column starts a segment
    seg = np.cumsum(start) - 1  # segment (run of full photosites, or gap) of each photosite
    seg_start = np.flatnonzero(start)
    seg_col = seg_start // h
    seg_full = f[seg_start]
    excess = np.bincount(seg, weights=np.where(f, v - fw, 0.0), minlength=seg_start.size)
    if spill < 1.0:
        excess *= spill
    up = 0.5 * excess
    down = excess - up
    same = seg_col[1:] == seg_col[:-1]  # what would flow past a column's end leaves the array
    from_above = np.zeros(seg_start.size)
    from_above[1:] = np.where(same, down[:-1], 0.0)  # a gap gets the run above's lower half ...
    from_below = np.zeros(seg_start.size)
    from_below[:-1] = np.where(same, up[1:], 0.0)  # ... and the run below's upper half
    seg_room = np.bincount(seg, weights=r, minlength=seg_start.size)
    above = np.cumsum(room, axis=1).ravel() - r  # room above in the column (per column: small sums)
    above -= above[seg_start][seg]  # ... within the segment
    below = seg_room[seg] - above - r
    out = np.where(f, fw, v + np.clip(from_above[seg] - above, 0.0, r) + np.clip(from_below[seg] - below, 0.0, r))
    left = np.where(seg_full, 0.0, from_above + from_below - seg_room)
    over = left > 0.0  # gaps given more than their room: full, the rest in their first photosite
    out[over[seg]] = fw
    out[seg_start[over]] += left[over]
    return out.reshape(n, h)


# --------------------------------------------------------------------------- stray light and ghost


def stray_light(h: int, w: int, sun_dir_cam, *, focal_length_m: float, pixel_pitch_m: float,
                aperture_m: float | None, config: ArtefactConfig,
                sun_irradiance_W_m2: float = SOLAR_IRRADIANCE_W_M2) -> np.ndarray | None:
    """Irradiance of the Sun's veiling glare and ghost on the focal plane [W/m²].

    Parameters
    ----------
    h, w : int
        Image height and width [px] (principal point at the centre, pinhole projection).
    sun_dir_cam : array_like of 3 float
        Direction to the Sun in the camera frame (OpenCV axes: z forward), any length > 0.
    focal_length_m, pixel_pitch_m : float, keyword-only
        f and p [m].
    aperture_m : float or None, keyword-only
        Entrance-pupil diameter D [m] (None: no ghost).
    config : ArtefactConfig, keyword-only
        ``pst_edge``, ``pst_slope``, ``sun_exclusion_deg``, ``glare_gradient``,
        ``ghost_reflectance``, ``ghost_radius_px``, ``ghost_magnification``.
    sun_irradiance_W_m2 : float, keyword-only
        Solar irradiance at the camera [W/m²]. Default 1361 (1 au).

    Returns
    -------
    irradiance : ndarray of float32, shape (H, W), or None
        None when the Sun is behind the camera (z ≤ 0) or at least ``sun_exclusion_deg``
        off-axis. Else glare + ghost:

        * glare: PST(θ)·E_sun·(1 + g·s), PST(θ) = pst_edge·(θ_edge / max(θ, θ_edge))ⁿ with
          θ the Sun's off-axis angle, θ_edge = atan(half-diagonal·p/f) and s ∈ [−1, 1] the
          pixel's offset from the centre toward the Sun's azimuth over the half-diagonal (the
          PST's definition: E. Fest, *Stray Light Analysis and Control*, SPIE Press 2013; a
          power-law fall-off as for Harvey-type scatter of the lens surfaces);
        * ghost: a uniform disc of radius R_g [px] centred at c + m·(u_sun − c) (c the image
          centre, u_sun the Sun's pinhole projection), holding the power
          R²·E_sun·cos θ·πD²/4 (two reflections of the light entering the pupil).

        A Sun inside the field keeps the edge value of the PST (its own image is not drawn;
        such frames are flagged ``sun_in_lens``).
    """
    _checks.instance("config", config, ArtefactConfig)
    h = _checks.integer("h", h, 1, 1 << 20)
    w = _checks.integer("w", w, 1, 1 << 20)
    d = np.asarray(sun_dir_cam, dtype=np.float64)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.linalg.norm(d) > 0:
        raise ValueError(f"sun_dir_cam must be a finite non-zero 3-vector, got {sun_dir_cam!r}")
    d = d / np.linalg.norm(d)
    f = _checks.finite_scalar("focal_length_m", focal_length_m, positive=True)
    p = _checks.finite_scalar("pixel_pitch_m", pixel_pitch_m, positive=True)
    e_sun = _checks.finite_scalar("sun_irradiance_W_m2", sun_irradiance_W_m2, nonnegative=True)
    theta = math.acos(min(max(d[2], -1.0), 1.0))
    if d[2] <= 0.0 or theta >= math.radians(config.sun_exclusion_deg):
        return None
    x, y = _centred_grid(h, w)
    half_diag = math.hypot((w - 1) / 2, (h - 1) / 2) or 1.0
    theta_edge = math.atan(math.hypot(w / 2, h / 2) * p / f)
    level = config.pst_edge * (theta_edge / max(theta, theta_edge)) ** config.pst_slope * e_sun
    azimuth = math.hypot(d[0], d[1])
    g = config.glare_gradient / half_diag if azimuth > 0 else 0.0
    # level·(1 + g·s) as the sum of a row and a column term: one pass over the frame
    row = (level * (1.0 + g * x * (d[0] / (azimuth or 1.0)))).astype(np.float32)
    col = (level * g * y * (d[1] / (azimuth or 1.0))).astype(np.float32)
    out = row + col
    # the ghost's distance from the centre, |m|·(f/p)·tan θ, against the image's size (no overflow near 90°)
    reach = 4.0 * (w + h + 2 * config.ghost_radius_px)
    far = abs(config.ghost_magnification) * (f / p) * math.hypot(d[0], d[1]) > d[2] * reach
    if aperture_m is not None and config.ghost_reflectance > 0 and not far:
        D = _checks.finite_scalar("aperture_m", aperture_m, positive=True)
        u_sun, v_sun = (f / p) * d[0] / d[2], (f / p) * d[1] / d[2]  # from the centre [px]
        m = config.ghost_magnification
        gx, gy, rg = m * u_sun, m * v_sun, config.ghost_radius_px
        power = config.ghost_reflectance ** 2 * e_sun * d[2] * math.pi * D * D / 4  # [W]
        # pixels of the disc on the unbounded pixel grid (so its power stays with the disc's part in view)
        r = math.ceil(rg) + 1
        k = np.arange(-r, r + 1)
        gcol, grow = gx + (w - 1) / 2, gy + (h - 1) / 2  # in pixel indices (integers at pixel centres)
        gxf, gyf = gcol - math.floor(gcol), grow - math.floor(grow)
        n_disc = int(np.count_nonzero((k[None, :] - gxf) ** 2 + (k[:, None] - gyf) ** 2 <= rg * rg))
        c0, c1 = max(0, math.floor(gcol - rg)), min(w, math.ceil(gcol + rg) + 1)
        r0, r1 = max(0, math.floor(grow - rg)), min(h, math.ceil(grow + rg) + 1)
        if n_disc and c0 < c1 and r0 < r1:  # the disc's bounding box in view
            inside = (x[:, c0:c1] - gx) ** 2 + (y[r0:r1] - gy) ** 2 <= rg * rg
            out[r0:r1, c0:c1] += np.float32(power / (n_disc * p * p)) * inside
    return out


def irradiance_to_signal(irradiance, *, exposure_s: float, pixel_pitch_m: float, wavelength_m: float,
                         photons_at_one: float):
    """Focal-plane irradiance [W/m²] → the chain's linear signal (1 = ``photons_at_one``
    photons per pixel): E·p²·t·λ/(h c) photons per pixel, as in the camera equation
    (:func:`degrade.exposure.physical_exposure`; the sensor applies the QE)."""
    from .exposure import LIGHT_SPEED_M_S, PLANCK_J_S
    photons = irradiance * (pixel_pitch_m ** 2 * exposure_s * wavelength_m / (PLANCK_J_S * LIGHT_SPEED_M_S))
    return photons / photons_at_one


# --------------------------------------------------------------------------- JPEG


def _jpeg_input(rgb8, quality) -> tuple[np.ndarray, int]:
    img = np.ascontiguousarray(rgb8)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise ValueError(f"rgb8 must be an H×W(×C) uint8 image, got {img.dtype} of shape {img.shape}")
    return img, _checks.integer("quality", quality, 1, 100)


def _write_jpeg(img: np.ndarray, quality: int, path: str) -> None:
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(img if img.ndim == 3 else img[:, :, None])
    buf.specmod().attribute("Compression", f"jpeg:{quality}")
    if not buf.write(path):  # pragma: no cover - OpenImageIO failure
        raise RuntimeError(f"OpenImageIO could not write JPEG: {buf.geterror()}")


def jpeg_bytes(rgb8, quality: int) -> bytes:
    """The JPEG file (baseline, OpenImageIO's libjpeg codec, ``Compression = "jpeg:Q"``) of an
    8-bit image at ``quality`` 1–100: what :func:`jpeg_roundtrip` decodes."""
    img, q = _jpeg_input(rgb8, quality)
    with tempfile.TemporaryDirectory(prefix="orbitsynth-jpeg-") as tmp:
        path = os.path.join(tmp, "frame.jpg")
        _write_jpeg(img, q, path)
        with open(path, "rb") as fh:
            return fh.read()


def jpeg_roundtrip(rgb8, quality: int) -> np.ndarray:
    """Compress an 8-bit image to JPEG at ``quality`` (1–100) with OpenImageIO's codec and
    decode it again (the on-board compression of the degraded copy).

    Parameters
    ----------
    rgb8 : array_like of uint8, shape (H, W, 3) or (H, W)
        The image.
    quality : int
        JPEG quality 1–100 (OpenImageIO ``Compression = "jpeg:Q"``).

    Returns
    -------
    decoded : ndarray of uint8, shape like ``rgb8``
    """
    import OpenImageIO as oiio
    img, q = _jpeg_input(rgb8, quality)
    with tempfile.TemporaryDirectory(prefix="orbitsynth-jpeg-") as tmp:
        path = os.path.join(tmp, "frame.jpg")
        _write_jpeg(img, q, path)
        out = oiio.ImageBuf(path).get_pixels(oiio.UINT8)
    return np.ascontiguousarray(out.reshape(img.shape))
