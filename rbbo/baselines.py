"""The optimisers a user would otherwise reach for, on the same objective and budget.

- :func:`random_search`: Haar-random points of Gr(M, C).
- :func:`cma_es`: CMA-ES (the ``cma`` package, imported lazily) on an unconstrained M x C
  matrix, mapped to Gr(M, C) by QR orthonormalisation (:func:`rbbo.grassmann.orthonormalize`).

Both evaluate at a fixed T and average each point over the same seeds (common random numbers,
as RBBO does), and return every evaluation as ``(B_c, R, wall_time_s)`` in order.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from .grassmann import _check_dims, identity_basis, orthonormalize, random_points

__all__ = ["cma_es", "random_search"]


def _evaluate(objective: Callable, basis: np.ndarray, t: float, seeds) -> float:
    return float(np.mean([objective(basis, t, int(s)) for s in seeds]))


def random_search(
    objective: Callable,
    sim_dim: int,
    control_dim: int,
    n_evaluations: int,
    *,
    T: float,
    seeds=(0,),
    rng: np.random.Generator | int | None = None,
    include_identity: bool = True,
) -> list[tuple[np.ndarray, float, float]]:
    """Evaluate the identity (optionally) and then Haar-random B_c."""
    m, c = _check_dims(sim_dim, control_dim)
    rng = np.random.default_rng(rng)
    start = time.perf_counter()
    out = []
    for i in range(n_evaluations):
        b = identity_basis(m, c) if include_identity and i == 0 else random_points(m, c, rng=rng)
        out.append((b, _evaluate(objective, b, T, seeds), time.perf_counter() - start))
    return out


def cma_es(
    objective: Callable,
    sim_dim: int,
    control_dim: int,
    n_evaluations: int,
    *,
    T: float,
    seeds=(0,),
    seed: int = 0,
    sigma0: float = 0.5,
    popsize: int | None = None,
) -> list[tuple[np.ndarray, float, float]]:
    """CMA-ES from the identity basis on the flattened M x C matrix (maximising R).

    ``popsize`` None sizes the population to the budget: CMA-ES's default 4 + 3 ln(M C), but
    small enough for at least four generations (and at least 4), because a budget of one
    generation (the default popsize is 16 on Gr(20, 3)) never updates the search
    distribution and would make CMA-ES a single Gaussian sample around the identity.
    """
    try:
        import cma
    except ImportError as exc:
        raise ImportError("the CMA-ES baseline needs cma: pip install cma") from exc
    m, c = _check_dims(sim_dim, control_dim)
    if popsize is None:
        default = 4 + int(3 * np.log(m * c))
        popsize = max(4, min(default, n_evaluations // 4))
    if isinstance(popsize, bool) or not isinstance(popsize, (int, np.integer)) or popsize < 2:
        raise ValueError(f"popsize must be an integer >= 2, got {popsize!r}")
    options = {"seed": seed + 1, "verbose": -9, "maxfevals": n_evaluations,
               "popsize": int(popsize)}  # fmt: skip
    es = cma.CMAEvolutionStrategy(identity_basis(m, c).ravel(), sigma0, options)
    start = time.perf_counter()
    out: list[tuple[np.ndarray, float, float]] = []
    while len(out) < n_evaluations and not es.stop():
        candidates = es.ask()
        losses = []
        for x in candidates:
            if len(out) >= n_evaluations:
                break
            try:
                b = orthonormalize(np.reshape(x, (m, c)))
            except ValueError:  # a (measure-zero) rank-deficient sample
                losses.append(1e300)
                continue
            r = _evaluate(objective, b, T, seeds)
            out.append((b, r, time.perf_counter() - start))
            losses.append(-r)
        if len(losses) == len(candidates):
            es.tell(candidates, losses)
    return out
