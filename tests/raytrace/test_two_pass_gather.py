"""The two-pass final gather (``Quality.pilot_rays``, raytrace.shade._gather_two_pass) and its
kernels, against independent answers:

* allocate_rays: the continuous Neyman allocation with costs (n ∝ σ/√c at a fixed total cost),
  solved here with scipy's root finder, and the variance it promises against an even split;
* same_part_mean: a direct loop over the neighbourhood;
* filter_variance: the closed forms of one pass inside a part and along a strip one pixel
  wide, the variance channel of the à-trous filter itself (raytrace._filter.atrous on a flat
  guide), and, for one pass, the spread of the filtered noise over many noise images;
* the two-pass estimate of the irradiance a dark plate receives from a lit perpendicular
  plate: its mean over seeds against the one-pass gather's mean (both unbiased) and against
  the analytic form factor, its spread over seeds against the one pass's; with the filter's
  passes steering the allocation, the same mean, and more rays on the plate's border.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy import integrate, optimize

from raytrace import _context, _filter, _gather, _sampling, shade
from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene


def test_allocation_matches_the_continuous_neyman_optimum_with_costs():
    rng = np.random.default_rng(4)
    n = 500
    sig = rng.lognormal(0.0, 1.0, n)
    cost = 1.0 + 3.0 * rng.random(n)
    n_min, n_max, n_avg = 4, 128, 16
    budget = n_avg * cost.sum()
    out = np.empty(n, dtype=np.int64)
    _gather.allocate_rays(sig, cost, n_min, n_max, budget, out)
    assert out.min() >= n_min and out.max() <= n_max
    assert (cost * out).sum() <= budget
    assert (cost * out).sum() >= budget - cost.max() * n * 0.02  # the budget is used, up to rounding

    w = sig / np.sqrt(cost)

    def spent(c):
        return (cost * np.clip(c * w, n_min, n_max)).sum() - budget

    c = optimize.brentq(spent, 1e-9, 1e6)
    ideal = np.clip(c * w, n_min, n_max)
    # rounding moves each point by at most about one ray from the continuous optimum
    assert np.abs(out - ideal).max() <= 1.5
    # and the summed variance Σ σ²/n is the continuous optimum's, far below an even split's
    # at the same cost
    even = budget / cost.sum()
    assert (sig ** 2 / out).sum() == pytest.approx((sig ** 2 / ideal).sum(), rel=0.03)
    assert (sig ** 2 / out).sum() < 0.7 * (sig ** 2 / even).sum()


def test_allocation_without_any_noise_is_an_even_split():
    out = np.empty(10, dtype=np.int64)
    _gather.allocate_rays(np.zeros(10), np.full(10, 2.0), 4, 64, 16 * 20.0, out)
    assert np.all(out == 16)


def test_same_part_mean_is_the_mean_of_the_other_pixels_of_the_same_part():
    rng = np.random.default_rng(1)
    inst = rng.integers(0, 3, (17, 23)).astype(np.uint16)
    inst[5, 5] = 7  # a part of one pixel: its own value
    img = rng.random(inst.shape)
    out = np.full(inst.shape, -1.0)
    r = 2
    _filter.same_part_mean(img, inst, r, out)
    H, W = inst.shape
    for v in range(H):
        for u in range(W):
            if inst[v, u] == 0:
                assert out[v, u] == -1.0
                continue
            vals = [img[vv, uu] for vv in range(v - r, v + r + 1) for uu in range(u - r, u + r + 1)
                    if 0 <= vv < H and 0 <= uu < W and (vv, uu) != (v, u) and inst[vv, uu] == inst[v, u]]
            want = np.mean(vals) if vals else img[v, u]
            assert out[v, u] == pytest.approx(want, rel=1e-12)


def _gather_u(counts, first, seed=9, pix=None, share=0):
    """(u1, u2) ∈ [0, 1)² of the rays of gather_rays about +z: u1 = 1 − cos²θ, u2 = φ / 2π
    (points keyed by ``pix``, default 100, 101, …)."""
    counts = np.asarray(counts, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)])
    n_pts = len(counts)
    P = np.zeros((n_pts, 3))
    N = np.tile([0.0, 0.0, 1.0], (n_pts, 1))
    o = np.empty((start[-1], 3))
    d = np.empty((start[-1], 3))
    pix = np.arange(100, 100 + n_pts, dtype=np.int64) if pix is None else np.asarray(pix, dtype=np.int64)
    _gather.gather_rays(P, N, N, start, first, seed, pix, share, int(counts.max()), 1e-6, o, d)
    u1 = 1.0 - d[:, 2] ** 2
    u2 = np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi) % 1.0
    return [(u1[start[k]:start[k + 1]], u2[start[k]:start[k + 1]]) for k in range(n_pts)]


def _is_net(u1, u2):
    """Whether the 2^m points are a (0, m, 2)-net: one in each cell of every 2^a × 2^(m−a) grid."""
    n = len(u1)
    m = int(round(math.log2(n)))
    assert 2 ** m == n
    return all(sorted(np.floor(u1 * 2 ** a).astype(int) + 2 ** a * np.floor(u2 * 2 ** (m - a)).astype(int))
               == list(range(n)) for a in range(m + 1))


def test_unscrambled_sequence_is_scipys_sobol():
    """The two dimensions under the scrambling (radical inverse and the byte-table second
    dimension) are the first two of scipy's Sobol sequence, which lists point gray(k) as its
    k-th (Gray-code order, gray(k) = k XOR k >> 1)."""
    from scipy.stats import qmc
    ref = qmc.Sobol(d=2, scramble=False, bits=32).random_base2(12)
    idx = [k ^ (k >> 1) for k in range(4096)] + [2**32 - 1, 0x9E3779B9, 0x80000001]
    ours = np.array([[_sampling._reverse_bits32(i), _sampling._sobol2_y(i)] for i in idx], dtype=np.float64) / 2.0**32
    np.testing.assert_array_equal(ours[:4096], ref)
    # a full 32-bit index (as the shuffled index is) against the direction-number recursion
    for i, (x, y) in zip(idx[4096:], ours[4096:] * 2.0**32):
        bits = [b for b in range(32) if i >> b & 1]
        m, y_ref = 1, 0
        for b in range(32):
            if b in bits:
                y_ref ^= m << (31 - b)
            m = (m << 1) ^ m
        assert y == y_ref and x == sum(1 << (31 - b) for b in bits)


@pytest.mark.parametrize("n", [1, 2, 4, 8, 16, 32, 64, 128])
def test_gather_directions_are_a_net_at_every_power_of_two(n):
    for u1, u2 in _gather_u([n] * 4, 0):
        assert _is_net(u1, u2)


@pytest.mark.parametrize("n_pilot,total", [(8, 16), (8, 32), (4, 64), (16, 128), (3, 8)])
def test_a_second_pass_fills_the_strata_the_first_left(n_pilot, total):
    """The pilot's n rays (samples 0 … n − 1) and a second pass continuing from sample n are
    together the first `total` samples of one sequence: a net when `total` is a power of 2;
    two independent patterns of those sizes are not."""
    pts = 5
    first = _gather_u([n_pilot] * pts, 0)
    second = _gather_u([total - n_pilot] * pts, n_pilot)
    for (a1, a2), (b1, b2) in zip(first, second):
        assert _is_net(np.concatenate([a1, b1]), np.concatenate([a2, b2]))
    other = _gather_u([total - n_pilot] * pts, 0, seed=10)
    assert not all(_is_net(np.concatenate([a1, b1]), np.concatenate([a2, b2]))
                   for (a1, a2), (b1, b2) in zip(first, other))


@pytest.mark.parametrize("S,rays", [(64, 8), (36, 4), (100, 2)])
def test_the_sub_samples_of_a_pixel_share_its_sequence(S, rays):
    """With ``share`` = S, point pixel · S + i (sub-sample i of a pixel) casts samples i · rays …
    of the pixel's own sequence: each sub-sample's rays are a net, and the sub-samples of a pixel
    together are one (aligned blocks of the index-shuffled sequence), which S independent
    sequences are not; pixels keep sequences of their own."""
    pixels = [7, 8, 1234]
    pix = [p * S + i for p in pixels for i in range(S)]
    shared = _gather_u([rays] * len(pix), 0, pix=pix, share=S)
    for b, p in enumerate(pixels):
        one = _gather_u([S * rays], 0, pix=[p])[0]  # the pixel's sequence as one point casts it
        u1 = np.concatenate([shared[b * S + i][0] for i in range(S)])
        u2 = np.concatenate([shared[b * S + i][1] for i in range(S)])
        np.testing.assert_array_equal(u1, one[0])
        np.testing.assert_array_equal(u2, one[1])
        assert all(_is_net(*shared[b * S + i]) for i in range(S))
        n = 2 ** int(math.log2(S * rays))  # the first power-of-two prefix of the union
        assert _is_net(u1[:n], u2[:n])
    apart = _gather_u([rays] * S, 0, pix=[7 * S + i for i in range(S)])  # a sequence per sub-sample
    assert not _is_net(np.concatenate([a for a, _ in apart])[:n], np.concatenate([b for _, b in apart])[:n])
    assert not np.array_equal(shared[0][0], shared[S][0])


def test_gather_directions_are_uniform_over_seeds():
    u = np.concatenate([np.column_stack(_gather_u([12], 5, seed=s)[0]) for s in range(300)])
    for col in (0, 1):
        hist = np.histogram(u[:, col], bins=10, range=(0, 1))[0]
        assert np.abs(hist / len(u) - 0.1).max() < 0.015


B3 = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0


def _filter_variance_reference(inst, passes):
    """The variance propagation of id-only à-trous passes, written out with NumPy shifts."""
    H, W = inst.shape
    v = (inst > 0).astype(float)
    step = 1
    for _ in range(passes):
        big = 2 * step
        pad_i = np.pad(inst.astype(np.int64), big, constant_values=-1)
        pad_v = np.pad(v, big)
        sw = np.zeros((H, W))
        sw2v = np.zeros((H, W))
        for a in range(5):
            for b in range(5):
                dv, du = (a - 2) * step, (b - 2) * step
                same = pad_i[big + dv:big + dv + H, big + du:big + du + W] == inst
                w = B3[a] * B3[b]
                sw += w * same
                sw2v += w * w * same * pad_v[big + dv:big + dv + H, big + du:big + du + W]
        v = np.where(inst > 0, sw2v / np.where(sw > 0, sw, 1.0) ** 2, 0.0)
        step *= 2
    return v


def _parts_image(rng, H=40, W=50):
    inst = np.zeros((H, W), dtype=np.uint16)
    inst[3:30, 4:30] = 1
    inst[10:20, 20:45] = 2          # overlaps part 1: a shared border
    inst[33, 5:45] = 3              # a strip one pixel wide
    inst[22:38, 40:41] = 4          # and a vertical one
    inst[rng.random((H, W)) < 0.02] = 5  # speckles
    return inst


@pytest.mark.parametrize("passes", [0, 1, 2, 3])
def test_filter_variance_is_the_propagated_variance_of_the_id_only_passes(passes):
    inst = _parts_image(np.random.default_rng(3))
    out = np.full(inst.shape, -1.0)
    _filter.filter_variance(inst, passes, out)
    np.testing.assert_allclose(out, _filter_variance_reference(inst, passes), rtol=1e-12, atol=0)
    # and the variance channel of the à-trous filter itself, on a guide whose normals and depths
    # are all alike (its weights are then the B3 kernel on the pixel's own part)
    H, W = inst.shape
    normal = np.zeros((H, W, 3))
    normal[..., 2] = 1.0
    depth = np.full((H, W), 5.0)
    _, var = shade._atrous_passes(np.zeros((H, W, 1)), (inst > 0).astype(float), inst,
                                  (normal, depth, 800.0, 800.0, W / 2, H / 2, *Camera().lens_arrays()), passes, 0.0)
    np.testing.assert_allclose(out[inst > 0], var[inst > 0], rtol=1e-12)


def test_filter_variance_closed_forms_and_the_spread_of_filtered_noise():
    H, W = 30, 60
    inst = np.zeros((H, W), dtype=np.uint16)
    inst[2:20, 2:58] = 1
    inst[25, 2:58] = 2
    out = np.empty((H, W))
    _filter.filter_variance(inst, 1, out)
    s2 = (B3 ** 2).sum()  # 70/256
    # inside a part: Σ w² with Σ w = 1, the 2-d kernel's (Σ h²)²
    assert out[10, 30] == pytest.approx(s2 * s2, rel=1e-12)
    # on a strip one pixel wide only the kernel's middle row counts: Σ w² / (Σ w)² = Σ h²
    assert out[25, 30] == pytest.approx(s2, rel=1e-12)
    # on a part's straight border (rows 2 of 2..19): the rows a = 2..4 of the kernel
    rows = B3[2:]
    assert out[2, 30] == pytest.approx((rows ** 2).sum() * s2 / rows.sum() ** 2, rel=1e-12)
    assert 0.0 == out[0, 0] == out[22, 30]
    # one pass of the filter over independent unit noise: its spread at each pixel
    rng = np.random.default_rng(8)
    n = 600
    samples = np.empty((n, H, W))
    normal = np.zeros((H, W, 3))
    normal[..., 2] = 1.0
    depth = np.full((H, W), 5.0)
    res, res_var = np.zeros((H, W, 1)), np.zeros((H, W))
    ones = np.ones((H, W))
    for i in range(n):
        img = rng.standard_normal((H, W, 1))
        _filter.atrous(img, ones, ones, ones, inst, normal, depth, 800.0, 800.0, W / 2, H / 2, *Camera().lens_arrays(), 1, 0.0,
                       res, res_var)
        samples[i] = res[..., 0]
    emp = samples.var(axis=0)
    on = inst > 0
    # the sample variance of n draws is within a few × √(2/n) of the truth
    assert np.all(np.abs(emp[on] / out[on] - 1.0) < 5.0 * np.sqrt(2.0 / n))


# ---------------------------------------------------------------- the two passes on two plates
RHO_A, E_SUN = 0.8, 1000.0


def _plates():
    """Plate A (albedo 0.8): x ∈ [0, 2], y ∈ [−1, 1], top face at z = 0, lit by the Sun
    overhead; plate B (black): the plane x = 0, y ∈ [−1, 1], z ∈ [0, 2], facing +x, edge-on to
    the Sun. B's irradiance is A's light alone: ρ_A E F(p → A)."""
    a = trimesh.creation.box((2.0, 2.0, 0.02))
    a.apply_translation((1.0, 0.0, -0.01))
    b = trimesh.creation.box((0.02, 2.0, 2.0))
    b.apply_translation((-0.01, 0.0, 1.0))
    return Scene(TargetModel("plates", (Component("a", a, "white_paint", "bus", 1.0, albedo=(RHO_A,) * 3),
                                        Component("b", b, "black_paint", "bus", 1.0, albedo=(0.0,) * 3))))


def _form_factor_to_floor(y, z):
    def f(yy, xx):
        r2 = xx * xx + (yy - y) ** 2 + z * z
        return (xx / math.sqrt(r2)) * (z / math.sqrt(r2)) / (math.pi * r2)
    return integrate.dblquad(f, 0.0, 2.0, -1.0, 1.0, epsabs=1e-10, epsrel=1e-7)[0]


@pytest.fixture(scope="module")
def plate_points():
    """A 6 × 6 grid of points on B's lit side, from the contact (z = 0.05) up to z = 1.5, and
    the same grid on its back (facing −x, which sees nothing: no noise at all), as a 6 × 12
    image of two parts."""
    scene = _plates()
    ctx = _context._Context(scene, Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=E_SUN), {})
    ys, zs = np.meshgrid(np.linspace(-0.6, 0.6, 6), np.linspace(0.05, 1.5, 6))
    front = np.column_stack([np.ones(ys.size), ys.ravel(), zs.ravel()])
    back = front * [-1.0, 1.0, 1.0]
    O = np.concatenate([front, back])
    D = np.concatenate([np.tile([-1.0, 0.0, 0.0], (ys.size, 1)), np.tile([1.0, 0.0, 0.0], (ys.size, 1))])
    h = scene.intersect(O, D)
    assert np.all(h["geomID"] == 1)
    face = scene.face_offset[h["geomID"]] + h["primID"].astype(np.int64)
    s = _context._surfaces(ctx.scene, O, D, face)
    inst = np.concatenate([np.full(ys.shape, 2), np.full(ys.shape, 3)], axis=1).astype(np.uint16)
    v, u = np.unravel_index(np.arange(ys.size), ys.shape)
    at = (np.concatenate([v, v]), np.concatenate([u, u + 6]))
    expect = np.array([RHO_A * E_SUN * _form_factor_to_floor(y, z) for y, z in zip(ys.ravel(), zs.ravel())])
    return ctx, s, inst, at, np.concatenate([expect, np.zeros(ys.size)])


def test_two_pass_gather_is_unbiased_and_puts_the_rays_where_the_noise_is(plate_points):
    ctx, s, inst, at, expect = plate_points
    n = len(expect)
    lit = expect > 0
    pix = np.arange(n, dtype=np.int64)
    seeds = range(1, 161)
    one, two, rays = [], [], []
    for seed in seeds:
        one.append(ctx.gather_E(s, 16, pix, seed)[:, 0])
        var = np.empty(n)
        rays.append(np.empty(n, dtype=np.int64))
        two.append(shade._gather_two_pass(ctx, s, 16, 8, pix, seed, var, inst, at, rays_out=rays[-1])[:, 0])
    one, two, rays = np.array(one), np.array(two), np.array(rays)
    se = np.sqrt(one.var(axis=0, ddof=1) / len(seeds) + two.var(axis=0, ddof=1) / len(seeds))
    # both passes are unbiased estimates of the same irradiance ...
    assert np.all(np.abs(two.mean(axis=0) - one.mean(axis=0)) <= 4.5 * se)
    # ... which is the form factor's (plate A's own indirect light, from a black B, is zero),
    # within the noise of 160 seeds; the back sees nothing, exactly
    se_two = np.sqrt(two.var(axis=0, ddof=1) / len(seeds))
    assert np.all(np.abs(two.mean(axis=0) - expect)[lit] < 4.5 * se_two[lit] + 0.005 * expect[lit])
    assert np.abs(two.mean(axis=0) - expect)[lit].mean() < 0.02 * expect[lit].mean()
    assert np.all(two[:, ~lit] == 0.0)
    # the back (no noise) kept its pilot rays only, and the lit side got the rest (the budget
    # is 16 rays per point, one that hits counted as 1 + 3, raytrace.shade._HIT_COST) ...
    assert np.all(rays[:, ~lit] == 8)
    assert rays[:, lit].mean() > 19
    # ... so its variance fell (by less than 1/N: a 21-ray prefix of the sequence is not as
    # evenly stratified as 16)
    assert two[:, lit].var(axis=0).sum() < 0.95 * one[:, lit].var(axis=0).sum()


def test_two_passes_are_stratified_as_one(plate_points):
    """Where the noise is even (the lit side alone), the two passes together are no noisier
    than one pass of the same rays: the second continues the pilot's sequence. (Two
    independent patterns of 8 would be ~1.4× as noisy: 2 × 8^−1.5 against 16^−1.5.)"""
    ctx, s, inst, at, expect = plate_points
    lit = np.flatnonzero(expect > 0)
    sl = {k: v[lit] for k, v in s.items()}
    pix = np.arange(len(lit), dtype=np.int64)
    inst_l = inst[:, :6]
    at_l = (at[0][lit], at[1][lit])
    one, two = [], []
    for seed in range(1, 161):
        one.append(ctx.gather_E(sl, 16, pix, seed)[:, 0])
        two.append(shade._gather_two_pass(ctx, sl, 16, 8, pix, seed, np.empty(len(lit)), inst_l, at_l)[:, 0])
    ratio = np.array(two).var(axis=0).sum() / np.array(one).var(axis=0).sum()
    assert ratio < 1.15


def test_the_filters_passes_give_a_parts_border_more_rays_and_keep_the_mean(plate_points):
    """With ``filter_passes`` the allocation weighs each pixel's noise by what the filter keeps
    of it (raytrace._filter.filter_variance): the lit plate's border pixels, which the filter
    averages over fewer neighbours, get more rays than without, its inner ones fewer; the
    estimate stays an unbiased one of the form factor's irradiance."""
    ctx, s, inst, at, expect = plate_points
    n = len(expect)
    lit = expect > 0
    pix = np.arange(n, dtype=np.int64)
    q = np.empty(inst.shape)
    _filter.filter_variance(inst, 2, q)
    q_lit = q[at][lit]
    border = q_lit > np.median(q_lit)
    assert border.any() and (~border).any()
    seeds = range(1, 81)
    rays0, rays2, two = [], [], []
    for seed in seeds:
        r0, r2 = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        shade._gather_two_pass(ctx, s, 16, 8, pix, seed, np.empty(n), inst, at, rays_out=r0)
        two.append(shade._gather_two_pass(ctx, s, 16, 8, pix, seed, np.empty(n), inst, at, rays_out=r2,
                                          filter_passes=2)[:, 0])
        rays0.append(r0)
        rays2.append(r2)
    rays0, rays2, two = np.array(rays0)[:, lit], np.array(rays2)[:, lit], np.array(two)
    gain = rays2.mean(axis=0) / rays0.mean(axis=0)
    assert gain[border].mean() > 1.1 * gain[~border].mean()
    se = np.sqrt(two.var(axis=0, ddof=1) / len(seeds))
    assert np.all(np.abs(two.mean(axis=0) - expect)[lit] < 4.5 * se[lit] + 0.005 * expect[lit])
    assert np.all(two[:, ~lit] == 0.0)
