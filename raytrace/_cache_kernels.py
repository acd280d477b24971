"""Numba kernels of the radiance cache (:class:`raytrace.cache.RadianceCache`): its lattice and
the look-ups of per-row values at a surface point, the cache rays and the binning of their hits,
the glossy continuations and glints, the rows' sunlight and open-sky irradiance, the assembly of
the transfer matrices and the Gauss–Seidel and Jacobi steps of the solve.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from . import environment as env
from ._jit import inline, jit, jit_exact, pjit, pjit_exact
from ._lights import SUN_E, SUN_X, SUN_Y, SUN_Z
from ._sampling import _hash01
from .brdf import brdf_cos, cosine_direction, sample_brdf


@jit
def _lattice_local(s, a, b):
    """Index of lattice point (a, b) (a + b ≤ s) within its triangle's table."""
    return a * (s + 1) - (a * (a - 1)) // 2 + b


@jit
def lattice_weights(s, b1, b2):
    """The three lattice points around barycentrics (b1, b2) and their weights:
    (a0, b0, a1, b1, a2, b2, w0, w1, w2) in lattice coordinates."""
    x = min(max(b1, 0.0), 1.0) * s
    y = min(max(b2, 0.0), 1.0) * s
    i = min(int(x), s - 1)
    j = min(int(y), s - 1 - i)
    fx = x - i
    fy = y - j
    if fx + fy > 1.0 and i + j + 2 <= s:
        return i + 1, j, i, j + 1, i + 1, j + 1, 1.0 - fy, 1.0 - fx, fx + fy - 1.0
    w1 = min(max(fx, 0.0), 1.0)
    w2 = min(max(fy, 0.0), 1.0 - w1)
    return i, j, i + 1, j, i, j + 1, 1.0 - w1 - w2, w1, w2


@jit
def _lattice_points(V, F, corner_normal, face_s, lat_start, pos, nrm):
    """Position and interpolated shading normal of every lattice point of every triangle."""
    for f in range(F.shape[0]):
        s = face_s[f]
        base = lat_start[f]
        for a in range(s + 1):
            for b in range(s + 1 - a):
                k = base + _lattice_local(s, a, b)
                w1 = a / s
                w2 = b / s
                w0 = 1.0 - w1 - w2
                nx = w0 * corner_normal[f, 0, 0] + w1 * corner_normal[f, 1, 0] + w2 * corner_normal[f, 2, 0]
                ny = w0 * corner_normal[f, 0, 1] + w1 * corner_normal[f, 1, 1] + w2 * corner_normal[f, 2, 1]
                nz = w0 * corner_normal[f, 0, 2] + w1 * corner_normal[f, 1, 2] + w2 * corner_normal[f, 2, 2]
                nn = math.sqrt(nx * nx + ny * ny + nz * nz)
                for c in range(3):
                    pos[k, c] = w0 * V[F[f, 0], c] + w1 * V[F[f, 1], c] + w2 * V[F[f, 2], c]
                nrm[k, 0] = nx / nn
                nrm[k, 1] = ny / nn
                nrm[k, 2] = nz / nn


@pjit
def _oct_cells(nrm, n):
    out = np.empty(nrm.shape[0], np.int64)
    for i in numba.prange(nrm.shape[0]):
        out[i] = env.oct_cell(nrm[i, 0], nrm[i, 1], nrm[i, 2], n)
    return out


