"""convolve_image against scipy.ndimage.convolve, and delta images against their PSF."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import ndimage

from degrade import convolve_image, psf

RNG = np.random.default_rng(20240601)


def reference(img, kernel, mode):
    """scipy.ndimage.convolve per channel in float64 (kernel (K1, K2) or (C, K1, K2))."""
    img = img.astype(np.float64)
    if img.ndim == 2:
        return ndimage.convolve(img, kernel, mode=mode)
    kernels = kernel if kernel.ndim == 3 else [kernel] * img.shape[2]
    return np.stack([ndimage.convolve(img[..., c], kernels[c], mode=mode) for c in range(img.shape[2])], -1)


@pytest.mark.parametrize("method", ["direct", "fft", "auto"])
@pytest.mark.parametrize("mode", ["reflect", "mirror"])
@pytest.mark.parametrize("shape", [(37, 52), (41, 36, 3)])
@pytest.mark.parametrize("kshape", [(3, 5), (9, 7), (1, 1)])
def test_matches_ndimage(method, mode, shape, kshape):
    img = RNG.random(shape, dtype=np.float32)
    kernel = RNG.random(kshape)  # asymmetric: catches a flipped (correlation) kernel
    kernel /= kernel.sum()
    out = convolve_image(img, kernel, mode=mode, method=method)
    assert out.dtype == np.float32 and out.shape == img.shape
    assert_allclose(out, reference(img, kernel, mode), rtol=0, atol=2e-6)


@pytest.mark.parametrize("method", ["direct", "fft"])
def test_per_channel_kernels(method):
    img = RNG.random((30, 44, 3), dtype=np.float32)
    kernels = RNG.random((3, 5, 7))
    kernels /= kernels.sum(axis=(1, 2), keepdims=True)
    out = convolve_image(img, kernels, method=method)
    assert_allclose(out, reference(img, kernels, "reflect"), rtol=0, atol=2e-6)


@pytest.mark.parametrize("method", ["direct", "fft"])
def test_sparse_asymmetric_kernels(method):
    # zeros that are not point-symmetric: the direct path must take its taps from the flipped
    # kernel (a one-sided shift kernel once came out as all zeros)
    img = RNG.random((20, 30, 3), dtype=np.float32)
    shift = np.zeros((3, 5))
    shift[0, 0], shift[1, 3] = 1.0, 0.5
    kernels = np.stack([shift, shift[::-1], shift[:, ::-1]])
    assert_allclose(convolve_image(img, shift, method=method), reference(img, shift, "reflect"), atol=2e-6)
    assert_allclose(convolve_image(img, kernels, method=method), reference(img, kernels, "reflect"), atol=2e-6)


def test_kernel_larger_than_image_mirror():
    img = RNG.random((6, 5), dtype=np.float32)
    kernel = psf.motion_psf(15.0, 30.0)  # 19×19 on a 6×5 image
    for mode in ("reflect", "mirror"):
        for method in ("direct", "fft"):
            assert_allclose(convolve_image(img, kernel, mode=mode, method=method),
                            reference(img, kernel, mode), atol=2e-6)


@pytest.mark.parametrize("method", ["direct", "fft"])
def test_delta_image_returns_the_psf(method):
    h = psf.compose(psf.airy_psf(1e-3, 600e-9, 4e-3, 3.45e-6), psf.defocus_psf(2.2), psf.motion_psf(8.0, 30.0))
    img = np.zeros((41, 45), np.float32)
    img[20, 22] = 1.0
    out = convolve_image(img, h, method=method)
    r = h.shape[0] // 2
    assert_allclose(out[20 - r:20 + r + 1, 22 - r:22 + r + 1], h, atol=1e-6)
    assert_allclose(out.sum(), 1.0, atol=1e-5)


def test_fft_output_stays_nonnegative():
    img = np.zeros((64, 64, 3), np.float32)
    img[10:20, 30:40] = 1.0  # large zero areas: FFT round-off would dip below 0
    out = convolve_image(img, psf.compose(psf.gaussian_psf(3.0), psf.motion_psf(20.0, 10.0)), method="fft")
    assert out.min() >= 0.0


def test_float64_input_gives_float32_and_input_untouched():
    img = RNG.random((20, 21, 3))
    before = img.copy()
    out = convolve_image(img, psf.gaussian_psf(1.0))
    assert out.dtype == np.float32
    np.testing.assert_array_equal(img, before)


@pytest.mark.parametrize("bad, match", [
    (np.full((8, 8), np.nan, np.float32), "image must be finite"),
    (np.full((8, 8), np.inf, np.float32), "image must be finite"),
    (-np.ones((8, 8), np.float32), "image must be >= 0"),
    (np.ones((8, 8), np.uint8), "image must be a float array"),
    (np.ones((8, 8, 3, 2), np.float32), "image must have 2 or 3 dimensions"),
])
def test_bad_images_raise(bad, match):
    with pytest.raises(ValueError, match=match):
        convolve_image(bad, np.ones((3, 3)) / 9)


def test_bad_kernels_and_options_raise():
    img = np.ones((8, 8, 3), np.float32)
    with pytest.raises(ValueError, match="odd"):
        convolve_image(img, np.ones((2, 3)))
    with pytest.raises(ValueError, match="kernel must have shape"):
        convolve_image(img, np.ones((2, 3, 3)))
    with pytest.raises(ValueError, match="kernel must be finite"):
        convolve_image(img, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="mode must be one of"):
        convolve_image(img, np.ones((3, 3)), mode="wrap")
    with pytest.raises(ValueError, match="method must be one of"):
        convolve_image(img, np.ones((3, 3)), method="magic")


@pytest.mark.parametrize("shape, per_channel", [((29, 43, 3), False), ((29, 43, 3), True), ((31, 22), False)])
def test_direct_is_float32_taps_added_in_order(shape, per_channel):
    """The direct kernels against NumPy adding w_t · shifted image in float32, tap after tap in
    the flipped kernel's C order from 0: the same bits (so no regrouping or fused multiply-add)."""
    channels = shape[2] if len(shape) == 3 else 1
    img = RNG.random(shape, dtype=np.float32)
    k = RNG.random((channels if per_channel else 1, 5, 7))  # 35 taps: 8 groups of four and 3 more
    k[:, 1, 2] = 0.0  # a zero tap is skipped
    out = convolve_image(img, k if per_channel else k[0], method="direct")
    pad = np.pad(img.reshape(*shape[:2], channels), ((2, 2), (3, 3), (0, 0)), mode="symmetric")
    kf = k[:, ::-1, ::-1].astype(np.float32)
    ref = np.zeros((*shape[:2], channels), np.float32)
    for i in range(5):
        for j in range(7):
            if np.any(kf[:, i, j] != 0):
                ref += kf[:, i, j] * pad[i:i + shape[0], j:j + shape[1]]
    assert out.tobytes() == ref.reshape(shape).tobytes()


