"""Numba kernels of the shading pass (fast and balanced qualities): surface points from rays,
direct sunlight, cache look-ups, final gather, the AOV-guided filter and anti-aliasing rays.

Conventions: body frame, float64 except the float32 arrays handed to Embree; ``wo`` points
from the surface to the viewer; normals are turned to face the incoming ray.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import environment as env
from ._jit import FASTMATH, inline, jit, jit_exact, pjit, pjit_exact
from ._kernels import moller_trumbore, normals_facing
from .brdf import brdf_cos, cosine_direction, onb, sample_brdf, specular_albedo
from ._sampling import (_cmj_perms, _cmj_point, _hash01, _hash32, _owen_sobol2_keyed, _strata, permute)
from ._cache_kernels import glossy_draw, hit_normals, interpolate_rows, lattice_rows


@pjit_exact
def surfaces(O, D, face, V, F, face_normal, corner_normal, P, NS, NG, WO, B, SIDE):
    """Hit point, shading and geometric normals (facing the ray), direction to the viewer,
    barycentrics and the side of the triangle seen (0 front, 1 back) for rays (O, D) known to
    hit triangle ``face`` (re-intersected in float64). ``O`` has a row per ray, or one row, the
    origin of all (sub-pixel rays from the camera centre): one signature for both, where a
    broadcast (non-contiguous, read-only) array of origins compiled a second one (~1.4 s on one
    core)."""
    o_step = 0 if O.shape[0] == 1 else 1  # O's row of ray k: k · o_step
    for k in numba.prange(D.shape[0]):
        ox = O[k * o_step, 0]
        oy = O[k * o_step, 1]
        oz = O[k * o_step, 2]
        dx = D[k, 0]
        dy = D[k, 1]
        dz = D[k, 2]
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        dx /= dn
        dy /= dn
        dz /= dn
        f = face[k]
        _t, b1, b2, _ok = moller_trumbore(ox, oy, oz, dx, dy, dz, V, F, f)
        b1 = min(max(b1, 0.0), 1.0)
        b2 = min(max(b2, 0.0), 1.0 - b1)
        b0 = 1.0 - b1 - b2
        for a in range(3):
            P[k, a] = b0 * V[F[f, 0], a] + b1 * V[F[f, 1], a] + b2 * V[F[f, 2], a]
        ngx, ngy, ngz, nsx, nsy, nsz, side = normals_facing(face_normal, corner_normal, f, b0, b1, b2, dx, dy, dz)
        facing = -(nsx * dx + nsy * dy + nsz * dz)
        if facing < 1e-4:  # interpolated normal turned away from the viewer: tilt it back
            tilt = 1e-4 - facing
            nsx -= tilt * dx
            nsy -= tilt * dy
            nsz -= tilt * dz
        ns = math.sqrt(nsx * nsx + nsy * nsy + nsz * nsz)
        NS[k, 0] = nsx / ns
        NS[k, 1] = nsy / ns
        NS[k, 2] = nsz / ns
        NG[k, 0] = ngx
        NG[k, 1] = ngy
        NG[k, 2] = ngz
        WO[k, 0] = -dx
        WO[k, 1] = -dy
        WO[k, 2] = -dz
        B[k, 0] = b1
        B[k, 1] = b2
        SIDE[k] = side


@pjit
def sun_rays(P, NS, NG, sx, sy, sz, eps, want, out_o):
    """Which points can see the Sun's direction at all (both normals towards it), and the
    shadow-ray origins (offset along the geometric normal)."""
    for k in numba.prange(P.shape[0]):
        ok = (NS[k, 0] * sx + NS[k, 1] * sy + NS[k, 2] * sz > 0.0) and \
             (NG[k, 0] * sx + NG[k, 1] * sy + NG[k, 2] * sz > 0.0)
        want[k] = ok
        for a in range(3):
            out_o[k, a] = P[k, a] + eps * NG[k, a]


@pjit
def sun_disc_dirs(pixel, number, n_strata, seed, sx, sy, sz, cos_half, out_d):
    """Directions uniform over the solar disc (the cone of half-angle acos(cos_half) about
    the Sun's centre direction): sample ``number[m]`` (< n_strata) of ``pixel[m]`` takes
    stratum permute(number, n_strata) of an exact gx × gy grid in (1 − cos θ, φ), the
    permutation drawn per pixel and seed (:func:`permute`), jittered from a hash of (pixel,
    number, seed). The permutation decouples the disc stratum from the sample's number, which
    also indexes its sub-pixel cell (:func:`subpixel_rays`): with stratum = number, sub-samples
    in the pixel's left column always took the disc's inner ring, and a penumbra crossing the
    pixel was estimated from 6 correlated pairs, not 36 samples (measured: Cassini ``earth``,
    ``balanced``-16, ±30 % from seed to seed on the dish's shadow edge)."""
    gx = _strata(n_strata)
    gy = n_strata // gx
    tx, ty, tz, bx, by, bz = onb(sx, sy, sz)
    for m in numba.prange(pixel.shape[0]):
        out_d[m, 0], out_d[m, 1], out_d[m, 2] = disc_direction(pixel[m], number[m], n_strata, gx, gy, seed, tx, ty,
                                                               tz, bx, by, bz, sx, sy, sz, cos_half)


@inline
def disc_direction(pixel, number, n_strata, gx, gy, seed, tx, ty, tz, bx, by, bz, sx, sy, sz, cos_half):
    """One direction of :func:`sun_disc_dirs` ((t, b) the basis about the Sun's direction s
    that :func:`raytrace.brdf.onb` gives)."""
    j = permute(number, n_strata, _hash32(pixel, 4 * seed + 23))
    key = pixel * n_strata + number
    u1 = ((j % gx) + _hash01(key, 4 * seed + 21)) / gx
    u2 = ((j // gx) + _hash01(key, 4 * seed + 22)) / gy
    ct = 1.0 - u1 * (1.0 - cos_half)
    st = math.sqrt(max(0.0, 1.0 - ct * ct))
    c = st * math.cos(2.0 * math.pi * u2)
    d = st * math.sin(2.0 * math.pi * u2)
    return c * tx + d * bx + ct * sx, c * ty + d * by + ct * sy, c * tz + d * bz + ct * sz


@pjit
def shade_sun(NS, WO, comp, mat_diff, mat_f0, mat_alpha, sx, sy, sz, e_sun, vis, out):
    """out += V·f·cosθ·E_sun with V the visible fraction of the solar disc (radiance, RGB)."""
    for k in numba.prange(NS.shape[0]):
        if vis[k] <= 0.0:
            continue
        c = comp[k]
        r, g, b = brdf_cos(NS[k, 0], NS[k, 1], NS[k, 2], WO[k, 0], WO[k, 1], WO[k, 2], sx, sy, sz,
                           mat_diff[c, 0], mat_diff[c, 1], mat_diff[c, 2], mat_f0[c, 0], mat_f0[c, 1],
                           mat_f0[c, 2], mat_alpha[c])
        out[k, 0] += r * e_sun * vis[k]
        out[k, 1] += g * e_sun * vis[k]
        out[k, 2] += b * e_sun * vis[k]


@pjit
def cache_irradiance(values, valid, face_s, lat_start, lat_ids, face, B, SIDE, out):
    """Per point: a per-row cache quantity interpolated at (face, b1, b2, side)."""
    for k in numba.prange(face.shape[0]):
        r, g, b = interpolate_rows(values, valid, face_s, lat_start, lat_ids, face[k], B[k, 0], B[k, 1], SIDE[k])
        out[k, 0] = r
        out[k, 1] = g
        out[k, 2] = b


@pjit_exact
def take_rows(src, idx, out):
    """out[j] = src[idx[j]] (rows of 3): NumPy's ``src[idx]`` on both cores."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            out[j, a] = src[i, a]


@pjit_exact
def subsample_hits(idx, geom, prim, face_offset, D, centre, number, face, D_hit, pixel, num):
    """The rows ``idx`` of a batch of sub-pixel rays that hit: their faces, directions, pixels
    and numbers, gathered on both cores in one pass. NumPy's fancy indexing runs on one core
    at ~3 ns per element; here, in :func:`put_rows` and :func:`group_means` together it took
    ~25 ms per Tiangong frame at 16 gather rays (line profile)."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        face[j] = face_offset[geom[i]] + prim[i]
        for a in range(3):
            D_hit[j, a] = D[i, a]
        pixel[j] = centre[i]
        num[j] = number[i]


@pjit_exact
def put_rows(idx, src, out):
    """out[idx[j]] = src[j] (rows of 3): NumPy's ``out[idx] = src`` on both cores."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            out[i, a] = src[j, a]


@pjit_exact
def put_rows_nonnegative(idx, src, out):
    """out[idx[j]] = max(src[j], 0) (rows of 3; ``out`` float32): NumPy's
    ``out[idx] = np.maximum(src, 0.0)``, the same bits (−0 becomes +0, as np.maximum returns its
    second argument when they compare equal), without the temporary and on both cores."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            v = src[j, a]
            out[i, a] = np.float32(v if v > 0.0 else 0.0)


@pjit_exact
def group_means(L, S, out):
    """out[p] = mean of rows p·S … p·S + S − 1 of L (rows of 3), summed in order: the box
    filter of a pixel's S sub-samples."""
    for p in numba.prange(out.shape[0]):
        r = 0.0
        g = 0.0
        b = 0.0
        for k in range(p * S, p * S + S):
            r += L[k, 0]
            g += L[k, 1]
            b += L[k, 2]
        out[p, 0] = r / S
        out[p, 1] = g / S
        out[p, 2] = b / S


@pjit_exact
def subsample_contrast(L, S, out):
    """out[p] = (max − min)² over rows p·S … p·S + S − 1 of L (rows of 3) of R + G + B: the
    squared contrast that pixel's S sub-samples saw. The noise of a stratified estimate of a
    pixel is driven by what changes inside it: a step of height c across the pixel (a
    silhouette, a part boundary, a shadow) leaves a variance ∝ c² in each stratum it cuts
    (Mitchell 1996, "Consequences of stratified sampling in graphics", SIGGRAPH), so c² ranks
    pixels by their noise (used by ``raytrace.shade`` to pick where a second sub-sample
    pattern pays)."""
    for p in numba.prange(out.shape[0]):
        lo = np.inf
        hi = -np.inf
        for k in range(p * S, p * S + S):
            y = L[k, 0] + L[k, 1] + L[k, 2]
            lo = min(lo, y)
            hi = max(hi, y)
        out[p] = (hi - lo) * (hi - lo)


@pjit_exact
def hit_or_miss_rows(geom, out):
    """out[k] = 0 where ray k hit (geom ≥ 0), −1 where it missed (rows of 3)."""
    for k in numba.prange(geom.shape[0]):
        v = 0.0 if geom[k] >= 0 else -1.0
        for a in range(3):
            out[k, a] = v


@pjit_exact
def hit_or_miss(geom, out):
    """out[k] = 0 where ray k hit (geom ≥ 0), −1 where it missed."""
    for k in numba.prange(geom.shape[0]):
        out[k] = 0.0 if geom[k] >= 0 else -1.0


@pjit_exact
def put_weighted_rows(idx, X, Wt, out):
    """out[idx[j]] = Wt[idx[j]] · X[j] per channel (rows of 3)."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            out[i, a] = Wt[i, a] * X[j, a]


@pjit_exact
def take_add_rows(k, A, B, outA, outB):
    """outA[i] = A[k[i]] and outB[i] += B[k[i]] where k[i] ≥ 0 (rows of 3): a centre's filtered
    irradiance in place of the cache's, its specular correction added."""
    for i in numba.prange(k.shape[0]):
        j = k[i]
        if j >= 0:
            for a in range(3):
                outA[i, a] = A[j, a]
                outB[i, a] += B[j, a]


@pjit
def add_diffuse(E, comp, mat_diff, out):
    """out += ρ_d/π · E."""
    for k in numba.prange(E.shape[0]):
        c = comp[k]
        for a in range(3):
            out[k, a] += mat_diff[c, a] / math.pi * E[k, a]


@pjit
def mirror_rays(NS, NG, WO, P, eps, want, out_o, out_d):
    """Mirror direction of the view about the shading normal, where it leaves the surface."""
    for k in numba.prange(NS.shape[0]):
        c = NS[k, 0] * WO[k, 0] + NS[k, 1] * WO[k, 1] + NS[k, 2] * WO[k, 2]
        rx = 2.0 * c * NS[k, 0] - WO[k, 0]
        ry = 2.0 * c * NS[k, 1] - WO[k, 1]
        rz = 2.0 * c * NS[k, 2] - WO[k, 2]
        ok = want[k] and (rx * NG[k, 0] + ry * NG[k, 1] + rz * NG[k, 2] > 0.0)
        want[k] = ok
        out_d[k, 0] = rx
        out_d[k, 1] = ry
        out_d[k, 2] = rz
        for a in range(3):
            out_o[k, a] = P[k, a] + eps * NG[k, a]


@inline
def incoming_env(p, tex, ox, oy, oz, dx, dy, dz):
    """Radiance arriving along a ray (o, d) that escaped the target (d need not be unit): the
    environment's.

    The hot loops call this for their misses and :func:`incoming` only for their hits: a
    call that passes the ~17 arrays of :func:`incoming` costs about 0.3 µs per ray on this
    machine (measured: the gather of a 1280×960 Crew Dragon frame, 2.6 M rays, 93 % misses,
    240 ms with every ray through :func:`incoming`, 48 ms with this split)."""
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    return env.env_radiance(p, tex, ox, oy, oz, dx / dn, dy / dn, dz / dn)


@numba.njit(cache=True, fastmath=FASTMATH, nogil=True, forceinline=True)
def incoming(geom, prim, hu, hv, ox, oy, oz, dx, dy, dz, face_offset, face_normal, corner_normal, comp_of_face,
             mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
             vis_sun, eir, eig, eib):
    """Radiance arriving along a traced ray (o, d) that hit a surface (``geom`` ≥ 0; for a ray
    that escaped, :func:`incoming_env`): that surface's radiance towards the ray from the
    cache: diffuse ρ_d/π·E,
    the exact specular reflection of the Sun towards −d and the specular albedo times the
    rest of its irradiance over π. ``sun`` = (s_x, s_y, s_z, ν·E_sun). The Sun's visibility at
    the hit comes from the cache when ``vis_sun`` < 0, else it is ``vis_sun`` (a shadow ray
    cast from the hit): then the hit's sunlight is exact and only its indirect light comes
    from the cache, so shadows finer than the cache's lattice are not blurred into the light
    bounced off them. (``eir``, ``eig``, ``eib``) ≥ 0 is a traced continuation of the path from
    the hit (:func:`bounce2_rays`): on a part that is not ``glossy`` it is an estimate of the
    hit's indirect irradiance and replaces the cache's; on a glossy part (metal, MLI foil) it
    is an estimate of the specular reflection of everything but the Sun (one sample of the
    lobe), which replaces the uniform stand-in, and the small diffuse term keeps the cache."""
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    dx /= dn
    dy /= dn
    dz /= dn
    f = face_offset[geom] + prim
    side = 0 if dx * face_normal[f, 0] + dy * face_normal[f, 1] + dz * face_normal[f, 2] < 0.0 else 1
    r0, r1, r2, w0, w1, w2 = lattice_rows(valid, face_s, lat_start, lat_ids, f, hu, hv, side)
    er = w0 * E_tot[r0, 0] + w1 * E_tot[r1, 0] + w2 * E_tot[r2, 0]
    eg = w0 * E_tot[r0, 1] + w1 * E_tot[r1, 1] + w2 * E_tot[r2, 1]
    eb = w0 * E_tot[r0, 2] + w1 * E_tot[r1, 2] + w2 * E_tot[r2, 2]
    es = w0 * E_sun[r0] + w1 * E_sun[r1] + w2 * E_sun[r2]
    c = comp_of_face[f]
    b0 = 1.0 - hu - hv
    sgn = 1.0 if side == 0 else -1.0
    nx = sgn * (b0 * corner_normal[f, 0, 0] + hu * corner_normal[f, 1, 0] + hv * corner_normal[f, 2, 0])
    ny = sgn * (b0 * corner_normal[f, 0, 1] + hu * corner_normal[f, 1, 1] + hv * corner_normal[f, 2, 1])
    nz = sgn * (b0 * corner_normal[f, 0, 2] + hu * corner_normal[f, 1, 2] + hv * corner_normal[f, 2, 2])
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx /= nn
    ny /= nn
    nz /= nn
    cs = nx * sun[0] + ny * sun[1] + nz * sun[2]
    traced_spec = eir >= 0.0 and glossy[c]
    if vis_sun >= 0.0:  # exact sunlight replaces the cache's
        ex = vis_sun * sun[3] * cs if cs > 0.0 else 0.0
    else:
        ex = es
    if eir >= 0.0 and not traced_spec:  # a traced estimate replaces the indirect light
        er = eir + ex
        eg = eig + ex
        eb = eib + ex
    elif vis_sun >= 0.0:
        er = max(er - es, 0.0) + ex
        eg = max(eg - es, 0.0) + ex
        eb = max(eb - es, 0.0) + ex
    es = ex
    lr = mat_diff[c, 0] / math.pi * er
    lg = mat_diff[c, 1] / math.pi * eg
    lb = mat_diff[c, 2] / math.pi * eb
    if mat_f0[c, 0] > 0.0 or mat_f0[c, 1] > 0.0 or mat_f0[c, 2] > 0.0:
        mu = -(nx * dx + ny * dy + nz * dz)
        if mu > 0.0:
            if es > 0.0 and cs > 0.0 and sun[3] > 0.0:
                vis = min(es / (sun[3] * cs), 1.0)
                sr, sg, sb = brdf_cos(nx, ny, nz, -dx, -dy, -dz, sun[0], sun[1], sun[2], 0.0, 0.0, 0.0,
                                      mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2], mat_alpha[c])
                lr += sr * sun[3] * vis
                lg += sg * sun[3] * vis
                lb += sb * sun[3] * vis
            if traced_spec:
                lr += eir
                lg += eig
                lb += eib
            else:
                ar, ag, ab = specular_albedo(table, mu, mat_alpha[c], mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2])
                lr += ar * max(er - es, 0.0) / math.pi
                lg += ag * max(eg - es, 0.0) / math.pi
                lb += ab * max(eb - es, 0.0) / math.pi
    return lr, lg, lb


# the mirror term (add_mirror) turns from the mirror ray (α ≤ GLOSSY_A0) to the prefiltered
# environment plus the parts' change of it (α ≥ GLOSSY_A1); where the mirror ray hits a part,
# only GLOSSY_HIT of that weight goes to the prefiltered side. Chosen on the four targets with
# their real materials at 640×480 (Sun, Earth 400 km below, sky 1 W/(m²·sr); against
# ``reference`` at 256 spp × 2; ``fast`` error of Tiangong / Crew Dragon / ICESat / Cassini):
# before (E/π for wide lobes) 11.3 / 3.7 / 17.1 / 10.9 %; prefiltered with GLOSSY_HIT 1:
# 11.1 / 3.7 / 16.5 / 10.6 %; 0 (a hit is the mirror ray's alone): 15.4 / 4.3 / 29.0 / 15.3 %;
# 0.5: 10.5 / 3.2 / 13.9 / 9.6 %; 0.6: 10.0 / 3.2 / 12.3 / 9.1 %; 0.7: 9.9 / 3.2 / 11.8 / 9.0 %;
# 0.8: 10.0 / 3.3 / 12.4 / 9.2 %; then GLOSSY_A1 0.35 → 0.2 with 0.7: 9.7 / 3.2 / 11.5 / 9.1 %
GLOSSY_A0 = 0.05
GLOSSY_A1 = 0.2
GLOSSY_HIT = 0.7
# ``balanced``'s mirror term (add_mirror) blends from the mirror ray to E/π by
# t = (α − MIRROR_BLEND_A0) / MIRROR_BLEND_WIDTH clamped to [0, 1]; where t = 1 it casts no
# mirror ray (shade._Context.mirror_weighted, the same expression)
MIRROR_BLEND_A0 = 0.05
MIRROR_BLEND_WIDTH = 0.3


@pjit
def add_mirror(idx, O, D, geom, prim, hu, hv, NS, WO, comp, E_point, face_offset, face_normal, corner_normal,
               comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start,
               lat_ids, p, tex, prefiltered, E_unocc, glossy_env, glossy_level, out, out_lbar):
    """out += L̄_in · (F0·A + B): the specular reflection of the environment and other parts.

    ``prefiltered`` (``fast``, where this term is the answer): L̄_in is blended by the lobe
    width α (weight t of the second from 0 at α ≤ GLOSSY_A0 to 1 at α ≥ GLOSSY_A1, times
    GLOSSY_HIT where the mirror ray hits a part) from the radiance along the mirror direction r
    (sharp lobes) to

        L̄_env(r, α) + (E − E_env(n)) / π,

    the unoccluded environment prefiltered by the lobe (:func:`raytrace.environment.glossy_table`,
    ``glossy_env[glossy_level[comp]]``) plus what the parts change about it: the point's own
    indirect irradiance ``E_point`` minus the environment's unoccluded irradiance on its plane
    (``E_unocc``), spread as if uniformly (the light the parts add, less the sky they hide).
    On an open surface that second term vanishes and the reflection of Earth's disc, its limb
    and terminator follows the lobe. Otherwise (``balanced``, where this term is the control
    variate of the sampled lobe, :func:`lobe_sum`, or the answer on parts whose specular albedo
    is too small to be worth sampling, ``shade.LOBE_MIN_SPECULAR``) L̄_in blends from the mirror ray
    (α ≤ 0.05) to E/π (α ≥ 0.35), the environment as if it arrived uniformly: smooth, it kept
    ``balanced``'s filtered residual nearer the truth on the four targets with real materials
    (8 rays, 640×480: 7.55 / 2.12 / 7.31 / 5.41 % against 7.62 / 2.08 / 7.39 / 5.64 % with the
    prefiltered form), while as an answer it made a gold sphere under Earth 0.73–1.79× the path
    tracer's per quadrant (prefiltered: 0.91–1.07×). L̄_in itself goes to ``out_lbar``."""
    for j in numba.prange(idx.shape[0]):
        k = idx[j]
        if geom[j] < 0:
            r, g, b = incoming_env(p, tex, O[j, 0], O[j, 1], O[j, 2], D[j, 0], D[j, 1], D[j, 2])
        else:
            r, g, b = incoming(geom[j], prim[j], hu[j], hv[j], O[j, 0], O[j, 1], O[j, 2], D[j, 0], D[j, 1], D[j, 2],
                               face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy,
                               table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex, -1.0, -1.0, -1.0, -1.0)
        c = comp[k]
        if not prefiltered:
            t = min(max((mat_alpha[c] - MIRROR_BLEND_A0) / MIRROR_BLEND_WIDTH, 0.0), 1.0)
            r = (1.0 - t) * r + t * E_point[k, 0] / math.pi
            g = (1.0 - t) * g + t * E_point[k, 1] / math.pi
            b = (1.0 - t) * b + t * E_point[k, 2] / math.pi
            t = 0.0
        else:
            t = min(max((mat_alpha[c] - GLOSSY_A0) / (GLOSSY_A1 - GLOSSY_A0), 0.0), 1.0)
            if geom[j] >= 0:
                t *= GLOSSY_HIT
        if t > 0.0:
            er, eg, eb = env.irradiance_lookup(E_unocc, NS[k, 0], NS[k, 1], NS[k, 2])
            lr, lg, lb = env.irradiance_lookup(glossy_env[glossy_level[c]], D[j, 0], D[j, 1], D[j, 2])
            r = (1.0 - t) * r + t * max(lr + (E_point[k, 0] - er) / math.pi, 0.0)
            g = (1.0 - t) * g + t * max(lg + (E_point[k, 1] - eg) / math.pi, 0.0)
            b = (1.0 - t) * b + t * max(lb + (E_point[k, 2] - eb) / math.pi, 0.0)
        mu = NS[k, 0] * WO[k, 0] + NS[k, 1] * WO[k, 1] + NS[k, 2] * WO[k, 2]
        ar, ag, ab = specular_albedo(table, mu, mat_alpha[c], mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2])
        out_lbar[k, 0] = r
        out_lbar[k, 1] = g
        out_lbar[k, 2] = b
        out[k, 0] += r * ar
        out[k, 1] += g * ag
        out[k, 2] += b * ab


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
    sequence (:func:`owen_sobol2`, keyed by pixel and seed) in (radius², azimuth). Any 2^m of
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
def bounce_sun_rays(O, D, tfar, geom, prim, face_offset, face_normal, sx, sy, sz, eps, want, out_o):
    """Shadow rays towards the Sun from the hits of traced rays (o + t·d, offset along the
    geometric normal on the side the ray arrived from), wanted where that side faces the Sun."""
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
    specular reflection is weight·L_in, :func:`incoming`). Wanted where the draw succeeds and
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
                  mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex, vis, e_ind, out):
    """:func:`incoming` along each ray (the Sun's visibility at its hit from ``vis``, its
    indirect irradiance from ``e_ind`` where ≥ 0, else from the cache)."""
    for m in numba.prange(D.shape[0]):
        if geom[m] < 0:
            out[m, 0], out[m, 1], out[m, 2] = incoming_env(p, tex, O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2])
            continue
        out[m, 0], out[m, 1], out[m, 2] = incoming(
            geom[m], prim[m], hu[m], hv[m], O[m, 0], O[m, 1], O[m, 2], D[m, 0], D[m, 1], D[m, 2], face_offset,
            face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun,
            valid, face_s, lat_start, lat_ids, p, tex, vis[m], e_ind[m, 0], e_ind[m, 1], e_ind[m, 2])


