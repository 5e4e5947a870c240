"""BOCA's choice of fidelity: how long a trajectory (T seconds) to evaluate a proposed B_c for.

Kandasamy, Dasarathy, Schneider & Poczos (2017), "Multi-fidelity Bayesian Optimisation with
Continuous Approximations" (arXiv 1703.06240), as the paper's RBBO uses it: the fidelity is
the trajectory length T in [T_min, T_max], normalised to z = (T - T_min) / (T_max - T_min)
with target z* = 1 (T_max), and the cost is lambda(z) proportional to T.

The rule implemented (BOCA's Algorithm 1 with the practical threshold of the paper's appendix
and its reference implementation):

1. B_c is chosen by maximising GP-UCB at the target fidelity z* (done by the caller).
2. For each candidate z (the first ``n_candidates - 1`` points of an even grid of
   ``n_candidates`` values of T over [T_min, T_max], T_max being the target, whose cost ratio
   lambda(z) / lambda(z*) = T / T_max is at most ``max_cost_ratio``: 0.9; BOCA's third
   condition, excluding fidelities barely cheaper than the target, is replaced by this cap as
   in the reference implementation), compute

   - tau(z): the GP's latent posterior standard deviation at (B_c, z) in units of the
     standard deviation of the observed R (the GP works on standardised observations; the
     reference implementation divides by the kernel scale instead, which makes the rule
     depend on how large a signal variance the marginal likelihood picks for smooth data);
   - xi(z) = sqrt(1 - k_T(z, z*)^2): the information gap of the fitted fidelity kernel;
   - gamma(z) = kappa * xi(z) * (lambda(z) / lambda(z*))^q: the threshold, with q = 1/2
     (the theory's q = 1 / (p + d + 2) is ~0.02 for d = 51 and would ignore cost).

3. T is the cheapest candidate with tau(z) > gamma(z) (the GP is still unsure of B_c there,
   so a cheap look is informative); if none qualifies, T = T_max.
4. A floor (ours): while fewer than ``target_fraction[0]`` of the last ``window`` choices (at
   least ``floor_after`` of them, the initial design's included) were at T_max, T = T_max.
   In a 51-dimensional B_c space tau stays near its prior value for tens of proposals, so
   rule 3 alone chose T below T_max for the first 29-59 search proposals of three of the
   45-minute reproduction's five Table I runs (the beam, the swimmer, the quadruped; the
   cross walker and the tripod chose T_max after three and one), and a short run evaluated none of
   the GP's proposals at T_max; the recommendation
   and its confirmation need some. On the synthetic objective (M = 20, C = 3, T in [2, 4] s,
   8 seeds; ``benchmarks/study_boca_recommendation.py`` with and without ``--no-floor``) the
   recommendation's noise-free R after 10 / 20 / 40 evaluations went from 0.176 / 0.211 /
   0.421 to 0.175 / 0.271 / 0.447 (the identity's is 0.094, the optimum's 1).

Adaptive threshold: kappa starts at ``kappa`` and, after each choice, over the last ``window``
choices, is divided by ``kappa_step`` when more than ``target_fraction[1]`` of them were at
T_max (too few cheap looks) and multiplied by it when fewer than ``target_fraction[0]`` were
(too many), as in the reference implementation; it adapts once the window is full, which
is why rule 4 holds the lower end of the target from the start. A resumed run replays its
history through :meth:`BOCAFidelity.record`, so it continues with the same kappa.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np

from .config import _positive_int, _real
from .gp import GrassmannGP

__all__ = ["BOCAFidelity", "FidelityChoice"]


@dataclass(frozen=True)
class FidelityChoice:
    """One BOCA decision, kept for the history and for tests.

    Attributes
    ----------
    T : float
        Chosen trajectory length (seconds).
    candidates : tuple of float
        Candidate T values considered (cost ratio <= max_cost_ratio).
    tau : tuple of float
        Posterior standard deviation at (B_c, z(T)) for each candidate, in units of the
        standard deviation of the observed R.
    gamma : tuple of float
        Threshold for each candidate.
    kappa : float
        The threshold coefficient used.
    floor : bool
        T_max was chosen by the floor (rule 4), not by the threshold.
    """

    T: float
    candidates: tuple[float, ...]
    tau: tuple[float, ...]
    gamma: tuple[float, ...]
    kappa: float
    floor: bool = False


@dataclass
class BOCAFidelity:
    """BOCA fidelity selection over trajectory length T (see the module docstring).

    Parameters
    ----------
    t_min, t_max : float
        Fidelity range in seconds (T_max is the target fidelity).
    n_candidates : int
        Points of an even grid over [T_min, T_max] (>= 2); all but the last (T_max) are the
        candidate T values, those whose cost ratio T / T_max is at most ``max_cost_ratio``.
    kappa : float
        Initial threshold coefficient.
    cost_exponent : float
        q in gamma(z) = kappa xi(z) (lambda(z) / lambda(z*))^q.
    max_cost_ratio : float
        Candidates costing more than this fraction of T_max are not considered.
    target_fraction : (float, float)
        Desired range of the fraction of T_max choices over the window.
    window : int
        Number of recent choices the adaptation looks at.
    kappa_step : float
        Factor by which kappa is adapted.
    floor_after : int
        Choices (recorded, or of proposals in flight) before the floor (rule 4) applies.

    Attributes
    ----------
    recent : collections.deque of bool
        Whether each of the latest ``window`` recorded choices was T_max (what the
        adaptation and the floor count).
    """

    t_min: float
    t_max: float
    n_candidates: int = 4
    kappa: float = 0.5
    cost_exponent: float = 0.5
    max_cost_ratio: float = 0.9
    target_fraction: tuple[float, float] = (0.25, 0.5)
    window: int = 20
    kappa_step: float = 1.1
    floor_after: int = 4
    # state, not a setting: whether each of the latest ``window`` choices was T_max
    recent: deque = field(default_factory=deque, init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("t_min", "t_max", "kappa", "cost_exponent", "max_cost_ratio", "kappa_step"):
            value = getattr(self, name)
            if not np.isfinite(_real(name, value)):
                raise ValueError(f"{name} must be finite, got {value!r}")
        if not 0 < self.t_min:
            raise ValueError(f"T_min must be a positive finite number, got {self.t_min}")
        if not self.t_max > self.t_min:
            raise ValueError(f"T_max = {self.t_max} must exceed T_min = {self.t_min}")
        for name, low in (("floor_after", 1), ("n_candidates", 2), ("window", 1)):
            _positive_int(name, getattr(self, name), low)
        if not self.kappa > 0:
            raise ValueError(f"kappa must be > 0, got {self.kappa}")
        if not self.cost_exponent >= 0:
            raise ValueError(f"cost_exponent must be >= 0, got {self.cost_exponent}")
        if not self.max_cost_ratio > 0:
            raise ValueError(f"max_cost_ratio must be > 0, got {self.max_cost_ratio}")
        if self.floor_after > self.window:  # (the window never holds that many choices)
            raise ValueError(f"floor_after = {self.floor_after} exceeds window = {self.window}: "
                             "the floor could never apply")  # fmt: skip
        if not self.kappa_step >= 1:  # (below 1 the adaptation would run the wrong way)
            raise ValueError(f"kappa_step must be >= 1, got {self.kappa_step}")
        if len(self.target_fraction) != 2:
            raise ValueError(f"target_fraction must be a (low, high) pair, got "
                             f"{self.target_fraction!r}")  # fmt: skip
        lo, hi = self.target_fraction
        if not 0 <= lo <= hi <= 1:
            raise ValueError(f"target_fraction must satisfy 0 <= lo <= hi <= 1, got {lo, hi}")
        self.recent = deque(maxlen=self.window)

    @overload
    def z(self, t: float) -> float: ...
    @overload
    def z(self, t: np.ndarray | Sequence[float]) -> np.ndarray: ...
    def z(self, t: float | np.ndarray | Sequence[float]) -> np.ndarray | float:
        """Normalised fidelity z = (T - T_min) / (T_max - T_min)."""
        return (np.asarray(t, dtype=float) - self.t_min) / (self.t_max - self.t_min)

    @property
    def candidates(self) -> np.ndarray:
        """Candidate T values: the grid's points but T_max whose cost is at most
        ``max_cost_ratio * T_max``."""
        grid = np.linspace(self.t_min, self.t_max, self.n_candidates)[:-1]  # (T_max: the target)
        return grid[grid / self.t_max <= self.max_cost_ratio]

    def choose(
        self, gp: GrassmannGP, basis: np.ndarray, pending: Sequence[float] = ()
    ) -> FidelityChoice:
        """The trajectory length T at which to evaluate ``basis`` next; ``pending``: the T of
        proposals still being evaluated (the floor counts them, so several workers do not all
        get T_max at once)."""
        if not gp.fidelity:
            raise ValueError("BOCA needs a GP with a fidelity kernel (GrassmannGP(fidelity=True))")
        cands = self.candidates
        if len(cands) == 0:
            return FidelityChoice(self.t_max, (), (), (), self.kappa)
        hp = gp.hyperparameters
        z = self.z(cands)
        _, tau = gp.predict_standardized(np.repeat(np.asarray(basis)[None], len(z), axis=0), z)
        # (predict_standardized refuses an unfitted GP; a fidelity GP fits h)
        assert hp is not None and hp.fidelity_length_scale is not None
        phi = np.exp(-0.5 * (z - 1.0) ** 2 / hp.fidelity_length_scale**2)
        xi = np.sqrt(np.maximum(1.0 - phi**2, 0.0))
        gamma = self.kappa * xi * (cands / self.t_max) ** self.cost_exponent
        qualifying = np.flatnonzero(tau > gamma)
        t = float(cands[qualifying[0]]) if len(qualifying) else float(self.t_max)
        floor = t != self.t_max and self.below_floor(pending)
        return FidelityChoice(float(self.t_max) if floor else t, tuple(cands.tolist()),
                              tuple(tau.tolist()), tuple(gamma.tolist()), float(self.kappa),
                              floor)  # fmt: skip

    def below_floor(self, pending: Sequence[float] = ()) -> bool:
        """Whether fewer than ``target_fraction[0]`` of the recent choices (the ``pending``
        ones, T of proposals in flight, last) were at T_max."""
        recent = [*self.recent, *(bool(np.isclose(t, self.t_max)) for t in pending)]
        recent = recent[-self.window :]
        return len(recent) >= self.floor_after and float(np.mean(recent)) < self.target_fraction[0]

    def record(self, t: float) -> None:
        """Note a chosen (or initial-design) T and adapt kappa towards the target fraction."""
        self.recent.append(bool(np.isclose(t, self.t_max)))
        if len(self.recent) < self.window:
            return
        fraction = float(np.mean(self.recent))
        if fraction > self.target_fraction[1]:
            self.kappa /= self.kappa_step
        elif fraction < self.target_fraction[0]:
            self.kappa *= self.kappa_step
