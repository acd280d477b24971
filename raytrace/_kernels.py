"""Numba kernels of the geometry pass: ray generation, hit refinement, shading normals.

The per-pixel kernels are compiled **without fastmath**: a pixel's result must not depend on
where it sits in the cast rectangle (vector body vs scalar remainder), so that a culled
render equals a full-frame render bit for bit. :func:`cast_and_refine` casts the rays itself
(Embree 4 called from numba, :mod:`raytrace._embree`) on numba's threads; where the embreex
wheel has no Embree 4, :func:`make_rays` and :func:`refine_hits`, serial and releasing the
GIL, run on row chunks in a thread pool around ``embreex``'s call.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._embree import intersect1, ray_buffer
from ._jit import inline, jit_exact, pjit_exact
from ._lens import ray_xy


@jit_exact
def make_rays(o_body, R_body_from_cam, fx, fy, cx, cy, lens, table, u0, v0, w, h, z0, out_o, out_d):
    """Fill float32 origins and body-frame directions for the pixel rectangle (row-major).

    Direction = R_body_from_cam · (x, y, 1), (x, y) = ((u − c_x)/f_x, (v − c_y)/f_y) undistorted
    (:func:`raytrace._lens.ray_xy`, ``lens``/``table`` of
    :meth:`raytrace.camera.Camera.lens_arrays`): unnormalised, so the
    ray parameter is the camera z-depth. Each origin is advanced to the plane z_cam = z0
    (just in front of the target): Embree then works in target-sized float32 coordinates,
    not camera-distance ones, and its hit parameter is z-depth − z0.
    """
    for r in range(h):
        yd = (v0 + r - cy) / fy
        for c in range(w):
            x, y = ray_xy(lens, table, (u0 + c - cx) / fx, yd)
            k = r * w + c
            for a in range(3):
                d = R_body_from_cam[a, 0] * x + R_body_from_cam[a, 1] * y + R_body_from_cam[a, 2]
                out_d[k, a] = d
                out_o[k, a] = o_body[a] + z0 * d


@pjit_exact
def centre_rays(pix, W, o_body, R_body_from_cam, fx, fy, cx, cy, lens, table, out_o, out_d):
    """Float64 rays through the centres of the flat pixel indices ``pix`` (row-major, width
    W): origins o_body and body-frame directions R_body_from_cam · (x, y, 1), undistorted
    and unnormalised as in :func:`make_rays`. The same arithmetic, in the same
    order, as the NumPy it replaced in ``shade.render`` (so the same bits), in one pass
    without temporaries (4–7 ms a frame in NumPy for 0.2–0.4 M target pixels)."""
    for k in numba.prange(pix.shape[0]):
        q = pix[k]
        x, y = ray_xy(lens, table, (float(q % W) - cx) / fx, (float(q // W) - cy) / fy)
        for a in range(3):
            out_d[k, a] = (x * R_body_from_cam[a, 0] + y * R_body_from_cam[a, 1]) + R_body_from_cam[a, 2]
            out_o[k, a] = o_body[a]


@pjit_exact
def ray_origins32(o_body, z0, D, out_o, out_d):
    """Float32 rays for Embree from float64 directions D: origins advanced to the plane
    z_cam = z0 (as :func:`make_rays`), directions rounded once; one pass instead of NumPy's
    three (o + z0·D in float64, then two casts)."""
    for k in numba.prange(D.shape[0]):
        for a in range(3):
            d = D[k, a]
            out_d[k, a] = d
            out_o[k, a] = o_body[a] + z0 * d


@inline
def moller_trumbore(ox, oy, oz, dx, dy, dz, V, F, f):
    """Float64 Möller–Trumbore of the ray o + t·d with triangle f: (t, b1, b2, ok); ok is
    False when the ray lies in the triangle's plane (|det| ≤ 1e-12·|e1||e2||d|)."""
    i0 = F[f, 0]
    i1 = F[f, 1]
    i2 = F[f, 2]
    e1x = V[i1, 0] - V[i0, 0]
    e1y = V[i1, 1] - V[i0, 1]
    e1z = V[i1, 2] - V[i0, 2]
    e2x = V[i2, 0] - V[i0, 0]
    e2y = V[i2, 1] - V[i0, 1]
    e2z = V[i2, 2] - V[i0, 2]
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    scale = math.sqrt((e1x * e1x + e1y * e1y + e1z * e1z) * (e2x * e2x + e2y * e2y + e2z * e2z)) * \
        math.sqrt(dx * dx + dy * dy + dz * dz)
    if not abs(det) > 1e-12 * scale:
        return -1.0, 1.0 / 3.0, 1.0 / 3.0, False
    sx = ox - V[i0, 0]
    sy = oy - V[i0, 1]
    sz = oz - V[i0, 2]
    inv = 1.0 / det
    b1 = (sx * px + sy * py + sz * pz) * inv
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    b2 = (dx * qx + dy * qy + dz * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t, b1, b2, True


@jit_exact
def refine_hits(o_body, R_body_from_cam, R_cam_from_body, fx, fy, cx, cy, lens, table, u0, v0, w, h, z0,
                geom_id, prim_id, tfar, V, F, face_offset, face_normal, corner_normal,
                depth, ray_dist, n_shade, n_geom, inst, face_idx, want_dist, want_geom):
    """Turn Embree hits into exact float64 AOVs written into full-size images.

    For each hit the ray is re-intersected in float64 (Möller–Trumbore) with the triangle
    Embree reported, giving the z-depth, barycentrics, the interpolated shading normal and
    the geometric normal, both turned to face the camera and rotated into the camera frame
    (:func:`refine_hit`).
    """
    for r in range(h):
        v = v0 + r
        yd = (v - cy) / fy
        for c in range(w):
            k = r * w + c
            g = geom_id[k]
            if g < 0:
                continue
            u = u0 + c
            x, y = ray_xy(lens, table, (u - cx) / fx, yd)
            dx = R_body_from_cam[0, 0] * x + R_body_from_cam[0, 1] * y + R_body_from_cam[0, 2]
            dy = R_body_from_cam[1, 0] * x + R_body_from_cam[1, 1] * y + R_body_from_cam[1, 2]
            dz = R_body_from_cam[2, 0] * x + R_body_from_cam[2, 1] * y + R_body_from_cam[2, 2]
            refine_hit(o_body, R_cam_from_body, x, y, dx, dy, dz, u, v, z0, g, prim_id[k], tfar[k], V, F,
                       face_offset, face_normal, corner_normal, depth, ray_dist, n_shade, n_geom, inst, face_idx,
                       want_dist, want_geom)


@pjit_exact
def cast_and_refine(scene, o_body, R_body_from_cam, R_cam_from_body, fx, fy, cx, cy, lens, table, u0, v0, w, h, z0, V, F,
                    face_offset, face_normal, corner_normal, depth, ray_dist, n_shade, n_geom, inst, face_idx,
                    want_dist, want_geom, cast):
    """:func:`make_rays`, Embree's closest hit (:func:`raytrace._embree.intersect1`, the same
    float32 rays) and :func:`refine_hits` for the pixel rectangle in one pass, row by row on
    numba's threads: no ray or hit arrays, no round of Python per chunk. The same AOVs, bit
    for bit (Embree's hits are those of ``embreex``, ``tests/raytrace/test_fused_gather.py``;
    the AOVs, ``tests/raytrace/test_scene.py``). ``cast`` (h, w) uint8, if not empty: only
    the pixels where it is non-zero are cast (the others cannot hit, :func:`cull_mask`)."""
    masked = cast.shape[0] > 0
    for r in numba.prange(h):
        buf = ray_buffer()
        v = v0 + r
        yd = (v - cy) / fy
        for c in range(w):
            if masked and cast[r, c] == 0:
                continue
            u = u0 + c
            x, y = ray_xy(lens, table, (u - cx) / fx, yd)
            if math.isnan(x):  # no ray lands there (beyond the distortion's invertible region)
                continue
            dx = R_body_from_cam[0, 0] * x + R_body_from_cam[0, 1] * y + R_body_from_cam[0, 2]
            dy = R_body_from_cam[1, 0] * x + R_body_from_cam[1, 1] * y + R_body_from_cam[1, 2]
            dz = R_body_from_cam[2, 0] * x + R_body_from_cam[2, 1] * y + R_body_from_cam[2, 2]
            g, pr, _, _, tf = intersect1(scene, buf, o_body[0] + z0 * dx, o_body[1] + z0 * dy, o_body[2] + z0 * dz,
                                         dx, dy, dz)
            if g < 0:
                continue
            refine_hit(o_body, R_cam_from_body, x, y, dx, dy, dz, u, v, z0, g, pr, tf, V, F, face_offset,
                       face_normal, corner_normal, depth, ray_dist, n_shade, n_geom, inst, face_idx, want_dist,
                       want_geom)


@inline
def _cross(xs, ys, o, a, b):
    """z of (a − o) × (b − o) for points o, a, b of (xs, ys): > 0 where o → a → b turns left."""
    return (xs[a] - xs[o]) * (ys[b] - ys[o]) - (ys[a] - ys[o]) * (xs[b] - xs[o])


@inline
def _xy_order(xs, ys):
    """The indices that sort the points (xs, ys) by x, then y, then index: what a stable sort
    by y followed by a stable sort by x gives (``np.argsort(kind="mergesort")`` twice), by a
    bottom-up merge sort of its own. numba's argsort compiles a generic merge sort, uncached,
    in every process that compiles a caller: with this one :func:`cull_mask` compiles in ~1 s
    less on one core (2.2 → 1.3 s). The points are finite (vertices in front of the camera)."""
    n = xs.shape[0]
    a = np.empty(n, np.int64)
    for i in range(n):
        a[i] = i
    b = np.empty(n, np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i = lo
            j = mid
            k = lo
            while i < mid and j < hi:
                # the right run's point first only if it sorts strictly before: stable
                if xs[a[j]] < xs[a[i]] or (xs[a[j]] == xs[a[i]] and ys[a[j]] < ys[a[i]]):
                    b[k] = a[j]
                    j += 1
                else:
                    b[k] = a[i]
                    i += 1
                k += 1
            while i < mid:
                b[k] = a[i]
                i += 1
                k += 1
            while j < hi:
                b[k] = a[j]
                j += 1
                k += 1
        a, b = b, a
        width *= 2
    return a


@jit_exact
def cull_mask(P_cam, ptr, fx, fy, cx, cy, u0, v0, w, h, z_min, cast):
    """The pixels of the rectangle (u0, v0, w, h) whose rays may hit a part: ``cast[r, c]`` = 1
    where pixel (u0 + c, v0 + r) lies, with a pixel's margin around, in the image of one of
    the convex polytopes whose vertices (camera frame) are rows ``ptr[g]:ptr[g + 1]`` of
    ``P_cam``, one per group of parts (:attr:`raytrace.scene.Scene.part_hulls`); else 0.

    The image of a convex polytope in front of the camera is the convex polygon of its
    vertices' images (Andrew's monotone chain here), and a pixel's ray (through its centre
    (u, v), :func:`make_rays`) can meet a triangle only where the triangle's image, inside
    its part's polygon, covers (u, v). Each row's span is the polygon's chord at y = v, widened
    by the endpoints of the edges that end within a row of it and by a pixel either side (so
    a marked pixel centre lies within √2 px of the polygon):
    Embree's float32 hits lie within ~1e-5 px of the float64 projection, so the margin keeps
    every hit (a culled frame equals the full frame bit for bit, tests/raytrace/test_scene.py).
    A polytope with a vertex at ``z ≤ z_min`` (at or behind the camera) marks every pixel."""
    for r in range(h):
        for c in range(w):
            cast[r, c] = 0
    lo = np.empty(h)
    hi = np.empty(h)
    for g in range(ptr.shape[0] - 1):
        a = ptr[g]
        n = ptr[g + 1] - a
        if n == 0:
            continue
        xs = np.empty(n)
        ys = np.empty(n)
        for i in range(n):
            z = P_cam[a + i, 2]
            if not z > z_min:
                for r in range(h):
                    for c in range(w):
                        cast[r, c] = 1
                return
            xs[i] = fx * P_cam[a + i, 0] / z + cx
            ys[i] = fy * P_cam[a + i, 1] / z + cy
        # lexicographic order (x, then y), then the lower and upper chains
        order = _xy_order(xs, ys)
        hull = np.empty(2 * n + 1, np.int64)
        k = 0
        for j in range(n):  # lower chain
            i = order[j]
            while k >= 2 and _cross(xs, ys, hull[k - 2], hull[k - 1], i) <= 0.0:
                k -= 1
            hull[k] = i
            k += 1
        start = k + 1
        for j in range(n - 2, -1, -1):  # upper chain
            i = order[j]
            while k >= start and _cross(xs, ys, hull[k - 2], hull[k - 1], i) <= 0.0:
                k -= 1
            hull[k] = i
            k += 1
        k -= 1  # the last point is the first
        k = max(k, 1)
        for r in range(h):
            lo[r] = np.inf
            hi[r] = -np.inf
        for j in range(k):
            xa = xs[hull[j]]
            ya = ys[hull[j]]
            xb = xs[hull[(j + 1) % k]]
            yb = ys[hull[(j + 1) % k]]
            if ya > yb:
                xa, ya, xb, yb = xb, yb, xa, ya
            # rows within one of the edge's y-range (clamped before conversion: a vertex near
            # the camera plane projects far away)
            f0 = math.ceil(ya) - 1.0 - v0
            f1 = math.floor(yb) + 1.0 - v0
            if f1 < 0.0 or f0 > h - 1.0:
                continue
            for r in range(int(max(f0, 0.0)), int(min(f1, h - 1.0)) + 1):
                y = float(v0 + r)
                if y <= ya:
                    x = xa
                elif y >= yb:
                    x = xb
                else:
                    x = xa + (y - ya) * ((xb - xa) / (yb - ya))
                if x < lo[r]:
                    lo[r] = x
                if x > hi[r]:
                    hi[r] = x
        for r in range(h):
            if lo[r] <= hi[r]:
                c0 = min(max(math.ceil(lo[r]) - 1.0 - u0, 0.0), float(w))
                c1 = min(max(math.floor(hi[r]) + 1.0 - u0, -1.0), w - 1.0)
                for c in range(int(c0), int(c1) + 1):
                    cast[r, c] = 1


@inline
def refine_hit(o_body, R_cam_from_body, x, y, dx, dy, dz, u, v, z0, g, pr, tf, V, F, face_offset, face_normal,
               corner_normal, depth, ray_dist, n_shade, n_geom, inst, face_idx, want_dist, want_geom):
    """Pixel (u, v)'s AOVs from Embree's hit (component g, triangle pr, float32 distance tf
    from the plane z_cam = z0) of the ray o_body + t·d, d = (dx, dy, dz) = R_body_from_cam ·
    (x, y, 1): the z-depth and barycentrics re-intersected in float64 (Möller–Trumbore), the
    interpolated shading normal and the geometric normal turned to the camera, in its frame."""
    f = face_offset[g] + pr
    t, b1, b2, ok = moller_trumbore(o_body[0], o_body[1], o_body[2], dx, dy, dz, V, F, f)
    if not ok:  # ray in the triangle's plane: keep Embree's answer
        t = float(tf) + z0
        b1 = 1.0 / 3.0
        b2 = b1
    b0 = 1.0 - b1 - b2
    ngx, ngy, ngz, nsx, nsy, nsz, _ = normals_facing(face_normal, corner_normal, f, b0, b1, b2, dx, dy, dz)
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    facing = (nsx * dx + nsy * dy + nsz * dz) / dn
    if facing > -1e-4:  # interpolated normal grazes or turns away: tilt it to the viewer
        tilt = facing + 1e-4
        nsx -= tilt * dx / dn
        nsy -= tilt * dy / dn
        nsz -= tilt * dz / dn
    ns = math.sqrt(nsx * nsx + nsy * nsy + nsz * nsz)
    if ns > 0.0:
        nsx /= ns
        nsy /= ns
        nsz /= ns
    else:
        nsx, nsy, nsz = ngx, ngy, ngz
    depth[v, u] = t
    if want_dist:
        ray_dist[v, u] = t * math.sqrt(x * x + y * y + 1.0)
    for a in range(3):
        n_shade[v, u, a] = R_cam_from_body[a, 0] * nsx + R_cam_from_body[a, 1] * nsy + R_cam_from_body[a, 2] * nsz
    if want_geom:
        for a in range(3):
            n_geom[v, u, a] = R_cam_from_body[a, 0] * ngx + R_cam_from_body[a, 1] * ngy + R_cam_from_body[a, 2] * ngz
    inst[v, u] = g + 1
    face_idx[v, u] = f


@inline
def normals_facing(face_normal, corner_normal, f, b0, b1, b2, dx, dy, dz):
    """Triangle f's geometric normal and its shading normal interpolated at barycentrics
    (b0, b1, b2), both turned against the ray direction d: (ng, ns, side), side 1 where the
    ray sees the triangle's back, else 0."""
    ngx = face_normal[f, 0]
    ngy = face_normal[f, 1]
    ngz = face_normal[f, 2]
    nsx = b0 * corner_normal[f, 0, 0] + b1 * corner_normal[f, 1, 0] + b2 * corner_normal[f, 2, 0]
    nsy = b0 * corner_normal[f, 0, 1] + b1 * corner_normal[f, 1, 1] + b2 * corner_normal[f, 2, 1]
    nsz = b0 * corner_normal[f, 0, 2] + b1 * corner_normal[f, 1, 2] + b2 * corner_normal[f, 2, 2]
    side = 0
    if ngx * dx + ngy * dy + ngz * dz > 0.0:  # back face seen: turn both towards the ray's origin
        side = 1
        ngx, ngy, ngz = -ngx, -ngy, -ngz
        nsx, nsy, nsz = -nsx, -nsy, -nsz
    return ngx, ngy, ngz, nsx, nsy, nsz, side


@jit_exact
def corner_normals(V, F, face_normal, face_angle, vert_faces_ptr, vert_faces, weld, cos_crease):
    """Shading normal at each face corner: angle-weighted mean of the normals of the faces
    around the (welded) vertex whose normal is within the crease angle of this face's
    (``cos_crease[f]``: cosine of the crease angle of face f's component)."""
    nf = F.shape[0]
    out = np.zeros((nf, 3, 3))
    for f in range(nf):
        for k in range(3):
            wv = weld[F[f, k]]
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for j in range(vert_faces_ptr[wv], vert_faces_ptr[wv + 1]):
                g = vert_faces[j] // 3
                kg = vert_faces[j] % 3
                dot = face_normal[f, 0] * face_normal[g, 0] + face_normal[f, 1] * face_normal[g, 1] + \
                    face_normal[f, 2] * face_normal[g, 2]
                if dot >= cos_crease[f]:
                    a = face_angle[g, kg]
                    sx += a * face_normal[g, 0]
                    sy += a * face_normal[g, 1]
                    sz += a * face_normal[g, 2]
            n = math.sqrt(sx * sx + sy * sy + sz * sz)
            if n > 0.0:
                out[f, k, 0] = sx / n
                out[f, k, 1] = sy / n
                out[f, k, 2] = sz / n
            else:
                out[f, k, 0] = face_normal[f, 0]
                out[f, k, 1] = face_normal[f, 1]
                out[f, k, 2] = face_normal[f, 2]
    return out


def rows_times_matrix(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """X @ M for rows X (n, 3) and a 3 × 3 M, elementwise instead of through BLAS: a threaded
    OpenBLAS product leaves its worker spinning for a while, and on 2 cores that halved the
    speed of the next parallel kernel (Earth's background on ICESat ``earth``: 13 ms alone,
    26 ms after the product); the result is also the same on every CPU."""
    return np.ascontiguousarray(X[:, 0:1] * M[0] + X[:, 1:2] * M[1] + X[:, 2:3] * M[2])
