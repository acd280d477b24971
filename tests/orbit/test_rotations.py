"""Tests of orbit.rotations against docs/conventions.md and an independent library (scipy)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from orbit.rotations import (axis_angle, euler_zyx_from_matrix, is_rotation,
                             matrix_from_euler_zyx, matrix_from_quat, orthonormalize,
                             quat_conjugate, quat_angle, quat_continuous, quat_from_matrix,
                             quat_multiply, rot_x, rot_y, rot_z, rotation_angle, skew)

SETTINGS = settings(deadline=None, max_examples=150)

angles = st.floats(-np.pi, np.pi, allow_nan=False)
unit_vectors = (st.tuples(*[st.floats(-1.0, 1.0)] * 3)
                .map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)
                .map(lambda v: v / np.linalg.norm(v)))
quaternions = (st.tuples(*[st.floats(-1.0, 1.0)] * 4)
               .map(np.array).filter(lambda q: np.linalg.norm(q) > 0.1)
               .map(lambda q: q / np.linalg.norm(q)))
rotations = quaternions.map(matrix_from_quat)


def scipy_quat(q_scalar_first):
    """scipy stores quaternions scalar last."""
    return Rotation.from_quat(np.roll(q_scalar_first, -1, axis=-1))


def wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


# --------------------------------------------------------------------------- worked examples

def test_spec_example_euler_to_quaternion():
    """docs/conventions.md: (ψ, θ, φ) = (30, 20, 10) deg → q = [0.95154852, 0.03813458, 0.18930786,
    0.23929834]; the matrix equals scipy's (an independent implementation)."""
    yaw, pitch, roll = np.deg2rad([30.0, 20.0, 10.0])
    R = matrix_from_euler_zyx(yaw, pitch, roll)
    q = quat_from_matrix(R)
    assert_allclose(q, [0.95154852, 0.03813458, 0.18930786, 0.23929834], atol=1e-8)
    R_scipy = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    assert_allclose(R, R_scipy, atol=1e-15)
    # scipy's quaternion, reordered to scalar first
    assert_allclose(q, np.roll(Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat(), 1),
                    atol=1e-15)
    assert_allclose(euler_zyx_from_matrix(R), [yaw, pitch, roll], atol=1e-15)


def test_elementary_rotations_match_spec_and_scipy():
    a = 0.7
    c, s = np.cos(a), np.sin(a)
    assert_allclose(rot_z(a), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=0)  # active R_z
    for f, e in ((rot_x, [1, 0, 0]), (rot_y, [0, 1, 0]), (rot_z, [0, 0, 1])):
        assert_allclose(f(a), Rotation.from_rotvec(a * np.array(e)).as_matrix(), atol=1e-15)
        assert_allclose(f(a), axis_angle(e, a), atol=1e-15)


def test_vectorised_shapes():
    a = np.linspace(-3, 3, 10).reshape(2, 5)
    assert rot_x(a).shape == (2, 5, 3, 3)
    assert rot_z(0.1).shape == (3, 3)
    R = matrix_from_euler_zyx(a, 0.3, -a)
    assert R.shape == (2, 5, 3, 3)
    assert quat_from_matrix(R).shape == (2, 5, 4)
    assert matrix_from_quat(quat_from_matrix(R)).shape == (2, 5, 3, 3)
    assert euler_zyx_from_matrix(R).shape == (2, 5, 3)
    assert axis_angle([0, 0, 1], a).shape == (2, 5, 3, 3)
    assert quat_angle(quat_from_matrix(R), [1, 0, 0, 0]).shape == (2, 5)
    assert rotation_angle(R, np.eye(3)).shape == (2, 5)
    assert is_rotation(R).shape == (2, 5)
    assert orthonormalize(R).shape == (2, 5, 3, 3)
    # each element agrees with the scalar call
    assert_allclose(R[1, 3], matrix_from_euler_zyx(a[1, 3], 0.3, -a[1, 3]), atol=0)


# --------------------------------------------------------------------------- properties

@SETTINGS
@given(angles, st.floats(-np.pi / 2, np.pi / 2), angles, unit_vectors, angles, quaternions)
def test_results_are_rotations(yaw, pitch, roll, w, phi, q):
    for R in (matrix_from_euler_zyx(yaw, pitch, roll), axis_angle(w, phi), matrix_from_quat(q),
              rot_x(phi), rot_y(phi), rot_z(phi)):
        assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert abs(np.linalg.det(R) - 1.0) < 1e-14
        assert is_rotation(R)