@pjit
def gather_sum(start, O, D, NG, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face,
               mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex, vis,
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
    per-ray terms: s²/N [(W/m²)²], which guides :func:`atrous` (0 for N = 1)."""
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


@pjit_exact
def same_part_mean(img, inst, r, out):
    """out[v, u] = the mean of img over the other pixels of the same part (inst equal to its
    own) among the (2r + 1)² around (v, u), or img[v, u] where there is none; left alone off
    the target (inst 0). Leaving the pixel itself out keeps a two-pass gather's allocation
    independent of the pixel's own first-pass rays (:func:`raytrace.shade._gather_two_pass`)."""
    H, W = inst.shape
    for v in numba.prange(H):
        for u in range(W):
            if inst[v, u] == 0:
                continue
            sv, nv = _same_part_sum(img, inst, v, u, r, False)
            out[v, u] = sv / nv if nv > 0 else img[v, u]


@pjit_exact
def filter_variance(inst, passes, out):
    """out[v, u] = the variance that ``passes`` à-trous passes (pass k: the 5×5 B3-spline kernel
    with holes of 2^k pixels, :func:`atrous`) leave of independent unit-variance noise at each
    pixel of the target (inst > 0), when a neighbour counts only on the pixel's own part (the
    geometric weights' first factor, the id; normals and depths not looked at): each pass
    takes v' = Σ w² v / (Σ w)² over the neighbours, the propagation :func:`atrous` applies to
    its variance channel. 1 where no pass ran (passes = 0); a part's border keeps more than its
    interior, a part one pixel wide the most. 0 off the target. It steers the two-pass final
    gather (:func:`raytrace.shade._gather_two_pass`).

    Each row is summed kernel tap by kernel tap over row slices indexed from 0, without
    branches, so the loops vectorise: 7 ms for a 1250 × 170 box and 30 ms for a whole
    1280 × 960 frame (two passes, one thread), where a loop over pixels visiting their 25
    neighbours in turn took 12 and 80 ms."""
    H, W = inst.shape
    h = (1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0)
    cur = np.empty((H, W))
    nxt = np.empty((H, W))
    for v in numba.prange(H):
        for u in range(W):
            cur[v, u] = 1.0 if inst[v, u] > 0 else 0.0
    step = 1
    for _ in range(passes):
        for v in numba.prange(H):
            sw = np.zeros(W)
            sw2v = np.zeros(W)
            own = inst[v]
            for a in range(5):
                vv = v + (a - 2) * step
                if vv < 0 or vv >= H:
                    continue
                ids = inst[vv]
                vals = cur[vv]
                for b in range(5):
                    off = (b - 2) * step
                    lo = max(0, -off)
                    hi = min(W, W - off)
                    if hi <= lo:
                        continue
                    w = h[a] * h[b]
                    w2 = w * w
                    n = hi - lo
                    own_s = own[lo:hi]
                    ids_s = ids[lo + off:hi + off]
                    vals_s = vals[lo + off:hi + off]
                    sw_s = sw[lo:hi]
                    sw2v_s = sw2v[lo:hi]
                    for k in range(n):
                        m = 1.0 if ids_s[k] == own_s[k] else 0.0
                        sw_s[k] += w * m
                        sw2v_s[k] += w2 * m * vals_s[k]
            for u in range(W):
                nxt[v, u] = sw2v[u] / (sw[u] * sw[u]) if own[u] > 0 else 0.0
        cur, nxt = nxt, cur
        step *= 2
    for v in numba.prange(H):
        for u in range(W):
            out[v, u] = cur[v, u]


@inline
def _same_part_sum(img, inst, v, u, r, with_centre):
    """Σ img and the number of pixels over the (2r + 1)² around (v, u) whose id is its own
    (itself included or not)."""
    H, W = inst.shape
    i0 = inst[v, u]
    sv = 0.0
    nv = 0
    for vv in range(max(v - r, 0), min(v + r + 1, H)):
        for uu in range(max(u - r, 0), min(u + r + 1, W)):
            if inst[vv, uu] == i0 and (with_centre or vv != v or uu != u):
                sv += img[vv, uu]
                nv += 1
    return sv, nv


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


# the filter kernels are compiled without fastmath: with it, the code numba loads from its cache
# and the code it has just compiled rounded differently (the same seed gave a first render after
# an install that differed from every later one; tests/raytrace/test_filter.py)
@pjit_exact
def guide_images(img, var, inst, lum, vblur):
    """The guides of :func:`atrous` for one pass: each target pixel's luminance of
    channels 0–2 (Rec. 709) and the mean of ``var`` over its 3×3 neighbours on the same part."""
    H, W = inst.shape
    for v in numba.prange(H):
        for u in range(W):
            i0 = inst[v, u]
            if i0 == 0:
                continue
            lum[v, u] = 0.2126 * img[v, u, 0] + 0.7152 * img[v, u, 1] + 0.0722 * img[v, u, 2]
            sv, nv = _same_part_sum(var, inst, v, u, 1, True)
            vblur[v, u] = sv / nv


@pjit_exact
def atrous(img, var, vblur, lum, inst, normal, depth, fx, fy, cx, cy, step, sigma_l, out, out_var):
    """One pass of the edge-avoiding à-trous wavelet filter (Dammertz et al. 2010,
    doi:10.2312/EGGH/HPG10/067-075): a 5×5 B3-spline kernel with holes of ``step`` pixels,
    weighted by same instance id, normal agreement (n·n')^64 and distance from the centre
    pixel's tangent plane (in units of the pixel footprint). ``img`` has any number of
    channels, all filtered with the same weights; (cx, cy) is the principal point in the
    coordinates of the (cropped) image.

    With σ_l > 0 it also stops at edges of the residual itself, after SVGF (Schied et al. 2017,
    doi:10.1145/3105762.3105770, eq. 5) but symmetric: a neighbour's weight is further
    multiplied by exp(−|l − l'| / (σ_l·√(v + v'))), where l is the luminance of channels 0–2
    (``lum``) and v the variance of a pixel's estimate (``var``) averaged over its 3×3
    same-part neighbours (``vblur``; both from :func:`guide_images`). |l − l'|/√(v + v') is the
    z-score of the difference of two estimates, so a step in the residual larger than the
    noise — contact shadow, gap, crease — is kept while noise is smoothed, and a noisy bright
    pixel and its quiet neighbour are averaged both ways (SVGF's one-sided √v would keep the
    quiet ones from taking the bright one's energy and darken the image). With σ_l = 0 the
    weights depend on the geometry only and ``vblur``, ``lum`` are not read. The variance is
    carried through the pass (v' = Σ w² v / (Σ w)²) for the next."""
    H, W = inst.shape
    C = img.shape[2]
    h = (1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0)
    s2 = sigma_l * sigma_l
    guided = sigma_l > 0.0
    ifx = 1.0 / fx
    ify = 1.0 / fy
    for v in numba.prange(H):
        acc = np.zeros(C)
        for u in range(W):
            i0 = inst[v, u]
            if i0 == 0:
                continue
            vb0 = vblur[v, u] if guided else 0.0
            l0 = lum[v, u] if guided else 0.0
            z0 = depth[v, u]
            n0x = normal[v, u, 0]
            n0y = normal[v, u, 1]
            n0z = normal[v, u, 2]
            # 1 / (pixel footprint · (1 + step)): tangent-plane distances in footprints (a camera
            # touching a surface sees it at depth 0: a huge but finite 1/footprint, no 0·∞)
            ik = fx / (max(z0, 1e-12) * (1.0 + step))
            for c in range(C):
                acc[c] = 0.0
            sw = 0.0
            sw2v = 0.0
            for a in range(5):
                vv = v + (a - 2) * step
                if vv < 0 or vv >= H:
                    continue
                ha = h[a]
                for b in range(5):
                    uu = u + (b - 2) * step
                    if uu < 0 or uu >= W or inst[vv, uu] != i0:
                        continue
                    nd = n0x * normal[vv, uu, 0] + n0y * normal[vv, uu, 1] + n0z * normal[vv, uu, 2]
                    if nd <= 0.0:
                        continue
                    wn = nd * nd  # (n·n')^64 by six squarings
                    wn *= wn
                    wn *= wn
                    wn *= wn
                    wn *= wn
                    wn *= wn
                    z1 = depth[vv, uu]
                    dz = z1 - z0
                    dxp = ((uu - u) * z1 + (u - cx) * dz) * ifx
                    dyp = ((vv - v) * z1 + (v - cy) * dz) * ify
                    dist = abs(n0x * dxp + n0y * dyp + n0z * dz) * ik
                    if guided:
                        dist += abs(lum[vv, uu] - l0) / math.sqrt(s2 * (vb0 + vblur[vv, uu]) + 1e-60)
                    w = ha * h[b] * wn * math.exp(-dist)
                    for c in range(C):
                        acc[c] += w * img[vv, uu, c]
                    sw += w
                    sw2v += w * w * var[vv, uu]
            isw = 1.0 / sw
            for c in range(C):
                out[v, u, c] = acc[c] * isw
            out_var[v, u] = sw2v * isw * isw


@pjit_exact
def residual_image(rows, var, av, au, unit, img, var_img):
    """The per-pixel rows (n, 3) and their variances into the (zeroed) images of the residual
    filter at (av[k], au[k]); with 14 channels also the local-linear fit's moments: y·u, y·v,
    u, v, u², u·v, v² (u, v the pixel's coordinates in units of ``unit`` pixels)."""
    linear = img.shape[2] == 14
    for k in numba.prange(rows.shape[0]):
        v = av[k]
        w = au[k]
        var_img[v, w] = var[k]
        for c in range(3):
            img[v, w, c] = rows[k, c]
        if linear:
            x = w / unit
            y = v / unit
            for c in range(3):
                img[v, w, 3 + c] = rows[k, c] * x
                img[v, w, 6 + c] = rows[k, c] * y
            img[v, w, 9] = x
            img[v, w, 10] = y
            img[v, w, 11] = x * x
            img[v, w, 12] = x * y
            img[v, w, 13] = y * y


@pjit_exact
def residual_rows(img, av, au, unit, ridge, beta, out):
    """The filtered residual at each pixel (av[k], au[k]) of ``img``: channels 0–2 (the
    weighted mean), or, with 14 channels (:func:`residual_image`), the weighted least-squares
    plane through the kernel's neighbours at the pixel, its slope scaled by β, from the
    filtered moments (a ridge on the coordinates' covariance)."""
    linear = img.shape[2] == 14
    for k in numba.prange(out.shape[0]):
        v = av[k]
        w = au[k]
        if not linear:
            for c in range(3):
                out[k, c] = img[v, w, c]
            continue
        mu = img[v, w, 9]
        mv = img[v, w, 10]
        cuu = img[v, w, 11] - mu * mu + ridge
        cuv = img[v, w, 12] - mu * mv
        cvv = img[v, w, 13] - mv * mv + ridge
        det = cuu * cvv - cuv * cuv
        du = w / unit - mu
        dv = v / unit - mv
        for c in range(3):
            mean = img[v, w, c]
            cyu = img[v, w, 3 + c] - mean * mu
            cyv = img[v, w, 6 + c] - mean * mv
            b = (cyu * cvv - cyv * cuv) / det
            g = (cyv * cuu - cyu * cuv) / det
            out[k, c] = mean + beta * (b * du + g * dv)


@inline
def _three_rows(img, v, vm, vp, lo, hi):
    """Columns lo:hi of rows v, vm (above) and vp (below) of ``img`` (views)."""
    return img[v, lo:hi], img[vm, lo:hi], img[vp, lo:hi]


@inline
def _id_or_earth_differs(a, am, ap, e, em, ep, k, left, right):
    """:func:`edge_pixels`' id and Earth test of pixel k of row slice ``a``/``e`` (rows above
    and below ``am``/``ap``, ``em``/``ep``), with or without its left and right neighbours."""
    x = a[k]
    y = e[k]
    f = (am[k] != x) | (ap[k] != x) | (em[k] != y) | (ep[k] != y)
    if left:
        f = f | (a[k - 1] != x) | (e[k - 1] != y)
    if right:
        f = f | (a[k + 1] != x) | (e[k + 1] != y)
    return f


@inline
def _differs(l0, n0, d0, k, l1, n1, d1, j):
    """:func:`edge_pixels`' shading test between pixel k of one row's lit, normal and depth
    slices and pixel j of another's (or the same)."""
    if l1[j] != l0[k]:
        return True
    nd = n0[k, 0] * n1[j, 0] + n0[k, 1] * n1[j, 1] + n0[k, 2] * n1[j, 2]
    return nd < 0.9 or abs(d1[j] - d0[k]) > 0.03 * d0[k]


@pjit
def edge_pixels(inst, lit_img, normal, depth, earth_px, rect, out):
    """Pixels whose 4-neighbours disagree: another id (or Earth vs space), lit vs shadowed,
    a crease (normals > ~25° apart) or a depth step (> 3 % of the depth); neighbours outside
    the image do not count. Sets ``out`` inside ``rect`` = (u0, v0, u1, v1), ends excluded.

    Per row, the loops run over row slices that start one pixel left of the first pixel with
    a left neighbour, and index from a constant: numba wraps negative indices, and where it
    cannot prove an index ≥ 0 (a start taken from ``rect``) the select it adds kept LLVM from
    vectorising. Written as one loop with the neighbours' offsets computed per pixel, the
    kernel took 10–14 ms on a 1280 × 960 Earth view (every pixel checked); this way 2–4 ms,
    the same flags (``tests/raytrace/test_edge_pixels.py``)."""
    H, W = inst.shape
    u0, v0, u1, v1 = rect[0], rect[1], rect[2], rect[3]
    if u1 <= u0 or v1 <= v0:
        return
    lo = max(u0, 1) - 1
    hi = min(u1, W - 1) + 1
    n = hi - lo
    for v in numba.prange(v0, v1):
        vm = v - 1 if v > 0 else v
        vp = v + 1 if v < H - 1 else v
        a, am, ap = _three_rows(inst, v, vm, vp, lo, hi)
        e, em, ep = _three_rows(earth_px, v, vm, vp, lo, hi)
        o = out[v, lo:hi]
        for k in range(1, n - 1):
            x = a[k]
            y = e[k]
            o[k] = ((a[k + 1] != x) | (a[k - 1] != x) | (am[k] != x) | (ap[k] != x)
                    | (e[k + 1] != y) | (e[k - 1] != y) | (em[k] != y) | (ep[k] != y))
        if u0 == 0:
            o[0] = _id_or_earth_differs(a, am, ap, e, em, ep, 0, False, n > 1)
        if u1 == W:
            o[n - 1] = _id_or_earth_differs(a, am, ap, e, em, ep, n - 1, n > 1, False)
        # lit/shadow, creases and depth steps: between target pixels only
        first = u0 - lo
        while first < u1 - lo and a[first] == 0:
            first += 1
        last = u1 - lo - 1
        while last >= first and a[last] == 0:
            last -= 1
        if first > last:
            continue
        li, lm, lp = _three_rows(lit_img, v, vm, vp, lo, hi)
        nr, nm, npl = _three_rows(normal, v, vm, vp, lo, hi)
        dr, dm, dp = _three_rows(depth, v, vm, vp, lo, hi)
        # pixels with both horizontal neighbours in the slices: shifted views, so that the loop
        # indexes from 0 and vectorises
        ks = max(first, 1)
        ke = min(last + 1, n - 1)
        if ke > ks:
            c_a, c_o = a[ks:ke], o[ks:ke]
            c_l, c_n, c_d = li[ks:ke], nr[ks:ke], dr[ks:ke]
            w_l, w_n, w_d = li[ks - 1:ke - 1], nr[ks - 1:ke - 1], dr[ks - 1:ke - 1]
            e_l, e_n, e_d = li[ks + 1:ke + 1], nr[ks + 1:ke + 1], dr[ks + 1:ke + 1]
            m_l, m_n, m_d = lm[ks:ke], nm[ks:ke], dm[ks:ke]
            p_l, p_n, p_d = lp[ks:ke], npl[ks:ke], dp[ks:ke]
            for j in range(ke - ks):
                l0 = c_l[j]
                d0 = c_d[j]
                tol = 0.03 * d0
                n0, n1, n2 = c_n[j, 0], c_n[j, 1], c_n[j, 2]
                f = ((w_l[j] != l0) | (e_l[j] != l0) | (m_l[j] != l0) | (p_l[j] != l0)
                     | (n0 * w_n[j, 0] + n1 * w_n[j, 1] + n2 * w_n[j, 2] < 0.9)
                     | (n0 * e_n[j, 0] + n1 * e_n[j, 1] + n2 * e_n[j, 2] < 0.9)
                     | (n0 * m_n[j, 0] + n1 * m_n[j, 1] + n2 * m_n[j, 2] < 0.9)
                     | (n0 * p_n[j, 0] + n1 * p_n[j, 1] + n2 * p_n[j, 2] < 0.9)
                     | (abs(w_d[j] - d0) > tol) | (abs(e_d[j] - d0) > tol)
                     | (abs(m_d[j] - d0) > tol) | (abs(p_d[j] - d0) > tol))
                c_o[j] = c_o[j] | ((c_a[j] != 0) & f)
        for k in (first, last):
            if (k >= ks and k < ke) or o[k] or a[k] == 0:
                continue
            # a neighbour outside the image: the pixel itself, which never differs from itself
            # (the same holds for the rows above and below at the image's top and bottom; a
            # target pixel's normal is a unit vector)
            kl = k - 1 if k + lo > 0 else k
            kr = k + 1 if k + lo < W - 1 else k
            o[k] = (_differs(li, nr, dr, k, li, nr, dr, kl) or _differs(li, nr, dr, k, li, nr, dr, kr)
                    or _differs(li, nr, dr, k, lm, nm, dm, k) or _differs(li, nr, dr, k, lp, npl, dp, k))


@inline
def _centre_on_surface(q, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot):
    """The row of pixel q's centre if sub-sample m (part ``comp``, point P, shading normal NS)
    lies on its surface — same part, normals within ~25°, within a pixel footprint of the
    centre's tangent plane —, else −1."""
    k = row_of_pixel[q]
    if k < 0 or inst[q] - 1 != comp[m]:
        return -1
    if NS[m, 0] * N_c[k, 0] + NS[m, 1] * N_c[k, 1] + NS[m, 2] * N_c[k, 2] <= 0.9:
        return -1
    dx = P[m, 0] - P_c[k, 0]
    dy = P[m, 1] - P_c[k, 1]
    dz = P[m, 2] - P_c[k, 2]
    if abs(dx * N_c[k, 0] + dy * N_c[k, 1] + dz * N_c[k, 2]) > foot[k]:
        return -1
    return k


@pjit_exact
def donor_rows(centre, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c, foot, borrow, out):
    """For each sub-sample (pixel ``centre``, part ``comp``, point P, shading normal NS): the
    row of the pixel centre whose filtered light it takes, −1 for none. Its own pixel's
    centre if that lies on the same surface (same part, normals within 25°, the point within
    a pixel footprint of the centre's tangent plane); otherwise, with ``borrow``, the nearest
    (in space) of the 8 neighbouring centres on its surface; otherwise none."""
    for m in numba.prange(centre.shape[0]):
        c = centre[m]
        v = c // W
        u = c % W
        best = -1
        best_d2 = np.inf
        for a in range(10 if borrow else 1):  # a = 0: the pixel itself; a = 1..9: its 3 × 3 neighbourhood
            dv = (a - 1) // 3 - 1 if a > 0 else 0
            du = (a - 1) % 3 - 1 if a > 0 else 0
            if a == 5:
                continue  # the pixel itself again
            vv = v + dv
            uu = u + du
            if vv < 0 or vv >= H or uu < 0 or uu >= W:
                continue
            k = _centre_on_surface(vv * W + uu, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot)
            if k < 0:
                continue
            if a == 0:
                best = k
                break
            dx = P[m, 0] - P_c[k, 0]
            dy = P[m, 1] - P_c[k, 1]
            dz = P[m, 2] - P_c[k, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best_d2:
                best_d2 = d2
                best = k
        out[m] = best


@pjit_exact
def interpolate_rows_into(sel, D, R_cam_from_body, fx, fy, cx, cy, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c,
                          foot, A, B, min_found, outA, outB, added):
    """For the listed sub-samples i (ray direction D[i], body frame; part ``comp``, point P,
    shading normal NS): outA[i] = Σ_j w_j A[k_j] (in place of what it held: the centres' filtered
    irradiance instead of the cache's) and outB[i] += Σ_j w_j B[k_j], over the (up to) four
    pixel centres k_j around the sub-sample's image point on its own surface
    (:func:`_centre_on_surface`), w_j their bilinear weights renormalised over those found (pixel
    centres at integer image coordinates). Nothing is added where fewer than ``min_found``
    (≥ 1) of the four are on its surface (outA and outB keep their values); added[t] tells
    whether sub-sample sel[t] was."""
    for t in numba.prange(sel.shape[0]):
        m = sel[t]
        xc = R_cam_from_body[0, 0] * D[m, 0] + R_cam_from_body[0, 1] * D[m, 1] + R_cam_from_body[0, 2] * D[m, 2]
        yc = R_cam_from_body[1, 0] * D[m, 0] + R_cam_from_body[1, 1] * D[m, 1] + R_cam_from_body[1, 2] * D[m, 2]
        zc = R_cam_from_body[2, 0] * D[m, 0] + R_cam_from_body[2, 1] * D[m, 1] + R_cam_from_body[2, 2] * D[m, 2]
        uf = fx * xc / zc + cx
        vf = fy * yc / zc + cy
        u0 = int(math.floor(uf))
        v0 = int(math.floor(vf))
        fu = uf - u0
        fv = vf - v0
        sw = 0.0
        found = 0
        a0 = a1 = a2 = b0 = b1 = b2 = 0.0
        for j in range(4):
            uu = u0 + (j & 1)
            vv = v0 + (j >> 1)
            if vv < 0 or vv >= H or uu < 0 or uu >= W:
                continue
            k = _centre_on_surface(vv * W + uu, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot)
            if k < 0:
                continue
            w = (fu if j & 1 else 1.0 - fu) * (fv if j >> 1 else 1.0 - fv)
            found += 1
            sw += w
            a0 += w * A[k, 0]
            a1 += w * A[k, 1]
            a2 += w * A[k, 2]
            b0 += w * B[k, 0]
            b1 += w * B[k, 1]
            b2 += w * B[k, 2]
        added[t] = found >= min_found and sw > 0.0
        if added[t]:
            outA[m, 0] = a0 / sw
            outA[m, 1] = a1 / sw
            outA[m, 2] = a2 / sw
            outB[m, 0] += b0 / sw
            outB[m, 1] += b1 / sw
            outB[m, 2] += b2 / sw


@inline
def _project(V, i, R, t, fx, fy, cx, cy):
    """Pixel coordinates and z-depth of vertex i (p_cam = R p + t); (0, 0, z) when z ≤ 0."""
    xc = R[0, 0] * V[i, 0] + R[0, 1] * V[i, 1] + R[0, 2] * V[i, 2] + t[0]
    yc = R[1, 0] * V[i, 0] + R[1, 1] * V[i, 1] + R[1, 2] * V[i, 2] + t[1]
    zc = R[2, 0] * V[i, 0] + R[2, 1] * V[i, 1] + R[2, 2] * V[i, 2] + t[2]
    if zc <= 0.0:
        return 0.0, 0.0, zc
    return fx * xc / zc + cx, fy * yc / zc + cy, zc


@pjit
def sliver_pixels(V, F, R, t, fx, fy, cx, cy, z_min, max_width, depth, out):
    """Pixels touched by triangles whose projection is a sliver: narrower than ``max_width``
    pixels (twice its area over its longest edge) — a rod, wire or panel seen edge-on that
    can fall between pixel centres and corners, or a part smaller than a pixel (a triangle
    shorter than a pixel as well: in ``fast``, which casts no corner rays, this is what finds
    an antenna tip that no pixel centre hits; at 1280×960 the 12 benchmark scenes have none
    in front of another surface, at 160×120 they do). Marks ``out``
    (H, W) conservatively: every pixel square the projected triangle overlaps (separating
    axes: the square's two and the triangle's three edge normals) where the triangle's
    nearest point is nearer than the pixel centre's surface (``depth``, z-depth, inf on
    space) by more than 0.1 %: a sliver hidden behind that surface, or lying in it (the
    tessellation of a surface seen at a grazing angle), needs no extra samples. Triangles
    with a vertex nearer than ``z_min`` are skipped (the target is in front of the camera)."""
    H, W = out.shape
    for f in numba.prange(F.shape[0]):  # threads may mark a pixel at once: all write True
        # the three projected vertices as tuples (no array allocated per triangle)
        u_0, v_0, z_0 = _project(V, F[f, 0], R, t, fx, fy, cx, cy)
        u_1, v_1, z_1 = _project(V, F[f, 1], R, t, fx, fy, cx, cy)
        u_2, v_2, z_2 = _project(V, F[f, 2], R, t, fx, fy, cx, cy)
        if z_0 <= z_min or z_1 <= z_min or z_2 <= z_min:
            continue
        z_near = min(z_0, z_1, z_2)
        px = (u_0, u_1, u_2)
        py = (v_0, v_1, v_2)
        area2 = abs((px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]))
        longest = 0.0
        for k in range(3):
            j = (k + 1) % 3
            longest = max(longest, math.hypot(px[j] - px[k], py[j] - py[k]))
        if area2 >= max_width * longest or longest > 4.0 * (W + H):
            continue  # (the last: a surface grazing the camera, not a wire)
        # pixel k spans [k − ½, k + ½]: the square's own axes are this bounding box
        u0 = max(math.ceil(min(px[0], px[1], px[2]) - 0.5), 0)
        u1 = min(math.floor(max(px[0], px[1], px[2]) + 0.5), W - 1)
        v0 = max(math.ceil(min(py[0], py[1], py[2]) - 0.5), 0)
        v1 = min(math.floor(max(py[0], py[1], py[2]) + 0.5), H - 1)
        # edge lines a·u + b·v + c ≥ 0 inside (orientation fixed by the sign of the area)
        sgn = 1.0 if (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]) > 0.0 else -1.0
        for v in range(v0, v1 + 1):
            # each edge's test is linear in u along the row: the u where it can pass, widened by
            # a pixel against rounding, bounds the pixels tested (a long diagonal wire's box is
            # mostly empty); the test below decides each of them as before
            ua = float(u0)
            ub = float(u1)
            for k in range(3):
                j = (k + 1) % 3
                a = -(py[j] - py[k]) * sgn
                b = (px[j] - px[k]) * sgn
                c = -(a * px[k] + b * py[k])
                r = b * v + c + 0.5 * (abs(a) + abs(b))  # the test: a·u + r ≥ 0
                # (an edge less than 10⁻³ px high bounds nothing: there the rounding of r,
                # ~10⁻⁸ px·px with coordinates ≲ 10⁴ px, divided by a could pass the widening)
                if a > 1e-3:
                    ua = max(ua, -r / a - 1.0)
                elif a < -1e-3:
                    ub = min(ub, -r / a + 1.0)
            if not ua <= ub:
                continue
            for u in range(int(math.ceil(ua)), int(math.floor(ub)) + 1):
                inside = True
                for k in range(3):
                    j = (k + 1) % 3
                    a = -(py[j] - py[k]) * sgn
                    b = (px[j] - px[k]) * sgn
                    c = -(a * px[k] + b * py[k])
                    # the square's farthest corner along (a, b) is inside the half-plane?
                    if a * u + b * v + c + 0.5 * (abs(a) + abs(b)) < 0.0:
                        inside = False
                        break
                if inside and z_near < 0.999 * depth[v, u]:
                    out[v, u] = True


