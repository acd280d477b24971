"""Numba kernels of the per-hit material: what a surface point's BRDF parameters (diffuse ρ_d,
F0, GGX α) and shading normal are where a component's material varies over its surface.

A component's row of ``mat_par`` (float64, NPAR columns, built by :mod:`raytrace.surfaces`)
says how: kind 0 (constant: the component's ``mat_diff``/``mat_f0``/``mat_alpha`` row, the fast
path that leaves everything as without this module), kind 1 (glTF 2.0 metallic-roughness with
optional textures), kind 2 (crinkled MLI foil: a normal perturbed by 3-D value noise of the body
point), kind 3 (a solar-cell grid laid out in the panel's plane). ``face_uv`` (float64, one row
per face, FACE_COLS columns) holds each face's three corner UVs, its tangent and bitangent
(per triangle, from the UVs: dP/du and dP/dv, Lengyel 2001, the per-triangle step of
MikkTSpace without its vertex averaging) and its corners' body points. ``atlas`` (float32, 1-D)
holds every texture's texels, row-major from the image's top row, ``channels`` per texel,
colour textures already converted from sRGB to linear, normal maps already decoded to signed
components.

UVs follow trimesh's convention (origin at the image's bottom-left, v up; trimesh flips glTF's
top-left V on load): texel row y = (1 − v)·h − ½, column x = u·w − ½ (texel centres at
half-integers), bilinear between the four nearest texels, wrapped (glTF's default sampler,
REPEAT, glTF 2.0 §3.8.4: https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html).

:func:`material_at` is inlined into the kernels of ``_surface``, ``_gather``, ``_paths`` and
``pathtrace``; numba's on-disk cache checks only a kernel's own source file, so after editing
this module delete the cached kernels (``find raytrace -name '*.nb[ic]' -delete``) or those
kernels keep the old code.
"""

from __future__ import annotations

import math

import numba

from ._jit import FASTMATH, inline, pjit

NPAR = 32
K_CONST, K_GLTF, K_MLI, K_SOLAR = 0, 1, 2, 3
# mat_par columns
P_KIND = 0
P_BASE = 1  # 3: glTF baseColorFactor (linear RGB) / procedural's second material's diffuse
P_METAL = 4  # metallicFactor
P_ROUGH = 5  # roughnessFactor (perceptual: α = roughness²) / MLI foil's GGX α
P_NSCALE = 6  # normalTexture.scale
P_SEED = 7
P_TEX_BASE = 8  # 4 each: atlas offset (−1: none), width, height, channels
P_TEX_MR = 12
P_TEX_N = 16
P_ORIGIN = 20  # 3: procedural frame's origin (body frame, m)
P_AX1 = 23  # 3: its first axis (unit)
P_AX2 = 26  # 3: its second axis (unit)
P_SCALE = 29  # MLI: noise cell [m]; solar grid: gap width [m]
P_AMP = 30  # MLI: slope amplitude; solar grid: busbar width [m]
P_EXTRA = 31  # glTF: the dielectric F0 (0.04); solar grid: the busbar's diffuse albedo (grey)
FACE_COLS = 21  # uv (6), tangent (3), bitangent (3), corner points (9)

# solar-cell grid: cell size (AZUR SPACE 3G30C-Advanced, 40 × 80 mm; datasheet
# https://www.azurspace.com/images/006-00036-00_3G30C-Advanced_80x40.pdf), gap between cells
SOLAR_CELL_U_M = 0.040
SOLAR_CELL_V_M = 0.080
GAP_DIFFUSE = (0.30, 0.30, 0.30)  # the panel substrate showing between cells (Kapton/white)
# variance of one component of the crinkle's noise vector (value noise + ½ the next octave):
# 0.200, measured over 2·10⁵ random points
MLI_NOISE_VAR = 0.20
MLI_FILTER = 8.0


@inline
def _fract_floor(x):
    f = math.floor(x)
    return x - f, int(f)


@inline
def tex_fetch(atlas, off, w, h, ch, x, y, a):
    """Channel ``a`` of texel (x, y), wrapped (REPEAT); grey textures repeat their channel 0,
    a missing alpha is 1."""
    x %= w
    y %= h
    if a >= ch:
        if a == 3:
            return 1.0
        a = 0 if ch < 3 else a
    return atlas[off + (y * w + x) * ch + a]