@SETTINGS
@given(quaternions)
def test_quaternion_matrix_round_trip(q):
    R = matrix_from_quat(q)
    q2 = quat_from_matrix(R)
    assert q2[0] >= 0.0
    assert abs(np.linalg.norm(q2) - 1.0) < 1e-15
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-14  # sign-invariant
    assert_allclose(matrix_from_quat(q2), R, atol=1e-14)
    # scipy is an independent implementation (scalar last)
    assert_allclose(scipy_quat(q).as_matrix(), R, atol=1e-14)
    assert quat_angle(q2, np.roll(Rotation.from_matrix(R).as_quat(), 1)) < 1e-7


def test_matrix_from_quat_normalises_and_scales_away():
    q = np.array([0.95154852, 0.03813458, 0.18930786, 0.23929834])
    assert_allclose(matrix_from_quat(7.5 * q), matrix_from_quat(q), atol=1e-15)
    assert_allclose(matrix_from_quat(-q), matrix_from_quat(q), atol=1e-15)


@SETTINGS
@given(angles, st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3), angles)
def test_euler_round_trip_away_from_gimbal_lock(yaw, pitch, roll):
    R = matrix_from_euler_zyx(yaw, pitch, roll)
    e = euler_zyx_from_matrix(R)
    assert abs(e[1] - pitch) < 1e-12
    assert np.all(np.abs(wrap(e - [yaw, pitch, roll])) < 1e-11)
    assert_allclose(matrix_from_euler_zyx(*e), R, atol=1e-15)
    # scipy's inverse gives the same angles (our R matches from_euler('ZYX'))
    assert np.all(np.abs(wrap(Rotation.from_matrix(R).as_euler("ZYX") - e)) < 1e-9)


@SETTINGS
@given(angles, st.sampled_from([-1.0, 1.0]), angles, st.floats(0.0, 1e-6))
@example(yaw=0.0, side=-1.0, roll=1.0, eps=4.7135991345147725e-15)  # failed with a 1e-12 lock threshold
def test_euler_at_and_near_gimbal_lock_reproduces_matrix(yaw, side, roll, eps):
    """At θ = ±90 deg only ψ ∓ φ is defined: roll is set to 0 and R is still reproduced."""
    pitch = side * (np.pi / 2 - eps)
    R = matrix_from_euler_zyx(yaw, pitch, roll)
    e = euler_zyx_from_matrix(R)
    assert_allclose(matrix_from_euler_zyx(*e), R, atol=1e-15)
    assert abs(e[1] - pitch) < 1e-9
    if eps == 0.0:
        assert e[2] == 0.0
        # θ = +90 deg: ψ' = ψ − φ; θ = −90 deg: ψ' = ψ + φ
        assert abs(wrap(e[0] - (yaw - side * roll))) < 1e-12


def test_euler_exact_gimbal_lock_from_constructed_matrix():
    # θ = +90 deg with an exact 0 in R₃₂ and R₃₃ (not produced via cos(π/2) = 6e-17)
    a = 0.4
    R = np.array([[0.0, np.sin(a), np.cos(a)], [0.0, np.cos(a), -np.sin(a)], [-1.0, 0.0, 0.0]])
    e = euler_zyx_from_matrix(R)
    assert_allclose(e, [-a, np.pi / 2, 0.0], atol=1e-15)
    assert_allclose(matrix_from_euler_zyx(*e), R, atol=1e-15)


@SETTINGS
@given(unit_vectors, st.floats(-4 * np.pi, 4 * np.pi))
def test_rodrigues_equals_matrix_exponential(w, phi):
    assert_allclose(axis_angle(w, phi), expm(phi * skew(w)), atol=1e-13)
    assert_allclose(axis_angle(3.7 * w, phi), axis_angle(w, phi), atol=1e-15)  # axis normalised


def test_skew_is_cross_product():
    v, w = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.4, -1.2])
    assert_allclose(skew(v) @ w, np.cross(v, w), atol=1e-15)


