"""A pixel's radiance is the mean over the pixel's area, not its centre's value
(``Quality.box_grid``): the outer rims of a penumbra, where the visible fraction of the solar
disc curves, against numerical integration.

Scene: a Lambertian floor (albedo 0.5, z ≤ 0) under a black lid (albedo 0, z = h), whose straight
edge at x = e casts a penumbra of the 0.53° Sun across the floor. Nothing else sends light to the
floor (the lid is black, the sky empty), so the floor's radiance is
L = ρ/π · E · cos θ_sun · V(x), V the visible fraction of the solar disc from the floor point.

Oracle: V(x) from a 200 × 200 grid over the solar disc, each direction tested against the lid
analytically; the pixel's area mean from 12 × 12 points per pixel, each intersected with the
floor plane analytically. Neither uses the renderer.

Statistic: the slope of (rendered − centre value) against (area mean − centre value) over the
floor pixels where the two oracles differ by more than 1 % of the sunlit radiance, weighted by
1/(V(1 − V) + 0.01) (the solar-disc sampling noise is least at the penumbra's rims, where the
profile curves most). An image of area means has slope 1; one of centre values, 0. Pixels that
are anti-aliased (where the penumbra's middle crosses a pixel corner) are area means either way,
which is why the centre-valued control comes out above 0.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.lighting import SUN_ANGULAR_DIAMETER_RAD, Lighting
from raytrace.model import Component, TargetModel
from raytrace.presets import quality_preset
from raytrace.scene import Scene
from raytrace.shade import render

W, H, F = 160, 120, 200.0
CAM = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)
H_LID = 2.0  # lid height [m]
THETA = math.radians(30.0)  # Sun's angle from the zenith, tilted towards +x
SUN = np.array([math.sin(THETA), 0.0, math.cos(THETA)])
EDGE_X = H_LID * math.tan(THETA)  # the lid spans x ∈ [EDGE_X − 4, EDGE_X]: the shadow's edge at x = 0
RHO = np.array([1.0, 0.3, 0.9])  # camera position (looking at the origin), below the lid
E_SUN, ALBEDO = 1000.0, 0.5
L_SUNLIT = ALBEDO / math.pi * E_SUN * math.cos(THETA)


@pytest.fixture(scope="module")
def penumbra():
    floor = trimesh.creation.box((3.0, 3.0, 0.02))
    floor.apply_translation((0.0, 0.0, -0.01))
    lid = trimesh.creation.box((4.0, 6.0, 0.02))
    lid.apply_translation((EDGE_X - 2.0, 0.0, H_LID + 0.01))
    scene = Scene(TargetModel("penumbra", (Component("floor", floor, "white_paint", "bus", 1.0,
                                                     albedo=(ALBEDO,) * 3),
                                           Component("lid", lid, "white_paint", "bus", 1.0, albedo=(0.0,) * 3))))
    R = look_at(RHO)
    return scene, R, -R @ RHO, _oracles(R)


def _floor_points(R, u, v):
    """Floor point (z = 0) seen through image point (u, v), and the ray parameter."""
    d = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1) @ R  # body frame
    t = -RHO[2] / d[..., 2]
    return RHO + t[..., None] * d, t


def _visible_fraction_table():
    """V(x) on the floor from a grid over the solar disc (it depends on x alone there)."""
    alpha = SUN_ANGULAR_DIAMETER_RAD / 2
    e1 = np.array([math.cos(THETA), 0.0, -math.sin(THETA)])
    e2 = np.array([0.0, 1.0, 0.0])
    n = 200
    a, b = np.meshgrid((np.arange(n) + 0.5) / n * 2 - 1, (np.arange(n) + 0.5) / n * 2 - 1)
    inside = a * a + b * b <= 1.0
    dirs = SUN + alpha * (a[inside][:, None] * e1 + b[inside][:, None] * e2)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    xs = np.linspace(-1.5, 1.5, 30001)
    # the ray from floor point x along a direction crosses the lid's plane at x + s: blocked
    # where that lies in [EDGE_X − 4, EDGE_X], i.e. s in [EDGE_X − 4 − x, EDGE_X − x]
    s = np.sort(H_LID * dirs[:, 0] / dirs[:, 2])
    blocked = np.searchsorted(s, EDGE_X - xs, "right") - np.searchsorted(s, EDGE_X - 4.0 - xs, "left")
    return xs, 1.0 - blocked / s.size


def _oracles(R):
    """Centre values and area means of the floor's radiance per pixel, and the floor mask."""
    xs, V = _visible_fraction_table()
    v, u = np.mgrid[0:H, 0:W].astype(float)
    P, t = _floor_points(R, u, v)
    on_floor = (t > 0) & (np.abs(P[..., 0]) < 1.4) & (np.abs(P[..., 1]) < 1.4)
    centre = L_SUNLIT * np.interp(P[..., 0], xs, V)
    m = 12
    offsets = (np.arange(m) + 0.5) / m - 0.5
    area = np.zeros((H, W))
    for dv in offsets:
        for du in offsets:
            area += np.interp(_floor_points(R, u + du, v + dv)[0][..., 0], xs, V)
    return centre, L_SUNLIT * area / (m * m), on_floor


def _slope(penumbra, samples, seeds):
    scene, R, t, (centre, area, on_floor) = penumbra
    d = area - centre
    light = Lighting(sun_dir_body=SUN, sun_irradiance_W_m2=E_SUN)
    num = den = 0.0
    for seed in seeds:
        frame = render(scene, CAM, R, t, light, quality="balanced", samples=samples, seed=seed)
        sel = on_floor & (frame.geometry.instance == 1) & (np.abs(d) > 0.01 * L_SUNLIT)
        assert sel.sum() > 150  # the penumbra's pixels
        r = frame.radiance[..., 0].astype(float)
        vb = area / L_SUNLIT
        w = 1.0 / (vb * (1.0 - vb) + 0.01)
        num += ((r - centre) * d * w)[sel].sum()
        den += (d * d * w)[sel].sum()
    return num / den


def test_pixels_carry_the_area_mean_of_a_penumbra(penumbra):
    assert quality_preset("balanced", 32).box_grid >= 2
    slope = _slope(penumbra, 32, (1, 2, 3, 4, 5))  # one seed's slope: 0.84–1.24 (σ ≈ 0.2)
    assert 0.7 < slope < 1.3, slope


def test_without_area_means_the_statistic_sees_centre_values(penumbra):
    """The control: ``balanced``-16 shades the pixels that are not anti-aliased at their
    centres, so the statistic can tell the two apart (measured: 0.18–0.42 per seed)."""
    assert quality_preset("balanced", 16).box_grid == 0
    assert _slope(penumbra, 16, (1, 2, 3)) < 0.5


def test_area_means_are_reproducible_from_the_seed(penumbra):
    scene, R, t, _ = penumbra
    light = Lighting(sun_dir_body=SUN, sun_irradiance_W_m2=E_SUN)
    a, b = (render(scene, CAM, R, t, light, quality="balanced", samples=32, seed=9).radiance for _ in range(2))
    assert a.tobytes() == b.tobytes()