@pjit
def _cache_rays(rows, pos, nrm, eps, gx, gy, out_o, out_d):
    """G = gx·gy cosine-weighted directions per row (sample 2i front, 2i+1 back), jittered
    stratified in (radius², azimuth)."""
    G = gx * gy
    for r in numba.prange(rows.shape[0]):
        row = rows[r]
        i = row // 2
        sgn = 1.0 if row % 2 == 0 else -1.0
        nx = sgn * nrm[i, 0]
        ny = sgn * nrm[i, 1]
        nz = sgn * nrm[i, 2]
        for k in range(G):  # jittered: an independent point in every stratum
            u1 = ((k % gx) + _hash01(row, 2 * k + 1)) / gx
            u2 = ((k // gx) + _hash01(row, 2 * k + 2)) / gy
            j = r * G + k
            out_d[j, 0], out_d[j, 1], out_d[j, 2] = cosine_direction(nx, ny, nz, u1, u2)
            out_o[j, 0] = pos[i, 0] + eps * nx
            out_o[j, 1] = pos[i, 1] + eps * ny
            out_o[j, 2] = pos[i, 2] + eps * nz


@jit
def _bin_hits(G, d, geom, prim, hu, hv, face_offset, face_normal, two_sided_face, face_s, lat_start, lat_ids,
              hit_ray, hit_cols, hit_w, buried):
    """Classify a chunk's hits: the three lattice rows around the hit and their interpolation
    weights, or a hit on the inside of a closed shell (counted per row in ``buried``). Returns
    the number of hits written."""
    nh = 0
    for j in range(d.shape[0]):
        g = geom[j]
        if g < 0:
            continue
        f = face_offset[g] + prim[j]
        dot = d[j, 0] * face_normal[f, 0] + d[j, 1] * face_normal[f, 1] + d[j, 2] * face_normal[f, 2]
        side = 0 if dot < 0.0 else 1
        if side == 1 and not two_sided_face[f]:
            buried[j // G] += 1
            continue
        s = face_s[f]
        a0, b0, a1, b1, a2, b2, w0, w1, w2 = lattice_weights(s, hu[j], hv[j])
        base = lat_start[f]
        hit_ray[nh] = j
        hit_cols[nh, 0] = 2 * lat_ids[base + _lattice_local(s, a0, b0)] + side
        hit_cols[nh, 1] = 2 * lat_ids[base + _lattice_local(s, a1, b1)] + side
        hit_cols[nh, 2] = 2 * lat_ids[base + _lattice_local(s, a2, b2)] + side
        hit_w[nh, 0] = w0
        hit_w[nh, 1] = w1
        hit_w[nh, 2] = w2
        nh += 1
    return nh


@inline
def hit_normals(face_normal, corner_normal, f, b1, b2, dx, dy, dz):
    """Shading and geometric normals (unit) at a ray's hit on face f (barycentrics b1, b2), both
    turned towards the ray's origin (d the ray's direction); the geometric normal stands in where
    the interpolated one is degenerate or faces away from the ray."""
    sg = -1.0 if face_normal[f, 0] * dx + face_normal[f, 1] * dy + face_normal[f, 2] * dz > 0.0 else 1.0
    gx, gy, gz = sg * face_normal[f, 0], sg * face_normal[f, 1], sg * face_normal[f, 2]
    b0 = 1.0 - b1 - b2
    nx = sg * (b0 * corner_normal[f, 0, 0] + b1 * corner_normal[f, 1, 0] + b2 * corner_normal[f, 2, 0])
    ny = sg * (b0 * corner_normal[f, 0, 1] + b1 * corner_normal[f, 1, 1] + b2 * corner_normal[f, 2, 1])
    nz = sg * (b0 * corner_normal[f, 0, 2] + b1 * corner_normal[f, 1, 2] + b2 * corner_normal[f, 2, 2])
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn < 1e-12 or nx * dx + ny * dy + nz * dz > 0.0:
        return gx, gy, gz, gx, gy, gz
    return nx / nn, ny / nn, nz / nn, gx, gy, gz


@jit
def glossy_draw(nx, ny, nz, gx, gy, gz, dx, dy, dz, fr, fg, fb, alpha, u1, u2):
    """A path's next direction at a glossy hit (normals from :func:`hit_normals`, d the arriving
    ray's direction): one draw from the GGX lobe (visible normals) about the mirror of the ray,
    with uniforms u1, u2. Returns (lx, ly, lz, wr, wg, wb, ok): weight f_s·cos/pdf (RGB); ok False
    where the draw fails or goes under the geometric surface."""
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    lx, ly, lz, wr, wg, wb, ok = sample_brdf(nx, ny, nz, -dx / dn, -dy / dn, -dz / dn, 0.0, 0.0, 0.0, fr, fg, fb,
                                             alpha, 0.0, u1, u2)
    return lx, ly, lz, wr, wg, wb, ok and lx * gx + ly * gy + lz * gz > 0.0


@pjit
def _glossy_bounce(idx, o, d, tfar, geom, prim, hu, hv, face_offset, face_normal, corner_normal, comp_of_face,
                   f0, alpha, eps, key0, out_o, out_d, out_w, out_n):
    """For each listed cache ray (idx) that hit a glossy surface: one direction drawn from the
    surface's GGX lobe (:func:`glossy_draw`), its weight (0 if the draw fails or goes under the
    surface, the direction then the geometric normal), the ray's origin at the hit, and the
    hit's shading normal turned towards the ray."""
    for k in numba.prange(idx.shape[0]):
        j = idx[k]
        f = face_offset[geom[j]] + prim[j]
        c = comp_of_face[f]
        nx, ny, nz, gx, gy, gz = hit_normals(face_normal, corner_normal, f, hu[j], hv[j], d[j, 0], d[j, 1], d[j, 2])
        key = (key0 + j) & 0x7FFFFFFF
        lx, ly, lz, wr, wg, wb, ok = glossy_draw(nx, ny, nz, gx, gy, gz, d[j, 0], d[j, 1], d[j, 2], f0[c, 0],
                                                 f0[c, 1], f0[c, 2], alpha[c], _hash01(key, 41), _hash01(key, 42))
        if not ok:
            wr = 0.0
            wg = 0.0
            wb = 0.0
            lx, ly, lz = gx, gy, gz
        t = tfar[j]
        out_d[k, 0] = lx
        out_d[k, 1] = ly
        out_d[k, 2] = lz
        out_w[k, 0] = wr
        out_w[k, 1] = wg
        out_w[k, 2] = wb
        out_n[k, 0] = nx
        out_n[k, 1] = ny
        out_n[k, 2] = nz
        out_o[k, 0] = o[j, 0] + t * d[j, 0] + eps * gx
        out_o[k, 1] = o[j, 1] + t * d[j, 1] + eps * gy
        out_o[k, 2] = o[j, 2] + t * d[j, 2] + eps * gz


@pjit
def _glint_lattice(rec_face, rec_u, rec_v, rec_side, valid, face_s, lat_start, lat_ids, rows, weights):
    """The lattice rows around each glossy-hit record and their weights (:func:`lattice_rows`),
    which do not depend on the lighting: :func:`_glints` reads them every frame."""
    for k in numba.prange(rec_face.shape[0]):
        rows[k, 0], rows[k, 1], rows[k, 2], weights[k, 0], weights[k, 1], weights[k, 2] = lattice_rows(
            valid, face_s, lat_start, lat_ids, rec_face[k], rec_u[k], rec_v[k], rec_side[k])


@pjit
def _glints(ptr, rec_face, rows, weights, rec_n, rec_wo, comp_of_face, f0, alpha, E_sun, sun, scale, out):
    """out[row] += scale × Σ over the row's glossy-hit records of the Sun's specular reflection
    at the hit towards the row: f_s(sun, wo)·cosθ_sun·ν·E_sun·V, V the hit's sunlit fraction
    interpolated from the lattice (the cache's own shadow rays) at the record's lattice rows and
    weights (:func:`_glint_lattice`); ``sun`` the Sun record (:mod:`raytrace._lights`)."""
    sx, sy, sz, e_sun = sun[SUN_X], sun[SUN_Y], sun[SUN_Z], sun[SUN_E]
    for r in numba.prange(ptr.shape[0] - 1):
        acc0 = 0.0
        acc1 = 0.0
        acc2 = 0.0
        for k in range(ptr[r], ptr[r + 1]):
            vis = (weights[k, 0] if E_sun[rows[k, 0]] > 0.0 else 0.0) + \
                (weights[k, 1] if E_sun[rows[k, 1]] > 0.0 else 0.0) + (weights[k, 2] if E_sun[rows[k, 2]] > 0.0 else 0.0)
            if vis <= 0.0:
                continue
            c = comp_of_face[rec_face[k]]
            a, b, cc = brdf_cos(rec_n[k, 0], rec_n[k, 1], rec_n[k, 2], rec_wo[k, 0], rec_wo[k, 1], rec_wo[k, 2],
                                sx, sy, sz, 0.0, 0.0, 0.0, f0[c, 0], f0[c, 1], f0[c, 2], alpha[c])
            acc0 += a * vis
            acc1 += b * vis
            acc2 += cc * vis
        out[r, 0] += scale * e_sun * acc0
        out[r, 1] += scale * e_sun * acc1
        out[r, 2] += scale * e_sun * acc2


@pjit
def _ray_cells(d, idx, n_cells, out):
    """Octahedral sky cell (n×n) of the directions d[idx]."""
    for k in numba.prange(idx.shape[0]):
        j = idx[k]
        out[k] = env.oct_cell(d[j, 0], d[j, 1], d[j, 2], n_cells)


@pjit
def _irradiance_corners(n_t, n_p, nrm, rows, idx, w):
    """Where each listed row's plane (sample normal, turned to the row's side) reads an n_t × n_p
    irradiance table (:func:`raytrace.environment.irradiance_table`): its cell (i, j, j + 1 mod
    n_p) and bilinear weights (w00, w01, w10, w11), as :func:`raytrace.environment.irradiance_lookup`
    finds them. They depend on the normals alone: found once per cache, the per-frame
    :func:`_rows_irradiance` only sums (its acos and atan2 were ~85 % of its time)."""
    for r in numba.prange(rows.shape[0]):
        row = rows[r]
        i = row // 2
        sgn = 1.0 if row % 2 == 0 else -1.0
        nx = sgn * nrm[i, 0]
        ny = sgn * nrm[i, 1]
        nz = sgn * nrm[i, 2]
        th = math.acos(max(-1.0, min(1.0, nz)))
        ph = math.atan2(ny, nx)
        if ph < 0.0:
            ph += 2.0 * math.pi
        x = th / math.pi * (n_t - 1)
        y = ph / (2.0 * math.pi) * n_p
        a = min(int(x), n_t - 2)
        j = int(y) % n_p
        fx = x - a
        fy = y - math.floor(y)
        idx[r, 0] = a
        idx[r, 1] = j
        idx[r, 2] = (j + 1) % n_p
        w[r, 0] = (1.0 - fx) * (1.0 - fy)
        w[r, 1] = (1.0 - fx) * fy
        w[r, 2] = fx * (1.0 - fy)
        w[r, 3] = fx * fy


@pjit
def _rows_irradiance(table, rows, idx, w, out):
    """The environment's unoccluded irradiance on each listed row's plane: the table bilinearly
    interpolated at the row's cell and weights (:func:`_irradiance_corners`), the same sum as
    :func:`raytrace.environment.irradiance_lookup`'s, the same bits."""
    for r in numba.prange(rows.shape[0]):
        row = rows[r]
        i = idx[r, 0]
        j = idx[r, 1]
        j1 = idx[r, 2]
        w00 = w[r, 0]
        w01 = w[r, 1]
        w10 = w[r, 2]
        w11 = w[r, 3]
        for c in range(3):
            out[row, c] = w00 * table[i, j, c] + w01 * table[i, j1, c] + w10 * table[i + 1, j, c] + \
                w11 * table[i + 1, j1, c]


@pjit
def _sun_rays(rows, pos, nrm, eps, sun, cos_out, out_o, out_d):
    """Per listed row: cos θ of the Sun on the row's side, and a shadow ray towards the Sun
    (``sun`` the Sun record, :mod:`raytrace._lights`) from the sample offset along that side."""
    sx, sy, sz = sun[SUN_X], sun[SUN_Y], sun[SUN_Z]
    for r in numba.prange(rows.shape[0]):
        row = rows[r]
        i = row // 2
        sgn = 1.0 if row % 2 == 0 else -1.0
        c = sgn * (nrm[i, 0] * sx + nrm[i, 1] * sy + nrm[i, 2] * sz)
        cos_out[r] = c
        for a in range(3):
            out_o[r, a] = pos[i, a] + sgn * eps * nrm[i, a]
        out_d[r, 0] = sx
        out_d[r, 1] = sy
        out_d[r, 2] = sz


@inline
def _row_sum(i, indptr, indices, data, Y, g_ptr, g_idx, g_data, Yb, X0):
    """Row i of X0 + W_ss Y + W_g Yb (CSR; W_g's entries RGB), the terms in stored order."""
    s0 = X0[i, 0]
    s1 = X0[i, 1]
    s2 = X0[i, 2]
    for k in range(indptr[i], indptr[i + 1]):
        j = indices[k]
        w = data[k]
        s0 += w * Y[j, 0]
        s1 += w * Y[j, 1]
        s2 += w * Y[j, 2]
    for k in range(g_ptr[i], g_ptr[i + 1]):
        j = g_idx[k]
        s0 += g_data[k, 0] * Yb[j, 0]
        s1 += g_data[k, 1] * Yb[j, 1]
        s2 += g_data[k, 2] * Yb[j, 2]
    return s0, s1, s2


@pjit_exact
def _jacobi_step(indptr, indices, data, Y, g_ptr, g_idx, g_data, Yb, X, X0, out):
    """out = X0 + W_ss Y + W_g Yb for CSR matrices: W_ss (rows, rows) with RGB rows Y (= ρ ⊙ X),
    and W_g, the light glossy parts reflect along their lobes, with RGB entries g_data (nnz, 3)
    and Yb = ρ_bounce ⊙ X (empty without glossy parts); returns max |out − X|. One row per
    thread, in a fixed order: the result does not depend on the thread count. Without
    fastmath: with it (reassociation) LLVM vectorised the sparse row sums into gathers that
    ran 1.5–2× slower (ICESat, 411 k non-zeros: 1.4 → 0.85 ms per step, median of 300).

    The per-row differences go to an ``np.empty`` array, their maximum is taken by a plain loop:
    ``np.zeros`` and ``.max()`` would each be a parallel loop of their own, which numba
    compiles like the row loop, LLVM's work four libraries over (the kernel's compile on one
    core 1.9 → 0.8 s; the same result: every row is written, and a maximum does not depend on
    its order)."""
    n = X.shape[0]
    dmax = np.empty(n)
    for i in numba.prange(n):
        s0, s1, s2 = _row_sum(i, indptr, indices, data, Y, g_ptr, g_idx, g_data, Yb, X0)
        out[i, 0] = s0
        out[i, 1] = s1
        out[i, 2] = s2
        dmax[i] = max(abs(s0 - X[i, 0]), abs(s1 - X[i, 1]), abs(s2 - X[i, 2]))
    d = 0.0
    for i in range(n):
        v = dmax[i]
        if v != v:  # NaN, as NumPy's max returns it
            return v
        if v > d:
            d = v
    return d


@jit_exact
def _csr_sum(rows, cols, vals, keep, n_rows, n_cols):
    """The CSR matrix (n_rows, n_cols) of the entries (rows[i], cols[i, a], vals[i, a, :]) of
    the kept i (all a), duplicates summed: (indptr int64, indices int32, data (nnz, k)), each
    row's columns ascending, its duplicates summed in input order (as ``np.bincount`` does).
    What ``scipy.sparse.csr_matrix((data, (i, j)))`` and ``np.unique`` + ``np.bincount`` did in
    0.5–60 s per cache build (a COO copy, a sort per row, Python's fancy indexing: 21 s of
    Hubble's 29 s build, 59 s of ICESat-2's 85 s), here in one pass over the entries with a
    dense accumulator per row: entries grouped by row (in input order where the rows ascend,
    else a counting sort, stable), each row's distinct columns marked in a bitmap and read
    back in order."""
    m, na = cols.shape
    nch = vals.shape[2]
    count = np.zeros(n_rows + 1, np.int64)
    ascending = True
    last = -1
    for i in range(m):
        if keep[i]:
            count[rows[i] + 1] += na
            if rows[i] < last:
                ascending = False
            last = rows[i]
    for r in range(n_rows):
        count[r + 1] += count[r]
    # entry i * na + a, grouped by row: the kept entries in input order where their rows ascend
    # (the cache's casts list them so), else a counting sort
    order = np.empty(count[n_rows], np.int64)
    if ascending:
        e = 0
        for i in range(m):
            if keep[i]:
                for a in range(na):
                    order[e] = i * na + a
                    e += 1
    else:
        fill = count[:n_rows].copy()
        for i in range(m):
            if keep[i]:
                r = rows[i]
                for a in range(na):
                    order[fill[r]] = i * na + a
                    fill[r] += 1
    # each row's distinct columns marked in a bitmap of the columns and a bitmap of its words,
    # then read back in ascending order (trailing-zero counts) and cleared: no sort per row
    acc = np.zeros((n_cols, nch))
    n_words = (n_cols + 63) // 64
    bits = np.zeros(n_words, np.uint64)
    summary = np.zeros((n_words + 63) // 64, np.uint64)
    one = np.uint64(1)
    indptr = np.zeros(n_rows + 1, np.int64)
    indices = np.empty(count[n_rows], np.int32)
    data = np.empty((count[n_rows], nch))
    nnz = 0
    for r in range(n_rows):
        s_lo = summary.shape[0]
        s_hi = -1
        for e in range(count[r], count[r + 1]):
            i = order[e] // na
            a = order[e] - i * na
            c = cols[i, a]
            wd = c >> 6
            bit = one << np.uint64(c & 63)
            if bits[wd] & bit:
                for ch in range(nch):
                    acc[c, ch] += vals[i, a, ch]
            else:
                bits[wd] |= bit
                sd = wd >> 6
                summary[sd] |= one << np.uint64(wd & 63)
                s_lo = min(s_lo, sd)
                s_hi = max(s_hi, sd)
                for ch in range(nch):
                    acc[c, ch] = vals[i, a, ch]
        for sd in range(s_lo, s_hi + 1):
            sw = summary[sd]
            summary[sd] = 0
            while sw:
                wd = sd * 64 + trailing_zeros(sw)
                sw &= sw - one
                bw = bits[wd]
                bits[wd] = 0
                while bw:
                    c = wd * 64 + trailing_zeros(bw)
                    bw &= bw - one
                    indices[nnz] = c
                    for ch in range(nch):
                        data[nnz, ch] = acc[c, ch]
                    nnz += 1
        indptr[r + 1] = nnz
    return indptr, indices[:nnz].copy(), data[:nnz].copy()


@pjit_exact
def _zero_rows(A, rows):
    """A[rows] = 0 for the rows of a 2-D array: what NumPy's masked assignment did in 1–4 ms per
    frame on the cache's unsolved rows (most of them: back sides, buried and passive rows; 141 k
    of Crew Dragon's 155 k contact rows), here ~0.1 ms."""
    for k in numba.prange(rows.shape[0]):
        r = rows[k]
        for c in range(A.shape[1]):
            A[r, c] = 0.0


@jit_exact
def _gauss_seidel_sweep(indptr, indices, data, g_ptr, g_idx, g_data, rho, rho_b, X0, X, Y, Yb, omega):
    """One Gauss–Seidel sweep of X = X0 + W_ss (ρ ⊙ X) + W_g (ρ_bounce ⊙ X), in place: the rows
    in order, each from the newest values of the rows before it, over-relaxed by ``omega``
    (X_i ← X_i + ω (s_i − X_i), s_i the row's sum; ω = 1: plain Gauss–Seidel, see
    :data:`raytrace.presets.SOR_OMEGA`). Y = ρ ⊙ X and Yb = ρ_bounce ⊙ X (empty without glossy
    parts) are kept up to date row by row. Returns max |s_i − X_i| (the row's residual, before relaxation).
    A row without entries whose X already equals X0 is skipped (its sum is X0, its residual 0, and
    Y, Yb hold ρ ⊙ X there as everywhere): the unsolved rows (back sides, buried rows), 68 % of
    Cassini's coarse rows; a sweep there 0.9× the time, the same bits.

    One thread, in row order, so the result does not depend on the thread count. It replaces
    the parallel Jacobi step (:func:`_jacobi_step`), which the sparse product's memory traffic
    held to about one core's speed (1.15–1.75 ms per step on Cassini with one thread or two).
    The transfer T (W_ss ρ and W_g ρ_bounce, per channel) is non-negative with spectral radius
    below 1, so I − T is an M-matrix; the Jacobi-like step (all of T on the right-hand side)
    and this sweep (T's strictly lower part on the left) are both regular splittings of it, and
    the sweep leaves less of T on the right, so its spectral radius is no larger (Varga's
    comparison theorem for regular splittings, Matrix Iterative Analysis, 2nd ed., 2000,
    ch. 3; with a zero diagonal, the Stein–Rosenberg theorem). Where Jacobi's error swings
    between two facing surfaces (eigenvalues near −r, which made over-relaxation diverge),
    a sweep updates the second surface from the first one's new value. Measured on the 12
    benchmark scenes: 12–14 sweeps to the 1e-3 tolerance where Jacobi took 18–25 (7–8 → 5–6
    on Crew Dragon), and a smaller error against a 1e-13 solve (BENCHMARKS.md, "Gauss–Seidel
    for the radiance cache")."""
    n = X.shape[0]
    glossy = Yb.shape[0] > 0
    dmax = 0.0
    for i in range(n):
        if indptr[i] == indptr[i + 1] and g_ptr[i] == g_ptr[i + 1] and X[i, 0] == X0[i, 0] and \
                X[i, 1] == X0[i, 1] and X[i, 2] == X0[i, 2]:
            continue  # a row without entries at its source: the sweep would write the same values
        s0, s1, s2 = _row_sum(i, indptr, indices, data, Y, g_ptr, g_idx, g_data, Yb, X0)
        d = max(abs(s0 - X[i, 0]), abs(s1 - X[i, 1]), abs(s2 - X[i, 2]))
        if d > dmax:
            dmax = d
        if omega != 1.0:
            s0 = X[i, 0] + omega * (s0 - X[i, 0])
            s1 = X[i, 1] + omega * (s1 - X[i, 1])
            s2 = X[i, 2] + omega * (s2 - X[i, 2])
        X[i, 0] = s0
        X[i, 1] = s1
        X[i, 2] = s2
        Y[i, 0] = rho[i, 0] * s0
        Y[i, 1] = rho[i, 1] * s1
        Y[i, 2] = rho[i, 2] * s2
        if glossy:
            Yb[i, 0] = rho_b[i, 0] * s0
            Yb[i, 1] = rho_b[i, 1] * s1
            Yb[i, 2] = rho_b[i, 2] * s2
    return dmax


@pjit_exact
def _lookup_rows(alias, n_c, E_c, E_f, sun_c, sun_f, rho_over_pi, E, E_sun, indirect, L_out):
    """Per lookup row r (coarse rows, then contact rows): the values of row alias[r] (a coarse
    row below n_c, else contact row alias[r] − n_c; buried rows take their stand-in's), its
    indirect part E − E_sun and its outgoing radiance ρ/π · E, the same bits as NumPy's
    whole-array concatenation, gather and products, which took up to ~12 ms per frame (Crew
    Dragon's 206 k rows; this pass 0.7–1.7 ms on the four targets)."""
    for r in numba.prange(alias.shape[0]):
        a = alias[r]
        if a < n_c:
            e0 = E_c[a, 0]
            e1 = E_c[a, 1]
            e2 = E_c[a, 2]
            es = sun_c[a]
        else:
            e0 = E_f[a - n_c, 0]
            e1 = E_f[a - n_c, 1]
            e2 = E_f[a - n_c, 2]
            es = sun_f[a - n_c]
        E[r, 0] = e0
        E[r, 1] = e1
        E[r, 2] = e2
        E_sun[r] = es
        indirect[r, 0] = e0 - es
        indirect[r, 1] = e1 - es
        indirect[r, 2] = e2 - es
        L_out[r, 0] = rho_over_pi[r, 0] * e0
        L_out[r, 1] = rho_over_pi[r, 1] * e1
        L_out[r, 2] = rho_over_pi[r, 2] * e2


@inline
def lattice_rows(valid, face_s, lat_start, lat_ids, f, b1, b2, side):
    """The three cache rows around barycentrics (b1, b2) of face f on ``side`` (0 front, 1
    back) and their linear interpolation weights; rows that do not exist get weight 0 (the
    others are renormalised; all three 0 when none exists)."""
    s = face_s[f]
    a0, c0, a1, c1, a2, c2, w0, w1, w2 = lattice_weights(s, b1, b2)
    base = lat_start[f]
    r0 = 2 * lat_ids[base + _lattice_local(s, a0, c0)] + side
    r1 = 2 * lat_ids[base + _lattice_local(s, a1, c1)] + side
    r2 = 2 * lat_ids[base + _lattice_local(s, a2, c2)] + side
    if not valid[r0]:
        w0 = 0.0
    if not valid[r1]:
        w1 = 0.0
    if not valid[r2]:
        w2 = 0.0
    wt = w0 + w1 + w2
    if wt > 0.0:
        w0 /= wt
        w1 /= wt
        w2 /= wt
    return r0, r1, r2, w0, w1, w2


@inline
def interpolate_rows(values, valid, face_s, lat_start, lat_ids, f, b1, b2, side):
    """Value (RGB) of a per-row array at barycentrics (b1, b2) of face f on ``side``."""
    r0, r1, r2, w0, w1, w2 = lattice_rows(valid, face_s, lat_start, lat_ids, f, b1, b2, side)
    return (w0 * values[r0, 0] + w1 * values[r1, 0] + w2 * values[r2, 0],
            w0 * values[r0, 1] + w1 * values[r1, 1] + w2 * values[r2, 1],
            w0 * values[r0, 2] + w1 * values[r1, 2] + w2 * values[r2, 2])


@jit
def _interp_rows(valid, face_s, lat_start, lat_ids, face, b1, b2, cols, w):
    """Rows 2i, 2i+1: the lattice rows around barycentrics (b1[i], b2[i]) of face[i] on the
    front and back side, and their interpolation weights (:func:`lattice_rows`)."""
    for i in range(face.shape[0]):
        for side in range(2):
            r0, r1, r2, w0, w1, w2 = lattice_rows(valid, face_s, lat_start, lat_ids, face[i], b1[i], b2[i], side)
            k = 2 * i + side
            cols[k, 0], cols[k, 1], cols[k, 2] = r0, r1, r2
            w[k, 0], w[k, 1], w[k, 2] = w0, w1, w2
