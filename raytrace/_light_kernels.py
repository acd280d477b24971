"""Kernels of the radiance split by source (:mod:`raytrace._light_parts`)."""

from __future__ import annotations

import math

import numba
import numpy as np

from . import environment as env
from ._cache_kernels import lattice_rows
from ._jit import inline, pjit_exact

# the parts' order in the image (raytrace._light_parts.PARTS: earth, inter, sky, sun)
_EARTH, _INTER, _SKY, _SUN = 0, 1, 2, 3


@pjit_exact
def centre_parts(D_earth, D_sky, has_earth, has_sky, valid, face_s, lat_start, lat_ids, face, B, SIDE, E_ind, L_sun,
                 L_total, out):
    """Per pixel centre k: its radiance ``L_total[k]`` split into parts ``out[k]`` (4, 3; float32): the
    Sun's term ``L_sun[k]``, and the rest in the proportions of the cache's indirect irradiance
    at the point ``E_ind[k]``: Earth's and the sky's direct environment terms (per-row arrays
    ``D_earth``, ``D_sky`` interpolated at the point as the cache's irradiance is; 0 without
    ``has_earth`` / ``has_sky``) and what remains of it, inter-reflection. Negative values
    (interpolation overshoot, a lobe correction) count as 0."""
    for k in numba.prange(face.shape[0]):
        r0, r1, r2, w0, w1, w2 = lattice_rows(valid, face_s, lat_start, lat_ids, face[k], B[k, 0], B[k, 1], SIDE[k])
        for c in range(3):
            e = 0.0
            if has_earth:
                e = max(w0 * D_earth[r0, c] + w1 * D_earth[r1, c] + w2 * D_earth[r2, c], 0.0)
            s = 0.0
            if has_sky:
                s = max(w0 * D_sky[r0, c] + w1 * D_sky[r1, c] + w2 * D_sky[r2, c], 0.0)
            i = max(E_ind[k, c], 0.0) - e - s
            if i < 0.0:
                i = 0.0
            tot = e + s + i
            sun = max(L_sun[k, c], 0.0)
            rest = max(L_total[k, c] - sun, 0.0)
            out[k, _SUN, c] = sun
            if tot > 0.0:
                out[k, _EARTH, c] = rest * (e / tot)
                out[k, _SKY, c] = rest * (s / tot)
                out[k, _INTER, c] = rest * (i / tot)
            else:
                out[k, _EARTH, c] = 0.0
                out[k, _SKY, c] = 0.0
                out[k, _INTER, c] = rest


@pjit_exact
def assemble(P, row_of_pixel, mixed, parts, bg, has_bg, H, W, out):
    """The parts image ``out`` (H·W, 12) of the radiance ``P`` (H·W, 3): a pixel whose centre
    is on the target (row_of_pixel ≥ 0: the row of ``parts`` (n, 4, 3) holding its centre's
    parts) is shared out in those proportions, a ``mixed`` one in the proportions of the sum
    of its 3 × 3 centres' parts (a background centre counting Earth's disc behind it as
    Earth's, with ``has_bg``: its own value in ``P``, or for a mixed one, whose value in ``P``
    is its sub-samples' mean, bg[−2 − row_of_pixel]), any other (row_of_pixel −1) is
    background, Earth's disc: all ``earth``. Per channel; where the
    proportions are all 0, all to the Sun. ``out`` must come zeroed: black background pixels
    are not written."""
    for i in numba.prange(H * W):
        r = row_of_pixel[i]
        if r == -1 and not mixed[i]:
            if P[i, 0] == 0.0 and P[i, 1] == 0.0 and P[i, 2] == 0.0:
                continue  # black space: ``out`` comes zeroed (untouched pages of np.zeros stay unmapped)
            for c in range(3):
                out[i, 3 * _EARTH + c] = P[i, c]
            continue
        if mixed[i]:
            # the neighbourhood's sum, gathered in place (float32; only its proportions matter)
            for j in range(12):
                out[i, j] = 0.0
            v = i // W
            u = i - v * W
            for dv in range(-1, 2):
                vv = min(max(v + dv, 0), H - 1)
                for du in range(-1, 2):
                    q = vv * W + min(max(u + du, 0), W - 1)
                    rq = row_of_pixel[q]
                    if rq >= 0:
                        for p in range(4):
                            for c in range(3):
                                out[i, 3 * p + c] += parts[rq, p, c]
                    elif has_bg:
                        for c in range(3):
                            out[i, 3 * _EARTH + c] += bg[-2 - rq, c] if rq <= -2 else P[q, c]
        for c in range(3):
            if mixed[i]:
                a0 = np.float64(out[i, c])
                a1 = np.float64(out[i, 3 + c])
                a2 = np.float64(out[i, 6 + c])
                a3 = np.float64(out[i, 9 + c])
            else:
                a0 = np.float64(parts[r, 0, c])
                a1 = np.float64(parts[r, 1, c])
                a2 = np.float64(parts[r, 2, c])
                a3 = np.float64(parts[r, 3, c])
            S = a0 + a1 + a2 + a3
            x = np.float64(P[i, c])
            if S > 0.0:
                out[i, c] = np.float32(x * (a0 / S))
                out[i, 3 + c] = np.float32(x * (a1 / S))
                out[i, 6 + c] = np.float32(x * (a2 / S))
                out[i, 9 + c] = np.float32(x * (a3 / S))
            else:
                out[i, c] = 0.0
                out[i, 3 + c] = 0.0
                out[i, 6 + c] = 0.0
                out[i, 9 + c] = 0.0
                out[i, 3 * _SUN + c] = np.float32(x)


