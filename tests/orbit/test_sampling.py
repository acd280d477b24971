"""Seeded pattern sampling with a range band scaled to the target (docs/orbit.md, "How a sequence
is drawn")."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from orbit import cw
from orbit.patterns import PATTERNS, parameters
from orbit.sampling import default_window_s, range_band, sample_pattern

N = 1.1313666536110223e-3
T = 2.0 * math.pi / N


def _integrated_range(s0, t):
    """|r(t)| by numerical integration of the CW ODE (independent of the closed form)."""
    A = cw.system_matrix(N)
    sol = solve_ivp(lambda _t, s: A @ s, (0.0, t[-1]), s0, method="DOP853", t_eval=t, rtol=1e-11, atol=1e-9)
    return np.linalg.norm(sol.y[:3].T, axis=1)


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("radius", [2.0, 4.5, 28.0])
def test_samples_have_requested_pattern_and_stay_in_band(pattern, radius):
    band = range_band(radius)
    for seed in range(12):
        smp = sample_pattern(pattern, N, target_radius_m=radius, n_frames=60, rng=seed)
        assert parameters(smp.s0_lvlh, N).pattern == pattern
        assert smp.params.pattern == pattern
        assert smp.t_s.shape == (60,) and smp.t_s[0] == 0.0 and smp.t_s[-1] == pytest.approx(smp.window_s)
        r = _integrated_range(np.array(smp.s0_lvlh), np.asarray(smp.t_s))
        assert r.min() >= band.r_min_m - 1e-6 and r.max() <= band.r_max_m + 1e-6
        # the window is centred: the ellipse centre passes the target along-track at T_w / 2
        p = smp.params
        y_centre_mid = p.gamma - p.beta * (smp.window_s / 2 - p.t_p)
        assert y_centre_mid == pytest.approx(0.0, abs=1e-6 * band.r_max_m)


def test_band_scales_with_target_size():
    assert (range_band(2.0).r_min_m, range_band(2.0).r_max_m) == (10.0, 60.0)
    assert (range_band(4.0).r_min_m, range_band(4.0).r_max_m) == (10.0, 60.0)
    big = range_band(28.0)
    assert (big.r_min_m, big.r_max_m) == pytest.approx((70.0, 420.0))
    # a large target keeps the camera outside its bounding sphere with margin
    for pattern in PATTERNS:
        smp = sample_pattern(pattern, N, target_radius_m=28.0, n_frames=50, rng=3)
        assert smp.range_m[0] > 2.0 * 28.0


@pytest.mark.parametrize("pattern, expected", [
    ("elliptical", 1.00), ("spiral", 0.94), ("drip-drop", 0.60), ("drift", 0.90),
])
def test_acceptance_rates_match_spec_table(pattern, expected):
    # acceptance rates of docs/orbit.md, "How a sequence is drawn"; 400 draws: binomial σ ≤ 0.025,
    # allow ±0.06
    draws = 400
    attempts = sum(sample_pattern(pattern, N, target_radius_m=3.0, n_frames=100, rng=s).attempts
                   for s in range(draws))
    assert draws / attempts == pytest.approx(expected, abs=0.06)


def test_sampled_parameters_are_recorded_and_follow_the_table():
    for seed in range(30):
        e = sample_pattern("elliptical", N, target_radius_m=3.0, n_frames=10, rng=seed)
        assert 10.0 <= e.draws["A_m"] <= 28.0 and e.draws["kappa"] == 0.0
        assert e.window_s == pytest.approx(T)
        s = sample_pattern("spiral", N, target_radius_m=3.0, n_frames=10, rng=seed)
        assert 10.0 <= s.draws["A_m"] <= 22.0 and 0.03 <= abs(s.draws["kappa"]) <= 0.28
        assert s.window_s == pytest.approx(T / 2)
        d = sample_pattern("drip-drop", N, target_radius_m=3.0, n_frames=10, rng=seed)
        assert 8.0 <= d.draws["A_m"] <= 16.0 and 0.30 <= abs(d.draws["kappa"]) <= 0.95
        f = sample_pattern("drift", N, target_radius_m=3.0, n_frames=10, rng=seed)
        assert 12.0 <= abs(f.draws["x_l_m"]) <= 30.0 and abs(f.draws["kappa"]) >= 1.0
        assert f.window_s == pytest.approx(min(T, 80.0 / (1.5 * N * abs(f.draws["x_l_m"]))))
        for smp in (e, s, d, f):
            assert smp.params.A == pytest.approx(smp.draws["A_m"], rel=1e-9)
            assert smp.params.z_amp == pytest.approx(smp.draws["z_amp_m"], abs=1e-9)


def test_both_drift_directions_are_sampled():
    sides = {sample_pattern("spiral", N, target_radius_m=3.0, n_frames=5, rng=s).params.side for s in range(20)}
    assert sides == {"above", "below"}


def test_same_seed_same_bytes_and_generator_accepted():
    a = sample_pattern("drip-drop", N, target_radius_m=3.0, n_frames=20, rng=123)
    b = sample_pattern("drip-drop", N, target_radius_m=3.0, n_frames=20, rng=123)
    c = sample_pattern("drip-drop", N, target_radius_m=3.0, n_frames=20, rng=124)
    assert a.s0_lvlh.tobytes() == b.s0_lvlh.tobytes() and a.t_s.tobytes() == b.t_s.tobytes()
    assert a.s0_lvlh.tobytes() != c.s0_lvlh.tobytes()
    g = sample_pattern("drip-drop", N, target_radius_m=3.0, n_frames=20, rng=np.random.default_rng(123))
    assert g.s0_lvlh.tobytes() == a.s0_lvlh.tobytes()
    assert not a.s0_lvlh.flags.writeable


def test_user_window_and_single_frame():
    smp = sample_pattern("elliptical", N, target_radius_m=3.0, n_frames=1, rng=0, window_s=600.0)
    assert smp.t_s.tolist() == [0.0] and smp.window_s == 600.0
    assert default_window_s("spiral", N) == pytest.approx(T / 2)


@pytest.mark.parametrize("kwargs, match", [
    (dict(pattern="stationary"), "^pattern must be one of elliptical, spiral, drip-drop, drift"),
    (dict(pattern="helix"), "^pattern must be one of"),
    (dict(n_frames=0), "^n_frames must be an integer >= 1"),
    (dict(n_frames=2.5), "^n_frames must be an integer >= 1"),
    (dict(target_radius_m=-1.0), "^target_radius_m must be > 0"),
    (dict(target_radius_m=math.nan), "^target_radius_m must be finite"),
    (dict(window_s=0.0), "^window_s must be > 0"),
    (dict(pattern="drift", window_s=50 * T, max_attempts=50), "no drift draw stayed within 10–60 m"),
])
def test_bad_input(kwargs, match):
    args = dict(pattern="spiral", n_frames=10, target_radius_m=3.0, rng=0)
    args.update(kwargs)
    pattern = args.pop("pattern")
    with pytest.raises(ValueError, match=match):
        sample_pattern(pattern, N, **args)
