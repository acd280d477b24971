"""Input validation shared by the public functions of :mod:`orbit`.

Every check raises ``ValueError`` whose message names the parameter, says what is allowed
and shows what arrived (docs/orbit.md, "Library API").
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np


def finite_scalar(name: str, value, *, positive: bool = False, nonnegative: bool = False) -> float:
    """Return ``value`` as a Python float, or raise if it is not a finite real number."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.number)):
        if isinstance(value, np.ndarray) and value.ndim == 0:
            value = value.item()
        else:
            raise ValueError(f"{name} must be a finite real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and not value > 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    if nonnegative and not value >= 0.0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return value


def finite_array(name: str, value, *, shape_tail: tuple[int, ...] | None = None,
                 ndim: tuple[int, ...] | None = None) -> np.ndarray:
    """Return ``value`` as a float64 array after checking its shape and finiteness.

    Parameters
    ----------
    name : str
        Parameter name used in error messages.
    value : array_like
        The input (float32 and integer inputs are promoted to float64).
    shape_tail : tuple of int, optional
        Required trailing shape, e.g. ``(6,)`` for states or ``(3,)`` for vectors.
    ndim : tuple of int, optional
        Allowed numbers of dimensions.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}") from None
    if ndim is not None and arr.ndim not in ndim:
        allowed = " or ".join(str(d) for d in ndim)
        raise ValueError(f"{name} must have {allowed} dimension(s), got shape {arr.shape}")
    if shape_tail is not None:
        k = len(shape_tail)
        if arr.ndim < k or arr.shape[arr.ndim - k:] != tuple(shape_tail):
            want = "(..., " + ", ".join(str(s) for s in shape_tail) + ")"
            raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name} must be finite, got {bad} NaN/inf value(s)")
    return arr


def mean_motion(name: str, n) -> float:
    """Validate a mean motion n [rad/s]: finite and > 0."""
    return finite_scalar(name, n, positive=True)


def one_of(name: str, value, allowed) -> str:
    """Return ``value`` if it is one of ``allowed`` (strings), else raise listing them."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(allowed)}; got {value!r}")
    return value
