"""controllers: MPC in the control space B_c (the paper's "MPC in Control-Space").

One planner interface (:class:`Planner`: ``reset``, ``plan``, ``action``), two planners
(:class:`MPPI`, :class:`GaussNewtonShooting`) over a shared :class:`SplinePlan`
(F_c = S F~_c), the objective R - Λ (:mod:`controllers.cost`), an episode runner
(:func:`run_episode`) and per-benchmark defaults (:func:`default_planner`). A planner of
one's own is chosen by name once registered (:func:`register_planner`), or by its import path
``package.module:ClassName``.
Planners use only the env's public MPC API (``get_state``, ``rollout``, ``action_bound``,
``dt``, ``direction``, ``center_of_mass``) and its action space.

    python -m controllers CrossWalk-v0 --planner mppi --seconds 10
"""

from .cost import CostWeights, Evaluation, evaluate
from .defaults import (
    DEFAULTS,
    GENERIC,
    TUNED_DT,
    default_planner,
    default_settings,
    has_defaults,
    planner_for,
)
from .episode import EpisodeResult, run_episode
from .gaits import SinusoidGait, gait_grid, phase_orders
from .gauss_newton import GaussNewtonSettings, GaussNewtonShooting
from .mppi import MPPI, MPPISettings
from .planner import Planner, PlannerSettings
from .registry import (
    PlannerEntry,
    PlannerNotImportable,
    planner_from_source,
    planner_source,
    register_planner,
    registered_planners,
    resolve_planner,
)
from .spline import SplinePlan

__all__ = [
    "DEFAULTS",
    "GENERIC",
    "MPPI",
    "TUNED_DT",
    "CostWeights",
    "EpisodeResult",
    "Evaluation",
    "GaussNewtonSettings",
    "GaussNewtonShooting",
    "MPPISettings",
    "Planner",
    "PlannerEntry",
    "PlannerNotImportable",
    "PlannerSettings",
    "SinusoidGait",
    "SplinePlan",
    "default_planner",
    "default_settings",
    "evaluate",
    "gait_grid",
    "has_defaults",
    "phase_orders",
    "planner_for",
    "planner_from_source",
    "planner_source",
    "register_planner",
    "registered_planners",
    "resolve_planner",
    "run_episode",
]
