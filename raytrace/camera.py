"""Pinhole camera with optional Brown–Conrady lens distortion (docs/conventions.md, "Camera
model"): intrinsics, pixel centres, OpenCV axes.

Camera frame: x right, y down, z forward (boresight). Integer pixel coordinates (u = column,
v = row) are pixel centres; a centred principal point is c = ((W − 1)/2, (H − 1)/2).
A primary ray through pixel (u, v) has the camera-frame direction ``d_cam = (x, y, 1)`` —
unnormalised, so the ray parameter at a hit *is* the z-depth — where (x, y) is the
undistorted normalised point whose distortion lands on the pixel: without distortion
(x, y) = ((u − c_x)/f_x, (v − c_y)/f_y).

Distortion is OpenCV's model with coefficients (k1, k2, p1, p2, k3)
(https://docs.opencv.org/4.x/d9/d0c/group__calib3d.html, "Detailed Description"):
r² = x² + y², x_d = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
y_d = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y, u = f_x x_d + c_x,
v = f_y y_d + c_y. :meth:`Camera.undistort` inverts it by Newton's method.

The default camera (1280×960, 3.45 µm pixels, 4.0 mm focal length: f_x = 1159.4 px,
field of view 57.8° × 45.0°) keeps a target's bounding sphere inside the frame at the near
edge of the range band of :func:`orbit.sampling.range_band` (2.5 bounding radii, a 43.6°
cone) and still ~150 px wide at the far edge (15 bounding radii).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_FOCAL_LENGTH_M", "DEFAULT_HEIGHT", "DEFAULT_PIXEL_PITCH_M", "DEFAULT_WIDTH", "Camera",
           "distort_normalised", "undistort_normalised"]

DEFAULT_WIDTH = 1280
DEFAULT_HEIGHT = 960
DEFAULT_FOCAL_LENGTH_M = 4.0e-3
DEFAULT_PIXEL_PITCH_M = 3.45e-6
_MAX_SIDE = 65535
# |f_x|, |f_y|, |c_x|, |c_y| at most 10⁹ px: a 65535-px image then still spans 13 arcsec, and
# pixel coordinates stay far from where float64 ray directions lose their digits
_MAX_PX = 1e9


# Newton's method for the undistortion stops when a step is below this [normalised units] and
# fails (NaN) where the distortion's residual is still above _UNDISTORT_TOL after _NEWTON_ITERS
_NEWTON_STEP = 1e-15
_NEWTON_ITERS = 50
_UNDISTORT_TOL = 1e-12
# pixels of the cached undistortion table beyond each side of the image (sub-pixel samples of
# the outer pixels, culling margins)
TABLE_BORDER = 2
_NO_LENS = np.empty(0)
_NO_TABLE = np.empty((0, 0, 2))
_NO_LENS.flags.writeable = False
_NO_TABLE.flags.writeable = False
_TABLES: dict = {}  # Camera → (lens, table), rebuilt in each process (never pickled)
_MAX_TABLES = 4


def distort_normalised(x, y, dist_coeffs):
    """OpenCV's Brown–Conrady distortion of normalised points (x, y) → (x_d, y_d).

    r² = x² + y², x_d = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
    y_d = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y, coefficients in OpenCV's
    order (k1, k2, p1, p2, k3) (https://docs.opencv.org/4.x/d9/d0c/group__calib3d.html).
    """
    k1, k2, p1, p2, k3 = dist_coeffs
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r2 = x * x + y * y
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def undistort_normalised(xd, yd, dist_coeffs):
    """The normalised points (x, y) whose distortion (:func:`distort_normalised`) is (x_d, y_d).

    Newton's method on the 2 × 2 system from x = x_d (the Jacobian of the distortion in closed
    form), until a step is below 1e-15 (at most 50 steps): on a monotonic radial distortion the
    iterates approach the root from one side after the first step and then converge
    quadratically (4–6 steps at |k1| ≈ 0.2 over a 58° field). The achieved residual
    |distort(x, y) − (x_d, y_d)| is ≤ 1e-15 in normalised units over the image of every
    camera :class:`Camera` accepts (a few float64 ulps; ``tests/raytrace/test_distortion.py``
    asserts < 1e-12). Points where the residual stays above 1e-12 (beyond the invertible
    region) come back NaN.

    Returns
    -------
    x, y : ndarray, float64
    """
    k1, k2, p1, p2, k3 = dist_coeffs
    xd = np.asarray(xd, dtype=np.float64)
    yd = np.asarray(yd, dtype=np.float64)
    x = xd.copy()
    y = yd.copy()
    with np.errstate(all="ignore"):
        for _ in range(_NEWTON_ITERS):
            r2 = x * x + y * y
            rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d rad / d r²
            ex = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            ey = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
            b = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
            d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            sx = (d * ex - b * ey) / det
            sy = (a * ey - b * ex) / det
            x = x - sx
            y = y - sy
            step = np.maximum(np.abs(sx), np.abs(sy))
            if not np.any(step > _NEWTON_STEP):  # (NaN steps stop nothing: they fail below)
                break
        ex, ey = distort_normalised(x, y, dist_coeffs)
        bad = ~(np.maximum(np.abs(ex - xd), np.abs(ey - yd)) <= _UNDISTORT_TOL)
    x[bad] = np.nan
    y[bad] = np.nan
    return x, y


def radial_limit(dist_coeffs) -> float:
    """The undistorted normalised radius where the radial distortion r(1 + k1 r² + k2 r⁴ + k3 r⁶)
    stops increasing (the first positive root of 1 + 3k1 r² + 5k2 r⁴ + 7k3 r⁶); inf if never."""
    k1, k2, _, _, k3 = dist_coeffs
    if (k1, k2, k3) == (0.0, 0.0, 0.0):
        return math.inf
    roots = np.atleast_1d(np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]))
    s = min((r.real for r in roots if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0), default=math.inf)
    return math.sqrt(s)


def _positive_finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and 0.0 < v <= _MAX_PX):
        raise ValueError(f"{name} must be a number in (0, {_MAX_PX:.0e}] px, got {value!r}")
    return v


@dataclass(frozen=True, slots=True)
class Camera:
    """Pinhole intrinsics and image size.

    Attributes
    ----------
    width, height : int
        Image size [px], 1 … 65535.
    fx, fy : float
        Focal lengths [px].
    cx, cy : float
        Principal point [px] (pixel-centre coordinates; need not lie inside the image).
    dist_coeffs : tuple of 5 float
        Brown–Conrady distortion (k1, k2, p1, p2, k3), OpenCV's order [-]; zeros (default): a
        pinhole. Finite, and the radial distortion r·(1 + k1 r² + k2 r⁴ + k3 r⁶) strictly
        increasing up to the image corners' radius (invertible over the image).
    """

    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    fx: float = DEFAULT_FOCAL_LENGTH_M / DEFAULT_PIXEL_PITCH_M
    fy: float = DEFAULT_FOCAL_LENGTH_M / DEFAULT_PIXEL_PITCH_M
    cx: float = (DEFAULT_WIDTH - 1) / 2.0
    cy: float = (DEFAULT_HEIGHT - 1) / 2.0
    dist_coeffs: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= _MAX_SIDE:
                raise ValueError(f"{name} must be an integer in [1, {_MAX_SIDE}] px, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy"):
            object.__setattr__(self, name, _positive_finite(name, getattr(self, name)))
        for name in ("cx", "cy"):
            v = getattr(self, name)
            try:
                v = float(v)
            except (TypeError, ValueError):
                v = math.nan
            if not (math.isfinite(v) and abs(v) <= _MAX_PX):
                raise ValueError(f"{name} must be a number in [-{_MAX_PX:.0e}, {_MAX_PX:.0e}] px, "
                                 f"got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "dist_coeffs", self._checked_dist_coeffs(self.dist_coeffs))

    def _checked_dist_coeffs(self, value) -> tuple:
        try:
            c = () if isinstance(value, (str, bytes)) else tuple(float(v) for v in value)
        except (TypeError, ValueError):
            c = ()
        if len(c) != 5 or not all(math.isfinite(v) and abs(v) <= _MAX_PX for v in c):
            raise ValueError(f"dist_coeffs must be 5 finite numbers (k1, k2, p1, p2, k3), got {value!r}")
        c = tuple(0.0 if v == 0.0 else v for v in c)  # −0.0 → 0.0: one pinhole, one hash
        if not any(c):
            return c
        k1, k2, _, _, k3 = c
        # the image corners' distorted radius (outer pixel edges), normalised
        r_corner = max(math.hypot(du / self.fx, dv / self.fy)
                       for du in (-0.5 - self.cx, self.width - 0.5 - self.cx)
                       for dv in (-0.5 - self.cy, self.height - 0.5 - self.cy))
        # d/dr r(1 + k1 r² + k2 r⁴ + k3 r⁶) = 1 + 3k1 r² + 5k2 r⁴ + 7k3 r⁶: its first positive
        # root bounds the invertible radius; the radial map must pass the corners' radius first
        r_star = radial_limit(c)
        if math.isfinite(r_star):
            s_star = r_star * r_star
            if not r_star * (1.0 + s_star * (k1 + s_star * (k2 + s_star * k3))) > r_corner:
                raise ValueError(f"dist_coeffs {c!r} fold the image: the radial distortion "
                                 f"r(1 + k1 r² + k2 r⁴ + k3 r⁶) stops increasing at r = {r_star:.4g}, "
                                 f"before the image corners' distorted radius {r_corner:.4g}")
        # and Newton's inverse must converge along the image border and on a grid inside
        # (tangential terms bend the map too)
        uu = np.concatenate([np.linspace(-0.5, self.width - 0.5, 65), np.full(49, -0.5),
                             np.full(49, self.width - 0.5), np.repeat(np.linspace(0, self.width - 1, 17), 17)])
        vv = np.concatenate([np.full(65, -0.5), np.linspace(-0.5, self.height - 0.5, 49),
                             np.linspace(-0.5, self.height - 0.5, 49), np.tile(np.linspace(0, self.height - 1, 17), 17)])
        uu = np.concatenate([uu, uu[:65]])
        vv = np.concatenate([vv, np.full(65, self.height - 0.5)])
        x, _ = undistort_normalised((uu - self.cx) / self.fx, (vv - self.cy) / self.fy, c)
        if np.isnan(x).any():
            raise ValueError(f"dist_coeffs {c!r} are not invertible over the image (Newton's inverse of the "
                             f"distortion diverges inside it)")
        return c

    @property
    def distorted(self) -> bool:
        """True when :attr:`dist_coeffs` is not all zeros."""
        return any(self.dist_coeffs)

    def lens_arrays(self) -> tuple:
        """What the numba kernels take for the lens: ``(lens, table)``. Pinhole: two empty
        arrays. Distorted: ``lens`` = (f_x, f_y, c_x, c_y, k1, k2, p1, p2, k3) and ``table``
        (H + 4, W + 4, 2), the undistorted normalised (x, y) of every pixel centre
        (u, v) = (j − 2, i − 2) at ``table[i, j]`` (a border of :data:`TABLE_BORDER` pixels;
        NaN where not invertible), by the iteration of :func:`undistort_normalised` (compiled:
        :func:`raytrace._lens.undistort_table`): exact at pixel centres; off them the kernels
        run the same Newton iteration from the nearest entry (:mod:`raytrace._lens`). Built
        once per camera and process (~0.16 s at 1280×960 on two cores), kept
        in a module-level cache: a pickled camera carries no table."""
        if not self.distorted:
            return _NO_LENS, _NO_TABLE
        hit = _TABLES.get(self)
        if hit is None:
            from ._lens import undistort_table
            b = TABLE_BORDER
            lens = np.array([self.fx, self.fy, self.cx, self.cy, *self.dist_coeffs])
            table = np.empty((self.height + 2 * b, self.width + 2 * b, 2))
            undistort_table(lens, table)
            table.flags.writeable = False
            lens.flags.writeable = False
            if len(_TABLES) >= _MAX_TABLES:
                _TABLES.pop(next(iter(_TABLES)))
            hit = _TABLES[self] = (lens, table)
        return hit

    def pixel_rect_of_box(self, x0: float, x1: float, y0: float, y1: float) -> tuple:
        """Unclipped pixel rectangle (u0, v0, u1, v1), end exclusive, holding every pixel centre
        whose ray's undistorted normalised (x, y) lies in [x0, x1] × [y0, y1] (a distorted
        camera; the box's points beyond :func:`radial_limit` cast no ray).

        The distortion maps the box (clipped to the invertible disc) onto a region bounded by
        the image of its boundary: the boundary is sampled (256 points a side, pulled radially
        onto the disc where beyond it), distorted, and the samples' bounding box padded by 2 px
        and by the largest gap between neighbouring samples.
        """
        t = np.linspace(0.0, 1.0, 257)
        xs = np.concatenate([x0 + (x1 - x0) * t, np.full(257, x1), x1 - (x1 - x0) * t, np.full(257, x0)])
        ys = np.concatenate([np.full(257, y0), y0 + (y1 - y0) * t, np.full(257, y1), y1 - (y1 - y0) * t])
        r_lim = radial_limit(self.dist_coeffs)
        if math.isfinite(r_lim):
            r = np.hypot(xs, ys)
            f = np.where(r > r_lim, r_lim / np.maximum(r, 1e-300), 1.0)
            xs, ys = xs * f, ys * f
        xd, yd = distort_normalised(xs, ys, self.dist_coeffs)
        u, v = self.fx * xd + self.cx, self.fy * yd + self.cy
        pad = 2.0 + float(np.hypot(np.diff(u), np.diff(v)).max())
        return (math.floor(u.min() - pad), math.floor(v.min() - pad), math.ceil(u.max() + pad) + 1,
                math.ceil(v.max() + pad) + 1)

    def undistort(self, uv) -> np.ndarray:
        """Undistorted normalised coordinates (x, y) of pixel coordinates (u, v): the camera-frame
        ray (x, y, 1) lands on (u, v). The exact inverse of :meth:`project`'s distortion
        (:func:`undistort_normalised`: residual ≤ 1e-15 in normalised units, i.e. ~1e-12 px at
        f ≈ 1000 px); NaN where it has none.

        Parameters
        ----------
        uv : array_like, shape (N, 2)
            Pixel coordinates [px].

        Returns
        -------
        ndarray, shape (N, 2), float64 [-]
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xd = (uv[:, 0] - self.cx) / self.fx
        yd = (uv[:, 1] - self.cy) / self.fy
        if not self.distorted:
            return np.column_stack([xd, yd])
        return np.column_stack(undistort_normalised(xd, yd, self.dist_coeffs))

    @classmethod
    def from_focal(cls, focal_length_m: float = DEFAULT_FOCAL_LENGTH_M,
                   pixel_pitch_m: float = DEFAULT_PIXEL_PITCH_M, width: int = DEFAULT_WIDTH,
                   height: int = DEFAULT_HEIGHT, dist_coeffs=(0.0, 0.0, 0.0, 0.0, 0.0)) -> Camera:
        """Camera from a focal length and a square pixel pitch, principal point centred.

        f_x = f_y = focal_length_m / pixel_pitch_m; c = ((W − 1)/2, (H − 1)/2).
        """
        f = _positive_finite("focal_length_m", focal_length_m)
        p = _positive_finite("pixel_pitch_m", pixel_pitch_m)
        return cls(width=width, height=height, fx=f / p, fy=f / p, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                   dist_coeffs=dist_coeffs)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix [[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]], shape (3, 3) [px]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_deg(self) -> tuple:
        """Full horizontal and vertical field of view through the outer pixel edges [deg] (with
        distortion: along the principal point's row and column)."""
        if self.distorted:
            x = self.undistort([[-0.5, self.cy], [self.width - 0.5, self.cy], [self.cx, -0.5],
                                [self.cx, self.height - 0.5]])
            return (math.degrees(math.atan(-x[0, 0]) + math.atan(x[1, 0])),
                    math.degrees(math.atan(-x[2, 1]) + math.atan(x[3, 1])))
        h = math.degrees(math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx))
        v = math.degrees(math.atan((self.cy + 0.5) / self.fy) + math.atan((self.height - 0.5 - self.cy) / self.fy))
        return h, v

    def ray_directions_cam(self, u0: int = 0, v0: int = 0, u1: int | None = None, v1: int | None = None) -> np.ndarray:
        """Unnormalised camera-frame ray directions for the pixel rectangle [u0, u1) × [v0, v1).

        Returns
        -------
        ndarray, shape ((v1 − v0)·(u1 − u0), 3), float64
            Row-major over the rectangle; z = 1 [-].
        """
        u1 = self.width if u1 is None else u1
        v1 = self.height if v1 is None else v1
        uu, vv = np.meshgrid(np.arange(u0, u1, dtype=np.float64), np.arange(v0, v1, dtype=np.float64))
        if self.distorted:  # the renderer's rays: the cached table's
            b = TABLE_BORDER
            xy = self.lens_arrays()[1][v0 + b:v1 + b, u0 + b:u1 + b].reshape(-1, 2)
            return np.column_stack([xy, np.ones(uu.size)])
        return np.column_stack([((uu - self.cx) / self.fx).ravel(), ((vv - self.cy) / self.fy).ravel(),
                                np.ones(uu.size)])

    def project(self, p_cam) -> np.ndarray:
        """Pixel coordinates (u, v) of camera-frame points: u = f_x·x_d + c_x, v = f_y·y_d + c_y,
        (x_d, y_d) the distortion (:func:`distort_normalised`) of (x/z, y/z); without
        distortion u = f_x·x/z + c_x, v = f_y·y/z + c_y.

        Parameters
        ----------
        p_cam : array_like, shape (N, 3)
            Points in the camera frame [m].

        Returns
        -------
        ndarray, shape (N, 2), float64
            Pixel coordinates (integer values at pixel centres) [px]; NaN for points at or
            behind the optical centre (z ≤ 0).
        """
        p = np.asarray(p_cam, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = p[:, 0] / z, p[:, 1] / z
            if self.distorted:
                x, y = distort_normalised(x, y, self.dist_coeffs)
        uv = np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy])
        uv[~(z > 0)] = np.nan
        return uv
