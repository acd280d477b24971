"""The radiance split by source (``render(..., parts=True)``, the ``light`` modality).

Oracles:
* the parts sum to the ``hdr`` radiance (the same render's, and one rendered without parts,
  which must be the same bits);
* without Earth in the lighting the Earth part is exactly 0;
* a geometric shadow found by shadow rays cast with the Scene (Embree, not the shading code):
  no Sun part there; where lit, the Sun part of a Lambertian plate is the closed form
  ρ/π · E · cos θ, while the total also holds the light the other plate reflects onto it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.ndimage import binary_erosion, minimum_filter

from orbit.pose import look_at
from raytrace import _light_parts
from raytrace.camera import Camera
from raytrace.lighting import Earth, Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.stars import StarField
from raytrace.shade import render

W, H, F = 64, 48, 60.0
CAM = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)
RHO_A, RHO_B, E_SUN = 0.8, 0.6, 1000.0
SUN = np.array([-0.6, 0.0, 0.8])  # from the −x side: plate B shades plate A where x < 1.5


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@pytest.fixture(scope="module")
def plates():
    # A: horizontal, x in [0, 2], y in [-1, 1], top face at z = 0; B: vertical at x in
    # [-0.02, 0], y in [-1, 1], z in [0, 2], facing +x. Thin closed boxes, pure Lambertian.
    a = trimesh.creation.box((2.0, 2.0, 0.02))
    a.apply_translation((1.0, 0.0, -0.01))
    b = trimesh.creation.box((0.02, 2.0, 2.0))
    b.apply_translation((-0.01, 0.0, 1.0))
    return Scene(TargetModel("plates", (Component("a", a, "white_paint", "bus", 1.0, albedo=(RHO_A,) * 3),
                                        Component("b", b, "white_paint", "bus", 1.0, albedo=(RHO_B,) * 3))))


def _pose(rho):
    rho = np.asarray(rho, dtype=float)
    R = look_at(rho)
    return R, -R @ rho


def _parts(frame):
    return {name: frame.light_parts[..., 3 * k:3 * k + 3] for k, name in enumerate(_light_parts.PARTS)}


def _all_lights():
    # Earth behind the plates as the camera sees them (its disc fills the lower background),
    # lighting A's top face near its horizon; an ambient sky; the Sun
    return Lighting(sun_dir_body=_unit([0.3, -0.5, 0.8]), sun_irradiance_W_m2=1361.0,
                    earth=Earth(tuple(_unit([-0.8, 0.55, -0.25])), 6_778_137.0, albedo=0.3, texture="procedural"),
                    ambient_radiance_W_m2_sr=2.0)


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8), ("balanced", 32), ("reference", 16)])
def test_parts_sum_to_the_radiance_at_every_preset(plates, quality, samples):
    R, t = _pose([3.5, -2.5, 3.0])
    light = _all_lights()
    plain = render(plates, CAM, R, t, light, quality=quality, samples=samples, seed=3)
    frame = render(plates, CAM, R, t, light, quality=quality, samples=samples, seed=3, parts=True)
    assert plain.light_parts is None
    assert np.array_equal(plain.radiance, frame.radiance)  # asking for the parts changes nothing
    lp = frame.light_parts
    assert lp.dtype == np.float32 and lp.shape == (H, W, 12)
    assert np.all(np.isfinite(lp)) and lp.min() >= 0.0
    total = lp.reshape(H, W, 4, 3).astype(np.float64).sum(axis=2)
    rad = frame.radiance.astype(np.float64)
    # float32 rounding of four non-negative terms: a few ulp of the sum
    assert np.all(np.abs(total - rad) <= 4 * np.finfo(np.float32).eps * rad + 1e-30)
    p = _parts(frame)
    target = frame.geometry.mask
    background = binary_erosion(~target, iterations=2, border_value=1)
    for name in _light_parts.PARTS:  # every source contributes on the target
        assert p[name][target].mean() > 0.0, name
    # the Earth disc drawn behind the plates is Earth's light, and nothing else is there
    assert (frame.radiance[background] > 0).any()
    assert np.array_equal(p["earth"][background], frame.radiance[background])


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8)])
def test_without_earth_the_earth_part_is_zero(plates, quality, samples):
    R, t = _pose([3.5, -2.5, 3.0])
    light = Lighting(sun_dir_body=_unit([0.3, -0.5, 0.8]), sun_irradiance_W_m2=1361.0, ambient_radiance_W_m2_sr=3.0,
                     stars=StarField.procedural(7.0, seed=0), R_body_from_eci=np.eye(3))
    frame = render(plates, CAM, R, t, light, quality=quality, samples=samples, parts=True)
    p = _parts(frame)
    assert not p["earth"].any()
    m = frame.geometry.mask
    assert p["sky"][m].mean() > 0.0 and p["sun"][m].mean() > 0.0 and p["inter"][m].mean() > 0.0
    # the stars, drawn in the background, are the sky's
    stars = binary_erosion(~m, iterations=2, border_value=1) & (frame.radiance > 0).any(axis=2)
    assert stars.sum() >= 3
    assert np.array_equal(p["sky"][stars], frame.radiance[stars]) and not p["sun"][stars].any()


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8)])
def test_sun_part_is_zero_in_shadow_and_the_lambertian_closed_form_where_lit(plates, quality, samples):
    R, t = _pose([3.0, -3.0, 3.5])
    light = Lighting(sun_dir_body=SUN, sun_irradiance_W_m2=E_SUN, ambient_radiance_W_m2_sr=1.0)
    frame = render(plates, CAM, R, t, light, quality=quality, samples=samples, parts=True)
    geo = frame.geometry
    on_a = geo.instance == 1
    # each pixel centre of plate A back-projected from its depth, and its shadow ray cast with
    # the Scene (Embree), independently of the renderer's shading
    v, u = np.nonzero(on_a)
    z = geo.depth_m[v, u].astype(np.float64)
    p_cam = np.stack([(u - CAM.cx) / CAM.fx * z, (v - CAM.cy) / CAM.fy * z, z], axis=1)
    p_body = (p_cam - t) @ R  # R^T (p_cam - t)
    top = np.abs(p_body[:, 2]) < 1e-4  # A's top face (not its 2 cm rim)
    assert top.mean() > 0.9
    v, u, p_body = v[top], u[top], p_body[top]
    o = (p_body + [0.0, 0.0, 1e-4]).astype(np.float32)
    blocked = plates.occluded(o, np.broadcast_to(SUN.astype(np.float32), o.shape).copy())
    shadow = np.zeros((H, W), dtype=bool)
    lit = np.zeros((H, W), dtype=bool)
    shadow[v[blocked], u[blocked]] = True
    lit[v[~blocked], u[~blocked]] = True
    # pixels whose whole 3 × 3 neighbourhood is in one state (a pixel is an area)
    deep_shadow = minimum_filter(shadow, size=3, mode="constant")
    deep_lit = minimum_filter(lit, size=3, mode="constant")
    assert deep_shadow.sum() > 30 and deep_lit.sum() > 30
    p = _parts(frame)
    assert not p["sun"][deep_shadow].any()
    assert (frame.radiance[deep_shadow] > 0).all()  # the sky and plate B still light it
    # the closed form on the lit part of A: ρ/π · E · cos θ (θ between A's normal +z and the Sun)
    expect = RHO_A / math.pi * E_SUN * SUN[2]
    # (float32; ``balanced`` anti-aliases a few of these pixels, whose parts are shared out by
    # their neighbourhood's proportions: measured 6e-5 off)
    np.testing.assert_allclose(p["sun"][deep_lit], expect, rtol=1e-5 if quality == "fast" else 1e-4)
    # and the total there is more: the sky, and B's light reflected onto A
    assert (frame.radiance[deep_lit][:, 0] > expect * 1.001).all()
    assert (p["inter"][deep_lit] > 0).all() and (p["sky"][deep_lit] > 0).all()


def test_bad_parts_argument_is_a_clear_error(plates):
    R, t = _pose([3.5, -2.5, 3.0])
    with pytest.raises(ValueError, match="parts must be True or False"):
        render(plates, CAM, R, t, Lighting(sun_dir_body=SUN), quality="fast", parts="yes")


def test_light_modality_files_name_their_layers_and_sum_to_hdr(tmp_path, capsys):
    import OpenImageIO as oiio

    from raytrace import files as F
    from tests.cli_helpers import run_main
    seq = tmp_path / "seq"
    assert run_main("--target", "cassini", "--pattern", "spiral", "--frames", "1", "--width", "64", "--height", "48",
                    "--quality", "fast", "--ambient-W-m2-sr", "1", "--quiet", "--workers", "1",
                    "--modalities", "mask,hdr,light", "--out", seq) == 0
    import json
    label = json.loads((seq / "labels.json").read_text())[0]
    assert label["files"]["light"] == "light/000000.exr"
    path = str(seq / label["files"]["light"])
    assert oiio.ImageInput.open(path).spec().channelnames == _light_parts.CHANNELS
    light = F.read_image(path)
    hdr = F.read_image(str(seq / label["files"]["hdr"])).astype(np.float64)
    assert light.dtype == np.float32 and light.shape == hdr.shape[:2] + (12,)
    total = light.reshape(*hdr.shape[:2], 4, 3).astype(np.float64).sum(axis=2)
    assert np.all(np.abs(total - hdr) <= 4 * np.finfo(np.float32).eps * hdr)
    mask = F.read_image(str(seq / label["files"]["mask"])) > 0
    assert mask.any() and light[mask].max() > 0


def test_each_part_is_that_light_rendered_alone(plates):
    """Superposition: the frame is linear in its lights, so each part of the frame lit by all
    three must be the same part of the frame lit by that light alone (where the others are
    0), and the inter-reflected part the sum of the three frames' (``fast``: no noise)."""
    R, t = _pose([3.5, -2.5, 3.0])
    sun, earth_dir = _unit([0.3, -0.5, 0.8]), tuple(_unit([-0.8, 0.55, -0.25]))
    lit_earth = Earth(earth_dir, 6_778_137.0, albedo=0.3, texture="procedural")
    dark_earth = Earth(earth_dir, 6_778_137.0, albedo=0.0)  # hides the same sky, sends nothing
    lights = {"all": Lighting(sun_dir_body=sun, earth=lit_earth, ambient_radiance_W_m2_sr=2.0),
              "sun": Lighting(sun_dir_body=sun),
              "earth": Lighting(sun_dir_body=sun, shadow_fraction=0.0, earth=lit_earth),  # Earth's day side lit
              "sky": Lighting(sun_dir_body=sun, shadow_fraction=0.0, earth=dark_earth, ambient_radiance_W_m2_sr=2.0)}
    p = {k: _parts(render(plates, CAM, R, t, light, quality="fast", parts=True)) for k, light in lights.items()}
    frame_mask = render(plates, CAM, R, t, lights["sun"], quality="fast").geometry.mask
    m = binary_erosion(frame_mask, iterations=2)
    for alone in ("sun", "earth", "sky"):
        for other in ("sun", "earth", "sky"):
            if other != alone:  # a light that is off contributes nothing (the coarse sky table: < 0.2 %)
                assert p[alone][other][m].max() <= 2e-3 * p[alone][alone][m].mean(), (alone, other)
        got, want = p["all"][alone][m].astype(float), p[alone][alone][m].astype(float)
        rel = np.abs(got - want) / np.maximum(want, 1e-3 * want.mean())  # the Sun's is 0 in shadow
        # (the worst pixels are anti-aliased ones, shared out by their neighbourhood)
        assert np.median(rel) < 1e-3 and np.percentile(rel, 90) < 1e-2, (alone, np.median(rel))
        assert got.mean() == pytest.approx(want.mean(), rel=5e-3), alone
    inter = sum(p[k]["inter"][m].astype(float) for k in ("sun", "earth", "sky"))
    rel = np.abs(p["all"]["inter"][m] - inter) / inter
    assert np.median(rel) < 1e-3 and np.percentile(rel, 90) < 1e-2


def test_channel_names_must_name_every_channel(tmp_path):
    from raytrace import files as F
    with pytest.raises(ValueError, match="channel_names must name the 12 channels, got 3 names"):
        F.write_image(str(tmp_path / "x.exr"), np.zeros((2, 2, 12), np.float32), channel_names=("a", "b", "c"))
    assert not (tmp_path / "x.exr").exists()
