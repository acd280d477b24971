"""Numba kernels of ``balanced``'s final gather and glossy-lobe sampling, batched (the fallback
of the fused kernels in :mod:`raytrace._paths`, which share their helpers): the gather's rays
and the bounces traced from their hits, the radiance they bring back, the gather's and the
lobe's estimates with their variances, and the rays a two-pass gather allots each pixel.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import environment as env
from ._cache_kernels import glossy_draw, hit_normals
from ._jit import inline, jit, jit_exact, pjit
from ._lights import SUN_X, SUN_Y, SUN_Z
from ._sampling import _cmj_perms, _cmj_point, _hash01, _hash32, _owen_sobol2_keyed, _strata
from ._surface import incoming, incoming_env
from .brdf import cosine_direction, sample_brdf


@jit
def gather_start(pix, seed, first, share, kmul):
    """Key of the scrambled Sobol sequence of a final gather's point, and the sample its rays
    start at (:func:`gather_rays`). ``share`` = 0: each point (pixel) its own sequence from sample
    ``first``. ``share`` > 0: pix = pixel · share + i, the sub-sample i of a pixel, and sub-sample
    i's kmul rays are samples first + i · kmul … of the pixel's one sequence, so that the
    gathers of a pixel's sub-samples are together one stratified set: as Owen scrambling
    maps every aligned block of 2^m indices onto an aligned block of the Sobol sequence, with
    kmul a power of two each sub-sample's rays are a (0, m, 2)-net of their own and all S
    sub-samples' a net of S · kmul (Burley 2020, §5), as a path tracer gives a pixel's samples
    consecutive indices of one sequence, rather than S independent sets."""
    if share > 0:
        return (pix // share) * 1009 + seed, first + (pix % share) * kmul
    return pix * 1009 + seed, first


@pjit
def gather_rays(P, NS, NG, start, first, seed, pix, share, kmul, eps, out_o, out_d):
    """Cosine-weighted directions about the shading normal, rays start[k] … start[k + 1] − 1
    for point k: samples first, first + 1, … of its pixel's Owen-scrambled Sobol
    sequence (:func:`raytrace._sampling.owen_sobol2`, keyed by pixel and seed) in (radius², azimuth). Any 2^m of
    them from sample 0 are a (0, m, 2)-net; a second pass from sample n continues the same
    sequence, so the two passes together are as well stratified as one. With ``share`` > 0 the
    points are the sub-samples of pixels: pix[k] = pixel · share + number, and the rays of
    number i are samples first + i · kmul, … of the pixel's one sequence (:func:`gather_start`)."""
    stream = 2 * seed + 15
    for k in numba.prange(P.shape[0]):
        key, first_k = gather_start(pix[k], seed, first, share, kmul)
        h_index, h_x, h_y = _hash32(key, stream), _hash32(key, stream + 1), _hash32(key, stream + 2)
        ox = P[k, 0] + eps * NG[k, 0]
        oy = P[k, 1] + eps * NG[k, 1]
        oz = P[k, 2] + eps * NG[k, 2]
        for j in range(start[k + 1] - start[k]):
            u1, u2 = _owen_sobol2_keyed(first_k + j, h_index, h_x, h_y)
            m = start[k] + j
            out_d[m, 0], out_d[m, 1], out_d[m, 2] = cosine_direction(NS[k, 0], NS[k, 1], NS[k, 2], u1, u2)
            out_o[m, 0] = ox
            out_o[m, 1] = oy
            out_o[m, 2] = oz


