"""The answer of an :class:`~rbbo.optimizer.RBBO` run so far: which basis is its
recommendation, whether the run is finished, and its R_init, R* and counts
(:class:`~rbbo.config.RBBOResult`, also written to summary.json and best_basis.npy).

A finished run keeps the basis it confirmed (or the one the last session's summary named,
nothing having been recorded since) rather than what a GP refitted on reloading would rank
first, so reloading a run never changes its answer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .config import CONFIRM_KINDS, RBBOResult
from .store import Evaluation, RunDirectoryError

if TYPE_CHECKING:
    from .optimizer import RBBO

__all__ = ["final_recommendation", "finished", "record_result", "result"]


def _ok_R(evaluation: Evaluation) -> float:
    """R of an 'ok' evaluation (which Evaluation checks is a finite number)."""
    assert evaluation.R is not None
    return evaluation.R


def record_result(opt: RBBO) -> RBBOResult:
    """The result so far, also written to summary.json and best_basis.npy."""
    result = opt.result()
    if opt.store is not None:
        opt.store.write_summary(result.summary())
        if result.best_basis is not None:
            opt.store.save_best(result.best_basis)
    else:
        opt._summary = result.summary()
    return result


def _final_confirmation(opt: RBBO) -> Evaluation | None:
    """The last successful confirm-best if no search evaluation was recorded after it.

    That basis was the recommendation when the search ended, and it stays the run's
    answer: a GP refitted when the run is reloaded (from other starting hyperparameters)
    may rank near-equal candidates differently, which must not unmake a finished run.
    """
    for e in reversed(opt.history):
        if e.kind == "confirm-best" and e.status == "ok":
            return e
        if e.kind not in CONFIRM_KINDS:
            return None
    return None


def finished(opt: RBBO) -> bool:
    """Whether the run ended (with its confirmation, if it has confirmation seeds) and
    searched no further since (see :attr:`RBBO.finished`)."""
    if _final_confirmation(opt) is not None:
        return True
    # a session that searched on and kept its confirmed recommendation (nothing new to
    # confirm) ended with a summary of it
    summary = _current_summary(opt)
    return summary is not None and (opt.config.n_confirm == 0 or summary.get("R_star") is not None)


def _current_summary(opt: RBBO) -> dict[str, Any] | None:
    """summary.json (a run in memory: the result its last session ended with) if no
    evaluation was recorded since a session wrote it."""
    if opt.store is None:
        summary = opt._summary
    else:
        try:
            summary = opt.store.summary()
        except RunDirectoryError:
            return None
    if not summary or summary.get("evaluations") != len(opt.evaluations):
        return None
    return summary


def _summary_recommendation(opt: RBBO) -> Evaluation | None:
    """The recommendation summary.json recorded when a session ended, if no evaluation was
    recorded since (a GP refitted in another process may rank near-equal bases
    otherwise, and best_basis.npy holds this one)."""
    summary = _current_summary(opt)
    if summary is None:
        return None
    return next((e for e in opt._observations() if e.index == summary.get("best_index")),
                None)  # fmt: skip


def final_recommendation(opt: RBBO) -> Evaluation | None:
    """The searched evaluation that a final confirmation measured, else the one the last
    session's summary named (nothing recorded since), else :meth:`RBBO.recommend`."""
    final = _final_confirmation(opt)
    if final is None:
        return _summary_recommendation(opt) or opt.recommend()
    # (recommended at any T since BOCA's recommendation looks at every fidelity; the
    # longest evaluation of the basis where it ran at several)
    matches = [e for e in opt._observations() if np.array_equal(e.basis, final.basis)]
    return max(matches, key=lambda e: e.T) if matches else opt.recommend()


def result(opt: RBBO) -> RBBOResult:
    """R_init, R* and the counts so far (see :meth:`RBBO.result`)."""
    best = final_recommendation(opt)
    confirmations = {}
    for e in opt.history:
        if e.kind in CONFIRM_KINDS and e.status == "ok":
            confirmations[e.kind] = e
    r_init = confirmations.get("confirm-init")
    r_star = confirmations.get("confirm-best")
    if r_star is not None and (best is None or not np.array_equal(r_star.basis, best.basis)):
        r_star = None  # measured for an earlier recommendation
    improvement = None
    if r_init is not None and r_star is not None and _ok_R(r_init) > 0:
        improvement = 100.0 * (_ok_R(r_star) / _ok_R(r_init) - 1.0)
    evaluations = opt.evaluations
    return RBBOResult(
        best_basis=None if best is None else best.basis,
        R_star=None if r_star is None else r_star.R,
        R_init=None if r_init is None else r_init.R,
        improvement_pct=improvement,
        evaluations=len(evaluations),
        failed=sum(e.status == "failed" for e in evaluations),
        wall_s=max([e.elapsed_s for e in opt.history], default=0.0),
        R_star_seeds=[] if r_star is None else list(r_star.R_seeds),
        R_init_seeds=[] if r_init is None else list(r_init.R_seeds),
        best_index=None if best is None else best.index,
    )
