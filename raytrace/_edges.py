"""Numba kernels of anti-aliasing: which pixels to anti-alias (neighbours that disagree,
triangles thinner than a pixel, the shadows of such slivers), their sub-pixel rays, the filtered
light a sub-sample takes from the pixel centres on its surface, and the coverage counts that
combine shaded sub-samples with unshaded coverage rays.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._jit import inline, jit, jit_exact, pjit, pjit_exact
from ._lens import project_px, ray_xy
from ._sampling import _cmj_perms, _cmj_point, _hash01


@inline
def _three_rows(img, v, vm, vp, lo, hi):
    """Columns lo:hi of rows v, vm (above) and vp (below) of ``img`` (views)."""
    return img[v, lo:hi], img[vm, lo:hi], img[vp, lo:hi]


@inline
def _id_or_earth_differs(a, am, ap, e, em, ep, k, left, right):
    """:func:`edge_pixels`' id and Earth test of pixel k of row slice ``a``/``e`` (rows above
    and below ``am``/``ap``, ``em``/``ep``), with or without its left and right neighbours."""
    x = a[k]
    y = e[k]
    f = (am[k] != x) | (ap[k] != x) | (em[k] != y) | (ep[k] != y)
    if left:
        f = f | (a[k - 1] != x) | (e[k - 1] != y)
    if right:
        f = f | (a[k + 1] != x) | (e[k + 1] != y)
    return f


@inline
def _differs(l0, n0, d0, k, l1, n1, d1, j):
    """:func:`edge_pixels`' shading test between pixel k of one row's lit, normal and depth
    slices and pixel j of another's (or the same)."""
    if l1[j] != l0[k]:
        return True
    nd = n0[k, 0] * n1[j, 0] + n0[k, 1] * n1[j, 1] + n0[k, 2] * n1[j, 2]
    return nd < 0.9 or abs(d1[j] - d0[k]) > 0.03 * d0[k]


