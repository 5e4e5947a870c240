"""Checks of user input shared by the robots and the envs."""

from __future__ import annotations

import numpy as np


def real(name: str, value: object) -> float:
    """``value`` as a float. A bool, a string or None is named, not read as a number; a 0-d
    array (``np.array(900.0)``) is its number."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(
        value, (int, float, np.integer, np.floating)
    ):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    return float(value)


def integer(name: str, value: object) -> int:
    """``value`` as an int. A bool (Python's or numpy's) or a float is named, not read as a
    count (``True`` would be 1, ``2.5`` fail later as a slice index)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    return int(value)


def real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array. A complex array is refused (casting would drop its
    imaginary part with a warning only), a boolean one too (True would act as 1.0), and so is
    anything that is not numbers, each naming ``name`` and what it got."""
    raw = np.asarray(value)
    if raw.dtype.kind in "bc":
        raise ValueError(f"{name} must be real numbers, got a {raw.dtype} array: {raw}")
    # numpy casts None to nan, which would be reported as a non-finite number (or, for a lone
    # None, as an array of shape ())
    if raw.dtype.kind == "O" and any(v is None for v in raw.flat):
        raise ValueError(f"{name} must be real numbers, got {value!r}")
    try:
        return np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be real numbers, got {value!r}") from None
