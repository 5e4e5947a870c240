"""Open-loop sinusoid gaits in control space: the baseline and the planners' gait seeds.

A gait drives each control dimension j with ``f_c,j(t) = A a sin(2 pi f t + phi_j)``, A a
fraction of the action bound a, f in Hz and phi_j the phase of mode j. A *phase order* is the
order in which the C modes peak: a travelling wave through the modes (phases a permutation
of 0, 2 pi / C, ...) or a standing wave (phases 0 or pi), see :func:`phase_orders`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ["SinusoidGait", "gait_grid", "phase_orders"]


def phase_orders(control_dim: int) -> list[tuple[float, ...]]:
    """Phase vectors (rad), the first mode's phase fixed at 0 (a time shift of the others).

    The travelling waves: every order of C equally spaced phases ((C - 1)! of them, C <= 4;
    the two directions beyond). The standing waves: every sign pattern of the modes, phases
    0 or pi (2^(C - 1) of them, C <= 4; all in phase beyond).
    """
    if isinstance(control_dim, bool) or not isinstance(control_dim, (int, np.integer)):
        raise TypeError(f"control_dim must be an int, got {control_dim!r}")
    if control_dim < 1:
        raise ValueError(f"control_dim must be >= 1, got {control_dim}")
    c = int(control_dim)
    base = 2 * np.pi * np.arange(c) / c
    if c <= 4:
        travelling = [(0.0, *(float(base[i]) for i in p))
                      for p in itertools.permutations(range(1, c))]  # fmt: skip
        standing = [(0.0, *(np.pi * np.array(s, dtype=float)).tolist())
                    for s in itertools.product((0, 1), repeat=c - 1)]  # fmt: skip
    else:
        travelling = [tuple(base.tolist()), tuple((-base % (2 * np.pi)).tolist())]
        standing = [(0.0,) * c]
    return list(dict.fromkeys(travelling + standing))


@dataclass(frozen=True)
class SinusoidGait:
    """``f_c,j(t) = amplitude * bound * sin(2 pi frequency t + phases[j])``.

    Attributes
    ----------
    frequency : float
        Hz.
    amplitude : float
        Fraction of the action bound a (values above 1 are clipped by the env: square-ish).
    phases : tuple of float
        Phase of each control dimension, rad.
    """

    frequency: float
    amplitude: float
    phases: tuple[float, ...]

    def controls(self, steps: int, dt: float, bound: float, t0: float = 0.0) -> np.ndarray:
        """f_c (steps, C) at the start of each control period, t = t0 + k dt."""
        t = t0 + dt * np.arange(steps)
        arg = 2 * np.pi * self.frequency * t[:, None] + np.asarray(self.phases)[None, :]
        return self.amplitude * bound * np.sin(arg)

    def label(self) -> str:
        """A short name: frequency, amplitude and phases in degrees ("2Hz A=1 phases=0/120/240")."""
        degrees = "/".join(str(round(np.degrees(p))) for p in self.phases)
        return f"{self.frequency:g}Hz A={self.amplitude:g} phases={degrees}"


def gait_grid(
    control_dim: int, frequencies: tuple[float, ...], amplitudes: tuple[float, ...]
) -> list[SinusoidGait]:
    """Every (frequency, amplitude, phase order) combination."""
    for name, values in (("frequencies", frequencies), ("amplitudes", amplitudes)):
        v = np.asarray(values, dtype=float)
        if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"{name} must be a non-empty list of positive numbers, got {values!r}")
    return [
        SinusoidGait(float(f), float(a), p)
        for f in frequencies
        for a in amplitudes
        for p in phase_orders(control_dim)
    ]
