"""PSFs against closed forms and docs/degradation.md values (Born & Wolf for the Airy pattern)."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import integrate, special
from scipy.signal.windows import gaussian as gaussian_window

from degrade import psf


def centroid_and_cov(h):
    """Centroid (row, col) and 2×2 covariance of a kernel, in pixels."""
    i, j = np.mgrid[:h.shape[0], :h.shape[1]].astype(float)
    ci, cj = (h * i).sum(), (h * j).sum()
    di, dj = i - ci, j - cj
    cov = np.array([[(h * di * di).sum(), (h * di * dj).sum()], [(h * di * dj).sum(), (h * dj * dj).sum()]])
    return np.array([ci, cj]), cov


KERNELS = {
    "airy_spec_example": lambda: psf.airy_psf(1e-3, 550e-9, 4e-3, 3.45e-6),
    "airy_wide": lambda: psf.airy_psf(1e-3, 600e-9, 20e-3, 3.45e-6),
    "gaussian": lambda: psf.gaussian_psf(1.7),
    "pillbox": lambda: psf.defocus_psf(3.3),
    "motion_30": lambda: psf.motion_psf(15.0, 30.0),
    "motion_odd_angle": lambda: psf.motion_psf(7.3, 117.0),
    "composite": lambda: psf.compose(psf.airy_psf(1e-3, 460e-9, 4e-3, 3.45e-6), psf.gaussian_psf(0.8),
                                     psf.defocus_psf(1.5), psf.motion_psf(6.0, -20.0)),
}


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_kernel_sums_to_one_is_odd_and_centred(name):
    h = KERNELS[name]()
    assert h.ndim == 2 and h.shape[0] % 2 == 1 and h.shape[1] % 2 == 1
    assert h.min() >= 0.0
    assert_allclose(h.sum(), 1.0, rtol=0, atol=1e-12)
    c, _ = centroid_and_cov(h)
    assert_allclose(c, [(h.shape[0] - 1) / 2, (h.shape[1] - 1) / 2], atol=1e-9)


def test_cached_kernels_are_read_only():
    h = psf.gaussian_psf(2.0)
    assert h is psf.gaussian_psf(2.0)
    with pytest.raises(ValueError):
        h[0, 0] = 1.0


def encircled_energy(v):
    """Born & Wolf eq. 8.5(20): fraction of the Airy energy within radius v."""
    return 1.0 - special.j0(v) ** 2 - special.j1(v) ** 2


def test_airy_first_zero_constant():
    assert_allclose(psf.AIRY_FIRST_ZERO, special.jn_zeros(1, 1)[0] / math.pi, rtol=1e-15)


def test_airy_838_percent_inside_first_dark_ring():
    # r1 = 8 px: finely sampled and many pixels across the core. Ratio of the energy inside r1
    # to that inside the third dark ring (v3 = j_{1,3}), a circle that fits in the kernel;
    # both rings are dark, so the pixel-centre classification at the boundary costs nothing.
    lam, f, p = 550e-9, 4e-3, 3.45e-6
    d = psf.AIRY_FIRST_ZERO * lam * f / (8.0 * p)
    h = psf.airy_psf(d, lam, f, p, supersample=9)
    c = (h.shape[0] - 1) / 2
    i, j = np.mgrid[:h.shape[0], :h.shape[1]]
    r_px = np.hypot(i - c, j - c)
    v1, v3 = special.jn_zeros(1, 3)[[0, 2]]
    r1_px, r3_px = 8.0, 8.0 * v3 / v1
    inside_r1 = h[r_px <= r1_px].sum() / h[r_px <= r3_px].sum() * encircled_energy(v3)
    assert_allclose(encircled_energy(v1), 0.838, atol=5e-4)  # Born & Wolf: 83.8 % inside r1
    assert_allclose(inside_r1, encircled_energy(v1), atol=3e-3)


def test_airy_sizes_follow_spec():
    # the default optics (docs/degradation.md, "Optics"): λ = 550 nm, f/D = 4, p = 3.45 µm
    # → r1 = 0.78 px; at least 5×5 px and a radius of at least 3 r1/p.
    r1 = psf.AIRY_FIRST_ZERO * 550e-9 * 4 / 3.45e-6
    assert_allclose(r1, 0.78, atol=0.005)
    h = psf.airy_psf(1e-3, 550e-9, 4e-3, 3.45e-6)
    assert h.shape == (2 * math.ceil(3 * r1) + 1,) * 2
    tiny = psf.airy_psf(1e-1, 400e-9, 4e-3, 3.45e-6)
    assert tiny.shape == (5, 5)
    assert tiny[2, 2] > 0.99


def test_airy_larger_for_longer_wavelength():
    _, cov_r = centroid_and_cov(psf.airy_psf(1e-3, 600e-9, 4e-3, 3.45e-6, radius_r1=3.0))
    _, cov_b = centroid_and_cov(psf.airy_psf(1e-3, 460e-9, 4e-3, 3.45e-6, radius_r1=3.0))
    assert cov_r[0, 0] > cov_b[0, 0]


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.3])
def test_gaussian_matches_scipy_window_and_variance(sigma):
    h = psf.gaussian_psf(sigma)
    k = 2 * math.ceil(3 * sigma) + 1  # kernel size 2⌈3σ⌉ + 1
    assert h.shape == (k, k)
    g = gaussian_window(k, sigma)  # independent sampled Gaussian exp(-n²/2σ²)
    assert_allclose(h, np.outer(g, g) / np.outer(g, g).sum(), rtol=1e-12, atol=1e-15)
    _, cov = centroid_and_cov(h)
    assert abs(cov[0, 1]) < 1e-12
    if sigma >= 1.0:  # finer sampling: truncation at 3σ removes ~2.7 % of the variance
        assert_allclose(np.diag(cov), sigma**2, rtol=0.035)


def test_zero_size_blurs_are_identity():
    for h in (psf.gaussian_psf(0.0), psf.defocus_psf(0.0), psf.motion_psf(0.0, 33.0)):
        assert h.shape == (1, 1) and h[0, 0] == 1.0


@pytest.mark.parametrize("radius", [1.0, 2.5, 6.2])
def test_pillbox_area_and_support(radius):
    h = psf.defocus_psf(radius)
    k = 2 * math.ceil(radius) + 1
    assert h.shape == (k, k)
    c = (k - 1) / 2
    i, j = np.mgrid[:k, :k]
    di, dj = np.abs(i - c), np.abs(j - c)
    far_corner = np.hypot(di + 0.5, dj + 0.5)  # pixel entirely inside the disc
    near_point = np.hypot(np.maximum(di - 0.5, 0), np.maximum(dj - 0.5, 0))  # pixel entirely outside
    assert np.all(h[near_point >= radius] == 0.0)
    inside = h[far_corner <= radius]
    assert_allclose(inside, inside.max(), rtol=1e-12)  # uniform disc
    assert_allclose(inside.max() * math.pi * radius**2, 1.0, rtol=0.01)  # area π R²
    # exact disc ∩ pixel areas by quadrature of the chord length (independent of the
    # 16×16 supersampling): within 4 % of a full pixel's weight everywhere
    def area(x0, x1, y0, y1):
        def chord(x):
            half = math.sqrt(max(radius**2 - x * x, 0.0))
            return max(0.0, min(y1, half) - max(y0, -half))

        lo, hi = max(x0, -radius), min(x1, radius)
        return integrate.quad(chord, lo, hi, limit=200)[0] if lo < hi else 0.0

    exact = np.array([[area(jj - c - 0.5, jj - c + 0.5, ii - c - 0.5, ii - c + 0.5) for jj in range(k)]
                      for ii in range(k)])
    assert_allclose(exact.sum(), math.pi * radius**2, rtol=1e-6)
    assert_allclose(h, exact / exact.sum(), atol=0.04 / (math.pi * radius**2))


def test_defocus_radius_thin_lens():
    d, f, p = 2e-3, 8e-3, 3.45e-6
    s, sf = 3.0, 10.0
    # independent thin-lens geometry: image distances, cone of half-width D/2 converging to v
    v = 1 / (1 / f - 1 / s)
    vf = 1 / (1 / f - 1 / sf)
    c = d * abs(v - vf) / v
    assert_allclose(psf.defocus_radius_px(d, f, p, s, sf), c / (2 * p), rtol=1e-12)
    assert_allclose(psf.defocus_radius_px(d, f, p, s), d * f / s / (2 * p), rtol=1e-12)
    assert psf.defocus_radius_px(d, f, p, sf, sf) == 0.0
    with pytest.raises(ValueError, match="object_distance_m"):
        psf.defocus_radius_px(d, f, p, f / 2)


def test_motion_spec_values_theta_0():
    h = psf.motion_psf(15.0, 0.0)
    k = 2 * math.ceil(15 / 2) + 3
    assert h.shape == (k, k)
    row = h[(k - 1) // 2] * 15
    expected = np.zeros(k)
    expected[1:18] = [0.125, 0.875] + [1.0] * 13 + [0.875, 0.125]  # segment [−7.5, 7.5] ⊛ tent Λ
    assert_allclose(row, expected, atol=1e-9)
    assert_allclose(np.delete(h, (k - 1) // 2, axis=0), 0.0, atol=0)


def test_motion_spec_values_theta_30():
    h = psf.motion_psf(15.0, 30.0)
    _, cov = centroid_and_cov(h)
    t = math.radians(30.0)
    along = np.array([-math.sin(t), math.cos(t)])  # (row, col): counter-clockwise as displayed
    across = np.array([math.cos(t), math.sin(t)])
    assert_allclose(along @ cov @ along, 18.918, atol=2e-3)  # docs/degradation.md, "Optics"
    assert_allclose(along @ cov @ along, 15**2 / 12 + 1 / 6, atol=2e-3)
    assert_allclose(across @ cov @ across, 0.170, atol=1e-3)
    assert_allclose(h, h[::-1, ::-1], atol=1e-12)  # point-symmetric


def test_motion_direction_is_counter_clockwise_as_displayed():
    h = psf.motion_psf(10.0, 45.0)
    k = h.shape[0]
    c = (k - 1) // 2
    # up-right diagonal (row decreasing as column increases) carries the energy
    assert h[c - 3, c + 3] > 0.05 and h[c + 3, c + 3] == 0.0


@pytest.mark.parametrize("du, dv", [(40.0, 0.0), (0.0, -40.0), (30.0, 30.0), (-12.0, 25.0)])
def test_motion_from_velocity_blurs_along_the_displacement(du, dv):
    length, angle = psf.motion_from_velocity([du, dv], 0.25)
    assert_allclose(length, 0.25 * math.hypot(du, dv), rtol=1e-15)
    # the kernel's long axis, in (row, col), must be the displacement (dv, du) in pixels
    _, cov = centroid_and_cov(psf.motion_psf(length, angle))
    w, vecs = np.linalg.eigh(cov)
    axis = vecs[:, np.argmax(w)]
    assert_allclose(abs(axis @ np.array([dv, du])) / math.hypot(du, dv), 1.0, atol=1e-9)
    assert_allclose(w.max(), length**2 / 12 + 1 / 6, rtol=0.02)  # along the line: L²/12 + 1/6


def test_motion_from_velocity_angle_convention():
    assert psf.motion_from_velocity([10.0, 0.0], 1.0) == (10.0, 0.0)
    assert psf.motion_from_velocity([0.0, -10.0], 1.0)[1] == 90.0  # moving up the screen
    assert psf.motion_from_velocity([0.0, 10.0], 0.5) == (5.0, -90.0)
    assert psf.motion_from_velocity([3.0, 4.0], 0.0) == (0.0, -53.13010235415598)
    for bad in ([1.0, np.nan], [1.0, 2.0, 3.0], "fast"):
        with pytest.raises(ValueError, match="velocity_px_s"):
            psf.motion_from_velocity(bad, 1.0)
    with pytest.raises(ValueError, match="exposure_s"):
        psf.motion_from_velocity([1.0, 2.0], -1.0)


def test_compose_gaussians_add_variances_and_delta_is_identity():
    g = psf.compose(psf.gaussian_psf(1.2), psf.gaussian_psf(1.6))
    _, cov = centroid_and_cov(g)
    _, c1 = centroid_and_cov(psf.gaussian_psf(1.2))
    _, c2 = centroid_and_cov(psf.gaussian_psf(1.6))
    assert_allclose(cov, c1 + c2, atol=1e-9)  # variances of independent blurs add
    m = psf.motion_psf(9.0, 10.0)
    assert_allclose(psf.compose(m, psf.gaussian_psf(0.0), psf.defocus_psf(0.0)), m, atol=1e-15)


def test_compose_convolution_is_scipy_fftconvolve_bit_for_bit():
    """compose's FFT convolution (scipy.fft only, no scipy.signal import) against
    scipy.signal.fftconvolve itself."""
    from scipy.signal import fftconvolve
    ks = [psf.airy_psf(1e-3, 600e-9, 4e-3, 3.45e-6), psf.gaussian_psf(1.3), psf.motion_psf(15.0, 30.0),
          psf.defocus_psf(2.2), np.random.default_rng(0).random((9, 5))]
    for a in ks:
        for b in ks:
            assert_array_equal(psf._fftconvolve_full(a, b), fftconvolve(a, b, mode="full"))


@pytest.mark.parametrize("call, name", [
    (lambda: psf.airy_psf(-1e-3, 550e-9, 4e-3, 3.45e-6), "aperture_m"),
    (lambda: psf.airy_psf(1e-3, 550e-9, 4e-3, 3.45e-6, supersample=4), "supersample"),
    (lambda: psf.airy_psf(1e-3, 550e-9, 4e-3, 3.45e-6, radius_r1=2), "radius_r1"),
    (lambda: psf.gaussian_psf(float("nan")), "sigma_px"),
    (lambda: psf.defocus_psf(-1.0), "radius_px"),
    (lambda: psf.defocus_psf(2.0, supersample=8), "supersample"),
    (lambda: psf.motion_psf(-1.0, 0.0), "length_px"),
    (lambda: psf.motion_psf(5.0, float("inf")), "angle_deg"),
    (lambda: psf.motion_psf(5.0, 0.0, samples_per_px=10), "samples_per_px"),
    (lambda: psf.compose(np.ones((2, 2))), "kernels"),
    (lambda: psf.compose(), "kernel"),
])
def test_invalid_parameters_name_the_parameter(call, name):
    with pytest.raises(ValueError, match=name):
        call()
