"""Fused kernels: rays and the paths traced from their hits in one pass, Embree called per ray.

The batched code (:meth:`raytrace._context._Context._gather_chunk` and ``_bounces``, kept as the
fallback) runs the final gather level by level: every ray's direction into an array
(:func:`raytrace._gather.gather_rays`), the batch through ``embreex``, the shadow rays
(:func:`raytrace._gather.bounce_sun_rays`), the next bounce's rays
(:func:`raytrace._gather.bounce2_rays`), and so on up to four bounces deep, then the sum
(:func:`raytrace._gather.gather_sum`), with a round of Python, NumPy indexing and arrays of
every ray between levels. :func:`gather_traced` computes the same estimate ray by ray inside
one kernel that calls Embree itself (:mod:`raytrace._embree`): the same directions, the same
keys of the same hashes, the same float32 rays, so the same result up to the last bits of the
fast-math shading arithmetic. :func:`lobe_traced` does the same for the GGX-lobe sampling
(:func:`raytrace._gather.lobe_rays` … :func:`raytrace._gather.lobe_sum`), and
:func:`sun_visibility` for the edge sub-samples' shadow rays towards the solar disc.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ._cache_kernels import glossy_draw, hit_normals
from ._embree import intersect1, occluded1, ray_buffer
from ._gather import add_lobe_term, gather_estimate, gather_start, mean_estimate
from ._jit import inline, pjit
from ._lights import SUN_COS_HALF, SUN_E, SUN_X, SUN_Y, SUN_Z
from ._sampling import _cmj_perms, _cmj_point, _hash01, _hash32, _owen_sobol2_keyed, _strata
from ._surface import disc_direction, incoming, incoming_env
from .brdf import cosine_direction, onb, sample_brdf

# points per block of the parallel loop (scheduled dynamically: the rays per point vary)
_BLOCK = 16


@inline
def _sun_visibility(scene, buf, ox, oy, oz, dx, dy, dz, g, pr, t, face_offset, face_normal, sun, eps):
    """The Sun's visibility at the hit of the ray (o, d) as :meth:`_context._Context._bounce_sun`
    gives it: −1 at a miss or when there is no sunlight (``sun[SUN_E]`` = 0), 0 where the side
    the ray arrived from faces away from the Sun or a shadow ray (from the hit, offset along
    that side's normal) is blocked, else 1. ``sun``: the Sun record (:mod:`raytrace._lights`)."""
    sx, sy, sz = sun[SUN_X], sun[SUN_Y], sun[SUN_Z]
    if g < 0 or not sun[SUN_E] > 0.0:
        return -1.0
    f = face_offset[g] + pr
    nx = face_normal[f, 0]
    ny = face_normal[f, 1]
    nz = face_normal[f, 2]
    if nx * dx + ny * dy + nz * dz > 0.0:
        nx, ny, nz = -nx, -ny, -nz
    if nx * sx + ny * sy + nz * sz <= 0.0:
        return 0.0
    tt = np.float64(t)
    if occluded1(scene, buf, ox + tt * dx + eps * nx, oy + tt * dy + eps * ny, oz + tt * dz + eps * nz, sx, sy, sz):
        return 0.0
    return 1.0


@inline
def _bounce_draw(ox, oy, oz, dx, dy, dz, f, hu, hv, t, face_normal, corner_normal, comp_of_face, glossy, mat_f0,
                 mat_alpha, key, seed, eps):
    """:func:`raytrace._gather.bounce2_rays` for one hit: (ok, o2, d2, w2)."""
    nx, ny, nz, ngx, ngy, ngz = hit_normals(face_normal, corner_normal, f, hu, hv, dx, dy, dz)
    u1 = _hash01(key, 4 * seed + 31)
    u2 = _hash01(key, 4 * seed + 32)
    c = comp_of_face[f]
    ok = True
    if glossy[c]:
        wx, wy, wz, wr, wg, wb, ok = glossy_draw(nx, ny, nz, ngx, ngy, ngz, dx, dy, dz, mat_f0[c, 0], mat_f0[c, 1],
                                                 mat_f0[c, 2], mat_alpha[c], u1, u2)
    else:
        wx, wy, wz = cosine_direction(nx, ny, nz, u1, u2)
        wr = wg = wb = math.pi
        if wx * ngx + wy * ngy + wz * ngz <= 0.0:
            ok = False
    tt = np.float64(t)
    return (ok, ox + tt * dx + eps * ngx, oy + tt * dy + eps * ngy, oz + tt * dz + eps * ngz, wx, wy, wz, wr, wg,
            wb)


@inline
def _traced_indirect(scene, buf, path, ox, oy, oz, dx, dy, dz, g, pr, hu, hv, t, key, seed, levels, first_near,
                     near, eps, lk):
    """The traced estimate of the indirect irradiance at the hit (g ≥ 0) of the gather ray
    (o, d), as :meth:`_context._Context._traced_indirect` computes it with ``levels`` bounces:
    −1 where the cache stands in (a miss; a hit farther than ``first_near`` on a part that is
    not glossy), 0 where the bounce's draw fails, else the weight of the bounce times the
    radiance its ray brings back, the path continued from hits nearer than ``near`` (float32
    distances, as the batched code compares them) and from every glossy hit; the Sun from the
    record ``sun`` of ``lk`` (:mod:`raytrace._lights`). ``path``
    (≥ levels, 14) is scratch for the path's vertices; ``lk`` the tuple of arrays
    :meth:`raytrace._context._Context._lookup` returns (a numba-inlined call takes at most 30
    arguments: CPython passes more as one tuple, which numba's inliner does not take)."""
    (face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot,
     E_sun, valid, face_s, lat_start, lat_ids, p, tex, mat_par, face_uv, atlas) = lk
    if g < 0 or levels <= 0:
        return -1.0, -1.0, -1.0
    f = face_offset[g] + pr
    if not (t < first_near or glossy[comp_of_face[f]]):
        return -1.0, -1.0, -1.0
    n = 0  # vertices of the path beyond the hit
    cx, cy, cz, ex, ey, ez = ox, oy, oz, dx, dy, dz
    cf, chu, chv, ct, ck = f, hu, hv, t, key
    result = 0.0  # the draw at the deepest hit failed: 0 (nothing comes from below the surface)
    while True:
        ok, o2x, o2y, o2z, d2x, d2y, d2z, wr, wg, wb = _bounce_draw(
            cx, cy, cz, ex, ey, ez, cf, chu, chv, ct, face_normal, corner_normal, comp_of_face, glossy, mat_f0,
            mat_alpha, ck, seed, eps)
        if not ok:
            break
        g2, p2, u2, v2, t2 = intersect1(scene, buf, o2x, o2y, o2z, d2x, d2y, d2z)
        vis2 = _sun_visibility(scene, buf, o2x, o2y, o2z, d2x, d2y, d2z, g2, p2, t2, face_offset, face_normal, sun,
                               eps)
        path[n, 0], path[n, 1], path[n, 2] = o2x, o2y, o2z
        path[n, 3], path[n, 4], path[n, 5] = d2x, d2y, d2z
        path[n, 6], path[n, 7], path[n, 8] = wr, wg, wb
        path[n, 9] = vis2
        path[n, 10] = g2
        path[n, 11] = p2
        path[n, 12] = u2
        path[n, 13] = v2
        n += 1
        result = -1.0  # the cache beyond the deepest traced hit
        if g2 < 0 or n >= levels:
            break
        f2 = face_offset[g2] + p2
        if not (t2 < near or glossy[comp_of_face[f2]]):
            break
        cx, cy, cz, ex, ey, ez = o2x, o2y, o2z, d2x, d2y, d2z
        cf, chu, chv, ct, ck = f2, np.float64(u2), np.float64(v2), t2, ck * 4 + 1
        result = 0.0
    # back along the path: each vertex's radiance with the deeper estimate as its indirect light
    er = eg = eb = result
    for i in range(n - 1, -1, -1):
        g2 = np.int32(path[i, 10])
        if g2 < 0:
            lr, lg, lb = incoming_env(p, tex, path[i, 0], path[i, 1], path[i, 2], path[i, 3], path[i, 4], path[i, 5])
        else:
            lr, lg, lb = incoming(g2, np.int32(path[i, 11]), path[i, 12], path[i, 13], path[i, 0], path[i, 1],
                                  path[i, 2], path[i, 3], path[i, 4], path[i, 5], face_offset, face_normal,
                                  corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot,
                                  E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                                  mat_par, face_uv, atlas, path[i, 9], er, eg, eb)
        er, eg, eb = path[i, 6] * lr, path[i, 7] * lg, path[i, 8] * lb
    return er, eg, eb


@pjit
def gather_traced(scene, P, NS, NG, rows, start, first, seed, path_seed, pix, share, kmul, eps, levels, first_near,
                  near, face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy,
                  table, sun, E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex,
                  mat_par, face_uv, atlas, E_unocc, alpha, out, out_var,
                  out_hits):
    """Final-gather irradiance per point k (at row rows[k] of P, NS and NG; every other array is
    per point) from rays start[k] … start[k + 1] − 1, as
    :meth:`raytrace._context._Context._gather_chunk` computes it from the kernels
    :func:`raytrace._gather.gather_rays` (samples ``first`` … of the pixel's sequence,
    keyed by ``seed``; with ``share`` > 0 of the sub-samples' pixels,
    :func:`raytrace._gather.gather_start`), the shadow rays of its hits, the paths traced from them
    (:func:`_traced_indirect`, keyed by pix·kmul + j and ``path_seed``) and
    :func:`raytrace._gather.gather_sum` (environment control variate with weight ``alpha``;
    ``out_var`` the estimate's luminance variance). ``out_hits[k]`` counts the rays that hit a
    part. ``sun`` is the Sun record (:mod:`raytrace._lights`: its shadow rays are cast where
    ``sun[SUN_E]`` > 0), ``scene`` a :class:`raytrace._embree.DirectScene` handle."""
    stream = 2 * seed + 15
    a = alpha
    lk = (face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot,
          E_sun, valid, face_s, lat_start, lat_ids, p, tex, mat_par, face_uv, atlas)
    n_pts = out.shape[0]
    n_blocks = (n_pts + _BLOCK - 1) // _BLOCK

    for blk in numba.prange(n_blocks):
        buf = ray_buffer()
        path = np.empty((max(levels, 1), 14))
        for k in range(blk * _BLOCK, min(n_pts, (blk + 1) * _BLOCK)):
            key0, first_k = gather_start(pix[k], seed, first, share, kmul)
            row = rows[k]
            h_index, h_x, h_y = _hash32(key0, stream), _hash32(key0, stream + 1), _hash32(key0, stream + 2)
            ox = P[row, 0] + eps * NG[row, 0]
            oy = P[row, 1] + eps * NG[row, 1]
            oz = P[row, 2] + eps * NG[row, 2]
            n_rays = start[k + 1] - start[k]
            sr = 0.0
            sg = 0.0
            sb = 0.0
            sy2 = 0.0
            hits = 0
            for j in range(n_rays):
                u1, u2 = _owen_sobol2_keyed(first_k + j, h_index, h_x, h_y)
                dx, dy, dz = cosine_direction(NS[row, 0], NS[row, 1], NS[row, 2], u1, u2)
                g, pr, hu32, hv32, t = intersect1(scene, buf, ox, oy, oz, dx, dy, dz)
                below = dx * NG[row, 0] + dy * NG[row, 1] + dz * NG[row, 2] <= 0.0
                if g < 0 and not below:
                    if a == 1.0:
                        continue  # exactly what the control variate expects
                    r, gg, b = incoming_env(p, tex, ox, oy, oz, dx, dy, dz)
                    sr += (1.0 - a) * r
                    sg += (1.0 - a) * gg
                    sb += (1.0 - a) * b
                    y = (1.0 - a) * (0.2126 * r + 0.7152 * gg + 0.0722 * b)
                    sy2 += y * y
                    continue
                if g >= 0:
                    hits += 1
                y = 0.0  # this ray's term's luminance
                if a != 0.0:
                    r, gg, b = incoming_env(p, tex, ox, oy, oz, dx, dy, dz)
                    sr -= a * r
                    sg -= a * gg
                    sb -= a * b
                    y -= a * (0.2126 * r + 0.7152 * gg + 0.0722 * b)
                if not below:  # (then a hit) under the geometric surface nothing arrives
                    hu = np.float64(hu32)
                    hv = np.float64(hv32)
                    vis = _sun_visibility(scene, buf, ox, oy, oz, dx, dy, dz, g, pr, t, face_offset, face_normal, sun,
                                          eps)
                    eir, eig, eib = _traced_indirect(scene, buf, path, ox, oy, oz, dx, dy, dz, g, pr, hu, hv, t,
                                                     pix[k] * kmul + j, path_seed, levels, first_near, near, eps, lk)
                    r, gg, b = incoming(g, pr, hu, hv, ox, oy, oz, dx, dy, dz, face_offset, face_normal, corner_normal,
                                        comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun,
                                        valid, face_s, lat_start, lat_ids, p, tex,
                                        mat_par, face_uv, atlas, vis, eir, eig, eib)
                    sr += r
                    sg += gg
                    sb += b
                    y += 0.2126 * r + 0.7152 * gg + 0.0722 * b
                sy2 += y * y
            out_hits[k] = hits
            out[k, 0], out[k, 1], out[k, 2], out_var[k] = gather_estimate(sr, sg, sb, sy2, n_rays, a, E_unocc,
                                                                          NS[row, 0], NS[row, 1], NS[row, 2])



@pjit
def lobe_traced(scene, idx, P, NS, NG, WO, comp, n_rays, seed, path_seed, pix, eps, levels, near,
                face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun,
                E_tot, E_sun, valid, face_s, lat_start, lat_ids, p, tex, mat_par, face_uv, atlas, CV, out, out_var):
    """Each listed point's (idx[j]) sampled specular reflection minus its control variate, as
    :meth:`raytrace._context._Context.lobe` computes it from :func:`raytrace._gather.lobe_rays`
    (n_rays lobe directions, keyed by pixel and ``seed``), the shadow rays and paths of their
    hits (:func:`_traced_indirect`: the first bounce from every hit, further ones from hits
    nearer than ``near``; keyed by pix·n_rays + r and ``path_seed``) and :func:`raytrace._gather.lobe_sum`; a draw that fails (weight 0) casts
    no ray. ``sun``: the Sun record (:mod:`raytrace._lights`)."""
    gx = _strata(n_rays)
    gy = n_rays // gx
    lk = (face_offset, face_normal, corner_normal, comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot,
          E_sun, valid, face_s, lat_start, lat_ids, p, tex, mat_par, face_uv, atlas)
    every = np.float32(np.inf)
    n_pts = out.shape[0]
    for blk in numba.prange((n_pts + _BLOCK - 1) // _BLOCK):
        buf = ray_buffer()
        path = np.empty((max(levels, 1), 14))
        for j in range(blk * _BLOCK, min(n_pts, (blk + 1) * _BLOCK)):
            k = idx[j]
            c = comp[k]
            key = pix[k] * 1013 + seed
            perm_x, perm_y = _cmj_perms(gx, gy, key, 2 * seed + 23)
            ox = P[k, 0] + eps * NG[k, 0]
            oy = P[k, 1] + eps * NG[k, 1]
            oz = P[k, 2] + eps * NG[k, 2]
            sr = 0.0
            sg = 0.0
            sb = 0.0
            sy2 = 0.0
            for r in range(n_rays):
                u1, u2 = _cmj_point(r, gx, gy, perm_x, perm_y, _hash01(key, 2 * r + 21), _hash01(key, 2 * r + 22))
                lx, ly, lz, wr, wg, wb, ok = sample_brdf(NS[k, 0], NS[k, 1], NS[k, 2], WO[k, 0], WO[k, 1], WO[k, 2],
                                                         0.0, 0.0, 0.0, mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2],
                                                         mat_alpha[c], 0.0, u1, u2)
                if not ok or lx * NG[k, 0] + ly * NG[k, 1] + lz * NG[k, 2] <= 0.0:
                    continue
                if wr == 0.0 and wg == 0.0 and wb == 0.0:
                    continue
                g, pr, hu32, hv32, t = intersect1(scene, buf, ox, oy, oz, lx, ly, lz)
                if g < 0:
                    a, b, cc = incoming_env(p, tex, ox, oy, oz, lx, ly, lz)
                else:
                    hu = np.float64(hu32)
                    hv = np.float64(hv32)
                    vis = _sun_visibility(scene, buf, ox, oy, oz, lx, ly, lz, g, pr, t, face_offset, face_normal, sun,
                                          eps)
                    eir, eig, eib = _traced_indirect(scene, buf, path, ox, oy, oz, lx, ly, lz, g, pr, hu, hv, t,
                                                     pix[k] * n_rays + r, path_seed, levels, every, near, eps, lk)
                    a, b, cc = incoming(g, pr, hu, hv, ox, oy, oz, lx, ly, lz, face_offset, face_normal, corner_normal,
                                        comp_of_face, mat_diff, mat_f0, mat_alpha, glossy, table, sun, E_tot, E_sun,
                                        valid, face_s, lat_start, lat_ids, p, tex,
                                        mat_par, face_uv, atlas, vis, eir, eig, eib)
                sr, sg, sb, sy2 = add_lobe_term(sr, sg, sb, sy2, wr, wg, wb, a, b, cc, CV[k, 0], CV[k, 1], CV[k, 2])
            out[j, 0], out[j, 1], out[j, 2], out_var[j] = mean_estimate(sr, sg, sb, sy2, n_rays)


@pjit
def sun_visibility(scene, idx, P, NG, sun, eps, pixel, number, n_strata, seed, out):
    """out[k] = 1 where the shadow ray of listed point k = idx[j] reaches the Sun, else 0 (the
    rest untouched), as :meth:`raytrace._context._Sunlight.sunlight` casts it: from P + ε·NG
    (float32, as Embree takes it) towards the Sun's centre, or with ``n_strata`` > 0 towards
    the solar-disc sample :func:`raytrace._surface.sun_disc_dirs` draws for (pixel[k],
    number[k]) — the same directions, without their array. ``sun``: the Sun record
    (:mod:`raytrace._lights`)."""
    sx, sy, sz, cos_half = sun[SUN_X], sun[SUN_Y], sun[SUN_Z], sun[SUN_COS_HALF]
    gx = _strata(max(n_strata, 1))
    gy = max(n_strata, 1) // gx
    tx, ty, tz, bx, by, bz = onb(sx, sy, sz)
    n = idx.shape[0]
    for blk in numba.prange((n + 255) // 256):
        buf = ray_buffer()
        for j in range(blk * 256, min(n, (blk + 1) * 256)):
            k = idx[j]
            dx, dy, dz = sx, sy, sz
            if n_strata > 0:
                dx, dy, dz = disc_direction(pixel[k], number[k], n_strata, gx, gy, seed, tx, ty, tz, bx, by, bz, sx,
                                            sy, sz, cos_half)
            blocked = occluded1(scene, buf, P[k, 0] + eps * NG[k, 0], P[k, 1] + eps * NG[k, 1],
                                P[k, 2] + eps * NG[k, 2], np.float32(dx), np.float32(dy), np.float32(dz))
            out[k] = 0.0 if blocked else 1.0
