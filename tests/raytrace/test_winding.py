"""A closed mesh written with the opposite winding convention renders as the same object.

The physics does not depend on the order of a triangle's vertices: a cube lit by the Sun and a
sky, resting on a plate, must give the same image whether its faces are wound outwards
(counter-clockwise seen from outside, as trimesh and glTF write them) or inwards (clockwise, as
some exporters write them). The radiance cache keeps only the front side of a closed shell's
faces; it took "closed" from ``is_watertight`` alone, so an inside-out cube kept the side
facing its interior and lost the light the cube and the plate exchange: ``fast`` was 11.8 %
(RMS) off the correctly wound scene on the frame below, ``balanced``-16 2.1 %.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene, closed_outward
from raytrace.shade import render

W, H, F = 160, 120, 200.0
CAM = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)
LIGHT = Lighting(sun_dir_body=tuple(np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])),
                 ambient_radiance_W_m2_sr=1.0)


def _reversed(mesh):
    return trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)


def _signed_volume(mesh) -> float:
    T = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->", T[:, 0], np.cross(T[:, 1], T[:, 2])) / 6.0)


def _cube(centre=(0.0, 0.0, 0.5)):
    m = trimesh.creation.box((1.0, 1.0, 1.0))
    m.apply_translation(centre)
    return m


def _plate():
    m = trimesh.creation.box((4.0, 4.0, 0.05))
    m.apply_translation((0.0, 0.0, -0.025))
    return m


def test_closed_outward_needs_a_closed_outward_wound_shell_per_body():
    cube = _cube()
    assert closed_outward(cube)
    assert not closed_outward(_reversed(cube))  # inside out
    two = trimesh.util.concatenate([_cube((-1.0, 0.0, 0.5)), _cube((1.0, 0.0, 0.5))])
    assert closed_outward(two)
    one_inside_out = trimesh.util.concatenate([_cube((-1.0, 0.0, 0.5)), _reversed(_cube((1.0, 0.0, 0.5)))])
    assert one_inside_out.is_watertight and one_inside_out.is_winding_consistent
    assert _signed_volume(one_inside_out) == pytest.approx(0.0, abs=1e-9)  # the total cannot tell
    assert not closed_outward(one_inside_out)
    bigger = trimesh.util.concatenate([trimesh.creation.box((2.0, 2.0, 2.0)), _reversed(_cube((5.0, 0.0, 0.0)))])
    assert _signed_volume(bigger) == pytest.approx(7.0) and not closed_outward(bigger)  # nor can its sign
    flipped_one = cube.copy()
    flipped_one.faces[0] = flipped_one.faces[0, ::-1]
    assert not closed_outward(flipped_one)  # inconsistent winding
    open_box = trimesh.Trimesh(cube.vertices, cube.faces[2:], process=False)
    assert not closed_outward(open_box)
    assert not closed_outward(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False))


def _scene(cube) -> Scene:
    return Scene(TargetModel("cube_on_plate", (Component("cube", cube, "white_paint", "bus", 1.0, albedo=(0.7,) * 3),
                                               Component("plate", _plate(), "white_paint", "bus", 1.0,
                                                         albedo=(0.7,) * 3))))


@pytest.mark.parametrize("quality, samples, bound", [("fast", None, 0.01), ("balanced", 16, 0.01)])
def test_an_inside_out_cube_renders_as_the_outward_wound_one(quality, samples, bound):
    rho = np.array([3.0, -4.0, 3.0])
    R = look_at(rho)
    t = -R @ rho
    out = _scene(_cube())
    inside_out = _scene(_reversed(_cube()))
    assert list(out.two_sided) == [False, False] and list(inside_out.two_sided) == [True, False]
    a = render(out, CAM, R, t, LIGHT, quality=quality, samples=samples, seed=3)
    b = render(inside_out, CAM, R, t, LIGHT, quality=quality, samples=samples, seed=3)
    assert np.array_equal(a.geometry.instance, b.geometry.instance)
    np.testing.assert_array_equal(a.geometry.normal_cam, b.geometry.normal_cam)  # turned to face the camera
    m = a.geometry.instance > 0
    A, B = a.radiance[m].astype(np.float64), b.radiance[m].astype(np.float64)
    assert m.sum() > 3000
    err = float(np.sqrt(((A - B) ** 2).sum() / (A ** 2).sum()))
    assert err < bound, f"{quality}: inside-out cube {100 * err:.2f} % (RMS) off the outward-wound one"
    # the cube's faces and the plate beside it: the light they exchange is there in both
    on_cube = a.geometry.instance == 1
    ratio = b.radiance[on_cube].sum() / a.radiance[on_cube].sum()
    assert ratio == pytest.approx(1.0, abs=0.01)