@pjit
def bounce_sun_rays(O, D, tfar, geom, prim, face_offset, face_normal, sun, eps, want, out_o):
    """Shadow rays towards the Sun from the hits of traced rays (o + t·d, offset along the
    geometric normal on the side the ray arrived from), wanted where that side faces the Sun
    (``sun`` the Sun record, :mod:`raytrace._lights`)."""
    sx, sy, sz = sun[SUN_X], sun[SUN_Y], sun[SUN_Z]
    for m in numba.prange(D.shape[0]):
        want[m] = False
        if geom[m] < 0:
            continue
        f = face_offset[geom[m]] + prim[m]
        nx = face_normal[f, 0]
        ny = face_normal[f, 1]
        nz = face_normal[f, 2]
        if nx * D[m, 0] + ny * D[m, 1] + nz * D[m, 2] > 0.0:
            nx, ny, nz = -nx, -ny, -nz
        if nx * sx + ny * sy + nz * sz <= 0.0:
            continue
        want[m] = True
        t = tfar[m]
        out_o[m, 0] = O[m, 0] + t * D[m, 0] + eps * nx
        out_o[m, 1] = O[m, 1] + t * D[m, 1] + eps * ny
        out_o[m, 2] = O[m, 2] + t * D[m, 2] + eps * nz


@pjit
def bounce2_rays(O, D, tfar, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face, glossy,
                 mat_f0, mat_alpha, keys, seed, eps, want, out_o, out_d, out_w):
    """A second bounce from the hits of traced rays, one direction per hit from a hash of
    (keys[m], seed), about the hit's shading normal (facing the ray's origin): cosine-weighted
    with weight π (the hit's irradiance is π·L_in), or on a ``glossy`` part a draw from its GGX
    lobe (visible normals) about the mirror of the ray with weight f_s·cos/pdf (RGB; the
    specular reflection is weight·L_in, :func:`raytrace._surface.incoming`). Wanted where the draw succeeds and
    leaves the surface (above the geometric normal)."""
    for m in numba.prange(D.shape[0]):
        want[m] = False
        if geom[m] < 0:
            continue
        f = face_offset[geom[m]] + prim[m]
        dx, dy, dz = D[m, 0], D[m, 1], D[m, 2]
        nx, ny, nz, ngx, ngy, ngz = hit_normals(face_normal, corner_normal, f, hu[m], hv[m], dx, dy, dz)
        u1 = _hash01(keys[m], 4 * seed + 31)
        u2 = _hash01(keys[m], 4 * seed + 32)
        c = comp_of_face[f]
        if glossy[c]:
            wx, wy, wz, wr, wg, wb, ok = glossy_draw(nx, ny, nz, ngx, ngy, ngz, dx, dy, dz, mat_f0[c, 0],
                                                     mat_f0[c, 1], mat_f0[c, 2], mat_alpha[c], u1, u2)
            if not ok:
                continue
        else:
            wx, wy, wz = cosine_direction(nx, ny, nz, u1, u2)
            wr = wg = wb = math.pi
            if wx * ngx + wy * ngy + wz * ngz <= 0.0:
                continue
        want[m] = True
        t = tfar[m]
        out_o[m, 0] = O[m, 0] + t * dx + eps * ngx
        out_o[m, 1] = O[m, 1] + t * dy + eps * ngy
        out_o[m, 2] = O[m, 2] + t * dz + eps * ngz
        out_d[m, 0] = wx
        out_d[m, 1] = wy
        out_d[m, 2] = wz
        out_w[m, 0] = wr
        out_w[m, 1] = wg
        out_w[m, 2] = wb


@pjit
def incoming_rays(O, D, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0,
                  mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                  mat_par, face_uv, atlas, vis, e_ind, out):
    """:func:`raytrace._surface.incoming` along each ray (the Sun's visibility at its hit from ``vis``, its
    indirect irradiance from ``e_ind`` where ≥ 0, else from the cache)."""
    for m in numba.prange(D.shape[0]):
        if geom[m] < 0:
            out[m, 0], out[m, 1], out[m, 2] = incoming_env(p, tex, O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2])
            continue
        out[m, 0], out[m, 1], out[m, 2] = incoming(
            geom[m], prim[m], hu[m], hv[m], O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2], face_offset,
            face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun,
            valid, face_s, lat_start, lat_ids, p, tex,
            mat_par, face_uv, atlas, vis[m], e_ind[m, 0], e_ind[m, 1], e_ind[m, 2])


