"""Relative-motion patterns: characteristic point, pattern parameters, classification.

The in-plane CW motion always has the form (τ = n(t − t_p); docs/orbit.md, "Patterns and their
thresholds")::

    x(t) = x_l + A cos τ
    y(t) = γ − 2A sin τ − β (t − t_p)

an ellipse of semi-axes A (radial) × 2A (along-track) whose centre sits at radial offset
x_l and drifts along-track at −β = −(3/2) n x_l. P, the characteristic point, is the
instant where ẋ = 0 and x is maximal (x_p = x_l + A).

Two dimensionless numbers describe the shape: κ = x_l / A and the paper's
σ = −ẏ_p / (n x_p) = (4 + 3κ) / (2(1 + κ)). The pattern follows from |κ| alone:

=============  ==========================  =================================================
pattern        κ                           σ (for x_p > 0)
=============  ==========================  =================================================
elliptical     κ = 0                       σ = 2
spiral         0 < |κ| < κ*                1.8877036417 < σ < 2.2038732545, σ ≠ 2
drip-drop      κ* ≤ |κ| < 1                7/4 < σ ≤ 1.8877036417 or σ ≥ 2.2038732545
drift          |κ| ≥ 1 (or A = 0, x_l ≠ 0)  σ ≤ 7/4 (and every x_p < 0)
stationary     A = 0 and x_l = 0           undefined
=============  ==========================  =================================================

κ* = (4/3)|cos u*| with u* the first root of tan u = u beyond π: below it consecutive
revolutions intersect (spiral), above it the loops are disjoint (drip-drop). |κ| < 1 is the
condition for the curve to cross the V-bar. κ* is computed here from its definition.

References
----------
W. H. Clohessy and R. S. Wiltshire (1960), doi:10.2514/8.8704.
The σ classification follows the source paper (Remote Sens. 2026, 18(8), 1177,
doi:10.3390/rs18081177) with the corrections listed in docs/accuracy.md, "Where this departs
from the source paper".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._checks import finite_array, finite_scalar, mean_motion
from .cw import propagate

__all__ = [
    "PATTERNS",
    "U_STAR",
    "KAPPA_STAR",
    "KAPPA_LOOP",
    "SIGMA_VBAR",
    "SIGMA_LOOP",
    "SIGMA_SPIRAL_LOW",
    "SIGMA_SPIRAL_HIGH",
    "ELLIPTICAL_RTOL",
    "PatternParameters",
    "parameters",
    "classify",
    "classify_sigma",
    "sigma_from_kappa",
    "kappa_from_sigma",
    "state_from_pattern",
    "state_from_kappa",
    "state_from_sigma",
]

PATTERNS = ("elliptical", "spiral", "drip-drop", "drift")
"""The four generated patterns (``"stationary"`` is the degenerate fifth class)."""


def _first_tan_root_beyond_pi() -> float:
    """First root of tan u = u in (π, 3π/2), by Newton on f(u) = sin u − u cos u."""
    u = 4.5
    for _ in range(50):
        f = math.sin(u) - u * math.cos(u)
        step = f / (u * math.sin(u))  # f'(u) = u sin u
        u -= step
        if abs(step) < 1e-16:
            break
    return u


U_STAR = _first_tan_root_beyond_pi()
"""u* ≈ 4.493409457909064: first root of tan u = u beyond π; min over w > 0 of sin w / w is cos u*."""

KAPPA_STAR = (4.0 / 3.0) * abs(math.cos(U_STAR))
"""κ* ≈ 0.2896448376: spiral (overlapping revolutions) for |κ| < κ*, drip-drop above."""

KAPPA_LOOP = 4.0 / 3.0
"""A self-crossing loop exists within one revolution iff |κ| < 4/3."""


def sigma_from_kappa(kappa: float) -> float:
    """σ = (4 + 3κ) / (2(1 + κ)) for a state at P with x_p > 0 (κ > −1); κ = ±inf gives 1.5."""
    if math.isinf(kappa):
        return 1.5
    return (4.0 + 3.0 * kappa) / (2.0 * (1.0 + kappa))


def kappa_from_sigma(sigma: float) -> float:
    """κ = (4 − 2σ) / (2σ − 3); σ = 1.5 (A = 0) gives +inf."""
    if sigma == 1.5:
        return math.inf
    return (4.0 - 2.0 * sigma) / (2.0 * sigma - 3.0)


SIGMA_VBAR = 7.0 / 4.0
"""σ at |κ| = 1: drift for σ ≤ 7/4 (the curve touches the V-bar at P)."""

SIGMA_LOOP = 12.0 / 7.0
"""σ at κ = 4/3: drift trajectories still loop for 12/7 < σ ≤ 7/4."""

SIGMA_SPIRAL_LOW = sigma_from_kappa(KAPPA_STAR)
"""σ ≈ 1.8877036417 at κ = +κ*: spiral above, drip-drop at or below."""

SIGMA_SPIRAL_HIGH = sigma_from_kappa(-KAPPA_STAR)
"""σ ≈ 2.2038732545 at κ = −κ*: spiral below, drip-drop at or above."""

ELLIPTICAL_RTOL = 1e-9
"""Elliptical iff |x_l| ≤ ELLIPTICAL_RTOL · max(A, |x_l|, 1e-9 m)."""

_P_PHASE_SNAP_RAD = 1e-9  # a P this close before t0 (in phase) is taken as at t0
_XP_ZERO_RTOL = 1e-12  # |x_p| below this fraction of max(A, |x_l|) is x_p = 0 (σ undefined)


@dataclass(frozen=True, slots=True)
class PatternParameters:
    """Pattern parameters of a relative state, SI units (docs/orbit.md, "Patterns and their
    thresholds").

    Attributes
    ----------
    A : float
        Radial semi-amplitude of the periodic ellipse (≥ 0) [m]; along-track semi-axis 2A.
    x_l : float
        Radial offset of the ellipse centre [m].
    beta : float
        Along-track drift rate β = (3/2) n x_l; the centre moves at ẏ = −β [m/s].
    gamma : float
        Along-track position y at P [m].
    t_p : float
        Time of the first P at or after ``t0`` [s].
    x_p : float
        Radial position at P, x_l + A [m].
    ydot_p : float
        Along-track velocity at P, −2nA − β [m/s].
    sigma : float
        σ = −ẏ_p/(n x_p) [-]; NaN where x_p = 0 (undefined).
    kappa : float
        κ = x_l/A [-]; ±inf for a pure drift line (A = 0), NaN when stationary.
    pattern : str
        ``"elliptical"``, ``"spiral"``, ``"drip-drop"``, ``"drift"`` or ``"stationary"``.
    side : str
        ``"above"`` (x_l > 0, drifts towards −y), ``"below"`` (x_l < 0, drifts towards +y),
        or ``""`` for elliptical and stationary motion.
    n : float
        Mean motion used [rad/s].
    t0 : float
        Time of the state the parameters were computed from [s].
    tau0 : float
        In-plane phase at ``t0``, n(t0 − previous P) mod 2π [rad].
    z_amp : float
        Out-of-plane amplitude B, z(t) = B cos(n(t − t0) + z_phase) [m].
    z_phase : float
        Out-of-plane phase at ``t0`` [rad].
    """

    A: float
    x_l: float
    beta: float
    gamma: float
    t_p: float
    x_p: float
    ydot_p: float
    sigma: float
    kappa: float
    pattern: str
    side: str
    n: float
    t0: float
    tau0: float
    z_amp: float
    z_phase: float

    @property
    def alpha(self) -> float:
        """The paper's size parameter α = −2A (≤ 0 because P is the maximum of x) [m]."""
        return -2.0 * self.A

    @property
    def drift_per_revolution_m(self) -> float:
        """Along-track displacement of the ellipse centre per revolution, −3π x_l [m]."""
        return -3.0 * math.pi * self.x_l

    def to_dict(self) -> dict:
        """Plain-Python view (NaN/inf become None/str so the result is valid JSON)."""
        out = {}
        for key in self.__slots__:
            value = getattr(self, key)
            if isinstance(value, float) and not math.isfinite(value):
                value = None if math.isnan(value) else ("inf" if value > 0 else "-inf")
            out[key] = value
        out["alpha"] = self.alpha
        return out


def classify(A: float, x_l: float, *, length_scale_m: float = 0.0) -> str:
    """Classify in-plane relative motion from its amplitude and centre offset (by κ = x_l / A).

    Parameters
    ----------
    A : float
        Radial semi-amplitude, ≥ 0 [m].
    x_l : float
        Radial offset of the ellipse centre [m].
    length_scale_m : float, optional
        Size of the whole motion (e.g. |γ|); A and x_l both below 1e-9 of it count as
        zero, i.e. a V-bar hold. With the default 0 only exact zeros are stationary.

    Returns
    -------
    str
        ``"elliptical"``, ``"spiral"``, ``"drip-drop"``, ``"drift"`` or ``"stationary"``.

    Notes
    -----
    Boundaries: |κ| = κ* is drip-drop, |κ| = 1 is drift (the paper's "σ ≤ 1.75").
    """
    A = finite_scalar("A", A, nonnegative=True)
    x_l = finite_scalar("x_l", x_l)
    length_scale_m = finite_scalar("length_scale_m", length_scale_m, nonnegative=True)
    if max(A, abs(x_l)) <= ELLIPTICAL_RTOL * length_scale_m or (A == 0.0 and x_l == 0.0):
        return "stationary"
    if abs(x_l) <= ELLIPTICAL_RTOL * max(A, abs(x_l), 1e-9):
        return "elliptical"
    if A == 0.0:
        return "drift"
    k = abs(x_l) / A
    if k < KAPPA_STAR:
        return "spiral"
    if k < 1.0:
        return "drip-drop"
    return "drift"


def classify_sigma(sigma: float, x_p: float) -> str:
    """Classify from the paper's σ and the sign of x_p, for compatibility.

    Parameters
    ----------
    sigma : float
        σ = −ẏ_p/(n x_p) evaluated at the characteristic point P [-].
    x_p : float
        Radial position at P [m]; only its sign matters.

    Returns
    -------
    str
        The pattern name; agrees with :func:`classify` away from round-off at boundaries.

    Raises
    ------
    ValueError
        σ < 1.5 with x_p > 0 (the state was a minimum of x, not P), σ > 1.5 with x_p < 0
        (negative amplitude), or x_p = 0 (σ undefined: use :func:`classify`).
    """
    sigma = finite_scalar("sigma", sigma)
    x_p = finite_scalar("x_p", x_p)
    if x_p == 0.0:
        raise ValueError("x_p must be non-zero to classify by sigma (sigma is undefined at x_p = 0); "
                         "classify by kappa with orbit.patterns.classify(A, x_l)")
    if x_p < 0.0:
        if sigma > 1.5:
            raise ValueError(f"sigma must be <= 1.5 when x_p < 0 (A = x_p(2 sigma - 3) >= 0), got {sigma!r}")
        return "drift"
    if sigma < 1.5:
        raise ValueError(f"sigma must be >= 1.5 when x_p > 0; sigma < 1.5 means the state is a minimum of x, "
                         f"not the characteristic point P, got {sigma!r}")
    if sigma <= SIGMA_VBAR:
        return "drift"
    if abs(kappa_from_sigma(sigma)) <= ELLIPTICAL_RTOL:
        return "elliptical"
    if sigma <= SIGMA_SPIRAL_LOW or sigma >= SIGMA_SPIRAL_HIGH:
        return "drip-drop"
    return "spiral"


def parameters(s_lvlh, n: float, t0: float = 0.0) -> PatternParameters:
    """Pattern parameters of any relative state, all in closed form.

    Parameters
    ----------
    s_lvlh : array_like, shape (6,)
        Relative state ``[x, y, z, ẋ, ẏ, ż]`` at time ``t0`` [m, m/s].
    n : float
        Mean motion [rad/s].
    t0 : float, optional
        Time of the state [s].

    Returns
    -------
    PatternParameters

    Notes
    -----
    With S = ẋ₀/n and C = −(3x₀ + 2ẏ₀/n): A = √(S² + C²), x_l = 4x₀ + 2ẏ₀/n,
    β = 3(ẏ₀ + 2n x₀), t_p = t₀ + (atan2(S, C) mod 2π)/n and γ = y(t_p).
    """
    s = finite_array("s_lvlh", s_lvlh)
    if s.shape != (6,):
        raise ValueError(f"s_lvlh must have shape (6,), got {s.shape}")
    n = mean_motion("n", n)
    t0 = finite_scalar("t0", t0)
    x0, y0, z0, vx0, vy0, vz0 = (float(v) for v in s)

    S = vx0 / n
    C = -(3.0 * x0 + 2.0 * vy0 / n)
    A = math.hypot(S, C)
    x_l = 4.0 * x0 + 2.0 * vy0 / n
    beta = 3.0 * (vy0 + 2.0 * n * x0)
    phase = math.atan2(S, C) % (2.0 * math.pi) if A > 0.0 else 0.0
    if phase > 2.0 * math.pi - _P_PHASE_SNAP_RAD:
        phase = 0.0
    dt_p = phase / n
    gamma = float(propagate(s, n, dt_p)[0, 1])
    x_p = x_l + A
    if abs(x_p) <= _XP_ZERO_RTOL * max(A, abs(x_l)):
        x_p = 0.0
    ydot_p = -2.0 * n * A - beta
    sigma = -ydot_p / (n * x_p) if x_p != 0.0 else math.nan
    if A > 0.0:
        kappa = x_l / A
    else:
        kappa = math.copysign(math.inf, x_l) if x_l != 0.0 else math.nan
    scale = max(abs(gamma), abs(y0), math.hypot(z0, vz0 / n))
    pattern = classify(A, x_l, length_scale_m=scale)
    side = ""
    if pattern not in ("elliptical", "stationary"):
        side = "above" if x_l > 0.0 else "below"
    if pattern == "stationary":
        kappa, sigma = math.nan, math.nan
    return PatternParameters(
        A=A, x_l=x_l, beta=beta, gamma=gamma, t_p=t0 + dt_p, x_p=x_p, ydot_p=ydot_p,
        sigma=sigma, kappa=kappa, pattern=pattern, side=side, n=n, t0=t0,
        tau0=(2.0 * math.pi - phase) % (2.0 * math.pi),
        z_amp=math.hypot(z0, vz0 / n), z_phase=math.atan2(-vz0 / n, z0),
    )


def state_from_pattern(A: float, beta: float, gamma: float, n: float, *, z_amp: float = 0.0,
                       z_phase: float = 0.0, tau0: float = 0.0) -> np.ndarray:
    """Initial state from pattern parameters (the inverse of :func:`parameters`).

    Parameters
    ----------
    A : float
        Radial semi-amplitude, ≥ 0 [m].
    beta : float
        Along-track drift rate; the ellipse centre moves at −β [m/s].
    gamma : float
        Along-track position at the characteristic point P that precedes t = 0 by τ₀/n [m].
    n : float
        Mean motion [rad/s].
    z_amp : float, optional
        Out-of-plane amplitude B ≥ 0 [m].
    z_phase : float, optional
        Out-of-plane phase φ_z at t = 0: z(t) = B cos(nt + φ_z) [rad].
    tau0 : float, optional
        In-plane phase at t = 0 after P; 0 starts the sequence at P [rad].

    Returns
    -------
    s0_lvlh : ndarray, shape (6,), float64
        ``Φ(τ₀/n) · [A + 2β/(3n), γ, 0, 0, −β − 2nA, 0]`` with z(0) = B cos φ_z and
        ż(0) = −nB sin φ_z [m, m/s].

    Notes
    -----
    :func:`parameters` reports γ at the first P at or after t = 0, so for τ₀ ∈ (0, 2π) it
    returns γ − β·2π/n (one revolution of drift later) and t_p = (2π − τ₀)/n.
    """
    A = finite_scalar("A", A, nonnegative=True)
    beta = finite_scalar("beta", beta)
    gamma = finite_scalar("gamma", gamma)
    n = mean_motion("n", n)
    z_amp = finite_scalar("z_amp", z_amp, nonnegative=True)
    z_phase = finite_scalar("z_phase", z_phase)
    tau0 = finite_scalar("tau0", tau0)
    s_p = np.array([A + 2.0 * beta / (3.0 * n), gamma, 0.0, 0.0, -beta - 2.0 * n * A, 0.0])
    s0 = propagate(s_p, n, tau0 / n)[0]
    s0[2] = z_amp * math.cos(z_phase)
    s0[5] = -n * z_amp * math.sin(z_phase)
    return s0


def state_from_kappa(A: float, kappa: float, gamma: float, n: float, *, z_amp: float = 0.0,
                     z_phase: float = 0.0, tau0: float = 0.0) -> np.ndarray:
    """Initial state from (A, κ, γ): x_l = κA, β = (3/2) n x_l, then :func:`state_from_pattern`.

    Parameters are as in :func:`state_from_pattern`, with ``kappa`` = x_l/A [-] (finite).
    """
    A = finite_scalar("A", A, nonnegative=True)
    kappa = finite_scalar("kappa", kappa)
    n = mean_motion("n", n)
    beta = 1.5 * n * kappa * A
    return state_from_pattern(A, beta, gamma, n, z_amp=z_amp, z_phase=z_phase, tau0=tau0)


def state_from_sigma(x_p: float, sigma: float, gamma: float, n: float, *, z_amp: float = 0.0,
                     z_phase: float = 0.0, tau0: float = 0.0) -> np.ndarray:
    """Initial state from the paper's parameters (x_p, σ, γ): A = x_p(2σ − 3), β = 3n x_p(2 − σ).

    Raises
    ------
    ValueError
        x_p = 0, σ < 1.5 with x_p > 0 (a minimum of x, not P) or σ > 1.5 with x_p < 0.
    """
    x_p = finite_scalar("x_p", x_p)
    sigma = finite_scalar("sigma", sigma)
    n = mean_motion("n", n)
    classify_sigma(sigma, x_p)  # validates the (σ, x_p) combination
    A = x_p * (2.0 * sigma - 3.0)
    beta = 3.0 * n * x_p * (2.0 - sigma)
    return state_from_pattern(max(A, 0.0), beta, gamma, n, z_amp=z_amp, z_phase=z_phase, tau0=tau0)
