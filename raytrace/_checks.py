"""Input checks at the public boundaries of ``raytrace``: numbers that are numbers, finite and in
range, unit vectors, rotations. Each raises ``ValueError`` with one line that names the
parameter and says what is allowed (callers add where the value came from)."""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["only_numbers", "finite_number", "finite_numbers", "unit3", "rotation"]


def only_numbers(value) -> bool:
    """Whether ``value`` (a number, a nested list or tuple, or an array) holds numbers only:
    no text or truth values, which ``np.asarray(..., float)`` would also take ("1361", True)."""
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    if isinstance(value, (list, tuple)):
        return all(only_numbers(x) for x in value)
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def finite_number(name: str, value, lo: float, hi: float = math.inf, lo_open: bool = False) -> float:
    """``value`` as a float in [lo, hi] (or (lo, hi] with ``lo_open``): a number, not text or a
    truth value that float() would also take ("1361", True)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo):
        lo_txt = f"({lo:g}" if lo_open else f"[{lo:g}"
        raise ValueError(f"{name} must be a finite number in {lo_txt}, {hi:g}], got {value!r}")
    return x


def finite_numbers(name: str, value, n: int, *, strict: bool = False) -> np.ndarray:
    """``value`` (flat or nested) as ``n`` finite float64 numbers; ``strict``: numbers only, as
    JSON writes them (no strings or booleans, :func:`only_numbers`)."""
    if strict and not only_numbers(value):
        raise ValueError(f"{name} must be {n} numbers (JSON numbers, not strings or booleans), got {value!r}")
    try:
        a = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be {n} finite numbers, got {value!r}")
    return a


def unit3(name: str, value) -> tuple:
    """A unit 3-vector (norm within 1e-3 of 1), renormalised, as a tuple of floats."""
    if not only_numbers(value):
        raise ValueError(f"{name} must be a unit 3-vector of numbers, got {value!r}")
    try:
        v = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a unit 3-vector, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    n = float(np.linalg.norm(v))
    if not 0.999 <= n <= 1.001:
        raise ValueError(f"{name} must be a unit vector (norm within 1e-3 of 1), got norm {n:.6g}")
    return tuple((v / n).tolist())


def rotation(name: str, value, when: str = "") -> np.ndarray:
    """A 3×3 rotation matrix (orthonormal to 1e-6, det +1); ``when``: a clause for the message."""
    R = None if value is None else np.asarray(value, dtype=np.float64)
    if R is None or R.shape != (3, 3) or not np.all(np.isfinite(R)) \
            or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a 3x3 rotation matrix (orthonormal, det +1){when}")
    return R
