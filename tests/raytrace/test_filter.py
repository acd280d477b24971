"""The residual filter of ``balanced`` (raytrace._filter.atrous) and the per-pixel
variance that guides it (raytrace._gather.gather_sum), against closed forms and against the
spread of independent estimates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.shade import _atrous_passes, _Context, _filter_residual, _surfaces, render

from .test_shading import CAM, _form_factor_to_floor, _plates, _pose

H, W = 40, 60
FX = FY = 500.0
CX, CY = W / 2, H / 2
# the B3-spline taps of one pass
TAPS = np.array([1, 4, 6, 4, 1]) / 16.0


def _flat_plane():
    """AOVs of a plane facing the camera at 10 m: one part, equal normals and depths."""
    inst = np.ones((H, W), dtype=np.uint16)
    normal = np.zeros((H, W, 3))
    normal[..., 2] = -1.0
    depth = np.full((H, W), 10.0)
    return inst, normal, depth


def _guided(img, var, passes, sigma_l=4.0):
    inst, normal, depth = _flat_plane()
    return _atrous_passes(img, var, inst, (normal, depth, FX, FY, CX, CY, *Camera().lens_arrays()), passes, sigma_l)


def _geometric(img, passes):
    return _guided(img, np.zeros((H, W)), passes, sigma_l=0.0)[0]


def test_variance_is_carried_through_a_pass_as_sum_of_squared_weights():
    # a constant image: every weight is the B3 tap product, so an interior pixel's variance
    # becomes v (Σ h²)² exactly, and the image is unchanged
    img = np.full((H, W, 3), 2.5)
    var = np.full((H, W), 0.3)
    out, out_var = _guided(img, var, 1)
    np.testing.assert_allclose(out, 2.5, rtol=1e-12)
    inner = (slice(2, H - 2), slice(2, W - 2))
    np.testing.assert_allclose(out_var[inner], 0.3 * (TAPS ** 2).sum() ** 2, rtol=1e-12)


def test_a_step_larger_than_the_noise_is_kept_and_noise_is_smoothed():
    rng = np.random.default_rng(1)
    sd = 0.1
    truth = np.where(np.arange(W) < W // 2, 0.0, 5.0)[None, :, None] * np.ones((H, 1, 3))
    img = truth + rng.normal(0.0, sd, (H, W, 1))
    var = np.full((H, W), sd * sd)
    guided, _ = _guided(img, var, 2)
    geometric = _geometric(img, 2)
    cols = slice(W // 2 - 3, W // 2 + 3)  # the step's neighbourhood
    rows = slice(4, H - 4)
    # the geometry-only filter blurs the step by a large fraction of its height ...
    assert np.abs(geometric[rows, cols] - truth[rows, cols]).max() > 1.0
    # ... the guided one keeps it to within the noise
    assert np.abs(guided[rows, cols] - truth[rows, cols]).max() < 4 * sd
    # and still smooths the noise away from it
    flat = (rows, slice(4, W // 2 - 6))
    assert np.std(guided[flat][..., 0] - truth[flat][..., 0]) < 0.6 * sd


def test_heavy_tailed_noise_is_smoothed_without_losing_energy():
    # each pixel averages n rays of which a few hit a bright part: a Bernoulli estimate with
    # its own sample variance, the noise of a final gather in a mostly unlit place. A filter
    # whose neighbours refuse a bright pixel's energy (one-sided edge stopping) darkens the
    # image; the symmetric z-score keeps the mean.
    rng = np.random.default_rng(7)
    n, p, value = 16, 0.05, 100.0
    hits = rng.binomial(n, p, (H, W))
    mean = hits / n * value
    var = (value ** 2 * hits * (1 - hits / n) / (n - 1)) / n  # s²/n of the n Bernoulli terms
    img = np.repeat(mean[..., None], 3, axis=2)
    out, _ = _guided(img, var, 2)
    truth = p * value
    inner = (slice(4, H - 4), slice(4, W - 4))
    assert out[inner].mean() == pytest.approx(img[inner].mean(), rel=0.03)
    assert np.sqrt(((out[inner] - truth) ** 2).mean()) < 0.6 * np.sqrt(((img[inner] - truth) ** 2).mean())


def _two_parts():
    """The plane of :func:`_flat_plane` split into two parts at column W // 2."""
    inst, normal, depth = _flat_plane()
    inst[:, W // 2:] = 2
    return inst, normal, depth


@pytest.mark.parametrize("passes", [1, 2])
def test_local_linear_filter_keeps_a_ramp_at_a_part_edge_where_the_weighted_mean_cannot(passes):
    # a residual rising linearly towards a part edge (the light of the neighbouring part, a
    # contact shadow): the weighted mean over a one-sided kernel at the edge is low by the
    # ramp's slope times the kernel's offset; the local-linear estimate is the ramp itself
    inst, normal, depth = _two_parts()
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    truth = np.where(inst == 1, 0.3 * uu + 0.1 * vv, 2.0 - 0.05 * uu)[..., None] * np.array([1.0, 0.5, 0.25])
    at = np.nonzero(inst > 0)
    var = np.full(len(at[0]), 0.01)
    guide = (normal, depth, FX, FY, CX, CY, *Camera().lens_arrays())
    rows = truth[at]
    edge = (at[1] == W // 2 - 1) & (at[0] >= 4) & (at[0] < H - 4)  # the last column of part 1, inner rows
    mean_only = _filter_residual(rows, var, inst, at, guide, passes, 0.0)
    linear = _filter_residual(rows, var, inst, at, guide, passes, 0.0, linear=1.0)
    # the one-sided kernel's centroid is ≥ 6/11 px inside the part (one pass: taps 1, 4, 6 of
    # 16 at −2, −1, 0), so the mean is low by ≥ 0.3 × 6/11 at the edge
    assert np.all(truth[at][edge, 0] - mean_only[edge, 0] > 0.16)
    # the plane is exact up to the ridge's pull on its slope (0.01 px² against the kernel's
    # spread: ≤ 0.005 at the image's corners and the part edge, where the kernel is one-sided; the
    # weighted mean is off by 0.16–1.3 at the edge)
    np.testing.assert_allclose(linear, rows, rtol=1e-3, atol=1e-2)
    assert np.abs(linear - rows)[edge].max() < 5e-3
    # β scales the slope: halfway between the mean and the plane
    half = _filter_residual(rows, var, inst, at, guide, passes, 0.0, linear=0.5)
    np.testing.assert_allclose(half, 0.5 * (mean_only + linear), rtol=1e-9, atol=1e-12)


def test_local_linear_filter_of_pure_noise_is_unbiased_and_still_smooths():
    rng = np.random.default_rng(7)
    inst, normal, depth = _two_parts()
    at = np.nonzero(inst > 0)
    sd = 1.0
    guide = (normal, depth, FX, FY, CX, CY, *Camera().lens_arrays())
    outs = []
    for _ in range(40):
        rows = rng.normal(0.0, sd, (len(at[0]), 3))
        outs.append(_filter_residual(rows, np.full(len(at[0]), sd * sd), inst, at, guide, 2, 3.0, linear=0.7))
    outs = np.array(outs)
    # mean over 40 frames × 2400 pixels × 3 channels: 0 within 5 standard errors of a smoothed
    # estimate (its sd ≤ sd), and the per-pixel spread well below the input's
    assert abs(outs.mean()) < 5 * sd / np.sqrt(outs.size / 25)
    assert outs.std() < 0.6 * sd


def test_gather_variance_matches_the_spread_of_independent_estimates():
    # plate B lit only by sunlight bounced off plate A: the gather's noise is its hits on A
    scene = _plates(1.0, 0.5)
    R, t = _pose(np.array([4.0, -0.3, 1.2]))
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=1000.0)
    geo = scene.render_geometry(CAM, R, t)
    ctx = _Context(scene, light, {})
    pix = np.flatnonzero(geo.instance.ravel() == 2)[::7][:200]
    u = (pix % CAM.width).astype(float)
    v = (pix // CAM.width).astype(float)
    D_cam = np.column_stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(len(pix))])
    D = D_cam @ R  # body frame: R.T @ d for each row
    O = np.broadcast_to(-R.T @ t, D.shape).copy()
    s = _surfaces(ctx.scene, O, D, geo.face_index.ravel()[pix].astype(np.int64))
    luma = np.array([0.2126, 0.7152, 0.0722])
    n_rays, n_seeds = 16, 40
    Y = np.empty((n_seeds, len(pix)))
    V = np.empty((n_seeds, len(pix)))
    for seed in range(n_seeds):
        var = np.empty(len(pix))
        Y[seed] = ctx.gather_E(s, n_rays, pix.astype(np.int64), seed, var) @ luma
        V[seed] = var
    assert Y.std() > 0.0 and V.mean() > 0.0
    # E[s²/N] is the variance of the mean of N independent terms; the gather's rays are
    # multi-jittered over the hemisphere, which can only lower the spread of the seeds'
    # estimates (here by 5.7×; 1.7× with plain jittered strata), so the reported variance is a
    # bound from above
    var_seeds = Y.var(axis=0, ddof=1)
    assert V.mean() >= var_seeds.mean()
    # and it is the right one: each of the N strata of a pixel's pattern holds one ray, so the
    # N terms together are a uniform draw over the hemisphere and E[Σ (t_j − t̄)²] = N σ² −
    # N Var(t̄), with σ² the variance of a single uniformly drawn ray's term: E[s²/N] =
    # (σ² − Var(t̄)) / (N − 1). σ² measured apart, from one-ray gathers over many seeds (a lost
    # π² or 1/N, or N for N − 1, is off by 6.7 % or more; measured 0.7 %)
    Y1 = np.array([ctx.gather_E(s, 1, pix.astype(np.int64), 1000 + seed) @ luma for seed in range(300)])
    expected = (Y1.var(axis=0, ddof=1) - var_seeds) / (n_rays - 1)
    assert V.mean() == pytest.approx(expected.mean(), rel=0.05), (V.mean(), expected.mean())


