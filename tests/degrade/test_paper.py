"""Paper mode: bit-identical to skimage.util.random_noise (scikit-image 0.26 source)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage, stats
from skimage.util import random_noise

from degrade import (
    PaperConfig,
    gaussian_noise,
    motion_psf,
    paper_blur,
    paper_degrade,
    poisson_noise,
)


def render(shape=(96, 128, 3), seed=0):
    """A textured target on black, as an 8-bit render in [0, 1]."""
    rng = np.random.default_rng(seed)
    img = np.zeros(shape, np.float32)
    h, w = shape[0] // 2, shape[1] // 2
    img[h // 2:h // 2 + h, w // 2:w // 2 + w] = rng.integers(0, 256, (h, w, *shape[2:])) / 255
    return img


def test_blur_is_ndimage_convolution_requantised():
    img = render()
    ref = ndimage.convolve(img.astype(np.float64), motion_psf(15.0, 30.0)[:, :, None], mode="reflect")
    ref_codes = np.rint(255 * np.clip(ref, 0, 1))
    codes = np.rint(paper_blur(img).astype(np.float64) * 255)
    assert_array_equal(paper_blur(img) * np.float32(255), codes.astype(np.float32))  # on the 8-bit grid
    # float32 vs float64 convolution can only flip a code at an exact .5 tie
    assert np.abs(codes - ref_codes).max() <= 1
    assert np.mean(codes != ref_codes) < 1e-3
    assert_array_equal(paper_degrade(img, "D1", rng=0), paper_blur(img))


@pytest.mark.parametrize("seed", [0, 7, 2024])
def test_groups_equal_random_noise_chain(seed):
    img = render(seed=seed)
    b = np.rint(paper_blur(img).astype(np.float64) * 255) / 255  # the 8-bit blurred image, float64
    p, g = np.random.default_rng(seed).spawn(2)
    d2 = random_noise(b, mode="poisson", rng=p)
    d4 = random_noise(d2, mode="gaussian", mean=0, var=0.01, rng=g)
    _, g = np.random.default_rng(seed).spawn(2)
    d3 = random_noise(b, mode="gaussian", mean=0, var=0.01, rng=g)
    for group, ref in (("D2", d2), ("D3", d3), ("D4", d4)):
        out = paper_degrade(img, group, rng=seed)
        assert out.dtype == np.float32
        assert_array_equal(out, ref.astype(np.float32), err_msg=group)


def test_poisson_scale_is_256_for_8bit_data():
    # as in skimage's random_noise: vals = 2^ceil(log2(#distinct)) = 256 with 8-bit data (here 200
    # distinct values)
    b = (np.arange(200 * 50) % 200 / 255.0).reshape(100, 100)
    out = poisson_noise(b, rng=1).astype(np.float64)
    assert_array_equal(out * 256, np.rint(out * 256))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_noise_functions_equal_random_noise(dtype):
    rng = np.random.default_rng(11)
    on_grid = (rng.integers(0, 256, (40, 50, 3)) / 255).astype(dtype)
    off_grid = rng.random((40, 50, 3)).astype(dtype)  # np.unique path, vals = 2^13
    for img in (on_grid, off_grid):
        assert_array_equal(poisson_noise(img, rng=5), random_noise(img, mode="poisson", rng=5).astype(np.float32))
        assert_array_equal(gaussian_noise(img, rng=5), random_noise(img, mode="gaussian", rng=5).astype(np.float32))
        assert_array_equal(gaussian_noise(img, var=0.03, mean=0.1, rng=5),
                           random_noise(img, mode="gaussian", var=0.03, mean=0.1, rng=5).astype(np.float32))


def clipped_gaussian_mse(b, c, sigma):
    """E[(clip(b + z, 0, 1) − c)²], z ~ N(0, σ²), in closed form (truncated-normal moments)."""
    lo, hi = -b / sigma, (1 - b) / sigma
    mass = stats.norm.cdf(hi) - stats.norm.cdf(lo)
    d = b - c
    inner = (d**2 * mass + 2 * d * sigma * (stats.norm.pdf(lo) - stats.norm.pdf(hi))
             + sigma**2 * (mass - hi * stats.norm.pdf(hi) + lo * stats.norm.pdf(lo)))
    return c**2 * stats.norm.cdf(lo) + (1 - c) ** 2 * stats.norm.sf(hi) + inner


def test_d3_error_matches_closed_form():
    # on black pixels clipping at 0 halves the noise power (MSE 0.005, not 0.01)
    img = render(shape=(192, 256, 3), seed=4)
    b = paper_blur(img).astype(np.float64)
    expected = clipped_gaussian_mse(b, img.astype(np.float64), 0.1)
    assert_allclose(clipped_gaussian_mse(np.zeros(1), np.zeros(1), 0.1), 0.005, rtol=1e-12)
    err2 = (paper_degrade(img, "D3", rng=9).astype(np.float64) - img) ** 2
    assert abs(err2.mean() - expected.mean()) < 5 * err2.std() / np.sqrt(err2.size)


def test_same_seed_same_bytes():
    img = render()
    a = paper_degrade(img, "D4", rng=3)
    assert a.tobytes() == paper_degrade(img, "D4", rng=np.random.default_rng(3)).tobytes()
    assert a.tobytes() != paper_degrade(img, "D4", rng=4).tobytes()


def test_config_changes_blur():
    img = render()
    assert not np.array_equal(paper_blur(img, PaperConfig(length_px=5.0)), paper_blur(img))
    assert_array_equal(paper_blur(img, PaperConfig(length_px=0.0)), img)  # 8-bit input, no blur


def test_errors():
    img = render()
    with pytest.raises(ValueError, match="group must be one of"):
        paper_degrade(img, "D5", rng=0)
    with pytest.raises(ValueError, match="image must be <= 1"):
        paper_degrade(img * 2, rng=0)
    with pytest.raises(ValueError, match="image must be finite"):
        paper_degrade(np.full((4, 4), np.nan, np.float32), rng=0)
    with pytest.raises(ValueError, match="gaussian_var"):
        PaperConfig(gaussian_var=-1.0)
    with pytest.raises(ValueError, match="config must be a PaperConfig"):
        paper_blur(img, {"length_px": 3})
