"""Physical constants the renderer's light sources share (SI units)."""

from __future__ import annotations

import math

SOLAR_CONSTANT_W_M2 = 1361.0
"""Total solar irradiance at 1 au (Kopp & Lean 2011, doi:10.1029/2010GL045777) [W/m²]."""
EARTH_RADIUS_M = 6378137.0
"""Earth's equatorial radius (WGS-84), as in :mod:`orbit.constants` [m]."""
SUN_ANGULAR_DIAMETER_RAD = math.radians(0.533)
"""Mean angular diameter of the Sun seen from Earth's distance [rad]."""
EARTH_TEXTURES = ("uniform", "procedural", "bluemarble")
"""The built-in Earth textures (:class:`raytrace.lighting.Earth`; an image array is the other choice)."""