@jit
def _edge_top(xa, ha, xb, hb, lo, hi):
    """Highest point over [lo, hi] of the segment from (xa, ha) to (xb, hb) (x along an axis,
    h the height), −inf where they do not overlap."""
    x0 = min(xa, xb)
    x1 = max(xa, xb)
    l0 = max(lo, x0)
    l1 = min(hi, x1)
    if l0 > l1:
        return -np.inf
    if x1 - x0 <= 0.0:
        return max(ha, hb)
    f0 = (l0 - xa) / (xb - xa)
    f1 = (l1 - xa) / (xb - xa)
    return max(ha + f0 * (hb - ha), ha + f1 * (hb - ha))


@jit
def shadow_map_of_slivers(V, F, e1, e2, s, a0, b0, cell, max_width, grid):
    """Conservative shadow map of the triangles that are slivers seen from the Sun: in the
    Sun's view (orthographic along the unit vector ``s`` towards the Sun, axes ``e1``, ``e2``,
    cells of ``cell`` metres from (a0, b0)), every triangle narrower than ``max_width`` metres
    (twice its projected area over its longest projected edge) writes into every cell its
    projection overlaps (separating axes) its greatest height towards the Sun, x·s, over the
    cell (along the sliver's long axis, the top of its three edges over the cell's extent),
    keeping the largest: a rod or wire whose shadow is thinner than a pixel, which neither
    pixel centres nor pixel corners may land in. Serial (a running maximum)."""
    ny, nx = grid.shape
    pa = np.empty(3)
    pb = np.empty(3)
    ph = np.empty(3)
    px = np.empty(3)
    for f in range(F.shape[0]):
        for k in range(3):
            i = F[f, k]
            pa[k] = (e1[0] * V[i, 0] + e1[1] * V[i, 1] + e1[2] * V[i, 2] - a0) / cell
            pb[k] = (e2[0] * V[i, 0] + e2[1] * V[i, 1] + e2[2] * V[i, 2] - b0) / cell
            ph[k] = s[0] * V[i, 0] + s[1] * V[i, 1] + s[2] * V[i, 2]
        cross = (pa[1] - pa[0]) * (pb[2] - pb[0]) - (pa[2] - pa[0]) * (pb[1] - pb[0])
        longest = 0.0
        kl = 0
        for k in range(3):
            j = (k + 1) % 3
            ln = math.hypot(pa[j] - pa[k], pb[j] - pb[k])
            if ln > longest:
                longest = ln
                kl = k
        if abs(cross) >= max_width / cell * longest:
            continue
        # the sliver's long axis and each vertex's coordinate along it
        jl = (kl + 1) % 3
        ax = 1.0
        ay = 0.0
        if longest > 0.0:
            ax = (pa[jl] - pa[kl]) / longest
            ay = (pb[jl] - pb[kl]) / longest
        for k in range(3):
            px[k] = pa[k] * ax + pb[k] * ay
        reach = 0.5 * (abs(ax) + abs(ay))  # half a cell's extent along the axis
        # cell (i, j) spans [j, j + 1] × [i, i + 1] in cell units; row by row, the cells
        # between the extremes of the triangle's part within the row (a convex polygon whose
        # x-extent is that of its edges clipped to the row)
        v0 = max(math.floor(min(pb[0], pb[1], pb[2])), 0)
        v1 = min(math.floor(max(pb[0], pb[1], pb[2])), ny - 1)
        for v in range(v0, v1 + 1):
            xlo = np.inf
            xhi = -np.inf
            for k in range(3):
                j = (k + 1) % 3
                ya, yb = pb[k], pb[j]
                t0, t1 = 0.0, 1.0
                if yb != ya:
                    ta = (v - ya) / (yb - ya)
                    tb = (v + 1.0 - ya) / (yb - ya)
                    t0 = max(t0, min(ta, tb))
                    t1 = min(t1, max(ta, tb))
                elif not (v <= ya <= v + 1.0):
                    continue
                if t0 > t1:
                    continue
                xa = pa[k] + t0 * (pa[j] - pa[k])
                xb = pa[k] + t1 * (pa[j] - pa[k])
                xlo = min(xlo, xa, xb)
                xhi = max(xhi, xa, xb)
            if xlo > xhi:
                continue
            for u in range(max(math.floor(xlo), 0), min(math.floor(xhi), nx - 1) + 1):
                xc = (u + 0.5) * ax + (v + 0.5) * ay
                top = -np.inf
                for k in range(3):
                    j = (k + 1) % 3
                    top = max(top, _edge_top(px[k], ph[k], px[j], ph[j], xc - reach, xc + reach))
                grid[v, u] = max(grid[v, u], top)


