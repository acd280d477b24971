"""Numba BRDF kernels: Lambertian + GGX (Trowbridge–Reitz) microfacet specular.

    f(ω_i, ω_o) = ρ_d/π + D(h) · V(ω_i, ω_o) · F(ω_o·h)

* D: GGX normal distribution, D(h) = α² / (π ((n·h)²(α² − 1) + 1)²) (Walter et al. 2007,
  doi:10.2312/EGWR/EGSR07/195-206).
* V = G₂/(4 cosθ_i cosθ_o) with the height-correlated Smith G₂ = 1/(1 + Λ(ω_i) + Λ(ω_o)),
  Λ(μ) = (√(1 + α²(1 − μ²)/μ²) − 1)/2 (Heitz 2014, JCGT 3(2)).
* F: Schlick's approximation F0 + (1 − F0)(1 − ω_o·h)⁵.
* Sampling: a mixture of cosine-weighted hemisphere sampling and sampling of the GGX
  distribution of visible normals (Heitz 2018, JCGT 7(4) "Sampling the GGX distribution of
  visible normals"), with the mixture pdf, so weights f·cos/pdf stay bounded.
* Split-sum table: ∫ f_spec cos dω_i = F0·A(μ_o, α) + B(μ_o, α) (Karis 2013, "Real shading in
  Unreal Engine 4"), integrated here by VNDF quadrature, used for the specular reflection of
  the environment in the fast presets.

Vectors are passed as scalar triples (no allocation inside kernels); all in one frame.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ._jit import inline, jit, side_cores

__all__ = [
    "bounce_albedo",
    "brdf_cos",
    "onb",
    "pdf_brdf",
    "sample_brdf",
    "specular_albedo",
    "split_sum_table",
]

INV_PI = 1.0 / math.pi


@jit
def onb(nx, ny, nz):
    """Orthonormal tangents (t, b) with n (Duff et al. 2017, JCGT 6(1))."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


@jit
def cosine_direction(nx, ny, nz, u1, u2):
    """Cosine-weighted unit direction about the unit normal n from two uniforms (u1 sets the
    squared radius on the unit disc, u2 the azimuth; Malley's method)."""
    tx, ty, tz, bx, by, bz = onb(nx, ny, nz)
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    lx = r * math.cos(phi)
    ly = r * math.sin(phi)
    lz = math.sqrt(max(0.0, 1.0 - u1))
    return lx * tx + ly * bx + lz * nx, lx * ty + ly * by + lz * ny, lx * tz + ly * bz + lz * nz


@jit
def _lambda(mu, a2):
    mu2 = mu * mu
    if mu2 >= 1.0:
        return 0.0
    return 0.5 * (math.sqrt(1.0 + a2 * (1.0 - mu2) / mu2) - 1.0)


@jit
def _ggx_d(noh, a2):
    d = noh * noh * (a2 - 1.0) + 1.0
    return a2 / (math.pi * d * d)


@jit
def brdf_cos(nx, ny, nz, ox, oy, oz, lx, ly, lz, dr, dg, db, fr, fg, fb, alpha):
    """f(ω_i = l, ω_o = o)·cosθ_l, RGB; zero when l or o is below the surface (n unit, o and
    l unit vectors pointing away from the surface)."""
    nol = nx * lx + ny * ly + nz * lz
    nov = nx * ox + ny * oy + nz * oz
    if nol <= 0.0 or nov <= 0.0:
        return 0.0, 0.0, 0.0
    r = dr * INV_PI * nol
    g = dg * INV_PI * nol
    b = db * INV_PI * nol
    if fr > 0.0 or fg > 0.0 or fb > 0.0:
        hx = lx + ox
        hy = ly + oy
        hz = lz + oz
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        hx /= hn
        hy /= hn
        hz /= hn
        noh = max(nx * hx + ny * hy + nz * hz, 0.0)
        voh = max(ox * hx + oy * hy + oz * hz, 0.0)
        a2 = alpha * alpha
        g2 = 1.0 / (1.0 + _lambda(nov, a2) + _lambda(nol, a2))
        spec = _ggx_d(noh, a2) * g2 / (4.0 * nov)  # D·V·cosθ_l = D·G2/(4 cosθ_o)
        fc = (1.0 - voh) ** 5
        r += spec * (fr + (1.0 - fr) * fc)
        g += spec * (fg + (1.0 - fg) * fc)
        b += spec * (fb + (1.0 - fb) * fc)
    return r, g, b


@jit
def _spec_prob(dr, dg, db, fr, fg, fb):
    ls = 0.2126 * fr + 0.7152 * fg + 0.0722 * fb
    ld = 0.2126 * dr + 0.7152 * dg + 0.0722 * db
    if ls <= 0.0:
        return 0.0
    if ld <= 0.0:
        return 1.0
    return ls / (ls + ld)


