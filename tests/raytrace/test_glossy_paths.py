"""Paths through glossy parts in ``balanced``, against the path tracer.

A gold foil plate (2 m × 2 m, GGX α = 0.32) lies in the plane z = 0; a white wall stands on its
edge x = 1 m, facing it, lit by the Sun from −x (just below the plate's plane, so the plate
itself gets no sunlight and no glint). All the light on the plate and all the indirect light
on the wall then go through a glossy reflection: the plate shows the wall mirrored, and the wall
gets back its own light off the plate. Both are compared with ``reference`` (the path tracer, a
separate estimator that samples the full BRDF at every bounce).

Before the final gather continued its paths along the lobe of a glossy hit, it spread the
plate's reflection uniformly (specular albedo × irradiance / π) and the wall came out 3.0 %
(red) too bright; tracing the lobe rays' hits without continuing the paths at glossy vertices
made the plate 2.2 % too bright (the wall's traced irradiance off the plate was 2.6× the
cache's there)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.ndimage import binary_erosion

from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render


@pytest.fixture(scope="module")
def plate_and_wall():
    plate = trimesh.creation.box((2.0, 2.0, 0.02))
    plate.apply_translation((0.0, 0.0, -0.01))
    wall = trimesh.creation.box((0.02, 2.0, 2.0))
    wall.apply_translation((1.01, 0.0, 1.0))
    sc = Scene(TargetModel("plates", (Component("plate", plate, "gold_mli", "bus", 1.0),
                                      Component("wall", wall, "white_paint", "bus", 1.0))))
    sun = np.array([-1.0, 0.3, -0.05])
    light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)))
    W, H, f = 96, 72, 120.0
    cam = Camera(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
    eye = np.array([-3.0, -1.0, 2.5])
    R = look_at(eye)
    t = -R @ eye
    ref = sum(render(sc, cam, R, t, light, quality="reference", samples=512, seed=s).radiance.astype(np.float64)
              for s in (1, 2)) / 2
    return sc, cam, R, t, light, ref


@pytest.mark.parametrize("part, name", [(1, "plate"), (2, "wall")])
def test_glossy_reflection_in_balanced_matches_the_path_tracer(plate_and_wall, part, name):
    sc, cam, R, t, light, ref = plate_and_wall
    x = sum(render(sc, cam, R, t, light, quality="balanced", samples=32, seed=s).radiance.astype(np.float64)
            for s in (0, 7)) / 2
    inst = render(sc, cam, R, t, light, quality="fast").geometry.instance
    sel = binary_erosion(inst == part, iterations=2)  # away from the part's edges
    assert sel.sum() > 300
    ratio = x[sel].mean(axis=0) / ref[sel].mean(axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.01, err_msg=f"{name}: balanced / reference per channel")


def test_balanced_casts_no_mirror_ray_it_would_weight_by_zero(plate_and_wall, monkeypatch):
    """``balanced`` blends its mirror term from the mirror ray to E/π by t(α) and casts no
    mirror ray where t = 1 (the white wall, α = 0.5): the image must be bit for bit the one
    with every mirror ray cast (the two places compute t alike)."""
    from raytrace import _context

    sc, cam, R, t, light, _ref = plate_and_wall
    ctx = _context._Context(sc, light, {})
    assert ctx.mirror_weighted.tolist() == [True, False]  # gold α = 0.32 is cast, paint is not
    a = render(sc, cam, R, t, light, quality="balanced", samples=8, seed=3).radiance
    init = _context._Context.__init__

    def every_ray(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.mirror_weighted = np.ones_like(self.mirror_weighted)

    monkeypatch.setattr(_context._Context, "__init__", every_ray)
    b = render(sc, cam, R, t, light, quality="balanced", samples=8, seed=3).radiance
    assert np.array_equal(a, b)
