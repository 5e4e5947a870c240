"""Confidence intervals for the numbers rbbo reports (R_init, R*, RL and MPC distances)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["confidence_interval"]


def confidence_interval(values, level: float = 0.95) -> tuple[float, float]:
    """Mean and half-width of the two-sided Student-t interval of ``values``:
    mean ± t_{(1 + level) / 2, n - 1} s / sqrt(n). The half-width is nan for n < 2 (and the
    mean too for n = 0)."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan
    half = float(stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, half