@jit
def pdf_brdf(nx, ny, nz, ox, oy, oz, lx, ly, lz, dr, dg, db, fr, fg, fb, alpha):
    """Solid-angle pdf with which :func:`sample_brdf` draws l."""
    nol = nx * lx + ny * ly + nz * lz
    nov = nx * ox + ny * oy + nz * oz
    if nol <= 0.0 or nov <= 0.0:
        return 0.0
    ps = _spec_prob(dr, dg, db, fr, fg, fb)
    p = (1.0 - ps) * nol * INV_PI
    if ps > 0.0:
        hx = lx + ox
        hy = ly + oy
        hz = lz + oz
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        noh = max((nx * hx + ny * hy + nz * hz) / hn, 0.0)
        a2 = alpha * alpha
        g1 = 1.0 / (1.0 + _lambda(nov, a2))
        p += ps * g1 * _ggx_d(noh, a2) / (4.0 * nov)
    return p


@jit
def sample_brdf(nx, ny, nz, ox, oy, oz, dr, dg, db, fr, fg, fb, alpha, u0, u1, u2):
    """Draw l from the mixture (cosine | GGX visible normals) with uniforms u0 (lobe), u1, u2.

    Returns (lx, ly, lz, wr, wg, wb, ok): weight = f·cosθ_l / pdf; ok False when the draw
    leaves the hemisphere (the path ends)."""
    tx, ty, tz, bx, by, bz = onb(nx, ny, nz)
    ps = _spec_prob(dr, dg, db, fr, fg, fb)
    if u0 < ps:  # GGX VNDF, in the local frame (t, b, n)
        vx = ox * tx + oy * ty + oz * tz
        vy = ox * bx + oy * by + oz * bz
        vz = ox * nx + oy * ny + oz * nz
        if vz <= 0.0:
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
        hx = alpha * vx
        hy = alpha * vy
        hz = vz
        hl = math.sqrt(hx * hx + hy * hy + hz * hz)
        hx /= hl
        hy /= hl
        hz /= hl
        lensq = hx * hx + hy * hy
        if lensq > 0.0:
            il = 1.0 / math.sqrt(lensq)
            t1x, t1y, t1z = -hy * il, hx * il, 0.0
        else:
            t1x, t1y, t1z = 1.0, 0.0, 0.0
        t2x = hy * t1z - hz * t1y
        t2y = hz * t1x - hx * t1z
        t2z = hx * t1y - hy * t1x
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        p1 = r * math.cos(phi)
        p2 = r * math.sin(phi)
        s = 0.5 * (1.0 + hz)
        p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
        p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
        mx = p1 * t1x + p2 * t2x + p3 * hx
        my = p1 * t1y + p2 * t2y + p3 * hy
        mz = max(0.0, p1 * t1z + p2 * t2z + p3 * hz)
        mx *= alpha
        my *= alpha
        ml = math.sqrt(mx * mx + my * my + mz * mz)
        mx /= ml
        my /= ml
        mz /= ml
        voh = vx * mx + vy * my + vz * mz
        lxl = 2.0 * voh * mx - vx
        lyl = 2.0 * voh * my - vy
        lzl = 2.0 * voh * mz - vz
    else:  # cosine-weighted hemisphere (Malley)
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        lxl = r * math.cos(phi)
        lyl = r * math.sin(phi)
        lzl = math.sqrt(max(0.0, 1.0 - u1))
    if lzl <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    lx = lxl * tx + lyl * bx + lzl * nx
    ly = lxl * ty + lyl * by + lzl * ny
    lz = lxl * tz + lyl * bz + lzl * nz
    pdf = pdf_brdf(nx, ny, nz, ox, oy, oz, lx, ly, lz, dr, dg, db, fr, fg, fb, alpha)
    if pdf <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    cr, cg, cb = brdf_cos(nx, ny, nz, ox, oy, oz, lx, ly, lz, dr, dg, db, fr, fg, fb, alpha)
    return lx, ly, lz, cr / pdf, cg / pdf, cb / pdf, True


_MU_BINS = 32
_ALPHA_MIN = 0.02


@jit
def _radical_inverse2(i):
    r = 0.0
    f = 0.5
    while i > 0:
        r += f * (i & 1)
        i >>= 1
        f *= 0.5
    return r


