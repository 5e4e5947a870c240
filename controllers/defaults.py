"""Per-benchmark planner defaults: one table, a reason for every value.

Times are env steps of the 40 Hz control period (dt = 0.025 s): 20 steps = 0.5 s.
"""

from __future__ import annotations

from typing import Any

from .cost import CostWeights
from .gauss_newton import GaussNewtonSettings, GaussNewtonShooting
from .mppi import MPPI, MPPISettings
from .planner import Planner, PlannerSettings

__all__ = ["DEFAULTS", "PLANNERS", "default_planner", "default_settings"]

PLANNERS = {"mppi": (MPPI, MPPISettings), "gn": (GaussNewtonShooting, GaussNewtonSettings)}

# Shared by every benchmark, with why:
_COMMON: dict[str, Any] = {
    # A gait, not a lean: the plan is one cycle of a periodic spline, repeated over the
    # horizon, and R counts only the last cycle (window = period), where a pose held after
    # a first lunge gains nothing. The warm start then carries the gait by advancing its phase.
    "knots": 8,  # per cycle: a sinusoid and its first overtones; more knots cost GN rollouts
    "kind": "cubic",  # smooth controls (C1) that still pass through their knots
    "gait_seed": True,  # start from the best sinusoid at the cycle's frequency, not from rest
    "seed_amplitudes": (0.5, 1.0),  # the open-loop grid's amplitudes
    "threads": 2,  # the project's machines have 2 cores
}
# Λ (metres): keep the body upright and on course without outweighing the distance, which
# is a few cm per second: 0.1 rad held 1 s costs 1 mm, a 0.1 m side offset 1 mm, full
# effort on three modes 3 mm; a step lost to a divergence costs 1 m, more than any gait gains.
_WEIGHTS = CostWeights(orientation=0.1, lateral=0.1, effort=1e-3, divergence=1.0)

# Per benchmark: the cycle (period, the open-loop grid's best frequency), the horizon (a
# lead-in cycle plus the scored one, at least 1 s) and how often to replan (half a cycle:
# the plan is a whole gait, so replanning every control period buys little).
DEFAULTS: dict[str, dict[str, Any]] = {
    "CrossSwim-v0": {"period": 20, "horizon": 40, "replan_every": 10},
    "CrossWalk-v0": {"period": 20, "horizon": 40, "replan_every": 10},
    "BeamWalk-v0": {"period": 20, "horizon": 40, "replan_every": 10},
    "QuadrupedWalk-v0": {"period": 20, "horizon": 40, "replan_every": 10},
    "TripodWalk-v0": {"period": 20, "horizon": 40, "replan_every": 10},
}
# Per planner:
_PLANNER: dict[str, dict[str, Any]] = {
    # 16 samples, one round: the most a 2-core replan affords; noise 0.15 of the bound around
    # a gait explores its shape without breaking it; temperature 0.1 of the spread.
    "mppi": {"samples": 16, "noise": 0.15, "temperature": 0.1, "iterations": 1},
    # One iteration per replan (K C + 1 + 4 rollouts); fd_step 0.02 of the bound is above the
    # float32 action rounding (1e-7) and the contact solver's tolerance, small against a gait.
    "gn": {"iterations": 1, "fd_step": 0.02, "damping": 0.01},
}


def _benchmark(env_id: str) -> str:
    name = env_id.split("/")[-1].split(":")[-1]
    if name not in DEFAULTS:
        raise ValueError(f"no defaults for {env_id!r}; benchmarks: {sorted(DEFAULTS)}")
    return name


def default_settings(env_id: str, planner: str) -> tuple[PlannerSettings, int]:
    """The default settings of ``planner`` ("mppi" or "gn") on a benchmark, and its
    replan interval (env steps)."""
    if planner not in PLANNERS:
        raise ValueError(f"unknown planner {planner!r}; valid: {sorted(PLANNERS)}")
    row = dict(DEFAULTS[_benchmark(env_id)])
    replan_every = row.pop("replan_every")
    row["window"] = row["period"]
    cls = PLANNERS[planner][1]
    return cls(**_COMMON, **row, **_PLANNER[planner], weights=_WEIGHTS), replan_every


def default_planner(env_id: str, planner: str, **changes: Any) -> tuple[Planner, int]:
    """A planner with the benchmark's defaults (``changes`` override settings) and its replan
    interval."""
    settings, replan_every = default_settings(env_id, planner)
    if changes:
        settings = settings.replace(**changes)
    return PLANNERS[planner][0](settings), replan_every
