"""Input validation shared by the public functions of :mod:`degrade`.

Every check raises ``ValueError`` whose message names the parameter, says what is allowed
and shows what arrived (docs/degradation.md). Same rules as
``orbit/_checks.py``, restated here because ``degrade`` imports nothing from ``orbit``.

Image dtype policy: images are real floating-point arrays. float32 passes through without a
copy; float16 and float64 are converted to float32 (the output of every public function is
float32), except where a function must reproduce another library's float64 arithmetic
(``keep_float64``, the paper-mode noise functions). Integer arrays are refused: their scale
(8-bit codes? raw DN?) is ambiguous.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np


def finite_scalar(name: str, value, *, positive: bool = False, nonnegative: bool = False) -> float:
    """Return ``value`` as a Python float, or raise if it is not a finite real number."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    is_real = isinstance(value, (Real, np.number)) and not isinstance(value, (bool, np.bool_))
    if not is_real:
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and not value > 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    if nonnegative and not value >= 0.0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return value


def fraction(name: str, value) -> float:
    """Return ``value`` as a Python float in [0, 1], or raise."""
    value = finite_scalar(name, value, nonnegative=True)
    if value > 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return value


def integer(name: str, value, lo: int, hi: int) -> int:
    """Return ``value`` as an int in ``[lo, hi]``, or raise."""
    is_int = isinstance(value, (Integral, np.integer)) and not isinstance(value, (bool, np.bool_))
    if not is_int or not lo <= int(value) <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def instance(name: str, value, cls: type):
    """Return ``value`` if it is a ``cls``, else raise ValueError (ValueError at public
    boundaries, also for a wrong type)."""
    is_cls = isinstance(value, cls)
    if not is_cls:
        raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
    return value


def flag(name: str, value) -> bool:
    """Return ``value`` as a bool if it is True or False (Python or NumPy), else raise."""
    is_bool = isinstance(value, (bool, np.bool_))
    if not is_bool:
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def one_of(name: str, value, allowed):
    """Return ``value`` if it is one of ``allowed``, else raise listing them."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}; got {value!r}")
    return value


def image(name: str, value, *, ndim: tuple[int, ...] = (2, 3), channels: int | None = None,
          max_value: float | None = None, keep_float64: bool = False, values: bool = True) -> np.ndarray:
    """Return ``value`` as a C-contiguous float32 image after checking it.

    Parameters
    ----------
    name : str
        Parameter name used in error messages.
    value : array_like
        A real floating-point array (float32 is passed through without a copy).
    ndim : tuple of int
        Allowed numbers of dimensions (2: H×W, 3: H×W×C).
    channels : int, optional
        Required C when the image is 3-D.
    max_value : float, optional
        Largest allowed value (e.g. 1 for display-encoded images); the minimum is always 0.
    keep_float64 : bool
        Return float64 input as float64 (for functions that must reproduce another
        library's float64 arithmetic bit for bit).
    values : bool
        Check the values (finite, ≥ 0, ≤ ``max_value``). False: only type and shape, for a
        caller whose kernel scans the values on its way and calls again with True when it
        found a bad one (that call raises the message of the bad value).
    """
    arr = np.asarray(value)
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{name} must be a float array (float32 preferred; 8-bit codes must be "
                         f"divided by 255 first), got dtype {arr.dtype}")
    if arr.ndim not in ndim:
        allowed = " or ".join(str(d) for d in ndim)
        raise ValueError(f"{name} must have {allowed} dimensions (H×W or H×W×C), got shape {arr.shape}")
    if arr.ndim == 3 and channels is not None and arr.shape[2] != channels:
        raise ValueError(f"{name} must have {channels} channels (H×W×{channels}), got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty, got shape {arr.shape}")
    keep = keep_float64 and arr.dtype == np.float64
    arr = np.ascontiguousarray(arr, dtype=np.float64 if keep else np.float32)
    if not values:
        return arr
    lo, hi = float(arr.min()), float(arr.max())
    if not (math.isfinite(lo) and math.isfinite(hi)):
        bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name} must be finite, got {bad} NaN/inf value(s)")
    if lo < 0.0:
        raise ValueError(f"{name} must be >= 0 everywhere, got minimum {lo!r}")
    if max_value is not None and hi > max_value:
        raise ValueError(f"{name} must be <= {max_value} everywhere, got maximum {hi!r}")
    return arr
