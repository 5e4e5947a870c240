"""Driving an :class:`~rbbo.optimizer.RBBO` through an executor (:meth:`RBBO.run` and
:meth:`RBBO.confirm_again`): the search loop that keeps every worker busy with a proposal
until the limits are reached (or tells results in proposal order with ``deterministic``),
stops when every evaluation of a stretch fails, measures R_init and R* on fresh seeds at the
end, and records each session's start and end in DIR/sessions.jsonl and its result in
summary.json and best_basis.npy.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, wait
from typing import TYPE_CHECKING, Any

import numpy as np

from ._warn import outside_stacklevel
from .config import CONFIRM_KINDS, Proposal, RBBOResult, _positive_int, _real
from .executors import Executor, ProcessExecutor, SerialExecutor
from .grassmann import identity_basis
from .run_result import final_recommendation, record_result
from .store import Evaluation

if TYPE_CHECKING:
    from .optimizer import RBBO

__all__ = ["MAX_CONSECUTIVE_FAILURES", "EvaluationsFailing", "confirm_again", "run"]

MAX_CONSECUTIVE_FAILURES = 10


class EvaluationsFailing(RuntimeError):
    """Every evaluation of the last stretch of a run failed, so :meth:`RBBO.run` stopped."""


class _Session:
    """One call of :meth:`RBBO.run` or :meth:`RBBO.confirm_again` as DIR/sessions.jsonl
    records it: its start with its first submission (a call that evaluates nothing, such as a
    finished run run again, leaves no record) and its end when the call is left."""

    def __init__(self, opt: RBBO, command: str, settings: dict[str, Any]):
        self._opt = opt
        self._start: tuple[str, dict[str, Any]] | None = (command, settings)
        self._started: str | None = None  # its start's stamp, once recorded

    def submit(self, executor: Executor, proposal: Proposal) -> Future:
        """Submit ``proposal``, first appending this session's code and machine to
        DIR/sessions.jsonl if nothing was submitted in it yet."""
        store = self._opt.store
        if self._start is not None and store is not None:
            from .provenance import session_record

            command, settings = self._start
            limits = {k: (None if v == math.inf else v) for k, v in settings.items()}
            record = {**session_record(command), **limits}
            store.append_session(record)
            self._started = record["started"]
        self._start = None
        return executor.submit(proposal.task())

    @contextlib.contextmanager
    def ending(self) -> Iterator[None]:
        """Append the end of the session whose start :meth:`submit` recorded (a call that
        evaluated nothing recorded neither) to DIR/sessions.jsonl when the block is left:
        when, and how (finished, interrupted by Ctrl-C or SIGTERM, or an error, named)."""
        status, error = "error", None
        try:
            yield
            status = "finished"
        except KeyboardInterrupt:
            status = "interrupted"
            raise
        except BaseException as exc:
            error = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]  # one line of it
            raise
        finally:
            started, self._started = self._started, None
            store = self._opt.store
            if started is not None and store is not None:
                from .provenance import session_end_record

                try:
                    store.append_session(session_end_record(started, status, error))
                except OSError as exc:
                    # (a full disk): the session's evaluations are recorded; what is raised
                    # already, or the result, matters more than its end's line; it names the
                    # caller's RBBO.run or confirm_again call that holds the session.
                    warnings.warn(f"{store.path}: the end of this session was not "
                                  f"recorded in sessions.jsonl: {exc}", RuntimeWarning,
                                  stacklevel=outside_stacklevel())  # fmt: skip


def run(
    opt: RBBO,
    objective: Callable | None = None,
    *,
    executor: Executor | None = None,
    workers: int = 1,
    timeout_s: float | None = None,
    max_evaluations: int | None = None,
    budget_s: float | None = None,
    confirm: bool = True,
    callback: Callable[[Evaluation], None] | None = None,
    deterministic: bool = False,
    allow_objective_change: bool = False,
) -> RBBOResult:
    """Optimise until ``max_evaluations`` or ``budget_s`` (see :meth:`RBBO.run`, which calls
    this with its own arguments)."""
    cfg = opt.config
    max_evaluations = cfg.max_evaluations if max_evaluations is None else max_evaluations
    budget_s = cfg.budget_s if budget_s is None else budget_s
    if max_evaluations is None and budget_s is None:
        raise ValueError("give max_evaluations or budget_s (here or in the config)")
    if max_evaluations == math.inf and budget_s == math.inf:
        raise ValueError("max_evaluations and budget_s are both unlimited (math.inf): give one")
    # (math.inf stands for "no limit of this kind", as the command line passes it)
    if max_evaluations is not None and max_evaluations != math.inf:
        _positive_int("max_evaluations", max_evaluations)
    if budget_s is not None and not _real("budget_s", budget_s) > 0:
        raise ValueError(f"budget_s must be > 0 seconds, got {budget_s!r}")
    evaluated = objective if executor is None else getattr(executor, "objective", None)
    if executor is not None or objective is not None:
        # (before anything is evaluated or written: a refused call changes nothing)
        _expect_objective(opt, evaluated, executor is not None, allow_objective_change)
    own = executor is None
    if executor is None:
        # (checked here, not by the executor alone: workers=True equalled 1 and ran serially,
        # and a string timeout failed on '>' between str and int)
        _positive_int("workers", workers)
        workers = int(workers)
        if timeout_s is not None and not _real("timeout_s", timeout_s) > 0:
            raise ValueError(f"timeout_s must be > 0 seconds or None, got {timeout_s!r}")
        if objective is None:
            raise ValueError("give an objective or an executor")
        if not callable(objective):
            raise TypeError(f"objective must be callable as objective(B_c, T, seed), got "
                            f"{type(objective).__name__}")  # fmt: skip
        executor = (
            SerialExecutor(objective)
            if workers == 1 and timeout_s is None
            else ProcessExecutor(objective, workers, timeout_s)
        )
    # A run whose every evaluation fails (a broken objective or executor) stops instead of
    # spending its budget on failures; one failure among successes is only recorded.
    session = _Session(opt, "search", {"max_evaluations": max_evaluations, "budget_s": budget_s,
                                       "workers": executor.workers})  # fmt: skip
    failure_limit = max(MAX_CONSECUTIVE_FAILURES, 2 * executor.workers)
    failed_in_a_row, last_error = 0, None
    ok = False
    untold = _hand_out_again(opt)
    with session.ending():
        try:
            in_flight: dict[Future, Proposal] = {}
            while True:
                while (
                    len(in_flight) < executor.workers
                    and failed_in_a_row < failure_limit
                    and opt.can_submit(max_evaluations, budget_s)
                ):
                    proposal = opt.ask()
                    in_flight[session.submit(executor, proposal)] = proposal
                if not in_flight:
                    break
                # in_flight keeps submission order: its first entry is the oldest proposal
                waiting = [next(iter(in_flight))] if deterministic else list(in_flight)
                done, _ = wait(waiting, timeout=1.0, return_when=FIRST_COMPLETED)
                for future in done:
                    proposal = in_flight.pop(future)
                    evaluation = _tell_outcome(opt, proposal, future.result(), callback)
                    failed = evaluation.status == "failed"
                    failed_in_a_row = failed_in_a_row + 1 if failed else 0
                    last_error = evaluation.error
            if failed_in_a_row >= failure_limit:
                record_result(opt)
                raise EvaluationsFailing(
                    f"the last {failed_in_a_row} evaluations all failed, the last with: "
                    f"{last_error}; the run stopped (its record is kept"
                    + (f"; resume it with: rbbo resume {opt.store.path}" if opt.store else "")
                    + ")"
                )
            if confirm:
                _confirm(opt, session, executor, callback)
            ok = True
        finally:
            # those the limits left unasked stay the caller's to tell, as they were (by
            # identity: a Proposal's == compares its basis array)
            left = [p for p in opt._restored if any(p is q for q in untold)]
            opt._restored = [p for p in opt._restored if not any(p is q for q in left)]
            opt.pending.update((p.index, p) for p in left)
            if own:
                executor.shutdown(wait=ok)
        return record_result(opt)


def _hand_out_again(opt: RBBO) -> list[Proposal]:
    """Queue the search proposals asked with :meth:`RBBO.ask` and not told to be asked again
    first, oldest first, and return them.

    They are recorded (proposals.jsonl), other proposals were fitted with them as fantasies,
    and :meth:`RBBO.can_submit` counts them: left pending, they took places of the run's
    ``max_evaluations`` that nothing filled. Evaluated first, as a resumed run evaluates those
    its stopped session left in flight, they make the run the one ask/tell in proposal order
    would have made.
    """
    untold = sorted((p for p in opt.pending.values() if p.kind not in CONFIRM_KINDS),
                    key=lambda p: p.index)  # fmt: skip
    for proposal in untold:
        del opt.pending[proposal.index]
    opt._restored = sorted(untold + opt._restored, key=lambda p: p.index)
    return untold


def confirm_again(
    opt: RBBO,
    executor: Executor,
    callback: Callable[[Evaluation], None] | None = None,
    allow_objective_change: bool = False,
) -> RBBOResult:
    """Measure R_init and R* again on the run's fresh seeds (see :meth:`RBBO.confirm_again`,
    which calls this)."""
    if final_recommendation(opt) is None:
        raise ValueError("the run has no evaluation to confirm yet")
    if opt.config.n_confirm == 0:
        raise ValueError("the run was made with no confirmation seeds (n_confirm = 0)")
    _expect_objective(opt, getattr(executor, "objective", None), True, allow_objective_change)
    session = _Session(opt, "confirm", {"workers": executor.workers})
    with session.ending():
        _confirm(opt, session, executor, callback, again=True)
        return record_result(opt)


def _expect_objective(opt: RBBO, objective: Any, via_executor: bool, allow_change: bool) -> None:
    """Refuse an objective other than the one the run recorded (config.json's "objective"),
    naming what differs, unless ``allow_change``: then it becomes the run's, and the one it
    replaces is kept in config.json's "replaced_objectives" with the number of history lines
    evaluated under it. What cannot be compared is not checked: a run that recorded no
    objective (made without ``objective_spec``), an executor that does not say what it
    evaluates (no ``objective`` attribute), an objective without a ``spec()`` (a function, or
    a wrapper of the recorded objective that injects faults or logs, which must go on)."""
    from .objective import ObjectiveMismatch, objective_differences
    from .objective.spec import json_spec

    recorded = opt.objective_spec
    if recorded is None or (via_executor and objective is None):
        return
    differences = objective_differences(recorded, objective)
    if not differences:  # (None: it cannot be compared)
        return
    where = f"the run in {opt.store.path}" if opt.store is not None else "this run"
    if not allow_change:
        raise ObjectiveMismatch(
            f"the objective given is not the one {where} recorded: {'; '.join(differences)}. "
            "Its R would be mixed with the recorded R of another objective. Pass the recorded "
            "objective (rbbo.objective.make_objective(opt.objective_spec, M, C) rebuilds it), "
            "start a new run, or pass allow_objective_change=True to go on with this one (the "
            "run then records it, and keeps the one it replaces)"
        )
    new = json_spec(objective)  # (it has one: it was compared)
    if opt.store is not None:
        replaced = list(opt.store.config.get("replaced_objectives") or [])
        replaced.append({"objective": recorded, "history_lines": len(opt.history)})
        opt.store.update_config({"objective": new, "replaced_objectives": replaced},
                                merge=False)  # fmt: skip
    opt.objective_spec = new


def _tell_outcome(opt: RBBO, proposal: Proposal, outcome, callback) -> Evaluation:
    evaluation = opt.tell(proposal.index, outcome.R, status=outcome.status,
                          wall_s=outcome.wall_s, worker=outcome.worker,
                          R_seeds=outcome.R_seeds, error=outcome.error)  # fmt: skip
    if callback is not None:
        callback(evaluation)
    return evaluation


def _confirm(opt: RBBO, session: _Session, executor: Executor, callback,
             again: bool = False) -> None:  # fmt: skip
    """Evaluate the identity and the recommendation on fresh seeds at T_max (``again``:
    even where the same basis was measured before)."""
    cfg = opt.config
    best = final_recommendation(opt)
    if best is None or cfg.n_confirm == 0:
        return
    wanted = {"confirm-init": identity_basis(cfg.sim_dim, cfg.control_dim),
              "confirm-best": best.basis}  # fmt: skip
    done = {e.kind: e for e in opt.history if e.kind in CONFIRM_KINDS and e.status == "ok"}
    futures = {}
    for kind, basis in wanted.items():
        if not again and kind in done and np.array_equal(done[kind].basis, basis):
            continue  # already measured (a resumed, finished run)
        proposal = Proposal(opt._next_index, basis, cfg.t_max, cfg.fresh_seeds, kind)
        opt.pending[proposal.index] = proposal
        opt._next_index += 1
        futures[session.submit(executor, proposal)] = proposal
    for future in futures:
        _tell_outcome(opt, futures[future], future.result(), callback)
