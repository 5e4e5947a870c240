"""What an RBBO run is set to do (:class:`RBBOConfig`, stored in config.json), what it
proposes (:class:`Proposal`) and what it reports (:class:`RBBOResult`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from .acquisition import OPTIMIZERS
from .executors import EvaluationTask
from .grassmann import _check_dims

__all__ = ["CONFIRM_KINDS", "FIDELITIES", "Proposal", "RBBOConfig", "RBBOResult"]

FIDELITIES = ("bo", "boca")
CONFIRM_KINDS = ("confirm-init", "confirm-best")


def _positive_int(name: str, value, minimum: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _real(name: str, value) -> float:
    """A real number (numpy's too) as a float, or ValueError naming the setting."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return float(value)


@dataclass
class RBBOConfig:
    """Settings of one RBBO run (stored in config.json).

    Parameters
    ----------
    sim_dim, control_dim : int
        M and C: B_c is M x C.
    fidelity : str
        "bo" (always T_max) or "boca" (BOCA picks T in [T_min, T_max]).
    t_min, t_max : float
        Trajectory lengths in seconds; T_max is the target fidelity.
    n_init : int
        Random initial points besides the identity.
    seeds : int
        Common-random-number seeds per evaluation (R is their mean).
    seed : int
        Seeds everything: the initial design, the acquisition's random starts, the CRN
        seeds (seed, seed + 1, ...).
    n_confirm : int
        Fresh seeds on which R_init and R* are measured at the end.
    max_evaluations : int or None
        Stop proposing after this many evaluations (confirmations not counted).
    budget_s : float or None
        Stop proposing after this much run time, in seconds (over all sessions of the run);
        finite, as config.json stores it (None: no time limit).
    optimizer : str
        Acquisition maximiser, "lrbfgs" or "cg".
    gp_restarts, acq_random, acq_starts, acq_max_iterations, boca_candidates
        GP fit restarts; random candidate starts, refined starts and iterations of the
        acquisition maximiser; points of BOCA's grid of T over [T_min, T_max], whose all but
        T_max are its candidates (:class:`rbbo.boca.BOCAFidelity`'s ``n_candidates``).
    """

    sim_dim: int
    control_dim: int
    fidelity: str = "bo"
    t_min: float = 4.0
    t_max: float = 10.0
    n_init: int = 5
    seeds: int = 1
    seed: int = 0
    n_confirm: int = 3
    max_evaluations: int | None = None
    budget_s: float | None = None
    optimizer: str = "lrbfgs"
    gp_restarts: int = 1
    acq_random: int = 128
    acq_starts: int = 4
    acq_max_iterations: int = 60
    boca_candidates: int = 4

    def __post_init__(self) -> None:
        self.sim_dim, self.control_dim = _check_dims(self.sim_dim, self.control_dim)
        if self.control_dim == self.sim_dim:
            raise ValueError(f"control_dim = {self.control_dim} must be below sim_dim = "
                             f"{self.sim_dim}: Gr(M, M) is one point (every B_c spans the "
                             "whole simulation space), so there is nothing to search")  # fmt: skip
        self.t_min, self.t_max = _real("t_min", self.t_min), _real("t_max", self.t_max)
        if self.budget_s is not None:
            self.budget_s = _real("budget_s", self.budget_s)
        if self.fidelity not in FIDELITIES:
            raise ValueError(f"unknown fidelity {self.fidelity!r}; valid: {list(FIDELITIES)}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"unknown optimizer {self.optimizer!r}; valid: {list(OPTIMIZERS)}")
        if not (math.isfinite(self.t_max) and self.t_max > 0):
            raise ValueError(f"t_max must be a positive number of seconds, got {self.t_max!r}")
        if self.fidelity == "boca" and not 0 < self.t_min < self.t_max:
            raise ValueError(f"need 0 < t_min < t_max for BOCA, got {self.t_min}, {self.t_max}")
        _positive_int("n_init", self.n_init, 0)
        _positive_int("seeds", self.seeds)
        _positive_int("n_confirm", self.n_confirm, 0)
        _positive_int("seed", self.seed, 0)
        _positive_int("gp_restarts", self.gp_restarts, 0)
        _positive_int("acq_random", self.acq_random, 0)
        _positive_int("acq_starts", self.acq_starts)
        _positive_int("acq_max_iterations", self.acq_max_iterations)
        _positive_int("boca_candidates", self.boca_candidates, 2)
        if self.max_evaluations is not None:
            _positive_int("max_evaluations", self.max_evaluations)
        if self.budget_s is not None and not self.budget_s > 0:
            raise ValueError(f"budget_s must be > 0 seconds, got {self.budget_s!r}")
        # config.json is strict JSON (no inf or nan): refused here by name rather than by
        # the JSON encoder when RBBO.create or set_limits writes it. No time limit is None.
        if self.budget_s is not None and not math.isfinite(self.budget_s):
            raise ValueError(f"budget_s must be a finite number of seconds (None: no time "
                             f"limit), got {self.budget_s!r}")  # fmt: skip
        if not math.isfinite(self.t_min):  # (read by BOCA only, but stored all the same)
            raise ValueError(f"t_min must be a finite number of seconds, got {self.t_min!r}")
        # numpy's integers pass the checks above; config.json stores Python's
        for name in ("n_init", "seeds", "seed", "n_confirm", "gp_restarts", "acq_random",
                     "acq_starts", "acq_max_iterations", "boca_candidates",
                     "max_evaluations"):  # fmt: skip
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, int(value))

    @property
    def crn_seeds(self) -> tuple[int, ...]:
        return tuple(self.seed + k for k in range(self.seeds))

    @property
    def fresh_seeds(self) -> tuple[int, ...]:
        # disjoint from the CRN seeds (seed .. seed + seeds - 1) of every run whose
        # seed + seeds <= 10**6
        return tuple(10**6 + 1000 * self.seed + k for k in range(self.n_confirm))


@dataclass(frozen=True)
class Proposal:
    """Where to evaluate next: B_c, trajectory length T and the seeds to average over."""

    index: int
    basis: np.ndarray
    T: float
    seeds: tuple[int, ...]
    kind: str
    info: dict = field(default_factory=dict, compare=False)

    def task(self) -> EvaluationTask:
        return EvaluationTask(self.index, self.basis, self.T, self.seeds)


@dataclass
class RBBOResult:
    """Outcome of :meth:`RBBO.run` (also written to summary.json), or of :meth:`RBBO.result`
    mid-run.

    Attributes
    ----------
    best_basis : (M, C) ndarray or None
        The recommendation: the evaluated basis with the highest posterior mean of R at
        T_max (see :meth:`RBBO.recommend`), the one R_star was measured for; None before a
        successful evaluation.
    R_star, R_init : float or None
        Means over the fresh confirmation seeds at T_max of the recommendation and of the
        identity basis (None if the confirmation was skipped, failed, or, for R_star, was
        measured for an earlier recommendation).
    improvement_pct : float or None
        100 (R* / R_init - 1), when both are measured and R_init is positive.
    evaluations : int
        Search evaluations recorded, failed ones included (confirmations not counted).
    failed : int
        How many of those failed.
    wall_s : float
        Run time in seconds (over all sessions of the run) when the latest evaluation,
        confirmations included, was recorded.
    R_star_seeds, R_init_seeds : list of float
        R on each confirmation seed (R_star and R_init are their means).
    best_index : int or None
        The evaluation index of ``best_basis`` in the history.
    """

    best_basis: np.ndarray | None
    R_star: float | None
    R_init: float | None
    improvement_pct: float | None
    evaluations: int
    failed: int
    wall_s: float
    R_star_seeds: list[float] = field(default_factory=list)
    R_init_seeds: list[float] = field(default_factory=list)
    best_index: int | None = None

    def summary(self) -> dict[str, Any]:
        out = asdict(self)
        out["best_basis"] = None if self.best_basis is None else self.best_basis.tolist()
        return out