@pjit_exact
def mark_rows(valid, face_s, lat_start, lat_ids, face, B, SIDE, mark):
    """mark[r] = True for the three cache rows around each point (face[k], B[k], SIDE[k]), the
    rows its interpolation reads."""
    for k in numba.prange(face.shape[0]):
        r0, r1, r2, w0, w1, w2 = lattice_rows(valid, face_s, lat_start, lat_ids, face[k], B[k, 0], B[k, 1], SIDE[k])
        mark[r0] = True
        mark[r1] = True
        mark[r2] = True


@inline
def _environment_row(row, nrm, ptr, idx, dat, L_env, table):
    """E_env(n) − π W_sb L_env of one solved row (sample row // 2, its side by the parity)."""
    i = row // 2
    sgn = 1.0 if row % 2 == 0 else -1.0
    e0, e1, e2 = env.irradiance_lookup(table, sgn * nrm[i, 0], sgn * nrm[i, 1], sgn * nrm[i, 2])
    for k in range(ptr[row], ptr[row + 1]):
        j = idx[k]
        w = -math.pi * dat[k]
        e0 += w * L_env[j, 0]
        e1 += w * L_env[j, 1]
        e2 += w * L_env[j, 2]
    return e0, e1, e2


@inline
def _coarse_environment(a, c_solved, c_nrm, c_ptr, c_idx, c_dat, L_env, table):
    if not c_solved[a]:
        return 0.0, 0.0, 0.0
    return _environment_row(a, c_nrm, c_ptr, c_idx, c_dat, L_env, table)


@pjit_exact
def environment_rows(rows, alias, n_c, c_solved, c_nrm, c_ptr, c_idx, c_dat, f_solved, f_nrm, f_ptr, f_idx, f_dat,
                     passive_pos, P_ptr, P_idx, P_dat, c_alias, L_env, table, out):
    """out[r] for each lookup row r of ``rows``: the direct environment term of the cache row it
    reads (alias[r]: a coarse row below n_c, else contact row alias[r] − n_c), as
    :meth:`raytrace.cache.RadianceCache.solve` forms its source term: E_env(n) − π W_sb L_env on
    solved rows (W_sb CSR ``*_ptr``, ``*_idx``, ``*_dat``; L_env per sky cell; ``table`` the
    unoccluded irradiance), 0 on unsolved ones, and on passive contact rows (passive_pos ≥ 0:
    their row of the CSR ``P_*``) the interpolation of the coarse rows' (through ``c_alias``)."""
    for m in numba.prange(rows.shape[0]):
        r = rows[m]
        a = alias[r]
        if a < n_c:
            v0, v1, v2 = _coarse_environment(a, c_solved, c_nrm, c_ptr, c_idx, c_dat, L_env, table)
        else:
            j = a - n_c
            pp = passive_pos[j]
            if pp >= 0:
                v0 = 0.0
                v1 = 0.0
                v2 = 0.0
                for k in range(P_ptr[pp], P_ptr[pp + 1]):
                    w = P_dat[k]
                    c0, c1, c2 = _coarse_environment(c_alias[P_idx[k]], c_solved, c_nrm, c_ptr, c_idx, c_dat, L_env,
                                                     table)
                    v0 += w * c0
                    v1 += w * c1
                    v2 += w * c2
            elif not f_solved[j]:
                v0 = 0.0
                v1 = 0.0
                v2 = 0.0
            else:
                v0, v1, v2 = _environment_row(j, f_nrm, f_ptr, f_idx, f_dat, L_env, table)
        out[r, 0] = v0
        out[r, 1] = v1
        out[r, 2] = v2
