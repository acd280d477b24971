"""Numba kernels that gather, scatter and reduce rows of 3 (points, rays, sub-samples) on both
cores: what NumPy's fancy indexing and reductions did on one.
"""

from __future__ import annotations

import numba
import numpy as np

from ._jit import pjit_exact


@pjit_exact
def take_rows(src, idx, out):
    """out[j] = src[idx[j]] (rows of 3): NumPy's ``src[idx]`` on both cores."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            out[j, a] = src[i, a]


@pjit_exact
def take_ray_rows(idx, O, D, O_out, D_out, O32, D32):
    """The rays ``idx`` of (O, D) (rows of 3, float64): O_out[j] = O[idx[j]], D_out[j] =
    D[idx[j]], and both rounded to float32 for Embree (O32, D32) in the same pass: NumPy's
    ``O[idx]``, ``D[idx]`` and their two ``astype(np.float32)``."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        for a in range(3):
            o = O[i, a]
            d = D[i, a]
            O_out[j, a] = o
            D_out[j, a] = d
            O32[j, a] = np.float32(o)
            D32[j, a] = np.float32(d)


@pjit_exact
def unit_rows(D, idx, out):
    """out[j] = D[idx[j]] / |D[idx[j]]|: NumPy's ``D[idx] / np.linalg.norm(D[idx], axis=1,
    keepdims=True)`` to the bit (its sum of squares is left to right, (x² + y²) + z²)."""
    for j in numba.prange(idx.shape[0]):
        i = idx[j]
        x = D[i, 0]
        y = D[i, 1]
        z = D[i, 2]
        n = np.sqrt(x * x + y * y + z * z)
        out[j, 0] = x / n
        out[j, 1] = y / n
        out[j, 2] = z / n


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
