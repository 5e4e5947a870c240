"""GP-UCB on the Grassmannian and its multi-start maximisation with pymanopt.

The paper's acquisition (Sec. "RBBO Algorithm") is

    gamma(B_c) = mu(B_c) + beta^(1/2) sigma(B_c),

maximised over B_c B_c^T in Gr(M, C). mu, sigma and their Euclidean gradients with respect to
B_c are written by hand (:meth:`rbbo.gp.GrassmannGP.ucb_and_gradient`); pymanopt's Grassmann
manifold projects them to Riemannian gradients. The maximiser is :class:`rbbo.optimizers.LRBFGS`
(the paper's Riemannian quasi-Newton), with pymanopt's ``ConjugateGradient`` as fallback.

beta schedule: the form of Srinivas, Krause, Kakade & Seeger 2010, Thm. 1, with the size of
the finite domain replaced by the manifold dimension d = C (M - C), and scaled by 1/5 as in
their experiments, which found the theoretical value over-explores:

    beta_t = 0.2 * 2 log(d t^2 pi^2 / (6 delta)),   delta = 0.1,

t being the number of observations so far (at least 1). Putting d for |D| is a heuristic, not
their theorem: Thm. 1 holds for a finite domain, and their Thm. 2 (a compact domain in R^d)
gives a beta_t that grows linearly in d. At d = 51 (M = 20, C = 3) this beta_t is 4.13, 5.64
and 7.26 at t = 6, 40 and 300. It does not grow with the proposals in flight, as GP-BUCB's
would (Desautels et al. 2014); the kriging believer spreads parallel proposals instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ._pymanopt import ConjugateGradient, Grassmann, OptimizerResult, pymanopt
from .gp import GrassmannGP, single_threaded_blas
from .grassmann import _check_dims, random_points, validate_basis
from .optimizers import LRBFGS

__all__ = [
    "OPTIMIZERS",
    "AcquisitionResult",
    "GrassmannFunction",
    "UCBAcquisition",
    "make_problem",
    "maximize_on_grassmann",
    "ucb_beta",
]

OPTIMIZERS = ("lrbfgs", "cg")


def ucb_beta(t: int, dim: int, delta: float = 0.1, scale: float = 0.2) -> float:
    """GP-UCB exploration weight beta_t (see the module docstring).

    Parameters
    ----------
    t : int
        Number of observations so far (values below 1 count as 1).
    dim : int
        Dimension of the search space, C (M - C) for Gr(M, C).
    delta : float
        Confidence parameter in (0, 1).
    scale : float
        Multiplier of the theoretical value.
    """
    if not 0 < delta < 1:
        raise ValueError(f"delta must be in (0, 1), got {delta}")
    if dim < 1:
        raise ValueError(f"dim must be >= 1, got {dim}")
    t = max(int(t), 1)
    return float(scale * 2.0 * np.log(dim * t**2 * np.pi**2 / (6.0 * delta)))


class GrassmannFunction(Protocol):
    """A smooth function of B_c that the maximiser understands."""

    def value_and_gradient(self, basis: np.ndarray) -> tuple[float, np.ndarray]: ...

    def values(self, bases: np.ndarray) -> np.ndarray: ...


class UCBAcquisition:
    """gamma(B_c) = mu(B_c) + beta^(1/2) sigma(B_c) at fidelity z (standardised units).

    Parameters
    ----------
    gp : GrassmannGP
        A fitted GP (possibly with kriging-believer fantasies).
    beta : float
        Exploration weight (see :func:`ucb_beta`).
    z : float
        Fidelity at which the acquisition is evaluated (BOCA: the target, 1).
    """

    def __init__(self, gp: GrassmannGP, beta: float, z: float = 1.0):
        if gp.hyperparameters is None:
            raise ValueError("UCBAcquisition needs a fitted GP")
        if not 0 <= beta < np.inf:  # (inf: every candidate's value inf, or nan where sd = 0)
            raise ValueError(f"beta must be a finite number >= 0, got {beta}")
        self.gp = gp
        self.beta = float(beta)
        self.sqrt_beta = float(np.sqrt(beta))
        self.z = float(z)

    def value_and_gradient(self, basis: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad, _, _ = self.gp.ucb_and_gradient(basis, self.sqrt_beta, self.z)
        return value, grad

    def values(self, bases: np.ndarray) -> np.ndarray:
        mu, sd = self.gp.predict_standardized(bases, self.z)
        return mu + self.sqrt_beta * sd


def make_problem(function: GrassmannFunction, sim_dim: int, control_dim: int) -> pymanopt.Problem:
    """A pymanopt Problem on Grassmann(M, C) that *minimises* -function (pymanopt minimises).

    Cost and Euclidean gradient share one evaluation: the last point is cached, since
    pymanopt asks for them separately at the same point. A gradient that is not finite raises
    a ValueError (a non-finite value is left to the optimiser, whose line search rejects it).
    """
    manifold = Grassmann(*_check_dims(sim_dim, control_dim))
    cache: dict = {"x": None}

    def evaluate(point):
        if cache["x"] is None or not np.array_equal(cache["x"], point):
            value, grad = function.value_and_gradient(point)
            # (a NaN gradient reached the retraction's SVD: "SVD did not converge")
            if not np.all(np.isfinite(grad)):
                raise ValueError(f"the function's gradient is not finite at a point where its "
                                 f"value is {float(value)!r}")  # fmt: skip
            cache.update(x=np.array(point, copy=True), value=float(value), grad=grad)
        return cache

    @pymanopt.function.numpy(manifold)
    def cost(point):
        return -evaluate(point)["value"]

    @pymanopt.function.numpy(manifold)
    def euclidean_gradient(point):
        return -evaluate(point)["grad"]

    return pymanopt.Problem(manifold, cost, euclidean_gradient=euclidean_gradient)


def _optimizer(name: str, max_iterations: int, min_gradient_norm: float):
    common: dict[str, Any] = {
        "max_iterations": max_iterations,
        "min_gradient_norm": min_gradient_norm,
        "verbosity": 0,
    }
    if name == "lrbfgs":
        return LRBFGS(**common)
    if name == "cg":
        return ConjugateGradient(**common)
    raise ValueError(f"unknown optimizer {name!r}; valid: {list(OPTIMIZERS)}")


def perturb(basis: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Retract B_c along a random tangent direction of norm ``scale``."""
    g = rng.standard_normal(basis.shape)
    g -= basis @ (basis.T @ g)
    g *= scale / max(float(np.linalg.norm(g)), 1e-300)
    u, _, vt = np.linalg.svd(basis + g, full_matrices=False)
    return u @ vt


