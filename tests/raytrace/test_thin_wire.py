"""A wire thinner than a pixel is drawn along its whole length, with the right brightness.

Scene: a long cylinder of radius r = 0.15 px footprint (diameter 0.3 px), tilted 7° in the
image plane so that it crosses pixel rows at every phase, lit by the Sun from the camera's
direction. Its radiance at a point whose normal is θ from the view direction is ρ E cos θ / π;
over its projected width (x = r sin θ) that integrates to ∫ ρ E cos θ / π · r cos θ dθ =
ρ E r / 2, so each image column it crosses (a length of 1 / cos 7° px) holds, summed over its
rows, ρ E r / (2 p cos 7°) in radiance × pixels (p the pixel footprint).

Pixel centres miss such a wire almost everywhere (a handful of mask pixels), and the pixel
corners find it only where it crosses one: ``fast`` without the sliver test (the projection of
a triangle narrower than a pixel in front of the centre's surface marks the pixel as an edge)
left 4 of 140 columns empty, a wire broken in dashes that flickers along a sequence.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render

W, H, F = 160, 120, 200.0
Z = 10.0
P = Z / F  # pixel footprint [m]
R_WIRE = 0.15 * P
TILT = math.radians(7.0)
ALBEDO = 0.8


@pytest.fixture(scope="module")
def wire_scene():
    wire = trimesh.creation.cylinder(radius=R_WIRE, height=3 * W * P, sections=24)
    wire.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))  # along x
    wire.apply_transform(trimesh.transformations.rotation_matrix(TILT, (0, 0, 1)))
    return Scene(TargetModel("wire", (Component("wire", wire, "white_paint", "bus", 1.0, albedo=(ALBEDO,) * 3),)))


@pytest.mark.parametrize("quality, samples, lo, hi", [("fast", None, 0.4, 1.8), ("balanced", 16, 0.7, 1.35)])
def test_a_wire_thinner_than_a_pixel_is_unbroken_and_as_bright_as_its_integral(wire_scene, quality, samples, lo, hi):
    light = Lighting(sun_dir_body=(0.0, 0.0, -1.0))  # from the camera's side
    cam = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)
    frame = render(wire_scene, cam, np.eye(3), np.array([0.0, 0.0, Z]), light, quality=quality, samples=samples,
                   seed=1)
    assert (frame.geometry.instance > 0).sum() < 0.5 * W  # the centres alone would miss most of it
    expect = ALBEDO * light.sun_irradiance_W_m2 * R_WIRE / 2 / P / math.cos(TILT)
    col = frame.radiance.astype(np.float64).mean(axis=2).sum(axis=0)[10:-10] / expect
    assert col.min() > lo, f"{quality}: the wire is broken (column {np.argmin(col) + 10} holds {col.min():.2f})"
    assert np.median(col) == pytest.approx(1.0, abs=0.05)
    assert col.mean() == pytest.approx(1.0, abs=0.03)
    assert col.max() < hi
