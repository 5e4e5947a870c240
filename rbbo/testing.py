"""Objectives that misbehave on purpose, for testing executors (light imports: spawn-fast).

:class:`FaultyObjective` lets a test choose, through T, what one evaluation does: succeed,
hang, kill its worker process, raise, return NaN, or warn.
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

__all__ = ["FaultyObjective"]


class FaultyObjective:
    """R(B_c, T, seed) = sum(B_c) + seed, except: T = 2 hangs, T = 3 kills the process
    (``os._exit(7)``), T = 4 raises RuntimeError("MPC diverged"), T = 5 returns NaN, T = 6
    warns (RuntimeWarning "the episode diverged once") and succeeds. With ``load_s`` > 0,
    unpickling it (a worker's start) takes that long."""

    HANG, CRASH, RAISE, NAN, WARN = 2.0, 3.0, 4.0, 5.0, 6.0

    def __init__(self, hang_s: float = 60.0, load_s: float = 0.0):
        self.hang_s = hang_s
        self.load_s = load_s

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        time.sleep(self.__dict__.get("load_s", 0.0))

    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float:
        if T == self.HANG:
            time.sleep(self.hang_s)
        elif T == self.CRASH:
            os._exit(7)
        elif T == self.RAISE:
            raise RuntimeError("MPC diverged")
        elif T == self.NAN:
            return float("nan")
        elif T == self.WARN:
            warnings.warn("the episode diverged once", RuntimeWarning, stacklevel=2)
        return float(np.sum(basis) + seed)
