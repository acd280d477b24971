"""Visibility of the target: Earth occlusion, Earth background, Sun exclusion, Earth shadow.

Implements docs/orbit.md, "Visibility" on ECI positions in metres: the segment test for the
line of sight, the cone test for "Earth in the background" (which is *not* an occlusion test,
although the source paper uses it as one), the Sun-exclusion angle, the cylindrical and conical
Earth-shadow models (the paper's test is the cylindrical one; docs/accuracy.md, "Where this
departs from the source paper") and the illuminated fraction ν of the solar disc.

Every function is vectorised: positions have shape (3,) or (n, 3) and are broadcast against
each other; results have shape () (NumPy scalars) or (n,). The Earth is a sphere of radius
R_E and the Sun a uniform disc of radius R_S (no oblateness, refraction or limb darkening).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ._checks import finite_array, finite_scalar
from .constants import R_EARTH_M, R_SUN_M

__all__ = [
    "SUNLIT", "PENUMBRA", "UMBRA", "SHADOW_NAMES", "DEFAULT_SUN_MARGIN_RAD",
    "line_of_sight", "earth_in_background", "sun_angle", "sun_clear",
    "shadow_cylindrical", "shadow_conical", "illuminated_fraction", "illuminated_fraction_seen",
    "Visibility", "visibility",
]

SUNLIT = 0
"""Shadow code: the whole solar disc is visible from the target."""
PENUMBRA = 1
"""Shadow code: the Earth hides part of the solar disc."""
UMBRA = 2
"""Shadow code: the Earth hides the whole solar disc."""
SHADOW_NAMES = ("sunlit", "penumbra", "umbra")
"""Names of the shadow codes, indexed by code."""

DEFAULT_SUN_MARGIN_RAD = float(np.radians(20.0))
"""Default stray-light margin added to the Sun's apparent radius [rad]."""


# --------------------------------------------------------------------------- validation

def _positions(**named) -> list[np.ndarray]:
    """Validate ECI positions (shape (3,) or (n, 3), finite) and broadcast them together."""
    arrays = [finite_array(name, value, shape_tail=(3,), ndim=(1, 2)) for name, value in named.items()]
    try:
        shape = np.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        got = ", ".join(f"{name} {a.shape}" for name, a in zip(named, arrays))
        raise ValueError(
            f"{' and '.join(named)} must have shape (3,) or the same shape (n, 3); got {got}"
        ) from None
    return [np.broadcast_to(a, shape) for a in arrays]


def _radius(name: str, value) -> float:
    return finite_scalar(name, value, positive=True)


def _margin(name: str, value) -> float:
    margin = finite_scalar(name, value, nonnegative=True)
    if not margin < np.pi:
        raise ValueError(f"{name} must be >= 0 and < pi rad, got {margin!r}")
    return margin


def _require_distinct(r_cam: np.ndarray, r_target: np.ndarray) -> None:
    if np.any(np.all(r_cam == r_target, axis=-1)):
        raise ValueError(
            "r_target_eci must differ from r_cam_eci: the viewing direction is undefined "
            "when the camera sits at the target"
        )


def _require_sun_far(r_sun: np.ndarray, r_from: np.ndarray, what: str, min_dist_m: float) -> None:
    if np.any(_norm(r_sun - r_from) <= min_dist_m):
        raise ValueError(
            f"r_sun_eci must be the Sun's position in metres, more than {min_dist_m:.4g} m from "
            f"{what}; got a point closer than that (a unit direction instead of a position?)"
        )


# --------------------------------------------------------------------------- kernels

