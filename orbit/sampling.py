"""Seeded sampling of relative-motion patterns around a target of a given size.

The draws (docs/orbit.md, "How a sequence is drawn") are distributions for a camera kept 10–60 m
from a target. Those numbers suit a target whose bounding radius is at most
:data:`REFERENCE_RADIUS_M` (4 m, a Crew Dragon).
For a larger target every length — the band, A, |x_l|, B and the drift length — is
multiplied by ``scale = max(1, R_b / REFERENCE_RADIUS_M)``. CW motion is linear and the
pattern classes depend only on κ, so the shapes and the acceptance rates are unchanged, and
the target keeps the same apparent size at the band's edges: the built-in Tiangong
(R_b = 36.2 m) is viewed from 91–544 m instead of 10–60 m.

A sample is rejected unless r_min ≤ |r(t)| ≤ r_max at every frame time **and** on a
1024-point grid over the window, so the band also holds between sparse frames.

The sampled quantities are returned with the state (:class:`PatternSample`) so that a
dataset records exactly how each sequence was drawn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ._checks import finite_scalar, mean_motion, one_of
from .cw import propagate
from .patterns import PATTERNS, PatternParameters, parameters, state_from_kappa

__all__ = [
    "REFERENCE_RADIUS_M",
    "BASE_BAND_M",
    "RangeBand",
    "PatternSample",
    "range_band",
    "default_window_s",
    "sample_pattern",
]

REFERENCE_RADIUS_M = 4.0
"""Largest target bounding radius for which the 10–60 m band is used unscaled [m]."""

BASE_BAND_M = (10.0, 60.0)
"""Allowed camera range for a target of radius ≤ REFERENCE_RADIUS_M [m]."""

_CHECK_GRID = 1024
_DRIFT_LENGTH_M = 80.0  # along-track distance the drift centre covers in its window
_DRIFT_MARGIN_M = 10.5  # |x_l| − A ≥ this keeps a drift clear of the 10 m keep-out


@dataclass(frozen=True, slots=True)
class RangeBand:
    """Allowed camera–target distance band [m]."""

    r_min_m: float
    r_max_m: float

    def __post_init__(self):
        lo = finite_scalar("r_min_m", self.r_min_m, positive=True)
        hi = finite_scalar("r_max_m", self.r_max_m, positive=True)
        if not hi > lo:
            raise ValueError(f"r_max_m must exceed r_min_m, got {lo!r}–{hi!r} m")

    @property
    def scale(self) -> float:
        """Length scale relative to the 10–60 m band [-]."""
        return self.r_min_m / BASE_BAND_M[0]


def range_band(target_radius_m: float) -> RangeBand:
    """Camera range band for a target of bounding radius ``target_radius_m`` [m].

    Returns ``(10 s, 60 s)`` m with ``s = max(1, target_radius_m / 4 m)``.
    """
    radius = finite_scalar("target_radius_m", target_radius_m, positive=True)
    s = max(1.0, radius / REFERENCE_RADIUS_M)
    return RangeBand(BASE_BAND_M[0] * s, BASE_BAND_M[1] * s)


def default_window_s(pattern: str, n: float, *, x_l_m: float = 0.0, scale: float = 1.0) -> float:
    """Window length T_w of the sampling table [s] (docs/orbit.md, "How a sequence is drawn").

    elliptical: one period T; spiral and drip-drop: T/2; drift: min(T, 80 m·scale / |β|) with
    β = (3/2) n x_l, i.e. the time for the drifting centre to cover 80 m·scale.
    """
    one_of("pattern", pattern, PATTERNS)
    n = mean_motion("n", n)
    period = 2.0 * math.pi / n
    if pattern == "elliptical":
        return period
    if pattern in ("spiral", "drip-drop"):
        return period / 2.0
    beta = 1.5 * n * abs(x_l_m)
    return period if beta == 0.0 else min(period, _DRIFT_LENGTH_M * scale / beta)


@dataclass(frozen=True, slots=True)
class PatternSample:
    """One accepted pattern draw.

    Attributes
    ----------
    pattern : str
        The requested (and verified) pattern.
    s0_lvlh : ndarray, shape (6,)
        Initial relative state at t = 0 [m, m/s].
    n : float
        Mean motion [rad/s].
    t_s : ndarray, shape (N,)
        Frame times, evenly spaced over [0, window_s] [s].
    window_s : float
        Window length T_w [s].
    band : RangeBand
        The range band every accepted sample respects.
    params : PatternParameters
        Pattern parameters of ``s0_lvlh``.
    draws : dict
        The sampled quantities: ``A_m``, ``kappa``, ``x_l_m``, ``beta_m_s``, ``gamma_m``,
        ``tau0_rad``, ``z_amp_m``, ``z_phase_rad`` (SI).
    attempts : int
        Number of draws made, the accepted one included.
    range_m : tuple of float
        (min, max) of |r| over the checked times [m].
    """

    pattern: str
    s0_lvlh: np.ndarray
    n: float
    t_s: np.ndarray
    window_s: float
    band: RangeBand
    params: PatternParameters
    draws: dict = field(default_factory=dict)
    attempts: int = 1
    range_m: tuple = (math.nan, math.nan)


def _draw(pattern: str, rng: np.random.Generator, scale: float, r_max: float):
    """One draw of (A, κ, B, T_w-relevant x_l) from the sampling table, lengths × scale."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if pattern == "elliptical":
        A = rng.uniform(10.0, 28.0) * scale
        kappa = 0.0
        z_amp = rng.uniform(0.0, min(A, math.sqrt(max(r_max * r_max - 4.0 * A * A, 0.0))))
    elif pattern == "spiral":
        A = rng.uniform(10.0, 22.0) * scale
        kappa = sign * rng.uniform(0.03, 0.28)
        z_amp = rng.uniform(0.0, 8.0) * scale
    elif pattern == "drip-drop":
        A = rng.uniform(8.0, 16.0) * scale
        kappa = sign * rng.uniform(0.30, 0.95)
        z_amp = rng.uniform(0.0, 5.0) * scale
    else:  # drift
        x_l_abs = rng.uniform(12.0, 30.0) * scale
        A = min(x_l_abs / rng.uniform(1.0, 6.0), x_l_abs - _DRIFT_MARGIN_M * scale)
        kappa = sign * x_l_abs / A
        z_amp = rng.uniform(0.0, 5.0) * scale
    tau0 = rng.uniform(0.0, 2.0 * math.pi)
    z_phase = rng.uniform(0.0, 2.0 * math.pi)
    return A, kappa, z_amp, tau0, z_phase


