"""Circular reference (target) orbit in ECI and the ECI ↔ LVLH transformation.

The target flies a circular orbit of radius a = R_E + altitude with inclination i, right
ascension of the ascending node Ω and argument of latitude u(t) = u₀ + n t, n = sqrt(μ/a³).
Its LVLH frame (docs/conventions.md: x̂ radial out, ŷ along-track, ẑ orbit normal) seen
from ECI is

    R_eci_from_lvlh(t) = R₃(Ω) R₁(i) R₃(u(t))          (active elementary rotations)

and an observer with relative state s = [ρ, ρ̇] (LVLH, derivative taken in the rotating
frame) sits at

    r_O = r_T + R ρ,      v_O = v_T + R (ρ̇ + ω × ρ),      ω = [0, 0, n] (LVLH)

with r_T = a x̂, v_T = n a ŷ. The inverse is ρ = Rᵀ(r_O − r_T), ρ̇ = Rᵀ(v_O − v_T) − ω × ρ.

Precision: ECI positions are ~7e6 m, so their float64 spacing is ~1e-9 m. Everything here is
float64 and float32 is never used; the renderer receives
LVLH/body-frame quantities only.

References
----------
D. A. Vallado, *Fundamentals of Astrodynamics and Applications*, 4th ed., Microcosm Press
(2013): orbital elements and the perifocal/ECI rotation R₃(−Ω) R₁(−i) R₃(−u) written here
with active rotations.
K. T. Alfriend, S. R. Vadali, P. Gurfil, J. P. How and L. S. Breger, *Spacecraft Formation
Flying: Dynamics, Control and Navigation*, Butterworth-Heinemann (2010), ch. 4 (LVLH frame,
transport theorem), ISBN 978-0-7506-8533-7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._checks import finite_array, finite_scalar
from .constants import MIN_ALTITUDE_M, MU_EARTH_M3_S2, R_EARTH_M
from .epoch import DEFAULT_EPOCH_UTC, to_iso_utc, to_unix_seconds

__all__ = ["ReferenceOrbit", "MAX_ALTITUDE_M"]

MAX_ALTITUDE_M = 1e9
"""Largest accepted altitude [m] (well beyond the Moon; guards against unit mistakes)."""


def _times(t_s) -> tuple[np.ndarray, bool]:
    """Validate ``t_s`` (scalar or 1-D) and return it as a 1-D float64 array and a scalar flag."""
    t = finite_array("t_s", t_s, ndim=(0, 1))
    return np.atleast_1d(t), t.ndim == 0


def _rows(name: str, value, width: int) -> tuple[np.ndarray, bool]:
    """Validate a (width,) or (N, width) array; return it as (N, width) and a single-row flag."""
    arr = finite_array(name, value, ndim=(1, 2), shape_tail=(width,))
    return np.atleast_2d(arr), arr.ndim == 1


def _broadcast(name: str, rows: np.ndarray, t: np.ndarray) -> int:
    """Common length of per-row inputs and times (a length of 1 broadcasts)."""
    n_rows, n_t = rows.shape[0], t.size
    if n_rows != n_t and n_rows != 1 and n_t != 1:
        raise ValueError(
            f"{name} with {n_rows} rows does not match t_s with {n_t} times; "
            "give one row, one time, or the same number of each"
        )
    return max(n_rows, n_t)


def _omega_cross(n: float, rho: np.ndarray) -> np.ndarray:
    """ω × ρ for ω = [0, 0, n] (LVLH), rows of ``rho`` shape (N, 3) [m/s]."""
    out = np.empty_like(rho)
    out[:, 0] = -n * rho[:, 1]
    out[:, 1] = n * rho[:, 0]
    out[:, 2] = 0.0
    return out


@dataclass(frozen=True, slots=True)
class ReferenceOrbit:
    """Circular orbit of the target spacecraft (docs/orbit.md, "The reference orbit and where on it
    a sequence is flown").

    Parameters
    ----------
    altitude_m : float
        Height above the equatorial radius R_E = 6 378 137 m; 100 km ≤ altitude ≤ 1e9 m [m].
    inclination_rad : float
        Inclination i ∈ [0, π] [rad]. Default 51.6 deg (ISS-like).
    raan_rad : float
        Right ascension of the ascending node Ω, any finite value [rad].
    arg_lat_rad : float
        Argument of latitude u₀ of the target at the epoch (t = 0), any finite value [rad].
    epoch_utc : str
        UTC instant of t = 0, ISO 8601 (``"2026-03-20T12:00:00Z"``). A ``datetime`` or Unix
        seconds are accepted too and stored as an ISO string.

    Raises
    ------
    ValueError
        If a value is not finite or out of range; the message names the field.

    Notes
    -----
    ``R_eci_from_lvlh`` = R₃(Ω) R₁(i) R₃(u) has columns::

        x̂ = [cΩ cu − sΩ su ci,   sΩ cu + cΩ su ci,   su si]
        ŷ = [−cΩ su − sΩ cu ci,  −sΩ su + cΩ cu ci,  cu si]
        ẑ = [sΩ si,              −cΩ si,             ci   ]

    with c = cos, s = sin and u = u₀ + n t. The LVLH frame of a circular orbit rotates at
    ω = n ẑ with respect to ECI.
    """

    altitude_m: float = 400e3
    inclination_rad: float = math.radians(51.6)
    raan_rad: float = 0.0
    arg_lat_rad: float = 0.0
    epoch_utc: str = DEFAULT_EPOCH_UTC

    def __post_init__(self) -> None:
        alt = finite_scalar("altitude_m", self.altitude_m)
        if alt < 0.0:
            raise ValueError(
                f"altitude_m is the height above the Earth's equatorial radius and must be "
                f">= {MIN_ALTITUDE_M:.0f} m (100 km); got a negative altitude {alt!r} m, which is "
                "below the Earth's surface (did you pass a depth or a radius difference?)"
            )
        if alt < MIN_ALTITUDE_M:
            raise ValueError(
                f"altitude_m must be >= {MIN_ALTITUDE_M:.0f} m (100 km): below that the orbit is "
                f"inside the atmosphere and cannot be circular; got {alt!r} m"
            )
        if alt > MAX_ALTITUDE_M:
            raise ValueError(
                f"altitude_m must be <= {MAX_ALTITUDE_M:.0e} m (metres, not km?); got {alt!r} m"
            )
        inc = finite_scalar("inclination_rad", self.inclination_rad)
        if not 0.0 <= inc <= math.pi:
            raise ValueError(
                f"inclination_rad must lie in [0, pi] rad (0–180 deg; radians, not degrees?); "
                f"got {inc!r}"
            )
        raan = finite_scalar("raan_rad", self.raan_rad)
        u0 = finite_scalar("arg_lat_rad", self.arg_lat_rad)
        epoch = self.epoch_utc
        unix = to_unix_seconds(epoch, name="epoch_utc")
        if not isinstance(epoch, str):
            epoch = to_iso_utc(unix)
        for name, value in (("altitude_m", alt), ("inclination_rad", inc), ("raan_rad", raan),
                            ("arg_lat_rad", u0), ("epoch_utc", epoch)):
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ derived scalars
    @property
    def a_m(self) -> float:
        """Orbit radius a = R_E + altitude [m]."""
        return R_EARTH_M + self.altitude_m

    @property
    def n_rad_s(self) -> float:
        """Mean motion n = sqrt(μ/a³) [rad/s]."""
        a = self.a_m
        return math.sqrt(MU_EARTH_M3_S2 / (a * a * a))

    @property
    def period_s(self) -> float:
        """Orbital period T = 2π/n [s]."""
        return 2.0 * math.pi / self.n_rad_s

    @property
    def epoch_unix_s(self) -> float:
        """The epoch (t = 0) as Unix seconds, UTC [s]."""
        return to_unix_seconds(self.epoch_utc, name="epoch_utc")

    # ------------------------------------------------------------------ time
    def unix_s(self, t_s) -> float | np.ndarray:
        """UTC instants of times since the epoch.

        Parameters
        ----------
        t_s : float or array_like, shape (N,)
            Times since the epoch [s].

        Returns
        -------
        float or ndarray, shape (N,), float64
            ``epoch_unix_s + t_s`` [s].
        """
        t, scalar = _times(t_s)
        out = self.epoch_unix_s + t
        return float(out[0]) if scalar else out

    # ------------------------------------------------------------------ frames
    def _rotation(self, t: np.ndarray) -> np.ndarray:
        """R_eci_from_lvlh for a 1-D time array, shape (N, 3, 3)."""
        u = self.arg_lat_rad + self.n_rad_s * t
        cu, su = np.cos(u), np.sin(u)
        cO, sO = math.cos(self.raan_rad), math.sin(self.raan_rad)
        ci, si = math.cos(self.inclination_rad), math.sin(self.inclination_rad)
        R = np.empty((t.size, 3, 3))
        R[:, 0, 0] = cO * cu - sO * su * ci
        R[:, 1, 0] = sO * cu + cO * su * ci
        R[:, 2, 0] = su * si
        R[:, 0, 1] = -cO * su - sO * cu * ci
        R[:, 1, 1] = -sO * su + cO * cu * ci
        R[:, 2, 1] = cu * si
        R[:, 0, 2] = sO * si
        R[:, 1, 2] = -cO * si
        R[:, 2, 2] = ci
        return R

    def R_eci_from_lvlh(self, t_s) -> np.ndarray:
        """Rotation from the target's LVLH frame to ECI.

        Parameters
        ----------
        t_s : float or array_like, shape (N,)
            Times since the epoch [s].

        Returns
        -------
        R_eci_from_lvlh : ndarray, shape (3, 3) for scalar ``t_s``, else (N, 3, 3), float64
            ``v_eci = R_eci_from_lvlh @ v_lvlh``; columns are x̂, ŷ, ẑ of LVLH in ECI [-].
        """
        t, scalar = _times(t_s)
        R = self._rotation(t)
        return R[0] if scalar else R

    def target_state_eci(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity of the target in ECI.

        Parameters
        ----------
        t_s : float or array_like, shape (N,)
            Times since the epoch [s].

        Returns
        -------
        r_tgt_eci : ndarray, shape (3,) or (N, 3), float64
            r_T = a x̂ [m].
        v_tgt_eci : ndarray, shape (3,) or (N, 3), float64
            v_T = n a ŷ [m/s].
        """
        t, scalar = _times(t_s)
        R = self._rotation(t)
        a = self.a_m
        r = a * R[:, :, 0]
        v = (self.n_rad_s * a) * R[:, :, 1]
        return (r[0], v[0]) if scalar else (r, v)

    def observer_state_eci(self, s_lvlh, t_s) -> tuple[np.ndarray, np.ndarray]:
        """ECI state of an observer given its relative state in LVLH (r_O = r_T + R ρ).

        Parameters
        ----------
        s_lvlh : array_like, shape (6,) or (N, 6)
            Relative states ``[x, y, z, ẋ, ẏ, ż]`` (observer minus target, LVLH, derivative in
            the rotating frame) [m, m/s].
        t_s : float or array_like, shape (N,)
            Times since the epoch [s]. One state or one time broadcasts against the other.

        Returns
        -------
        r_obs_eci : ndarray, shape (3,) or (N, 3), float64
            r_O = r_T + R ρ [m]; shape (3,) only for one state at a scalar time.
        v_obs_eci : ndarray, shape (3,) or (N, 3), float64
            v_O = v_T + R (ρ̇ + ω × ρ), ω = [0, 0, n] [m/s].

        Raises
        ------
        ValueError
            If the shapes do not match or a value is not finite.
        """
        s, one_state = _rows("s_lvlh", s_lvlh, 6)
        t, scalar = _times(t_s)
        m = _broadcast("s_lvlh", s, t)
        s = np.broadcast_to(s, (m, 6))
        t = np.broadcast_to(t, (m,))
        R = self._rotation(t)
        a, n = self.a_m, self.n_rad_s
        rho, rho_dot = s[:, :3], s[:, 3:]
        dr = np.einsum("nij,nj->ni", R, rho)
        dv = np.einsum("nij,nj->ni", R, rho_dot + _omega_cross(n, rho))
        r = a * R[:, :, 0] + dr
        v = (n * a) * R[:, :, 1] + dv
        if one_state and scalar:
            return r[0], v[0]
        return r, v

    def relative_state_lvlh(self, r_obs_eci, v_obs_eci, t_s) -> np.ndarray:
        """Relative LVLH state of an observer given its ECI state (inverse of
        :meth:`observer_state_eci`).

        Parameters
        ----------
        r_obs_eci : array_like, shape (3,) or (N, 3)
            Observer position in ECI [m].
        v_obs_eci : array_like, shape (3,) or (N, 3)
            Observer velocity in ECI [m/s]; same shape as ``r_obs_eci``.
        t_s : float or array_like, shape (N,)
            Times since the epoch [s]. One position or one time broadcasts against the other.

        Returns
        -------
        s_lvlh : ndarray, shape (6,) or (N, 6), float64
            ρ = Rᵀ(r_O − r_T), ρ̇ = Rᵀ(v_O − v_T) − ω × ρ [m, m/s]; shape (6,) only for one
            position at a scalar time.

        Notes
        -----
        The differences r_O − r_T are taken between ~7e6 m numbers, so ρ carries an absolute
        error of about one float64 spacing of the ECI coordinates (≈ 1e-9 m in LEO).
        """
        r, one_r = _rows("r_obs_eci", r_obs_eci, 3)
        v, one_v = _rows("v_obs_eci", v_obs_eci, 3)
        if r.shape != v.shape:
            raise ValueError(
                f"v_obs_eci must have the same shape as r_obs_eci {r.shape}, got {v.shape}"
            )
        t, scalar = _times(t_s)
        m = _broadcast("r_obs_eci", r, t)
        r = np.broadcast_to(r, (m, 3))
        v = np.broadcast_to(v, (m, 3))
        t = np.broadcast_to(t, (m,))
        R = self._rotation(t)
        a, n = self.a_m, self.n_rad_s
        dr = r - a * R[:, :, 0]
        dv = v - (n * a) * R[:, :, 1]
        rho = np.einsum("nji,nj->ni", R, dr)
        rho_dot = np.einsum("nji,nj->ni", R, dv) - _omega_cross(n, rho)
        s = np.concatenate([rho, rho_dot], axis=1)
        return s[0] if (one_r and scalar) else s