def _norm(v: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", v, v))


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", u, v)


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between vectors [rad], accurate near 0 and π; 0 if either vector is zero."""
    return np.arctan2(_norm(np.cross(u, v)), _dot(u, v))


def _scalar_or_array(x: np.ndarray):
    """Shape () → NumPy scalar, shape (n,) → the array itself."""
    return x[()]


def _line_of_sight(r_cam, r_target, radius_m):
    d = r_target - r_cam
    dd = _dot(d, d)
    t_star = np.divide(-_dot(r_cam, d), dd, out=np.zeros_like(dd), where=dd > 0.0)
    t_star = np.clip(t_star, 0.0, 1.0)
    closest = r_cam + t_star[..., np.newaxis] * d
    return _norm(closest) > radius_m


def _earth_in_background(r_cam, r_target, radius_m):
    cam_dist = _norm(r_cam)
    inside = cam_dist <= radius_m
    ratio = np.divide(radius_m, cam_dist, out=np.ones_like(cam_dist), where=~inside)
    half_angle = np.arcsin(np.minimum(ratio, 1.0))
    theta = _angle(-r_cam, r_target - r_cam)
    return inside | (theta < half_angle)


def _sun_angle(r_cam, r_target, r_sun):
    return _angle(r_sun - r_cam, r_target - r_cam)


def _sun_exclusion_rad(r_cam, r_sun, margin_rad):
    return np.arcsin(np.minimum(R_SUN_M / _norm(r_sun - r_cam), 1.0)) + margin_rad


def _shadow_cylindrical(r_target, r_sun):
    s_hat = r_sun / _norm(r_sun)[..., np.newaxis]
    along = _dot(r_target, s_hat)
    across = _norm(np.cross(r_target, s_hat))
    return (along < 0.0) & (across < R_EARTH_M)


def _shadow_conical(r_target, r_sun):
    d_sun = _norm(r_sun)
    s_hat = r_sun / d_sun[..., np.newaxis]
    sin_u = (R_SUN_M - R_EARTH_M) / d_sun
    sin_p = (R_SUN_M + R_EARTH_M) / d_sun
    x_u = R_EARTH_M / sin_u                      # umbra apex, behind the Earth
    x_p = R_EARTH_M / sin_p                      # penumbra apex, on the Sun's side
    tan_u = sin_u / np.sqrt(1.0 - sin_u**2)
    tan_p = sin_p / np.sqrt(1.0 - sin_p**2)
    xi = -_dot(r_target, s_hat)                  # > 0 behind the Earth
    delta = _norm(np.cross(r_target, s_hat))     # = |r_T + ξ ŝ|, distance from the shadow axis
    r_penumbra = (x_p + xi) * tan_p
    r_umbra = (x_u - xi) * tan_u                 # <= 0 beyond the umbra apex: no umbra there
    code = np.where(delta < r_umbra, UMBRA, PENUMBRA)
    code = np.where((xi <= 0.0) | (delta >= r_penumbra), SUNLIT, code)
    return code.astype(np.int8)


def _segment_shape(theta: np.ndarray) -> np.ndarray:
    """θ − sin θ cos θ = (φ − sin φ)/2 with φ = 2θ, without cancellation for small θ.

    A circular segment of radius r and half-angle θ has area r²(θ − sin θ cos θ).
    """
    phi = 2.0 * theta
    phi2 = phi * phi
    # φ − sin φ = Σ_{k≥1} (−1)^(k+1) φ^(2k+1)/(2k+1)!; 7 terms: relative error < 1e-17 for φ < 0.5
    series = phi * phi2 * (1.0 / 6.0 + phi2 * (-1.0 / 120.0 + phi2 * (1.0 / 5040.0 + phi2 * (
        -1.0 / 362880.0 + phi2 * (1.0 / 39916800.0 + phi2 * (-1.0 / 6227020800.0
                                                              + phi2 / 1307674368000.0))))))
    return 0.5 * np.where(phi < 0.5, series, phi - np.sin(phi))


def _illuminated_fraction(r_target, r_sun):
    to_sun = r_sun - r_target
    a = np.arcsin(np.minimum(R_SUN_M / _norm(to_sun), 1.0))
    target_dist = _norm(r_target)
    ratio = np.divide(R_EARTH_M, target_dist, out=np.ones_like(target_dist), where=target_dist > R_EARTH_M)
    b = np.arcsin(np.minimum(ratio, 1.0))
    c = _angle(-r_target, to_sun)

    full = c >= a + b
    none = ~full & (c <= b - a)
    annulus = ~full & ~none & (c <= a - b)       # Earth disc wholly inside the Sun disc
    partial = ~(full | none | annulus)

    # Partial overlap, |a − b| < c < a + b. The x, y and acos terms of illuminated_fraction's
    # Notes, rewritten without cancellation: y from Heron's formula, the acos as atan2
    # half-angles θ_a, θ_b of the common chord, and each lens half as a circular segment
    # r²(θ − sin θ cos θ).
    c_p = np.where(partial, c, a + b)            # harmless stand-in elsewhere (y = 0)
    heron = (np.maximum(a + b - c_p, 0.0) * np.maximum(b - a + c_p, 0.0)
             * np.maximum(a - b + c_p, 0.0) * (a + b + c_p))
    y = np.sqrt(heron) / (2.0 * c_p)
    x = ((c_p - b) * (c_p + b) + a * a) / (2.0 * c_p)
    theta_a = np.arctan2(y, x)                   # = acos(x/a)
    theta_b = np.arctan2(y, ((c_p - a) * (c_p + a) + b * b) / (2.0 * c_p))   # = acos((c − x)/b)
    sun_part = a * a * _segment_shape(theta_a)
    earth_part = b * b * _segment_shape(theta_b)
    sun_area = np.pi * a * a
    # ν = 1 − lens/(π a²); when most of the Sun is hidden (θ_a > π/2) use the visible
    # remainder directly, a² g(π − θ_a) − b² g(θ_b), so ν near 0 keeps its relative accuracy.
    nu_partial = np.where(theta_a <= 0.5 * np.pi,
                          1.0 - (sun_part + earth_part) / sun_area,
                          (a * a * _segment_shape(np.pi - theta_a) - earth_part) / sun_area)

    nu = np.select([full, none, annulus], [1.0, 0.0, 1.0 - b**2 / a**2], nu_partial)
    return np.clip(nu, 0.0, 1.0)


# --------------------------------------------------------------------------- public API

def line_of_sight(r_cam_eci, r_target_eci, *, radius_m: float = R_EARTH_M):
    """Whether the Earth leaves the straight line from the camera to the target free.

    Parameters
    ----------
    r_cam_eci : array_like of float, shape (3,) or (n, 3)
        Camera position in ECI [m].
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m].
    radius_m : float
        Radius of the blocking ball, > 0; e.g. ``R_EARTH_M + 100e3`` to include the
        atmosphere [m].

    Returns
    -------
    numpy.bool_ or ndarray of bool, shape () or (n,)
        True when the segment camera → target does not meet the ball |r| ≤ ``radius_m``.

    Raises
    ------
    ValueError
        If a position is not finite or badly shaped, the shapes do not broadcast, or
        ``radius_m`` is not a finite positive number.

    Notes
    -----
    Closest point of the segment to the Earth's centre::

        d = r_T − r_C,  t* = clamp(−(r_C·d)/(d·d), 0, 1),  p = r_C + t* d,  visible ⇔ |p| > R

    A camera at the target (d = 0) sees it iff it lies outside the ball. Between two
    spacecraft 10–60 m apart in LEO the line of sight is never blocked.
    """
    r_cam, r_target = _positions(r_cam_eci=r_cam_eci, r_target_eci=r_target_eci)
    return _scalar_or_array(_line_of_sight(r_cam, r_target, _radius("radius_m", radius_m)))


def earth_in_background(r_cam_eci, r_target_eci, *, radius_m: float = R_EARTH_M):
    """Whether the direction to the target lies inside the Earth's apparent disc.

    This is **not** an occlusion test (the source paper uses it as one): a target 20 m
    straight below the camera is in front of the Earth, fully visible, and has the Earth
    behind it. Use :func:`line_of_sight` for occlusion; use this flag for rendering and labels
    (the Earth fills the image around the target).

    Parameters
    ----------
    r_cam_eci : array_like of float, shape (3,) or (n, 3)
        Camera position in ECI [m].
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m]; must differ from the camera position.
    radius_m : float
        Radius of the Earth's sphere, > 0 [m].

    Returns
    -------
    numpy.bool_ or ndarray of bool, shape () or (n,)
        True when the ray from the camera through the target points into the Earth's
        disc (the Earth is behind the target if :func:`line_of_sight` is True, in front of
        it otherwise). True for a camera inside the sphere.

    Raises
    ------
    ValueError
        On non-finite or badly shaped positions, a camera at the target, or a bad radius.

    Notes
    -----
    Cone test: θ = angle(−r_C, r_T − r_C) < asin(R/|r_C|), i.e.
    cos θ > sqrt(|r_C|² − R²)/|r_C|. Angles are computed with atan2 so the test
    stays accurate for small θ.
    """
    r_cam, r_target = _positions(r_cam_eci=r_cam_eci, r_target_eci=r_target_eci)
    radius = _radius("radius_m", radius_m)
    _require_distinct(r_cam, r_target)
    return _scalar_or_array(_earth_in_background(r_cam, r_target, radius))


def sun_angle(r_cam_eci, r_target_eci, r_sun_eci):
    """Angle between the directions camera → Sun and camera → target.

    Parameters
    ----------
    r_cam_eci : array_like of float, shape (3,) or (n, 3)
        Camera position in ECI [m].
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m]; must differ from the camera position.
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI, e.g. from :func:`orbit.sun.sun_position_eci` [m].

    Returns
    -------
    numpy.float64 or ndarray of float64, shape () or (n,)
        Angle in [0, π] between r_S − r_C and r_T − r_C [rad].

    Raises
    ------
    ValueError
        On non-finite or badly shaped positions, a camera at the target, or a Sun
        position within R_S of the camera (typically a unit vector passed by mistake).
    """
    r_cam, r_target, r_sun = _positions(r_cam_eci=r_cam_eci, r_target_eci=r_target_eci,
                                        r_sun_eci=r_sun_eci)
    _require_distinct(r_cam, r_target)
    _require_sun_far(r_sun, r_cam, "the camera", R_SUN_M)
    return _scalar_or_array(_sun_angle(r_cam, r_target, r_sun))


def sun_clear(r_cam_eci, r_target_eci, r_sun_eci, *, margin_rad: float = DEFAULT_SUN_MARGIN_RAD):
    """Whether the Sun is far enough from the line of sight (Sun-exclusion constraint).

    Parameters
    ----------
    r_cam_eci : array_like of float, shape (3,) or (n, 3)
        Camera position in ECI [m].
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m]; must differ from the camera position.
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI [m].
    margin_rad : float
        Stray-light margin of the optics added to the Sun's apparent radius, in [0, π)
        (default 20 deg) [rad].

    Returns
    -------
    numpy.bool_ or ndarray of bool, shape () or (n,)
        True iff angle(r_S − r_C, r_T − r_C) > α_s.

    Raises
    ------
    ValueError
        As :func:`sun_angle`, or if ``margin_rad`` is negative, ≥ π or not finite.

    Notes
    -----
    α_s = asin(R_S/|r_S − r_C|) + margin; the Sun's apparent radius is
    ≈ 0.267 deg at 1 AU. The boresight is assumed to point at the target.
    """
    r_cam, r_target, r_sun = _positions(r_cam_eci=r_cam_eci, r_target_eci=r_target_eci,
                                        r_sun_eci=r_sun_eci)
    margin = _margin("margin_rad", margin_rad)
    _require_distinct(r_cam, r_target)
    _require_sun_far(r_sun, r_cam, "the camera", R_SUN_M)
    clear = _sun_angle(r_cam, r_target, r_sun) > _sun_exclusion_rad(r_cam, r_sun, margin)
    return _scalar_or_array(clear)


def shadow_cylindrical(r_target_eci, r_sun_eci):
    """Whether the target is in the Earth's cylindrical shadow.

    Parameters
    ----------
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m].
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI [m].

    Returns
    -------
    numpy.bool_ or ndarray of bool, shape () or (n,)
        True in shadow.

    Raises
    ------
    ValueError
        On non-finite or badly shaped positions, or a Sun position within R_S + R_E of the
        Earth's centre (typically a unit vector passed by mistake).

    Notes
    -----
    With ŝ = r_S/|r_S|: in shadow iff r_T·ŝ < 0 and |r_T − (r_T·ŝ)ŝ| < R_E.
    Equivalent to the source paper's inequality with its lost minus sign restored: lit iff
    r_T·ŝ > −sqrt(|r_T|² − R_E²). The conical model (:func:`shadow_conical`) is preferred.
    """
    r_target, r_sun = _positions(r_target_eci=r_target_eci, r_sun_eci=r_sun_eci)
    _require_sun_far(r_sun, 0.0, "the Earth's centre", R_SUN_M + R_EARTH_M)
    return _scalar_or_array(_shadow_cylindrical(r_target, r_sun))


def shadow_conical(r_target_eci, r_sun_eci):
    """Earth-shadow region of the target in the conical (umbra/penumbra) model.

    Parameters
    ----------
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m].
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI [m].

    Returns
    -------
    numpy.int8 or ndarray of int8, shape () or (n,)
        :data:`SUNLIT` (0), :data:`PENUMBRA` (1) or :data:`UMBRA` (2).

    Raises
    ------
    ValueError
        As :func:`shadow_cylindrical`.

    Notes
    -----
    Umbra and penumbra cones, with d_S = |r_S| and ŝ = r_S/d_S::

        α_u = asin((R_S − R_E)/d_S),  α_p = asin((R_S + R_E)/d_S)
        x_u = R_E/sin α_u (umbra apex behind the Earth),  x_p = R_E/sin α_p
        ξ = −r_T·ŝ,  δ = |r_T + ξ ŝ|
        r_pen = (x_p + ξ) tan α_p,  r_umb = (x_u − ξ) tan α_u

    ξ ≤ 0 or δ ≥ r_pen → sunlit; δ < r_umb → umbra (possible only for ξ < x_u);
    otherwise penumbra (including the antumbra beyond x_u). Points less than about 70 m
    above the surface near the terminator with ξ ≤ 0 are reported sunlit although the
    limb can touch the solar disc there (:func:`illuminated_fraction` sees it).
    """
    r_target, r_sun = _positions(r_target_eci=r_target_eci, r_sun_eci=r_sun_eci)
    _require_sun_far(r_sun, 0.0, "the Earth's centre", R_SUN_M + R_EARTH_M)
    return _scalar_or_array(_shadow_conical(r_target, r_sun))


def illuminated_fraction(r_target_eci, r_sun_eci):
    """Fraction ν of the solar disc not hidden by the Earth, seen from the target.

    Parameters
    ----------
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m].
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI [m].

    Returns
    -------
    numpy.float64 or ndarray of float64, shape () or (n,)
        ν in [0, 1]: 1 sunlit, 0 umbra, in between penumbra [-]. Never NaN.

    Raises
    ------
    ValueError
        As :func:`shadow_cylindrical`.

    Notes
    -----
    Overlap of two discs in the plane of the sky, from the apparent radii seen
    at r_T: a = asin(R_S/|r_S − r_T|), b = asin(R_E/|r_T|), c = angle(−r_T, r_S − r_T)::

        c ≥ a + b → ν = 1;   c ≤ b − a → ν = 0;   c ≤ a − b → ν = 1 − b²/a²;   else
        x = (c² + a² − b²)/(2c),  y = sqrt(a² − x²),
        ν = 1 − [a² acos(x/a) + b² acos((c − x)/b) − c y]/(π a²)

    The partial case is evaluated in an algebraically identical but cancellation-free
    form (y by Heron's formula, the two acos terms as atan2 half-angles of the common
    chord, each lens half as a circular segment r²(θ − sin θ cos θ)), so ν keeps its
    accuracy at the edges of the penumbra; it agrees with :func:`shadow_conical` except
    within ~1 µm of a cone surface.

    The Sun is a uniform disc (no limb darkening) and the Earth's limb is treated as a
    plane circle of radius b; at 400 km (b ≈ 70 deg) the true overlap on the celestial
    sphere differs by at most 2.2e-4 inside the penumbra, and the boundaries ν = 0 and
    ν = 1 are exact (they coincide with the cones of :func:`shadow_conical`). Points
    inside the Earth are not physical; they get b = π/2 and a finite ν.
    """
    r_target, r_sun = _positions(r_target_eci=r_target_eci, r_sun_eci=r_sun_eci)
    _require_sun_far(r_sun, 0.0, "the Earth's centre", R_SUN_M + R_EARTH_M)
    return _scalar_or_array(_illuminated_fraction(r_target, r_sun))


def illuminated_fraction_seen(earth_dir, earth_distance_m: float, sun_dir, *, earth_radius_m: float = R_EARTH_M,
                             sun_angular_diameter_rad: float):
    """:func:`illuminated_fraction` of a target that sees the Earth's centre along the unit
    vector ``earth_dir`` at ``earth_distance_m`` (an Earth of radius ``earth_radius_m``) and the
    Sun along ``sun_dir`` with the angular diameter ``sun_angular_diameter_rad``, in any one
    frame of axes: only the angles count. Returns ν in [0, 1]."""
    # the same angles in a frame scaled to this module's Earth radius: the target at −ê·d, the
    # Sun at the distance where its disc has the given angular diameter
    k = R_EARTH_M / finite_scalar("earth_radius_m", earth_radius_m, positive=True)
    r_target = -k * finite_scalar("earth_distance_m", earth_distance_m, positive=True) * np.asarray(earth_dir, float)
    half = max(0.5 * finite_scalar("sun_angular_diameter_rad", sun_angular_diameter_rad, positive=True), 1e-7)
    r_sun = r_target + R_SUN_M / math.sin(half) * np.asarray(sun_dir, float)
    return illuminated_fraction(r_target, r_sun)


_VISIBILITY_DTYPES = {"line_of_sight": np.bool_, "earth_in_background": np.bool_,
                      "sun_angle_rad": np.float64, "sun_clear": np.bool_, "shadow": np.int8,
                      "illuminated_fraction": np.float64}


@dataclass(frozen=True, slots=True)
class Visibility:
    """All visibility flags of a sequence of frames (shape () or (n,) each, read-only).

    Attributes
    ----------
    line_of_sight : ndarray of bool, shape () or (n,)
        The Earth does not block the segment camera → target.
    earth_in_background : ndarray of bool, shape () or (n,)
        The target is seen against the Earth's disc (not an occlusion flag).
    sun_angle_rad : ndarray of float64, shape () or (n,)
        Angle between camera → Sun and camera → target [rad].
    sun_clear : ndarray of bool, shape () or (n,)
        The Sun is outside the exclusion cone (apparent radius + margin).
    shadow : ndarray of int8, shape () or (n,)
        Conical shadow code of the target: SUNLIT, PENUMBRA or UMBRA.
    illuminated_fraction : ndarray of float64, shape () or (n,)
        Visible fraction ν of the solar disc at the target [-].
    """

    line_of_sight: np.ndarray
    earth_in_background: np.ndarray
    sun_angle_rad: np.ndarray
    sun_clear: np.ndarray
    shadow: np.ndarray
    illuminated_fraction: np.ndarray

    def __post_init__(self) -> None:
        shape = None
        for field in fields(self):
            arr = np.array(getattr(self, field.name), dtype=_VISIBILITY_DTYPES[field.name], copy=True)
            if arr.ndim > 1:
                raise ValueError(f"{field.name} must have shape () or (n,), got {arr.shape}")
            if shape is None:
                shape = arr.shape
            elif arr.shape != shape:
                raise ValueError(
                    f"{field.name} must have the shape {shape} of line_of_sight, got {arr.shape}"
                )
            arr.flags.writeable = False
            object.__setattr__(self, field.name, arr)

    @property
    def visible(self) -> np.ndarray:
        """ndarray of bool, shape () or (n,): line of sight, Sun clear and target lit (ν > 0)."""
        return self.line_of_sight & self.sun_clear & (self.illuminated_fraction > 0.0)

    def to_dict(self, i: int | None = None) -> dict:
        """Plain-Python flags of frame ``i`` (``None`` for shape ()), ready for JSON.

        Returns
        -------
        dict
            ``visible``, ``line_of_sight``, ``earth_in_background``, ``sun_clear`` (bool),
            ``sun_angle_deg`` (float, deg), ``shadow`` ("sunlit", "penumbra" or "umbra")
            and ``illuminated_fraction`` (float).
        """
        if self.line_of_sight.ndim == 0:
            if i is not None:
                raise ValueError(f"i must be None for a single frame, got {i!r}")
            index = ()
        else:
            n = self.line_of_sight.shape[0]
            if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)) or not -n <= i < n:
                raise ValueError(f"i must be an integer frame index in [-{n}, {n}), got {i!r}")
            index = int(i)
        return {
            "visible": bool(self.visible[index]),
            "line_of_sight": bool(self.line_of_sight[index]),
            "earth_in_background": bool(self.earth_in_background[index]),
            "sun_clear": bool(self.sun_clear[index]),
            "sun_angle_deg": float(np.degrees(self.sun_angle_rad[index])),
            "shadow": SHADOW_NAMES[int(self.shadow[index])],
            "illuminated_fraction": float(self.illuminated_fraction[index]),
        }


def visibility(r_cam_eci, r_target_eci, r_sun_eci, *, sun_margin_rad: float = DEFAULT_SUN_MARGIN_RAD,
               earth_radius_m: float = R_EARTH_M) -> Visibility:
    """Compute every visibility flag (docs/orbit.md, "Visibility") at once.

    Parameters
    ----------
    r_cam_eci : array_like of float, shape (3,) or (n, 3)
        Camera position in ECI [m].
    r_target_eci : array_like of float, shape (3,) or (n, 3)
        Target position in ECI [m]; must differ from the camera position.
    r_sun_eci : array_like of float, shape (3,) or (n, 3)
        Sun position in ECI [m].
    sun_margin_rad : float
        Stray-light margin of the Sun exclusion, in [0, π) [rad].
    earth_radius_m : float
        Radius of the Earth used by the line-of-sight and background tests, > 0 (e.g.
        ``R_EARTH_M + 100e3`` for the atmosphere). The shadow uses R_E [m].

    Returns
    -------
    Visibility
        Flags with shape () or (n,).

    Raises
    ------
    ValueError
        As the individual functions.
    """
    r_cam, r_target, r_sun = _positions(r_cam_eci=r_cam_eci, r_target_eci=r_target_eci,
                                        r_sun_eci=r_sun_eci)
    margin = _margin("sun_margin_rad", sun_margin_rad)
    radius = _radius("earth_radius_m", earth_radius_m)
    _require_distinct(r_cam, r_target)
    _require_sun_far(r_sun, r_cam, "the camera", R_SUN_M)
    _require_sun_far(r_sun, 0.0, "the Earth's centre", R_SUN_M + R_EARTH_M)
    angle = _sun_angle(r_cam, r_target, r_sun)
    return Visibility(
        line_of_sight=_line_of_sight(r_cam, r_target, radius),
        earth_in_background=_earth_in_background(r_cam, r_target, radius),
        sun_angle_rad=angle,
        sun_clear=angle > _sun_exclusion_rad(r_cam, r_sun, margin),
        shadow=_shadow_conical(r_target, r_sun),
        illuminated_fraction=_illuminated_fraction(r_target, r_sun),
    )