@pjit
def near_shadow_slivers(P, NS, WO, lit, foot, e1, e2, s, a0, b0, cell, grid, out):
    """Lit points (``lit``) whose pixel footprint, seen from the Sun, comes within reach of a
    sliver of :func:`shadow_map_of_slivers` that stands towards the Sun: the pixel may hold a
    thin shadow that its centre and corners missed. The footprint (``foot`` metres per pixel at
    the point, stretched by 1/|n·v| on the surface) spans a disc of radius ρ in the Sun's view;
    the surface itself rises towards the Sun by at most (ρ√2 + cell)·tanθ_s over the cells
    looked at (θ_s the Sun's incidence), so only a sliver higher than that by 5 % of ρ
    counts."""
    ny, nx = grid.shape
    for k in numba.prange(P.shape[0]):
        out[k] = False
        if not lit[k]:
            continue
        cs = NS[k, 0] * s[0] + NS[k, 1] * s[1] + NS[k, 2] * s[2]
        cv = abs(NS[k, 0] * WO[k, 0] + NS[k, 1] * WO[k, 1] + NS[k, 2] * WO[k, 2])
        if cs <= 0.05:
            continue  # grazing Sun: too little light for a thin shadow to matter
        rho = 0.75 * foot[k] / max(cv, 0.1)
        # the cells looked at reach ρ√2 from the point, and a cell's top is taken over its
        # width: the point's own plane may rise by (ρ√2 + cell)·tanθ_s over them
        h = (s[0] * P[k, 0] + s[1] * P[k, 1] + s[2] * P[k, 2]
             + (1.4143 * rho + cell) * math.sqrt(1.0 - cs * cs) / cs + 0.05 * rho)
        a = (e1[0] * P[k, 0] + e1[1] * P[k, 1] + e1[2] * P[k, 2] - a0) / cell
        b = (e2[0] * P[k, 0] + e2[1] * P[k, 1] + e2[2] * P[k, 2] - b0) / cell
        r = rho / cell
        u0 = max(math.floor(a - r), 0)
        u1 = min(math.floor(a + r), nx - 1)
        v0 = max(math.floor(b - r), 0)
        v1 = min(math.floor(b + r), ny - 1)
        hit = False
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if grid[v, u] > h:
                    hit = True
                    break
            if hit:
                break
        out[k] = hit