@pjit
def gather_sum(start, O, D, NG, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face,
               mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
               mat_par, face_uv, atlas, vis,
               e_ind, NS, E_unocc, alpha, out, out_var):
    """Irradiance estimate per point k from its N = start[k + 1] − start[k] cosine-weighted rays
    (rays start[k] … start[k + 1] − 1, about NS; rays under the geometric surface carry
    nothing), with the environment as a control variate:

        E = α·E_env(n) + π/N Σ_j [L_in(ω_j) − α·L_env(ω_j)],

    where E_env(n) is the environment's unoccluded irradiance (``E_unocc``, the table of
    :func:`raytrace.environment.irradiance_table`) and L_env(ω) the environment's radiance
    along ω. It is unbiased for every α (E[π/N Σ L_env] = E_env); with α = 1 an escaped ray
    adds exactly nothing, so on an open surface the noise of sampling Earth's disc and the
    sky vanishes and only blocked directions are noisy; in a cavity, where most rays are
    blocked, α = 0 (the plain estimate π/N Σ L_in) would be better. Measured on the 12 scenes
    of ``benchmarks/bench_time_error.py`` at 640×480, α = 1 against 0: never worse by more than
    0.01 %, better where Earth lights the target (``balanced``-16 ICESat ``backlit`` 4.79 →
    4.20 %, Crew Dragon ``backlit`` 6.39 → 5.96 %; median over the 12: 4.55 → 4.25 %).
    ``vis[m]`` the Sun's visibility at ray m's hit (< 0: from the cache), ``e_ind[m]`` a traced
    estimate of the hit's indirect irradiance (< 0: from the cache). ``out_var[k]`` is the
    sample variance of the estimate's luminance (Rec. 709 weights) from the spread of its N
    per-ray terms: s²/N [(W/m²)²], which guides :func:`raytrace._filter.atrous` (0 for N = 1)."""
    a = alpha
    for k in numba.prange(out.shape[0]):
        n_rays = start[k + 1] - start[k]
        sr = 0.0
        sg = 0.0
        sb = 0.0
        sy2 = 0.0  # Σ (luminance of the ray's term)²
        for j in range(n_rays):
            m = start[k] + j
            below = D[m, 0] * NG[k, 0] + D[m, 1] * NG[k, 1] + D[m, 2] * NG[k, 2] <= 0.0
            if geom[m] < 0 and not below:
                if a == 1.0:
                    continue  # exactly what the control variate expects
                r, g, b = incoming_env(p, tex, O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2])
                sr += (1.0 - a) * r
                sg += (1.0 - a) * g
                sb += (1.0 - a) * b
                y = (1.0 - a) * (0.2126 * r + 0.7152 * g + 0.0722 * b)
                sy2 += y * y
                continue
            y = 0.0  # luminance of this ray's term
            if a != 0.0:
                r, g, b = incoming_env(p, tex, O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2])
                sr -= a * r
                sg -= a * g
                sb -= a * b
                y -= a * (0.2126 * r + 0.7152 * g + 0.0722 * b)
            if not below:
                r, g, b = incoming(geom[m], prim[m], hu[m], hv[m], O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1],
                                   D[m, 2], face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0,
                                   mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                                   mat_par, face_uv, atlas,
                                   vis[m], e_ind[m, 0], e_ind[m, 1], e_ind[m, 2])
                sr += r
                sg += g
                sb += b
                y += 0.2126 * r + 0.7152 * g + 0.0722 * b
            sy2 += y * y
        out[k, 0], out[k, 1], out[k, 2], out_var[k] = gather_estimate(sr, sg, sb, sy2, n_rays, a, E_unocc, NS[k, 0],
                                                                      NS[k, 1], NS[k, 2])


