"""Lens distortion in the numba kernels: the undistorted ray of an image point, the distorted
image point of a ray (OpenCV's Brown–Conrady model, :mod:`raytrace.camera`).

Every kernel that makes camera rays or projects points takes the camera's
:meth:`raytrace.camera.Camera.lens_arrays` ``(lens, table)``; for a pinhole both are empty and
:func:`ray_xy` returns its arguments unchanged, so a pinhole camera's arithmetic is what it
was without distortion, bit for bit. A kernel first computes the *distorted* normalised
coordinates of its image point as a pinhole would, x_d = (u − c_x)/f_x (with whatever shifted
c_x or scaled f_x it works in), then :func:`ray_xy` turns them into the undistorted (x, y)
of the ray: at a pixel centre the camera's cached table (exact, from
:func:`raytrace.camera.undistort_normalised`), elsewhere (sub-pixel samples, pixel corners)
Newton's method from the nearest table entry, 2–3 steps to a step below 1e-15 — the same
answer as the table's to a few ulps, so no interpolation error.
"""

from __future__ import annotations

import math

import numba

from ._jit import inline, jit_exact, pjit_exact

# lens = (f_x, f_y, c_x, c_y, k1, k2, p1, p2, k3): indices
L_FX, L_FY, L_CX, L_CY, L_K1, L_K2, L_P1, L_P2, L_K3 = range(9)
BORDER = 2  # raytrace.camera.TABLE_BORDER
# an image point within this of a pixel centre [px] takes the table's entry as it is
_CENTRE_TOL = 1e-6


@inline
def distort_xy(lens, x, y):
    """(x_d, y_d) of the normalised point (x, y) (``lens`` not empty): r² = x² + y²,
    x_d = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
    y_d = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y
    (https://docs.opencv.org/4.x/d9/d0c/group__calib3d.html)."""
    k1 = lens[L_K1]
    k2 = lens[L_K2]
    p1 = lens[L_P1]
    p2 = lens[L_P2]
    k3 = lens[L_K3]
    r2 = x * x + y * y
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


@jit_exact
def undistort_newton(k1, k2, p1, p2, k3, xd, yd, x, y):
    """Newton's method for the (x, y) whose distortion is (x_d, y_d), from (x, y), as
    :func:`raytrace.camera.undistort_normalised` (the same steps and stopping rule); NaN
    where its residual stays above 1e-12. Scalars only, and not inlined: one compiled copy
    that the kernels call (inlined into each of them it tripled their compile times), with
    no array whose reference count a call would touch."""
    for _ in range(50):
        r2 = x * x + y * y
        rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        ex = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        ey = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        b = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        det = a * d - b * b
        sx = (d * ex - b * ey) / det
        sy = (a * ey - b * ex) / det
        x -= sx
        y -= sy
        if not (abs(sx) > 1e-15 or abs(sy) > 1e-15):
            break
    r2 = x * x + y * y
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ex = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
    ey = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
    if not (abs(ex) <= 1e-12 and abs(ey) <= 1e-12):
        return math.nan, math.nan
    return x, y


@inline
def ray_xy(lens, table, xd, yd):
    """Undistorted normalised (x, y) of the ray through the image point whose pinhole
    coordinates are (x_d, y_d) = ((u − c_x)/f_x, (v − c_y)/f_y); (x_d, y_d) itself for a pinhole
    (``lens`` empty). NaN where the distortion has no inverse (far outside the image)."""
    if lens.shape[0] == 0:
        return xd, yd
    pu = xd * lens[L_FX] + lens[L_CX] + BORDER  # table indices
    pv = yd * lens[L_FY] + lens[L_CY] + BORDER
    x0 = xd
    y0 = yd
    if abs(pu) < 1e15 and abs(pv) < 1e15:
        iu = min(max(math.floor(pu + 0.5), 0.0), table.shape[1] - 1.0)
        iv = min(max(math.floor(pv + 0.5), 0.0), table.shape[0] - 1.0)
        tx = table[int(iv), int(iu), 0]
        ty = table[int(iv), int(iu), 1]
        if not (math.isnan(tx) or math.isnan(ty)):  # (NaN beyond the invertible region)
            if abs(pu - iu) <= _CENTRE_TOL and abs(pv - iv) <= _CENTRE_TOL:
                return tx, ty
            x0 = tx
            y0 = ty
    return undistort_newton(lens[L_K1], lens[L_K2], lens[L_P1], lens[L_P2], lens[L_K3], xd, yd, x0, y0)


@inline
def project_px(lens, fx, fy, cx, cy, xc, yc, zc):
    """Image point (u, v) of the camera-frame point (xc, yc, zc), zc > 0: f_x·x_d + c_x with the
    distortion (x_d, y_d) of (xc/zc, yc/zc); for a pinhole (``lens`` empty) f_x·xc/zc + c_x."""
    if lens.shape[0] == 0:
        return fx * xc / zc + cx, fy * yc / zc + cy
    x_d, y_d = distort_xy(lens, xc / zc, yc / zc)
    return fx * x_d + cx, fy * y_d + cy


@pjit_exact
def undistort_table(lens, out):
    """The undistorted normalised (x, y) of every pixel centre (u, v) = (j − 2, i − 2) into
    ``out[i, j]`` (H + 4, W + 4, 2): :meth:`raytrace.camera.Camera.lens_arrays`'s table."""
    for i in numba.prange(out.shape[0]):
        yd = (i - BORDER - lens[L_CY]) / lens[L_FY]
        for j in range(out.shape[1]):
            xd = (j - BORDER - lens[L_CX]) / lens[L_FX]
            x, y = undistort_newton(lens[L_K1], lens[L_K2], lens[L_P1], lens[L_P2], lens[L_K3], xd, yd, xd, yd)
            out[i, j, 0] = x
            out[i, j, 1] = y