@SETTINGS
@given(quaternions, quaternions)
def test_quat_multiply_composes_like_matrices(p, q):
    pq = quat_multiply(p, q)
    assert_allclose(matrix_from_quat(pq), matrix_from_quat(p) @ matrix_from_quat(q), atol=1e-14)
    assert_allclose(np.linalg.norm(pq), 1.0, atol=1e-15)
    assert_allclose((scipy_quat(p) * scipy_quat(q)).as_matrix(), matrix_from_quat(pq), atol=1e-14)
    # active rotation of a vector: q ⊗ (0, v) ⊗ q*
    v = np.array([0.3, -1.0, 2.0])
    rotated = quat_multiply(quat_multiply(q, np.r_[0.0, v]), quat_conjugate(q))
    assert_allclose(rotated, np.r_[0.0, matrix_from_quat(q) @ v], atol=1e-14)


@SETTINGS
@given(unit_vectors, st.one_of(st.just(0.0), st.floats(0.0, 1e-6)))
def test_shepperd_stable_near_pi(w, delta):
    """Angles at and near π: the trace branch would divide by ~0; Shepperd does not."""
    angle = np.pi - delta
    R = axis_angle(w, angle)
    q = quat_from_matrix(R)
    q_scipy = np.roll(Rotation.from_rotvec(angle * w).as_quat(), 1)
    assert quat_angle(q, q_scipy) < 1e-7
    assert min(np.abs(q - q_scipy).max(), np.abs(q + q_scipy).max()) < 1e-14
    assert_allclose(matrix_from_quat(q), R, atol=1e-15)
    assert abs(rotation_angle(np.eye(3), R) - angle) < 1e-14


def test_quat_continuous_removes_deliberate_sign_flips():
    t = np.linspace(0.0, 1.0, 200)
    w = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    angle = 4.0 * np.pi * t  # two full turns: q passes q₀ = 0 and q → −q
    q_smooth = np.column_stack([np.cos(angle / 2), np.sin(angle / 2)[:, None] * w])
    flips = np.where(np.random.default_rng(7).random(t.size) < 0.4, -1.0, 1.0)
    flips[0] = -1.0  # the first one too
    q_flipped = q_smooth * flips[:, None]
    q_c = quat_continuous(q_flipped)
    assert_allclose(q_c, q_smooth, atol=0)
    assert q_c[0, 0] >= 0.0
    assert np.all(np.sum(q_c[1:] * q_c[:-1], axis=1) >= 0.0)
    # Shepperd's q₀ ≥ 0 makes the raw sequence jump; continuity restores it
    q_raw = quat_from_matrix(matrix_from_quat(q_smooth))
    assert np.any(np.sum(q_raw[1:] * q_raw[:-1], axis=1) < 0.0)
    assert_allclose(quat_continuous(q_raw), q_smooth, atol=1e-14)


@SETTINGS
@given(quaternions, unit_vectors, st.floats(1e-12, 1e-6))
def test_quat_angle_small_angle_accuracy(q, w, alpha):
    dq = np.r_[np.cos(alpha / 2), np.sin(alpha / 2) * w]
    q2 = quat_multiply(q, dq)
    assert abs(quat_angle(q, q2) - alpha) < 1e-9
    assert abs(quat_angle(q, -q2) - alpha) < 1e-9  # sign-invariant
    assert abs(rotation_angle(matrix_from_quat(q), matrix_from_quat(q2)) - alpha) < 1e-9


def test_quat_angle_beats_naive_acos():
    """2 acos(|q·q'|) loses √ε: at 1e-8 rad it is off by ~1e-8; ours is not."""
    alpha = 1e-8
    q1 = np.array([1.0, 0.0, 0.0, 0.0])
    q2 = np.array([np.cos(alpha / 2), np.sin(alpha / 2), 0.0, 0.0])
    naive = 2.0 * np.arccos(min(1.0, abs(q1 @ q2)))
    assert abs(naive - alpha) > 1e-9
    assert abs(quat_angle(q1, q2) - alpha) < 1e-20


@SETTINGS
@given(quaternions, quaternions)
def test_angles_match_scipy(p, q):
    expected = (scipy_quat(p).inv() * scipy_quat(q)).magnitude()
    assert abs(quat_angle(p, q) - expected) < 1e-7
    assert abs(rotation_angle(matrix_from_quat(p), matrix_from_quat(q)) - expected) < 1e-7
    assert abs(quat_angle(p, q) - rotation_angle(matrix_from_quat(p), matrix_from_quat(q))) < 1e-7


