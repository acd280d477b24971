"""Rotation matrices, z-y-x Euler angles and unit quaternions.

Conventions (docs/conventions.md, "Rotations and quaternions"):

* Rotation matrices are **active** and act on column vectors, named target-from-source:
  ``v_ref = R_ref_from_body @ v_body``. ``R_z(a) = [[c, −s, 0], [s, c, 0], [0, 0, 1]]``.
* Euler angles are the z-y-x (3-2-1) sequence, yaw ψ about z, pitch θ about the new y, roll φ
  about the newest x: ``R = R_z(ψ) R_y(θ) R_x(φ)``; identical to scipy
  ``Rotation.from_euler('ZYX', [ψ, θ, φ])``.
* Quaternions are Hamilton, **scalar first**, unit, active: ``q = [cos(φ/2), sin(φ/2) ŵ]``
  for a rotation by φ about ŵ, ``v' = q ⊗ v ⊗ q*``. scipy stores them scalar last.

Every function is pure NumPy and vectorised over leading dimensions: angles ``(...)``,
vectors ``(..., 3)``, quaternions ``(..., 4)``, matrices ``(..., 3, 3)``.

References
----------
S. W. Shepperd, "Quaternion from rotation matrix", J. Guidance and Control 1(3), 223–224
(1978), doi:10.2514/3.55767.
F. L. Markley and J. L. Crassidis, *Fundamentals of Spacecraft Attitude Determination and
Control*, Springer (2014), ch. 2, doi:10.1007/978-1-4939-0802-8.
"""

from __future__ import annotations

import numpy as np

from ._checks import finite_array, finite_scalar

__all__ = [
    "rot_x", "rot_y", "rot_z", "axis_angle", "skew",
    "matrix_from_euler_zyx", "euler_zyx_from_matrix",
    "quat_from_matrix", "matrix_from_quat", "quat_multiply", "quat_conjugate",
    "quat_continuous", "quat_angle", "rotation_angle",
    "is_rotation", "orthonormalize",
]

_GIMBAL_COS_TOL = 5e-16
"""Below this |cos θ| the z-y-x decomposition is taken to be in gimbal lock (roll := 0).
Only there is φ undetermined: above it R₃₂ = cθ sφ and R₃₃ = cθ cφ still fix φ well enough
for ψ (built to match) to reproduce R to rounding. cos(π/2) in floating point is 6.1e-17, so
θ = ±π/2 exactly falls inside; with the earlier 1e-12, the dropped cos θ terms left R
reproduced only to |cos θ| (up to 2e-12; hypothesis found eps = 4.7e-15 with 4.0e-15).
Measured: 2·10⁵ random (ψ, φ, ε ∈ [1e-17, 1e-6]) reproduce R within 5.7e-16."""


# --------------------------------------------------------------------------- elementary

def _elementary(name: str, a, i: int, j: int) -> np.ndarray:
    """Active rotation by ``a`` in the (i, j) coordinate plane: e_i → cos a e_i + sin a e_j."""
    a = finite_array(name, a)
    c = np.cos(a)
    s = np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    k = 3 - i - j
    R[..., k, k] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., j, i] = s
    R[..., i, j] = -s
    return R


def rot_x(a) -> np.ndarray:
    """Active rotation about the x axis.

    Parameters
    ----------
    a : float or array_like, shape (...)
        Rotation angle, right-handed about +x [rad].

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        ``[[1, 0, 0], [0, c, −s], [0, s, c]]`` [-].
    """
    return _elementary("a", a, 1, 2)


def rot_y(a) -> np.ndarray:
    """Active rotation about the y axis.

    Parameters
    ----------
    a : float or array_like, shape (...)
        Rotation angle, right-handed about +y [rad].

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        ``[[c, 0, s], [0, 1, 0], [−s, 0, c]]`` [-].
    """
    return _elementary("a", a, 2, 0)