@pjit
def edge_pixels(inst, lit_img, normal, depth, earth_px, rect, out):
    """Pixels whose 4-neighbours disagree: another id (or Earth vs space), lit vs shadowed,
    a crease (normals > ~25° apart) or a depth step (> 3 % of the depth); neighbours outside
    the image do not count. Sets ``out`` inside ``rect`` = (u0, v0, u1, v1), ends excluded.

    Per row, the loops run over row slices that start one pixel left of the first pixel with
    a left neighbour, and index from a constant: numba wraps negative indices, and where it
    cannot prove an index ≥ 0 (a start taken from ``rect``) the select it adds kept LLVM from
    vectorising. Written as one loop with the neighbours' offsets computed per pixel, the
    kernel took 10–14 ms on a 1280 × 960 Earth view (every pixel checked); this way 2–4 ms,
    the same flags (``tests/raytrace/test_edge_pixels.py``)."""
    H, W = inst.shape
    u0, v0, u1, v1 = rect[0], rect[1], rect[2], rect[3]
    if u1 <= u0 or v1 <= v0:
        return
    lo = max(u0, 1) - 1
    hi = min(u1, W - 1) + 1
    n = hi - lo
    for v in numba.prange(v0, v1):
        vm = v - 1 if v > 0 else v
        vp = v + 1 if v < H - 1 else v
        a, am, ap = _three_rows(inst, v, vm, vp, lo, hi)
        e, em, ep = _three_rows(earth_px, v, vm, vp, lo, hi)
        o = out[v, lo:hi]
        for k in range(1, n - 1):
            x = a[k]
            y = e[k]
            o[k] = ((a[k + 1] != x) | (a[k - 1] != x) | (am[k] != x) | (ap[k] != x)
                    | (e[k + 1] != y) | (e[k - 1] != y) | (em[k] != y) | (ep[k] != y))
        if u0 == 0:
            o[0] = _id_or_earth_differs(a, am, ap, e, em, ep, 0, False, n > 1)
        if u1 == W:
            o[n - 1] = _id_or_earth_differs(a, am, ap, e, em, ep, n - 1, n > 1, False)
        # lit/shadow, creases and depth steps: between target pixels only
        first = u0 - lo
        while first < u1 - lo and a[first] == 0:
            first += 1
        last = u1 - lo - 1
        while last >= first and a[last] == 0:
            last -= 1
        if first > last:
            continue
        li, lm, lp = _three_rows(lit_img, v, vm, vp, lo, hi)
        nr, nm, npl = _three_rows(normal, v, vm, vp, lo, hi)
        dr, dm, dp = _three_rows(depth, v, vm, vp, lo, hi)
        # pixels with both horizontal neighbours in the slices: shifted views, so that the loop
        # indexes from 0 and vectorises
        ks = max(first, 1)
        ke = min(last + 1, n - 1)
        if ke > ks:
            c_a, c_o = a[ks:ke], o[ks:ke]
            c_l, c_n, c_d = li[ks:ke], nr[ks:ke], dr[ks:ke]
            w_l, w_n, w_d = li[ks - 1:ke - 1], nr[ks - 1:ke - 1], dr[ks - 1:ke - 1]
            e_l, e_n, e_d = li[ks + 1:ke + 1], nr[ks + 1:ke + 1], dr[ks + 1:ke + 1]
            m_l, m_n, m_d = lm[ks:ke], nm[ks:ke], dm[ks:ke]
            p_l, p_n, p_d = lp[ks:ke], npl[ks:ke], dp[ks:ke]
            for j in range(ke - ks):
                l0 = c_l[j]
                d0 = c_d[j]
                tol = 0.03 * d0
                n0, n1, n2 = c_n[j, 0], c_n[j, 1], c_n[j, 2]
                f = ((w_l[j] != l0) | (e_l[j] != l0) | (m_l[j] != l0) | (p_l[j] != l0)
                     | (n0 * w_n[j, 0] + n1 * w_n[j, 1] + n2 * w_n[j, 2] < 0.9)
                     | (n0 * e_n[j, 0] + n1 * e_n[j, 1] + n2 * e_n[j, 2] < 0.9)
                     | (n0 * m_n[j, 0] + n1 * m_n[j, 1] + n2 * m_n[j, 2] < 0.9)
                     | (n0 * p_n[j, 0] + n1 * p_n[j, 1] + n2 * p_n[j, 2] < 0.9)
                     | (abs(w_d[j] - d0) > tol) | (abs(e_d[j] - d0) > tol)
                     | (abs(m_d[j] - d0) > tol) | (abs(p_d[j] - d0) > tol))
                c_o[j] = c_o[j] | ((c_a[j] != 0) & f)
        for k in (first, last):
            if (k >= ks and k < ke) or o[k] or a[k] == 0:
                continue
            # a neighbour outside the image: the pixel itself, which never differs from itself
            # (the same holds for the rows above and below at the image's top and bottom; a
            # target pixel's normal is a unit vector)
            kl = k - 1 if k + lo > 0 else k
            kr = k + 1 if k + lo < W - 1 else k
            o[k] = (_differs(li, nr, dr, k, li, nr, dr, kl) or _differs(li, nr, dr, k, li, nr, dr, kr)
                    or _differs(li, nr, dr, k, lm, nm, dm, k) or _differs(li, nr, dr, k, lp, npl, dp, k))


@inline
def _centre_on_surface(q, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot):
    """The row of pixel q's centre if sub-sample m (part ``comp``, point P, shading normal NS)
    lies on its surface — same part, normals within ~25°, within a pixel footprint of the
    centre's tangent plane —, else −1."""
    k = row_of_pixel[q]
    if k < 0 or inst[q] - 1 != comp[m]:
        return -1
    if NS[m, 0] * N_c[k, 0] + NS[m, 1] * N_c[k, 1] + NS[m, 2] * N_c[k, 2] <= 0.9:
        return -1
    dx = P[m, 0] - P_c[k, 0]
    dy = P[m, 1] - P_c[k, 1]
    dz = P[m, 2] - P_c[k, 2]
    if abs(dx * N_c[k, 0] + dy * N_c[k, 1] + dz * N_c[k, 2]) > foot[k]:
        return -1
    return k


