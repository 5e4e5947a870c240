"""What an :class:`~rbbo.optimizer.RBBO` search evaluates next (:meth:`RBBO.ask` hands it
out): first the initial design, the identity basis at T_max and ``n_init`` Haar-random points
(under BOCA alternately at T_min and T_max); then, once a GP is fitted, the maximiser of
GP-UCB on the Grassmannian, with the proposals still in flight added as kriging-believer
fantasies, T chosen by BOCA (or T_max), and a maximiser that repeats a basis evaluated or in
flight at that T replaced by the next-best local optimum, or failing those by a random point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .acquisition import UCBAcquisition, maximize_on_grassmann, ucb_beta
from .config import CONFIRM_KINDS, RBBOConfig
from .gp import GrassmannGP
from .grassmann import dimension, identity_basis, projection_sq_distances, random_points

if TYPE_CHECKING:
    from .optimizer import RBBO

__all__ = ["DUPLICATE_DISTANCE", "initial_design", "next_design_position", "propose"]

# Two bases closer than this (projection distance ||P_1 - P_2||_F) at the same T are one
# evaluation: under common random numbers the MPC sees actuation directions within a
# thousandth of each other, and R differs by far less than its noise across seeds.
DUPLICATE_DISTANCE = 1e-3


def _is_duplicate(basis: np.ndarray, t: float, taken: list[tuple[np.ndarray, float]]) -> bool:
    same_t = [b for b, t_b in taken if abs(t_b - t) <= 1e-9 * max(1.0, abs(t))]
    if not same_t:
        return False
    d2 = projection_sq_distances(basis[None], np.stack(same_t))
    return bool(d2.min() < DUPLICATE_DISTANCE**2)


def initial_design(cfg: RBBOConfig) -> list[tuple[np.ndarray, float, str]]:
    """The run's initial design: ``(basis, T, "initial")`` for the identity basis, then for
    each of the ``n_init`` random points."""
    rng = np.random.default_rng([cfg.seed, 1])
    design = [(identity_basis(cfg.sim_dim, cfg.control_dim), cfg.t_max, "initial")]
    for i in range(cfg.n_init):
        t = cfg.t_max if cfg.fidelity == "bo" or i % 2 == 1 else cfg.t_min
        design.append((random_points(cfg.sim_dim, cfg.control_dim, rng=rng), t, "initial"))
    return design


def next_design_position(opt: RBBO) -> int | None:
    """The first initial-design point neither recorded nor pending, if any.

    Matched by basis, not by index: confirmations share the index sequence, and a point
    lost in flight when a run stopped is proposed again when it resumes.
    """
    started = [e.basis for e in opt.history if e.kind == "initial"]
    started += [p.basis for p in opt.pending.values() if p.kind == "initial"]
    for position, (basis, _, _) in enumerate(opt._initial):
        if not any(b.shape == basis.shape and np.array_equal(b, basis) for b in started):
            return position
    return None


def _with_fantasies(opt: RBBO, gp: GrassmannGP) -> GrassmannGP:
    """``gp`` conditioned on the search proposals in flight, observed at its posterior mean
    (kriging believer), so that parallel workers are sent to different places."""
    pending = [p for p in opt.pending.values() if p.kind not in CONFIRM_KINDS]
    if not pending:
        return gp
    bases = np.stack([p.basis for p in pending])
    z = opt._z([p.T for p in pending])
    mu, _ = gp.predict(bases, 1.0 if z is None else z)
    return gp.conditioned_on(bases, mu, z)


def propose(
    opt: RBBO, gp: GrassmannGP, rng: np.random.Generator
) -> tuple[np.ndarray, float, float | None, int]:
    """The next search point of ``opt`` from its fitted ``gp``.

    Parameters
    ----------
    opt : RBBO
        Its observations, the proposals in flight, its settings and BOCA are read.
    gp : GrassmannGP
        The GP fitted on those observations (:meth:`RBBO.fit`).
    rng : numpy.random.Generator
        The proposal's generator (the maximiser's random starts, a random point).

    Returns
    -------
    basis : ndarray, shape (M, C)
        Orthonormal to round-off.
    T : float
    value : float or None
        The acquisition there; None for a random point that replaced duplicates.
    skipped : int
        How many duplicates were passed over.
    """
    cfg = opt.config
    believer = _with_fantasies(opt, gp)
    n = len(opt._observations())
    acquisition = UCBAcquisition(believer, ucb_beta(n, dimension(cfg.sim_dim, cfg.control_dim)))
    # incumbents: the observed bases the model rates best at the target fidelity
    observed = np.stack([e.basis for e in opt._observations()])
    mu, _ = gp.predict_standardized(observed, 1.0)
    incumbents = observed[np.argsort(-mu)[:3]]
    result = maximize_on_grassmann(
        acquisition, cfg.sim_dim, cfg.control_dim, incumbents=incumbents, rng=rng,
        optimizer=cfg.optimizer, n_random=cfg.acq_random, n_starts=cfg.acq_starts,
        max_iterations=cfg.acq_max_iterations,
    )  # fmt: skip
    # Under common random numbers an evaluation repeated at the same T returns the same R:
    # it costs a worker, teaches the GP nothing and drags its noise fit to the floor. So a
    # maximiser that lands on a basis evaluated (or in flight) at that T gives way to the
    # next-best local optimum, and failing those to a random point (as GPyOpt's
    # de-duplication does).
    in_flight = [p for p in opt.pending.values() if p.kind not in CONFIRM_KINDS]
    taken = [(e.basis, e.T) for e in opt.evaluations] + [(p.basis, p.T) for p in in_flight]
    optima = sorted(
        ((-float(r.cost), r.point) for r in result.results  # (a NaN key would misorder)
         if np.isfinite(r.cost) and not np.array_equal(r.point, result.basis)),
        key=lambda v: -v[0],
    )  # fmt: skip
    choices = [(result.value, result.basis), *optima, (None, None)]
    for skipped, (value, point) in enumerate(choices):
        if point is None:
            point = random_points(cfg.sim_dim, cfg.control_dim, rng=rng)
        u, _, vt = np.linalg.svd(point, full_matrices=False)
        basis = u @ vt  # orthonormal to round-off, as the env requires
        if opt._boca is None:
            t = cfg.t_max
        else:
            t = opt._boca.choose(believer, basis, [p.T for p in in_flight]).T
        if value is None or not _is_duplicate(basis, t, taken):
            return basis, t, value, skipped
    raise AssertionError("unreachable: the last choice is always taken")
