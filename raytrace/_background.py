"""Numba kernels of what the camera sees off the target: Earth behind it (per pixel, or from
its albedo interpolated on cells of pixels), and the environment along given directions.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from . import _earth
from . import environment as env
from ._jit import inline, jit, pjit
from ._lens import ray_xy


@pjit
def background(pix, W, o_body, R_body_from_cam, fx, fy, cx, cy, lens, table, n_grid, p, tex, out):
    """Earth (no ambient sky) seen through each listed pixel, box-filtered over n_grid²
    sub-pixel rays (through the lens, :func:`raytrace._lens.ray_xy`); returns nothing, writes
    out[k]."""
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
            x, y = ray_xy(lens, table, (u + du - cx) / fx, (v + dv - cy) / fy)
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


NS = _earth.N_STATE  # per cell corner: albedo RGB (procedural) or the Blue Marble's state (raytrace._earth)


@jit
def _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, mu_min, out):
    """Where the unit ray (o, d) meets Earth: True, writing into ``out`` the albedo RGB
    (procedural) or :func:`raytrace._earth.fill_state` (``bluemarble``), and returning the
    outward normal; or False first on a miss or where the Sun's cosine is ≤ mu_min."""
    t = env.earth_hit(p, ox, oy, oz, dx, dy, dz)
    if t < 0.0:
        return False, 0.0, 0.0, 0.0
    mx, my, mz = env.earth_normal(p, ox, oy, oz, dx, dy, dz, t)
    if mx * p[env.P_SX] + my * p[env.P_SY] + mz * p[env.P_SZ] <= mu_min:
        return False, 0.0, 0.0, 0.0
    if p[env.P_TEXTURE] == env.TEX_BLUEMARBLE:
        _earth.fill_state(p, tex, mx, my, mz, dx, dy, dz, out)
    else:
        out[0], out[1], out[2] = env.earth_albedo(p, tex, mx, my, mz)
    return True, mx, my, mz


@inline
def _fine_start(p, S, k, mx, my, mz, dx, dy, dz, foot_m):
    """:func:`raytrace._earth.fine_start` of the ground point of normal m seen along the unit ray
    d, given its state ``S[k]`` and the footprint across the view ``foot_m``."""
    ex, ey, ez = _earth.to_earth(p, mx, my, mz)
    mu_v = max(-(mx * dx + my * dy + mz * dz), 0.05)
    return _earth.fine_start(ex, ey, ez, S[k, 5], S[k, 6], S[k, 7], max(foot_m / mu_v, 100.0), p[env.P_RADIUS],
                             S[k, 4], S[k, 3], p[env.P_CLOUD_THRESHOLD])


@inline
def _fine_octaves_of_row(n, qx, qy, qz, count, c, land):
    """The fine octaves (:func:`raytrace._earth.fine_octaves`) of a row's ``count`` ground points
    from their :func:`raytrace._earth.fine_start` (n, q), written into ``c`` and ``land``: each
    point's octaves added in the same order, an octave at a time over all of them (a loop LLVM
    vectorises); a point whose octave is faded out adds zero."""
    n_max = 0.0
    for k in range(count):
        c[k] = 0.0
        land[k] = 0.0
        n_max = max(n_max, n[k])
    a = _earth.A_FINE
    f = _earth.F_FINE
    for i in range(_earth.N_COARSE, _earth.N_OCTAVES):
        if n_max - (i - _earth.N_COARSE) <= 0.0:
            break
        for k in range(count):
            fade = min(max(n[k] - (i - _earth.N_COARSE), 0.0), 1.0)
            v = _earth.noise_inline(f * qx[k] + 7.3 * i, f * qy[k], f * qz[k]) - 0.5
            c[k] += fade * a * v
            land[k] += fade * _earth.LAND_LOG_AMP * v
        a *= _earth.FINE_GAIN
        f *= 2.0


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
    if tol < 0.0:  # band-limited by construction (the Blue Marble's coarse state)
        return True
    for c in range(3):
        mid = 0.25 * (A[i, j, c] + A[i, j + 1, c] + A[i + 1, j, c] + A[i + 1, j + 1, c])
        if abs(mid - C[i, j, c]) > tol * C[i, j, c]:
            return False
    return True