@inline
def gather_estimate(sr, sg, sb, sy2, n_rays, a, E_unocc, nx, ny, nz):
    """The estimate of :func:`gather_sum` from its sums over a point's N rays (Σ of the terms
    per channel, Σ of their luminance²): (E_r, E_g, E_b, luminance variance)."""
    k_ = math.pi / max(n_rays, 1)
    er = sr * k_
    eg = sg * k_
    eb = sb * k_
    # variance of the mean of the N terms π·t_j: π² (Σy² − N ȳ²) / (N (N − 1))
    var = 0.0
    if n_rays > 1:
        ym = (0.2126 * sr + 0.7152 * sg + 0.0722 * sb) / n_rays
        var = max(math.pi * math.pi * (sy2 - n_rays * ym * ym) / (n_rays * (n_rays - 1.0)), 0.0)
    if a != 0.0:
        ur, ug, ub = env.irradiance_lookup(E_unocc, nx, ny, nz)
        er += a * ur
        eg += a * ug
        eb += a * ub
    return er, eg, eb, var


@jit_exact
def _allotted(c, w, cost, n_min, n_max):
    """Σ_k cost_k · clip(⌊c·w_k + ½⌋, n_min, n_max)."""
    t = 0.0
    for k in range(w.shape[0]):
        t += cost[k] * min(max(int(math.floor(c * w[k] + 0.5)), n_min), n_max)
    return t


@jit_exact
def allocate_rays(sig, cost, n_min, n_max, budget, out):
    """Rays per point for the least summed variance Σ σ_k²/n_k at a given cost Σ cost_k·n_k
    (Neyman allocation with costs: n_k ∝ σ_k/√cost_k; σ_k the per-ray standard deviation of
    point k's estimate, cost_k what one of its rays costs), rounded and clipped to
    [n_min, n_max]: out[k] = clip(⌊c·σ_k/√cost_k + ½⌋, n_min, n_max) with the largest c (by
    bisection) whose cost does not exceed ``budget``. Where every σ is 0, every point gets the
    same number of rays."""
    n = sig.shape[0]
    if n == 0:
        return
    smax = 0.0
    csum = 0.0
    for k in range(n):
        smax = max(smax, sig[k])
        csum += cost[k]
    if not smax > 0.0:
        for k in range(n):
            out[k] = min(max(int(budget / csum), n_min), n_max)
        return
    w = np.empty(n)
    for k in range(n):
        w[k] = max(sig[k], 1e-3 * smax) / math.sqrt(cost[k])  # a σ of 0 from a few rays is not certain
    wmin = w[0]
    for k in range(n):
        wmin = min(wmin, w[k])
    lo = 0.0
    hi = (n_max + 1.0) / wmin
    for _ in range(40):  # c to 2^−40 of hi: every c·w_k to < 10⁻⁶ of a ray
        c = 0.5 * (lo + hi)
        if _allotted(c, w, cost, n_min, n_max) > budget:
            hi = c
        else:
            lo = c
    for k in range(n):
        out[k] = min(max(int(math.floor(lo * w[k] + 0.5)), n_min), n_max)


@pjit
def lobe_rays(idx, P, NS, NG, WO, comp, mat_f0, mat_alpha, n_rays, seed, pix, eps, out_o, out_d, out_w):
    """n_rays directions per listed point drawn from its GGX lobe (visible normals, correlated
    multi-jittered per pixel and seed, :func:`raytrace._sampling._cmj_point`), with weights f_spec·cos/pdf (RGB;
    0 where the draw fails or goes under the geometric surface)."""
    gx = _strata(n_rays)
    gy = n_rays // gx
    for j in numba.prange(idx.shape[0]):
        k = idx[j]
        c = comp[k]
        key = pix[k] * 1013 + seed
        perm_x, perm_y = _cmj_perms(gx, gy, key, 2 * seed + 23)
        for r in range(n_rays):
            u1, u2 = _cmj_point(r, gx, gy, perm_x, perm_y, _hash01(key, 2 * r + 21), _hash01(key, 2 * r + 22))
            lx, ly, lz, wr, wg, wb, ok = sample_brdf(NS[k, 0], NS[k, 1], NS[k, 2], WO[k, 0], WO[k, 1], WO[k, 2],
                                                     0.0, 0.0, 0.0, mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2],
                                                     mat_alpha[c], 0.0, u1, u2)
            m = j * n_rays + r
            if not ok or lx * NG[k, 0] + ly * NG[k, 1] + lz * NG[k, 2] <= 0.0:
                wr = 0.0
                wg = 0.0
                wb = 0.0
                lx, ly, lz = NG[k, 0], NG[k, 1], NG[k, 2]
            out_d[m, 0] = lx
            out_d[m, 1] = ly
            out_d[m, 2] = lz
            out_w[m, 0] = wr
            out_w[m, 1] = wg
            out_w[m, 2] = wb
            for a in range(3):
                out_o[m, a] = P[k, a] + eps * NG[k, a]