def sample_pattern(pattern: str, n: float, *, target_radius_m: float, n_frames: int,
                   rng=None, window_s: float | None = None, max_attempts: int = 10_000) -> PatternSample:
    """Draw an initial state of the requested pattern that keeps the camera in range.

    Parameters
    ----------
    pattern : {"elliptical", "spiral", "drip-drop", "drift"}
        Pattern to sample.
    n : float
        Mean motion of the target orbit [rad/s].
    target_radius_m : float
        Bounding radius of the target about its centre of mass [m]; sets the band
        (:func:`range_band`) and the length scale of the draws.
    n_frames : int
        Number of frame times, evenly spaced over [0, window_s] (≥ 1).
    rng : int, numpy.random.Generator or None, keyword-only
        Seed or generator; normalised once with ``np.random.default_rng``.
    window_s : float, optional
        Window length [s]; default from :func:`default_window_s`.
    max_attempts : int, optional
        Draws before giving up.

    Returns
    -------
    PatternSample

    Raises
    ------
    ValueError
        Unknown pattern, non-positive sizes or counts, or no draw kept the band within
        ``max_attempts`` (e.g. a ``window_s`` so long that the drift leaves the band).

    Notes
    -----
    Each draw centres the window on the target along-track: x_l = κA, β = (3/2) n x_l,
    γ = β(T_w/2 + τ₀/n), so the ellipse centre passes y = 0 at t = T_w/2.
    """
    one_of("pattern", pattern, PATTERNS)
    n = mean_motion("n", n)
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ValueError(f"n_frames must be an integer >= 1, got {n_frames!r}")
    if isinstance(max_attempts, bool) or not isinstance(max_attempts, (int, np.integer)) or max_attempts < 1:
        raise ValueError(f"max_attempts must be an integer >= 1, got {max_attempts!r}")
    if window_s is not None:
        window_s = finite_scalar("window_s", window_s, positive=True)
    band = range_band(target_radius_m)
    scale = band.scale
    rng = np.random.default_rng(rng)

    for attempt in range(1, int(max_attempts) + 1):
        A, kappa, z_amp, tau0, z_phase = _draw(pattern, rng, scale, band.r_max_m)
        x_l = kappa * A
        beta = 1.5 * n * x_l
        t_w = window_s if window_s is not None else default_window_s(pattern, n, x_l_m=x_l, scale=scale)
        gamma = beta * (t_w / 2.0 + tau0 / n)
        s0 = state_from_kappa(A, kappa, gamma, n, z_amp=z_amp, z_phase=z_phase, tau0=tau0)
        t_frames = np.linspace(0.0, t_w, int(n_frames)) if n_frames > 1 else np.zeros(1)
        t_check = np.concatenate([t_frames, np.linspace(0.0, t_w, _CHECK_GRID)])
        r = np.linalg.norm(propagate(s0, n, t_check)[:, :3], axis=1)
        r_lo, r_hi = float(r.min()), float(r.max())
        if r_lo < band.r_min_m or r_hi > band.r_max_m:
            continue
        params = parameters(s0, n)
        if params.pattern != pattern:  # cannot happen with the table's κ ranges; guard anyway
            continue
        s0.setflags(write=False)
        t_frames.setflags(write=False)
        draws = {"A_m": A, "kappa": kappa, "x_l_m": x_l, "beta_m_s": beta, "gamma_m": gamma,
                 "tau0_rad": tau0, "z_amp_m": z_amp, "z_phase_rad": z_phase}
        return PatternSample(pattern=pattern, s0_lvlh=s0, n=n, t_s=t_frames, window_s=t_w, band=band,
                             params=params, draws=draws, attempts=attempt, range_m=(r_lo, r_hi))
    raise ValueError(
        f"no {pattern} draw stayed within {band.r_min_m:g}–{band.r_max_m:g} m over window_s="
        f"{window_s if window_s is not None else 'default'} in {max_attempts} attempts; "
        "use a shorter window_s")