@dataclass
class AcquisitionResult:
    """Outcome of one multi-start maximisation.

    Attributes
    ----------
    basis : (M, C) ndarray
        The maximiser found.
    value : float
        The function value there.
    optimizer : str
        "lrbfgs" or "cg" (the one asked for).
    fallback_used : bool
        Whether a local run failed and was redone with ConjugateGradient.
    results : list of pymanopt OptimizerResult
        One per local run (cost = -value).
    """

    basis: np.ndarray
    value: float
    optimizer: str
    fallback_used: bool = False
    results: list[OptimizerResult] = field(default_factory=list)


def maximize_on_grassmann(
    function: GrassmannFunction,
    sim_dim: int,
    control_dim: int,
    *,
    incumbents: np.ndarray | None = None,
    rng: np.random.Generator | int | None = None,
    optimizer: str = "lrbfgs",
    n_random: int = 128,
    n_perturbations: int = 4,
    perturbation_scale: float = 0.3,
    n_starts: int = 4,
    max_iterations: int = 60,
    min_gradient_norm: float = 1e-6,
) -> AcquisitionResult:
    """Maximise a smooth function of B_c on Gr(M, C) from several starts.

    Candidate starts are the incumbents, ``n_perturbations`` random perturbations of each,
    and ``n_random`` (>= 0) Haar-random points; the ``n_starts`` best by value (those with a
    finite value first) are refined with the chosen optimiser (a failing run is redone with
    ConjugateGradient; a start where that fails too is passed over) and the best point with
    a finite value is returned (a start, where no local run improves on it). A ValueError
    says so where neither a start nor a local run reaches a finite value.

    ``perturbation_scale`` (finite, >= 0) is the tangent norm of the middle perturbation.
    """
    m, c = _check_dims(sim_dim, control_dim)
    if optimizer not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {optimizer!r}; valid: {list(OPTIMIZERS)}")
    # (-1 was taken as 0, and a NaN scale reached numpy's SVD: "SVD did not converge")
    if isinstance(n_random, bool) or not isinstance(n_random, (int, np.integer)) or n_random < 0:
        raise ValueError(f"n_random must be an integer >= 0, got {n_random!r}")
    if not 0.0 <= perturbation_scale < np.inf:
        raise ValueError(f"perturbation_scale must be a finite number >= 0, got "
                         f"{perturbation_scale!r}")  # fmt: skip
    with single_threaded_blas():
        return _maximize(function, m, c, incumbents, np.random.default_rng(rng), optimizer,
                         n_random, n_perturbations, perturbation_scale, n_starts,
                         max_iterations, min_gradient_norm)  # fmt: skip