@pjit
def subpixel_rays(pix, W, n_grid, seed, R_body_from_cam, fx, fy, cx, cy, out_d):
    """n_grid² sub-pixel ray directions (body frame, z_cam = 1) per edge pixel, correlated
    multi-jittered (Kensler 2013, "Correlated Multi-Jittered Sampling", Pixar TM 13-01): one
    point in each cell of the n_grid × n_grid grid over the pixel *and* one in each of the
    n_grid² columns and n_grid² rows of the fine grid (n-rooks), the fine offsets permuted per
    pixel from a hash of (seed, pixel), jittered within the fine cell. Unbiased for any
    content, like plain jittered stratification, but a near-horizontal or near-vertical edge
    or shadow stripe is sampled at n_grid² distinct offsets, not n_grid."""
    S = n_grid * n_grid
    for k in numba.prange(pix.shape[0]):
        v = pix[k] // W
        u = pix[k] % W
        perm_a, perm_b = _cmj_perms(n_grid, n_grid, pix[k] & 0x7FFFFFFF, 2 * seed + 13)
        for j in range(S):
            key = (pix[k] * S + j) & 0x7FFFFFFF
            fu, fv = _cmj_point(j, n_grid, n_grid, perm_b, perm_a, _hash01(key, 2 * seed + 11),
                                _hash01(key, 2 * seed + 12))
            du = fu - 0.5
            dv = fv - 0.5
            x = (u + du - cx) / fx
            y = (v + dv - cy) / fy
            m = k * S + j
            for a in range(3):
                out_d[m, a] = R_body_from_cam[a, 0] * x + R_body_from_cam[a, 1] * y + R_body_from_cam[a, 2]


