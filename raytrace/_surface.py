"""Numba kernels of the shading pass at surface points (``fast`` and ``balanced``): the points
rays hit, direct sunlight (shadow-ray origins, solar-disc directions, the BRDF times the Sun),
the radiance cache's irradiance there, the diffuse term, and the mirror term with the radiance a
traced ray brings back from the surface it hits (:func:`incoming`) or from the environment.

Conventions: body frame, float64 except the float32 arrays handed to Embree; ``wo`` points
from the surface to the viewer; normals are turned to face the incoming ray.
"""

from __future__ import annotations

import math

import numba

from . import environment as env
from ._cache_kernels import interpolate_rows, lattice_rows
from ._jit import FASTMATH, inline, pjit, pjit_exact
from ._kernels import moller_trumbore, normals_facing
from ._lights import SUN_COS_HALF, SUN_E, SUN_X, SUN_Y, SUN_Z
from ._sampling import _hash01, _hash32, _strata, permute
from ._texture import material_at
from .brdf import brdf_cos, onb, specular_albedo


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
def sun_rays(P, NS, NG, sun, eps, want, out_o):
    """Which points can see the Sun's direction at all (both normals towards it), and the
    shadow-ray origins (offset along the geometric normal). ``sun``: the Sun record
    (:mod:`raytrace._lights`)."""
    sx, sy, sz = sun[SUN_X], sun[SUN_Y], sun[SUN_Z]
    for k in numba.prange(P.shape[0]):
        ok = (NS[k, 0] * sx + NS[k, 1] * sy + NS[k, 2] * sz > 0.0) and \
             (NG[k, 0] * sx + NG[k, 1] * sy + NG[k, 2] * sz > 0.0)
        want[k] = ok
        for a in range(3):
            out_o[k, a] = P[k, a] + eps * NG[k, a]


@pjit
def sun_disc_dirs(pixel, number, n_strata, seed, sun, out_d):
    """Directions uniform over the solar disc (the cone of half-angle acos(sun[SUN_COS_HALF])
    about the Sun's centre direction; ``sun`` the Sun record, :mod:`raytrace._lights`): sample
    ``number[m]`` (< n_strata) of ``pixel[m]`` takes stratum permute(number, n_strata) of an exact gx × gy grid in (1 − cos θ, φ), the
    permutation drawn per pixel and seed (:func:`raytrace._sampling.permute`), jittered from a hash of (pixel,
    number, seed). The permutation decouples the disc stratum from the sample's number, which
    also indexes its sub-pixel cell (:func:`raytrace._edges.subpixel_rays`): with stratum = number, sub-samples
    in the pixel's left column always took the disc's inner ring, and a penumbra crossing the
    pixel was estimated from 6 correlated pairs, not 36 samples (measured: Cassini ``earth``,
    ``balanced``-16, ±30 % from seed to seed on the dish's shadow edge)."""
    sx, sy, sz, cos_half = sun[SUN_X], sun[SUN_Y], sun[SUN_Z], sun[SUN_COS_HALF]
    gx = _strata(n_strata)
    gy = n_strata // gx
    tx, ty, tz, bx, by, bz = onb(sx, sy, sz)
    for m in numba.prange(pixel.shape[0]):
        out_d[m, 0], out_d[m, 1], out_d[m, 2] = disc_direction(pixel[m], number[m], n_strata, gx, gy, seed, tx, ty,
                                                               tz, bx, by, bz, sx, sy, sz, cos_half)


