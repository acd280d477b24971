"""Sample patterns: the sub-pixel samples of anti-aliased pixels (raytrace._edges.subpixel_rays)
and the final gather's directions (gather_rays):
correlated multi-jittered (Kensler 2013) — one sample per coarse cell and per fine row and
column of the domain, uniform over it across seeds."""
import numpy as np
import pytest

from raytrace import _edges, _gather, _lights, _sampling, _surface, brdf
from raytrace.camera import Camera

FX, FY, CX, CY, W = 800.0, 700.0, 40.0, 30.0, 80


def _offsets(pix, n, seed):
    """Sub-pixel offsets (du, dv) in [-0.5, 0.5) of the rays of pixels ``pix``, read back from
    their directions through the pinhole (identity pose)."""
    pix = np.asarray(pix, dtype=np.int64)
    d = np.empty((len(pix) * n * n, 3))
    _edges.subpixel_rays(pix, W, n, seed, np.eye(3), FX, FY, CX, CY, *Camera().lens_arrays(), d)
    u = d[:, 0] / d[:, 2] * FX + CX
    v = d[:, 1] / d[:, 2] * FY + CY
    pu = np.repeat(pix % W, n * n)
    pv = np.repeat(pix // W, n * n)
    return (u - pu).reshape(len(pix), n * n), (v - pv).reshape(len(pix), n * n)


@pytest.mark.parametrize("n", [1, 3, 4, 6, 8])
def test_every_coarse_cell_and_every_fine_row_and_column_holds_one_sample(n):
    du, dv = _offsets([0, 17, 1234, 5555], n, seed=3)
    assert np.all((du >= -0.5) & (du < 0.5) & (dv >= -0.5) & (dv < 0.5))
    for a, b in zip(du, dv):
        x, y = a + 0.5, b + 0.5
        coarse = np.floor(x * n).astype(int) + n * np.floor(y * n).astype(int)
        assert sorted(coarse) == list(range(n * n))  # jittered stratification
        assert sorted(np.floor(x * n * n).astype(int)) == list(range(n * n))  # n-rooks in u
        assert sorted(np.floor(y * n * n).astype(int)) == list(range(n * n))  # n-rooks in v


def test_pattern_is_uniform_over_the_pixel_across_seeds_and_differs_between_pixels():
    n = 4
    xs = np.concatenate([_offsets([321], n, seed=s)[0].ravel() for s in range(400)]) + 0.5
    # each of 64 bins of width 1/64 (four per fine column of 1/16, which holds one sample per
    # seed) gets 1/64 of the samples: χ² of 6400 draws with the fine columns' totals fixed,
    # 48 d.o.f.; a jitter that is not uniform within the fine cell (e.g. always its middle)
    # gives far more than 48 ± 3·10
    counts = np.bincount(np.floor(xs * 64).astype(int), minlength=64)
    assert counts.sum() == 6400
    chi2 = ((counts - 100.0) ** 2 / 100.0).sum()
    assert 20.0 < chi2 < 110.0
    a = _offsets([100, 101], n, seed=5)[0]
    assert not np.allclose(np.sort(a[0]), np.sort(a[1]))
    assert np.array_equal(_offsets([100], n, seed=5)[0], _offsets([100], n, seed=5)[0])


@pytest.mark.parametrize("n_rays", [4, 8, 16, 32])
def test_final_gather_directions_are_multi_jittered_in_radius_squared_and_azimuth(n_rays):
    """raytrace._gather.gather_rays about the normal +z: u1 = 1 − cos²θ (the squared radius
    on the unit disc) and u2 = φ / 2π of each point's rays fall one per cell of the gx × gy
    grid and one per fine row and column of the n_rays × n_rays grid."""
    n_pts = 5
    P = np.zeros((n_pts, 3))
    N = np.tile([0.0, 0.0, 1.0], (n_pts, 1))
    o = np.empty((n_pts * n_rays, 3))
    d = np.empty((n_pts * n_rays, 3))
    start = np.arange(n_pts + 1, dtype=np.int64) * n_rays
    _gather.gather_rays(P, N, N, start, 0, 9, np.arange(100, 100 + n_pts, dtype=np.int64), 0, 0,
                        1e-6, o, d)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    u1 = (1.0 - d[:, 2] ** 2).reshape(n_pts, n_rays)
    u2 = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi) % 1.0).reshape(n_pts, n_rays)
    gx = int(np.sqrt(n_rays))
    while n_rays % gx:
        gx -= 1
    gy = n_rays // gx
    for a, b in zip(u1, u2):
        cell = np.floor(a * gx).astype(int) + gx * np.floor(b * gy).astype(int)
        assert sorted(cell) == list(range(n_rays))
        assert sorted(np.floor(a * n_rays).astype(int)) == list(range(n_rays))
        assert sorted(np.floor(b * n_rays).astype(int)) == list(range(n_rays))


