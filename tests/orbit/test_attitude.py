"""Tests of the target attitude laws (SPEC §9, "Target attitude modes")."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orbit.attitude import ATTITUDE_MODES, TargetAttitude, torque_free
from orbit.rotations import (axis_angle, is_rotation, matrix_from_euler_zyx, rot_z,
                             rotation_angle)

N_400KM = 1.1313666536110223e-3  # SPEC §0 [rad/s]
T_400KM = 2.0 * np.pi / N_400KM
R0 = matrix_from_euler_zyx(0.3, -0.4, 1.0)
J_GENERAL = np.array([[10.0, 0.5, -0.3], [0.5, 14.0, 0.2], [-0.3, 0.2, 7.0]])  # kg m²


def R_inertial_from_lvlh(t, n, inclination=0.9, raan=-0.6, u0=0.3):
    """LVLH axes built from a circular orbit in an inertial frame (SPEC §1), columns x̂ ŷ ẑ.

    Independent of the R_z(n t) shortcut used by the code: the orbit is inclined and the
    LVLH triad is computed from r and h = r × v.
    """
    a = 6778137.0
    u = u0 + n * t
    P = rot_z(raan) @ np.array([[1, 0, 0], [0, np.cos(inclination), -np.sin(inclination)],
                                [0, np.sin(inclination), np.cos(inclination)]])
    r = a * np.column_stack([np.cos(u), np.sin(u), np.zeros_like(u)]) @ P.T
    v = a * n * np.column_stack([-np.sin(u), np.cos(u), np.zeros_like(u)]) @ P.T
    x = r / np.linalg.norm(r, axis=1, keepdims=True)
    h = np.cross(r, v)
    z = h / np.linalg.norm(h, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def test_lvlh_fixed_is_constant():
    att = TargetAttitude("lvlh-fixed", R0)
    t = np.linspace(-100.0, 3 * T_400KM, 50)
    R = att.R_lvlh_from_body(t, N_400KM)
    assert R.shape == (50, 3, 3)
    assert_allclose(R, np.broadcast_to(R0, R.shape), atol=1e-15)
    assert att.R_lvlh_from_body(12.0, N_400KM).shape == (3, 3)


def test_default_is_identity_lvlh_fixed():
    att = TargetAttitude()
    assert att.mode == "lvlh-fixed"
    assert_allclose(att.R_lvlh_from_body([0.0, 5.0], N_400KM),
                    np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_inertial_formula_and_fixed_in_inertial_space():
    att = TargetAttitude("inertial", R0)
    t = np.linspace(-0.3 * T_400KM, 2 * T_400KM, 101)
    R = att.R_lvlh_from_body(t, N_400KM)
    assert_allclose(R, rot_z(-N_400KM * t) @ R0, atol=1e-15)
    assert_allclose(att.R_lvlh_from_body(0.0, N_400KM), R0, atol=0)
    # independent check: body axes fixed in inertial space along a real (inclined) orbit
    R_ib = R_inertial_from_lvlh(t, N_400KM) @ R
    R_ib0 = R_inertial_from_lvlh(np.array([0.0]), N_400KM)[0] @ R0
    assert np.max(rotation_angle(R_ib, R_ib0)) < 1e-12
    # and after one orbit the LVLH attitude is back to R0
    assert rotation_angle(att.R_lvlh_from_body(T_400KM, N_400KM), R0) < 1e-12


def test_spin_formula():
    w = np.array([1.0, -1.0, 2.0])
    att = TargetAttitude("spin", R0, spin_axis_body=w, spin_rate_rad_s=0.02)
    t = np.array([0.0, 10.0, -55.0, 3000.0])
    expected = rot_z(-N_400KM * t) @ R0 @ axis_angle(w, 0.02 * t)
    assert_allclose(att.R_lvlh_from_body(t, N_400KM), expected, atol=1e-14)
    assert_allclose(att.spin_axis_body, w / np.linalg.norm(w))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_spin_equals_tumble_about_a_principal_axis(axis):
    J = np.diag([10.0, 14.0, 7.0])
    e = np.eye(3)[axis]
    rate = -0.05
    t = np.concatenate([np.linspace(0.0, 2 * T_400KM, 60), [-700.0, -5.0]])
    spin = TargetAttitude("spin", R0, spin_axis_body=e, spin_rate_rad_s=rate)
    tumble = TargetAttitude("tumble", R0, omega0_body_rad_s=rate * e, inertia_body_kg_m2=J)
    err = rotation_angle(spin.R_lvlh_from_body(t, N_400KM), tumble.R_lvlh_from_body(t, N_400KM))
    assert np.max(err) < 1e-9


def test_tumble_conserves_energy_and_inertial_angular_momentum():
    """Torque-free: ½ωᵀJω and M J ω are constant. Measured ~1e-11 relative over two orbits."""
    w0 = np.array([0.03, -0.02, 0.04])
    t = np.linspace(0.0, 2 * T_400KM, 300)
    M, w = torque_free(t, R0, w0, J_GENERAL)
    assert np.all(is_rotation(M, atol=1e-13))
    E = 0.5 * np.einsum("ni,ij,nj->n", w, J_GENERAL, w)
    H = np.einsum("nij,jk,nk->ni", M, J_GENERAL, w)
    assert np.max(np.abs(E / E[0] - 1.0)) < 1e-9
    assert np.max(np.linalg.norm(H - H[0], axis=1)) / np.linalg.norm(H[0]) < 1e-9
    # the motion is not trivial: the body rate changes direction in the body
    assert np.max(np.linalg.norm(w - w0, axis=1)) > 0.5 * np.linalg.norm(w0)


def test_tumble_axisymmetric_closed_form():
    """J = diag(I1, I1, I3): M(t) = Rot(ĥ, |H| t / I1) M₀ Rot(ẑ, −λ t), λ = (I3 − I1)/I1 ω_z0.

    Derivation: with this M, M[ω]× = Ṁ gives ω = (|H|/I1) Mᵀĥ − λẑ = Jω/I1 − λẑ, which holds
    component-wise; ĥ = M₀ J ω₀ / |H| is the fixed inertial angular-momentum direction.
    """
    I1, I3 = 8.0, 13.0
    J = np.diag([I1, I1, I3])
    w0 = np.array([0.02, -0.01, 0.05])
    t = np.concatenate([np.linspace(-0.5 * T_400KM, 2 * T_400KM, 200), [0.0]])
    att = TargetAttitude("tumble", R0, omega0_body_rad_s=w0, inertia_body_kg_m2=J)
    H0 = R0 @ J @ w0
    h = H0 / np.linalg.norm(H0)
    lam = (I3 - I1) / I1 * w0[2]
    M_closed = axis_angle(h, np.linalg.norm(H0) * t / I1) @ R0 @ rot_z(-lam * t)
    R_closed = rot_z(-N_400KM * t) @ M_closed
    err = rotation_angle(att.R_lvlh_from_body(t, N_400KM), R_closed)
    assert np.max(err) < 1e-8
    # body rate: ω_z constant, transverse part turning at +λ in the body
    _, w = torque_free(t, R0, w0, J)
    assert_allclose(w, (rot_z(lam * t) @ w0), atol=1e-12)


def test_tumble_negative_and_unsorted_times():
    w0 = np.array([0.01, 0.03, -0.02])
    att = TargetAttitude("tumble", R0, omega0_body_rad_s=w0, inertia_body_kg_m2=J_GENERAL)
    t = np.array([400.0, -250.0, 0.0, 1200.0, -250.0, -3.0, 400.0])
    R = att.R_lvlh_from_body(t, N_400KM)
    assert R.shape == (7, 3, 3)
    for k, tk in enumerate(t):
        assert rotation_angle(R[k], att.R_lvlh_from_body(tk, N_400KM)) < 1e-10
    assert_allclose(R[2], R0, atol=1e-15)
    assert_allclose(R[1], R[4], atol=0)
    # backward propagation undoes forward propagation: start at M(−250) and go forward 250 s
    M_back, w_back = torque_free(-250.0, R0, w0, J_GENERAL)
    M_fwd, w_fwd = torque_free(250.0, M_back, w_back, J_GENERAL)
    assert rotation_angle(M_fwd, R0) < 1e-10
    assert_allclose(w_fwd, w0, atol=1e-13)


def test_mode_spin_special_case_of_inertial():
    t = np.linspace(0, 1000.0, 7)
    spin0 = TargetAttitude("spin", R0, spin_rate_rad_s=0.0)
    inertial = TargetAttitude("inertial", R0)
    assert_allclose(spin0.R_lvlh_from_body(t, N_400KM), inertial.R_lvlh_from_body(t, N_400KM),
                    atol=1e-15)


def test_from_euler_and_hashable():
    att = TargetAttitude.from_euler_zyx_deg("spin", 30.0, 20.0, 10.0, spin_rate_rad_s=0.1)
    assert_allclose(att.R0, matrix_from_euler_zyx(*np.deg2rad([30.0, 20.0, 10.0])), atol=1e-15)
    assert hash(att) == hash(TargetAttitude.from_euler_zyx_deg("spin", 30.0, 20.0, 10.0,
                                                               spin_rate_rad_s=0.1))
    with pytest.raises(AttributeError):
        att.mode = "tumble"


def test_R0_slightly_off_is_orthonormalised():
    att = TargetAttitude("lvlh-fixed", np.round(R0, 8))
    assert is_rotation(att.R0, atol=1e-14)
    assert rotation_angle(att.R0, R0) < 1e-7


@pytest.mark.parametrize("kwargs, field", [
    ({"mode": "wobble"}, "mode"),
    ({"mode": "lvlh-fixed", "R0_lvlh_from_body": np.diag([1.0, 1.0, -1.0])}, "R0_lvlh_from_body"),
    ({"mode": "lvlh-fixed", "R0_lvlh_from_body": 2 * np.eye(3)}, "R0_lvlh_from_body"),
    ({"mode": "lvlh-fixed", "R0_lvlh_from_body": np.eye(2)}, "R0_lvlh_from_body"),
    ({"mode": "spin", "spin_axis_body": (0, 0, 0)}, "spin_axis_body"),
    ({"mode": "spin", "spin_rate_rad_s": np.nan}, "spin_rate_rad_s"),
    ({"mode": "tumble", "omega0_body_rad_s": (0.0, np.nan, 0.0)}, "omega0_body_rad_s"),
    ({"mode": "tumble", "inertia_body_kg_m2": np.diag([1.0, -1.0, 1.0])}, "inertia_body_kg_m2"),
    ({"mode": "tumble", "inertia_body_kg_m2": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]},
     "inertia_body_kg_m2"),
    ({"mode": "tumble", "inertia_body_kg_m2": np.zeros((3, 3))}, "inertia_body_kg_m2"),
])
def test_bad_fields_raise_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=rf"^{field} ") as info:
        TargetAttitude(**kwargs)
    if field == "mode":
        for mode in ATTITUDE_MODES:
            assert mode in str(info.value)
        assert "wobble" in str(info.value)


def test_bad_times_and_mean_motion():
    att = TargetAttitude("inertial")
    with pytest.raises(ValueError, match="^t_s "):
        att.R_lvlh_from_body([0.0, np.nan], N_400KM)
    with pytest.raises(ValueError, match="^t_s "):
        att.R_lvlh_from_body(np.zeros((2, 2)), N_400KM)
    with pytest.raises(ValueError, match="^n "):
        att.R_lvlh_from_body([0.0], -1.0)