@pytest.mark.parametrize("mode", ["reflect", "mirror"])
@pytest.mark.parametrize("shape", [(29, 43, 3), (30, 8, 3), (5, 4, 3)])
@pytest.mark.parametrize("per_channel", [False, True])
def test_rggb_sites_are_the_mosaic_of_the_direct_convolution(mode, shape, per_channel):
    """Only the channel each RGGB photosite keeps, convolved at the sites: the same bits as the
    mosaic of the whole direct convolution (also with a tap that is zero in one channel only),
    and close to scipy.ndimage's float64 convolution at the sites."""
    from degrade.convolve import _convolve_sites
    from degrade.sensor import mosaic_rggb
    img = RNG.random(shape, dtype=np.float32)
    k = RNG.random((3 if per_channel else 1, 7, 5))  # 35 taps: 8 groups of four and 3 more
    k[:, 0, 0] = 0.0
    if per_channel:
        k[2, :, 0] = 0.0  # blue only: a narrower kernel inside the stack
    kernel = k if per_channel else k[0]
    sites = _convolve_sites(img, kernel, mode)
    assert sites.dtype == np.float32 and sites.shape == shape[:2]
    assert sites.tobytes() == mosaic_rggb(convolve_image(img, kernel, mode=mode, method="direct")).tobytes()
    assert_allclose(sites, mosaic_rggb(reference(img, kernel, mode)), rtol=2e-6, atol=1e-6)


def test_rggb_sites_decline_what_the_direct_path_does_not_do():
    from degrade.convolve import _convolve_sites
    img = RNG.random((20, 20, 3), dtype=np.float32)
    assert _convolve_sites(img, np.ones((1, 1)), "reflect") is None  # a scale: no convolution
    assert _convolve_sites(img, np.ones((31, 31)), "reflect") is None  # FFT-sized kernel
    assert _convolve_sites(img[:3], np.ones((7, 7)), "reflect") is None  # 3 rows ≤ radius 3