@pjit
def background(pix, W, o_body, R_body_from_cam, fx, fy, cx, cy, n_grid, p, tex, out):
    """Earth (no ambient sky) seen through each listed pixel, box-filtered over n_grid²
    sub-pixel rays; returns nothing, writes out[k]."""
    S = n_grid * n_grid
    for k in numba.prange(pix.shape[0]):
        v = pix[k] // W
        u = pix[k] % W
        sr = 0.0
        sg = 0.0
        sb = 0.0
        for j in range(S):
            du = ((j % n_grid) + 0.5) / n_grid - 0.5
            dv = ((j // n_grid) + 0.5) / n_grid - 0.5
            x = (u + du - cx) / fx
            y = (v + dv - cy) / fy
            dx = R_body_from_cam[0, 0] * x + R_body_from_cam[0, 1] * y + R_body_from_cam[0, 2]
            dy = R_body_from_cam[1, 0] * x + R_body_from_cam[1, 1] * y + R_body_from_cam[1, 2]
            dz = R_body_from_cam[2, 0] * x + R_body_from_cam[2, 1] * y + R_body_from_cam[2, 2]
            dn = math.sqrt(dx * dx + dy * dy + dz * dz)
            r, g, b = env.env_radiance(p, tex, o_body[0], o_body[1], o_body[2], dx / dn, dy / dn, dz / dn)
            sr += r
            sg += g
            sb += b
        out[k, 0] = sr / S
        out[k, 1] = sg / S
        out[k, 2] = sb / S


@jit
def _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, mu_min):
    """Where the unit ray (o, d) meets Earth: (True, albedo RGB, outward normal), or False
    first on a miss or where the Sun's cosine is ≤ mu_min."""
    t = env.earth_hit(p, ox, oy, oz, dx, dy, dz)
    if t < 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx, my, mz = env.earth_normal(p, ox, oy, oz, dx, dy, dz, t)
    if mx * p[env.P_SX] + my * p[env.P_SY] + mz * p[env.P_SZ] <= mu_min:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    a0, a1, a2 = env.earth_albedo(p, tex, mx, my, mz)
    return True, a0, a1, a2, mx, my, mz


@inline
def _chord2(M, i0, j0, i1, j1):
    """Squared distance between the unit normals M[i0, j0] and M[i1, j1]."""
    a = M[i0, j0, 0] - M[i1, j1, 0]
    b = M[i0, j0, 1] - M[i1, j1, 1]
    c = M[i0, j0, 2] - M[i1, j1, 2]
    return a * a + b * b + c * c


@inline
def _cell_trusted(A, M, C, ok, ok_c, i, j, chord2, tol):
    """Whether cell (i, j) of :func:`earth_background` interpolates its albedo: all four
    corners and the centre on Earth's day side, both diagonals shorter than √chord2 on the
    unit sphere, and the corners' mean within ``tol`` of the centre's albedo (relative)."""
    if not (ok_c[i, j] and ok[i, j + 1] and ok[i + 1, j] and ok[i + 1, j + 1]):
        return False
    if _chord2(M, i, j, i + 1, j + 1) > chord2 or _chord2(M, i, j + 1, i + 1, j) > chord2:
        return False
    for c in range(3):
        mid = 0.25 * (A[i, j, c] + A[i, j + 1, c] + A[i + 1, j, c] + A[i + 1, j + 1, c])
        if abs(mid - C[i, j, c]) > tol * C[i, j, c]:
            return False
    return True


@inline
def _pixel_ray(R, fx, fy, cx, cy, u, v):
    """Unit body-frame direction of the ray through image point (u, v)."""
    x = (u - cx) / fx
    y = (v - cy) / fy
    dx = R[0, 0] * x + R[0, 1] * y + R[0, 2]
    dy = R[1, 0] * x + R[1, 1] * y + R[1, 2]
    dz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / dn, dy / dn, dz / dn


@pjit
def earth_background(inst, o_body, R_body_from_cam, fx, fy, cx, cy, p, tex, step, tol, max_chord, earth_px, rad):
    """Earth behind the target in one pass over the image: ``earth_px[v, u]`` is set where the
    pixel's centre ray meets Earth, and there, off the target (``inst`` 0), ``rad[v, u]``
    (H, W, 3) receives Earth's radiance along it (``p`` without the ambient sky: the sky
    lights the target but is not drawn).

    Where and whether the ray meets Earth, and the Sun's cosine there (day, night, terminator,
    limb), are exact per pixel. The procedural texture's albedo (11 octaves of value noise,
    :func:`raytrace.environment.procedural_albedo`; its finest detail ~60 km, a pixel ~0.1–1 km
    from low orbit) is, with ``step`` > 1, evaluated on the corners of step × step cells of
    the image and interpolated bilinearly inside each cell that spans less than ``max_chord``
    of Earth's radius (its diagonals on the sphere: so not near the limb, where a pixel covers
    kilometres) and whose centre it matches there to ``tol`` (relative, per channel); a cell
    that fails, or whose corners do not all see Earth's day side (or its night side within
    ``max_chord`` of the terminator: the Sun's cosine changes by less than that across a cell
    that passes), is evaluated per pixel. Other textures (uniform, an image) are looked up per
    pixel. Whether a cell interpolates is decided once per cell, and the per-pixel hit test and
    normal work on the unnormalised ray (one square root and one division a pixel); with them
    the kernel takes ~0.55× the time on one thread where Earth fills the view, the same bytes
    (BENCHMARKS.md, "Earth behind the target, per pixel in half the time")."""
    H, W = inst.shape
    ox, oy, oz = o_body[0], o_body[1], o_body[2]
    interp = step > 1 and int(p[env.P_TEXTURE]) == env.TEX_PROCEDURAL
    s = step if interp else 1
    nv = (H - 1) // s + 2 if interp else 1
    nu = (W - 1) // s + 2 if interp else 1
    A = np.empty((nv, nu, 3))  # albedo at the cells' corners,
    M = np.empty((nv, nu, 3))  # Earth's normal there,
    C = np.empty((nv, nu, 3))  # the albedo at the cells' centres
    # cleared by plain loops, not np.zeros or a slice assignment: under parallel=True numba
    # turns each of those into a parallel loop of its own, compiled like the kernel's own loops
    # (LLVM's work four libraries over), for arrays that take microseconds to clear (the kernel
    # compiled in ~1 s less on one core, 4.5 → 3.6 s; the same bytes)
    ok = np.empty((nv, nu), dtype=np.bool_)
    ok_c = np.empty((nv, nu), dtype=np.bool_)
    trusted = np.empty((nv, nu), dtype=np.bool_)
    for i in range(nv):
        for j in range(nu):
            ok[i, j] = False
            ok_c[i, j] = False
            trusted[i, j] = False
    if interp:
        for i in numba.prange(nv):
            for j in range(nu):
                dx, dy, dz = _pixel_ray(R_body_from_cam, fx, fy, cx, cy, float(j * s), float(i * s))
                hit, A[i, j, 0], A[i, j, 1], A[i, j, 2], M[i, j, 0], M[i, j, 1], M[i, j, 2] = \
                    _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, -max_chord)
                ok[i, j] = hit
                if hit:
                    dx, dy, dz = _pixel_ray(R_body_from_cam, fx, fy, cx, cy, (j + 0.5) * s, (i + 0.5) * s)
                    hit, C[i, j, 0], C[i, j, 1], C[i, j, 2], _, _, _ = \
                        _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, -2.0)
                    ok_c[i, j] = hit
    chord2 = max_chord * max_chord
    # whether each cell interpolates, decided once per cell (not at each of its pixels)
    if interp:
        for i in numba.prange(nv - 1):
            for j in range(nu - 1):
                trusted[i, j] = _cell_trusted(A, M, C, ok, ok_c, i, j, chord2, tol)
    if p[env.P_HAS_EARTH] == 0.0:
        for v in range(H):
            for u in range(W):
                earth_px[v, u] = False
        return
    inv = 1.0 / s
    k_sun = p[env.P_ESUN] / math.pi
    r = p[env.P_RADIUS]
    r2 = r * r
    inv_r = 1.0 / r
    # Earth's centre from the camera, c; the pixel's ray o + t'·d with d unnormalised,
    # d = R (x, y, 1) linear in the pixel's x, so |d|² and c × d need no square root or
    # division per pixel: the ray meets Earth where c·d > 0 and |c × d|² < r²|d|², at
    # t' = (c·d − √(r²|d|² − |c × d|²)) / |d|², and Earth's normal there is (t'·d − c) / r
    ccx = p[env.P_DIST] * p[env.P_EX] - ox
    ccy = p[env.P_DIST] * p[env.P_EY] - oy
    ccz = p[env.P_DIST] * p[env.P_EZ] - oz
    sx, sy, sz = p[env.P_SX], p[env.P_SY], p[env.P_SZ]
    ifx = 1.0 / fx
    for v in numba.prange(H):
        i = v // s
        fv = (v - i * s) * inv
        y = (v - cy) / fy
        # d = d0 + x·g, x = (u − cx)/fx
        d0x = R_body_from_cam[0, 1] * y + R_body_from_cam[0, 2]
        d0y = R_body_from_cam[1, 1] * y + R_body_from_cam[1, 2]
        d0z = R_body_from_cam[2, 1] * y + R_body_from_cam[2, 2]
        gx = R_body_from_cam[0, 0]
        gy = R_body_from_cam[1, 0]
        gz = R_body_from_cam[2, 0]
        for u in range(W):
            x = (u - cx) * ifx
            dx = d0x + x * gx
            dy = d0y + x * gy
            dz = d0z + x * gz
            b = dx * ccx + dy * ccy + dz * ccz
            qx = ccy * dz - ccz * dy
            qy = ccz * dx - ccx * dz
            qz = ccx * dy - ccy * dx
            q2 = qx * qx + qy * qy + qz * qz
            d2 = dx * dx + dy * dy + dz * dz
            disc = r2 * d2 - q2
            hit = b > 0.0 and disc > 0.0
            earth_px[v, u] = hit
            if not hit or inst[v, u] != 0:
                continue
            t = (b - math.sqrt(disc)) / d2
            mx = (t * dx - ccx) * inv_r
            my = (t * dy - ccy) * inv_r
            mz = (t * dz - ccz) * inv_r
            mu = mx * sx + my * sy + mz * sz
            if mu <= 0.0:
                rad[v, u, 0] = 0.0
                rad[v, u, 1] = 0.0
                rad[v, u, 2] = 0.0
                continue
            k = k_sun * mu
            j = u // s
            if interp and trusted[i, j]:
                fu = (u - j * s) * inv
                for c in range(3):
                    a = (1.0 - fv) * ((1.0 - fu) * A[i, j, c] + fu * A[i, j + 1, c]) + \
                        fv * ((1.0 - fu) * A[i + 1, j, c] + fu * A[i + 1, j + 1, c])
                    rad[v, u, c] = a * k
            else:
                a0, a1, a2 = env.earth_albedo(p, tex, mx, my, mz)
                rad[v, u, 0] = a0 * k
                rad[v, u, 1] = a1 * k
                rad[v, u, 2] = a2 * k