@pjit_exact
def donor_rows(centre, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c, foot, borrow, out):
    """For each sub-sample (pixel ``centre``, part ``comp``, point P, shading normal NS): the
    row of the pixel centre whose filtered light it takes, −1 for none. Its own pixel's
    centre if that lies on the same surface (same part, normals within 25°, the point within
    a pixel footprint of the centre's tangent plane); otherwise, with ``borrow``, the nearest
    (in space) of the 8 neighbouring centres on its surface; otherwise none."""
    for m in numba.prange(centre.shape[0]):
        c = centre[m]
        v = c // W
        u = c % W
        best = -1
        best_d2 = np.inf
        for a in range(10 if borrow else 1):  # a = 0: the pixel itself; a = 1..9: its 3 × 3 neighbourhood
            dv = (a - 1) // 3 - 1 if a > 0 else 0
            du = (a - 1) % 3 - 1 if a > 0 else 0
            if a == 5:
                continue  # the pixel itself again
            vv = v + dv
            uu = u + du
            if vv < 0 or vv >= H or uu < 0 or uu >= W:
                continue
            k = _centre_on_surface(vv * W + uu, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot)
            if k < 0:
                continue
            if a == 0:
                best = k
                break
            dx = P[m, 0] - P_c[k, 0]
            dy = P[m, 1] - P_c[k, 1]
            dz = P[m, 2] - P_c[k, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best_d2:
                best_d2 = d2
                best = k
        out[m] = best


@pjit_exact
def interpolate_rows_into(sel, D, R_cam_from_body, fx, fy, cx, cy, lens, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c,
                          foot, A, B, min_found, outA, outB, added):
    """For the listed sub-samples i (ray direction D[i], body frame; part ``comp``, point P,
    shading normal NS): outA[i] = Σ_j w_j A[k_j] (in place of what it held: the centres' filtered
    irradiance instead of the cache's) and outB[i] += Σ_j w_j B[k_j], over the (up to) four
    pixel centres k_j around the sub-sample's image point on its own surface
    (:func:`_centre_on_surface`), w_j their bilinear weights renormalised over those found (pixel
    centres at integer image coordinates). Nothing is added where fewer than ``min_found``
    (≥ 1) of the four are on its surface (outA and outB keep their values); added[t] tells
    whether sub-sample sel[t] was."""
    for t in numba.prange(sel.shape[0]):
        m = sel[t]
        xc = R_cam_from_body[0, 0] * D[m, 0] + R_cam_from_body[0, 1] * D[m, 1] + R_cam_from_body[0, 2] * D[m, 2]
        yc = R_cam_from_body[1, 0] * D[m, 0] + R_cam_from_body[1, 1] * D[m, 1] + R_cam_from_body[1, 2] * D[m, 2]
        zc = R_cam_from_body[2, 0] * D[m, 0] + R_cam_from_body[2, 1] * D[m, 1] + R_cam_from_body[2, 2] * D[m, 2]
        uf, vf = project_px(lens, fx, fy, cx, cy, xc, yc, zc)  # (distorted where ``lens`` is not empty)
        u0 = int(math.floor(uf))
        v0 = int(math.floor(vf))
        fu = uf - u0
        fv = vf - v0
        sw = 0.0
        found = 0
        a0 = a1 = a2 = b0 = b1 = b2 = 0.0
        for j in range(4):
            uu = u0 + (j & 1)
            vv = v0 + (j >> 1)
            if vv < 0 or vv >= H or uu < 0 or uu >= W:
                continue
            k = _centre_on_surface(vv * W + uu, m, row_of_pixel, inst, comp, P, NS, P_c, N_c, foot)
            if k < 0:
                continue
            w = (fu if j & 1 else 1.0 - fu) * (fv if j >> 1 else 1.0 - fv)
            found += 1
            sw += w
            a0 += w * A[k, 0]
            a1 += w * A[k, 1]
            a2 += w * A[k, 2]
            b0 += w * B[k, 0]
            b1 += w * B[k, 1]
            b2 += w * B[k, 2]
        added[t] = found >= min_found and sw > 0.0
        if added[t]:
            outA[m, 0] = a0 / sw
            outA[m, 1] = a1 / sw
            outA[m, 2] = a2 / sw
            outB[m, 0] += b0 / sw
            outB[m, 1] += b1 / sw
            outB[m, 2] += b2 / sw


@inline
def _project(V, i, R, t, fx, fy, cx, cy, lens):
    """Pixel coordinates (distorted by ``lens`` if not empty) and z-depth of vertex i
    (p_cam = R p + t); (0, 0, z) when z ≤ 0."""
    xc = R[0, 0] * V[i, 0] + R[0, 1] * V[i, 1] + R[0, 2] * V[i, 2] + t[0]
    yc = R[1, 0] * V[i, 0] + R[1, 1] * V[i, 1] + R[1, 2] * V[i, 2] + t[1]
    zc = R[2, 0] * V[i, 0] + R[2, 1] * V[i, 1] + R[2, 2] * V[i, 2] + t[2]
    if zc <= 0.0:
        return 0.0, 0.0, zc
    u, v = project_px(lens, fx, fy, cx, cy, xc, yc, zc)
    return u, v, zc


@pjit
def sliver_pixels(V, F, R, t, fx, fy, cx, cy, lens, z_min, max_width, depth, out):
    """Pixels touched by triangles whose projection is a sliver: narrower than ``max_width``
    pixels (twice its area over its longest edge) — a rod, wire or panel seen edge-on that
    can fall between pixel centres and corners, or a part smaller than a pixel (a triangle
    shorter than a pixel as well: in ``fast``, which casts no corner rays, this is what finds
    an antenna tip that no pixel centre hits; at 1280×960 the 12 benchmark scenes have none
    in front of another surface, at 160×120 they do). Marks ``out``
    (H, W) conservatively: every pixel square the projected triangle overlaps (separating
    axes: the square's two and the triangle's three edge normals) where the triangle's
    nearest point is nearer than the pixel centre's surface (``depth``, z-depth, inf on
    space) by more than 0.1 %: a sliver hidden behind that surface, or lying in it (the
    tessellation of a surface seen at a grazing angle), needs no extra samples. Triangles
    with a vertex nearer than ``z_min`` are skipped (the target is in front of the camera).
    Under lens distortion (``lens`` not empty) the vertices are projected with it and the
    triangle's image taken as straight-edged: a sliver's edges bend by far less than a pixel
    over its width."""
    H, W = out.shape
    for f in numba.prange(F.shape[0]):  # threads may mark a pixel at once: all write True
        # the three projected vertices as tuples (no array allocated per triangle)
        u_0, v_0, z_0 = _project(V, F[f, 0], R, t, fx, fy, cx, cy, lens)
        u_1, v_1, z_1 = _project(V, F[f, 1], R, t, fx, fy, cx, cy, lens)
        u_2, v_2, z_2 = _project(V, F[f, 2], R, t, fx, fy, cx, cy, lens)
        if z_0 <= z_min or z_1 <= z_min or z_2 <= z_min:
            continue
        z_near = min(z_0, z_1, z_2)
        px = (u_0, u_1, u_2)
        py = (v_0, v_1, v_2)
        area2 = abs((px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]))
        longest = 0.0
        for k in range(3):
            j = (k + 1) % 3
            longest = max(longest, math.hypot(px[j] - px[k], py[j] - py[k]))
        if area2 >= max_width * longest or longest > 4.0 * (W + H):
            continue  # (the last: a surface grazing the camera, not a wire)
        # pixel k spans [k − ½, k + ½]: the square's own axes are this bounding box
        u0 = max(math.ceil(min(px[0], px[1], px[2]) - 0.5), 0)
        u1 = min(math.floor(max(px[0], px[1], px[2]) + 0.5), W - 1)
        v0 = max(math.ceil(min(py[0], py[1], py[2]) - 0.5), 0)
        v1 = min(math.floor(max(py[0], py[1], py[2]) + 0.5), H - 1)
        # edge lines a·u + b·v + c ≥ 0 inside (orientation fixed by the sign of the area)
        sgn = 1.0 if (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]) > 0.0 else -1.0
        for v in range(v0, v1 + 1):
            # each edge's test is linear in u along the row: the u where it can pass, widened by
            # a pixel against rounding, bounds the pixels tested (a long diagonal wire's box is
            # mostly empty); the test below decides each of them as before
            ua = float(u0)
            ub = float(u1)
            for k in range(3):
                j = (k + 1) % 3
                a = -(py[j] - py[k]) * sgn
                b = (px[j] - px[k]) * sgn
                c = -(a * px[k] + b * py[k])
                r = b * v + c + 0.5 * (abs(a) + abs(b))  # the test: a·u + r ≥ 0
                # (an edge less than 10⁻³ px high bounds nothing: there the rounding of r,
                # ~10⁻⁸ px·px with coordinates ≲ 10⁴ px, divided by a could pass the widening)
                if a > 1e-3:
                    ua = max(ua, -r / a - 1.0)
                elif a < -1e-3:
                    ub = min(ub, -r / a + 1.0)
            if not ua <= ub:
                continue
            for u in range(int(math.ceil(ua)), int(math.floor(ub)) + 1):
                inside = True
                for k in range(3):
                    j = (k + 1) % 3
                    a = -(py[j] - py[k]) * sgn
                    b = (px[j] - px[k]) * sgn
                    c = -(a * px[k] + b * py[k])
                    # the square's farthest corner along (a, b) is inside the half-plane?
                    if a * u + b * v + c + 0.5 * (abs(a) + abs(b)) < 0.0:
                        inside = False
                        break
                if inside and z_near < 0.999 * depth[v, u]:
                    out[v, u] = True


