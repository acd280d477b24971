"""Pinhole camera (docs/conventions.md, "Camera model"): intrinsics, pixel centres, OpenCV axes.

Camera frame: x right, y down, z forward (boresight). Integer pixel coordinates (u = column,
v = row) are pixel centres; a centred principal point is c = ((W − 1)/2, (H − 1)/2).
A primary ray through pixel (u, v) has the camera-frame direction
``d_cam = ((u − c_x)/f_x, (v − c_y)/f_y, 1)`` — unnormalised, so the ray parameter at a hit
*is* the z-depth.

The default camera (1280×960, 3.45 µm pixels, 4.0 mm focal length: f_x = 1159.4 px,
field of view 57.8° × 45.0°) keeps a target's bounding sphere inside the frame at the near
edge of the range band of :func:`orbit.sampling.range_band` (2.5 bounding radii, a 43.6°
cone) and still ~150 px wide at the far edge (15 bounding radii).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_FOCAL_LENGTH_M", "DEFAULT_HEIGHT", "DEFAULT_PIXEL_PITCH_M", "DEFAULT_WIDTH", "Camera"]

DEFAULT_WIDTH = 1280
DEFAULT_HEIGHT = 960
DEFAULT_FOCAL_LENGTH_M = 4.0e-3
DEFAULT_PIXEL_PITCH_M = 3.45e-6
_MAX_SIDE = 65535
# |f_x|, |f_y|, |c_x|, |c_y| at most 10⁹ px: a 65535-px image then still spans 13 arcsec, and
# pixel coordinates stay far from where float64 ray directions lose their digits
_MAX_PX = 1e9


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
    """

    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    fx: float = DEFAULT_FOCAL_LENGTH_M / DEFAULT_PIXEL_PITCH_M
    fy: float = DEFAULT_FOCAL_LENGTH_M / DEFAULT_PIXEL_PITCH_M
    cx: float = (DEFAULT_WIDTH - 1) / 2.0
    cy: float = (DEFAULT_HEIGHT - 1) / 2.0

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

    @classmethod
    def from_focal(cls, focal_length_m: float = DEFAULT_FOCAL_LENGTH_M,
                   pixel_pitch_m: float = DEFAULT_PIXEL_PITCH_M, width: int = DEFAULT_WIDTH,
                   height: int = DEFAULT_HEIGHT) -> Camera:
        """Camera from a focal length and a square pixel pitch, principal point centred.

        f_x = f_y = focal_length_m / pixel_pitch_m; c = ((W − 1)/2, (H − 1)/2).
        """
        f = _positive_finite("focal_length_m", focal_length_m)
        p = _positive_finite("pixel_pitch_m", pixel_pitch_m)
        return cls(width=width, height=height, fx=f / p, fy=f / p, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix [[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]], shape (3, 3) [px]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_deg(self) -> tuple:
        """Full horizontal and vertical field of view through the outer pixel edges [deg]."""
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
        return np.column_stack([((uu - self.cx) / self.fx).ravel(), ((vv - self.cy) / self.fy).ravel(),
                                np.ones(uu.size)])

    def project(self, p_cam) -> np.ndarray:
        """Pixel coordinates (u, v) of camera-frame points: u = f_x·x/z + c_x, v = f_y·y/z + c_y.

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
        uv = np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy])
        uv[~(z > 0)] = np.nan
        return uv