def _maximize(function, m, c, incumbents, rng, optimizer, n_random, n_perturbations,
              perturbation_scale, n_starts, max_iterations, min_gradient_norm):  # fmt: skip
    candidates = [random_points(m, c, n_random, rng)] if n_random > 0 else []
    if incumbents is not None and len(incumbents):
        inc = np.asarray(incumbents, dtype=float)
        inc = inc[None] if inc.ndim == 2 else inc
        if inc.ndim != 3 or inc.shape[1:] != (m, c):  # (a reshape took any array of n M C)
            raise ValueError(f"incumbents must have shape (n, {m}, {c}) or ({m}, {c}), got "
                             f"{np.shape(incumbents)}")  # fmt: skip
        for i, basis in enumerate(inc):  # (each is a start: a point of the manifold)
            validate_basis(basis, name=f"incumbents[{i}]")
        candidates.append(inc)
        for scale in perturbation_scale * np.linspace(0.5, 1.5, max(n_perturbations, 0)):
            candidates.append(np.stack([perturb(b, scale, rng) for b in inc]))
    if not candidates:
        raise ValueError("no starts: give incumbents or n_random > 0")
    starts = np.concatenate(candidates)
    values = np.asarray(function.values(starts), dtype=float)
    # Non-finite values rank last (a NaN start ranked first and, as the best value so far,
    # made every finite optimum compare as no better); a run from one may still find one.
    finite = np.isfinite(values)
    order = np.argsort(-np.where(finite, values, -np.inf))[: max(n_starts, 1)]

    problem = make_problem(function, m, c)
    first = order[0]
    best = AcquisitionResult(starts[first], float(values[first]) if finite[first] else -np.inf,
                             optimizer)  # fmt: skip
    failure = None
    for i in order:
        result = _run(optimizer, problem, starts[i], max_iterations, min_gradient_norm)
        if isinstance(result, Exception) or not np.isfinite(result.cost):
            best.fallback_used = True
            result = _run("cg", problem, starts[i], max_iterations, min_gradient_norm)
        if isinstance(result, Exception):  # (the fallback failed too: pass this start over)
            failure = result
            continue
        best.results.append(result)
        if np.isfinite(result.cost) and -result.cost > best.value:
            best.basis, best.value = result.point, float(-result.cost)
    if not np.isfinite(best.value):
        raise ValueError(f"no start and no local run reached a finite value (the best starts' "
                         f"values: {values[order]!r}; last failure: {failure!r})")  # fmt: skip
    return best


def _run(name, problem, start, max_iterations, min_gradient_norm):
    """One local run from ``start``: its result, or the exception that ended it."""
    try:
        return _optimizer(name, max_iterations, min_gradient_norm).run(problem, initial_point=start)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
        return exc