@jit
def _edge_top(xa, ha, xb, hb, lo, hi):
    """Highest point over [lo, hi] of the segment from (xa, ha) to (xb, hb) (x along an axis,
    h the height), −inf where they do not overlap."""
    x0 = min(xa, xb)
    x1 = max(xa, xb)
    l0 = max(lo, x0)
    l1 = min(hi, x1)
    if l0 > l1:
        return -np.inf
    if x1 - x0 <= 0.0:
        return max(ha, hb)
    f0 = (l0 - xa) / (xb - xa)
    f1 = (l1 - xa) / (xb - xa)
    return max(ha + f0 * (hb - ha), ha + f1 * (hb - ha))


@jit
def shadow_map_of_slivers(V, F, e1, e2, s, a0, b0, cell, max_width, grid):
    """Conservative shadow map of the triangles that are slivers seen from the Sun: in the
    Sun's view (orthographic along the unit vector ``s`` towards the Sun, axes ``e1``, ``e2``,
    cells of ``cell`` metres from (a0, b0)), every triangle narrower than ``max_width`` metres
    (twice its projected area over its longest projected edge) writes into every cell its
    projection overlaps (separating axes) its greatest height towards the Sun, x·s, over the
    cell (along the sliver's long axis, the top of its three edges over the cell's extent),
    keeping the largest: a rod or wire whose shadow is thinner than a pixel, which neither
    pixel centres nor pixel corners may land in. Serial (a running maximum)."""
    ny, nx = grid.shape
    pa = np.empty(3)
    pb = np.empty(3)
    ph = np.empty(3)
    px = np.empty(3)
    for f in range(F.shape[0]):
        for k in range(3):
            i = F[f, k]
            pa[k] = (e1[0] * V[i, 0] + e1[1] * V[i, 1] + e1[2] * V[i, 2] - a0) / cell
            pb[k] = (e2[0] * V[i, 0] + e2[1] * V[i, 1] + e2[2] * V[i, 2] - b0) / cell
            ph[k] = s[0] * V[i, 0] + s[1] * V[i, 1] + s[2] * V[i, 2]
        cross = (pa[1] - pa[0]) * (pb[2] - pb[0]) - (pa[2] - pa[0]) * (pb[1] - pb[0])
        longest = 0.0
        kl = 0
        for k in range(3):
            j = (k + 1) % 3
            ln = math.hypot(pa[j] - pa[k], pb[j] - pb[k])
            if ln > longest:
                longest = ln
                kl = k
        if abs(cross) >= max_width / cell * longest:
            continue
        # the sliver's long axis and each vertex's coordinate along it
        jl = (kl + 1) % 3
        ax = 1.0
        ay = 0.0
        if longest > 0.0:
            ax = (pa[jl] - pa[kl]) / longest
            ay = (pb[jl] - pb[kl]) / longest
        for k in range(3):
            px[k] = pa[k] * ax + pb[k] * ay
        reach = 0.5 * (abs(ax) + abs(ay))  # half a cell's extent along the axis
        # cell (i, j) spans [j, j + 1] × [i, i + 1] in cell units; row by row, the cells
        # between the extremes of the triangle's part within the row (a convex polygon whose
        # x-extent is that of its edges clipped to the row)
        v0 = max(math.floor(min(pb[0], pb[1], pb[2])), 0)
        v1 = min(math.floor(max(pb[0], pb[1], pb[2])), ny - 1)
        for v in range(v0, v1 + 1):
            xlo = np.inf
            xhi = -np.inf
            for k in range(3):
                j = (k + 1) % 3
                ya, yb = pb[k], pb[j]
                t0, t1 = 0.0, 1.0
                if yb != ya:
                    ta = (v - ya) / (yb - ya)
                    tb = (v + 1.0 - ya) / (yb - ya)
                    t0 = max(t0, min(ta, tb))
                    t1 = min(t1, max(ta, tb))
                elif not (v <= ya <= v + 1.0):
                    continue
                if t0 > t1:
                    continue
                xa = pa[k] + t0 * (pa[j] - pa[k])
                xb = pa[k] + t1 * (pa[j] - pa[k])
                xlo = min(xlo, xa, xb)
                xhi = max(xhi, xa, xb)
            if xlo > xhi:
                continue
            for u in range(max(math.floor(xlo), 0), min(math.floor(xhi), nx - 1) + 1):
                xc = (u + 0.5) * ax + (v + 0.5) * ay
                top = -np.inf
                for k in range(3):
                    j = (k + 1) % 3
                    top = max(top, _edge_top(px[k], ph[k], px[j], ph[j], xc - reach, xc + reach))
                grid[v, u] = max(grid[v, u], top)


