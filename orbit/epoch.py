"""UTC epochs: parsing, Unix seconds and Julian dates.

Inside :mod:`orbit` an instant is a float of **Unix seconds** (UTC, POSIX: leap seconds not
counted). Users give ISO 8601 strings (``"2026-03-20T12:00:00Z"``), timezone-aware
``datetime`` objects, or numbers of Unix seconds; naive datetimes and strings without an
offset are taken as UTC.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

from ._checks import finite_array

__all__ = ["DEFAULT_EPOCH_UTC", "JD_UNIX_EPOCH", "gmst_rad", "julian_date", "to_iso_utc", "to_unix_seconds"]

DEFAULT_EPOCH_UTC = "2026-03-20T12:00:00Z"
"""Default epoch (the March 2026 equinox day; the Sun test vector of tests/orbit/test_sun.py is
at this instant)."""

JD_UNIX_EPOCH = 2440587.5
"""Julian date of 1970-01-01T00:00:00 UTC [d]."""

_MIN_YEAR, _MAX_YEAR = 1900, 2200


def to_unix_seconds(utc, *, name: str = "epoch") -> float:
    """Convert one UTC instant to Unix seconds.

    Parameters
    ----------
    utc : str, datetime.datetime or float
        ISO 8601 string (``Z`` or an offset; none means UTC), a datetime (naive = UTC),
        or Unix seconds.
    name : str
        Parameter name for error messages.

    Returns
    -------
    float
        Seconds since 1970-01-01T00:00:00 UTC [s].
    """
    if isinstance(utc, str):
        text = utc.strip()
        if text.endswith(("Z", "z")):
            text = text[:-1] + "+00:00"
        try:
            when = _dt.datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(
                f"{name} must be an ISO 8601 UTC time such as 2026-03-20T12:00:00Z, got {utc!r}"
            ) from None
        return to_unix_seconds(when, name=name)
    if isinstance(utc, _dt.datetime):
        if utc.tzinfo is None:
            utc = utc.replace(tzinfo=_dt.timezone.utc)
        if not _MIN_YEAR <= utc.year <= _MAX_YEAR:
            raise ValueError(f"{name} must lie in the years {_MIN_YEAR}–{_MAX_YEAR}, got {utc.isoformat()}")
        return utc.timestamp()
    if isinstance(utc, _dt.date):
        raise ValueError(f"{name} must be a date and time, got the date {utc.isoformat()}")
    arr = finite_array(name, utc, ndim=(0,))
    value = float(arr)
    year = 1970 + value / (365.25 * 86400.0)
    if not _MIN_YEAR <= year <= _MAX_YEAR:
        raise ValueError(f"{name} must lie in the years {_MIN_YEAR}–{_MAX_YEAR}, got {value!r} Unix seconds")
    return value


def to_iso_utc(unix_s: float) -> str:
    """Format Unix seconds as an ISO 8601 UTC string with microseconds and a ``Z`` suffix."""
    if not math.isfinite(unix_s):
        raise ValueError(f"unix_s must be finite, got {unix_s!r}")
    whole = math.floor(unix_s)
    micro = int(round((unix_s - whole) * 1e6))
    if micro == 1_000_000:
        whole, micro = whole + 1, 0
    when = _dt.datetime.fromtimestamp(whole, tz=_dt.timezone.utc).replace(microsecond=micro)
    return when.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def julian_date(unix_s) -> np.ndarray | float:
    """Julian date of Unix seconds: JD = 2440587.5 + unix_s / 86400 [d].

    Parameters
    ----------
    unix_s : float or array_like
        UTC instants [s].

    Returns
    -------
    float or ndarray
        Julian dates (UTC scale) [d], same shape as the input.
    """
    arr = finite_array("unix_s", unix_s)
    jd = JD_UNIX_EPOCH + arr / 86400.0
    return float(jd) if jd.ndim == 0 else jd


def gmst_rad(unix_s) -> np.ndarray:
    """Greenwich mean sidereal time (IAU 1982; Vallado, *Fundamentals of Astrodynamics and
    Applications*, 4th ed., eq. 3-47), taking UT1 ≈ UTC (|UT1 − UTC| < 0.9 s, i.e. < 4 arcsec
    of Earth rotation). It orients the Earth-fixed axes of Earth's texture only.

    Parameters
    ----------
    unix_s : float or array_like
        UTC instants, Unix seconds [s].

    Returns
    -------
    ndarray, float64
        GMST in [0, 2π) [rad].
    """
    u = finite_array("unix_s", unix_s)
    T = (u / 86400.0 + JD_UNIX_EPOCH - 2451545.0) / 36525.0
    sec = 67310.54841 + (876600.0 * 3600.0 + 8640184.812866) * T + 0.093104 * T**2 - 6.2e-6 * T**3
    return np.mod(sec, 86400.0) * (2.0 * math.pi / 86400.0)
