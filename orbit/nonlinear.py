"""Numerical reference for relative motion: exact two-body dynamics and, beyond the CW model, J2.

The closed-form Clohessy–Wiltshire solution (:mod:`orbit.cw`) is a linearisation. This module
integrates the motion it approximates so that its error can be measured (docs/accuracy.md,
"CW error after one orbit"):

* ``method="rotating"`` — exact two-body relative dynamics of the observer in the rotating LVLH
  frame of a circular target orbit (no linearisation; f ≈ −3x/r₀ gives the CW equations)::

      ẍ = 2n ẏ − n² f (r₀ + x),   ÿ = −2n ẋ − n² f y,   z̈ = −n² (1 + f) z,
      f = (r₀/r_O)³ − 1 = expm1(−1.5 · log1p(q)),   q = (2 r₀ x + |ρ|²)/r₀².

* ``method="eci"`` — an independent formulation: the target's ECI state and the observer's
  ECI offset δ = r_O − r_T are integrated together (12 states). The differential gravity is
  written without cancellation::

      a(r_T + δ) − a(r_T) = −μ/|r_O|³ [δ + r_T (1 − |r_O|³/|r_T|³)],
      1 − |r_O|³/|r_T|³ = −expm1(1.5 · log1p(q)),   q = (2 r_T·δ + |δ|²)/|r_T|²,

  plus, with ``j2=True``, the J2 acceleration of both spacecraft (the target's orbit is then
  no longer circular and its RAAN precesses). Results are expressed in the target's *actual*
  LVLH frame at each instant: x̂ = r_T/|r_T|, ẑ = h/|h|, ŷ = ẑ × x̂, rotating at
  ω = [|r_T| a_h/|h|, 0, |h|/|r_T|²] (a_h: out-of-plane perturbing acceleration of the target),
  so that ρ = Rᵀ δ and ρ̇ = Rᵀ δv − ω × ρ.

Both are integrated with scipy's DOP853 (Hairer, Nørsett & Wanner) at ``rtol = 1e-12`` by
default. With two-body gravity they agree after one orbit to ≈ 1.7e-11·|ρ| at that rtol
(< 1e-7 m up to |ρ| ≈ 5 km) and to ≈ 1.7e-12·|ρ| at ``rtol = 1e-13`` (< 1e-7 m for
10 m ≤ |ρ| ≤ 10 km); the difference is the truncation error of the "eci"
formulation (tests/orbit/test_nonlinear.py).

J2 is not part of the CW model (a known limitation, docs/accuracy.md, "Orbit model"). With it a CW
ellipse of radial semi-axis A drifts along-track by ≈ −0.045·A·(1 − 3 sin²φ₀) per orbit at
400 km, φ₀ being the target's latitude when the CW state is set (measured; the secular J2
effects on formations are analysed by Schweighart & Sedwick).

References
----------
K. T. Alfriend, S. R. Vadali, P. Gurfil, J. P. How and L. S. Breger, *Spacecraft Formation
Flying: Dynamics, Control and Navigation*, Butterworth-Heinemann (2010), ch. 4 "Nonlinear
models of relative dynamics" (LVLH angular velocity, relative motion under J2),
ISBN 978-0-7506-8533-7.
H. D. Curtis, *Orbital Mechanics for Engineering Students*, Butterworth-Heinemann, chapter
"Introduction to orbital perturbations" (J2 perturbing acceleration in ECI).
S. A. Schweighart and R. J. Sedwick, "High-fidelity linearized J2 model for satellite
formation flight", J. Guid. Control Dyn. 25(6), 1073–1080 (2002), doi:10.2514/2.4986.
E. Hairer, S. P. Nørsett and G. Wanner, *Solving Ordinary Differential Equations I*, 2nd ed.,
Springer (1993), doi:10.1007/978-3-540-78862-1 (DOP853).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from . import cw
from ._checks import finite_array, finite_scalar, mean_motion, one_of
from .constants import J2_EARTH, MU_EARTH_M3_S2, R_EARTH_M
from .reference import ReferenceOrbit

__all__ = ["relative_rhs", "propagate_nonlinear", "cw_error", "CWError", "METHODS"]

METHODS = ("rotating", "eci")
"""Formulations accepted by :func:`propagate_nonlinear`."""

_ATOL_FRACTION = 1e-3
"""atol = _ATOL_FRACTION · rtol · (length scale of the state): atol only matters when a
component passes through zero, so the relative tolerance sets the accuracy."""

_MIN_LENGTH_M = 1e-6
"""Floor of the length scale used for atol [m] (an observer exactly at the target)."""


# ----------------------------------------------------------------------------- dynamics
def relative_rhs(t: float, s, n: float, r0_m: float) -> np.ndarray:
    """Exact two-body relative dynamics in the rotating LVLH frame of a circular orbit.

    Parameters
    ----------
    t : float
        Time [s] (unused: the dynamics are autonomous; present for ``solve_ivp``).
    s : ndarray, shape (6,) or (6, K), float64
        Relative state(s) ``[x, y, z, ẋ, ẏ, ż]`` [m, m/s].
    n : float
        Mean motion of the target orbit [rad/s].
    r0_m : float
        Radius of the target orbit, r₀ = a [m]; n² r₀³ = μ for a Keplerian orbit.

    Returns
    -------
    ds : ndarray, shape like ``s``, float64
        ``[ẋ, ẏ, ż, ẍ, ÿ, z̈]`` [m/s, m/s²].

    Notes
    -----
    Exact two-body relative dynamics, written so that f avoids cancellation::

        ẍ = 2n ẏ − n² f (r₀ + x),   ÿ = −2n ẋ − n² f y,   z̈ = −n² (1 + f) z
        f = (r₀/r_O)³ − 1 = expm1(−1.5 · log1p(q)),   q = (2 r₀ x + |ρ|²)/r₀²

    The form avoids the cancellation of μ/r_O³ − μ/r₀³; linearising f ≈ −3x/r₀ gives CW.
    Inputs are not validated: this is the integrator's hot path.
    """
    x, y, z, vx, vy, vz = s
    q = (2.0 * r0_m * x + (x * x + y * y + z * z)) / (r0_m * r0_m)
    f = np.expm1(-1.5 * np.log1p(q))
    n2 = n * n
    return np.array([
        vx,
        vy,
        vz,
        2.0 * n * vy - n2 * f * (r0_m + x),
        -2.0 * n * vx - n2 * f * y,
        -n2 * (1.0 + f) * z,
    ])


def _j2_accel(r_eci: np.ndarray) -> np.ndarray:
    """J2 perturbing acceleration in ECI (z = Earth's pole) [m/s²].

    a = −(3/2) J2 μ R_E² / r⁵ · [x (1 − 5z²/r²), y (1 − 5z²/r²), z (3 − 5z²/r²)]
    (Curtis, "Introduction to orbital perturbations"; Vallado, *Fundamentals of Astrodynamics
    and Applications*, zonal harmonics).
    """
    x, y, z = r_eci
    r2 = x * x + y * y + z * z
    r = math.sqrt(r2)
    k = -1.5 * J2_EARTH * MU_EARTH_M3_S2 * R_EARTH_M * R_EARTH_M / (r2 * r2 * r)
    w = 5.0 * z * z / r2
    return np.array([k * x * (1.0 - w), k * y * (1.0 - w), k * z * (3.0 - w)])


def _j2_accel_diff(r_t: np.ndarray, d: np.ndarray) -> np.ndarray:
    """a_J2(r_T + δ) − a_J2(r_T) without forming r_T + δ [m/s²].

    With p = 1/r⁵, w = 5z²/r², c = [1, 1, 3] and k = −(3/2) J2 μ R_E²::

        Δa = k [δ p_O (c − w_O) + r_T (Δp (c − w_O) − p_T Δw)]
        Δp = p_T expm1(−2.5 log1p(q)),   Δw = 5 (2 z_T δz + δz² − z_T² q) / r_O²

    Subtracting two ~1e-2 m/s² accelerations would leave ~1e-18 m/s² of rounding noise
    (and r_T + δ loses ~1e-9 m), which the step-size control would chase for small δ.
    """
    rt2 = float(r_t @ r_t)
    q = (2.0 * float(r_t @ d) + float(d @ d)) / rt2
    l1p = math.log1p(q)
    p_t = 1.0 / (rt2 * rt2 * math.sqrt(rt2))
    dp = p_t * math.expm1(-2.5 * l1p)
    p_o = p_t + dp
    ro2 = rt2 * (1.0 + q)
    z_t, dz = float(r_t[2]), float(d[2])
    w_o = 5.0 * (z_t + dz) ** 2 / ro2
    dw = 5.0 * ((2.0 * z_t + dz) * dz - z_t * z_t * q) / ro2
    c_minus_w = np.array([1.0 - w_o, 1.0 - w_o, 3.0 - w_o])
    k = -1.5 * J2_EARTH * MU_EARTH_M3_S2 * R_EARTH_M * R_EARTH_M
    return k * (d * (p_o * c_minus_w) + r_t * (dp * c_minus_w - p_t * dw))


def _eci_rhs(t: float, y: np.ndarray, j2: bool) -> np.ndarray:
    """ṡ for [r_T, v_T, δ, δv] (ECI, 12 states) with two-body gravity (+ J2)."""
    r_t = y[0:3]
    d = y[6:9]
    rt2 = float(r_t @ r_t)
    rt = math.sqrt(rt2)
    inv_rt3 = 1.0 / (rt2 * rt)
    q = (2.0 * float(r_t @ d) + float(d @ d)) / rt2
    l1p = math.log1p(q)
    one_minus_ratio3 = -math.expm1(1.5 * l1p)      # 1 − (|r_O|/|r_T|)³
    inv_ro3 = inv_rt3 * math.exp(-1.5 * l1p)        # 1/|r_O|³
    a_t = -MU_EARTH_M3_S2 * inv_rt3 * r_t
    da = -MU_EARTH_M3_S2 * inv_ro3 * (d + r_t * one_minus_ratio3)
    if j2:
        a_t = a_t + _j2_accel(r_t)
        da = da + _j2_accel_diff(r_t, d)
    out = np.empty(12)
    out[0:3] = y[3:6]
    out[3:6] = a_t
    out[6:9] = y[9:12]
    out[9:12] = da
    return out


def _lvlh_frame(r_t: np.ndarray, v_t: np.ndarray, j2: bool) -> tuple[np.ndarray, np.ndarray]:
    """Actual LVLH frame of an ECI target state: R_eci_from_lvlh (3, 3) and ω_lvlh (3,) [rad/s]."""
    rn = math.sqrt(float(r_t @ r_t))
    h = np.cross(r_t, v_t)
    hn = math.sqrt(float(h @ h))
    x_hat = r_t / rn
    z_hat = h / hn
    y_hat = np.cross(z_hat, x_hat)
    R = np.column_stack([x_hat, y_hat, z_hat])
    a_h = float(_j2_accel(r_t) @ z_hat) if j2 else 0.0
    omega = np.array([rn * a_h / hn, 0.0, hn / (rn * rn)])
    return R, omega


# ----------------------------------------------------------------------------- integration
def _integrate(fun, y0: np.ndarray, t: np.ndarray, rtol: float, atol: np.ndarray) -> np.ndarray:
    """Integrate from 0 to every time in ``t`` (any order, any sign); rows follow ``t``."""
    out = np.empty((t.size, y0.size))
    out[t == 0.0] = y0
    for sign in (1.0, -1.0):
        mask = sign * t > 0.0
        if not np.any(mask):
            continue
        tt = np.unique(t[mask])                       # ascending
        t_eval = tt if sign > 0 else tt[::-1]         # in the direction of integration
        sol = solve_ivp(fun, (0.0, float(t_eval[-1])), y0, method="DOP853", t_eval=t_eval,
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"DOP853 integration failed: {sol.message}")
        ys = sol.y.T if sign > 0 else sol.y.T[::-1]   # rows in ascending time
        out[mask] = ys[np.searchsorted(tt, t[mask])]
    return out


def propagate_nonlinear(s0_lvlh, orbit: ReferenceOrbit, t_s, *, j2: bool = False,
                        rtol: float = 1e-12, method: str | None = None) -> np.ndarray:
    """Propagate a relative state with nonlinear dynamics (numerical reference for CW).

    Parameters
    ----------
    s0_lvlh : array_like, shape (6,)
        Relative state ``[x, y, z, ẋ, ẏ, ż]`` at t = 0 in the target's LVLH frame [m, m/s].
    orbit : ReferenceOrbit
        Target orbit; circular at t = 0 (its altitude, inclination, RAAN and u₀ matter only
        for ``method="eci"``).
    t_s : float or array_like, shape (N,)
        Times since t = 0 [s], any order and sign (integrated forward and backward from 0).
    j2 : bool
        Add the J2 perturbation to both spacecraft (needs ``method="eci"``).
    rtol : float
        Relative tolerance of DOP853, 2.2e-14 ≤ rtol < 1 [-]. The absolute tolerance is
        ``1e-3 · rtol`` times the size of the state (|ρ₀|, |ρ̇₀|/n; a for the target), so
        ``rtol`` governs the accuracy.
    method : {"rotating", "eci"}, optional
        Formulation (see the module docstring). Default: ``"eci"`` if ``j2`` else
        ``"rotating"``.

    Returns
    -------
    s_lvlh : ndarray, shape (N, 6), float64
        Relative states at ``t_s`` in input order [m, m/s]; a scalar ``t_s`` gives (1, 6).
        With ``method="eci"`` they are expressed in the target's actual (osculating) LVLH
        frame, which with J2 drifts away from the circular frame of ``orbit``.

    Raises
    ------
    ValueError
        On a non-finite or mis-shaped input, an unknown ``method``, or ``j2=True`` with
        ``method="rotating"``.
    RuntimeError
        If the integrator fails.

    Notes
    -----
    With ``method="eci"`` the observer's initial ECI offset is δ₀ = R ρ₀,
    δv₀ = R (ρ̇₀ + ω₀ × ρ₀) — the same as ``orbit.observer_state_eci(s0, 0) − target`` but
    without subtracting two 7e6 m numbers — where ω₀ is the actual frame rate at t = 0
    (= [0, 0, n] without J2), so that ``t_s = 0`` returns ``s0_lvlh`` exactly.

    Accuracy after one orbit at ``rtol = 1e-12`` (measured against ``rtol = 3e-14``): about
    1e-12·|ρ| for ``"rotating"`` and 1.5e-11·|ρ| for ``"eci"`` (the inertial components of δ
    are harder for the step-size control); both scale with ``rtol``. The formulations thus
    agree to < 1e-7 m up to |ρ| ≈ 5 km at the default and up to 10 km at ``rtol = 1e-13``.
    """
    s0 = finite_array("s0_lvlh", s0_lvlh)
    if s0.shape != (6,):
        raise ValueError(f"s0_lvlh must have shape (6,), got {s0.shape}")
    if not isinstance(orbit, ReferenceOrbit):
        raise ValueError(f"orbit must be a ReferenceOrbit, got {type(orbit).__name__}")
    t = np.atleast_1d(finite_array("t_s", t_s, ndim=(0, 1)))
    if not isinstance(j2, (bool, np.bool_)):
        raise ValueError(f"j2 must be True or False, got {j2!r}")
    j2 = bool(j2)
    rtol = finite_scalar("rtol", rtol, positive=True)
    if not 100.0 * np.finfo(float).eps <= rtol < 1.0:
        raise ValueError(f"rtol must lie in [{100 * np.finfo(float).eps:.2e}, 1), got {rtol!r}")
    if method is None:
        method = "eci" if j2 else "rotating"
    one_of("method", method, METHODS)
    if j2 and method == "rotating":
        raise ValueError(
            "method='rotating' integrates Keplerian motion about a circular orbit and cannot "
            "include J2; with j2=True use method='eci' (or leave method unset)"
        )

    n, a = orbit.n_rad_s, orbit.a_m
    length = max(float(np.linalg.norm(s0[:3])), float(np.linalg.norm(s0[3:])) / n, _MIN_LENGTH_M)
    atol_rel = _ATOL_FRACTION * rtol * np.array([length] * 3 + [n * length] * 3)

    if method == "rotating":
        return _integrate(lambda _t, s: relative_rhs(_t, s, n, a), s0, t, rtol, atol_rel)

    r_t0, v_t0 = orbit.target_state_eci(0.0)
    R0, omega0 = _lvlh_frame(r_t0, v_t0, j2)
    d0 = R0 @ s0[:3]
    dv0 = R0 @ (s0[3:] + np.cross(omega0, s0[:3]))
    y0 = np.concatenate([r_t0, v_t0, d0, dv0])
    atol_tgt = _ATOL_FRACTION * rtol * np.array([a] * 3 + [n * a] * 3)
    ys = _integrate(lambda _t, y: _eci_rhs(_t, y, j2), y0, t, rtol,
                    np.concatenate([atol_tgt, atol_rel]))
    out = np.empty((t.size, 6))
    for k, y in enumerate(ys):
        R, omega = _lvlh_frame(y[0:3], y[3:6], j2)
        rho = R.T @ y[6:9]
        out[k, :3] = rho
        out[k, 3:] = R.T @ y[9:12] - np.cross(omega, rho)
    out[t == 0.0] = s0
    return out


# ----------------------------------------------------------------------------- CW error
@dataclass(frozen=True, slots=True, eq=False)
class CWError:
    """Clohessy–Wiltshire closed form against the nonlinear reference (docs/accuracy.md,
    "CW error after one orbit").

    Attributes
    ----------
    t_s : ndarray, shape (N,), float64
        Times since the initial state [s].
    s_cw : ndarray, shape (N, 6), float64
        CW states (:func:`orbit.cw.propagate` with n = ``orbit.n_rad_s``) [m, m/s].
    s_ref : ndarray, shape (N, 6), float64
        Nonlinear reference states (:func:`propagate_nonlinear`) [m, m/s].
    position_error_m : ndarray, shape (N,), float64
        |r_ref − r_CW| [m].
    max_position_error_m : float
        Largest entry of ``position_error_m`` [m].
    along_track_error_m : ndarray, shape (N,), float64
        y_ref − y_CW (signed) [m].
    """

    t_s: np.ndarray
    s_cw: np.ndarray
    s_ref: np.ndarray
    position_error_m: np.ndarray
    max_position_error_m: float
    along_track_error_m: np.ndarray


def cw_error(s0_lvlh, orbit: ReferenceOrbit, t_s, *, j2: bool = False) -> CWError:
    """Error of the closed-form CW solution against nonlinear propagation.

    Parameters
    ----------
    s0_lvlh : array_like, shape (6,)
        Initial relative state in LVLH [m, m/s].
    orbit : ReferenceOrbit
        Target orbit (its mean motion is used for CW).
    t_s : float or array_like, shape (N,)
        Times since t = 0 [s], any order and sign.
    j2 : bool
        Include J2 in the reference (then ``method="eci"``).

    Returns
    -------
    CWError
        Both solutions and their position and along-track differences [m].
    """
    if not isinstance(orbit, ReferenceOrbit):
        raise ValueError(f"orbit must be a ReferenceOrbit, got {type(orbit).__name__}")
    t = np.atleast_1d(finite_array("t_s", t_s, ndim=(0, 1)))
    s_ref = propagate_nonlinear(s0_lvlh, orbit, t, j2=j2)
    s_cw = cw.propagate(s0_lvlh, mean_motion("orbit.n_rad_s", orbit.n_rad_s), t)
    err = np.linalg.norm(s_ref[:, :3] - s_cw[:, :3], axis=1)
    return CWError(t_s=t, s_cw=s_cw, s_ref=s_ref, position_error_m=err,
                   max_position_error_m=float(err.max()),
                   along_track_error_m=s_ref[:, 1] - s_cw[:, 1])