@inline
def disc_direction(pixel, number, n_strata, gx, gy, seed, tx, ty, tz, bx, by, bz, sx, sy, sz, cos_half):
    """One direction of :func:`sun_disc_dirs` ((t, b) the basis about the Sun's direction s
    that :func:`raytrace.brdf.onb` gives). It takes the Sun record's entries as scalars, read
    once by the kernels that call it per sample before their loop: the basis is computed
    there too, once per kernel."""
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
def shade_sun(NS, WO, comp, mat_diff, mat_f0, mat_alpha, sun, vis, out):
    """out += V·f·cosθ·ν·E_sun with V the visible fraction of the solar disc (radiance, RGB);
    ``sun`` the Sun record (:mod:`raytrace._lights`)."""
    sx, sy, sz, e_sun = sun[SUN_X], sun[SUN_Y], sun[SUN_Z], sun[SUN_E]
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
             mat_par, face_uv, atlas,
             vis_sun, eir, eig, eib):
    """Radiance arriving along a traced ray (o, d) that hit a surface (``geom`` ≥ 0; for a ray
    that escaped, :func:`incoming_env`): that surface's radiance towards the ray from the
    cache: diffuse ρ_d/π·E,
    the exact specular reflection of the Sun towards −d and the specular albedo times the
    rest of its irradiance over π. ``sun``: the Sun record (:mod:`raytrace._lights`). The Sun's visibility at
    the hit comes from the cache when ``vis_sun`` < 0, else it is ``vis_sun`` (a shadow ray
    cast from the hit): then the hit's sunlight is exact and only its indirect light comes
    from the cache, so shadows finer than the cache's lattice are not blurred into the light
    bounced off them. (``eir``, ``eig``, ``eib``) ≥ 0 is a traced continuation of the path from
    the hit (:func:`raytrace._gather.bounce2_rays`): on a part that is not ``glossy`` it is an estimate of the
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
    cs = nx * sun[SUN_X] + ny * sun[SUN_Y] + nz * sun[SUN_Z]
    traced_spec = eir >= 0.0 and glossy[c]
    if vis_sun >= 0.0:  # exact sunlight replaces the cache's
        ex = vis_sun * sun[SUN_E] * cs if cs > 0.0 else 0.0
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
    # the hit's own material (raytrace._texture; the component's row where it is uniform): its
    # perturbed normal shapes the specular terms, the irradiance stays the surface's
    dr, dg, db, f0r, f0g, f0b, al, nx, ny, nz = material_at(c, f, hu, hv, nx, ny, nz, -1.0, mat_diff, mat_f0, mat_alpha,
                                                            mat_par, face_uv, atlas)
    lr = dr / math.pi * er
    lg = dg / math.pi * eg
    lb = db / math.pi * eb
    if f0r > 0.0 or f0g > 0.0 or f0b > 0.0:
        mu = -(nx * dx + ny * dy + nz * dz)
        if mu > 0.0:
            if es > 0.0 and cs > 0.0 and sun[SUN_E] > 0.0:
                vis = min(es / (sun[SUN_E] * cs), 1.0)
                sr, sg, sb = brdf_cos(nx, ny, nz, -dx, -dy, -dz, sun[SUN_X], sun[SUN_Y], sun[SUN_Z], 0.0, 0.0, 0.0,
                                      f0r, f0g, f0b, al)
                lr += sr * sun[SUN_E] * vis
                lg += sg * sun[SUN_E] * vis
                lb += sb * sun[SUN_E] * vis
            if traced_spec:
                lr += eir
                lg += eig
                lb += eib
            else:
                ar, ag, ab = specular_albedo(table, mu, al, f0r, f0g, f0b)
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
# mirror ray (_context._Context.mirror_weighted, the same expression)
MIRROR_BLEND_A0 = 0.05
MIRROR_BLEND_WIDTH = 0.3


@pjit
def add_mirror(idx, O, D, geom, prim, hu, hv, NS, WO, comp, E_point, face_offset, face_normal, corner_normal,
               comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun, valid, face_s, lat_start,
               lat_ids, p, tex, mat_par, face_uv, atlas, prefiltered, E_unocc, glossy_env, glossy_level, out, out_lbar):
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
    variate of the sampled lobe, :func:`raytrace._gather.lobe_sum`, or the answer on parts whose specular albedo
    is too small to be worth sampling, ``_context.LOBE_MIN_SPECULAR``) L̄_in blends from the mirror ray
    (α ≤ 0.05) to E/π (α ≥ 0.35), the environment as if it arrived uniformly: smooth, it kept
    ``balanced``'s filtered residual nearer the truth on the four targets with real materials
    (8 rays, 640×480: 7.55 / 2.12 / 7.31 / 5.41 % against 7.62 / 2.08 / 7.39 / 5.64 % with the
    prefiltered form), while as an answer it made a gold sphere under Earth 0.73–1.79× the path
    tracer's per quadrant (prefiltered: 0.91–1.07×). L̄_in itself goes to ``out_lbar``."""
    for j in numba.prange(idx.shape[0]):
        k = idx[j]
        c = comp[k]
        if geom[j] >= 0:
            r, g, b = incoming(geom[j], prim[j], hu[j], hv[j], O[j, 0], O[j, 1], O[j, 2], D[j, 0], D[j, 1], D[j, 2],
                               face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy,
                               table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                               mat_par, face_uv, atlas, -1.0, -1.0, -1.0, -1.0)
        elif prefiltered and mat_alpha[c] >= GLOSSY_A1:
            # weighted by 1 − t = 0 below: the environment along the mirror ray (Earth's ground,
            # the costliest part of the term) is not looked up; 0·L = 0 for the finite L it
            # would be, so the same bits
            r, g, b = 0.0, 0.0, 0.0
        else:
            r, g, b = incoming_env(p, tex, O[j, 0], O[j, 1], O[j, 2], D[j, 0], D[j, 1], D[j, 2])
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