@SETTINGS
@given(rotations, st.floats(1e-8, 1e-2), st.integers(0, 2**32 - 1))
def test_orthonormalize_returns_nearest_rotation(R, noise, seed):
    R_noisy = R + noise * np.random.default_rng(seed).standard_normal((3, 3))
    R_fixed = orthonormalize(R_noisy)
    assert is_rotation(R_fixed, atol=1e-13)
    assert rotation_angle(R_fixed, R) < 10 * noise
    assert_allclose(orthonormalize(R), R, atol=1e-14)  # rotations are fixed points


def test_is_rotation_rejects_non_rotations():
    R = rot_z(0.3)
    assert is_rotation(R)
    assert not is_rotation(np.diag([1.0, 1.0, -1.0]))  # reflection
    assert not is_rotation(1.001 * R)
    assert not is_rotation(np.full((3, 3), np.nan))
    assert is_rotation(1.001 * R, atol=1e-2)
    assert orthonormalize(np.diag([1.0, 1.0, -1.0])).tolist() != np.diag([1.0, 1.0, -1.0]).tolist()
    assert is_rotation(orthonormalize(np.diag([1.0, 2.0, -1.0])))


# --------------------------------------------------------------------------- errors

@pytest.mark.parametrize("call, name", [
    (lambda: axis_angle([0, 0, 0], 1.0), "axis"),
    (lambda: matrix_from_quat([0, 0, 0, 0]), "q"),
    (lambda: matrix_from_quat([1, 0, 0]), "q"),
    (lambda: rot_x(np.nan), "a"),
    (lambda: quat_from_matrix(np.eye(2)), "R"),
    (lambda: quat_continuous(np.ones(4)), "q_seq"),
    (lambda: quat_angle([1, 0, 0, 0], [0, 0, 0, 0]), "q2"),
    (lambda: matrix_from_euler_zyx(0.0, np.inf, 0.0), "pitch"),
    (lambda: is_rotation(np.eye(3), atol=-1.0), "atol"),
])
def test_bad_input_raises_naming_the_parameter(call, name):
    with pytest.raises(ValueError, match=rf"^{name} "):
        call()


# --------------------------------------------------------------------------- the source paper

def test_paper_quaternion_matrix_is_the_transpose_of_ours():
    """The paper prints the frame-transformation (passive) form R(q)ᵀ (docs/accuracy.md)."""
    q0, q1, q2, q3 = q = np.array([0.95154852, 0.03813458, 0.18930786, 0.23929834])
    R_paper = np.array([
        [q0**2 + q1**2 - q2**2 - q3**2, 2 * (q1 * q2 + q0 * q3), 2 * (q1 * q3 - q0 * q2)],
        [2 * (q1 * q2 - q0 * q3), q0**2 - q1**2 + q2**2 - q3**2, 2 * (q2 * q3 + q0 * q1)],
        [2 * (q1 * q3 + q0 * q2), 2 * (q2 * q3 - q0 * q1), q0**2 - q1**2 - q2**2 + q3**2],
    ])
    R_ours = matrix_from_quat(q)
    assert_allclose(R_paper, R_ours.T, atol=1e-8)
    assert rotation_angle(R_paper, R_ours) > 0.5  # not the same matrix for a generic q
    # both describe the same rotation: active maps body vectors into the reference frame,
    # the passive form maps reference coordinates into body coordinates
    v_body = np.array([1.0, 2.0, 3.0])
    assert_allclose(R_paper @ (R_ours @ v_body), v_body, atol=1e-8)


def test_paper_euler_product_is_zxy_not_zyx():
    """The paper's "zyx" matrix is R_y(θ) R_x(φ) R_z(ψ), a 3-1-2 sequence (docs/accuracy.md)."""
    yaw, pitch, roll = np.deg2rad([30.0, 20.0, 10.0])
    R_paper = rot_y(pitch) @ rot_x(roll) @ rot_z(yaw)
    assert_allclose(R_paper, Rotation.from_euler("YXZ", [pitch, roll, yaw]).as_matrix(), atol=1e-15)
    R_ours = matrix_from_euler_zyx(yaw, pitch, roll)
    assert rotation_angle(R_paper, R_ours) > 0.05
    assert_allclose(R_ours, rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), atol=1e-15)