@jit
def _split_sum(n_mu, n_alpha, n_samples, i0, i1):
    """Rows i0 … i1 − 1 (μ_o bins) of :func:`split_sum_table`'s table, shape (i1 − i0, n_alpha, 2):
    each row is its own sums, so the table computed in pieces is the same bits."""
    out = np.zeros((i1 - i0, n_alpha, 2))
    for i in range(i0, i1):
        mu = (i + 0.5) / n_mu
        ox = math.sqrt(1.0 - mu * mu)
        for j in range(n_alpha):
            alpha = _ALPHA_MIN + (1.0 - _ALPHA_MIN) * j / (n_alpha - 1)
            a2 = alpha * alpha
            g1 = 1.0 / (1.0 + _lambda(mu, a2))
            sa = 0.0
            sb = 0.0
            for k in range(n_samples):
                lx, ly, lz, _wr, _wg, _wb, ok = sample_brdf(0.0, 0.0, 1.0, ox, 0.0, mu, 0.0, 0.0, 0.0,
                                                        1.0, 1.0, 1.0, alpha, 0.0,
                                                        (k + 0.5) / n_samples, _radical_inverse2(k))
                if not ok:
                    continue
                hx = lx + ox
                hz = lz + mu
                hn = math.sqrt(hx * hx + ly * ly + hz * hz)
                voh = max((ox * hx + mu * hz) / hn, 0.0)
                fc = (1.0 - voh) ** 5
                g2 = 1.0 / (1.0 + _lambda(mu, a2) + _lambda(lz, a2))
                w = g2 / g1
                sa += (1.0 - fc) * w
                sb += fc * w
            out[i - i0, j, 0] = sa / n_samples
            out[i - i0, j, 1] = sb / n_samples
    return out


def _split_sum_table(n_mu, n_alpha, n_samples):
    """:func:`_split_sum` of all rows: in two halves on two threads where the calling thread has
    two cores (``raytrace._jit.side_cores``; ~0.45 s on one core, once per machine), the same
    bits."""
    if side_cores() < 2:
        return _split_sum(n_mu, n_alpha, n_samples, 0, n_mu)
    from concurrent.futures import ThreadPoolExecutor
    half = n_mu // 2
    with ThreadPoolExecutor(2, thread_name_prefix="raytrace-splitsum") as ex:
        parts = [ex.submit(_split_sum, n_mu, n_alpha, n_samples, a, b) for a, b in ((0, half), (half, n_mu))]
        return np.concatenate([f.result() for f in parts])


_SPLIT_SUM_SAMPLES = 4096


@functools.cache
def split_sum_table() -> np.ndarray:
    """(A, B) of ∫ f_spec cos dω_i = F0·A + B on a grid of μ_o = cosθ_o (bin centres of 32
    bins in (0, 1)) × α (32 values from 0.02 to 1), shape (32, 32, 2), float64. Computed once
    per machine and code (~0.5 s) and kept in the persistent cache (:mod:`raytrace._diskcache`)."""
    from . import _diskcache
    shape = (_MU_BINS, _MU_BINS, 2)

    def load(payload):  # writable, as computed
        ok = len(payload) == 8 * math.prod(shape)
        return np.frombuffer(payload, dtype=np.float64).reshape(shape).copy() if ok else None

    return _diskcache.memoised("splitsum", (repr((shape, _SPLIT_SUM_SAMPLES, _ALPHA_MIN)).encode(),),
                               lambda: _split_sum_table(_MU_BINS, _MU_BINS, _SPLIT_SUM_SAMPLES),
                               lambda table: np.ascontiguousarray(table, dtype=np.float64).tobytes(), load)


@inline
def specular_albedo(table, mu, alpha, fr, fg, fb):
    """Directional albedo of the specular lobe, F0·A + B, RGB, bilinear in (μ, α)."""
    n_mu = table.shape[0]
    n_a = table.shape[1]
    x = min(max(mu * n_mu - 0.5, 0.0), n_mu - 1.0)
    y = min(max((alpha - _ALPHA_MIN) / (1.0 - _ALPHA_MIN) * (n_a - 1), 0.0), n_a - 1.0)
    i = min(int(x), n_mu - 2)
    j = min(int(y), n_a - 2)
    fx = x - i
    fy = y - j
    a = ((1 - fx) * (1 - fy) * table[i, j, 0] + fx * (1 - fy) * table[i + 1, j, 0]
         + (1 - fx) * fy * table[i, j + 1, 0] + fx * fy * table[i + 1, j + 1, 0])
    b = ((1 - fx) * (1 - fy) * table[i, j, 1] + fx * (1 - fy) * table[i + 1, j, 1]
         + (1 - fx) * fy * table[i, j + 1, 1] + fx * fy * table[i + 1, j + 1, 1])
    return fr * a + b, fg * a + b, fb * a + b


def bounce_albedo(diffuse, f0, roughness) -> np.ndarray:
    """Hemispherical (cosine-averaged) albedo of a material, RGB: ρ_d + 2∫(F0·A + B) μ dμ —
    the reflectance the body-space radiance cache gives a surface when it treats the light it
    reflects towards other parts as diffuse."""
    table = split_sum_table()
    mus = (np.arange(_MU_BINS) + 0.5) / _MU_BINS
    spec = np.array([specular_albedo(table, m, float(roughness), *map(float, f0)) for m in mus])
    avg = (spec * 2.0 * mus[:, None]).sum(axis=0) / _MU_BINS
    return np.minimum(np.asarray(diffuse, dtype=np.float64) + avg, 0.999)