@pytest.mark.parametrize("n", [1, 2, 5, 16, 36, 100, 257])
def test_hash_permutation_is_a_permutation_and_depends_on_its_key(n):
    """raytrace._sampling.permute (Kensler 2013, §3): for every key, i ↦ permute(i, n, key)
    maps 0 … n − 1 onto itself one to one; different keys give different orders."""
    orders = set()
    for key in (0, 1, 7, 0x9E3779B9, 0xFFFFFFFF, 123456789):
        perm = [_sampling.permute(i, n, key) for i in range(n)]
        assert sorted(perm) == list(range(n))
        orders.add(tuple(perm))
    if n >= 5:
        assert len(orders) >= 5


def _disc_strata(pixels, n, seed):
    """Stratum (a, b) of the (1 − cos θ, φ) grid of sun_disc_dirs for sample j of each pixel,
    read back from the directions about the Sun at +z."""
    half = 0.0046
    pixel = np.repeat(np.asarray(pixels, dtype=np.int64), n)
    number = np.tile(np.arange(n, dtype=np.int64), len(pixels))
    d = np.empty((len(pixel), 3))
    sun = _lights.sun_record((0.0, 0.0, 1.0), 1361.0, 2 * half)
    _surface.sun_disc_dirs(pixel, number, n, seed, sun, d)
    gx = _sampling._strata(n)
    gy = n // gx
    u1 = (1.0 - d[:, 2]) / (1.0 - np.cos(half))
    u2 = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    # the azimuth is measured from the basis raytrace.brdf.onb builds about the Sun
    t = brdf.onb(0.0, 0.0, 1.0)
    u2 = (u2 - np.arctan2(t[1], t[0]) / (2 * np.pi)) % 1.0
    a = np.minimum(np.floor(u1 * gx), gx - 1).astype(int)
    b = np.minimum(np.floor(u2 * gy), gy - 1).astype(int)
    return a.reshape(len(pixels), n), b.reshape(len(pixels), n), gx, gy


def test_solar_disc_samples_are_stratified_per_pixel_and_independent_of_the_sub_pixel_cell():
    """The S solar-disc samples of a pixel's S sub-samples fill the S strata of the disc, one
    each, and which stratum sample j takes does not follow from j (which also fixes its
    sub-pixel cell, subpixel_rays): over 600 pixels, sample j's radial stratum is spread evenly
    over the gx rings (χ² per j), where taking stratum j would always put it in ring j mod gx."""
    n = 36
    a, b, gx, gy = _disc_strata(np.arange(600) * 7 + 3, n, seed=4)
    for k in range(len(a)):
        assert sorted(a[k] + gx * b[k]) == list(range(n))
    chi2 = []
    for j in range(n):
        counts = np.bincount(a[:, j], minlength=gx)
        e = len(a) / gx
        chi2.append(((counts - e) ** 2 / e).sum())
    # 5 d.o.f. each: mean 5; ring = j mod gx would give 3000
    assert 2.0 < np.mean(chi2) < 9.0
    assert max(chi2) < 30.0
