"""The Sun record the kernels take (raytrace._lights) holds what the Lighting says."""
from __future__ import annotations

import math

import numpy as np

from raytrace import _lights, environment as env
from raytrace.lighting import Lighting


def test_sun_record_from_lighting():
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), sun_irradiance_W_m2=1361.0, shadow_fraction=0.25,
                     sun_angular_diameter_rad=0.0093)
    sun = light.sun_record()
    assert sun.dtype == np.float64 and sun.shape == (_lights.N_SUN,)
    assert tuple(sun[[_lights.SUN_X, _lights.SUN_Y, _lights.SUN_Z]]) == light.sun_dir_body
    assert sun[_lights.SUN_E] == light.sun_irradiance_at_target_W_m2 == 0.25 * 1361.0
    assert sun[_lights.SUN_COS_HALF] == math.cos(0.5 * 0.0093)
    # the environment record keeps the Sun's direction and its irradiance outside Earth's shadow
    p = light.packed()[0]
    assert tuple(p[env.P_SX:env.P_SZ + 1]) == light.sun_dir_body
    assert p[env.P_ESUN] == 1361.0


def test_umbra_has_no_sun_term():
    sun = Lighting(sun_dir_body=(0, 0, 1), shadow_fraction=0.0).sun_record()
    assert sun[_lights.SUN_E] == 0.0
