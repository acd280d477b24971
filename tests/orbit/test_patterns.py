"""Pattern parameters and classification (docs/orbit.md, "Patterns and their thresholds").

Thresholds are checked against brute-force geometry: segment–segment intersection of the
in-plane trajectory drawn as a polyline, bisected on κ — no use of the sin w / w derivation.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from orbit import cw, patterns
from orbit.patterns import (KAPPA_STAR, SIGMA_SPIRAL_HIGH, SIGMA_SPIRAL_LOW, classify, classify_sigma,
                            parameters, state_from_kappa, state_from_pattern, state_from_sigma)

N = 1.1313666536110223e-3
T = 2.0 * math.pi / N

# expected parameters of the worked examples E1–E5 of tests/orbit/test_cw.py, from the closed-form
# expressions for A, x_l, β, γ, t_p, σ and κ at this n
E = {
    "E1": dict(s0=[10, 0, 5, 0, -2 * N * 10, 0], A=10, x_l=0, beta=0, gamma=0, sigma=2, kappa=0, t_p=0,
               pattern="elliptical"),
    "E2": dict(s0=[15, 0, 0, 0, -1.95 * N * 15, 0], A=13.5, x_l=1.5, beta=2.545574971e-3, gamma=0, sigma=1.95,
               kappa=0.1111111, t_p=0, pattern="spiral"),
    "E3": dict(s0=[10, 0, 0, 0, -2.5 * N * 10, 3 * N], A=20, x_l=-10, beta=-1.697049980e-2, gamma=0, sigma=2.5,
               kappa=-0.5, t_p=0, pattern="drip-drop"),
    "E4": dict(s0=[20, 0, 0, 0, -1.6 * N * 20, 0], A=4, x_l=16, beta=2.715279969e-2, gamma=0, sigma=1.6, kappa=4,
               t_p=0, pattern="drift"),
    "E5": dict(s0=[5, 30, 2, 0.012, -0.004, 0.002], A=13.24267285, x_l=12.92890596, beta=2.1940999608e-2,
               gamma=-34.12539865, sigma=1.752997210, kappa=0.9763063780, t_p=1955.795875, pattern="drip-drop",
               x_p=26.17157881, ydot_p=-0.05190563650),
}


@pytest.mark.parametrize("name", sorted(E))
def test_spec_vector_parameters(name):
    e = E[name]
    p = parameters(e["s0"], N)
    assert p.pattern == e["pattern"]
    for key in ("A", "x_l", "gamma", "x_p"):
        if key in e:
            assert getattr(p, key) == pytest.approx(e[key], abs=1e-7)
    assert p.beta == pytest.approx(e["beta"], rel=1e-9, abs=1e-15)
    assert p.sigma == pytest.approx(e["sigma"], abs=1e-8)
    assert p.kappa == pytest.approx(e["kappa"], abs=1e-7)
    assert p.t_p == pytest.approx(e["t_p"], abs=1e-6)
    if "ydot_p" in e:
        assert p.ydot_p == pytest.approx(e["ydot_p"], abs=1e-10)
    assert p.alpha == pytest.approx(-2 * e["A"], abs=1e-7)


def test_characteristic_point_is_the_maximum_of_x():
    # independent: sample x(t) densely over one revolution after t0 and find its maximum
    s0 = E["E5"]["s0"]
    p = parameters(s0, N)
    t = np.linspace(0, T, 200_001)
    s = cw.propagate(s0, N, t)
    i = np.argmax(s[:, 0])
    assert t[i] == pytest.approx(p.t_p, abs=T / 200_000)
    assert s[i, 0] == pytest.approx(p.x_p, abs=1e-6)
    assert s[i, 1] == pytest.approx(p.gamma, abs=1e-3)
    # the ellipse centre drifts by −β per second: centre y over a revolution
    assert np.mean(s[:-1, 1]) == pytest.approx(p.gamma - p.beta * (T / 2 - p.t_p) + 0.0, abs=0.05)


# ---------------------------------------------------------------- brute-force geometry
def _curve(kappa, tau):
    """In-plane trajectory with A = 1, n = 1 (shape depends on κ only), from P."""
    return np.stack([kappa + np.cos(tau), -2 * np.sin(tau) - 1.5 * kappa * tau], axis=-1)


def _proper_intersections(P, Q):
    """Index pairs (i, j) where segment P[i]P[i+1] properly crosses Q[j]Q[j+1]."""
    a, b = P[:-1, None, :], P[1:, None, :]
    c, d = Q[None, :-1, :], Q[None, 1:, :]

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    hit = (orient(a, b, c) * orient(a, b, d) < 0) & (orient(c, d, a) * orient(c, d, b) < 0)
    return np.nonzero(hit)


def _self_crossings(kappa, lo, hi, m):
    """Parameter pairs (τa < τb) where the polyline over [lo, hi] crosses itself."""
    tau = np.linspace(lo, hi, m)
    P = _curve(kappa, tau)
    i, j = _proper_intersections(P, P)
    keep = j > i + 1
    return tau[i[keep]], tau[j[keep]]


def _cross_crossings(kappa, w1, w2, m):
    """Parameter pairs where the polyline over w1 crosses the polyline over w2."""
    t1 = np.linspace(*w1, m)
    t2 = np.linspace(*w2, m)
    i, j = _proper_intersections(_curve(kappa, t1), _curve(kappa, t2))
    return t1[i], t2[j]


THREE_REVS = (-3 * math.pi, 3 * math.pi)


def _overlaps(kappa, m=2400):
    """Consecutive revolutions cross: a self-crossing whose parameters are 2π–4π apart."""
    ta, tb = _self_crossings(kappa, *THREE_REVS, m)
    return bool(np.any((tb - ta > 2 * math.pi) & (tb - ta < 4 * math.pi)))


def _loops(kappa, m=2400):
    """A loop within one revolution: a self-crossing whose parameters are < 2π apart."""
    ta, tb = _self_crossings(kappa, *THREE_REVS, m)
    return bool(np.any(tb - ta < 2 * math.pi))


def _bisect(predicate, lo, hi, tol):
    """predicate(lo) is True, predicate(hi) is False (lo > hi allowed); returns the switching κ."""
    assert predicate(lo) and not predicate(hi)
    while abs(hi - lo) > tol:
        mid = 0.5 * (lo + hi)
        if predicate(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _refined_threshold(predicate_coarse, lo, hi, separation):
    """Bisect coarsely, then again on ±0.1 rad windows around the crossings found by brute force.

    ``lo`` is on the crossing side (predicate True), ``hi`` on the other (either order).
    """
    k_coarse = _bisect(predicate_coarse, lo, hi, 1e-4)
    d = math.copysign(1.0, hi - lo)
    ta, tb = _self_crossings(k_coarse - d * 2e-4, *THREE_REVS, 2400)
    ta, tb = ta[separation(tb - ta)], tb[separation(tb - ta)]
    near = np.abs(ta - ta.min()) < 0.5  # the pair of crossings about to merge at one tangency
    c1, c2 = float(np.mean(ta[near])), float(np.mean(tb[near]))

    def fine(k):  # 1e-4 rad segments: chord sag ~1e-9
        u1, _ = _cross_crossings(k, (c1 - 0.075, c1 + 0.075), (c2 - 0.075, c2 + 0.075), 1500)
        return u1.size > 0

    return _bisect(fine, k_coarse - d * 3e-4, k_coarse + d * 3e-4, 1e-10)


def test_kappa_star_from_polyline_intersections():
    def consecutive(sep):
        return (sep > 2 * math.pi) & (sep < 4 * math.pi)

    k_pos = _refined_threshold(_overlaps, 0.1, 0.5, consecutive)
    k_neg = _refined_threshold(_overlaps, -0.1, -0.5, consecutive)
    assert k_pos == pytest.approx(KAPPA_STAR, abs=1e-8)
    assert k_neg == pytest.approx(-KAPPA_STAR, abs=1e-8)
    assert KAPPA_STAR == pytest.approx(0.2896448376149622, abs=1e-15)  # (4/3)|cos u*|, tan u* = u*
    assert SIGMA_SPIRAL_LOW == pytest.approx(1.8877036417, abs=1e-10)
    assert SIGMA_SPIRAL_HIGH == pytest.approx(2.2038732545, abs=1e-10)
    assert patterns.sigma_from_kappa(k_pos) == pytest.approx(SIGMA_SPIRAL_LOW, abs=1e-8)
    assert patterns.sigma_from_kappa(k_neg) == pytest.approx(SIGMA_SPIRAL_HIGH, abs=1e-8)


def test_loop_threshold_four_thirds_from_polyline():
    # the loop shrinks to a cusp: refine with self-crossings of one fine polyline around it
    k_coarse = _bisect(_loops, 1.0, 1.5, 1e-4)
    ta, tb = _self_crossings(k_coarse - 2e-4, *THREE_REVS, 2400)
    loop = tb - ta < 2 * math.pi
    c = float(np.mean((ta[loop] + tb[loop])[:1])) / 2

    def fine(k):  # 5e-5 rad segments
        u1, _ = _self_crossings(k, c - 0.05, c + 0.05, 2000)
        return u1.size > 0

    k_loop = _bisect(fine, k_coarse - 3e-4, k_coarse + 3e-4, 1e-10)
    # a loop narrower than a few segments is missed, so the bisection stops ~1e-7 short of 4/3
    assert k_loop == pytest.approx(4 / 3, abs=1e-6)
    assert patterns.sigma_from_kappa(4 / 3) == pytest.approx(12 / 7, abs=1e-15)


def test_vbar_crossing_threshold_is_one():
    tau = np.linspace(0, 2 * math.pi, 100_001)
    for k in (0.999, 0.9999):
        assert np.any(_curve(k, tau)[:, 0] < 0)
    for k in (1.0, 1.0001, 1.2):
        assert np.all(_curve(k, tau)[:, 0] >= -1e-15)
    assert patterns.sigma_from_kappa(1.0) == 1.75


@pytest.mark.parametrize("kappa, spiral_overlap, has_loop", [
    (0.1, True, True), (-0.2, True, True), (0.5, False, True), (-0.9, False, True),
    (1.2, False, True), (-1.2, False, True), (1.4, False, False), (3.0, False, False),
])
def test_pattern_meaning_brute_force(kappa, spiral_overlap, has_loop):
    assert _overlaps(kappa) == spiral_overlap
    assert _loops(kappa) == has_loop


# ---------------------------------------------------------------- classification
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_classify_at_and_around_thresholds(sign):
    A = 10.0
    below = np.nextafter(KAPPA_STAR, 0.0)
    assert classify(A, sign * below * A) == "spiral"
    assert classify(A, sign * KAPPA_STAR * A) == "drip-drop"
    assert classify(A, sign * 0.999999 * A) == "drip-drop"
    assert classify(A, sign * 1.0 * A) == "drift"
    assert classify(A, sign * 1.2 * A) == "drift"
    assert classify(A, sign * 5.0 * A) == "drift"
    assert classify(A, sign * 1e-10 * A) == "elliptical"
    assert classify(A, sign * 1e-8 * A) == "spiral"


def test_classify_degenerate_cases():
    assert classify(0.0, 0.0) == "stationary"
    assert classify(0.0, 5.0) == "drift"
    assert classify(0.0, -5.0) == "drift"
    assert classify(1e-12, 0.0, length_scale_m=30.0) == "stationary"
    assert classify(1e-12, 0.0) == "elliptical"  # a 1 pm ellipse with no other scale
    # x_p = 0 with ẏ_p < 0: κ = −1, trajectory below the V-bar touching it at P
    p = parameters(state_from_pattern(10.0, 1.5 * N * -10.0, 0.0, N), N)
    assert p.kappa == pytest.approx(-1.0) and p.pattern == "drift" and math.isnan(p.sigma)
    assert p.x_p == 0.0


def test_stationary_vbar_hold_and_pure_drift_parameters():
    p = parameters([0, 30, 0, 0, 0, 0], N)
    assert p.pattern == "stationary" and math.isnan(p.sigma) and math.isnan(p.kappa) and p.side == ""
    p = parameters(state_from_pattern(0.0, 1.5 * N * 12.0, 0.0, N), N)  # A = 0, x_l = 12
    assert p.pattern == "drift" and p.kappa == math.inf and p.sigma == pytest.approx(1.5)
    assert p.to_dict()["kappa"] == "inf"


def test_negative_sigma_requires_negative_xp():
    # σ < 0 with x_p < 0: below the target, looping (a drift)
    s0 = state_from_sigma(-5.0, -0.5, 0.0, N)
    p = parameters(s0, N)
    assert p.x_p == pytest.approx(-5.0) and p.sigma == pytest.approx(-0.5) and p.pattern == "drift"
    assert abs(p.kappa) < 4 / 3  # small loops


@pytest.mark.parametrize("sigma, expected", [
    (2.0, "elliptical"), (1.75, "drift"), (1.75 + 1e-12, "drip-drop"), (1.6, "drift"), (1.5, "drift"),
    (SIGMA_SPIRAL_LOW, "drip-drop"), (1.8877, "drip-drop"), (1.8878, "spiral"), (1.95, "spiral"),
    (2.2038, "spiral"), (SIGMA_SPIRAL_HIGH, "drip-drop"), (2.2039, "drip-drop"), (12 / 7 + 1e-9, "drift"),
    (40.0, "drip-drop"),
])
def test_classify_sigma_thresholds(sigma, expected):
    assert classify_sigma(sigma, 10.0) == expected


def test_classify_sigma_rejects_invalid_combinations():
    with pytest.raises(ValueError, match="sigma must be >= 1.5 when x_p > 0"):
        classify_sigma(1.4, 10.0)
    with pytest.raises(ValueError, match="sigma must be <= 1.5 when x_p < 0"):
        classify_sigma(1.6, -10.0)
    with pytest.raises(ValueError, match="x_p must be non-zero"):
        classify_sigma(2.0, 0.0)
    assert classify_sigma(-3.0, -10.0) == "drift"
    with pytest.raises(ValueError, match="sigma must be >= 1.5"):
        state_from_sigma(10.0, 1.2, 0.0, N)


def test_sigma_and_kappa_classifications_agree_on_random_states():
    rng = np.random.default_rng(7)
    count = 0
    while count < 200:
        s = np.concatenate([rng.uniform(-50, 50, 3), rng.uniform(-0.1, 0.1, 3)])
        p = parameters(s, N)
        if p.x_p == 0.0:
            continue
        k = abs(p.kappa)
        if min(abs(k - KAPPA_STAR), abs(k - 1.0)) < 1e-6:
            continue  # round-off at a boundary may legitimately differ
        assert classify_sigma(p.sigma, p.x_p) == p.pattern
        assert p.sigma == pytest.approx(patterns.sigma_from_kappa(p.kappa), rel=1e-9, abs=1e-9)
        count += 1


# ---------------------------------------------------------------- inverse map
@settings(deadline=None, max_examples=200)
@given(A=st.floats(0.5, 100), kappa=st.floats(-3, 3), gamma=st.floats(-100, 100),
       z_amp=st.floats(0, 20), z_phase=st.floats(-3.1, 3.1), tau0=st.floats(0, 6.28))
def test_inverse_map_round_trip(A, kappa, gamma, z_amp, z_phase, tau0):
    beta = 1.5 * N * kappa * A
    s0 = state_from_pattern(A, beta, gamma, N, z_amp=z_amp, z_phase=z_phase, tau0=tau0)
    p = parameters(s0, N)
    assert p.A == pytest.approx(A, rel=1e-9)
    assert p.x_l == pytest.approx(kappa * A, abs=1e-9 * A)
    assert p.beta == pytest.approx(beta, abs=1e-12)
    assert p.z_amp == pytest.approx(z_amp, abs=1e-9)
    if z_amp > 1e-6:
        assert math.cos(p.z_phase - z_phase) == pytest.approx(1.0, abs=1e-12)
    # parameters() reports the first P at or after t = 0: one revolution later unless τ0 = 0
    phase_gap = (2 * math.pi - tau0) % (2 * math.pi)
    if 1e-6 < phase_gap < 2 * math.pi - 1e-6:
        assert p.t_p == pytest.approx(phase_gap / N, abs=1e-6)
        assert p.gamma == pytest.approx(gamma - beta * 2 * math.pi / N, abs=1e-7 * (1 + abs(gamma) + A))
        assert p.tau0 == pytest.approx(tau0 % (2 * math.pi), abs=1e-9)


def test_inverse_map_start_at_p():
    s0 = state_from_pattern(12.0, 0.004, -7.0, N, tau0=0.0)
    assert s0[3] == 0.0
    p = parameters(s0, N)
    assert p.t_p == 0.0 and p.gamma == pytest.approx(-7.0) and p.tau0 == 0.0
    # s_P = [A + 2β/(3n), γ, 0, 0, −β − 2nA, 0]
    assert_allclose(s0, [12 + 2 * 0.004 / (3 * N), -7.0, 0, 0, -0.004 - 2 * N * 12, 0], rtol=1e-15)


def test_state_from_sigma_and_kappa():
    s0 = state_from_sigma(26.17157881, 1.752997210, -34.12539865, N)
    p = parameters(s0, N)
    assert p.x_p == pytest.approx(26.17157881, abs=1e-7)
    assert p.sigma == pytest.approx(1.752997210, abs=1e-9)
    assert p.kappa == pytest.approx(0.9763063780, abs=1e-8)
    s1 = state_from_kappa(13.5, 1.5 / 13.5, 0.0, N)
    assert_allclose(s1, E["E2"]["s0"], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("call, match", [
    (lambda: state_from_pattern(-1.0, 0.0, 0.0, N), "^A must be >= 0"),
    (lambda: state_from_pattern(math.nan, 0.0, 0.0, N), "^A must be finite"),
    (lambda: state_from_pattern(1.0, math.inf, 0.0, N), "^beta must be finite"),
    (lambda: state_from_pattern(1.0, 0.0, 0.0, -N), "^n must be > 0"),
    (lambda: state_from_pattern(1.0, 0.0, 0.0, N, z_amp=-1.0), "^z_amp must be >= 0"),
    (lambda: parameters([1, 2, 3, 4, 5, math.nan], N), "^s_lvlh must be finite"),
    (lambda: parameters([1, 2, 3], N), r"^s_lvlh must have shape \(6,\)"),
    (lambda: classify(-1.0, 0.0), "^A must be >= 0"),
    (lambda: classify(1.0, math.nan), "^x_l must be finite"),
    (lambda: classify_sigma(math.nan, 1.0), "^sigma must be finite"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()