@inline
def tex_bilinear(atlas, off, w, h, ch, u, v):
    """Bilinear RGB of a texture at (u, v) (module notes: trimesh's UV origin, REPEAT)."""
    fx, x0 = _fract_floor(u * w - 0.5)
    fy, y0 = _fract_floor((1.0 - v) * h - 0.5)
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for a in range(3):
        t00 = tex_fetch(atlas, off, w, h, ch, x0, y0, a)
        t10 = tex_fetch(atlas, off, w, h, ch, x0 + 1, y0, a)
        t01 = tex_fetch(atlas, off, w, h, ch, x0, y0 + 1, a)
        t11 = tex_fetch(atlas, off, w, h, ch, x0 + 1, y0 + 1, a)
        val = (1.0 - fy) * ((1.0 - fx) * t00 + fx * t10) + fy * ((1.0 - fx) * t01 + fx * t11)
        if a == 0:
            out0 = val
        elif a == 1:
            out1 = val
        else:
            out2 = val
    return out0, out1, out2


@inline
def _hash3(ix, iy, iz, seed):
    """Uniform in [−1, 1) from integer lattice coordinates (a 32-bit integer hash)."""
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ (seed * 2654435761)
    h &= 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x7FEB352D) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x846CA68B) & 0xFFFFFFFF
    h ^= h >> 16
    return h / 2147483648.0 - 1.0


@inline
def value_noise(x, y, z, seed):
    """3-D value noise in [−1, 1]: lattice values smoothly interpolated (quintic fade,
    Perlin 2002, "Improving noise", SIGGRAPH)."""
    fx, ix = _fract_floor(x)
    fy, iy = _fract_floor(y)
    fz, iz = _fract_floor(z)
    ux = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0)
    uy = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0)
    uz = fz * fz * fz * (fz * (fz * 6.0 - 15.0) + 10.0)
    acc = 0.0
    for dz in range(2):
        wz = uz if dz else 1.0 - uz
        for dy in range(2):
            wy = uy if dy else 1.0 - uy
            for dx in range(2):
                wx = ux if dx else 1.0 - ux
                acc += wx * wy * wz * _hash3(ix + dx, iy + dy, iz + dz, seed)
    return acc


@inline
def _periodic_cover(x, period, lo, hi, w):
    """Fraction of [x − w/2, x + w/2] inside the periodic band [lo, hi) + k·period (box-filtered
    indicator; the point's own indicator when w = 0)."""
    if w <= 0.0:
        r = x - period * math.floor(x / period)
        return 1.0 if lo <= r < hi else 0.0
    return (_band_integral(x + 0.5 * w, period, lo, hi) - _band_integral(x - 0.5 * w, period, lo, hi)) / w


@inline
def _band_integral(x, period, lo, hi):
    k = math.floor(x / period)
    r = x - k * period
    return k * (hi - lo) + min(max(r - lo, 0.0), hi - lo)


@inline
def _perturb(nx, ny, nz, gx, gy, gz):
    """n + g's component across n, normalised."""
    d = gx * nx + gy * ny + gz * nz
    mx = nx + gx - d * nx
    my = ny + gy - d * ny
    mz = nz + gz - d * nz
    m = math.sqrt(mx * mx + my * my + mz * mz)
    return mx / m, my / m, mz / m


