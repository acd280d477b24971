"""Tests of the target attitude laws (docs/orbit.md, "Target attitude")."""

from __future__ import annotations

import time

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp
from scipy.special import ellipk

from orbit.attitude import ATTITUDE_MODES, TargetAttitude, torque_free
from orbit.rotations import (axis_angle, is_rotation, matrix_from_euler_zyx, matrix_from_quat,
                             quat_from_matrix, rot_z, rotation_angle)

N_400KM = 1.1313666536110223e-3  # n = sqrt(μ/a³) at 400 km altitude [rad/s]
T_400KM = 2.0 * np.pi / N_400KM
R0 = matrix_from_euler_zyx(0.3, -0.4, 1.0)
J_GENERAL = np.array([[10.0, 0.5, -0.3], [0.5, 14.0, 0.2], [-0.3, 0.2, 7.0]])  # kg m²


def R_inertial_from_lvlh(t, n, inclination=0.9, raan=-0.6, u0=0.3):
    """LVLH axes built from a circular orbit in an inertial frame, columns x̂ ŷ ẑ.

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


# --------------------------------------------------------------------------- tumble in closed form
# References for these tests are computed here, independently of orbit.attitude: a tight
# DOP853 integration of Euler's equations and the quaternion kinematics, and the polhode
# period 4K(m)/λ of Landau & Lifshitz §37 with scipy's ellipk.

def _integrate(t, R0_ib, w0, J, tol=1e-13):
    """M(t), ω(t) by DOP853 (rtol = atol = tol) forward and backward from t = 0."""
    J = np.asarray(J, dtype=float)
    J_inv = np.linalg.inv(J)

    def f(_t, y):
        q0, q1, q2, q3, wx, wy, wz = y
        w = y[4:]
        dq = 0.5 * np.array([-q1 * wx - q2 * wy - q3 * wz, q0 * wx + q2 * wz - q3 * wy,
                             q0 * wy + q3 * wx - q1 * wz, q0 * wz + q1 * wy - q2 * wx])
        return np.concatenate([dq, J_inv @ np.cross(J @ w, w)])

    y0 = np.concatenate([quat_from_matrix(R0_ib), w0])
    t, inverse = np.unique(np.asarray(t, dtype=float), return_inverse=True)
    Y = np.tile(y0, (t.size, 1))
    for side in (t > 0.0, t < 0.0):
        idx = np.flatnonzero(side)
        if idx.size == 0:
            continue
        idx = idx[np.argsort(np.abs(t[idx]))]
        sol = solve_ivp(f, (0.0, t[idx[-1]]), y0, method="DOP853", t_eval=t[idx],
                        rtol=tol, atol=tol)
        assert sol.success
        Y[idx] = sol.y.T
    Y = Y[inverse.reshape(-1)]
    return matrix_from_quat(Y[:, :4]), Y[:, 4:]


def _polhode(J, w0):
    """Parameter m, polhode period T = 4K(m)/λ and rate λ (Landau & Lifshitz §37)."""
    Jp, P = np.linalg.eigh(np.asarray(J, dtype=float))
    w = P.T @ w0
    I1, I2, I3 = Jp
    E2, M2 = np.sum(Jp * w * w), np.sum((Jp * w) ** 2)
    if M2 < E2 * I2:  # polhode around the axis of least inertia
        I1, I3 = I3, I1
    m = (I2 - I1) * (E2 * I3 - M2) / ((I3 - I2) * (M2 - E2 * I1))
    lam = np.sqrt((I3 - I2) * (M2 - E2 * I1) / (I1 * I2 * I3))
    return m, 4.0 * ellipk(m) / lam, lam


def _separatrix_w1(Jp, w3, rel):
    """ω₁ putting (ω₁, ·, ω₃) in principal axes at relative distance ``rel`` from H² = 2EJ₂."""
    return np.sqrt(Jp[2] * (Jp[2] - Jp[1]) / (Jp[0] * (Jp[1] - Jp[0]))) * w3 * (1.0 + rel)


_JG_EIG, _JG_AXES = np.linalg.eigh(J_GENERAL)
TUMBLE_CASES = {
    "diag, about the major axis": (np.diag([1.0, 2.0, 3.0]), [0.1, 0.2, 0.5]),
    "diag, about the minor axis": (np.diag([1.0, 2.0, 3.0]), [0.5, 0.2, -0.1]),
    "diag unsorted, negative rates": (np.diag([10.0, 14.0, 7.0]), [-0.02, -0.03, 0.01]),
    "general, major": (J_GENERAL, [0.03, -0.02, 0.04]),
    "general, minor": (J_GENERAL, [0.01, 0.03, -0.02]),
    "near axisymmetric, oblate": (np.diag([8.0, 8.0 * (1 + 1e-6), 13.0]), [0.02, -0.01, 0.05]),
    "near axisymmetric, prolate": (np.diag([3.0, 13.0 * (1 - 1e-7), 13.0]), [0.05, -0.01, 0.02]),
    "near a principal axis": (np.diag([1.0, 2.0, 3.0]), [1e-7, -2e-7, 0.3]),
    "near separatrix, major side": (np.diag([1.0, 2.0, 3.0]),
                                    [_separatrix_w1([1, 2, 3], 0.1, -1e-4), 0.05, 0.1]),
    "near separatrix, minor side": (np.diag([1.0, 2.0, 3.0]),
                                    [_separatrix_w1([1, 2, 3], 0.1, 1e-4), 0.05, 0.1]),
    "general, near separatrix": (J_GENERAL, _JG_AXES @ [_separatrix_w1(_JG_EIG, 0.02, 1e-3),
                                                        0.01, 0.02]),
}


@pytest.mark.parametrize("J, w0", TUMBLE_CASES.values(), ids=TUMBLE_CASES.keys())
def test_tumble_matches_numerical_integration(J, w0):
    """Several polhode periods, unsorted negative and positive times, repeated times.

    Measured: ≤ 5e-12 rad, 7e-11 rad at 1 − m = 2e-4, where the integrator's own error
    grows (near the separatrix the closed form agrees with a 25–28-digit Taylor integration
    to 2e-14 rad at 1 − m = 2e-6 and 8e-13 rad at 2e-10, DOP853 to 2e-10 and 3e-5 rad).
    """
    w0 = np.asarray(w0, dtype=float)
    m, T, _ = _polhode(J, w0)
    rng = np.random.default_rng(7)
    t = np.concatenate([rng.uniform(-1.5 * T, 4.0 * T, 120), [0.0, 2.5 * T, -T, 2.5 * T]])
    M, w = torque_free(t, R0, w0, J)
    M_ref, w_ref = _integrate(t, R0, w0, J)
    assert np.max(rotation_angle(M, M_ref)) < 1e-9
    assert np.max(np.linalg.norm(w - w_ref, axis=1)) < 1e-10 * np.linalg.norm(w0)
    assert np.all(is_rotation(M, atol=1e-14))
    assert_allclose(M[t == 0.0], np.broadcast_to(R0, (1, 3, 3)), atol=1e-15)
    assert_allclose(M[-3], M[-1], atol=0)
    if m > 1e-6:  # the body rate really changes direction in the body
        assert np.max(np.linalg.norm(w - w0, axis=1)) > 0.1 * np.linalg.norm(w0)


def test_tumble_on_the_separatrix():
    """H² = 2EJ₂ exactly (m = 1): the rate tends to the intermediate axis for t → ±∞."""
    from fractions import Fraction
    J = np.diag([1.0, 1.5, 3.0])
    for w0 in ([0.75, -0.2, 0.25], [-0.75, 0.3, 0.25], [0.75, 0.1, -0.25]):
        w0 = np.array(w0)
        Jq, wq = [Fraction(x) for x in np.diag(J)], [Fraction(x) for x in w0]
        assert sum((j * w) ** 2 for j, w in zip(Jq, wq)) == Jq[1] * sum(
            j * w * w for j, w in zip(Jq, wq))  # exactly on the separatrix
        m, _, lam = _polhode(J, w0)
        assert m == pytest.approx(1.0, abs=1e-14)
        t = np.linspace(-8.0, 8.0, 101) / lam  # the turn-over and its approach
        M, w = torque_free(t, R0, w0, J)
        M_ref, w_ref = _integrate(t, R0, w0, J)
        assert np.max(rotation_angle(M, M_ref)) < 1e-9
        assert np.max(np.linalg.norm(w - w_ref, axis=1)) < 1e-10 * np.linalg.norm(w0)
        # far from t = 0: spin about the intermediate axis at |H|/J₂, H conserved
        H = R0 @ J @ w0
        M_far, w_far = torque_free([-1e4, 1e4, 1e7], R0, w0, J)
        assert_allclose(np.abs(w_far[:, 1]), np.linalg.norm(H) / 1.5, rtol=1e-14)
        assert_allclose(w_far[:, [0, 2]], 0.0, atol=1e-300)
        assert_allclose(np.einsum("nij,jk,nk->ni", M_far, J, w_far), np.tile(H, (3, 1)),
                        rtol=0, atol=1e-14)


@pytest.mark.parametrize("J", [np.diag([1.0, 2.0, 3.0]), J_GENERAL])
def test_tumble_conservation_at_very_long_times(J):
    """10 rev/s up to 1e7 s (6e8 rad), far beyond any integration: ½ωᵀJω, M J ω, MᵀM = I."""
    w0 = np.array([0.6, -0.3, 0.74])
    w0 *= 20.0 * np.pi / np.linalg.norm(w0)
    t = np.concatenate([np.geomspace(1.0, 1e7, 400), -np.geomspace(1.0, 1e7, 100)])
    M, w = torque_free(t, R0, w0, J)
    E0, H0 = 0.5 * w0 @ J @ w0, R0 @ J @ w0
    E = 0.5 * np.einsum("ni,ij,nj->n", w, J, w)
    H = np.einsum("nij,jk,nk->ni", M, J, w)
    assert np.max(np.abs(E / E0 - 1.0)) < 1e-13
    assert np.max(np.linalg.norm(H - H0, axis=1)) < 1e-13 * np.linalg.norm(H0)
    assert np.all(is_rotation(M, atol=1e-14))


def test_tumble_long_time_precession_from_one_integrated_period():
    """M(kT) = Rot(ĥ, kΔφ) M₀ with Δφ from ONE integrated polhode period, k up to 1e5.

    Checks the reduction of the phase at long times against an independent answer: the
    rotation D = M(T) M₀ᵀ over one period is integrated, then M(kT) must be D^k M₀.
    """
    J = J_GENERAL
    w0 = np.array([0.3, 0.5, -0.45])
    _, T, _ = _polhode(J, w0)
    M_T, w_T = _integrate([T], R0, w0, J)
    assert_allclose(w_T[0], w0, atol=1e-12)  # one full period of the body rate
    D = M_T[0] @ R0.T
    h = R0 @ J @ w0
    h /= np.linalg.norm(h)
    v = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
    dphi = np.arctan2(0.5 * v @ h, 0.5 * (np.trace(D) - 1.0))
    assert_allclose(D, axis_angle(h, dphi), atol=1e-12)  # D is a rotation about ĥ
    k = np.array([1.0, 7.0, 1000.0, 123457.0])
    M = torque_free(k * T, R0, w0, J)[0]
    expected = axis_angle(h, k * dphi) @ R0
    # the integrated Δφ carries ~1e-12 rad, multiplied by k
    assert np.all(rotation_angle(M, expected) < 2e-13 * k + 1e-11)


def test_tumble_semigroup_at_long_times():
    """Propagating to t₁ then by t₂ equals propagating to t₁ + t₂ (t₁ up to 1e7 s, 10 rev/s).

    The state at t₁ carries the rounding of a phase of |ω| t₁ ≈ 6e8 rad (≈ 1e-16 relative).
    """
    J = J_GENERAL
    w0 = np.array([0.6, -0.3, 0.74])
    w0 *= 20.0 * np.pi / np.linalg.norm(w0)
    t2 = np.linspace(-3.0, 3.0, 31)
    for t1 in (1e3, 1e5, 1e7):
        M1, w1 = torque_free(t1, R0, w0, J)
        M_a, w_a = torque_free(t1 + t2, R0, w0, J)
        M_b, w_b = torque_free(t2, M1, w1, J)
        tol = 4e-16 * np.linalg.norm(w0) * t1 + 1e-12
        assert np.max(rotation_angle(M_a, M_b)) < tol
        assert np.max(np.linalg.norm(w_a - w_b, axis=1)) < tol * np.linalg.norm(w0)


def test_tumble_fast_example_is_bounded_in_cost(monkeypatch):
    """Inertia diag(1, 2, 3) kg m², ω₀ = 3600 deg/s on each axis (polhode period 0.1 s).

    A step-by-step integration over a 2800 s window (≈ 27 000 polhode periods) takes
    minutes. The closed form makes a fixed number of special-function calls whatever the
    window, each over the requested times only.
    """
    import orbit.attitude as attitude
    calls = []

    def counting(f):
        def wrapped(*args):
            calls.append(int(np.size(np.broadcast(*args))))
            return f(*args)
        return wrapped

    monkeypatch.setattr(attitude, "elliprj", counting(attitude.elliprj))
    monkeypatch.setattr(attitude, "elliprf", counting(attitude.elliprf))
    J = np.diag([1.0, 2.0, 3.0])
    w0 = np.deg2rad([3600.0, 3600.0, 3600.0])
    sizes = {}
    for n_times, window in ((48, 2800.0), (48, 2.8e6), (10 ** 6, 2800.0)):
        t = np.linspace(0.0, window, n_times)
        calls.clear()
        start = time.perf_counter()
        M, w = torque_free(t, R0, w0, J)
        elapsed = time.perf_counter() - start
        assert elapsed < 5.0  # measured 2 ms for 48 times, ≈ 1 s for 1e6 on a slow machine
        assert len(calls) <= 8 and sum(calls) <= 2 * n_times + 8
        sizes[n_times, window] = len(calls)
        E = 0.5 * np.einsum("ni,ij,nj->n", w, J, w)
        assert np.max(np.abs(E / E[0] - 1.0)) < 1e-14
    assert sizes[48, 2800.0] == sizes[48, 2.8e6]
    # and it is right: the first ten polhode periods against the integrator
    _, T, _ = _polhode(J, w0)
    t = np.linspace(-2.0 * T, 10.0 * T, 97)
    M_ref, w_ref = _integrate(t, R0, w0, J)
    M, w = torque_free(t, R0, w0, J)
    assert np.max(rotation_angle(M, M_ref)) < 1e-9
    att = TargetAttitude("tumble", R0, omega0_body_rad_s=w0, inertia_body_kg_m2=J)
    assert att.R_lvlh_from_body(np.linspace(0.0, 2800.0, 48), N_400KM).shape == (48, 3, 3)


def test_tumble_at_rest_spherical_and_about_an_exact_eigenvector():
    t = np.array([-1e5, -3.0, 0.0, 2.0, 1e6])
    M, w = torque_free(t, R0, np.zeros(3), J_GENERAL)
    assert_allclose(M, np.broadcast_to(R0, (5, 3, 3)), atol=1e-15)
    assert_allclose(w, 0.0, atol=0)
    w0 = np.array([0.02, -0.05, 0.01])
    Q = matrix_from_euler_zyx(0.7, 0.2, -1.1)
    for J in (5.0 * np.eye(3), Q @ np.diag([5.0, 5.0, 5.0]) @ Q.T):  # spherical: ω constant
        M, w = torque_free(t, R0, w0, J)
        angle = np.linalg.norm(w0) * t
        err = rotation_angle(M, R0 @ axis_angle(w0, np.mod(angle, 2 * np.pi)))
        assert np.max(err) < 1e-9
        assert_allclose(w, np.broadcast_to(w0, w.shape), atol=1e-15)
    # rotation exactly about the intermediate eigenvector of a non-diagonal J (J ω ∥ ω)
    J = np.array([[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]])  # eigenvalues 1, 3, 5
    w0 = np.array([0.04, 0.04, 0.0])
    t = np.linspace(-1e4, 1e4, 11)
    M, w = torque_free(t, R0, w0, J)
    err = rotation_angle(M, R0 @ axis_angle(w0, np.mod(np.linalg.norm(w0) * t, 2 * np.pi)))
    assert np.max(err) < 1e-9
    assert_allclose(w, np.broadcast_to(w0, w.shape), atol=0)


def test_tumble_refuses_times_beyond_float64_phase():
    w0 = np.array([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="^t_s "):
        torque_free([0.0, 1e16], R0, w0, J_GENERAL)
    with pytest.raises(ValueError, match="^t_s "):
        torque_free(1e16, R0, w0, np.eye(3))


@pytest.mark.parametrize("axis, expected", [
    ((1e-200, 0.0, 0.0), (1.0, 0.0, 0.0)),
    ((0.0, -3e-320, 0.0), (0.0, -1.0, 0.0)),
    ((1e-200, 1e-200, 0.0), (2 ** -0.5, 2 ** -0.5, 0.0)),
    ((1e300, 0.0, -1e300), (2 ** -0.5, 0.0, -(2 ** -0.5))),
])
def test_spin_axis_tiny_or_huge_is_normalised(axis, expected):
    att = TargetAttitude("spin", spin_axis_body=axis)
    assert_allclose(att.spin_axis_body, expected, rtol=1e-15, atol=0)
    with pytest.raises(ValueError, match="^spin_axis_body .*non-zero"):
        TargetAttitude("spin", spin_axis_body=(0.0, 0.0, 0.0))