@inline
def _pixel_ray(R, fx, fy, cx, cy, lens, table, u, v):
    """Unit body-frame direction of the ray through image point (u, v) (NaN where the lens
    has none)."""
    x, y = ray_xy(lens, table, (u - cx) / fx, (v - cy) / fy)
    dx = R[0, 0] * x + R[0, 1] * y + R[0, 2]
    dy = R[1, 0] * x + R[1, 1] * y + R[1, 2]
    dz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / dn, dy / dn, dz / dn


@pjit
def earth_background(inst, o_body, R_body_from_cam, fx, fy, cx, cy, lens, table, p, tex, step, tol, max_chord, earth_px,
                     rad):
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
    normal work on the unnormalised ray (one square root and one division a pixel).

    The ``bluemarble`` Earth (:mod:`raytrace._earth`): its smooth state (image, water, clouds
    coarser than 12.5 km, air masses, path radiance, glint) on the corners of 2·step-pixel cells
    that span up to 8 × ``max_chord`` and whose corners all see Earth above μ_s = −0.15, bilinear
    inside; per pixel its fine octaves and the Sun's cosine, and the atmosphere's limb glow on
    rays that miss the ground (``earth_px`` stays False there). The fine octaves are summed after
    each row, an octave at a time over the row's lit ground points (:func:`_fine_octaves_of_row`,
    a loop LLVM vectorises): the same bits as point by point, the kernel ~0.92× the time on the
    main job's frames (BENCHMARKS.md, "Earth behind the target")."""
    H, W = inst.shape
    ox, oy, oz = o_body[0], o_body[1], o_body[2]
    kind = int(p[env.P_TEXTURE])
    blue = kind == env.TEX_BLUEMARBLE
    interp = step > 1 and (kind == env.TEX_PROCEDURAL or blue)
    s = (2 * step if blue else step) if interp else 1  # the Blue Marble's state: 8 × 8 cells
    nv = (H - 1) // s + 2 if interp else 1
    nu = (W - 1) // s + 2 if interp else 1
    A = np.empty((nv, nu, NS))  # albedo (or coarse state) at the cells' corners,
    M = np.empty((nv, nu, 3))  # Earth's normal there,
    C = np.empty((nv, nu, NS))  # the albedo at the cells' centres
    tol_cells = -1.0 if blue else tol
    mu_corner = _earth.MU_NIGHT if blue else -max_chord  # the Blue Marble's twilight is drawn
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
                dx, dy, dz = _pixel_ray(R_body_from_cam, fx, fy, cx, cy, lens, table, float(j * s), float(i * s))
                if math.isnan(dx):  # beyond the lens's invertible region: no cell here
                    ok[i, j] = False
                    continue
                hit, M[i, j, 0], M[i, j, 1], M[i, j, 2] = \
                    _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, mu_corner, A[i, j])
                ok[i, j] = hit
                if hit:
                    if blue:  # band-limited: no centre to compare, only that it sees Earth
                        ok_c[i, j] = True
                        continue
                    dx, dy, dz = _pixel_ray(R_body_from_cam, fx, fy, cx, cy, lens, table, (j + 0.5) * s,
                                            (i + 0.5) * s)
                    hit, _, _, _ = _earth_albedo_along(p, tex, ox, oy, oz, dx, dy, dz, -2.0, C[i, j])
                    ok_c[i, j] = hit
    # the Blue Marble's state is band-limited (≥ 12.5 km) but for the view's (the limb's air mass):
    # its cells (twice as wide) interpolate it up to 8 × the chord
    chord2 = max_chord * max_chord * (64.0 if blue else 1.0)
    # whether each cell interpolates, decided once per cell (not at each of its pixels)
    if interp:
        for i in numba.prange(nv - 1):
            for j in range(nu - 1):
                trusted[i, j] = _cell_trusted(A, M, C, ok, ok_c, i, j, chord2, tol_cells)
    if p[env.P_HAS_EARTH] == 0.0:
        for v in range(H):
            for u in range(W):
                earth_px[v, u] = False
        return
    inv = 1.0 / s
    pix_rad = p[env.P_PIX_RAD]
    sx, sy, sz = p[env.P_SX], p[env.P_SY], p[env.P_SZ]
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
    ifx = 1.0 / fx
    distorted = lens.shape[0] > 0
    r_shell2 = (r + _earth.SHELL_M) ** 2
    for v in numba.prange(H):
        # the Blue Marble's lit ground points of the row: their column, state, Sun's cosine and
        # fine octaves' start (fine_start), whose octaves are summed after the row, together
        cols = np.empty(W if blue else 0, dtype=np.int64)
        S = np.empty((W if blue else 0, NS))
        mus = np.empty(W if blue else 0)
        fn = np.empty(W if blue else 0)
        fqx = np.empty(W if blue else 0)
        fqy = np.empty(W if blue else 0)
        fqz = np.empty(W if blue else 0)
        count = 0
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
            if distorted:  # the pixel's own undistorted ray
                x, yu = ray_xy(lens, table, (u - cx) / fx, y)
                dx = R_body_from_cam[0, 0] * x + R_body_from_cam[0, 1] * yu + R_body_from_cam[0, 2]
                dy = R_body_from_cam[1, 0] * x + R_body_from_cam[1, 1] * yu + R_body_from_cam[1, 2]
                dz = R_body_from_cam[2, 0] * x + R_body_from_cam[2, 1] * yu + R_body_from_cam[2, 2]
            else:
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
            if inst[v, u] != 0:
                continue
            if not hit:
                if blue and b > 0.0 and r_shell2 * d2 - q2 > 0.0:  # the atmosphere's limb
                    dn = 1.0 / math.sqrt(d2)
                    rad[v, u, 0], rad[v, u, 1], rad[v, u, 2] = _earth.limb_glow(p, ox, oy, oz, dx * dn, dy * dn,
                                                                                dz * dn)
                continue
            t = (b - math.sqrt(disc)) / d2
            mx = (t * dx - ccx) * inv_r
            my = (t * dy - ccy) * inv_r
            mz = (t * dz - ccz) * inv_r
            mu = mx * sx + my * sy + mz * sz
            if blue and mu > _earth.MU_NIGHT:
                dn = 1.0 / math.sqrt(d2)
                ux, uy, uz = dx * dn, dy * dn, dz * dn
                j = u // s
                if interp and trusted[i, j]:
                    fu = (u - j * s) * inv
                    w00 = (1.0 - fv) * (1.0 - fu)
                    w01 = (1.0 - fv) * fu
                    w10 = fv * (1.0 - fu)
                    w11 = fv * fu
                    for c in range(NS):
                        S[count, c] = w00 * A[i, j, c] + w01 * A[i, j + 1, c] + w10 * A[i + 1, j, c] + \
                            w11 * A[i + 1, j + 1, c]
                else:
                    _earth.fill_state(p, tex, mx, my, mz, ux, uy, uz, S[count])
                if mu <= 0.0 and S[count, 15] == 0.0 and S[count, 16] == 0.0 and S[count, 17] == 0.0:
                    # night without glint: combine() is the path radiance alone, whatever the
                    # clouds and the land (the same bits without their fine octaves)
                    rad[v, u, 0], rad[v, u, 1], rad[v, u, 2] = S[count, 12], S[count, 13], S[count, 14]
                    continue
                fn[count], fqx[count], fqy[count], fqz[count] = _fine_start(p, S, count, mx, my, mz, ux, uy, uz,
                                                                            pix_rad * t / dn)
                cols[count] = u
                mus[count] = mu
                count += 1
                continue
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
        if count == 0:
            continue
        cf = np.empty(count)
        land = np.empty(count)
        _fine_octaves_of_row(fn, fqx, fqy, fqz, count, cf, land)
        for k in range(count):
            rad[v, cols[k], 0], rad[v, cols[k], 1], rad[v, cols[k], 2] = _earth.combine(
                p, S[k, 0], S[k, 1], S[k, 2], S[k, 3], S[k, 9], S[k, 10], S[k, 11], S[k, 12], S[k, 13], S[k, 14],
                S[k, 15], S[k, 16], S[k, 17], S[k, 4] + cf[k], S[k, 8] + land[k], mus[k])


@pjit
def env_along(o_body, D, p, tex, out):
    """Environment radiance along unit directions D from o_body."""
    for k in numba.prange(D.shape[0]):
        r, g, b = env.env_radiance(p, tex, o_body[0], o_body[1], o_body[2], D[k, 0], D[k, 1], D[k, 2])
        out[k, 0] = r
        out[k, 1] = g
        out[k, 2] = b