@pjit
def near_shadow_slivers(P, NS, WO, lit, foot, e1, e2, s, a0, b0, cell, grid, out):
    """Lit points (``lit``) whose pixel footprint, seen from the Sun, comes within reach of a
    sliver of :func:`shadow_map_of_slivers` that stands towards the Sun: the pixel may hold a
    thin shadow that its centre and corners missed. The footprint (``foot`` metres per pixel at
    the point, stretched by 1/|n·v| on the surface) spans a disc of radius ρ in the Sun's view;
    the surface itself rises towards the Sun by at most (ρ√2 + cell)·tanθ_s over the cells
    looked at (θ_s the Sun's incidence), so only a sliver higher than that by 5 % of ρ
    counts."""
    ny, nx = grid.shape
    for k in numba.prange(P.shape[0]):
        out[k] = False
        if not lit[k]:
            continue
        cs = NS[k, 0] * s[0] + NS[k, 1] * s[1] + NS[k, 2] * s[2]
        cv = abs(NS[k, 0] * WO[k, 0] + NS[k, 1] * WO[k, 1] + NS[k, 2] * WO[k, 2])
        if cs <= 0.05:
            continue  # grazing Sun: too little light for a thin shadow to matter
        rho = 0.75 * foot[k] / max(cv, 0.1)
        # the cells looked at reach ρ√2 from the point, and a cell's top is taken over its
        # width: the point's own plane may rise by (ρ√2 + cell)·tanθ_s over them
        h = (s[0] * P[k, 0] + s[1] * P[k, 1] + s[2] * P[k, 2]
             + (1.4143 * rho + cell) * math.sqrt(1.0 - cs * cs) / cs + 0.05 * rho)
        a = (e1[0] * P[k, 0] + e1[1] * P[k, 1] + e1[2] * P[k, 2] - a0) / cell
        b = (e2[0] * P[k, 0] + e2[1] * P[k, 1] + e2[2] * P[k, 2] - b0) / cell
        r = rho / cell
        u0 = max(math.floor(a - r), 0)
        u1 = min(math.floor(a + r), nx - 1)
        v0 = max(math.floor(b - r), 0)
        v1 = min(math.floor(b + r), ny - 1)
        hit = False
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if grid[v, u] > h:
                    hit = True
                    break
            if hit:
                break
        out[k] = hit


