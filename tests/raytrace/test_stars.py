"""Stars against independent answers.

Oracles:
* Brightness: the Sun's own magnitude gives the solar constant; Pogson's ratio (5 mag = 100×).
* Procedural counts against the star counts of Allen's Astrophysical Quantities (4th ed.,
  § 20.2): about 48, 513 and 4800 stars brighter than V = 2, 4 and 6 over the whole sky.
* Flux: a star's radiance times the exact solid angle of its pixel (a spherical
  quadrilateral, from Van Oosterom & Strackee's triangle formula) is its irradiance.
* Occlusion: a star straight behind the target or inside Earth's disc adds nothing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.lighting import SOLAR_CONSTANT_W_M2, Earth, Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render
from raytrace.stars import SUN_V_MAG, StarField, irradiance_of_magnitude

W, H, F = 160, 120, 200.0
CAM = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)


def _rot(axis, angle):
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


R_BODY_FROM_ECI = _rot([0.3, -0.5, 0.8], 1.1)


@pytest.fixture(scope="module")
def scene():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    return Scene(TargetModel("ball", (Component("ball", mesh, "white_paint", "bus", 1.0),)))


@pytest.fixture(scope="module")
def pose():
    rho = np.array([0.0, -8.0, 2.0])
    R = look_at(rho)
    return R, -R @ rho


def _dir_eci_of_pixel(R, u, v):
    """Inertial direction of the camera ray through image point (u, v)."""
    d_cam = np.array([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, 1.0])
    d_cam /= np.linalg.norm(d_cam)
    return R_BODY_FROM_ECI.T @ (R.T @ d_cam)


def _triangle_solid_angle(a, b, c):
    """Van Oosterom & Strackee (1983): solid angle of the triangle of unit vectors a, b, c."""
    num = abs(np.dot(a, np.cross(b, c)))
    den = 1.0 + np.dot(a, b) + np.dot(b, c) + np.dot(c, a)
    return 2.0 * math.atan2(num, den)


def _pixel_solid_angle(iu, iv):
    corners = []
    for du, dv in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
        d = np.array([(iu + du - CAM.cx) / CAM.fx, (iv + dv - CAM.cy) / CAM.fy, 1.0])
        corners.append(d / np.linalg.norm(d))
    a, b, c, d = corners
    return _triangle_solid_angle(a, b, c) + _triangle_solid_angle(a, c, d)


def _light(stars, earth=None):
    return Lighting(sun_dir_body=(0.0, -1.0, 0.0), earth=earth, stars=stars, R_body_from_eci=R_BODY_FROM_ECI)


def test_magnitude_scale():
    assert irradiance_of_magnitude(SUN_V_MAG) == pytest.approx(SOLAR_CONSTANT_W_M2, rel=1e-12)
    assert irradiance_of_magnitude(1.0) / irradiance_of_magnitude(6.0) == pytest.approx(100.0, rel=1e-12)
    # Vega-like V = 0: a few 10⁻⁸ W/m² over the visible band
    assert 1e-8 < irradiance_of_magnitude(0.0) < 1e-7


def test_procedural_counts_isotropy_and_seed():
    sky = StarField.procedural(6.5, seed=3)
    v_mag = SUN_V_MAG - 2.5 * np.log10(sky.irradiance_W_m2 / SOLAR_CONSTANT_W_M2)
    for limit, allen in ((2.0, 48), (4.0, 513), (6.0, 4800)):
        n = int((v_mag < limit).sum())
        assert 0.75 * allen < n < 1.3 * allen, (limit, n)
    assert v_mag.min() >= -1.5 and v_mag.max() <= 6.5
    # isotropic: the mean direction of n uniform unit vectors has sd 1/sqrt(3n) per axis
    assert np.all(np.abs(sky.dirs_eci.mean(axis=0)) < 4.0 / math.sqrt(3 * len(sky)))
    again = StarField.procedural(6.5, seed=3)
    assert np.array_equal(again.dirs_eci, sky.dirs_eci)
    assert np.array_equal(again.irradiance_W_m2, sky.irradiance_W_m2)
    assert not np.array_equal(StarField.procedural(6.5, seed=4).dirs_eci[:10], sky.dirs_eci[:10])


@pytest.mark.parametrize("bad", [-2.0, 9.5, float("nan"), "6", True])
def test_procedural_rejects_bad_limit(bad):
    with pytest.raises(ValueError, match="limit magnitude"):
        StarField.procedural(bad)


def test_lighting_needs_attitude_with_stars():
    sky = StarField.procedural(2.0)
    with pytest.raises(ValueError, match="R_body_from_eci"):
        Lighting(sun_dir_body=(0.0, 0.0, 1.0), stars=sky)
    with pytest.raises(ValueError, match="R_body_from_eci"):
        Lighting(sun_dir_body=(0.0, 0.0, 1.0), stars=sky, R_body_from_eci=np.diag([1.0, 1.0, -1.0]))


@pytest.mark.parametrize("quality", ["fast", "balanced", "reference"])
def test_star_flux_lands_in_its_pixel(scene, pose, quality):
    R, t = pose
    # a bright star near a corner (far off-axis: cos θ = 0.76) and one near the centre-left
    spots = [(5.3, 6.8), (40.2, 61.0)]
    dirs = np.array([_dir_eci_of_pixel(R, u, v) for u, v in spots])
    E = np.array([3e-6, 5e-7])
    stars = StarField(dirs, E)
    kw = {"quality": quality, "samples": 2 if quality == "reference" else None, "seed": 1}
    base = render(scene, CAM, R, t, _light(None), **kw).radiance
    img = render(scene, CAM, R, t, _light(stars), **kw).radiance
    diff = (img.astype(np.float64) - base).sum(axis=2)
    for (u, v), e in zip(spots, E):
        iu, iv = round(u), round(v)
        assert diff[iv, iu] / 3.0 * _pixel_solid_angle(iu, iv) == pytest.approx(e, rel=2e-4)
        diff[iv, iu] = 0.0
    assert not diff.any()  # nothing else changed


def test_stars_hidden_by_target_and_earth(scene, pose):
    R, t = pose
    o_body = -R.T @ t
    behind_target = R_BODY_FROM_ECI.T @ (-o_body / np.linalg.norm(o_body))
    # Earth's disc (half-angle 0.5 rad) 0.6 rad below the optical axis: its upper limb 0.1 rad
    # below the axis, in the lower part of the view
    alpha, half = 0.6, 0.5
    e_cam = np.array([0.0, math.sin(alpha), math.cos(alpha)])
    earth = Earth(earth_dir_body=R.T @ e_cam, distance_m=6378137.0 / math.sin(half), texture="uniform")
    # towards the upper right of Earth's centre (clear of the target): inside the disc by
    # 0.02 rad, and outside it by 0.02 rad
    w = np.array([0.4, -0.9, 0.0])
    w -= (w @ e_cam) * e_cam
    w /= np.linalg.norm(w)
    inside, outside = [R_BODY_FROM_ECI.T @ (R.T @ (math.cos(b) * e_cam + math.sin(b) * w))
                       for b in (half - 0.02, half + 0.02)]
    stars = StarField(np.array([behind_target, inside, outside]), np.full(3, 1e-6))
    base = render(scene, CAM, R, t, _light(None, earth), quality="fast").radiance
    img = render(scene, CAM, R, t, _light(stars, earth), quality="fast").radiance
    changed = np.argwhere((img != base).any(axis=2))
    d = R @ (R_BODY_FROM_ECI @ outside)
    u, v = CAM.fx * d[0] / d[2] + CAM.cx, CAM.fy * d[1] / d[2] + CAM.cy
    assert 0 <= u < W - 1 and 0 <= v < H - 1
    assert changed.tolist() == [[math.floor(v + 0.5), math.floor(u + 0.5)]]


def test_catalogue_csv(tmp_path):
    p = tmp_path / "cat.csv"
    p.write_text("name,ra_deg,dec_deg,v_mag\nSirius,101.2872,-16.7161,-1.46\nfaint,10,20,8.0\n")
    cat = StarField.from_csv(p, limit_mag=7.0)
    assert len(cat) == 1
    ra, dec = math.radians(101.2872), math.radians(-16.7161)
    assert np.allclose(cat.dirs_eci[0], [math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])
    assert cat.irradiance_W_m2[0] == pytest.approx(SOLAR_CONSTANT_W_M2 * 10 ** (-0.4 * (-1.46 - SUN_V_MAG)))
    (tmp_path / "bad.csv").write_text("ra,dec\n1,2\n")
    with pytest.raises(ValueError, match="ra_deg, dec_deg, v_mag"):
        StarField.from_csv(tmp_path / "bad.csv")
    (tmp_path / "nan.csv").write_text("ra_deg,dec_deg,v_mag\n1,x,3\n")
    with pytest.raises(ValueError, match="line 2"):
        StarField.from_csv(tmp_path / "nan.csv")
    with pytest.raises(ValueError, match="cannot read"):
        StarField.from_csv(tmp_path / "missing.csv")
