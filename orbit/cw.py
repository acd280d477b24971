"""Clohessy–Wiltshire (Hill) relative motion about a circular target orbit.

State convention (docs/conventions.md): ``s = [x, y, z, ẋ, ẏ, ż]`` is the observer's
position relative to the target in the target's LVLH frame (x radial out, y along-track, z orbit
normal) [m] and its derivative in the rotating frame [m/s]. Equations: docs/orbit.md,
"Relative motion (Clohessy–Wiltshire)".

Everything here is closed form and vectorised over time: no time stepping.

References
----------
W. H. Clohessy and R. S. Wiltshire, "Terminal guidance system for satellite rendezvous",
J. Aerospace Sci. 27(9), 653–658 (1960), doi:10.2514/8.8704.
"""

from __future__ import annotations

import numpy as np

from ._checks import finite_array, mean_motion

__all__ = ["system_matrix", "stm", "propagate"]


def system_matrix(n: float) -> np.ndarray:
    """CW system matrix A with ṡ = A s.

    Parameters
    ----------
    n : float
        Mean motion of the circular target orbit [rad/s].

    Returns
    -------
    A : ndarray, shape (6, 6), float64
        ``[[0, I], [diag(3n², 0, −n²), [[0, 2n, 0], [−2n, 0, 0], [0, 0, 0]]]]`` [1/s, 1/s²].
    """
    n = mean_motion("n", n)
    A = np.zeros((6, 6))
    A[0:3, 3:6] = np.eye(3)
    A[3, 0] = 3.0 * n * n
    A[5, 2] = -n * n
    A[3, 4] = 2.0 * n
    A[4, 3] = -2.0 * n
    return A


def _times(t_s) -> tuple[np.ndarray, bool]:
    t = finite_array("t_s", t_s, ndim=(0, 1))
    return np.atleast_1d(t), t.ndim == 0


def stm(n: float, t_s) -> np.ndarray:
    """Closed-form CW state transition matrix Φ(t), s(t) = Φ(t) s(0).

    Parameters
    ----------
    n : float
        Mean motion [rad/s].
    t_s : float or array_like, shape (N,)
        Times since the initial state [s]; negative times propagate backwards.

    Returns
    -------
    Phi : ndarray, shape (6, 6) for scalar ``t_s``, else (N, 6, 6), float64
        State transition matrices [mixed units: 1, s, 1/s].

    Notes
    -----
    With S = sin nt, C = cos nt (the closed-form solution of Clohessy and Wiltshire)::

        [4−3C,      0, 0,   S/n,       2(1−C)/n,    0  ]
        [6(S−nt),   1, 0,   2(C−1)/n,  (4S−3nt)/n,  0  ]
        [0,         0, C,   0,         0,           S/n]
        [3nS,       0, 0,   C,         2S,          0  ]
        [6n(C−1),   0, 0,   −2S,       4C−3,        0  ]
        [0,         0, −nS, 0,         0,           C  ]

    ``1 − C`` is evaluated as ``2 sin²(nt/2)`` to avoid cancellation at small ``nt``.
    """
    n = mean_motion("n", n)
    t, scalar = _times(t_s)
    nt = n * t
    S = np.sin(nt)
    C = np.cos(nt)
    omc = 2.0 * np.sin(0.5 * nt) ** 2  # 1 - cos(nt), without cancellation
    Phi = np.zeros((t.size, 6, 6))
    Phi[:, 0, 0] = 1.0 + 3.0 * omc
    Phi[:, 0, 3] = S / n
    Phi[:, 0, 4] = 2.0 * omc / n
    Phi[:, 1, 0] = 6.0 * (S - nt)
    Phi[:, 1, 1] = 1.0
    Phi[:, 1, 3] = -2.0 * omc / n
    Phi[:, 1, 4] = (4.0 * S - 3.0 * nt) / n
    Phi[:, 2, 2] = C
    Phi[:, 2, 5] = S / n
    Phi[:, 3, 0] = 3.0 * n * S
    Phi[:, 3, 3] = C
    Phi[:, 3, 4] = 2.0 * S
    Phi[:, 4, 0] = -6.0 * n * omc
    Phi[:, 4, 3] = -2.0 * S
    Phi[:, 4, 4] = 1.0 - 4.0 * omc
    Phi[:, 5, 2] = -n * S
    Phi[:, 5, 5] = C
    return Phi[0] if scalar else Phi


def propagate(s0_lvlh, n: float, t_s) -> np.ndarray:
    """Propagate one relative state to many times at once with the closed-form CW solution.

    Parameters
    ----------
    s0_lvlh : array_like, shape (6,)
        Initial relative state ``[x, y, z, ẋ, ẏ, ż]`` in LVLH at t = 0 [m, m/s].
        float32 and integer inputs are promoted to float64.
    n : float
        Mean motion of the circular target orbit [rad/s].
    t_s : float or array_like, shape (N,)
        Times since the initial state [s], any order, negative allowed.

    Returns
    -------
    s_lvlh : ndarray, shape (N, 6), float64
        States at ``t_s`` [m, m/s]; a scalar ``t_s`` gives shape (1, 6).

    Raises
    ------
    ValueError
        If ``s0_lvlh`` is not a finite 6-vector, ``n`` is not finite and positive, or
        ``t_s`` is not a finite scalar or 1-D array.

    Notes
    -----
    Equivalent to ``stm(n, t_s) @ s0`` but evaluated component-wise::

        x = x₀ + (ẋ₀/n) S + (3x₀ + 2ẏ₀/n)(1 − C)
        y = y₀ − (2ẋ₀/n)(1 − C) + (6x₀ + 4ẏ₀/n) S − (6n x₀ + 3ẏ₀) t
        z = z₀ C + (ż₀/n) S
        ẋ = ẋ₀ C + (3n x₀ + 2ẏ₀) S
        ẏ = ẏ₀ − 2ẋ₀ S − (6n x₀ + 4ẏ₀)(1 − C)
        ż = −n z₀ S + ż₀ C
    """
    s0 = finite_array("s0_lvlh", s0_lvlh)
    if s0.shape != (6,):
        raise ValueError(f"s0_lvlh must have shape (6,), got {s0.shape}")
    n = mean_motion("n", n)
    t, _ = _times(t_s)
    x0, y0, z0, vx0, vy0, vz0 = (float(v) for v in s0)

    nt = n * t
    S = np.sin(nt)
    C = np.cos(nt)
    omc = np.sin(0.5 * nt)
    omc *= omc
    omc *= 2.0  # 1 - cos(nt) without cancellation

    out = np.empty((t.size, 6))
    a = 3.0 * x0 + 2.0 * vy0 / n  # ellipse term
    b = 6.0 * x0 + 4.0 * vy0 / n
    beta = 6.0 * n * x0 + 3.0 * vy0  # along-track drift rate β = (3/2) n x_l: centre moves at -β
    out[:, 0] = x0 + (vx0 / n) * S + a * omc
    out[:, 1] = y0 - (2.0 * vx0 / n) * omc + b * S - beta * t
    out[:, 2] = z0 * C + (vz0 / n) * S
    out[:, 3] = vx0 * C + (n * a) * S
    out[:, 4] = vy0 - 2.0 * vx0 * S - (n * b) * omc
    out[:, 5] = vz0 * C - (n * z0) * S
    return out
