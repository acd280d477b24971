"""The lights as the kernels take them: each light one small float64 record.

**Sun** — a directional light with a disc, the record ``sun`` (:func:`sun_record`, made from a
:class:`raytrace.lighting.Lighting` by ``Lighting.sun_record()``), shape (:data:`N_SUN`,):

* ``sun[SUN_X]``, ``sun[SUN_Y]``, ``sun[SUN_Z]``: unit vector from the target towards the
  Sun's centre, body frame [-];
* ``sun[SUN_E]``: ν·E_sun, the direct solar irradiance on a surface facing the Sun after
  Earth's shadow (ν the visible fraction of the solar disc) [W/m²]; 0 when the target is in
  umbra (no shadow rays are cast then);
* ``sun[SUN_COS_HALF]``: cos(θ☉/2), the cosine of the solar disc's angular radius, for the
  directions over the disc that soft shadows sample [-].

The first four entries are also the 4-vector ``(s_x, s_y, s_z, ν·E_sun)`` that
:func:`raytrace._surface.incoming` reads, so one record serves every Sun kernel: the shadow
rays (:func:`raytrace._surface.sun_rays`, :func:`raytrace._gather.bounce_sun_rays`,
:func:`raytrace._paths.sun_visibility`, :func:`raytrace._cache_kernels._sun_rays`), the disc
samples (:func:`raytrace._surface.sun_disc_dirs`), the shading terms
(:func:`raytrace._surface.shade_sun`, :func:`raytrace._cache_kernels._glints`,
:func:`raytrace._surface.incoming`), the fused paths (:func:`raytrace._paths.gather_traced`,
:func:`raytrace._paths.lobe_traced`) and the path tracer's next-event estimate
(:func:`raytrace.pathtrace._vertex`).

**Earth and the ambient sky** — the environment record ``p`` with its texture
(:mod:`raytrace.environment`'s ``P_*`` indices, made by ``Lighting.packed()``). ``p`` also
holds the Sun's direction and its irradiance *outside* Earth's shadow (``P_SX`` … ``P_SZ``,
``P_ESUN``): that is what lights Earth's day side, which the environment kernels read from
there; they duplicate the direction of the Sun record, not its ν·E_sun.

**Stars** — their own arrays (:mod:`raytrace.stars`): they are drawn in the background and
light nothing.

A new light is one more record (its layout here, its builder on ``Lighting``) and one more
term in the kernels that sum the light at a point.
"""

from __future__ import annotations

import math

import numpy as np

# Sun record layout
SUN_X, SUN_Y, SUN_Z, SUN_E, SUN_COS_HALF = 0, 1, 2, 3, 4
N_SUN = 5


def sun_record(sun_dir_body, sun_irradiance_at_target_W_m2: float, sun_angular_diameter_rad: float) -> np.ndarray:
    """The Sun record (float64, shape (N_SUN,)): the unit direction towards the Sun (body
    frame), ν·E_sun [W/m²] and cos(θ☉/2) of the disc's angular diameter θ☉ [rad]."""
    sun = np.empty(N_SUN)
    sun[SUN_X], sun[SUN_Y], sun[SUN_Z] = (float(x) for x in sun_dir_body)
    sun[SUN_E] = float(sun_irradiance_at_target_W_m2)
    sun[SUN_COS_HALF] = math.cos(0.5 * sun_angular_diameter_rad)
    return sun
