"""Target attitude laws ``R_lvlh_from_body(t)`` (SPEC §9, "Target attitude modes").

The target body frame is the mesh's model frame; LVLH is the target-centred frame of SPEC §1,
which turns at +n about its ẑ axis (orbit normal) relative to inertial space. Times are
measured from the start of the sequence; the inertial frame used for the tumble coincides
with LVLH at t = 0, so that ``R_inertial_from_lvlh(t) = R_z(n t)``.

Modes (R₀ = ``R0_lvlh_from_body``):

* ``"lvlh-fixed"`` (Earth pointing): ``R₀``;
* ``"inertial"``: ``R_z(−n t) R₀``;
* ``"spin"`` at rate ω about the body axis ŵ: ``R_z(−n t) R₀ Rot(ŵ, ω t)``;
* ``"tumble"`` (torque-free rigid body): ``R_z(−n t) M(t)`` with ``M(0) = R₀`` from Euler's
  equations ``J ω̇ = −ω × (J ω)`` and ``q̇ = ½ q ⊗ (0, ω)`` (ω in body axes).

References
----------
F. L. Markley and J. L. Crassidis, *Fundamentals of Spacecraft Attitude Determination and
Control*, Springer (2014), §3.3 (kinematics) and §3.5 (torque-free motion),
doi:10.1007/978-1-4939-0802-8.
J. R. Dormand and P. J. Prince, "A family of embedded Runge–Kutta formulae", J. Comput. Appl.
Math. 6(1), 19–26 (1980), doi:10.1016/0771-050X(80)90013-3 (DOP853 via scipy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ._checks import finite_array, finite_scalar, mean_motion, one_of
from .rotations import (axis_angle, is_rotation, matrix_from_euler_zyx, matrix_from_quat,
                        orthonormalize, quat_from_matrix, rot_z)

__all__ = ["ATTITUDE_MODES", "TargetAttitude", "torque_free"]

ATTITUDE_MODES = ("lvlh-fixed", "inertial", "spin", "tumble")
"""Allowed values of :attr:`TargetAttitude.mode`."""

_RTOL = 1e-12
_ATOL = 1e-12
_ROTATION_ATOL = 1e-6  # accepted deviation of R0 from a rotation; it is then re-orthonormalised


def _times(t_s) -> tuple[np.ndarray, bool]:
    t = finite_array("t_s", t_s, ndim=(0, 1))
    return np.atleast_1d(t), t.ndim == 0


def _inertia(name: str, J) -> np.ndarray:
    J = finite_array(name, J)
    if J.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3), got {J.shape}")
    scale = float(np.max(np.abs(J)))
    if not np.allclose(J, J.T, rtol=0.0, atol=1e-12 * max(scale, 1e-300)):
        raise ValueError(f"{name} must be symmetric, got {J.tolist()}")
    eig = np.linalg.eigvalsh(J)
    if not eig[0] > 0.0:
        raise ValueError(f"{name} must be positive definite, got eigenvalues "
                         f"{eig.tolist()} [kg m²]")
    return J


def _rhs(J: np.ndarray, J_inv: np.ndarray):
    def f(_t, y):
        q0, q1, q2, q3 = y[0], y[1], y[2], y[3]
        w = y[4:7]
        wx, wy, wz = w[0], w[1], w[2]
        dq = 0.5 * np.array([
            -q1 * wx - q2 * wy - q3 * wz,
            q0 * wx + q2 * wz - q3 * wy,
            q0 * wy + q3 * wx - q1 * wz,
            q0 * wz + q1 * wy - q2 * wx,
        ])
        dw = J_inv @ (-np.cross(w, J @ w))
        return np.concatenate([dq, dw])
    return f


def torque_free(t_s, R0_inertial_from_body, omega0_body_rad_s, inertia_body_kg_m2):
    """Torque-free rigid-body attitude and body rate by numerical integration.

    Parameters
    ----------
    t_s : float or array_like, shape (N,)
        Times since the initial state, any order, negative allowed [s].
    R0_inertial_from_body : array_like, shape (3, 3)
        Attitude M(0) (body → inertial) [-].
    omega0_body_rad_s : array_like, shape (3,)
        Angular velocity of the body w.r.t. inertial space at t = 0, in body axes [rad/s].
    inertia_body_kg_m2 : array_like, shape (3, 3)
        Inertia tensor J about the centre of mass in body axes, symmetric positive
        definite [kg m²].

    Returns
    -------
    M : ndarray, shape (N, 3, 3) or (3, 3) for scalar ``t_s``, float64
        Attitude ``M(t) = R_inertial_from_body(t)`` [-].
    omega_body : ndarray, shape (N, 3) or (3,) for scalar ``t_s``, float64
        Body rate ω(t) in body axes [rad/s].

    Raises
    ------
    ValueError
        On non-finite input, a non-rotation ``R0_inertial_from_body``, a non-SPD inertia, or
        if the integrator fails.

    Notes
    -----
    Integrates ``q̇ = ½ q ⊗ (0, ω)`` (equivalently ``Ṁ = M [ω]×``) and
    ``J ω̇ = −ω × (J ω)`` with scipy ``solve_ivp`` (DOP853, rtol = atol = 1e-12) forward from
    0 to ``max(t_s)`` and backward from 0 to ``min(t_s)``; the quaternion is renormalised at
    the output times. Kinetic energy ½ωᵀJω and the inertial angular momentum M J ω are
    conserved to ≈1e-11 (relative) over two 400 km orbits at 0.05 rad/s.
    """
    t, scalar = _times(t_s)
    R0 = finite_array("R0_inertial_from_body", R0_inertial_from_body)
    if R0.shape != (3, 3) or not bool(is_rotation(R0, _ROTATION_ATOL)):
        raise ValueError(f"R0_inertial_from_body must be a 3x3 rotation matrix, got {R0.tolist()}")
    w0 = finite_array("omega0_body_rad_s", omega0_body_rad_s)
    if w0.shape != (3,):
        raise ValueError(f"omega0_body_rad_s must have shape (3,), got {w0.shape}")
    J = _inertia("inertia_body_kg_m2", inertia_body_kg_m2)

    y0 = np.concatenate([quat_from_matrix(orthonormalize(R0)), w0])
    f = _rhs(J, np.linalg.inv(J))
    uniq, inverse = np.unique(t, return_inverse=True)
    Y = np.empty((uniq.size, 7))
    Y[uniq == 0.0] = y0
    for side, step in ((uniq > 0.0, 1), (uniq < 0.0, -1)):
        idx = np.flatnonzero(side)[::step]  # in the direction of integration, away from 0
        if idx.size == 0:
            continue
        t_eval = uniq[idx]
        sol = solve_ivp(f, (0.0, float(t_eval[-1])), y0, method="DOP853", t_eval=t_eval,
                        rtol=_RTOL, atol=_ATOL)
        if not sol.success:
            raise ValueError(f"tumble integration failed: {sol.message}")
        Y[idx] = sol.y.T
    Y = Y[inverse.reshape(-1)]
    M = matrix_from_quat(Y[:, :4])  # normalises the quaternion
    w = Y[:, 4:]
    return (M[0], w[0]) if scalar else (M, w)


@dataclass(frozen=True, slots=True)
class TargetAttitude:
    """Attitude law of the target, ``R_lvlh_from_body(t)`` (SPEC §9).

    Parameters
    ----------
    mode : {"lvlh-fixed", "inertial", "spin", "tumble"}
        Attitude law (see the module docstring).
    R0_lvlh_from_body : array_like, shape (3, 3)
        Initial attitude R₀ (body → LVLH at t = 0); must be a rotation within 1e-6 and is
        stored re-orthonormalised as nested tuples [-].
    spin_axis_body : array_like, shape (3,)
        Spin axis ŵ in body axes for ``"spin"``; non-zero, stored normalised [-].
    spin_rate_rad_s : float
        Spin rate ω about ``spin_axis_body`` for ``"spin"`` (right-handed) [rad/s].
    omega0_body_rad_s : array_like, shape (3,)
        Initial body rate w.r.t. inertial space, body axes, for ``"tumble"`` [rad/s].
    inertia_body_kg_m2 : array_like, shape (3, 3)
        Inertia tensor J in body axes for ``"tumble"``, symmetric positive definite; only its
        ratios matter for the attitude [kg m²].

    Raises
    ------
    ValueError
        Naming the field, on an unknown mode, a non-rotation R₀, a zero spin axis, a
        non-symmetric or non-positive-definite inertia, or non-finite values.

    Notes
    -----
    All fields are validated whatever the mode (their defaults are valid), so the object is
    hashable and the meaning of a field never depends on the mode.
    """

    mode: str = "lvlh-fixed"
    R0_lvlh_from_body: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    spin_axis_body: tuple = (0.0, 0.0, 1.0)
    spin_rate_rad_s: float = 0.0
    omega0_body_rad_s: tuple = (0.0, 0.0, 0.0)
    inertia_body_kg_m2: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def __post_init__(self):
        if not isinstance(self.mode, str):
            raise ValueError(f"mode must be one of {', '.join(ATTITUDE_MODES)}; got {self.mode!r}")
        one_of("mode", self.mode, ATTITUDE_MODES)

        R0 = finite_array("R0_lvlh_from_body", self.R0_lvlh_from_body)
        if R0.shape != (3, 3):
            raise ValueError(f"R0_lvlh_from_body must have shape (3, 3), got {R0.shape}")
        if not bool(is_rotation(R0, _ROTATION_ATOL)):
            raise ValueError("R0_lvlh_from_body must be a rotation matrix (RᵀR = I, det +1 within "
                             f"{_ROTATION_ATOL:g}), got {R0.tolist()}")
        R0 = orthonormalize(R0)

        axis = finite_array("spin_axis_body", self.spin_axis_body)
        if axis.shape != (3,):
            raise ValueError(f"spin_axis_body must have shape (3,), got {axis.shape}")
        norm = float(np.linalg.norm(axis))
        if not norm > 0.0:
            raise ValueError(f"spin_axis_body must be a non-zero 3-vector, got {axis.tolist()}")

        rate = finite_scalar("spin_rate_rad_s", self.spin_rate_rad_s)

        w0 = finite_array("omega0_body_rad_s", self.omega0_body_rad_s)
        if w0.shape != (3,):
            raise ValueError(f"omega0_body_rad_s must have shape (3,), got {w0.shape}")

        J = _inertia("inertia_body_kg_m2", self.inertia_body_kg_m2)

        set_ = object.__setattr__
        set_(self, "R0_lvlh_from_body", tuple(tuple(float(x) for x in row) for row in R0))
        set_(self, "spin_axis_body", tuple(float(x) for x in axis / norm))
        set_(self, "spin_rate_rad_s", rate)
        set_(self, "omega0_body_rad_s", tuple(float(x) for x in w0))
        set_(self, "inertia_body_kg_m2", tuple(tuple(float(x) for x in row) for row in J))

    @classmethod
    def from_euler_zyx_deg(cls, mode: str, yaw_deg: float = 0.0, pitch_deg: float = 0.0,
                           roll_deg: float = 0.0, *, spin_axis_body=(0.0, 0.0, 1.0),
                           spin_rate_rad_s: float = 0.0, omega0_body_rad_s=(0.0, 0.0, 0.0),
                           inertia_body_kg_m2=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                               (0.0, 0.0, 1.0))) -> TargetAttitude:
        """Build with R₀ from z-y-x Euler angles in degrees (``R₀ = R_z(ψ) R_y(θ) R_x(φ)``).

        Parameters
        ----------
        mode : str
            As for the class.
        yaw_deg, pitch_deg, roll_deg : float
            Initial attitude of the body w.r.t. LVLH as z-y-x Euler angles [deg].
        spin_axis_body, spin_rate_rad_s, omega0_body_rad_s, inertia_body_kg_m2
            As for the class.

        Returns
        -------
        attitude : TargetAttitude
        """
        ang = [np.deg2rad(finite_scalar(name, v)) for name, v in
               (("yaw_deg", yaw_deg), ("pitch_deg", pitch_deg), ("roll_deg", roll_deg))]
        return cls(mode, matrix_from_euler_zyx(*ang), spin_axis_body, spin_rate_rad_s,
                   omega0_body_rad_s, inertia_body_kg_m2)

    @property
    def R0(self) -> np.ndarray:
        """ndarray, shape (3, 3), float64: ``R0_lvlh_from_body`` as a new array [-]."""
        return np.array(self.R0_lvlh_from_body)

    @property
    def inertia(self) -> np.ndarray:
        """ndarray, shape (3, 3), float64: ``inertia_body_kg_m2`` as a new array [kg m²]."""
        return np.array(self.inertia_body_kg_m2)

    def R_lvlh_from_body(self, t_s, n: float) -> np.ndarray:
        """Attitude of the target body relative to LVLH at the given times.

        Parameters
        ----------
        t_s : float or array_like, shape (N,)
            Times since the sequence start, any order, negative allowed [s].
        n : float
            Mean motion of the circular target orbit (LVLH rotation rate) [rad/s].

        Returns
        -------
        R_lvlh_from_body : ndarray, shape (N, 3, 3) or (3, 3) for scalar ``t_s``, float64
            Active rotation body → LVLH [-].

        Raises
        ------
        ValueError
            If ``t_s`` is not a finite scalar or 1-D array or ``n`` is not finite and > 0.
        """
        t, scalar = _times(t_s)
        n = mean_motion("n", n)
        R0 = self.R0
        if self.mode == "lvlh-fixed":
            R = np.broadcast_to(R0, (t.size, 3, 3)).copy()
        elif self.mode == "inertial":
            R = rot_z(-n * t) @ R0
        elif self.mode == "spin":
            R = rot_z(-n * t) @ R0 @ axis_angle(self.spin_axis_body, self.spin_rate_rad_s * t)
        else:  # tumble
            M, _ = torque_free(t, R0, self.omega0_body_rad_s, self.inertia_body_kg_m2)
            R = rot_z(-n * t) @ M
        return R[0] if scalar else R
