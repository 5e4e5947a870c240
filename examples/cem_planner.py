"""A cross-entropy method (CEM) planner of one's own, written against the Planner base class,
run with ``run_episode`` and compared with MPPI on the same plan and objective.

    python examples/cem_planner.py softrom_gym/CrossSwim-v0 --seconds 2

Each replan samples knots around the sampling mean (the warm-started plan, kept as sample 0),
scores them in one batched rollout, and refits the mean and standard deviation to the best
``elites``; the plan takes the last mean. ``Planner`` supplies the rest: the spline, the warm
start, the gait seed at reset, the seeded random stream and the objective R - Λ.

A planner chosen by its import path runs wherever "mppi" and "gn" do, with the benchmark's
plan and objective and its settings class's own defaults (from the repository's root)::

    python -m controllers CrossSwim-v0 --planner examples.cem_planner:CEM --seconds 2
    rbbo optimize CrossSwim-v0 --controller examples.cem_planner:CEM --budget 10m
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from controllers import Planner, PlannerSettings, planner_for, run_episode


@dataclass(frozen=True)
class CEMSettings(PlannerSettings):
    """:class:`PlannerSettings` plus the sampling: ``samples`` per iteration, the best
    ``elites`` refit the distribution, ``iterations`` per replan, ``noise`` the first
    iteration's standard deviation (units of the action bound)."""

    samples: int = 8
    elites: int = 2
    iterations: int = 2
    noise: float = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 2 <= self.elites <= self.samples:
            raise ValueError(f"elites must be in [2, samples = {self.samples}], got {self.elites}")
        if self.iterations < 1 or not self.noise >= 0:
            raise ValueError(f"need iterations >= 1 and noise >= 0, got {self.iterations}, "
                             f"{self.noise}")  # fmt: skip


class CEM(Planner):
    """The cross-entropy method over the plan's knots."""

    name = "cem"
    settings: CEMSettings
    settings_class = CEMSettings

    def optimise(self, state: Any) -> None:
        s, plan = self.settings, self.spline
        mean, std = plan.knots.copy(), np.full(plan.knots.shape, s.noise)
        best = -np.inf
        for i in range(s.iterations):
            samples = mean + std * self.rng_.standard_normal((s.samples, *mean.shape))
            samples[0] = mean  # the warm start competes: a replan can keep it
            samples = np.clip(samples, -1.0, 1.0)
            j = self.evaluate_knots(state, samples).objective
            if i == 0:
                self.last_["objective_start"] = float(j[0])
            best = max(best, float(j.max()))
            elite = samples[np.argsort(j)[-s.elites :]]
            mean, std = elite.mean(axis=0), elite.std(axis=0)
        plan.knots = mean
        self.last_["objective_best"] = best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("env_id", nargs="?", default="softrom_gym/CrossSwim-v0")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    env = gym.make(args.env_id)
    dt = env.get_wrapper_attr("dt")
    mppi, every = planner_for(args.env_id, "mppi", dt=dt)
    # MPPI's plan, gait seed and objective (a benchmark's tuned ones, else the shared ones);
    # CEM's defaults roll out 16 plans a replan, as MPPI's 16 samples on the benchmarks
    cem = CEM(CEMSettings.from_shared(mppi.settings), dt=dt)
    for planner in (mppi, cem):
        result = run_episode(env, planner, args.seconds, replan_every=every, seed=args.seed,
                             progress=False)  # fmt: skip
        print(result.summary(start=0.0))


if __name__ == "__main__":
    main()
