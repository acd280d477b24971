"""Target attitude laws ``R_lvlh_from_body(t)`` (docs/orbit.md, "Target attitude").

The target body frame is the mesh's model frame; LVLH is the target-centred frame of
docs/conventions.md, which turns at +n about its ẑ axis (orbit normal) relative to inertial
space. Times are measured from the start of the sequence; the inertial frame used for the
tumble coincides with LVLH at t = 0, so that ``R_inertial_from_lvlh(t) = R_z(n t)``.

Modes (R₀ = ``R0_lvlh_from_body``):

* ``"lvlh-fixed"`` (Earth pointing): ``R₀``;
* ``"inertial"``: ``R_z(−n t) R₀``;
* ``"spin"`` at rate ω about the body axis ŵ: ``R_z(−n t) R₀ Rot(ŵ, ω t)``;
* ``"tumble"`` (torque-free rigid body): ``R_z(−n t) M(t)`` with ``M(0) = R₀``, the solution
  of Euler's equations ``J ω̇ = −ω × (J ω)`` and ``Ṁ = M [ω]×`` (ω in body axes), evaluated
  in closed form (:func:`torque_free`): the body rate from Jacobi elliptic functions in the
  principal axes, the attitude from the fixed inertial angular momentum and the precession
  angle about it (an incomplete elliptic integral of the third kind). The cost does not
  depend on the times asked for or on the number of revolutions.

References
----------
L. D. Landau and E. M. Lifshitz, *Mechanics*, 3rd ed., Pergamon Press, Oxford (1976), §37
(the asymmetrical top).
F. L. Markley and J. L. Crassidis, *Fundamentals of Spacecraft Attitude Determination and
Control*, Springer (2014), §3.3 (kinematics) and §3.5 (torque-free motion),
doi:10.1007/978-1-4939-0802-8.
NIST Digital Library of Mathematical Functions (DLMF), https://dlmf.nist.gov/, §22 (Jacobi
elliptic functions; §22.20(ii) for the arithmetic-geometric mean) and §19 (Legendre and Carlson
elliptic integrals; §19.25 for the relations between them).
B. C. Carlson, "Numerical computation of real or complex elliptic integrals", Numer.
Algorithms 10, 13–26 (1995), doi:10.1007/BF02198293 (R_F, R_J via scipy).
T. J. Dekker, "A floating-point technique for extending the available precision", Numer.
Math. 18, 224–242 (1971), doi:10.1007/BF01397083 (exact products for the phase reduction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from scipy.special import elliprf, elliprj

from ._checks import finite_array, finite_scalar, mean_motion, one_of
from .rotations import (axis_angle, is_rotation, matrix_from_euler_zyx, orthonormalize, rot_z)

__all__ = ["ATTITUDE_MODES", "TargetAttitude", "torque_free"]

ATTITUDE_MODES = ("lvlh-fixed", "inertial", "spin", "tumble")
"""Allowed values of :attr:`TargetAttitude.mode`."""

_ROTATION_ATOL = 1e-6  # accepted deviation of R0 from a rotation; it is then re-orthonormalised
_TWO_PI = 2.0 * math.pi
_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's splitting constant for binary64
_AGM_TOL = 2.0 ** -60  # c_N / a_N at which the arithmetic-geometric mean is converged
_AGM_MAX = 64
_MAX_TURNS = 2.0 ** 50  # largest phase (turns, half polhode periods) accepted for |t|


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


# --------------------------------------------------------------------------- arithmetic

def _two_product(a, b) -> tuple[np.ndarray, np.ndarray]:
    """``a b = p + e`` with ``p = fl(a b)`` and ``e`` its rounding error (Dekker 1971).

    Elementwise; where the splitting would overflow (|a|, |b| ≳ 1e300) ``e`` is set to 0.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    p = a * b
    with np.errstate(over="ignore", invalid="ignore"):
        ah = _SPLIT * a
        ah = ah - (ah - a)
        al = a - ah
        bh = _SPLIT * b
        bh = bh - (bh - b)
        bl = b - bh
        e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, np.where(np.isfinite(e), e, 0.0)


