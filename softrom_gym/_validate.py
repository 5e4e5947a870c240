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
