"""Stars: point sources at infinity behind the target, in the background of the image.

A star is a direction in the inertial frame (ECI: J2000 mean equator and equinox, as in
:mod:`orbit`; ICRS catalogue positions agree with it within 0.02 arcsec) and an irradiance
at the observer. Its light on the target (< 10⁻⁷ W/m²) is neglected; in the image it is a
point, so the box-filtered radiance of the one pixel that holds it is E / Ω_pixel, where
nothing (target or Earth) lies in front of it. The optics' blur comes later, in
:mod:`degrade`. With the default exposures of a sunlit target stars stay below one DN, as
on a real camera; they show in the linear HDR output and in long exposures.

Brightness. A star of visual magnitude V gives E = E_sun · 10^(−0.4 (V − V_sun)) with
V_sun = −26.76 (Willmer 2018, ApJS 236 47, table 3) and E_sun = 1361 W/m²: stars are given
the Sun's spectrum (white in the renderer's RGB), so V = 0 is 2.8 · 10⁻⁸ W/m².

Fields. :meth:`StarField.procedural` draws a sky with the real count of stars per magnitude
(about 4800 brighter than V = 6 and √10 times more per magnitude: 4.8 / 48 / 480 / 4800 at
V < 0 / 2 / 4 / 6, against 4 / 48 / 513 / 4800 in the star counts of Allen's Astrophysical
Quantities, 4th ed., § 20.2), isotropic and reproducible from a seed.
:meth:`StarField.from_csv` reads a catalogue (right ascension, declination, magnitude).
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass

import numpy as np

from ._kernels import rows_times_matrix
from .camera import distort_normalised
from .constants import SOLAR_CONSTANT_W_M2

__all__ = ["MAG_BRIGHTEST", "MAG_FAINTEST", "SUN_V_MAG", "StarField", "irradiance_of_magnitude"]

SUN_V_MAG = -26.76
"""Apparent V magnitude of the Sun at 1 au (Willmer 2018, ApJS 236 47) [mag]."""
MAG_BRIGHTEST = -1.5
"""Brightest star of a procedural sky (Sirius: V = −1.46) [mag]."""
MAG_FAINTEST = 9.0
"""Faintest allowed magnitude limit of a procedural sky (~150 000 stars) [mag]."""
CATALOGUE_LIMIT_BYTES = 1 << 30
"""Largest star catalogue read [bytes] (Hipparcos as CSV is ~10 MB; a device or pipe is refused)."""
_N_AT_6 = 4800.0  # stars brighter than V = 6 over the whole sky


def irradiance_of_magnitude(v_mag) -> np.ndarray:
    """Irradiance at the observer of a Sun-like star of visual magnitude ``v_mag`` [W/m²]."""
    return SOLAR_CONSTANT_W_M2 * 10.0 ** (-0.4 * (np.asarray(v_mag, dtype=np.float64) - SUN_V_MAG))


def _count_brighter(v_mag: float) -> float:
    """Mean number of stars brighter than ``v_mag`` over the whole sky (see module notes)."""
    return _N_AT_6 * 10.0 ** (0.5 * (v_mag - 6.0))


@dataclass(frozen=True, slots=True, eq=False)
class StarField:
    """Stars as unit directions and irradiances.

    Attributes
    ----------
    dirs_eci : ndarray, shape (n, 3)
        Unit vectors towards the stars, inertial frame [-].
    irradiance_W_m2 : ndarray, shape (n,)
        Irradiance of each star at the observer [W/m²].
    source : dict or None
        How the field was made (the ``stars`` section of a scene file, without the attitude),
        or None for a field given star by star.
    """

    dirs_eci: np.ndarray
    irradiance_W_m2: np.ndarray
    source: dict | None = None

    def __post_init__(self):
        d = np.asarray(self.dirs_eci, dtype=np.float64).reshape(-1, 3)
        e = np.asarray(self.irradiance_W_m2, dtype=np.float64).ravel()
        if len(d) != len(e):
            raise ValueError(f"stars: {len(d)} directions but {len(e)} irradiances")
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))) or np.any(e < 0):
            raise ValueError("stars: directions and irradiances must be finite, irradiances >= 0")
        n = np.linalg.norm(d, axis=1)
        if np.any(np.abs(n - 1.0) > 1e-6):
            raise ValueError("stars: directions must be unit vectors")
        object.__setattr__(self, "dirs_eci", np.ascontiguousarray(d))
        object.__setattr__(self, "irradiance_W_m2", np.ascontiguousarray(e))

    def __len__(self) -> int:
        return len(self.irradiance_W_m2)

    @classmethod
    def procedural(cls, limit_mag: float = 6.5, seed: int = 0) -> StarField:
        """An isotropic sky of every star brighter than ``limit_mag`` (in [−1.5, 9]), with the
        real count per magnitude (module notes); the same seed gives the same sky."""
        if isinstance(limit_mag, bool) or not isinstance(limit_mag, (int, float, np.integer, np.floating)) \
                or not MAG_BRIGHTEST <= float(limit_mag) <= MAG_FAINTEST:
            raise ValueError(f"star limit magnitude must be a number in [{MAG_BRIGHTEST:g}, {MAG_FAINTEST:g}], "
                             f"got {limit_mag!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"star seed must be a non-negative integer, got {seed!r}")
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0x57A25,)))
        n0, n1 = _count_brighter(MAG_BRIGHTEST), _count_brighter(float(limit_mag))
        n = int(rng.poisson(n1 - n0))
        # inverse of the cumulative count: N(<V) uniform in [N(<V_brightest), N(<limit)]
        v_mag = 6.0 + 2.0 * np.log10(rng.uniform(n0, n1, n) / _N_AT_6)
        z = rng.uniform(-1.0, 1.0, n)
        phi = rng.uniform(0.0, 2.0 * math.pi, n)
        r = np.sqrt(1.0 - z * z)
        d = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
        return cls(d / np.linalg.norm(d, axis=1, keepdims=True), irradiance_of_magnitude(v_mag),
                   {"limit_mag": float(limit_mag), "seed": int(seed)})

    @classmethod
    def from_csv(cls, path, limit_mag: float = math.inf) -> StarField:
        """A catalogue in CSV with a header naming the columns ``ra_deg``, ``dec_deg`` and
        ``v_mag`` (ICRS / J2000; other columns ignored); stars fainter than ``limit_mag`` are
        dropped."""
        import io

        from .files import read_regular_file
        data = read_regular_file(path, limit_bytes=CATALOGUE_LIMIT_BYTES, what=f"star catalogue {path}")
        try:
            rows = list(csv.DictReader(io.StringIO(data.decode("utf-8"), newline="")))
        except (UnicodeDecodeError, csv.Error) as exc:
            raise ValueError(f"star catalogue {path}: not a CSV text file ({exc})") from None
        need = ("ra_deg", "dec_deg", "v_mag")
        if not rows or any(k not in rows[0] for k in need):
            raise ValueError(f"star catalogue {path}: needs a header with columns {', '.join(need)} and at least "
                             f"one star")
        vals = np.empty((len(rows), 3))
        for i, row in enumerate(rows):
            try:
                vals[i] = [float(row[k]) for k in need]
            except (TypeError, ValueError):
                raise ValueError(f"star catalogue {path}: line {i + 2}: ra_deg, dec_deg and v_mag must be "
                                 f"numbers") from None
        if not np.all(np.isfinite(vals)) or np.any(np.abs(vals[:, 1]) > 90.0):
            raise ValueError(f"star catalogue {path}: values must be finite, dec_deg in [-90, 90]")
        try:
            limit = float(limit_mag)
        except (TypeError, ValueError):
            limit = math.nan
        if math.isnan(limit):
            raise ValueError(f"star limit magnitude must be a number, got {limit_mag!r}")
        vals = vals[vals[:, 2] <= limit]
        ra, dec = np.radians(vals[:, 0]), np.radians(vals[:, 1])
        d = np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
        source = {"catalogue": os.fspath(path)}
        if math.isfinite(limit):
            source["limit_mag"] = limit
        return cls(d, irradiance_of_magnitude(vals[:, 2]), source)


def add_stars(radiance: np.ndarray, stars: StarField, R_body_from_eci, scene, camera, R_cam_from_body, t_cam_m,
              earth=None) -> int:
    """Add the stars in view to ``radiance`` (H, W, 3, linear W/(m²·sr), in place): each star
    lands in the pixel that holds its direction, with E / Ω_pixel, unless the target (one ray
    towards it) or Earth's disc lies in front. Returns the number of stars drawn.

    Ω_pixel = cos³θ / (f_x f_y) is the solid angle of a pixel whose centre is θ off the
    optical axis of a pinhole camera (the image-plane area 1 px² seen at distance f / cos θ,
    tilted by θ); under lens distortion Ω is that of the undistorted image-plane area, the
    pixel's area divided by the distortion's Jacobian determinant."""
    R_body_from_eci = np.asarray(R_body_from_eci, dtype=np.float64).reshape(3, 3)
    R = np.asarray(R_cam_from_body, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t_cam_m, dtype=np.float64).ravel()
    H, W = radiance.shape[:2]
    d_cam = rows_times_matrix(stars.dirs_eci, (R @ R_body_from_eci).T)  # (no BLAS on the hot path)
    front = d_cam[:, 2] > 1e-9
    z = np.where(front, d_cam[:, 2], 1.0)
    if camera.distorted:
        uv = camera.project(d_cam / z[:, None])
        u, v = uv[:, 0], uv[:, 1]
    else:
        u = camera.fx * d_cam[:, 0] / z + camera.cx
        v = camera.fy * d_cam[:, 1] / z + camera.cy
    iu, iv = np.floor(u + 0.5), np.floor(v + 0.5)  # integer coordinates are pixel centres
    k = np.flatnonzero(front & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H))
    if not len(k):
        return 0
    o_body = -R.T @ t
    d_body = rows_times_matrix(d_cam[k], R)  # R_body_from_cam d_cam, per row
    if earth is not None:
        # behind Earth's disc: the line of sight meets the sphere (centre c, radius r)
        c = np.asarray(earth.earth_dir_body) * earth.distance_m - o_body
        b = d_body[:, 0] * c[0] + d_body[:, 1] * c[1] + d_body[:, 2] * c[2]
        keep = ~((b > 0.0) & (c @ c - b * b < earth.radius_m ** 2))
        k, d_body = k[keep], d_body[keep]
    if len(k):
        # behind the target
        k = k[~scene.occluded(np.broadcast_to(o_body, (len(k), 3)), d_body)]
    # Ω of the pixel, at its centre (its spread over the pixel is second order, ~1e-5 here)
    x, y = (iu[k] - camera.cx) / camera.fx, (iv[k] - camera.cy) / camera.fy
    if camera.distorted:
        # the pixel's ray, and its area in the undistorted image plane: 1/det of the
        # distortion's Jacobian (central differences, step 1e-6)
        x, y = camera.undistort(np.column_stack([iu[k], iv[k]])).T
        h = 1e-6
        xa, ya = distort_normalised(x + h, y, camera.dist_coeffs)
        xb, yb = distort_normalised(x - h, y, camera.dist_coeffs)
        xc, yc = distort_normalised(x, y + h, camera.dist_coeffs)
        xe, ye = distort_normalised(x, y - h, camera.dist_coeffs)
        det = ((xa - xb) * (yc - ye) - (xc - xe) * (ya - yb)) / (4.0 * h * h)
    else:
        det = 1.0
    cos_t = 1.0 / np.sqrt(1.0 + x * x + y * y)
    L = stars.irradiance_W_m2[k] * camera.fx * camera.fy / cos_t ** 3
    if camera.distorted:
        L = L * det
    flat = radiance.reshape(H * W, radiance.shape[2])
    np.add.at(flat, (iv[k] * W + iu[k]).astype(np.int64), L[:, None].astype(flat.dtype))
    return len(k)