@pjit
def lobe_sum(n_rays, O, D, Wt, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face,
             mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
             mat_par, face_uv, atlas, idx, CV,
             vis, e_ind, out, out_var):
    """Each listed point's (idx[j]) sampled specular reflection minus its cheap counterpart
    L̄·A (:func:`raytrace._surface.add_mirror`, L̄ = ``CV[idx[j]]``, A the split-sum albedo): the mean over the
    lobe rays of weight × (incoming radiance − L̄).

    L̄ is a control variate with a known mean, E[weight] = A: the difference is unbiased up to
    L̄ times the split-sum table's error (≤ 0.2 % of A for μ_o ≥ 0.1 and α ≤ 0.6,
    tests/raytrace/test_brdf.py), and the rays that see L̄ add nothing. Without it the spread
    of the weights f·cos/pdf alone made a gold sphere under a uniform sky 4 % noisy per pixel
    at 8 rays; with it, exact."""
    for j in numba.prange(out.shape[0]):
        k = idx[j]
        sr = 0.0
        sg = 0.0
        sb = 0.0
        sy2 = 0.0  # Σ (luminance of the ray's term)²
        for r in range(n_rays):
            m = j * n_rays + r
            if Wt[m, 0] == 0.0 and Wt[m, 1] == 0.0 and Wt[m, 2] == 0.0:
                continue
            if geom[m] < 0:
                a, b, c = incoming_env(p, tex, O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2])
            else:
                a, b, c = incoming(geom[m], prim[m], hu[m], hv[m], O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1],
                                   D[m, 2], face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0,
                                   mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                                   mat_par, face_uv, atlas,
                                   vis[m], e_ind[m, 0], e_ind[m, 1], e_ind[m, 2])
            sr, sg, sb, sy2 = add_lobe_term(sr, sg, sb, sy2, Wt[m, 0], Wt[m, 1], Wt[m, 2], a, b, c, CV[k, 0], CV[k, 1],
                                            CV[k, 2])
        out[j, 0], out[j, 1], out[j, 2], out_var[j] = mean_estimate(sr, sg, sb, sy2, n_rays)


@inline
def add_lobe_term(sr, sg, sb, sy2, wr, wg, wb, lr, lg, lb, cr, cg, cb):
    """The sums of :func:`lobe_sum` with one more lobe ray's term, weight × (incoming radiance
    L − the control variate L̄)."""
    tr = wr * (lr - cr)
    tg = wg * (lg - cg)
    tb = wb * (lb - cb)
    y = 0.2126 * tr + 0.7152 * tg + 0.0722 * tb
    return sr + tr, sg + tg, sb + tb, sy2 + y * y


@inline
def mean_estimate(sr, sg, sb, sy2, n):
    """The mean of N terms from their sums per channel and the sum of their luminance²:
    (mean_r, mean_g, mean_b, the luminance variance of the mean)."""
    # variance of the mean of the N terms: (Σy² − N ȳ²) / (N (N − 1))
    var = 0.0
    if n > 1:
        ym = (0.2126 * sr + 0.7152 * sg + 0.0722 * sb) / n
        var = max((sy2 - n * ym * ym) / (n * (n - 1.0)), 0.0)
    return sr / n, sg / n, sb / n, var