def rot_z(a) -> np.ndarray:
    """Active rotation about the z axis (``R_z``).

    Parameters
    ----------
    a : float or array_like, shape (...)
        Rotation angle, right-handed about +z [rad].

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        ``[[c, −s, 0], [s, c, 0], [0, 0, 1]]`` [-].
    """
    return _elementary("a", a, 0, 1)


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v]×`` with ``[v]× w = v × w``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Vector(s).

    Returns
    -------
    K : ndarray, shape (..., 3, 3), float64
        ``[[0, −v₃, v₂], [v₃, 0, −v₁], [−v₂, v₁, 0]]`` (units of ``v``).
    """
    v = finite_array("v", v, shape_tail=(3,))
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1] = -v[..., 2]
    K[..., 0, 2] = v[..., 1]
    K[..., 1, 0] = v[..., 2]
    K[..., 1, 2] = -v[..., 0]
    K[..., 2, 0] = -v[..., 1]
    K[..., 2, 1] = v[..., 0]
    return K


def _unit(name: str, v, what: str = "vector") -> np.ndarray:
    """Normalise ``v`` (..., k) along its last axis; a zero or non-finite norm raises."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    bad = ~(norm[..., 0] > 0.0) | ~np.isfinite(norm[..., 0])
    if np.any(bad):
        idx = np.argwhere(np.atleast_1d(bad))[0]
        where = "" if np.ndim(bad) == 0 else f" at index {tuple(int(i) for i in idx)}"
        raise ValueError(f"{name} must be a non-zero {what}, got norm 0{where}")
    return v / norm


def axis_angle(axis, angle) -> np.ndarray:
    """Rotation by ``angle`` about ``axis`` (Rodrigues' formula, ``Rot(ŵ, φ)``).

    Parameters
    ----------
    axis : array_like, shape (..., 3)
        Rotation axis ŵ in the frame the matrix acts in; normalised here [-].
    angle : float or array_like, shape (...)
        Right-handed rotation angle φ; broadcast against ``axis[..., 0]`` [rad].

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        ``I + sin φ [ŵ]× + (1 − cos φ) [ŵ]×²`` [-].

    Raises
    ------
    ValueError
        If ``axis`` is zero or either input is not finite.

    Notes
    -----
    ``1 − cos φ`` is evaluated as ``2 sin²(φ/2)`` to keep small angles accurate.
    """
    w = _unit("axis", finite_array("axis", axis, shape_tail=(3,)), "3-vector")
    phi = finite_array("angle", angle)
    shape = np.broadcast_shapes(w.shape[:-1], phi.shape)
    w = np.broadcast_to(w, shape + (3,))
    phi = np.broadcast_to(phi, shape)
    K = skew(w)
    s = np.sin(phi)[..., None, None]
    omc = (2.0 * np.sin(0.5 * phi) ** 2)[..., None, None]
    return np.eye(3) + s * K + omc * (K @ K)


# --------------------------------------------------------------------------- Euler z-y-x

def matrix_from_euler_zyx(yaw, pitch, roll) -> np.ndarray:
    """Rotation from z-y-x (3-2-1) Euler angles: ``R_z(ψ) R_y(θ) R_x(φ)``.

    Parameters
    ----------
    yaw, pitch, roll : float or array_like, shape (...)
        ψ about z, θ about the new y, φ about the newest x; broadcast together [rad].

    Returns
    -------
    R_ref_from_body : ndarray, shape (..., 3, 3), float64
        Active rotation body → reference [-]. Equals scipy
        ``Rotation.from_euler('ZYX', [ψ, θ, φ]).as_matrix()``.

    Notes
    -----
    ::

        [[cθcψ,  sφsθcψ − cφsψ,  cφsθcψ + sφsψ],
         [cθsψ,  sφsθsψ + cφcψ,  cφsθsψ − sφcψ],
         [−sθ,   sφcθ,           cφcθ        ]]
    """
    psi, theta, phi = np.broadcast_arrays(finite_array("yaw", yaw), finite_array("pitch", pitch),
                                          finite_array("roll", roll))
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(theta), np.sin(theta)
    cph, sph = np.cos(phi), np.sin(phi)
    R = np.empty(psi.shape + (3, 3))
    R[..., 0, 0] = cth * cps
    R[..., 0, 1] = sph * sth * cps - cph * sps
    R[..., 0, 2] = cph * sth * cps + sph * sps
    R[..., 1, 0] = cth * sps
    R[..., 1, 1] = sph * sth * sps + cph * cps
    R[..., 1, 2] = cph * sth * sps - sph * cps
    R[..., 2, 0] = -sth
    R[..., 2, 1] = sph * cth
    R[..., 2, 2] = cph * cth
    return R


