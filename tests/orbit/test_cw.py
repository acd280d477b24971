"""CW closed form against worked examples, the matrix exponential and numerical integration."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from orbit import cw

N = 1.1313666536110223e-3  # n = sqrt(μ/a³), 400 km circular orbit (a = 6 778 137 m)
T = 2.0 * math.pi / N

# worked examples E1–E5 (one per pattern and a general state): s0 and r(T/4), r(T/2), r(T) [m],
# from the closed-form CW solution at this n (docs/orbit.md, "Relative motion (Clohessy–Wiltshire)")
VECTORS = {
    "E1": ([10, 0, 5, 0, -2 * N * 10, 0], [[0, -20, 0], [-10, 0, -5], [10, 0, 5]]),
    "E2": ([15, 0, 0, 0, -1.95 * N * 15, 0], [[1.5, -30.5342917, 0], [-12, -7.06858347, 0], [15, -14.1371669, 0]]),
    "E3": ([10, 0, 0, 0, -2.5 * N * 10, 3 * N], [[-10, -16.4380551, 3], [-30, 47.1238898, 0], [10, 94.2477796, 0]]),
    "E4": ([20, 0, 0, 0, -1.6 * N * 20, 0], [[16, -45.6991118, 0], [12, -75.3982237, 0], [20, -150.796447, 0]]),
    "E5": ([5, 30, 2, 0.012, -0.004, 0.002],
           [[23.535547, -5.81848718, 1.76777351], [20.8578119, -73.3525982, -2], [5, -91.852068, 2]]),
}

states = st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3).flatmap(
    lambda r: st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(lambda v: np.array(r + v)))


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_spec_vectors(name):
    s0, expected = VECTORS[name]
    r = cw.propagate(s0, N, [T / 4, T / 2, T])[:, :3]
    assert_allclose(r, expected, atol=1e-6, rtol=0)  # the examples' precision


def test_stm_identity_and_determinant():
    assert_allclose(cw.stm(N, 0.0), np.eye(6), atol=0, rtol=0)
    t = np.linspace(-3 * T, 3 * T, 41)
    assert_allclose(np.linalg.det(cw.stm(N, t)), 1.0, rtol=0, atol=1e-9)


def test_stm_equals_matrix_exponential():
    # independent oracle: Φ(t) = expm(A t)
    A = cw.system_matrix(N)
    for t in (-2000.0, -1.0, 1e-3, 17.0, 1234.5, T, 7.3 * T):
        assert_allclose(cw.stm(N, t), expm(A * t), rtol=1e-10, atol=1e-12 * max(1.0, abs(t)))


def test_stm_composition_including_negative_times():
    for a, b in [(100.0, 250.0), (-300.0, 4000.0), (-T, -0.25 * T), (3.3 * T, -5.1 * T)]:
        lhs = cw.stm(N, a + b)
        rhs = cw.stm(N, a) @ cw.stm(N, b)
        assert_allclose(lhs, rhs, rtol=1e-12, atol=1e-12 * (1 + abs(a) + abs(b)))


def test_stm_satisfies_ode_by_central_difference():
    A = cw.system_matrix(N)
    h = 1e-2
    for t in (0.0, 123.0, 2500.0, -800.0):
        dphi = (cw.stm(N, t + h) - cw.stm(N, t - h)) / (2 * h)
        assert_allclose(dphi, A @ cw.stm(N, t), rtol=1e-8, atol=1e-11)


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_propagate_matches_numerical_integration(name):
    # independent oracle: DOP853 on ṡ = A s (rtol 1e-13)
    s0 = np.array(VECTORS[name][0], dtype=float)
    A = cw.system_matrix(N)
    t = np.linspace(0, 1.5 * T, 31)
    sol = solve_ivp(lambda _t, s: A @ s, (0, t[-1]), s0, method="DOP853", t_eval=t, rtol=1e-13, atol=1e-12)
    assert_allclose(cw.propagate(s0, N, t), sol.y.T, rtol=1e-9, atol=1e-8)


def test_propagate_equals_stm_times_state():
    s0 = np.array(VECTORS["E5"][0])
    t = np.linspace(-T, 2 * T, 101)
    assert_allclose(cw.propagate(s0, N, t), cw.stm(N, t) @ s0, rtol=1e-12, atol=1e-10)


def test_invariant_vy_plus_2nx():
    s = cw.propagate(VECTORS["E5"][0], N, np.linspace(0, 5 * T, 500))
    c = s[:, 4] + 2 * N * s[:, 0]
    assert_allclose(c, c[0], rtol=0, atol=1e-15)


def test_closed_ellipse_is_periodic_for_1000_orbits():
    s0 = np.array(VECTORS["E1"][0])
    k = np.arange(0, 1001)
    s = cw.propagate(s0, N, k * T)
    assert np.all(np.isfinite(s))
    assert_allclose(s[:, :3], np.broadcast_to(s0[:3], (k.size, 3)), atol=1e-8, rtol=0)
    assert_allclose(s[:, 3:], np.broadcast_to(s0[3:], (k.size, 3)), atol=1e-11, rtol=0)


def test_drift_is_linear_over_1000_orbits():
    # E4 drifts by −β T per revolution with β = 3(ẏ0 + 2n x0) = (3/2) n x_l
    s0 = np.array(VECTORS["E4"][0])
    beta = 3 * (s0[4] + 2 * N * s0[0])
    k = np.arange(0, 1001)
    s = cw.propagate(s0, N, k * T)
    assert_allclose(s[:, 1], -beta * k * T, rtol=1e-12, atol=1e-6)
    assert_allclose(s[:, 0], s0[0], atol=1e-8)


def test_million_epochs_vectorised():
    t = np.linspace(-10 * T, 10 * T, 1_000_000)
    s = cw.propagate(VECTORS["E3"][0], N, t)
    assert s.shape == (1_000_000, 6) and s.dtype == np.float64
    assert np.all(np.isfinite(s))
    idx = np.array([0, 1, 12345, 500_000, 999_999])
    assert_allclose(s[idx], cw.stm(N, t[idx]) @ np.array(VECTORS["E3"][0]), rtol=1e-11, atol=1e-9)


def test_scalar_time_gives_one_row():
    out = cw.propagate(VECTORS["E1"][0], N, T / 4)
    assert out.shape == (1, 6)
    assert cw.stm(N, 1.0).shape == (6, 6)


def test_float32_inputs_are_promoted():
    s32 = np.array(VECTORS["E2"][0], dtype=np.float32)
    out = cw.propagate(s32, np.float32(N), np.array([100.0, 200.0], dtype=np.float32))
    assert out.dtype == np.float64
    ref = cw.propagate(s32.astype(np.float64), float(np.float32(N)), [100.0, 200.0])
    assert_allclose(out, ref, rtol=1e-15)


@settings(deadline=None, max_examples=200)
@given(s0=states, t1=st.floats(-2e4, 2e4), t2=st.floats(-2e4, 2e4))
def test_property_composition(s0, t1, t2):
    direct = cw.propagate(s0, N, t1 + t2)[0]
    via = cw.propagate(cw.propagate(s0, N, t1)[0], N, t2)[0]
    scale = 1.0 + np.abs(s0[:3]).max() + 1e3 * np.abs(s0[3:]).max()
    assert_allclose(via, direct, rtol=1e-9, atol=1e-9 * scale * (1 + (abs(t1) + abs(t2)) / T))


@settings(deadline=None, max_examples=100)
@given(s0=states, t=st.floats(-2e4, 2e4))
def test_property_ode_residual(s0, t):
    A = cw.system_matrix(N)
    h = 0.05
    s = cw.propagate(s0, N, [t - h, t, t + h])
    deriv = (s[2] - s[0]) / (2 * h)
    scale = 1.0 + np.abs(s).max()
    assert_allclose(deriv, A @ s[1], atol=1e-8 * scale, rtol=1e-6)


@pytest.mark.parametrize("s0, match", [
    ([np.nan, 0, 0, 0, 0, 0], "s0_lvlh must be finite"),
    ([np.inf, 0, 0, 0, 0, 0], "s0_lvlh must be finite"),
    ([1, 2, 3], r"s0_lvlh must have shape \(6,\)"),
    ("abc", "s0_lvlh must be a numeric array"),
])
def test_bad_state(s0, match):
    with pytest.raises(ValueError, match=match):
        cw.propagate(s0, N, [1.0])


@pytest.mark.parametrize("n", [0.0, -1e-3, np.nan, np.inf, "x"])
def test_bad_mean_motion(n):
    with pytest.raises(ValueError, match="^n must"):
        cw.propagate(VECTORS["E1"][0], n, [1.0])


@pytest.mark.parametrize("t", [[np.nan], [[1.0, 2.0]], np.inf])
def test_bad_times(t):
    with pytest.raises(ValueError, match="^t_s must"):
        cw.propagate(VECTORS["E1"][0], N, t)
