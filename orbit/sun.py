"""Geocentric Sun position from the Astronomical Almanac's low-precision formulae.

The Sun is needed only as a direction for lighting and for the shadow and exclusion tests
of :mod:`orbit.visibility`, so the almanac's closed form (accurate to about 0.011 deg over
1950–2050) is used instead of a numerical ephemeris. Conventions: docs/conventions.md
(ECI = J2000 mean equator and equinox, metres) and docs/orbit.md, "The reference orbit and
where on it a sequence is flown".

Instants are Unix seconds (UTC), as everywhere in :mod:`orbit`; see :mod:`orbit.epoch`.
"""

from __future__ import annotations

import numpy as np

from ._checks import finite_array, one_of
from .constants import AU_M
from .epoch import julian_date

__all__ = ["FRAMES", "VALID_UTC_RANGE_S", "sun_position_eci", "sun_direction_eci"]

FRAMES = ("j2000", "date")
"""Allowed values of ``frame``: J2000 mean equator & equinox, or mean equator & equinox of date."""

VALID_UTC_RANGE_S = (-631152000.0, 2556144000.0)
"""Validity of the almanac formulae, [1950-01-01T00:00Z, 2051-01-01T00:00Z] in Unix seconds [s]."""

_JD_J2000 = 2451545.0
_DAYS_PER_CENTURY = 36525.0
_GENERAL_PRECESSION_DEG_PER_CENTURY = 1.396971
_OBLIQUITY_J2000_DEG = 23.4392911


def _check_utc(utc) -> np.ndarray:
    """Validate Unix seconds: finite, scalar or 1-D, inside the almanac's validity."""
    t = finite_array("utc", utc, ndim=(0, 1))
    lo, hi = VALID_UTC_RANGE_S
    outside = (t < lo) | (t > hi)
    if np.any(outside):
        bad = float(np.atleast_1d(t)[np.atleast_1d(outside)][0])
        raise ValueError(
            "utc must lie in 1950-01-01 .. 2051-01-01 UTC (Unix seconds "
            f"{lo:.0f} .. {hi:.0f}), the validity of the low-precision solar formulae; got {bad!r}"
        )
    return t


def _ecliptic_of_date(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apparent ecliptic longitude λ [deg], mean obliquity ε [deg] and distance R [AU]."""
    mean_longitude_deg = np.mod(280.460 + 0.9856474 * d, 360.0)
    mean_anomaly_rad = np.radians(np.mod(357.528 + 0.9856003 * d, 360.0))
    lam_deg = (mean_longitude_deg + 1.915 * np.sin(mean_anomaly_rad)
               + 0.020 * np.sin(2.0 * mean_anomaly_rad))
    eps_deg = 23.439 - 4.0e-7 * d
    dist_au = 1.00014 - 0.01671 * np.cos(mean_anomaly_rad) - 0.00014 * np.cos(2.0 * mean_anomaly_rad)
    return lam_deg, eps_deg, dist_au


def _sun_unit_and_distance(utc, frame: str) -> tuple[np.ndarray, np.ndarray]:
    """Unit vector (shape (..., 3)) and distance [m] (shape (...)) after validation."""
    frame = one_of("frame", frame, FRAMES)
    t = _check_utc(utc)
    d = np.asarray(julian_date(t), dtype=np.float64) - _JD_J2000
    lam_deg, eps_deg, dist_au = _ecliptic_of_date(d)
    if frame == "j2000":
        lam_deg = lam_deg - _GENERAL_PRECESSION_DEG_PER_CENTURY * d / _DAYS_PER_CENTURY
        eps_deg = np.full_like(d, _OBLIQUITY_J2000_DEG)
    lam, eps = np.radians(lam_deg), np.radians(eps_deg)
    unit = np.stack([np.cos(lam), np.cos(eps) * np.sin(lam), np.sin(eps) * np.sin(lam)], axis=-1)
    return unit, dist_au * AU_M


def sun_position_eci(utc, *, frame: str = "j2000") -> np.ndarray:
    """Geocentric position of the Sun from the almanac's low-precision formulae.

    Parameters
    ----------
    utc : float or array_like of float, shape () or (n,)
        Instants as Unix seconds (UTC), within 1950–2050 [s].
    frame : {"j2000", "date"}
        ``"j2000"``: mean equator and equinox of J2000, the ECI frame of docs/conventions.md (within
        0.011 deg of GCRS). ``"date"``: mean equator and equinox of date (the almanac's own
        frame). Mixing the two costs up to 0.7 deg by 2050.

    Returns
    -------
    ndarray of float64, shape (3,) or (n, 3)
        Sun position relative to the Earth's centre [m].

    Raises
    ------
    ValueError
        If ``utc`` is not finite, not scalar or 1-D, or outside 1950–2050, or if ``frame``
        is not one of the allowed values.

    Notes
    -----
    With d = JD(UTC) − 2451545.0 (Astronomical Almanac; using UTC for TT costs < 0.001 deg):

    * L = 280.460 + 0.9856474 d, g = 357.528 + 0.9856003 d (deg, mod 360),
    * λ = L + 1.915 sin g + 0.020 sin 2g (apparent ecliptic longitude, deg),
    * ε = 23.439 − 4.0e-7 d (deg), R = 1.00014 − 0.01671 cos g − 0.00014 cos 2g (AU),
    * ŝ = [cos λ, cos ε sin λ, sin ε sin λ] (ecliptic latitude taken as zero), r = R·AU·ŝ.

    For ``frame="j2000"`` the longitude is referred back to the J2000 equinox with the
    general precession in longitude, λ₂₀₀₀ = λ − 1.396971 deg · d/36525, and rotated with
    the J2000 obliquity ε₀ = 23.4392911 deg. Against an ephemeris (ERFA ``epv00`` through
    astropy's ``get_sun``) the J2000 direction is within 0.011 deg of GCRS over 1950–2050
    (mean 0.0036 deg, largest after 2020), the ``"date"`` direction within 0.0103 deg of
    the mean equator and equinox of date, and the distance within 9e-5 AU.

    References
    ----------
    .. [1] Astronomical Almanac, Section C, "Low-precision formulas for the Sun's
       coordinates" (U.S. Naval Observatory / HM Nautical Almanac Office).
    .. [2] J. Meeus, *Astronomical Algorithms*, 2nd ed., Willmann-Bell, 1998, ch. 25
       ("Solar coordinates") for the higher-accuracy theory and context.
    """
    unit, dist_m = _sun_unit_and_distance(utc, frame)
    return unit * dist_m[..., np.newaxis]


def sun_direction_eci(utc, *, frame: str = "j2000") -> np.ndarray:
    """Unit vector from the Earth's centre towards the Sun.

    Parameters
    ----------
    utc : float or array_like of float, shape () or (n,)
        Instants as Unix seconds (UTC), within 1950–2050 [s].
    frame : {"j2000", "date"}
        Axes of the result; see :func:`sun_position_eci`.

    Returns
    -------
    ndarray of float64, shape (3,) or (n, 3)
        Geocentric unit vector towards the Sun [-].

    Raises
    ------
    ValueError
        As :func:`sun_position_eci`.

    Notes
    -----
    Same formulae as :func:`sun_position_eci` without the distance; the direction seen
    from a spacecraft in LEO differs from the geocentric one by at most R_orbit/AU
    ≈ 2.6 arcsec, far below the almanac's accuracy.

    References
    ----------
    .. [1] Astronomical Almanac, Section C, "Low-precision formulas for the Sun's
       coordinates".
    """
    unit, _ = _sun_unit_and_distance(utc, frame)
    return unit