@pjit
def subpixel_rays(pix, W, n_grid, seed, R_body_from_cam, fx, fy, cx, cy, lens, table, out_d):
    """n_grid² sub-pixel ray directions (body frame, z_cam = 1) per edge pixel, correlated
    multi-jittered (Kensler 2013, "Correlated Multi-Jittered Sampling", Pixar TM 13-01): one
    point in each cell of the n_grid × n_grid grid over the pixel *and* one in each of the
    n_grid² columns and n_grid² rows of the fine grid (n-rooks), the fine offsets permuted per
    pixel from a hash of (seed, pixel), jittered within the fine cell. Unbiased for any
    content, like plain jittered stratification, but a near-horizontal or near-vertical edge
    or shadow stripe is sampled at n_grid² distinct offsets, not n_grid."""
    S = n_grid * n_grid
    for k in numba.prange(pix.shape[0]):
        v = pix[k] // W
        u = pix[k] % W
        perm_a, perm_b = _cmj_perms(n_grid, n_grid, pix[k] & 0x7FFFFFFF, 2 * seed + 13)
        for j in range(S):
            key = (pix[k] * S + j) & 0x7FFFFFFF
            fu, fv = _cmj_point(j, n_grid, n_grid, perm_b, perm_a, _hash01(key, 2 * seed + 11),
                                _hash01(key, 2 * seed + 12))
            du = fu - 0.5
            dv = fv - 0.5
            x, y = ray_xy(lens, table, (u + du - cx) / fx, (v + dv - cy) / fy)
            m = k * S + j
            for a in range(3):
                out_d[m, a] = R_body_from_cam[a, 0] * x + R_body_from_cam[a, 1] * y + R_body_from_cam[a, 2]


