"""Tests of camera pointing, projection and pose labels (docs/orbit.md, "Camera pointing and pose
labels")."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from orbit.attitude import TargetAttitude
from orbit.pose import (PoseLabels, blender_from_opencv, camera_matrix, intrinsics_from_focal,
                        look_at, pose_from_relative, pose_labels, project)
from orbit.rotations import (is_rotation, matrix_from_euler_zyx, matrix_from_quat, rot_z,
                             rotation_angle)

SETTINGS = settings(deadline=None, max_examples=150)
N_400KM = 1.1313666536110223e-3

directions = (st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array)
              .filter(lambda v: np.linalg.norm(v) > 0.1).map(lambda v: v / np.linalg.norm(v)))
positions = st.tuples(directions, st.floats(1e-3, 1e6)).map(lambda dr: dr[0] * dr[1])
quats = (st.tuples(*[st.floats(-1.0, 1.0)] * 4).map(np.array)
         .filter(lambda q: np.linalg.norm(q) > 0.1))


def test_spec_example():
    """Look-at worked by hand: ρ = [0, −30, 5] → R_cam_from_lvlh and t_cam = [0, 0, sqrt(925)]."""
    rho = np.array([0.0, -30.0, 5.0])
    R = look_at(rho)
    assert_allclose(R, [[1, 0, 0], [0, -0.16439899, -0.98639392], [0, 0.98639392, -0.16439899]],
                    atol=1e-8)
    R_cb, t_cam = pose_from_relative(rho, np.eye(3), R)
    assert_allclose(t_cam, [0.0, 0.0, 30.41381265], atol=1e-8)
    assert_allclose(R_cb, R, atol=0)


@SETTINGS
@given(positions, directions)
def test_look_at_properties(rho, up):
    R = look_at(rho, up_ref_lvlh=up)
    assert is_rotation(R, atol=1e-13)
    # boresight on the target centre
    assert_allclose(R @ (-rho / np.linalg.norm(rho)), [0.0, 0.0, 1.0], atol=1e-13)
    # the target projects to the principal point
    K = intrinsics_from_focal(0.05, 5e-6, 1024, 768)
    _, t_cam = pose_from_relative(rho, np.eye(3), R)
    assert_allclose(project(K, t_cam), [511.5, 383.5], atol=1e-6)
    # image up (−y_cam) leans towards u_ref and image x is horizontal
    parallel = np.linalg.norm(np.cross(up, R[2])) < 1e-6
    if not parallel:
        assert -R[1] @ up >= 0.0
        assert abs(R[0] @ up) < 1e-12
        # "as close as possible": −y_cam is the unit projection of u_ref orthogonal to ẑ_c
        u_perp = up - (up @ R[2]) * R[2]
        assert_allclose(-R[1], u_perp / np.linalg.norm(u_perp), atol=1e-9)


@pytest.mark.parametrize("rho", [[0.0, 0.0, 5.0], [0.0, 0.0, -12.0], [1e-8, 0.0, 40.0],
                                 [0.0, 2e-8, -3.0]])
def test_fallback_when_rho_is_along_the_up_reference(rho):
    """|u_ref × ẑ_c| < 1e-6 → up reference +y_LVLH."""
    rho = np.array(rho)
    R = look_at(rho)
    assert is_rotation(R, atol=1e-14)
    assert_allclose(R[2], -rho / np.linalg.norm(rho), atol=1e-15)
    assert -R[1] @ [0.0, 1.0, 0.0] > 0.999
    assert abs(R[0] @ [0.0, 1.0, 0.0]) < 1e-6


@pytest.mark.parametrize("angle", [1.01e-6, 2e-6, 1e-5, 1e-3])
def test_nearly_parallel_up_reference_stays_orthonormal(angle):
    """Just outside the fallback tolerance the projection of u_ref cancels heavily."""
    rho = 7.0 * np.array([np.sin(angle) * np.cos(0.3), np.sin(angle) * np.sin(0.3), -np.cos(angle)])
    R = look_at(rho)
    assert is_rotation(R, atol=1e-14)
    assert_allclose(R[2], -rho / np.linalg.norm(rho), atol=1e-15)
    assert -R[1] @ [0.0, 0.0, 1.0] > 0.0


def test_second_fallback_when_up_reference_is_along_track():
    R = look_at([0.0, -30.0, 0.0], up_ref_lvlh=[0.0, 1.0, 0.0])
    assert is_rotation(R, atol=1e-14)
    assert_allclose(R[2], [0.0, 1.0, 0.0], atol=1e-15)
    assert_allclose(-R[1], [1.0, 0.0, 0.0], atol=1e-15)


def test_fallback_applies_per_row():
    rho = np.array([[0.0, -30.0, 5.0], [0.0, 0.0, 8.0], [3.0, 1.0, 2.0]])
    R = look_at(rho)
    for k in range(3):
        assert_allclose(R[k], look_at(rho[k]), atol=0)
    assert_allclose(R[0], look_at([0.0, -30.0, 5.0]), atol=0)


@SETTINGS
@given(positions, st.floats(-np.pi, np.pi))
def test_roll_about_the_boresight(rho, roll):
    R0 = look_at(rho)
    R = look_at(rho, roll_rad=roll)
    assert_allclose(R, rot_z(roll) @ R0, atol=1e-15)
    assert_allclose(R[2], R0[2], atol=1e-15)  # boresight unchanged
    assert abs(rotation_angle(R, R0) - abs(roll)) < 1e-7
    assert is_rotation(R, atol=1e-13)


def test_roll_vectorised():
    rho = np.array([[0.0, -30.0, 5.0], [10.0, 1.0, 2.0]])
    roll = np.array([0.1, -0.4])
    R = look_at(rho, roll_rad=roll)
    for k in range(2):
        assert_allclose(R[k], look_at(rho[k], roll_rad=roll[k]), atol=0)


@SETTINGS
@given(positions, quats, st.lists(st.tuples(*[st.floats(-10.0, 10.0)] * 3), min_size=1, max_size=8))
def test_pose_from_relative_maps_body_points(rho, q, points):
    """p_cam = R p_body + t equals the composition body → LVLH → shift to camera → camera axes."""
    R_lvlh_from_body = matrix_from_quat(q)
    R_cam_from_lvlh = look_at(rho)
    R, t = pose_from_relative(rho, R_lvlh_from_body, R_cam_from_lvlh)
    p_body = np.array(points)
    p_cam = p_body @ R.T + t
    for p, pc in zip(p_body, p_cam):
        p_lvlh = R_lvlh_from_body @ p  # point relative to the target centre, LVLH
        expected = R_cam_from_lvlh @ (p_lvlh - rho)  # relative to the camera, camera axes
        assert_allclose(pc, expected, atol=1e-9 * max(1.0, np.linalg.norm(rho)))
    assert is_rotation(R, atol=1e-13)


def test_pose_from_relative_vectorised_with_attitude_law():
    t = np.linspace(0.0, 2000.0, 25)
    rho = np.column_stack([50 * np.cos(N_400KM * t), -100 * np.sin(N_400KM * t), 20 + 0 * t])
    att = TargetAttitude("spin", matrix_from_euler_zyx(0.2, 0.1, -0.3), spin_rate_rad_s=0.03)
    R_lb = att.R_lvlh_from_body(t, N_400KM)
    R_cl = look_at(rho)
    R, tc = pose_from_relative(rho, R_lb, R_cl)
    assert R.shape == (25, 3, 3) and tc.shape == (25, 3)
    for k in (0, 7, 24):
        Rk, tk = pose_from_relative(rho[k], R_lb[k], R_cl[k])
        assert_allclose(R[k], Rk, atol=0)
        assert_allclose(tc[k], tk, atol=0)
    assert_allclose(tc[:, :2], 0.0, atol=1e-12)
    assert_allclose(tc[:, 2], np.linalg.norm(rho, axis=1), rtol=1e-15)


def test_pose_labels_sequence():
    t = np.linspace(0.0, 3000.0, 300)
    rho = np.column_stack([40 * np.sin(N_400KM * t), 80 * np.cos(N_400KM * t), 10 + 0 * t])
    att = TargetAttitude("tumble", matrix_from_euler_zyx(2.5, 0.3, -2.0),
                         omega0_body_rad_s=(0.01, 0.02, -0.015),
                         inertia_body_kg_m2=np.diag([3.0, 4.0, 5.0]))
    R, tc = pose_from_relative(rho, att.R_lvlh_from_body(t, N_400KM), look_at(rho))
    labels = pose_labels(R, tc)
    assert isinstance(labels, PoseLabels) and len(labels) == 300
    q = labels.q_cam_from_body
    assert q.shape == (300, 4) and labels.euler_zyx_rad.shape == (300, 3)
    assert q[0, 0] >= 0.0
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) >= 0.0)
    # no jumps: consecutive quaternions are 2 sin(α/4) apart for the inter-frame angle α
    alpha = rotation_angle(R[1:], R[:-1])
    assert_allclose(np.linalg.norm(np.diff(q, axis=0), axis=1), 2 * np.sin(alpha / 4), atol=1e-13)
    assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert_allclose(matrix_from_quat(q), R, atol=1e-14)
    e = labels.euler_zyx_rad
    assert_allclose(matrix_from_euler_zyx(e[:, 0], e[:, 1], e[:, 2]), R, atol=1e-14)
    assert_allclose(labels.t_cam_m, tc, atol=0)
    with pytest.raises(ValueError):
        labels.t_cam_m[0, 0] = 1.0  # read-only
    # the rotation sweeps past 180 deg so Shepperd's q₀ ≥ 0 alone would jump
    assert np.min(q[:, 0]) < 0.0


def test_pose_labels_single_pose():
    R = look_at([0.0, -30.0, 5.0])
    labels = pose_labels(R, [0.0, 0.0, 30.41381265])
    assert labels.R_cam_from_body.shape == (1, 3, 3)
    assert labels.q_cam_from_body[0, 0] >= 0.0


def test_project_pinhole():
    K = camera_matrix(1000.0, 1200.0, 320.0, 240.0)
    p = np.array([[0.5, -0.25, 10.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [1.0, 1.0, -2.0]])
    uv = project(K, p)
    assert_allclose(uv[0], [1000 * 0.05 + 320, 1200 * -0.025 + 240], atol=1e-12)
    assert_allclose(uv[1], [320.0, 240.0], atol=0)
    assert np.all(np.isnan(uv[2:]))  # z ≤ 0: not imaged (and no RuntimeWarning)
    assert project(K, p[0]).shape == (2,)


def test_intrinsics_from_focal():
    K = intrinsics_from_focal(0.05, 5e-6, 1024, 768)
    assert_allclose(K, [[1e4, 0, 511.5], [0, 1e4, 383.5], [0, 0, 1]], rtol=1e-15)
    K2 = intrinsics_from_focal(0.05, (5e-6, 4e-6), 1024, 768)
    assert_allclose(np.diag(K2)[:2], [1e4, 1.25e4], rtol=1e-15)


def test_blender_from_opencv():
    R = look_at([0.0, -30.0, 5.0])
    t = np.array([0.0, 0.0, 30.41381265])
    R_b, t_b = blender_from_opencv(R, t)
    F = np.diag([1.0, -1.0, -1.0])
    assert_allclose(R_b, F @ R, atol=0)
    assert_allclose(t_b, [0.0, 0.0, -30.41381265], atol=0)  # Blender looks along −z
    assert is_rotation(R_b)
    # a point above the image centre (v < c_y, i.e. y_cv < 0) has y_blender > 0 (y up)
    assert (F @ np.array([0.0, -1.0, 5.0]))[1] > 0
    Rs, ts = blender_from_opencv(np.stack([R, R]), np.stack([t, t]))
    assert Rs.shape == (2, 3, 3) and ts.shape == (2, 3)


@pytest.mark.parametrize("call, name", [
    (lambda: look_at([0.0, 0.0, 0.0]), "rho_lvlh"),
    (lambda: look_at([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), "rho_lvlh"),
    (lambda: look_at([1.0, np.nan, 0.0]), "rho_lvlh"),
    (lambda: look_at([1.0, 2.0, 3.0], up_ref_lvlh=[0, 0, 0]), "up_ref_lvlh"),
    (lambda: look_at([1.0, 2.0, 3.0], roll_rad=[0.1, 0.2]), "roll_rad"),
    (lambda: camera_matrix(-1.0, 1.0, 0.0, 0.0), "fx"),
    (lambda: intrinsics_from_focal(0.05, 0.0, 10, 10), "pixel_pitch_m"),
    (lambda: intrinsics_from_focal(0.05, 5e-6, 10.5, 10), "width"),
    (lambda: project(np.eye(2), [0, 0, 1]), "K"),
    (lambda: pose_labels(np.eye(3)[None].repeat(2, 0), np.zeros((3, 3))), "t_cam_m"),
])
def test_bad_input_raises_naming_the_parameter(call, name):
    with pytest.raises(ValueError, match=rf"^{name} "):
        call()


def test_camera_at_target_centre_message():
    with pytest.raises(ValueError, match="camera at the target centre"):
        look_at(np.zeros(3))