def euler_zyx_from_matrix(R) -> np.ndarray:
    """z-y-x (3-2-1) Euler angles of a rotation matrix (inverse of :func:`matrix_from_euler_zyx`).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrix ``R_ref_from_body`` [-].

    Returns
    -------
    euler_zyx : ndarray, shape (..., 3), float64
        ``(yaw ψ, pitch θ, roll φ)`` with ψ, φ in [−π, π] and θ in [−π/2, π/2] [rad].

    Notes
    -----
    In closed form (1-based indices): ψ = atan2(R₂₁, R₁₁), θ = −asin(R₃₁), φ = atan2(R₃₂, R₃₃).
    Evaluated in an equivalent, better conditioned form:

    * θ = atan2(−R₃₁, hypot(R₁₁, R₂₁)) — equal to −asin(R₃₁) (clipped) for a rotation, but
      without the √ε loss of ``asin`` near ±90 deg;
    * φ = atan2(R₃₂, R₃₃);
    * ψ = atan2(sφ R₁₃ − cφ R₁₂, cφ R₂₂ − sφ R₂₃) — the same ψ as atan2(R₂₁, R₁₁) away from
      gimbal lock, but built from O(1) elements so that ``matrix_from_euler_zyx(ψ, θ, φ)``
      reproduces ``R`` to rounding even when cos θ → 0.

    **Gimbal lock** (θ = ±90 deg, here |cos θ| < 5e-16): only ψ − φ (θ = +90 deg) or ψ + φ
    (θ = −90 deg) is defined. The roll is then set to φ = 0 and the yaw to
    ψ = atan2(−R₁₂, R₂₂), which still reproduces ``R``. Near gimbal lock yaw and roll are
    individually ill-conditioned (error ≈ ε / |cos θ|) although the matrix is reproduced.
    """
    R = finite_array("R", R, shape_tail=(3, 3))
    cth = np.hypot(R[..., 0, 0], R[..., 1, 0])
    theta = np.arctan2(-R[..., 2, 0], cth)
    lock = cth < _GIMBAL_COS_TOL
    phi = np.where(lock, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    cph, sph = np.cos(phi), np.sin(phi)
    psi = np.arctan2(sph * R[..., 0, 2] - cph * R[..., 0, 1],
                     cph * R[..., 1, 1] - sph * R[..., 1, 2])
    return np.stack([psi, theta, phi], axis=-1)


# --------------------------------------------------------------------------- quaternions

def quat_from_matrix(R) -> np.ndarray:
    """Unit quaternion of a rotation matrix by Shepperd's method (Shepperd 1978).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Active rotation matrix [-].

    Returns
    -------
    q : ndarray, shape (..., 4), float64
        Hamilton, scalar-first unit quaternion with ``matrix_from_quat(q) == R`` and
        ``q₀ ≥ 0`` [-].

    Notes
    -----
    The symmetric matrix ``4 q qᵀ`` is read off ``R``::

        4q₀² = 1 + tr R          4q₀q₁ = R₃₂ − R₂₃   4q₁q₂ = R₁₂ + R₂₁
        4q₁² = 1 + R₁₁ − R₂₂ − R₃₃  4q₀q₂ = R₁₃ − R₃₁   4q₁q₃ = R₁₃ + R₃₁
        4q₂² = 1 − R₁₁ + R₂₂ − R₃₃  4q₀q₃ = R₂₁ − R₁₂   4q₂q₃ = R₂₃ + R₃₂
        4q₃² = 1 − R₁₁ − R₂₂ + R₃₃

    Shepperd (1978) takes the column whose diagonal entry is largest (at least 1/4 of the
    trace of 4qqᵀ, so no division by a small number, stable for angles near π) and
    normalises it (Markley & Crassidis 2014, §2.9.3). The sign is then fixed to q₀ ≥ 0.
    For a slightly non-orthogonal ``R`` the result is still a unit quaternion.
    """
    R = finite_array("R", R, shape_tail=(3, 3))
    r = R
    d0 = 1.0 + r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    d1 = 1.0 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2]
    d2 = 1.0 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2]
    d3 = 1.0 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2]
    a01 = r[..., 2, 1] - r[..., 1, 2]
    a02 = r[..., 0, 2] - r[..., 2, 0]
    a03 = r[..., 1, 0] - r[..., 0, 1]
    s12 = r[..., 0, 1] + r[..., 1, 0]
    s13 = r[..., 0, 2] + r[..., 2, 0]
    s23 = r[..., 1, 2] + r[..., 2, 1]
    # cols[..., i, :] = i-th column of 4 q qᵀ = 4 q_i q
    cols = np.stack([
        np.stack([d0, a01, a02, a03], axis=-1),
        np.stack([a01, d1, s12, s13], axis=-1),
        np.stack([a02, s12, d2, s23], axis=-1),
        np.stack([a03, s13, s23, d3], axis=-1),
    ], axis=-2)
    best = np.argmax(np.stack([d0, d1, d2, d3], axis=-1), axis=-1)
    q = np.take_along_axis(cols, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def matrix_from_quat(q) -> np.ndarray:
    """Active rotation matrix of a quaternion (``R(q)``).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Hamilton, scalar-first quaternion ``[q₀, q₁, q₂, q₃]``; normalised here [-].

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        ``v' = R v`` equals ``q ⊗ v ⊗ q*`` [-].

    Raises
    ------
    ValueError
        If ``q`` is zero or not finite.

    Notes
    -----
    ::

        [[1−2(q₂²+q₃²), 2(q₁q₂ − q₀q₃), 2(q₁q₃ + q₀q₂)],
         [2(q₁q₂ + q₀q₃), 1−2(q₁²+q₃²), 2(q₂q₃ − q₀q₁)],
         [2(q₁q₃ − q₀q₂), 2(q₂q₃ + q₀q₁), 1−2(q₁²+q₂²)]]

    The source paper prints the transpose (frame-transformation form; docs/accuracy.md, "Where
    this departs from the source paper").
    """
    q = _unit("q", finite_array("q", q, shape_tail=(4,)), "quaternion")
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
    R[..., 0, 1] = 2.0 * (q1 * q2 - q0 * q3)
    R[..., 0, 2] = 2.0 * (q1 * q3 + q0 * q2)
    R[..., 1, 0] = 2.0 * (q1 * q2 + q0 * q3)
    R[..., 1, 1] = 1.0 - 2.0 * (q1 * q1 + q3 * q3)
    R[..., 1, 2] = 2.0 * (q2 * q3 - q0 * q1)
    R[..., 2, 0] = 2.0 * (q1 * q3 - q0 * q2)
    R[..., 2, 1] = 2.0 * (q2 * q3 + q0 * q1)
    R[..., 2, 2] = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
    return R


def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (scalar first).

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Quaternions; broadcast together [-].

    Returns
    -------
    pq : ndarray, shape (..., 4), float64
        ``[p₀q₀ − p·q, p₀ q + q₀ p + p × q]``; ``R(p ⊗ q) = R(p) R(q)`` [-].
    """
    p = finite_array("p", p, shape_tail=(4,))
    q = finite_array("q", q, shape_tail=(4,))
    p0, pv = p[..., 0], p[..., 1:]
    q0, qv = q[..., 0], q[..., 1:]
    pv, qv = np.broadcast_arrays(pv, qv)
    s = p0 * q0 - np.sum(pv * qv, axis=-1)
    v = p0[..., None] * qv + q0[..., None] * pv + np.cross(pv, qv)
    return np.concatenate([s[..., None], v], axis=-1)


def quat_conjugate(q) -> np.ndarray:
    """Conjugate ``q* = [q₀, −q₁, −q₂, −q₃]`` (the inverse rotation for a unit quaternion).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternion(s) [-].

    Returns
    -------
    q_conj : ndarray, shape (..., 4), float64
        Conjugate [-].
    """
    q = finite_array("q", q, shape_tail=(4,))
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_continuous(q_seq) -> np.ndarray:
    """Choose quaternion signs along a sequence so that it has no sign jumps (q_k·q_{k−1} ≥ 0).

    Parameters
    ----------
    q_seq : array_like, shape (N, 4)
        Quaternions of consecutive frames (scalar first) [-].

    Returns
    -------
    q_seq : ndarray, shape (N, 4), float64
        ``±q_k`` with ``q₀ ≥ 0`` in the first frame and ``q_k · q_{k−1} ≥ 0`` afterwards [-].
        The rotations are unchanged.
    """
    q = finite_array("q_seq", q_seq, shape_tail=(4,), ndim=(2,))
    if q.shape[0] == 0:
        return q.copy()
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    flips = np.concatenate([[-1.0 if q[0, 0] < 0.0 else 1.0], np.where(dots < 0.0, -1.0, 1.0)])
    return q * np.cumprod(flips)[:, None]


def quat_angle(q1, q2) -> np.ndarray:
    """Angle of the rotation between two quaternions, sign-invariant (2 acos |q₁·q₂|).

    Parameters
    ----------
    q1, q2 : array_like, shape (..., 4)
        Quaternions (normalised here); broadcast together [-].

    Returns
    -------
    angle : ndarray, shape (...), float64
        ``2 acos(|q1 · q2|)`` in [0, π] [rad].

    Notes
    -----
    With s = ±1 the sign of q1·q2, ``|q1 − s q2| = 2 sin(α/4)`` and ``|q1 + s q2| = 2 cos(α/4)``
    for the rotation angle α, so ``α = 4 atan2(|q1 − s q2|, |q1 + s q2|)``. Unlike the ``acos``
    form this keeps full relative accuracy for small angles.
    """
    a = _unit("q1", finite_array("q1", q1, shape_tail=(4,)), "quaternion")
    b = _unit("q2", finite_array("q2", q2, shape_tail=(4,)), "quaternion")
    s = np.where(np.sum(a * b, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    return 4.0 * np.arctan2(np.linalg.norm(a - s * b, axis=-1),
                            np.linalg.norm(a + s * b, axis=-1))


def rotation_angle(R_a, R_b) -> np.ndarray:
    """Geodesic angle between two rotations: the angle of ``R_aᵀ R_b``.

    Parameters
    ----------
    R_a, R_b : array_like, shape (..., 3, 3)
        Rotation matrices; broadcast together [-].

    Returns
    -------
    angle : ndarray, shape (...), float64
        In [0, π] [rad].

    Notes
    -----
    With D = R_aᵀ R_b: sin α = |vee(D − Dᵀ)|/2 and cos α = (tr D − 1)/2, and
    α = atan2(sin α, cos α), accurate near 0 and near π (``acos`` alone loses √ε).
    """
    A = finite_array("R_a", R_a, shape_tail=(3, 3))
    B = finite_array("R_b", R_b, shape_tail=(3, 3))
    D = np.swapaxes(A, -1, -2) @ B
    v = np.stack([D[..., 2, 1] - D[..., 1, 2], D[..., 0, 2] - D[..., 2, 0],
                  D[..., 1, 0] - D[..., 0, 1]], axis=-1)
    s = 0.5 * np.linalg.norm(v, axis=-1)
    c = 0.5 * (np.trace(D, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)


# --------------------------------------------------------------------------- checks

def is_rotation(R, atol: float = 1e-9) -> np.ndarray:
    """Whether matrices are proper rotations: ``RᵀR = I`` and ``det R = +1`` within ``atol``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Matrices to test; non-finite entries give ``False`` [-].
    atol : float, optional
        Absolute tolerance on every entry of ``RᵀR − I`` and on ``det R − 1`` [-].

    Returns
    -------
    ok : ndarray of bool, shape (...)
        ``True`` where ``R`` is a rotation (a 0-d array for a single matrix).
    """
    atol = finite_scalar("atol", atol, nonnegative=True)
    try:
        R = np.asarray(R, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"R must be a numeric array, got {type(R).__name__}") from None
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got {R.shape}")
    with np.errstate(invalid="ignore", over="ignore"):
        G = np.swapaxes(R, -1, -2) @ R
        ortho = np.all(np.abs(G - np.eye(3)) <= atol, axis=(-2, -1))
        det = np.abs(np.linalg.det(R) - 1.0) <= atol
    return np.asarray(ortho & det & np.all(np.isfinite(R), axis=(-2, -1)))


def orthonormalize(R) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm), via the SVD.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Approximately orthogonal matrices [-].

    Returns
    -------
    R_rot : ndarray, shape (..., 3, 3), float64
        ``U diag(1, 1, det(U Vᵀ)) Vᵀ`` for ``R = U Σ Vᵀ``: orthonormal with det +1 [-].
    """
    R = finite_array("R", R, shape_tail=(3, 3))
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0.0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt
