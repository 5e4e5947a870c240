"""Objectives R(B_c, T, seed) that RBBO maximises: the MPC task reward, or a synthetic one.

An objective is any picklable callable ``objective(B_c, T, seed) -> float`` (B_c an (M, C)
orthonormal basis, T the trajectory length in seconds, seed the MPC's random seed). The
executors run it in worker processes (spawn), so it must be a module-level class instance.

Specs (what ``rbbo optimize ENV_ID`` turns into an objective, and what config.json stores so a
run can be resumed):

- ``softrom_gym/CrossWalk-v0`` (any registered env id): :class:`EnvObjective`, the MPC
  controller run on the env (needs :mod:`controllers`, imported lazily).
- ``synthetic[:key=value,...]``: :class:`SyntheticObjective`, a Grassmann objective with known
  optimum, for tests, benchmarks and trying the CLI without the simulator. Keys: ``seed``
  (which hidden optimum), ``noise`` (seed-noise scale), ``bias`` (low-fidelity bias),
  ``delay`` (seconds of sleep per evaluation at T_max, scaled by T / T_max).
"""

# The objectives, module by job: protocol.py (what an objective is, and the errors that
# refuse a run's stored objective), synthetic.py (SyntheticObjective), env.py (EnvObjective:
# an MPC episode on a softrom env, scored as R), env_keywords.py (what rbbo passes to gym.make
# itself, and the check of the env keywords), planner.py (a planner's record), reward.py (R
# from an episode's rewards) and spec.py (ENV_ID to spec to objective). The names below are
# re-exported so that imports from rbbo.objective keep working.
from .env import EnvObjective
from .env_keywords import NO_TIME_LIMIT, SET_BY_RBBO
from .env_keywords import _check_env_keywords as _check_env_keywords
from .planner import planner_record
from .protocol import Objective, ObjectiveMismatch, PlannerMismatch, SimulationSpaceMismatch
from .reward import measured_steps, settled_reward_rate, settled_step
from .spec import _SYNTHETIC_KEYS as _SYNTHETIC_KEYS
from .spec import make_objective, objective_differences, parse_objective_spec
from .synthetic import SyntheticObjective

__all__ = [
    "NO_TIME_LIMIT",
    "SET_BY_RBBO",
    "EnvObjective",
    "Objective",
    "ObjectiveMismatch",
    "PlannerMismatch",
    "SimulationSpaceMismatch",
    "SyntheticObjective",
    "make_objective",
    "measured_steps",
    "objective_differences",
    "parse_objective_spec",
    "planner_record",
    "settled_reward_rate",
    "settled_step",
]
