"""What an objective is, and the errors that refuse a run's stored objective.

:class:`Objective` is the protocol RBBO evaluates, ``objective(B_c, T, seed) -> float``;
:class:`SimulationSpaceMismatch` and :class:`PlannerMismatch` are raised when a run's
recorded objective cannot be rebuilt as it was (another simulation space B_r, another
planner), :class:`ObjectiveMismatch` when the objective given to a run is not the one it
recorded.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Objective(Protocol):
    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float: ...


class SimulationSpaceMismatch(ValueError):
    """The env builds another simulation space B_r than the one a run's B_c were found in."""


class ObjectiveMismatch(ValueError):
    """The objective given to a run is not the one its config.json records."""


class PlannerMismatch(ValueError):
    """The controllers build another planner than the one a run's evaluations used."""