@pjit_exact
def ray_groups(geom, prim, face_offset, component_of_face, out):
    """The group of each ray's hit for coverage counting: its part + 1, or 0 on a miss."""
    for k in numba.prange(geom.shape[0]):
        g = geom[k]
        out[k] = 0 if g < 0 else component_of_face[face_offset[g] + prim[k]] + 1


@inline
def _slot(groups, n, g):
    """Index of g among groups[:n], −1 if absent."""
    for k in range(n):
        if groups[k] == g:
            return k
    return -1


@inline
def _slot_or_new(groups, n, g):
    """(index of g among groups[:n], appended as groups[n] if absent; the new n)."""
    k = _slot(groups, n, g)
    if k >= 0:
        return k, n
    groups[n] = g
    return n, n + 1


@jit_exact
def coverage_unshaded_first(g_s, g_c, out):
    """out[i, j]: coverage ray j of pixel i is the first of that pixel's coverage rays to see
    a group (part, or space) that none of its shaded sub-samples saw (g_s (n, S), g_c (n, C):
    groups, :func:`ray_groups`)."""
    n, S = g_s.shape
    C = g_c.shape[1]
    groups = np.empty(S + C, np.int64)
    for i in range(n):
        d = 0
        for a in range(S):
            _k, d = _slot_or_new(groups, d, g_s[i, a])
        for b in range(C):
            _k, d_new = _slot_or_new(groups, d, g_c[i, b])
            out[i, b] = d_new > d
            d = d_new


@jit_exact
def coverage_combine(g_s, L_s, g_c, shaded_c, L_c, out):
    """Radiance of anti-aliased pixels from their shaded sub-samples and coverage rays
    (multisample anti-aliasing): each group (part, or space) seen in pixel i weighs the mean
    radiance of its shaded rays — the S sub-samples (groups g_s (n, S), radiance L_s (n, S, 3))
    and the coverage rays flagged in shaded_c (n, C) (radiance L_c (n, C, 3)) — by the
    fraction of all S + C rays that saw it (g_c (n, C) the coverage rays' groups). Every
    group seen must have a shaded ray (:func:`coverage_unshaded_first`). out (n, 3)."""
    n, S = g_s.shape
    C = g_c.shape[1]
    inv = 1.0 / (S + C)
    groups = np.empty(S + C, np.int64)
    cnt = np.zeros(S + C)
    nsh = np.zeros(S + C)
    tot = np.zeros((S + C, 3))
    for i in range(n):
        d = 0
        for a in range(S):
            k, d = _slot_or_new(groups, d, g_s[i, a])
            cnt[k] += 1.0
            nsh[k] += 1.0
            for c in range(3):
                tot[k, c] += L_s[i, a, c]
        for b in range(C):
            k, d = _slot_or_new(groups, d, g_c[i, b])
            cnt[k] += 1.0
            if shaded_c[i, b]:
                nsh[k] += 1.0
                for c in range(3):
                    tot[k, c] += L_c[i, b, c]
        r0 = 0.0
        r1 = 0.0
        r2 = 0.0
        for k in range(d):
            w = cnt[k] * inv / max(nsh[k], 1.0)
            r0 += w * tot[k, 0]
            r1 += w * tot[k, 1]
            r2 += w * tot[k, 2]
            cnt[k] = 0.0
            nsh[k] = 0.0
            tot[k, 0] = 0.0
            tot[k, 1] = 0.0
            tot[k, 2] = 0.0
        out[i, 0] = r0
        out[i, 1] = r1
        out[i, 2] = r2