def _fraction(p, e) -> np.ndarray:
    """``p + e`` minus an integer, in [−1, 1], for a number carried as the pair (p, e)."""
    return (p - np.round(p)) + (e - np.round(e))


def _pow2(x: float) -> float:
    """A power of two within a factor 2 of ``x > 0`` (scaling by it is exact)."""
    return math.ldexp(1.0, math.frexp(x)[1])


def _principal_axes(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J = P diag(Jp) Pᵀ`` with ``Jp`` ascending and det P = +1; exact for a diagonal J."""
    J = 0.5 * (J + J.T)
    if not np.any(J - np.diag(np.diag(J))):
        d = np.diag(J)
        order = np.argsort(d, kind="stable")
        Jp, P = d[order].copy(), np.eye(3)[:, order]
    else:
        Jp, P = np.linalg.eigh(J)
    if np.linalg.det(P) < 0.0:
        P[:, 2] = -P[:, 2]
    return Jp, P


# --------------------------------------------------------------------------- elliptic functions

def _agm(m: float, m1: float) -> tuple[np.ndarray, np.ndarray]:
    """Arithmetic-geometric mean sequences ``a_n``, ``c_n`` for parameter m (DLMF 22.20.1).

    Starts from a₀ = 1, b₀ = √m1, c₀ = √m with m1 = 1 − m given separately, so that m → 1
    keeps its precision; ``c_{n+1} = c_n² / (4 a_{n+1})`` avoids the cancellation in
    (a_n − b_n)/2. Requires m1 > 0.
    """
    a, b, c = [1.0], math.sqrt(m1), [math.sqrt(m)]
    while c[-1] > _AGM_TOL * a[-1] and len(a) < _AGM_MAX:
        a_next = 0.5 * (a[-1] + b)
        b = math.sqrt(a[-1] * b)
        c.append(c[-1] ** 2 / (4.0 * a_next))
        a.append(a_next)
    return np.array(a), np.array(c)


def _am(u: np.ndarray, a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Jacobi amplitude am(u | m) by the descending AGM recursion (DLMF 22.20(ii)).

    φ_N = 2^N a_N u, φ_{n−1} = ½ (φ_n + arcsin((c_n / a_n) sin φ_n)), am = φ₀.
    """
    N = a.size - 1
    phi = math.ldexp(a[N], N) * u
    for j in range(N, 0, -1):
        phi = 0.5 * (phi + np.arcsin((c[j] / a[j]) * np.sin(phi)))
    return phi


def _pi_minus_f(n: float, s: np.ndarray, c: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Π(n; θ | m) − F(θ | m) for |θ| ≤ π/2 from s = sin θ, c = cos θ ≥ 0, d2 = 1 − m sin²θ.

    DLMF 19.25.14 (Carlson 1995) multiplied out by sin³θ (R_J is homogeneous of degree −3/2):
    Π − F = (n/3) s³ R_J(c², d2, 1, 1 − n s²); needs n < 1 so that 1 − n s² > 0.
    """
    if n == 0.0:
        return np.zeros_like(s)
    return (n / 3.0) * s ** 3 * elliprj(c * c, d2, 1.0, 1.0 - n * s * s)


# --------------------------------------------------------------------------- torque-free motion

class _TorqueFreeMotion:
    """Constants of one torque-free motion and its evaluation at any times.

    Principal axes relabelled so that axis 3 is the one the polhode circles (largest moment
    when H² > 2EJ_mid, smallest otherwise, the order reversed and the middle axis negated
    to keep the frame right-handed), axis 2 the intermediate one; then with
    D_ij = J_i − J_j (all of one sign), the constants of Landau & Lifshitz §37 are

    * A₁ = 2EJ₃ − H² = J₁D₃₁ω₁² + J₂D₃₂ω₂², A₃ = H² − 2EJ₁ = J₂D₂₁ω₂² + J₃D₃₁ω₃²;
    * amplitudes a₁² = A₁/(J₁D₃₁), a₂² = A₁/(J₂D₃₂), a₃² = A₃/(J₃D₃₁);
    * rate λ² = D₃₂A₃/(J₁J₂J₃), parameter m = D₂₁A₁/(D₃₂A₃) and
      1 − m = D₃₁Q/(D₃₂A₃), Q = J₃D₃₂ω₃² − J₁D₂₁ω₁² = H² − 2EJ₂ (zero on the separatrix),
      all evaluated in exact rational arithmetic on the float64 values, then rounded once;
    * ω = (a₁ cn u, a₂ sn u, σ₃ a₃ dn u), u = λt + u₀, σ₃ = sign ω₃, sign λ = σ₃ sign D₃₁,
      u₀ = F(am u₀ | m) from (cn u₀, sn u₀) = (ω₁/a₁, ω₂/a₂) (R_F, DLMF 19.25.5).

    With the z-x-z Euler angles (φ, θ, ψ) of the principal frame relative to a frame whose
    z axis is ĥ = H/|H| (Landau & Lifshitz §37; Markley & Crassidis §3.5),
    ĥ_body = (sin θ sin ψ, sin θ cos ψ, cos θ) = Jω/|H| and
    φ̇ = |H| (J₁ω₁² + J₂ω₂²)/(J₁²ω₁² + J₂²ω₂²) = |H|/J₃ + C/(1 − n sn²u),
    C = |H| D₃₁/(J₁J₃), n = −(J₃/J₁)(D₂₁/D₃₂) ≤ 0, so that
    φ(t) − φ(0) = |H| t/J₃ + (C/λ) [Π(n; am u | m) − Π(n; am u₀ | m)].
    ψ and θ are built from ratios (J₁ cn : g sn, with g = J₂a₂/a₁ = √(J₁J₂D₃₁/D₃₂)) that
    stay defined when the rate is (nearly) along axis 3. Since sn and cn change sign and
    am u and Π(n; am u) grow by π and 2Π(n | m) when u grows by 2K, with u = 2Kk + v,
    |v| ≤ K:

    φ(t) − φ(0) = |H| t/J₃ + (k − k₀) 2CΠ(n | m)/λ + (C/λ) [Π(n; am v) − Π(n; am v₀)],

    the first two terms carried modulo one turn with exact products.

    On the separatrix (m = 1, Q = H² − 2EJ₂ = 0 exactly) ω = (σ₁a₁ sech u, a₂ tanh u,
    σ₃a₃ sech u) with sign λ = σ₁σ₃ sign D₃₁, and ∫ du/(1 − n tanh²u) is elementary.
    """

    def __init__(self, M0: np.ndarray, w0: np.ndarray, J: np.ndarray):
        self.M0 = M0
        self.w0 = w0
        w_max = float(np.max(np.abs(w0)))
        if w_max == 0.0:
            self.kind = "rest"
            return
        Jp, P = _principal_axes(J)
        J_scale = _pow2(Jp[2])
        w_scale = _pow2(w_max)
        Js, ws = J / J_scale, w0 / w_scale
        Jp = Jp / J_scale
        w = P.T @ ws
        # exact rational arithmetic on these doubles: the sign of H² − 2EJ₂ and 1 − m keep
        # full precision however close to the separatrix, with no overflow or underflow
        Jq, wq = [Fraction(x) for x in Jp], [Fraction(x) for x in w]
        Dq = {(i, j): Jq[i] - Jq[j] for i in range(3) for j in range(3)}
        wsq = [Fraction(x) for x in ws]
        Jwq = [sum(Fraction(Js[i, j]) * wsq[j] for j in range(3)) for i in range(3)]
        body_cross = [wsq[1] * Jwq[2] - wsq[2] * Jwq[1], wsq[2] * Jwq[0] - wsq[0] * Jwq[2],
                      wsq[0] * Jwq[1] - wsq[1] * Jwq[0]]
        if (not any(wq[i] * wq[j] * Dq[j, i] for i, j in ((0, 1), (0, 2), (1, 2)))
                or not any(body_cross)):
            self._set_constant(ws, w_scale)  # ω₀ along a principal axis, or J spherical
            return
        Q = Jq[2] * Dq[2, 1] * wq[2] ** 2 - Jq[0] * Dq[1, 0] * wq[0] ** 2  # ∝ H² − 2EJ₂
        if Q >= 0:
            Pr, order, flip = P, (0, 1, 2), (1, 1, 1)
        else:  # polhode around the axis of least inertia: reverse the axes, negate the middle
            Pr, order, flip = np.column_stack([P[:, 2], -P[:, 1], P[:, 0]]), (2, 1, 0), (1, -1, 1)
        J1, J2, J3 = (Jq[i] for i in order)
        w1, w2, w3 = (f * wq[i] for f, i in zip(flip, order))
        D21, D31, D32 = J2 - J1, J3 - J1, J3 - J2
        A1 = J1 * D31 * w1 ** 2 + J2 * D32 * w2 ** 2
        A3 = J2 * D21 * w2 ** 2 + J3 * D31 * w3 ** 2
        try:
            a1, a2, a3, lam_abs, g = (math.sqrt(float(x)) for x in (
                A1 / (J1 * D31), A1 / (J2 * D32), A3 / (J3 * D31), D32 * A3 / (J1 * J2 * J3),
                J1 * J2 * D31 / D32))
            m, m1, n = (float(x) for x in (D21 * A1 / (D32 * A3), D31 * Q / (D32 * A3),
                                             -(J3 / J1) * (D21 / D32)))
            H = math.sqrt(float((J1 * w1) ** 2 + (J2 * w2) ** 2 + (J3 * w3) ** 2))
            C = H * float(D31 / (J1 * J3))
            usable = (all(math.isfinite(x) for x in (a1, a2, a3, lam_abs, g, n, H, C))
                      and min(a1, a3, lam_abs) > 0.0)
        except (OverflowError, ZeroDivisionError):
            usable = False
        if not usable:
            # only for inertia ratios or rate components beyond ~1e150: a polhode rate or a
            # nutation amplitude below the floating-point range, ω constant for any finite t
            self._set_constant(ws, w_scale)
            return
        Jr = np.array([float(J1), float(J2), float(J3)])
        wr = np.array([float(w1), float(w2), float(w3)])
        sign = 1.0 if D31 > 0 else -1.0
        self.P, self.J, self.w_scale = Pr, Jr, w_scale
        self.a = np.array([a1, a2, a3])
        self.g = g
        if m1 == 0.0:
            self._set_separatrix(wr, sign, lam_abs, n, H, C)
        else:
            self._set_periodic(wr, sign, lam_abs, m, m1, n, H, C)
        x1, x2, x3, _ = self._phase(np.zeros(1))
        self.L = M0 @ np.vstack(self._frame(x1, x2, x3)).T  # M₀ (B₀ Pᵀ)ᵀ

    # ------------------------------------------------------------------ set-up per case

    def _set_constant(self, ws: np.ndarray, w_scale: float):
        self.kind = "constant"
        self.axis = ws
        self.turn_rate = w_scale * float(np.linalg.norm(ws)) / _TWO_PI  # [turn/s]
        self.cycle_rate = self.turn_rate

    def _set_separatrix(self, wr, sign, lam_abs, n, H, C):
        """m = 1: sn = tanh u, cn = dn = sech u, ω₁ and ω₃ keep their signs σ₁, σ₃."""
        self.kind = "separatrix"
        a1, a2, _ = self.a
        self.sig1, self.sig3 = math.copysign(1.0, wr[0]), math.copysign(1.0, wr[2])
        lam = sign * self.sig1 * self.sig3 * lam_abs
        self.lam = self.w_scale * lam  # [rad/s]
        # sinh u₀ = tanh u₀ / sech u₀ = (ω₂/a₂)/(|ω₁|/a₁), through logarithms when it overflows
        w1, w2 = abs(float(wr[0])), float(wr[1])
        if w2 == 0.0:
            self.u0 = 0.0
        else:
            log_y = math.log(abs(w2)) - math.log(a2) + math.log(a1) - math.log(w1)
            self.u0 = math.copysign(math.asinh(math.exp(log_y)) if log_y < 700.0
                                    else math.log(2.0) + log_y, w2)
        self.nu = math.sqrt(-n)
        # ∫ du/(1 − n tanh²u) = (u + ν atan(ν tanh u))/(1 + ν²), ν² = −n; the linear part
        # adds up with |H|/J₃ to the rate |H|/J₂ about the intermediate axis.
        self.amp = (C / lam) * self.nu / (1.0 + self.nu ** 2)  # [rad]
        self.atan0 = math.atan(self.nu * math.tanh(self.u0))
        self.turn_H = self.w_scale * H / (self.J[1] * _TWO_PI)  # [turn/s]
        self.cycle_rate = self.turn_H

    def _set_periodic(self, wr, sign, lam_abs, m, m1, n, H, C):
        self.kind = "periodic"
        a1, a2, _ = self.a
        self.m, self.m1, self.n = m, m1, n
        self.sig3 = math.copysign(1.0, wr[2])
        lam = sign * self.sig3 * lam_abs
        self.lam = self.w_scale * lam  # [rad/s]
        self.agm_a, self.agm_c = _agm(m, m1)
        self.K = math.pi / (2.0 * self.agm_a[-1])
        self.kp = math.sqrt(m1)
        Pi_c = float(elliprf(0.0, m1, 1.0))  # Π(n | m), DLMF 19.25.1–2
        if n != 0.0:
            Pi_c += n / 3.0 * float(elliprj(0.0, m1, 1.0, 1.0 - n))
        self.Pi_c = Pi_c
        # 1/(1 − n cd²w) = [α + (1 − α)/(1 − n₂ sn²w)]/(1 − n), n₂ = (m − n)/(1 − n) ∈ [0, 1)
        self.n2 = (m - n) / (1.0 - n)
        self.alpha = m * (1.0 - n) / (m - n) if m - n > 0.0 else 1.0
        x1, x2 = float(wr[0]) / a1, float(wr[1]) / a2  # (cn u₀, sn u₀), one of them ≥ ½
        r = math.hypot(x1, x2)
        cn0, sn0 = x1 / r, x2 / r
        F0 = sn0 * float(elliprf(cn0 * cn0, m1 + m * cn0 * cn0, 1.0))  # F(am u₀), |am| ≤ π/2
        self.u0 = F0 if cn0 >= 0.0 else math.copysign(2.0 * self.K, sn0) - F0
        self.Cl = C / lam  # [-]
        self.turn_H = self.w_scale * H / (self.J[2] * _TWO_PI)  # [turn/s]
        self.turn_half = C * Pi_c / (math.pi * lam)  # Π part of φ per 2K of u [turn]
        self.cycle_rate = max(self.turn_H, abs(self.lam) / (2.0 * self.K))  # [1/s]
        k0, _, _, _, Pi0 = self._reduce(np.zeros(1))
        self.k0, self.Pi0 = float(k0[0]), float(Pi0[0])

    # ------------------------------------------------------------------ evaluation

    def _reduce(self, t):
        """u = λt + u₀ = 2K k + v with |v| ≤ K, without rounding λt or 2K k."""
        hi, lo = _two_product(self.lam, t)
        K2 = 2.0 * self.K
        k = np.round((hi + (lo + self.u0)) / K2)
        p, e = _two_product(k, K2)
        v = ((hi - p) + (lo - e)) + self.u0
        sn, cn, dn, Pi = self._jacobi(v)
        return k, sn, cn, dn, Pi

    def _jacobi(self, v):
        """sn, cn, dn and Π(n; am v | m) for |v| ≤ K (to rounding), accurate as functions of v.

        For |v| > K/2 the functions are taken at w = K − |v| (DLMF 22.4.3:
        sn(K − w) = cd w, cn(K − w) = k' sd w, dn(K − w) = k' nd w) and
        Π(n; am v) = Π(n | m) − ∫₀ʷ du/(1 − n cd²u); near am = π/2 the amplitude carries
        little information on u when m → 1, whereas at |v| ≤ K/2, dn ≥ √k'.
        """
        av = np.abs(v)
        near = av <= 0.5 * self.K
        r = np.where(near, av, np.maximum(self.K - av, 0.0))
        th = _am(r, self.agm_a, self.agm_c)
        s, c = np.sin(th), np.cos(th)
        d2 = self.m1 + self.m * c * c
        d = np.sqrt(d2)
        sn = np.where(near, s, c / d)
        cn = np.where(near, c, self.kp * s / d)
        dn = np.where(near, d, self.kp / d)
        Pi = np.empty_like(v)  # at |v|, using F(am r) = r exactly
        if np.any(near):
            Pi[near] = r[near] + _pi_minus_f(self.n, s[near], c[near], d2[near])
        far = ~near
        if np.any(far):
            G = r[far]  # (1 − n) ∫₀ʳ du/(1 − n cd²u)
            if self.alpha != 1.0:
                G = G + (1.0 - self.alpha) * _pi_minus_f(self.n2, s[far], c[far], d2[far])
            Pi[far] = self.Pi_c - G / (1.0 - self.n)
        neg = v < 0.0
        return np.where(neg, -sn, sn), cn, dn, np.where(neg, -Pi, Pi)

    def _phase(self, t):
        """(x₁, x₂, x₃) = (ω₁/a₁, ω₂/a₂, ω₃/a₃) and the precession angle φ(t) − φ(0) [turn]."""
        if self.kind == "separatrix":
            u = self.lam * t + self.u0
            e = np.exp(-np.abs(u))
            sech = 2.0 * e / (1.0 + e * e)
            th = np.tanh(u)
            turns = (_fraction(*_two_product(t, self.turn_H))
                     + self.amp * (np.arctan(self.nu * th) - self.atan0) / _TWO_PI)
            return self.sig1 * sech, th, self.sig3 * sech, turns
        k, sn, cn, dn, Pi = self._reduce(t)
        odd = np.fmod(np.abs(k), 2.0) == 1.0  # sn, cn change sign every 2K
        sn = np.where(odd, -sn, sn)
        cn = np.where(odd, -cn, cn)
        turns = (_fraction(*_two_product(t, self.turn_H))
                 + _fraction(*_two_product(k - self.k0, self.turn_half))
                 + self.Cl * (Pi - self.Pi0) / _TWO_PI)
        return cn, sn, self.sig3 * dn, turns

    def _frame(self, x1, x2, x3) -> tuple[np.ndarray, ...]:
        """Rows of B Pᵀ, each (N, 3), with B = R_x(θ) R_z(ψ) (principal → ĥ frame, up to φ).

        B = [[cψ, −sψ, 0], [cθ sψ, cθ cψ, −sθ], [sθ sψ, sθ cψ, cθ]], its last row ĥ in
        principal axes; products with the columns p_j of P are written out, which for long
        time arrays is much faster than batched 3×3 matrix products.
        """
        J1, _, J3 = self.J
        a1, _, a3 = self.a
        hx, hy = J1 * x1, self.g * x2  # ∝ (ĥ₁, ĥ₂), never both 0
        rho = np.hypot(hx, hy)
        sp, cp = (hx / rho)[:, None], (hy / rho)[:, None]
        ct, st = J3 * a3 * x3, a1 * rho  # ∝ (ĥ₃, |(ĥ₁, ĥ₂)|)
        h = np.hypot(ct, st)
        ct, st = (ct / h)[:, None], (st / h)[:, None]
        p0, p1, p2 = self.P.T  # columns of P
        u = sp * p0 + cp * p1
        return cp * p0 - sp * p1, ct * u - st * p2, st * u + ct * p2

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        N = t.size
        if self.kind == "rest":
            return np.broadcast_to(self.M0, (N, 3, 3)).copy(), np.zeros((N, 3))
        t_max = float(np.max(np.abs(t)))
        if not t_max * self.cycle_rate < _MAX_TURNS:
            raise ValueError(f"t_s must stay below {_MAX_TURNS / self.cycle_rate:g} s in "
                             f"magnitude for these rates (a phase of 2**50 turns, beyond which "
                             f"float64 does not resolve the attitude), got {t_max:g} s")
        if self.kind == "constant":
            turns = _fraction(*_two_product(t, self.turn_rate))
            M = self.M0 @ axis_angle(self.axis, _TWO_PI * turns)
            return M, np.broadcast_to(self.w0, (N, 3)).copy()
        x1, x2, x3, turns = self._phase(t)
        phi = _TWO_PI * (turns - np.round(turns))
        c, s = np.cos(phi), np.sin(phi)
        G0, G1, G2 = self._frame(x1, x2, x3)
        L = self.L
        M = np.empty((N, 3, 3))
        for i in range(3):  # M = L R_z(φ) (B Pᵀ), row by row
            M[:, i, :] = ((L[i, 0] * c + L[i, 1] * s)[:, None] * G0
                          + (L[i, 1] * c - L[i, 0] * s)[:, None] * G1 + L[i, 2] * G2)
        p0, p1, p2 = self.P.T
        a1, a2, a3 = self.w_scale * self.a
        w = (a1 * x1)[:, None] * p0 + (a2 * x2)[:, None] * p1 + (a3 * x3)[:, None] * p2
        return M, w


def torque_free(t_s, R0_inertial_from_body, omega0_body_rad_s, inertia_body_kg_m2):
    """Torque-free rigid-body attitude and body rate, in closed form.

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
        ``t_s`` so long that the phase exceeds 2⁵⁰ turns (or 2⁵⁰ half polhode periods),
        beyond which float64 times no longer resolve the attitude.

    Notes
    -----
    Solves ``J ω̇ = −ω × (J ω)``, ``Ṁ = M [ω]×`` in closed form (Landau & Lifshitz §37;
    Markley & Crassidis §3.5). With J = P diag(J₁, J₂, J₃) Pᵀ (principal axes relabelled so
    that axis 3 is the one the polhode circles), the rate in principal axes is
    ``(a₁ cn u, a₂ sn u, ±a₃ dn u)``, u = λt + u₀, Jacobi elliptic functions of parameter m
    (DLMF §22), evaluated by the arithmetic-geometric mean. The attitude is
    ``M(t) = C R_z(φ(t)) B(t) Pᵀ``: B(t) = R_x(θ) R_z(ψ) takes ĥ = Jω/|Jω| (principal
    axes) to ẑ, so θ and ψ follow from ω(t); C is constant (ẑ → the inertial angular
    momentum direction); the precession angle φ about it is
    ``|H| t/J₃ + (C'/λ) Π(n; am u | m)``, with Π the incomplete elliptic integral of the
    third kind in Carlson's form (R_J; DLMF §19.25). See ``_TorqueFreeMotion``.

    The cost is a set-up of a few dozen scalar operations plus a fixed number of vectorised
    operations per requested time (an AGM of ≲ 15 steps, one R_J), independent of the times
    and rates: over a 2800 s window at 3600 deg/s per axis, 48 times take ≈ 2 ms and 10⁶
    times ≈ 1 s. Long times keep their precision: u is reduced modulo 2K and the secular
    parts of φ modulo one turn with exact products (Dekker 1971), so the error grows only
    with the rounding of the phase itself (≈ 1e-16 × the number of radians turned, 1e-7 rad
    after 1e7 s at 10 rev/s).

    Special cases: ω₀ = 0 (M = M₀); ω₀ along a principal axis (exactly: J ω₀ × ω₀ = 0) or
    J spherical, ω constant and ``M = M₀ Rot(ω̂₀, |ω₀| t)``; axisymmetric bodies (m = 0,
    regular precession); rates near a principal axis (θ, ψ from ratios that stay defined);
    the separatrix H² = 2EJ₂ (m = 1: sn = tanh, cn = dn = sech and φ elementary; ω tends
    to the intermediate axis for t → ±∞, with no period).

    Near the separatrix the motion itself is ill-conditioned: a relative change δ of ω₀
    changes 1 − m by ≈ δ/(1 − m) relative, hence the time spent near the intermediate axis
    (≈ ln(16/(1 − m))/(2|λ|) per half period) by ≈ δ/(2|λ|(1 − m)). The sign of H² − 2EJ₂ and
    1 − m are computed in exact rational arithmetic from the (float64) inputs in principal
    axes, so for a diagonal J no precision is lost there; a non-diagonal J adds the
    ≈ 1e-16 relative error of its eigen-decomposition.

    Accuracy, as rotation angle from DOP853 (rtol = atol = 1e-13) over −1.5 to 4 polhode
    periods, diagonal and non-diagonal inertias, both polhode families, near-axisymmetric
    and near a principal axis: ≤ 5e-12 rad (≤ 2e-11 over 60 random cases), body rate
    ≤ 1.1e-12 relative; at 1 − m = 2e-4, 7e-11 rad, the integrator's own error. Against
    a 25–30-digit Taylor integration at 1 − m = 2e-6, 2e-10 and 2e-13 the closed form is
    within 2e-14, 8e-13 and 3e-12 rad (DOP853: 2e-10, 3e-5 and 2e-3 rad). Energy ½ωᵀJω and
    the inertial angular momentum M J ω are conserved to ≈ 1e-15 relative at any time.
    """
    t, scalar = _times(t_s)
    R0 = finite_array("R0_inertial_from_body", R0_inertial_from_body)
    if R0.shape != (3, 3) or not bool(is_rotation(R0, _ROTATION_ATOL)):
        raise ValueError(f"R0_inertial_from_body must be a 3x3 rotation matrix, got {R0.tolist()}")
    w0 = finite_array("omega0_body_rad_s", omega0_body_rad_s)
    if w0.shape != (3,):
        raise ValueError(f"omega0_body_rad_s must have shape (3,), got {w0.shape}")
    J = _inertia("inertia_body_kg_m2", inertia_body_kg_m2)

    M0 = orthonormalize(R0)
    uniq, inverse = np.unique(t, return_inverse=True)
    M, w = _TorqueFreeMotion(M0, w0, J)(uniq)
    at_zero = uniq == 0.0
    M[at_zero] = M0
    w[at_zero] = w0
    inverse = inverse.reshape(-1)
    M, w = M[inverse], w[inverse]
    return (M[0], w[0]) if scalar else (M, w)


@dataclass(frozen=True, slots=True)
class TargetAttitude:
    """Attitude law of the target, ``R_lvlh_from_body(t)`` (docs/orbit.md, "Target attitude").

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
        scale = float(np.max(np.abs(axis)))  # scaled first: |axis| may underflow
        if not scale > 0.0:
            raise ValueError(f"spin_axis_body must be a non-zero 3-vector, got {axis.tolist()}")
        axis = axis / scale
        norm = float(np.linalg.norm(axis))

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