@pytest.mark.parametrize("samples", [1, 8])
def test_few_gather_rays_are_still_smoothed_per_pixel(samples):
    # with one gather ray a pixel has no variance of its own to guide the filter, which must
    # then fall back to the geometry alone: each pixel of plate B, lit by plate A's bounce,
    # is near the analytic first bounce, 25 % RMS (one unfiltered ray per pixel is off by
    # ~100 %: it finds A's sunlit face or not)
    rho_a, rho_b, e = 1.0, 0.1, 1000.0
    scene = _plates(rho_a, rho_b)
    R, t = _pose(np.array([4.0, -0.3, 1.2]))
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=e)
    frame = render(scene, CAM, R, t, light, quality="balanced", samples=samples, seed=5)
    geo = frame.geometry
    v, u = np.nonzero(binary_erosion(geo.instance == 2, iterations=6))
    rel = []
    for k in np.linspace(0, len(u) - 1, 25).astype(int):
        z_c = float(geo.depth_m[v[k], u[k]])
        p_cam = np.array([(u[k] - CAM.cx) / CAM.fx * z_c, (v[k] - CAM.cy) / CAM.fy * z_c, z_c])
        p = R.T @ (p_cam - t)
        expect = rho_b / np.pi * rho_a * e * _form_factor_to_floor(p[1], p[2])
        rel.append(float(frame.radiance[v[k], u[k], 0]) / expect - 1.0)
    # measured: 13 % RMS at one ray (geometry-only filter), 171 % if that pixel's zero
    # variance were allowed to guide the filter
    assert np.sqrt(np.mean(np.square(rel))) < 0.25, rel


