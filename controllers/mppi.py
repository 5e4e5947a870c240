"""MPPI in control space: reward-weighted averaging of sampled knot perturbations.

Each iteration of a replan draws N - 1 perturbations of the knots F~_c (Gaussian, standard
deviation ``noise`` in units of the action bound, clipped so that every knot stays within
the bound), keeps the current plan as sample 0, runs all N in one batched ``rollout``, and
moves the knots to the weighted mean with weights ``exp((J_i - max J) / (temperature *
spread))``: J_i = R - Λ of sample i and the spread the range of J over the samples, so the
temperature is dimensionless (0.1: a sample 10 % of the range below the best weighs 1/e).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .planner import Planner, PlannerSettings, _check_int, _check_positive

__all__ = ["MPPI", "MPPISettings"]


@dataclass(frozen=True)
class MPPISettings(PlannerSettings):
    """:class:`PlannerSettings` plus

    Attributes
    ----------
    samples : int
        N >= 2, rollouts per iteration: the current plan and N - 1 perturbations of it.
    noise : float
        Standard deviation of the knot perturbations, in units of the action bound (>= 0;
        0 returns the warm start).
    temperature : float
        lambda > 0, relative to the spread of the objective over the samples.
    iterations : int
        Sampling rounds per replan.
    """

    samples: int = 16
    noise: float = 0.3
    temperature: float = 0.1
    iterations: int = 1

    def __post_init__(self) -> None:
        super().__post_init__()
        # N = 1 would be the current plan alone, never perturbed: a replan that does nothing
        # (noise = 0 says that on purpose).
        _check_int("samples", self.samples, low=2)
        _check_positive("noise", self.noise, allow_zero=True)
        _check_positive("temperature", self.temperature)
        _check_int("iterations", self.iterations)


class MPPI(Planner):
    """Model-predictive path integral control over spline knots (see the module docstring)."""

    name = "mppi"
    settings: MPPISettings

    def __init__(self, settings: MPPISettings | None = None, *, dt: float | None = None) -> None:
        settings = MPPISettings() if settings is None else settings
        if not isinstance(settings, MPPISettings):
            raise TypeError(f"settings must be MPPISettings, got {type(settings).__name__}")
        super().__init__(settings, dt=dt)

    def _optimise(self, state: Any) -> None:
        s, plan = self.settings, self._plan
        history = []
        for _ in range(s.iterations):
            eps = s.noise * self.rng_.standard_normal((s.samples, *plan.knots.shape))
            eps[0] = 0.0
            samples = np.clip(plan.knots[None] + eps, -1.0, 1.0)
            ev = self._evaluate(state, samples)
            j = ev.objective
            spread = float(j.max() - j.min())
            if spread > 0:
                w = np.exp((j - j.max()) / (s.temperature * spread))
            else:
                w = np.ones_like(j)
            w /= w.sum()
            # Averaging the differences keeps the warm start exact when they are all zero.
            plan.knots = plan.knots + np.einsum("b,bkc->kc", w, samples - plan.knots[None])
            history.append((float(j[0]), float(j.max())))
        self.last_.update(
            objective_start=history[0][0],
            objective_best=max(h[1] for h in history),
            effective_samples=float(1.0 / np.sum(w**2)),
        )
