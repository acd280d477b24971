"""Earth behind the target (raytrace._background.earth_background): the procedural texture's albedo
interpolated on 4 × 4 pixel cells against the same texture evaluated at every pixel (a second
method), in views from low orbit where the texture is smooth at the pixel scale (nadir) and
where it is not (the limb, where a pixel spans kilometres)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from raytrace import _context, shade
from raytrace._background import earth_background
from raytrace.camera import Camera
from raytrace.lighting import EARTH_RADIUS_M, SOLAR_CONSTANT_W_M2, Earth, Lighting

CAM = Camera()  # the main job's camera: 1280 × 960, 4 mm focal length, 3.45 µm pixels
ALT_M = 400e3


def _rotation_about_x(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _background(texture: str, tilt_rad: float, step: int, inst=None):
    """Earth radiance and Earth mask of the main job's camera at 400 km, its optical axis
    ``tilt_rad`` from nadir (body frame = camera frame rotated about x)."""
    R_body_from_cam = _rotation_about_x(tilt_rad)
    earth = Earth((0.0, 0.0, 1.0), EARTH_RADIUS_M + ALT_M, albedo=0.3, texture=texture,
                  R_body_from_earth=_rotation_about_x(0.7) @ np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]))
    sun = np.array([0.3, -0.4, -0.6])  # above the camera, slanting: day side with a Sun gradient
    light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)), earth=earth)
    p, tex = _context._background_params(light)
    H, W = CAM.height, CAM.width
    inst = np.zeros((H, W), np.uint16) if inst is None else inst
    earth_px = np.zeros((H, W), bool)
    rad = np.zeros((H, W, 3), np.float32)
    earth_background(inst, np.zeros(3), np.ascontiguousarray(R_body_from_cam), CAM.fx, CAM.fy, CAM.cx, CAM.cy,
                     *CAM.lens_arrays(), p, tex,
                     step, shade._BACKGROUND_TOL, shade._BACKGROUND_CHORD, earth_px, rad)
    return rad, earth_px


def _limb_tilt() -> float:
    """Tilt that puts Earth's limb across the image centre."""
    return math.asin(EARTH_RADIUS_M / (EARTH_RADIUS_M + ALT_M))


def test_nadir_view_interpolated_albedo_matches_every_pixel_evaluation():
    exact, earth0 = _background("procedural", 0.2, 1)
    fast, earth1 = _background("procedural", 0.2, shade._BACKGROUND_STEP)
    assert earth0.all() and np.array_equal(earth0, earth1)  # where Earth is: exact per pixel
    lit = exact.sum(-1) > 0
    assert lit.mean() > 0.9
    rel = np.abs(fast[lit].astype(float) - exact[lit]) / exact[lit]
    assert rel.max() < 2e-3 and np.sqrt((rel ** 2).mean()) < 2e-4
    # the interpolation is in use (else this test could not fail), on most of the image
    assert np.count_nonzero(fast != exact) > 0.3 * fast.size
    # night stays black, bit for bit
    assert np.array_equal(fast[~lit], exact[~lit])


def test_limb_pixels_are_evaluated_per_pixel():
    exact, earth0 = _background("procedural", _limb_tilt(), 1)
    fast, earth1 = _background("procedural", _limb_tilt(), shade._BACKGROUND_STEP)
    assert 0.2 < earth0.mean() < 0.8 and np.array_equal(earth0, earth1)
    lit = exact.sum(-1) > 0
    rel = np.abs(fast[lit].astype(float) - exact[lit]) / exact[lit]
    assert rel.max() < 2e-3
    # within 16 pixels of the limb a pixel spans kilometres of Earth: no interpolation there
    near_limb = binary_dilation(~earth0, iterations=16) & earth0
    assert near_limb.sum() > 10000
    assert np.array_equal(fast[near_limb], exact[near_limb])


def test_uniform_texture_is_per_pixel():
    """The uniform texture is never interpolated: the same bytes at every step (its closed form
    at every pixel: test_earth_mask_and_radiance_match_the_closed_form_at_every_pixel)."""
    exact, _ = _background("uniform", 0.2, 1)
    fast, _ = _background("uniform", 0.2, shade._BACKGROUND_STEP)
    assert np.array_equal(fast, exact)


def test_target_pixels_are_left_alone():
    inst = np.zeros((CAM.height, CAM.width), np.uint16)
    inst[300:600, 400:900] = 1
    exact, _ = _background("procedural", 0.2, 1)
    fast, earth = _background("procedural", 0.2, shade._BACKGROUND_STEP, inst=inst)
    assert earth[300:600, 400:900].all()  # Earth is behind the target, flagged,
    assert np.all(fast[300:600, 400:900] == 0.0)  # but not drawn over it
    off = inst == 0
    lit = off & (exact.sum(-1) > 0)
    assert np.all(np.abs(fast[lit].astype(float) - exact[lit]) <= 2e-3 * exact[lit])


@pytest.mark.parametrize("tilt", [0.2, "limb"])
def test_earth_mask_and_radiance_match_the_closed_form_at_every_pixel(tilt):
    """Every pixel against the closed form in NumPy (unit rays, float64): the ray through the
    pixel centre meets the sphere where its distance from Earth's centre is below the radius,
    in front of the camera, and the radiance there is albedo · E · max(0, m·s) / π (uniform
    texture). The mask may differ only at rays tangent to the sphere to 1e-9."""
    tilt_rad = _limb_tilt() if tilt == "limb" else tilt
    fast, earth = _background("uniform", tilt_rad, shade._BACKGROUND_STEP)
    R = _rotation_about_x(tilt_rad)
    sun = np.array([0.3, -0.4, -0.6])
    sun /= np.linalg.norm(sun)
    c = np.array([0.0, 0.0, EARTH_RADIUS_M + ALT_M])
    v, u = np.mgrid[0:CAM.height, 0:CAM.width]
    d = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(u.shape)], -1) @ R.T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ c
    q2 = c @ c - b * b  # squared distance of Earth's centre from the ray
    want_hit = (b > 0) & (q2 < EARTH_RADIUS_M ** 2)
    grazing = np.abs(q2 / EARTH_RADIUS_M ** 2 - 1.0) < 1e-9
    assert np.array_equal(earth[~grazing], want_hit[~grazing])
    if tilt == "limb":
        assert 0.2 < want_hit.mean() < 0.8  # the limb crosses the image
    hit = want_hit & ~grazing
    t = b[hit] - np.sqrt(EARTH_RADIUS_M ** 2 - q2[hit])
    m = (t[:, None] * d[hit] - c) / EARTH_RADIUS_M
    want = 0.3 * SOLAR_CONSTANT_W_M2 * np.maximum(0.0, m @ sun) / math.pi
    got = fast[hit].astype(float)
    assert np.all(np.abs(got - want[:, None]) <= 1e-5 * want[:, None] + 1e-6)
    assert np.all(fast[~earth] == 0.0)  # space stays black