_FILTER_RUN = """
import sys
import numpy as np
from raytrace import _filter
from raytrace.camera import Camera
from raytrace.shade import _atrous_passes
rng = np.random.default_rng(0)
H, W = 96, 128
inst = np.ones((H, W), np.uint16)
inst[:, :40] = 2
inst[:8] = 0
img = rng.normal(size=(H, W, 3))
var = rng.uniform(0.1, 1.0, (H, W))
normal = np.zeros((H, W, 3))
normal[..., 2] = -1.0
normal[..., 0] = rng.normal(scale=0.05, size=(H, W))
normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
depth = rng.uniform(9.0, 11.0, (H, W))
out, out_var = _atrous_passes(img, var, inst, (normal, depth, 500.0, 500.0, 64.0, 48.0, *Camera().lens_arrays()), 2,
                              4.0)
np.save(sys.argv[1], np.concatenate([out.ravel(), out_var.ravel()]))
"""


def test_filter_gives_the_same_bits_compiled_fresh_and_loaded_from_numba_cache(tmp_path):
    """The same seed must give the same bytes whether numba compiles the kernels in this run
    or loads them from its cache. With fastmath the à-trous kernel did not: the code numba
    cached and the code it had just compiled rounded differently (1e-15 here; after the
    filter's edge-stopping weights, 57 pixels of a Tiangong frame by up to 0.012 W/(m²·sr)), so
    the first render after an install differed from every later one. The filter kernels are
    compiled without fastmath; this runs them twice in a fresh cache folder, compiling then
    loading."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    outs = []
    for k in range(2):
        path = tmp_path / f"out{k}.npy"
        subprocess.run([sys.executable, "-c", _FILTER_RUN, str(path)], check=True, env=env, cwd=root)
        outs.append(path.read_bytes())
    assert any((tmp_path / "numba").rglob("*.nbc")), "the first run wrote no numba cache"
    assert outs[0] == outs[1]
