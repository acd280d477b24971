"""Tests of orbit.reference: circular target orbit and ECI ↔ LVLH."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orbit import cw
from orbit.epoch import DEFAULT_EPOCH_UTC, to_unix_seconds
from orbit.reference import ReferenceOrbit

DEG = math.pi / 180.0

# LEO radii stay below 2**23 m ≈ 8.39e6 m, where the float64 spacing of an ECI coordinate is
# 2**-30 m ≈ 9.3e-10 m and of an ECI velocity (< 2**13 m/s) 2**-40 m/s ≈ 9.1e-13 m/s.
leo_altitudes = st.floats(100e3, 2000e3)
any_altitudes = st.floats(100e3, 1e9)
inclinations = st.floats(0.0, math.pi)
angles = st.floats(-10.0, 10.0)
times = st.floats(-2e5, 2e5)


def orbits(altitudes=leo_altitudes):
    return st.builds(ReferenceOrbit, altitude_m=altitudes, inclination_rad=inclinations,
                     raan_rad=angles, arg_lat_rad=angles)


def states(max_pos_m=1e4, max_vel_m_s=10.0):
    pos = st.floats(-max_pos_m, max_pos_m)
    vel = st.floats(-max_vel_m_s, max_vel_m_s)
    return st.tuples(pos, pos, pos, vel, vel, vel).map(np.array)


# --------------------------------------------------------------------------- default orbit
def test_default_orbit_matches_spec_section0():
    orbit = ReferenceOrbit()
    assert orbit.altitude_m == 400e3
    assert orbit.inclination_rad == pytest.approx(51.6 * DEG, rel=1e-15)
    assert orbit.a_m == 6778137.0
    assert orbit.n_rad_s == pytest.approx(1.1313666536110223e-3, rel=1e-15)
    assert orbit.period_s == pytest.approx(5553.624271252229, rel=1e-15)
    assert orbit.epoch_utc == DEFAULT_EPOCH_UTC


def test_epoch_and_unix_seconds():
    # 2026-03-20T12:00Z is JD 2461120.0 → (2461120.0 − 2440587.5)·86400 s.
    orbit = ReferenceOrbit()
    assert orbit.epoch_unix_s == (2461120.0 - 2440587.5) * 86400.0
    assert orbit.unix_s(60.0) == orbit.epoch_unix_s + 60.0
    np.testing.assert_array_equal(orbit.unix_s([0.0, -1.5]), orbit.epoch_unix_s + np.array([0.0, -1.5]))
    # a datetime or Unix seconds is stored as an ISO string
    other = ReferenceOrbit(epoch_utc=orbit.epoch_unix_s)
    assert isinstance(other.epoch_utc, str)
    assert to_unix_seconds(other.epoch_utc) == orbit.epoch_unix_s


# --------------------------------------------------------------------------- ECI ← LVLH rotation
def test_rotation_matches_spec_check_value():
    """R₃(Ω) R₁(i) R₃(u) evaluated at i = 51.6, Ω = 30, u = 10 deg → R_eci_from_lvlh to 1e-8."""
    expected = np.array([[0.79893794, -0.45623931, 0.39184673],
                         [0.58581440, 0.44293331, -0.67869844],
                         [0.13608694, 0.77178739, 0.62114778]])
    orbit = ReferenceOrbit(inclination_rad=51.6 * DEG, raan_rad=30.0 * DEG, arg_lat_rad=10.0 * DEG)
    np.testing.assert_allclose(orbit.R_eci_from_lvlh(0.0), expected, rtol=0, atol=1e-8)
    # the same u reached by propagation: u = u₀ + n t
    later = ReferenceOrbit(inclination_rad=51.6 * DEG, raan_rad=30.0 * DEG, arg_lat_rad=0.0)
    t = 10.0 * DEG / later.n_rad_s
    np.testing.assert_allclose(later.R_eci_from_lvlh(t), expected, rtol=0, atol=1e-8)


def test_rotation_is_product_of_elementary_rotations():
    def r1(x):
        c, s = math.cos(x), math.sin(x)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    def r3(x):
        c, s = math.cos(x), math.sin(x)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    orbit = ReferenceOrbit(inclination_rad=1.1, raan_rad=-2.3, arg_lat_rad=0.7)
    t = 1234.5
    u = 0.7 + orbit.n_rad_s * t
    np.testing.assert_allclose(orbit.R_eci_from_lvlh(t), r3(-2.3) @ r1(1.1) @ r3(u), atol=1e-15)


def test_vectorised_shapes_match_scalar_calls():
    orbit = ReferenceOrbit(raan_rad=0.4, arg_lat_rad=-1.0)
    t = np.array([-100.0, 0.0, 37.5, 5000.0])
    R = orbit.R_eci_from_lvlh(t)
    r, v = orbit.target_state_eci(t)
    assert R.shape == (4, 3, 3) and r.shape == (4, 3) and v.shape == (4, 3)
    assert orbit.R_eci_from_lvlh(1.0).shape == (3, 3)
    for k, tk in enumerate(t):
        np.testing.assert_array_equal(R[k], orbit.R_eci_from_lvlh(tk))
        np.testing.assert_array_equal(r[k], orbit.target_state_eci(tk)[0])
    s = np.arange(6.0)
    assert orbit.observer_state_eci(s, 0.0)[0].shape == (3,)
    assert orbit.observer_state_eci(s, t)[0].shape == (4, 3)            # one state, many times
    assert orbit.observer_state_eci(np.tile(s, (4, 1)), 2.0)[0].shape == (4, 3)  # many, one time
    r_o, v_o = orbit.observer_state_eci(s, t)
    assert orbit.relative_state_lvlh(r_o[0], v_o[0], t[0]).shape == (6,)
    assert orbit.relative_state_lvlh(r_o, v_o, t).shape == (4, 6)


@settings(deadline=None, max_examples=200)
@given(orbit=orbits(any_altitudes), t=times)
def test_rotation_orthonormal_and_target_state_consistent(orbit, t):
    """R is a proper rotation; x̂ ∥ r_T, ŷ ∥ v_T, ẑ ∥ r_T × v_T; |v_T| = n a."""
    R = orbit.R_eci_from_lvlh(t)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    r, v = orbit.target_state_eci(t)
    a, n = orbit.a_m, orbit.n_rad_s
    assert np.linalg.norm(r) == pytest.approx(a, rel=1e-14)
    assert np.linalg.norm(v) == pytest.approx(n * a, rel=1e-14)
    h = np.cross(r, v)
    np.testing.assert_allclose(R[:, 0], r / np.linalg.norm(r), atol=1e-14)
    np.testing.assert_allclose(R[:, 1], v / np.linalg.norm(v), atol=1e-14)
    np.testing.assert_allclose(R[:, 2], h / np.linalg.norm(h), atol=1e-14)
    assert float(r @ v) == pytest.approx(0.0, abs=1e-14 * a * n * a)  # circular
    # ẑ does not depend on time and has the inclination to the pole
    assert R[2, 2] == pytest.approx(math.cos(orbit.inclination_rad), abs=1e-15)


# --------------------------------------------------------------------------- round trip
@settings(deadline=None, max_examples=300)
@given(orbit=orbits(), s=states(), t=times)
def test_observer_state_round_trip(orbit, s, t):
    """LVLH → ECI → LVLH returns the state.

    Absolute bounds, set by float64 spacing of ECI numbers in LEO: r_O is rounded to
    ≤ 4.7e-10 m per component (≤ 8.1e-10 m in norm) and v_O to ≤ 4.6e-13 m/s per component;
    ρ's error enters ρ̇ again through ω × ρ (n · 8e-10 m ≈ 1e-12 m/s), hence 2e-12 m/s.
    Observed per-component maxima over 150 000 random cases: 7.3e-10 m and 1.3e-12 m/s.
    """
    r_o, v_o = orbit.observer_state_eci(s, t)
    back = orbit.relative_state_lvlh(r_o, v_o, t)
    np.testing.assert_allclose(back[:3], s[:3], rtol=1e-15, atol=1e-9)
    np.testing.assert_allclose(back[3:], s[3:], rtol=1e-15, atol=2e-12)


@settings(deadline=None, max_examples=100)
@given(orbit=orbits(any_altitudes), s=states(), t=times)
def test_observer_state_round_trip_any_altitude(orbit, s, t):
    """Same round trip up to 1e9 m altitude, with tolerances scaled by the float64 spacing."""
    r_o, v_o = orbit.observer_state_eci(s, t)
    back = orbit.relative_state_lvlh(r_o, v_o, t)
    ulp_r = float(np.spacing(orbit.a_m + 1e4))
    ulp_v = float(np.spacing(orbit.n_rad_s * orbit.a_m + 20.0))
    np.testing.assert_allclose(back[:3], s[:3], rtol=1e-15, atol=2 * ulp_r)
    np.testing.assert_allclose(back[3:], s[3:], rtol=1e-15, atol=2 * ulp_v + orbit.n_rad_s * 2 * ulp_r)


def test_target_has_zero_relative_state_and_observer_offset_is_R_rho():
    orbit = ReferenceOrbit(raan_rad=1.0, arg_lat_rad=2.0)
    t = np.array([0.0, 100.0, -3000.0])
    r_t, v_t = orbit.target_state_eci(t)
    np.testing.assert_array_equal(orbit.relative_state_lvlh(r_t, v_t, t), np.zeros((3, 6)))
    s = np.array([10.0, -20.0, 5.0, 0.01, 0.02, -0.03])
    r_o, _ = orbit.observer_state_eci(s, t)
    R = orbit.R_eci_from_lvlh(t)
    np.testing.assert_allclose(r_o - r_t, R @ s[:3], atol=2e-9)


# --------------------------------------------------------------------------- velocity term
@pytest.mark.parametrize("orbit", [ReferenceOrbit(),
                                   ReferenceOrbit(altitude_m=700e3, inclination_rad=2.5,
                                                  raan_rad=-1.2, arg_lat_rad=3.3)])
def test_observer_velocity_is_derivative_of_observer_position(orbit):
    """Finite-difference r_O(t) = r_T(t) + R(t) ρ(t) along a CW trajectory and compare with
    v_O = v_T + R (ρ̇ + ω × ρ): an independent check of the rotating-frame term ω × ρ.

    Five-point stencil with h = 1 s: truncation h⁴ n⁵ a / 30 ≈ 4e-10 m/s, rounding of the
    7e6 m positions ≈ 7e-10 m/s / h; ω × ρ itself is ≈ 1.4 m/s here (a wrong sign or a
    missing term would be off by that much).
    """
    n = orbit.n_rad_s
    s0 = np.array([800.0, -1200.0, 300.0, 0.05, -0.4, 0.2])
    h = 1.0
    for t0 in (0.0, 1000.0, -2500.0):
        tt = t0 + h * np.array([-2.0, -1.0, 1.0, 2.0])
        r_o, _ = orbit.observer_state_eci(cw.propagate(s0, n, tt), tt)
        v_fd = (r_o[0] - 8.0 * r_o[1] + 8.0 * r_o[2] - r_o[3]) / (12.0 * h)
        s_t0 = cw.propagate(s0, n, t0)[0]
        _, v_o = orbit.observer_state_eci(s_t0, t0)
        np.testing.assert_allclose(v_fd, v_o, rtol=0, atol=1e-8)
        # the check is sensitive: dropping ω × ρ would move v_O by n|ρ| ≈ 1.7 m/s
        R = orbit.R_eci_from_lvlh(t0)
        wxr = np.cross([0.0, 0.0, n], s_t0[:3])
        assert np.linalg.norm(R @ wxr) > 1.0


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("kwargs", "field", "extra"),
    [
        ({"altitude_m": float("nan")}, "altitude_m", "finite"),
        ({"altitude_m": -400e3}, "altitude_m", "negative"),
        ({"altitude_m": 50e3}, "altitude_m", "atmosphere"),
        ({"altitude_m": 2e9}, "altitude_m", "<="),
        ({"altitude_m": "400 km"}, "altitude_m", "real number"),
        ({"inclination_rad": 4.0}, "inclination_rad", "[0, pi]"),
        ({"inclination_rad": -0.1}, "inclination_rad", "[0, pi]"),
        ({"raan_rad": float("inf")}, "raan_rad", "finite"),
        ({"arg_lat_rad": float("nan")}, "arg_lat_rad", "finite"),
        ({"epoch_utc": "yesterday"}, "epoch_utc", "ISO 8601"),
        ({"epoch_utc": "2026-13-45T00:00:00Z"}, "epoch_utc", "ISO 8601"),
    ],
)
def test_bad_parameters_raise_naming_the_field(kwargs, field, extra):
    with pytest.raises(ValueError, match=field) as info:
        ReferenceOrbit(**kwargs)
    assert extra in str(info.value)


def test_altitude_limits_are_inclusive():
    assert ReferenceOrbit(altitude_m=100e3).altitude_m == 100e3
    assert ReferenceOrbit(altitude_m=1e9).altitude_m == 1e9
    assert ReferenceOrbit(inclination_rad=0.0).inclination_rad == 0.0
    assert ReferenceOrbit(inclination_rad=math.pi).inclination_rad == math.pi


def test_bad_method_inputs_raise_naming_the_parameter():
    orbit = ReferenceOrbit()
    with pytest.raises(ValueError, match="t_s"):
        orbit.R_eci_from_lvlh([[0.0, 1.0]])
    with pytest.raises(ValueError, match="t_s"):
        orbit.target_state_eci(float("nan"))
    with pytest.raises(ValueError, match="s_lvlh"):
        orbit.observer_state_eci(np.zeros(5), 0.0)
    with pytest.raises(ValueError, match="s_lvlh"):
        orbit.observer_state_eci(np.zeros((3, 6)), np.zeros(4))
    with pytest.raises(ValueError, match="v_obs_eci"):
        orbit.relative_state_lvlh(np.zeros((2, 3)), np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="r_obs_eci"):
        orbit.relative_state_lvlh(np.array([np.nan, 0.0, 0.0]), np.zeros(3), 0.0)


def test_frozen():
    orbit = ReferenceOrbit()
    with pytest.raises(AttributeError):
        orbit.altitude_m = 500e3  # type: ignore[misc]
