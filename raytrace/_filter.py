"""Numba kernels of ``balanced``'s residual filter: the edge-avoiding à-trous passes guided by
the ids, normals and depths and by the gathers' own noise, the variance they leave, the
local-linear fit's moments, and the same-part neighbourhood means of the two-pass gather.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._jit import inline, pjit_exact
from ._lens import ray_xy


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
def atrous(img, var, vblur, lum, inst, normal, depth, fx, fy, cx, cy, lens, table, step, sigma_l, out, out_var):
    """One pass of the edge-avoiding à-trous wavelet filter (Dammertz et al. 2010,
    doi:10.2312/EGGH/HPG10/067-075): a 5×5 B3-spline kernel with holes of ``step`` pixels,
    weighted by same instance id, normal agreement (n·n')^64 and distance from the centre
    pixel's tangent plane (in units of the pixel footprint). ``img`` has any number of
    channels, all filtered with the same weights; (cx, cy) is the principal point in the
    coordinates of the (cropped) image, ``lens``/``table`` the camera's lens
    (:mod:`raytrace._lens`: pixels back-projected along their undistorted rays).

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
    distorted = lens.shape[0] > 0
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
            x0, y0 = ray_xy(lens, table, (u - cx) / fx, (v - cy) / fy)
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
                    if distorted:  # the two points along their rays, (x, y, 1)·z
                        x1, y1 = ray_xy(lens, table, (uu - cx) / fx, (vv - cy) / fy)
                        dxp = x1 * z1 - x0 * z0
                        dyp = y1 * z1 - y0 * z0
                    else:
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