@pjit
def env_along(o_body, D, p, tex, out):
    """Environment radiance along unit directions D from o_body."""
    for k in numba.prange(D.shape[0]):
        r, g, b = env.env_radiance(p, tex, o_body[0], o_body[1], o_body[2], D[k, 0], D[k, 1], D[k, 2])
        out[k, 0] = r
        out[k, 1] = g
        out[k, 2] = b


@pjit
def lobe_rays(idx, P, NS, NG, WO, comp, mat_f0, mat_alpha, n_rays, seed, pix, eps, out_o, out_d, out_w):
    """n_rays directions per listed point drawn from its GGX lobe (visible normals, correlated
    multi-jittered per pixel and seed, :func:`_cmj_point`), with weights f_spec·cos/pdf (RGB;
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
             mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex, idx, CV,
             vis, e_ind, out, out_var):
    """Each listed point's (idx[j]) sampled specular reflection minus its cheap counterpart
    L̄·A (:func:`add_mirror`, L̄ = ``CV[idx[j]]``, A the split-sum albedo): the mean over the
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


@pjit_exact
def ray_groups(geom, prim, face_offset, component_of_face, out):
    """The group of each ray's hit for coverage counting: its part + 1, or 0 on a miss."""
    for k in numba.prange(geom.shape[0]):
        g = geom[k]
        out[k] = 0 if g < 0 else component_of_face[face_offset[g] + prim[k]] + 1


