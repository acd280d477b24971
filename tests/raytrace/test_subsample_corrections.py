"""Edge sub-samples take the gather corrections of the pixel centres around them on their own
surface, interpolated bilinearly (raytrace._edges.interpolate_rows_into)."""

from __future__ import annotations

import numpy as np

from raytrace import _edges
from raytrace.camera import Camera

H, W = 4, 6


def _plane(parts):
    """Pixel centres of a plane z = 10 m facing the camera, 0.01 m per pixel; ``parts`` (H, W)
    the part id + 1 of every pixel."""
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    P_c = np.column_stack([0.01 * uu.ravel(), 0.01 * vv.ravel(), np.full(H * W, 10.0)])
    N_c = np.tile([0.0, 0.0, -1.0], (H * W, 1))
    foot = np.full(H * W, 0.01)
    return P_c, N_c, foot, np.arange(H * W, dtype=np.int32), parts.ravel().astype(np.uint16)


FX = FY = 1000.0
CX, CY = 2.5, 1.5


def _interp(uf, vf, comp, parts, A, B, min_found=1):
    """A and B interpolated at sub-samples on image points (uf, vf) of parts ``comp``; the
    camera looks along +z (R = I), so the ray through (uf, vf) is ((uf − cx)/fx, (vf − cy)/fy, 1)."""
    P_c, N_c, foot, row_of_pixel, inst = _plane(parts)
    D = np.column_stack([(uf - CX) / FX, (vf - CY) / FY, np.ones(len(uf))])
    P = np.column_stack([0.01 * uf, 0.01 * vf, np.full(len(uf), 10.0)])
    NS = np.tile([0.0, 0.0, -1.0], (len(uf), 1))
    outA = np.zeros((len(uf), 3))
    outB = np.zeros((len(uf), 3))
    added = np.empty(len(uf), dtype=np.bool_)
    _edges.interpolate_rows_into(np.arange(len(uf), dtype=np.int64), D, np.eye(3), FX, FY, CX, CY,
                                 Camera().lens_arrays()[0], W, H, comp, P, NS,
                                 row_of_pixel, inst, P_c, N_c, foot, A, B, min_found, outA, outB, added)
    return outA, outB, added


def test_interpolated_corrections_reproduce_a_linear_residual_at_any_sub_pixel_position():
    rng = np.random.default_rng(3)
    parts = np.ones((H, W), dtype=int)
    n = 500
    uf = rng.uniform(0.0, W - 1.0, n)
    vf = rng.uniform(0.0, H - 1.0, n)
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    A = np.column_stack([1.0 + 0.2 * uu.ravel() - 0.3 * vv.ravel()] * 3)  # a linear residual
    outA, outB, added = _interp(uf, vf, np.zeros(n, dtype=np.int64), parts, A, 2.0 * A, min_found=4)
    assert added.all()
    want = 1.0 + 0.2 * uf - 0.3 * vf
    np.testing.assert_allclose(outA[:, 0], want, rtol=1e-9)
    np.testing.assert_allclose(outB[:, 2], 2.0 * want, rtol=1e-9)


def test_centres_on_another_part_are_left_out_and_the_weights_renormalised():
    parts = np.ones((H, W), dtype=int)
    parts[:, 3:] = 2  # part 1 from column 3
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    A = np.column_stack([uu.ravel(), vv.ravel(), np.ones(H * W)])
    # a sub-sample of part 0 at (2.25, 1.5), between the centres of columns 2 (part 0) and
    # 3 (part 1): columns 2's two centres, rows 1 and 2, half each
    outA, _, added = _interp(np.array([2.25]), np.array([1.5]), np.array([0]), parts, A, A)
    np.testing.assert_allclose(outA[0], [2.0, 1.5, 1.0], rtol=1e-12)
    assert added[0]
    # a sub-sample of a part none of the four centres lies on gets nothing
    outA, _, added = _interp(np.array([2.25]), np.array([1.5]), np.array([4]), parts, A, A)
    assert np.all(outA == 0.0) and not added[0]


def test_with_four_required_a_sub_sample_beside_another_part_is_left_to_its_own_gather():
    """Quality.own_at_boundary: only sub-samples whose four surrounding centres all lie on
    their surface take the interpolated corrections; the others are reported not added and
    keep their values."""
    parts = np.ones((H, W), dtype=int)
    parts[:, 3:] = 2  # part 1 from column 3
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    A = np.column_stack([uu.ravel(), vv.ravel(), np.ones(H * W)])
    uf = np.array([2.25, 1.5, 0.75, 3.5])  # beside part 1; inside part 0 (twice); on part 1
    vf = np.array([1.5, 1.5, 2.25, 1.25])
    comp = np.array([0, 0, 0, 1])
    outA, _, added = _interp(uf, vf, comp, parts, A, A, min_found=4)
    np.testing.assert_array_equal(added, [False, True, True, True])
    assert np.all(outA[0] == 0.0)
    np.testing.assert_allclose(outA[1:, :2], np.column_stack([uf[1:], vf[1:]]), rtol=1e-12)
    # with one centre required, the first is extrapolated from column 2 as before
    outA, _, added = _interp(uf, vf, comp, parts, A, A, min_found=1)
    assert added.all()
    np.testing.assert_allclose(outA[0], [2.0, 1.5, 1.0], rtol=1e-12)
