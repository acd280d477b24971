"""Reference renderer: unbiased path tracing of the full light transport (``reference`` quality).

Per pixel and sample: a primary ray jittered uniformly over the pixel (box filter); at every
surface hit, next-event estimation of the Sun (a direction drawn uniformly in the solar disc's
cone, one shadow ray: soft shadows), then a new direction drawn from the BRDF mixture
(:func:`raytrace.brdf.sample_brdf`) with weight f·cos/pdf; rays that escape collect the
environment (Earth, ambient sky; the Sun is reached only through next-event estimation, so it
is never counted twice). Russian roulette from the fourth vertex on; at most 32 vertices.

Sample patterns: the pixel jitter uses a rank-1 lattice (the R2 sequence, Roberts 2018)
shifted per pixel (Cranley–Patterson rotation); every other dimension is a hash of (seed,
pixel, sample, dimension), so the image depends only on the seed, not on threads. (A second
R2 pair for the first bounce, as used before, is the same lattice shifted: the bounce
direction was then a fixed function of the sub-pixel position, and pixels whose content
varies across the pixel — silhouettes, shadow edges — converged to a seed-dependent wrong
value.)

The path tracer is a wavefront: numba kernels build and shade ray batches, Embree traces them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import environment as env
from ._background import background
from ._jit import jit, pjit
from ._lens import ray_xy
from ._lights import SUN_COS_HALF, SUN_E, SUN_X, SUN_Y, SUN_Z
from ._surface import surfaces
from .brdf import brdf_cos, onb, sample_brdf
from .surfaces import point_materials

_PHI2 = 1.324717957244746
_A1 = 1.0 / _PHI2
_A2 = 1.0 / (_PHI2 * _PHI2)
_MAX_DEPTH = 32
_RR_DEPTH = 3


@jit
def _rand(seed, pix, s, dim):
    h = (seed * 0x9E3779B1 + pix * 0x85EBCA77 + s * 0xC2B2AE3D + dim * 0x27D4EB2F + 0x165667B1) & 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x7FEB352D) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x846CA68B) & 0xFFFFFFFF
    h ^= h >> 16
    return (h & 0xFFFFFF) / 16777216.0


@jit
def _r2(seed, pix, s, pair):
    """Dimension pair `pair` of sample s: an R2 lattice point shifted per pixel."""
    a = 0.5 + s * _A1 + _rand(seed, pix, 0x7FFF, 2 * pair)
    b = 0.5 + s * _A2 + _rand(seed, pix, 0x7FFF, 2 * pair + 1)
    return a - math.floor(a), b - math.floor(b)


@pjit
def _primary(pix, W, s, seed, o_body, R_bc, fx, fy, cx, cy, lens, table, z0, out_o32, out_d, out_d32):
    for k in numba.prange(pix.shape[0]):
        p = pix[k]
        v = p // W
        u = p % W
        ju, jv = _r2(seed, p, s, 0)
        x, y = ray_xy(lens, table, (u + ju - 0.5 - cx) / fx, (v + jv - 0.5 - cy) / fy)
        for a in range(3):
            d = R_bc[a, 0] * x + R_bc[a, 1] * y + R_bc[a, 2]
            out_d[k, a] = d
            out_d32[k, a] = d
            out_o32[k, a] = o_body[a] + z0 * d


@pjit
def _escape(idx, pix_of, O, D, thr, p, tex, acc):
    """Escaped rays: add throughput × environment radiance to their pixel."""
    for j in numba.prange(idx.shape[0]):
        k = idx[j]
        dn = math.sqrt(D[k, 0] ** 2 + D[k, 1] ** 2 + D[k, 2] ** 2)
        r, g, b = env.env_radiance(p, tex, O[k, 0], O[k, 1], O[k, 2], D[k, 0] / dn, D[k, 1] / dn, D[k, 2] / dn)
        q = pix_of[k]
        acc[q, 0] += thr[k, 0] * r
        acc[q, 1] += thr[k, 1] * g
        acc[q, 2] += thr[k, 2] * b


@pjit
def _vertex(pix_of, s, seed, depth, P, NS, NG, WO, comp, mat_diff, mat_f0, mat_alpha, thr, sun, eps, sh_o, sh_d,
            sh_c, sh_ok, nx_o, nx_d, alive):
    """At each hit: a Sun sample for next-event estimation (shadow ray + its would-be
    contribution; ``sun`` the Sun record, :mod:`raytrace._lights`) and the next direction from
    the BRDF (throughput updated, roulette)."""
    sx, sy, sz, cos_half, e_sun = sun[SUN_X], sun[SUN_Y], sun[SUN_Z], sun[SUN_COS_HALF], sun[SUN_E]
    for k in numba.prange(P.shape[0]):
        q = pix_of[k]
        c = comp[k]
        nsx, nsy, nsz = NS[k, 0], NS[k, 1], NS[k, 2]
        ngx, ngy, ngz = NG[k, 0], NG[k, 1], NG[k, 2]
        ox, oy, oz = WO[k, 0], WO[k, 1], WO[k, 2]
        dim = 8 + 6 * depth
        # --- Sun: uniform direction in the cone of the solar disc
        sh_ok[k] = False
        if e_sun > 0.0:
            u1 = _rand(seed, q, s, dim)
            u2 = _rand(seed, q, s, dim + 1)
            ct = 1.0 - u1 * (1.0 - cos_half)
            st = math.sqrt(max(0.0, 1.0 - ct * ct))
            phi = 2.0 * math.pi * u2
            tx, ty, tz, bx, by, bz = onb(sx, sy, sz)  # basis about the Sun direction
            lx = st * math.cos(phi) * tx + st * math.sin(phi) * bx + ct * sx
            ly = st * math.cos(phi) * ty + st * math.sin(phi) * by + ct * sy
            lz = st * math.cos(phi) * tz + st * math.sin(phi) * bz + ct * sz
            if lx * ngx + ly * ngy + lz * ngz > 0.0 and lx * nsx + ly * nsy + lz * nsz > 0.0:
                r, g, b = brdf_cos(nsx, nsy, nsz, ox, oy, oz, lx, ly, lz, mat_diff[c, 0], mat_diff[c, 1],
                                   mat_diff[c, 2], mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2], mat_alpha[c])
                sh_c[k, 0] = thr[k, 0] * r * e_sun
                sh_c[k, 1] = thr[k, 1] * g * e_sun
                sh_c[k, 2] = thr[k, 2] * b * e_sun
                sh_ok[k] = True
                for a in range(3):
                    sh_o[k, a] = P[k, a] + eps * NG[k, a]
                sh_d[k, 0] = lx
                sh_d[k, 1] = ly
                sh_d[k, 2] = lz
        # --- next direction
        u1 = _rand(seed, q, s, dim + 2)
        u2 = _rand(seed, q, s, dim + 3)
        u0 = _rand(seed, q, s, dim + 4)
        lx, ly, lz, wr, wg, wb, ok = sample_brdf(nsx, nsy, nsz, ox, oy, oz, mat_diff[c, 0], mat_diff[c, 1],
                                                 mat_diff[c, 2], mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2],
                                                 mat_alpha[c], u0, u1, u2)
        if not ok or lx * ngx + ly * ngy + lz * ngz <= 0.0:
            alive[k] = False
            continue
        tr = thr[k, 0] * wr
        tg = thr[k, 1] * wg
        tb = thr[k, 2] * wb
        if depth + 1 >= _RR_DEPTH:
            pr = min(0.95, max(tr, tg, tb))
            if _rand(seed, q, s, dim + 5) >= pr:
                alive[k] = False
                continue
            tr /= pr
            tg /= pr
            tb /= pr
        thr[k, 0] = tr
        thr[k, 1] = tg
        thr[k, 2] = tb
        alive[k] = depth + 1 < _MAX_DEPTH
        for a in range(3):
            nx_o[k, a] = P[k, a] + eps * NG[k, a]
        nx_d[k, 0] = lx
        nx_d[k, 1] = ly
        nx_d[k, 2] = lz


@pjit
def _add_shadowed(pix_of, sh_c, idx, blocked, acc):
    for j in numba.prange(idx.shape[0]):
        if blocked[j]:
            continue
        k = idx[j]
        q = pix_of[k]
        for a in range(3):
            acc[q, a] += sh_c[k, a]


def render_reference(scene, camera, R, t, lighting, geo, *, spp: int, seed: int) -> np.ndarray:
    """Path-traced radiance image (H, W, 3), float64 [W/(m²·sr)] (see module notes)."""
    H, W = camera.height, camera.width
    R_bc = np.ascontiguousarray(R.T)
    o_body = -R_bc @ t
    mats = scene.materials
    diff = np.array([m.diffuse for m in mats])
    f0 = np.array([m.f0 for m in mats])
    alpha = np.array([m.roughness for m in mats])
    p, tex = lighting.packed()
    p_bg = p.copy()
    p_bg[env.P_AMBIENT] = 0.0
    p_bg[env.P_PIX_RAD] = 1.0 / camera.fx  # the detail a pixel resolves
    sun = lighting.sun_record()
    eps = scene.ray_eps_m
    out = np.zeros((H * W, 3))
    # pixels where the target may appear (plus a 1-pixel border: jittered rays reach it)
    u0, v0, u1, v1 = geo.cast_rect
    if geo.camera_inside_hull:
        u0, v0, u1, v1 = 0, 0, W, H
    u0, v0, u1, v1 = max(u0 - 1, 0), max(v0 - 1, 0), min(u1 + 1, W), min(v1 + 1, H)
    rect = np.zeros((H, W), dtype=bool)
    rect[v0:v1, u0:u1] = u1 > u0 and v1 > v0
    # the rest of the image: Earth only (4×4 box-filtered)
    if lighting.earth is not None:
        rest = np.flatnonzero(~rect.ravel())
        bg = np.empty((len(rest), 3))
        background(rest, W, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, *camera.lens_arrays(), 4, p_bg, tex,
                   bg)
        out[rest] = bg
    pix = np.flatnonzero(rect.ravel()).astype(np.int64)
    if len(pix) == 0:
        return out.reshape(H, W, 3)
    n = len(pix)
    p_hull = scene.hull_vertices @ R.T + t
    z0 = 0.0 if geo.camera_inside_hull else scene._near_plane(p_hull)
    acc = np.zeros((n, 3))
    local = np.arange(n, dtype=np.int64)
    for s in range(spp):
        o32 = np.empty((n, 3), np.float32)
        d = np.empty((n, 3))
        d32 = np.empty((n, 3), np.float32)
        _primary(pix, W, s, seed, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, *camera.lens_arrays(), z0,
                 o32, d, d32)
        # the yardstick traces every ray through Embree's robust scene (Scene.direct), as the
        # labels do, not the faster one the presets' shading rays take
        h = scene.intersect(o32, d32, robust=True)
        O = np.ascontiguousarray(np.broadcast_to(o_body, (n, 3)))
        miss = np.flatnonzero(h["geomID"] < 0)
        if len(miss) and lighting.earth is not None:
            _escape(miss, local, O, d, np.ones((n, 3)), p_bg, tex, acc)
        # active paths: index into pixel list, origin, direction, throughput
        hit = np.flatnonzero(h["geomID"] >= 0)
        pix_of = local[hit]
        O = O[hit]
        D = np.ascontiguousarray(d[hit])
        face = (scene.face_offset[h["geomID"][hit]] + h["primID"][hit]).astype(np.int64)
        thr = np.ones((len(hit), 3))
        depth = 0
        while len(pix_of):
            m = len(pix_of)
            P = np.empty((m, 3))
            NS = np.empty((m, 3))
            NG = np.empty((m, 3))
            WO = np.empty((m, 3))
            B = np.empty((m, 2))
            SIDE = np.empty(m, np.int64)
            surfaces(O, D, face, scene.vertices, scene.faces, scene.face_normal, scene.corner_normal,
                     P, NS, NG, WO, B, SIDE)
            comp = scene.component_of_face[face]
            # each vertex's own material where materials vary (raytrace.surfaces): rows
            # n_comp + k of the material arrays, the components' rows before them; at the
            # camera's hits filtered over a pixel's footprint as the presets filter it (the
            # procedural patterns' level of detail is part of the material, as a texture's
            # mipmap is), deeper vertices with the patterns' mean, as the presets' secondary hits
            vx = {"face": face, "comp": comp, "B": B, "NS": NS, "WO": WO, "P": P}
            point_materials(scene, vx, O, 1.0 / camera.fx if depth == 0 else -1.0)
            k_comp, k_diff, k_f0, k_alpha = comp, diff, f0, alpha
            if "m_diff" in vx:
                k_comp = len(diff) + np.arange(m, dtype=np.int64)
                k_diff = np.concatenate([diff, vx["m_diff"]])
                k_f0 = np.concatenate([f0, vx["m_f0"]])
                k_alpha = np.concatenate([alpha, vx["m_alpha"]])
            sh_o = np.empty((m, 3))
            sh_d = np.empty((m, 3))
            sh_c = np.empty((m, 3))
            sh_ok = np.empty(m, dtype=bool)
            nx_o = np.empty((m, 3))
            nx_d = np.empty((m, 3))
            alive = np.empty(m, dtype=bool)
            _vertex(pix_of, s, seed, depth, P, NS, NG, WO, k_comp, k_diff, k_f0, k_alpha, thr, sun, eps, sh_o, sh_d,
                    sh_c, sh_ok, nx_o, nx_d, alive)
            sidx = np.flatnonzero(sh_ok)
            if len(sidx):
                blocked = scene.occluded(sh_o[sidx], sh_d[sidx], robust=True)
                _add_shadowed(pix_of, sh_c, sidx, blocked, acc)
            keep = np.flatnonzero(alive)
            if len(keep) == 0:
                break
            O = np.ascontiguousarray(nx_o[keep])
            D = np.ascontiguousarray(nx_d[keep])
            pix_of = pix_of[keep]
            thr = thr[keep]
            h = scene.intersect(O, D, robust=True)
            esc = np.flatnonzero(h["geomID"] < 0)
            if len(esc):
                _escape(esc, pix_of, O, D, thr, p, tex, acc)
            hit = np.flatnonzero(h["geomID"] >= 0)
            O = O[hit]
            D = np.ascontiguousarray(D[hit])
            pix_of = pix_of[hit]
            thr = thr[hit]
            face = (scene.face_offset[h["geomID"][hit]] + h["primID"][hit]).astype(np.int64)
            depth += 1
    out[pix] = acc / spp
    return out.reshape(H, W, 3)