@inline
def _slot(groups, n, g):
    """Index of g among groups[:n], −1 if absent."""
    for k in range(n):
        if groups[k] == g:
            return k
    return -1


@inline
def _slot_or_new(groups, n, g):
    """(index of g among groups[:n], appended as groups[n] if absent; the new n)."""
    k = _slot(groups, n, g)
    if k >= 0:
        return k, n
    groups[n] = g
    return n, n + 1


@jit_exact
def coverage_unshaded_first(g_s, g_c, out):
    """out[i, j]: coverage ray j of pixel i is the first of that pixel's coverage rays to see
    a group (part, or space) that none of its shaded sub-samples saw (g_s (n, S), g_c (n, C):
    groups, :func:`ray_groups`)."""
    n, S = g_s.shape
    C = g_c.shape[1]
    groups = np.empty(S + C, np.int64)
    for i in range(n):
        d = 0
        for a in range(S):
            _k, d = _slot_or_new(groups, d, g_s[i, a])
        for b in range(C):
            _k, d_new = _slot_or_new(groups, d, g_c[i, b])
            out[i, b] = d_new > d
            d = d_new


@jit_exact
def coverage_combine(g_s, L_s, g_c, shaded_c, L_c, out):
    """Radiance of anti-aliased pixels from their shaded sub-samples and coverage rays
    (multisample anti-aliasing): each group (part, or space) seen in pixel i weighs the mean
    radiance of its shaded rays — the S sub-samples (groups g_s (n, S), radiance L_s (n, S, 3))
    and the coverage rays flagged in shaded_c (n, C) (radiance L_c (n, C, 3)) — by the
    fraction of all S + C rays that saw it (g_c (n, C) the coverage rays' groups). Every
    group seen must have a shaded ray (:func:`coverage_unshaded_first`). out (n, 3)."""
    n, S = g_s.shape
    C = g_c.shape[1]
    inv = 1.0 / (S + C)
    groups = np.empty(S + C, np.int64)
    cnt = np.zeros(S + C)
    nsh = np.zeros(S + C)
    tot = np.zeros((S + C, 3))
    for i in range(n):
        d = 0
        for a in range(S):
            k, d = _slot_or_new(groups, d, g_s[i, a])
            cnt[k] += 1.0
            nsh[k] += 1.0
            for c in range(3):
                tot[k, c] += L_s[i, a, c]
        for b in range(C):
            k, d = _slot_or_new(groups, d, g_c[i, b])
            cnt[k] += 1.0
            if shaded_c[i, b]:
                nsh[k] += 1.0
                for c in range(3):
                    tot[k, c] += L_c[i, b, c]
        r0 = 0.0
        r1 = 0.0
        r2 = 0.0
        for k in range(d):
            w = cnt[k] * inv / max(nsh[k], 1.0)
            r0 += w * tot[k, 0]
            r1 += w * tot[k, 1]
            r2 += w * tot[k, 2]
            cnt[k] = 0.0
            nsh[k] = 0.0
            tot[k, 0] = 0.0
            tot[k, 1] = 0.0
            tot[k, 2] = 0.0
        out[i, 0] = r0
        out[i, 1] = r1
        out[i, 2] = r2
