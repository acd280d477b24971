"""Kernels of the radiance split by source (:mod:`raytrace._light_parts`)."""

from __future__ import annotations

import numba
import numpy as np

from ._cache_kernels import lattice_rows
from ._jit import pjit_exact

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
    of its 3 × 3 centres' parts (a background centre counting Earth's disc ``bg`` behind it as
    Earth's), any other is background, Earth's disc: all ``earth``. Per channel; where the
    proportions are all 0, all to the Sun."""
    for i in numba.prange(H * W):
        r = row_of_pixel[i]
        if not mixed[i] and r < 0:
            for c in range(3):
                out[i, 3 * _EARTH + c] = P[i, c]
                out[i, 3 * _INTER + c] = 0.0
                out[i, 3 * _SKY + c] = 0.0
                out[i, 3 * _SUN + c] = 0.0
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
                            out[i, 3 * _EARTH + c] += bg[q, c]
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
