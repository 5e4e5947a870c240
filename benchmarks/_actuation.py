"""Shared by the benchmark scripts: the five benchmarks (``BENCHMARKS``: name -> robot, task)
and the modal forces they drive the robots with.

``random``: uniform random forces of up to 0.5 body weight in each control direction, drawn
anew every step (a stress test: the contact state changes from step to step). ``gait``: one
open-loop sinusoid per rollout, frequency 0.5-4 Hz, amplitude 0.5-1 body weight and a random
phase per direction (smooth, as a controller's splines are). Body weight in modal units is
sqrt(m) g, B_r being mass-orthonormal. The same seed gives the same forces in every script.
"""

from __future__ import annotations

import numpy as np

G = 9.81
KINDS = ("random", "gait")
BENCHMARKS = {
    "cross-swim": ("cross", "swim"),
    "cross-walk": ("cross", "walk"),
    "beam-walk": ("beam", "walk"),
    "quadruped-walk": ("quadruped", "walk"),
    "tripod-walk": ("tripod", "walk"),
}


def modal_forces(model, shape: tuple[int, int, int], seed: int = 0, kind: str = "random"):
    """Forces of shape (rollouts, steps, directions) for ``model`` (its ``total_mass``, and
    its ``dt`` for a gait)."""
    rng = np.random.default_rng(seed)
    weight = np.sqrt(model.total_mass) * G
    if kind == "random":
        return 0.5 * weight * rng.uniform(-1.0, 1.0, shape)
    if kind != "gait":
        raise ValueError(f"actuation must be one of {KINDS}, got {kind!r}")
    rollouts, steps, directions = shape
    t = np.arange(steps) * model.dt
    out = np.empty(shape)
    for b in range(rollouts):
        f, a = rng.uniform(0.5, 4.0), rng.uniform(0.5, 1.0)
        phase = rng.uniform(0, 2 * np.pi, directions)
        out[b] = a * weight * np.sin(2 * np.pi * f * t[:, None] + phase[None, :])
    return out
