"""Physical constants used by :mod:`orbit` (SI units).

Values: EGM2008/WGS-84 Earth GM and equatorial radius, the EGM2008 J2,
IAU 2012 astronomical unit, and the nominal solar radius used for shadow geometry.
"""

MU_EARTH_M3_S2 = 3.986004418e14
"""Earth gravitational parameter μ [m³/s²] (WGS-84 / EGM2008)."""

R_EARTH_M = 6378137.0
"""Earth equatorial radius R_E [m] (WGS-84)."""

J2_EARTH = 1.08262668e-3
"""Earth second zonal harmonic J2 [-] (EGM2008, unnormalised)."""

R_SUN_M = 6.96e8
"""Solar radius R_S [m] used for penumbra geometry."""

AU_M = 1.495978707e11
"""Astronomical unit [m] (IAU 2012 Resolution B2, exact)."""

MIN_ALTITUDE_M = 100e3
"""Lowest accepted circular-orbit altitude [m]: the Kármán line. Below it there is no orbit."""
