"""Greenwich mean sidereal time against published values (independent of our code)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from orbit.epoch import gmst_rad, to_unix_seconds


@pytest.mark.parametrize("utc,deg", [
    # Vallado, Fundamentals of Astrodynamics and Applications, Example 3-5:
    # 1992 August 20, 12:14 UT1 -> GMST 152.578 787 810 deg
    ("1992-08-20T12:14:00Z", 152.578787810),
    # the IAU 1982 constant itself: at J2000.0 (2000-01-01 12:00 UT1) GMST = 18h41m50.54841s
    ("2000-01-01T12:00:00Z", (18 + 41 / 60 + 50.54841 / 3600) * 15.0),
])
def test_gmst_matches_published_values(utc, deg):
    got = math.degrees(float(gmst_rad(to_unix_seconds(utc))))
    assert abs(got - deg) < 1e-6


def test_gmst_advances_one_sidereal_turn_per_sidereal_day_and_stays_in_range():
    t0 = to_unix_seconds("2026-03-20T12:00:00Z")
    sidereal_day_s = 86164.0905  # IERS: mean sidereal day in SI seconds
    a, b = gmst_rad(np.array([t0, t0 + sidereal_day_s]))
    assert abs(math.remainder(b - a, 2 * math.pi)) < 2e-6
    g = gmst_rad(t0 + np.linspace(0.0, 4 * 86400.0, 1001))
    assert g.min() >= 0.0 and g.max() < 2 * math.pi


def test_gmst_rejects_nan():
    with pytest.raises(ValueError, match="unix_s"):
        gmst_rad(float("nan"))