@numba.njit(cache=True, fastmath=FASTMATH, nogil=True, forceinline=True)
def material_at(c, f, b1, b2, nx, ny, nz, foot, mat_diff, mat_f0, mat_alpha, mat_par, face_uv, atlas):
    """The BRDF parameters and shading normal at barycentrics (b1, b2) of face ``f`` of
    component ``c``, whose interpolated shading normal (facing the viewer) is n; ``foot`` the
    width [m] a pixel covers there (the procedural patterns are box-filtered over it; 0: the
    point's own; < 0: their mean, as the surfaces that secondary rays hit take them: their
    glints and gaps would only add noise to the light those rays gather). Returns
    (ρ_d r, g, b, F0 r, g, b, α, n'x, n'y, n'z)."""
    dr, dg, db = mat_diff[c, 0], mat_diff[c, 1], mat_diff[c, 2]
    fr, fg, fb = mat_f0[c, 0], mat_f0[c, 1], mat_f0[c, 2]
    al = mat_alpha[c]
    kind = mat_par[c, P_KIND]
    if kind == K_CONST:
        return dr, dg, db, fr, fg, fb, al, nx, ny, nz
    b0 = 1.0 - b1 - b2
    px = b0 * face_uv[f, 12] + b1 * face_uv[f, 15] + b2 * face_uv[f, 18]
    py = b0 * face_uv[f, 13] + b1 * face_uv[f, 16] + b2 * face_uv[f, 19]
    pz = b0 * face_uv[f, 14] + b1 * face_uv[f, 17] + b2 * face_uv[f, 20]
    if kind == K_GLTF:
        u = b0 * face_uv[f, 0] + b1 * face_uv[f, 2] + b2 * face_uv[f, 4]
        v = b0 * face_uv[f, 1] + b1 * face_uv[f, 3] + b2 * face_uv[f, 5]
        br, bg, bb = mat_par[c, P_BASE], mat_par[c, P_BASE + 1], mat_par[c, P_BASE + 2]
        if mat_par[c, P_TEX_BASE] >= 0.0:
            tr, tg, tb = tex_bilinear(atlas, int(mat_par[c, P_TEX_BASE]), int(mat_par[c, P_TEX_BASE + 1]),
                                      int(mat_par[c, P_TEX_BASE + 2]), int(mat_par[c, P_TEX_BASE + 3]), u, v)
            br *= tr
            bg *= tg
            bb *= tb
        metal = mat_par[c, P_METAL]
        rough = mat_par[c, P_ROUGH]
        if mat_par[c, P_TEX_MR] >= 0.0:
            _r, tg, tb = tex_bilinear(atlas, int(mat_par[c, P_TEX_MR]), int(mat_par[c, P_TEX_MR + 1]),
                                      int(mat_par[c, P_TEX_MR + 2]), int(mat_par[c, P_TEX_MR + 3]), u, v)
            rough *= tg
            metal *= tb
        metal = min(max(metal, 0.0), 1.0)
        # glTF 2.0 Appendix B.3: c_diff = lerp(base, black, metallic), F0 = lerp(f_d, base, metallic) (f_d 0.04),
        # α = roughness²
        dr = br * (1.0 - metal)
        dg = bg * (1.0 - metal)
        db = bb * (1.0 - metal)
        fd = mat_par[c, P_EXTRA]  # the dielectric's F0: 0.04 (glTF), 0 (OBJ's Lambertian Kd)
        fr = fd * (1.0 - metal) + br * metal
        fg = fd * (1.0 - metal) + bg * metal
        fb = fd * (1.0 - metal) + bb * metal
        al = min(max(rough * rough, 0.02), 1.0)
        if mat_par[c, P_TEX_N] >= 0.0:
            tx, ty, tz = tex_bilinear(atlas, int(mat_par[c, P_TEX_N]), int(mat_par[c, P_TEX_N + 1]),
                                      int(mat_par[c, P_TEX_N + 2]), int(mat_par[c, P_TEX_N + 3]), u, v)
            if tx != 0.0 or ty != 0.0:
                sc = mat_par[c, P_NSCALE]
                tx *= sc
                ty *= sc
                # tangent frame: T (dP/du) made orthogonal to n, B = ±n × T on the side of dP/dv
                Tx, Ty, Tz = face_uv[f, 6], face_uv[f, 7], face_uv[f, 8]
                d = Tx * nx + Ty * ny + Tz * nz
                Tx -= d * nx
                Ty -= d * ny
                Tz -= d * nz
                tn = math.sqrt(Tx * Tx + Ty * Ty + Tz * Tz)
                if tn > 0.0:
                    Tx /= tn
                    Ty /= tn
                    Tz /= tn
                    Bx = ny * Tz - nz * Ty
                    By = nz * Tx - nx * Tz
                    Bz = nx * Ty - ny * Tx
                    if Bx * face_uv[f, 9] + By * face_uv[f, 10] + Bz * face_uv[f, 11] < 0.0:
                        Bx, By, Bz = -Bx, -By, -Bz
                    mx = tx * Tx + ty * Bx + tz * nx
                    my = tx * Ty + ty * By + tz * ny
                    mz = tx * Tz + ty * Bz + tz * nz
                    m = math.sqrt(mx * mx + my * my + mz * mz)
                    if m > 0.0 and tz > 0.0:
                        nx, ny, nz = mx / m, my / m, mz / m
        return dr, dg, db, fr, fg, fb, al, nx, ny, nz
    if kind == K_MLI:
        s = 1.0 / mat_par[c, P_SCALE]
        amp = mat_par[c, P_AMP]
        seed = int(mat_par[c, P_SEED])
        # the crinkle keeps the fraction r = exp(−(8·foot/cell)²) of its slope variance (none
        # once a pixel spans a quarter of a noise cell: pixel centres would alias it); the rest
        # widens the lobe (α² += 2σ² of the unresolved slopes, the Beckmann relation α² = 2σ²,
        # as in Toksvig 2005 / LEAN mapping, Olano & Baker 2010)
        w = MLI_FILTER * foot * s
        r = math.exp(-w * w) if foot >= 0.0 else 0.0
        al = math.sqrt(mat_par[c, P_ROUGH] ** 2 + 2.0 * (1.0 - r) * MLI_NOISE_VAR * amp * amp)
        amp *= math.sqrt(r)
        x, y, z = px * s, py * s, pz * s
        # two octaves (cm and half-cm wrinkles)
        gx = value_noise(x, y, z, seed) + 0.5 * value_noise(2.0 * x, 2.0 * y, 2.0 * z, seed + 3)
        gy = value_noise(x, y, z, seed + 1) + 0.5 * value_noise(2.0 * x, 2.0 * y, 2.0 * z, seed + 4)
        gz = value_noise(x, y, z, seed + 2) + 0.5 * value_noise(2.0 * x, 2.0 * y, 2.0 * z, seed + 5)
        nx, ny, nz = _perturb(nx, ny, nz, amp * gx, amp * gy, amp * gz)
        return dr, dg, db, fr, fg, fb, al, nx, ny, nz
    # K_SOLAR: cells (the component's preset) with gaps (substrate) and a busbar along one short
    # edge of each cell, in the plane of the part's two first principal axes. The cover glass
    # over them keeps the preset's specular lobe everywhere; the pattern is in the diffuse
    # albedo alone, so the box filter over a pixel's footprint is exact in the BRDF
    qx, qy, qz = px - mat_par[c, P_ORIGIN], py - mat_par[c, P_ORIGIN + 1], pz - mat_par[c, P_ORIGIN + 2]
    uu = qx * mat_par[c, P_AX1] + qy * mat_par[c, P_AX1 + 1] + qz * mat_par[c, P_AX1 + 2]
    vv = qx * mat_par[c, P_AX2] + qy * mat_par[c, P_AX2 + 1] + qz * mat_par[c, P_AX2 + 2]
    gap = mat_par[c, P_SCALE]
    bus = mat_par[c, P_AMP]
    pu = SOLAR_CELL_U_M + gap
    pv = SOLAR_CELL_V_M + gap
    if foot >= 0.0:
        gu = _periodic_cover(uu, pu, 0.0, gap, foot)
        gv = _periodic_cover(vv, pv, 0.0, gap, foot)
        bv = _periodic_cover(vv, pv, gap, gap + bus, foot)
    else:  # the pattern's mean
        gu = gap / pu
        gv = gap / pv
        bv = bus / pv
    w_cell = (1.0 - gu) * max(1.0 - gv - bv, 0.0)
    w_bus = (1.0 - gu) * bv
    w_gap = max(1.0 - w_cell - w_bus, 0.0)
    bus_d = mat_par[c, P_EXTRA]
    dr = w_cell * dr + w_gap * mat_par[c, P_BASE] + w_bus * bus_d
    dg = w_cell * dg + w_gap * mat_par[c, P_BASE + 1] + w_bus * bus_d
    db = w_cell * db + w_gap * mat_par[c, P_BASE + 2] + w_bus * bus_d
    return dr, dg, db, fr, fg, fb, al, nx, ny, nz


