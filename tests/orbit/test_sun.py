"""Tests of orbit.sun: a worked example and an independent ephemeris (ERFA via astropy)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from orbit.constants import AU_M
from orbit.epoch import to_unix_seconds
from orbit.sun import VALID_UTC_RANGE_S, sun_direction_eci, sun_position_eci

EXAMPLE_UTC = "2026-03-20T12:00:00Z"


def _angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(u * v, axis=-1)))


# --- worked example: the almanac's formulae at JD 2461120.0 ------------------------------

def test_spec_example_of_date():
    t = to_unix_seconds(EXAMPLE_UTC)
    np.testing.assert_allclose(sun_direction_eci(t, frame="date"),
                               [0.99999818, -0.00174934, -0.00075828], atol=1e-7)


def test_spec_example_j2000():
    t = to_unix_seconds(EXAMPLE_UTC)
    np.testing.assert_allclose(sun_direction_eci(t), [0.99996557, -0.00761343, -0.00330083], atol=1e-7)
    np.testing.assert_allclose(sun_direction_eci(t, frame="j2000"), sun_direction_eci(t), atol=0)


def test_spec_example_distance():
    t = to_unix_seconds(EXAMPLE_UTC)
    for frame in ("j2000", "date"):
        assert abs(np.linalg.norm(sun_position_eci(t, frame=frame)) / AU_M - 0.99583724) < 1e-7


def test_shapes_and_unit_norm():
    t = to_unix_seconds(EXAMPLE_UTC) + np.array([0.0, 86400.0, 1e7])
    assert sun_position_eci(t[0]).shape == (3,)
    assert sun_position_eci(t).shape == (3, 3)
    assert sun_direction_eci(t[:1]).shape == (1, 3)
    assert sun_position_eci(t).dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(sun_direction_eci(t, frame="date"), axis=-1), 1.0, atol=1e-15)
    # vectorised result equals the scalar calls
    for k, tk in enumerate(t):
        np.testing.assert_array_equal(sun_position_eci(t)[k], sun_position_eci(tk))


def test_frames_differ_by_precession():
    # mixing the frames costs up to 0.7 deg by 2050 (precession 1.397 deg/century).
    t = to_unix_seconds("2050-06-01T00:00:00Z")
    sep = _angle_deg(sun_direction_eci(t, frame="date"), sun_direction_eci(t, frame="j2000"))
    assert 0.6 < sep < 0.75


# --- independent ephemeris ---------------------------------------------------------------

@pytest.fixture(scope="module")
def ephemeris():
    """Sun from astropy's get_sun: ERFA epv00 analytic ephemeris (VSOP87-fitted), apparent
    (light time + aberration) in GCRS; no network: IERS auto-download and internet are off,
    and UTC→TT uses the bundled leap-second table."""
    astropy = pytest.importorskip("astropy")
    del astropy
    from astropy.utils import iers
    from astropy.utils.data import conf as data_conf

    with iers.conf.set_temp("auto_download", False), data_conf.set_temp("allow_internet", False), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ERFA "dubious year" for UTC beyond the leap-second table
        import astropy.units as u
        from astropy.coordinates import PrecessedGeocentric, get_sun
        from astropy.time import Time

        rng = np.random.default_rng(20260320)
        lo, hi = VALID_UTC_RANGE_S
        t = np.concatenate([[lo, hi, to_unix_seconds(EXAMPLE_UTC)], rng.uniform(lo, hi, 200)])
        when = Time(t, format="unix", scale="utc")
        sun = get_sun(when)
        gcrs_m = sun.cartesian.xyz.to_value(u.m).T
        of_date = sun.transform_to(PrecessedGeocentric(equinox=when, obstime=when))
        of_date_m = of_date.cartesian.xyz.to_value(u.m).T
    return t, gcrs_m, of_date_m


def test_j2000_direction_vs_gcrs(ephemeris):
    # Measured max over 1950–2051 on a dense 16 s grid: 0.01101 deg (in 2049); this seeded
    # sample reaches 0.00826 deg; a sparse sample alone would suggest ≤ 0.0083 deg.
    t, gcrs_m, _ = ephemeris
    err_deg = _angle_deg(sun_position_eci(t), gcrs_m)
    assert err_deg.max() < 0.0112
    assert err_deg.mean() < 0.0045        # dense-grid mean 0.0036 deg: no systematic offset


def test_date_direction_vs_mean_of_date(ephemeris):
    # GCRS rotated to the mean equator and equinox of date (IAU 2006 precession, no nutation).
    # Dense-grid max 0.01023 deg (a smaller sample gives ≤ 0.0072 deg).
    t, _, of_date_m = ephemeris
    err_deg = _angle_deg(sun_position_eci(t, frame="date"), of_date_m)
    assert err_deg.max() < 0.0105


def test_distance_vs_ephemeris(ephemeris):
    # Dense-grid max 8.77e-5 AU (the formula ignores the lunar wobble of the geocentre, 3e-5 AU).
    t, gcrs_m, _ = ephemeris
    err_au = np.abs(np.linalg.norm(sun_position_eci(t), axis=-1) - np.linalg.norm(gcrs_m, axis=-1)) / AU_M
    assert err_au.max() < 9e-5


# --- bad input -----------------------------------------------------------------------------

@pytest.mark.parametrize("func", [sun_position_eci, sun_direction_eci])
@pytest.mark.parametrize("bad", [np.nan, np.inf, [1.7e9, np.nan]])
def test_non_finite_time(func, bad):
    with pytest.raises(ValueError, match="utc"):
        func(bad)


@pytest.mark.parametrize("func", [sun_position_eci, sun_direction_eci])
@pytest.mark.parametrize("when", ["1949-12-31T23:59:59Z", "2051-01-01T00:00:01Z"])
def test_outside_validity(func, when):
    t = to_unix_seconds(when)
    with pytest.raises(ValueError, match="utc.*1950"):
        func(t)
    with pytest.raises(ValueError, match="utc.*1950"):
        func([to_unix_seconds(EXAMPLE_UTC), t])


def test_validity_edges_accepted():
    lo, hi = VALID_UTC_RANGE_S
    assert lo == to_unix_seconds("1950-01-01T00:00:00Z")
    assert hi == to_unix_seconds("2051-01-01T00:00:00Z")
    assert sun_position_eci([lo, hi]).shape == (2, 3)


def test_unknown_frame():
    with pytest.raises(ValueError, match="frame.*j2000.*date.*'gcrs'"):
        sun_position_eci(to_unix_seconds(EXAMPLE_UTC), frame="gcrs")
    with pytest.raises(ValueError, match="frame"):
        sun_direction_eci(to_unix_seconds(EXAMPLE_UTC), frame="J2000")


def test_wrong_shape():
    with pytest.raises(ValueError, match="utc"):
        sun_position_eci(np.full((2, 2), 1.7e9))
    with pytest.raises(ValueError, match="utc"):
        sun_position_eci("2026-03-20")
