"""MPPI in control space: reward-weighted averaging of sampled knot perturbations.

Each iteration of a replan draws N - 1 perturbations of the knots F~_c (Gaussian, standard
deviation ``noise`` in units of the action bound, one for all control dimensions or one per
dimension, clipped so that every knot stays within the bound), keeps the current plan as
sample 0, runs all N in one batched ``rollout``, and moves the knots to the weighted mean with
weights ``exp((J_i - max J) / (temperature * spread))``: J_i = R - Λ of sample i and the
spread the range of J over the samples, so the temperature is dimensionless (0.1: a sample
10 % of the range below the best weighs 1/e).

With several iterations per replan, ``noise_decay`` γ anneals the search: iteration i draws
with standard deviation γ^i ``noise``, so later rounds refine around the mean the earlier
ones moved to (the geometric schedule of annealed MPPI and of the cross-entropy method's
shrinking sampling distribution; γ = 1, the default, draws every round alike). Measured with
``python benchmarks/bench_mpc.py BeamWalk-v0 CrossWalk-v0 CrossSwim-v0 --planners mppi
--seeds 0 1 2 --mpc iterations=3[,noise_decay=0.5]`` (t = 2..10 s, body lengths, mean ± sd
over seeds; AMD EPYC, 2026-12-05): three rounds at γ = 1 walked 1.556 ± 0.083 (beam), 0.856 ±
0.092 (cross) and swam 3.040 ± 0.060, at γ = 0.5 1.537 ± 0.005, 0.839 ± 0.127 and 2.970 ±
0.034: no gain on these, so the benchmarks' planners (one round, ``controllers.defaults``)
keep γ = 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .planner import Planner
from .settings import PlannerSettings, _check_int, _check_positive, _real_tuple

__all__ = ["MPPI", "MPPISettings"]


@dataclass(frozen=True)
class MPPISettings(PlannerSettings):
    """:class:`PlannerSettings` plus

    Attributes
    ----------
    samples : int
        N >= 2, rollouts per iteration: the current plan and N - 1 perturbations of it.
    noise : float or tuple of float
        Standard deviation of the knot perturbations, in units of the action bound (>= 0;
        0 returns the warm start): one for every control dimension, or a sequence of one per
        dimension (C numbers, checked against the env at :meth:`MPPI.reset`; a dimension at 0
        keeps its knots).
    temperature : float
        lambda > 0, relative to the spread of the objective over the samples.
    iterations : int
        Sampling rounds per replan.
    noise_decay : float
        γ in (0, 1]: iteration i of a replan draws with standard deviation γ^i ``noise``
        (annealing; 1 draws every iteration alike). Matters only with ``iterations > 1``.
    """

    samples: int = 16
    noise: float | tuple[float, ...] = 0.3
    temperature: float = 0.1
    iterations: int = 1
    noise_decay: float = 1.0

    # Added after runs began recording their planner; at these values MPPI plans as it did
    # before they existed (see PlannerSettings.record).
    _neutral_since_records: ClassVar[dict[str, Any]] = {"noise_decay": 1.0}

    def __post_init__(self) -> None:
        super().__post_init__()
        # N = 1 would be the current plan alone, never perturbed: a replan that does nothing
        # (noise = 0 says that on purpose).
        _check_int("samples", self.samples, low=2)
        if isinstance(self.noise, (list, tuple, np.ndarray)):
            sigma = _real_tuple(self, "noise")
            if sigma.size == 0 or not np.all(np.isfinite(sigma) & (sigma >= 0)):
                raise ValueError(
                    "noise must be a finite number >= 0 or a sequence of them (one per control "
                    f"dimension), got {self.noise!r}"
                )
        else:
            _check_positive("noise", self.noise, allow_zero=True)
        _check_positive("temperature", self.temperature)
        _check_int("iterations", self.iterations)
        _check_positive("noise_decay", self.noise_decay)
        if self.noise_decay > 1:
            raise ValueError(f"noise_decay must be in (0, 1], got {self.noise_decay!r}")

    def check_control_dim(self, control_dim: int) -> None:
        if isinstance(self.noise, tuple) and len(self.noise) != control_dim:
            raise ValueError(
                f"noise has {len(self.noise)} standard deviations, one per control dimension, "
                f"but the env has C = {control_dim}: give {control_dim} numbers, or one number "
                "(not in a sequence) for every dimension"
            )


class MPPI(Planner):
    """Model-predictive path integral control over spline knots (see the module docstring)."""

    name = "mppi"
    settings: MPPISettings
    settings_class = MPPISettings

    def __init__(self, settings: MPPISettings | None = None, *, dt: float | None = None) -> None:
        settings = MPPISettings() if settings is None else settings
        if not isinstance(settings, MPPISettings):
            raise TypeError(f"settings must be MPPISettings, got {type(settings).__name__}")
        super().__init__(settings, dt=dt)

    def optimise(self, state: Any) -> None:
        s, plan = self.settings, self.spline
        # (a scalar for a scalar noise, so the draws are those of before per-dimension noise)
        noise = s.noise if not isinstance(s.noise, tuple) else np.asarray(s.noise)
        history = []
        for i in range(s.iterations):
            sigma = noise * s.noise_decay**i  # γ^0 = 1: the first round's noise as given
            eps = sigma * self.rng_.standard_normal((s.samples, *plan.knots.shape))
            eps[0] = 0.0
            samples = np.clip(plan.knots[None] + eps, -1.0, 1.0)
            ev = self.evaluate_knots(state, samples)
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