@pjit
def eval_hits(face, comp, B, NS, WO, foot, mat_diff, mat_f0, mat_alpha, mat_par, face_uv, atlas, out_diff, out_f0,
              out_alpha):
    """Per hit k: its material (:func:`material_at`) into out_* and its shading normal NS[k]
    replaced by the perturbed one (tilted back towards the viewer where it turned away)."""
    for k in numba.prange(face.shape[0]):
        dr, dg, db, fr, fg, fb, al, nx, ny, nz = material_at(comp[k], face[k], B[k, 0], B[k, 1], NS[k, 0], NS[k, 1],
                                                             NS[k, 2], foot[k], mat_diff, mat_f0, mat_alpha, mat_par,
                                                             face_uv, atlas)
        facing = nx * WO[k, 0] + ny * WO[k, 1] + nz * WO[k, 2]
        if facing < 1e-4:
            t = 1e-4 - facing
            nx += t * WO[k, 0]
            ny += t * WO[k, 1]
            nz += t * WO[k, 2]
            m = math.sqrt(nx * nx + ny * ny + nz * nz)
            nx /= m
            ny /= m
            nz /= m
        NS[k, 0] = nx
        NS[k, 1] = ny
        NS[k, 2] = nz
        out_diff[k, 0] = dr
        out_diff[k, 1] = dg
        out_diff[k, 2] = db
        out_f0[k, 0] = fr
        out_f0[k, 1] = fg
        out_f0[k, 2] = fb
        out_alpha[k] = al
