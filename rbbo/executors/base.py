"""What an executor runs (an evaluation task) and what it returns (an outcome).

An executor evaluates R(B_c, T) for tasks from the optimiser, each in some worker, and hands
back a ``concurrent.futures.Future`` per task that always resolves to an
:class:`EvaluationOutcome`: a failing evaluation (exception, crash, timeout, non-finite R) is
an outcome with ``status="failed"``, never an exception, so a run goes on.
"""

from __future__ import annotations

import abc
import math
import time
import traceback
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

__all__ = ["EvaluationOutcome", "EvaluationTask", "Executor", "SerialExecutor", "evaluate_task"]


@dataclass(frozen=True)
class EvaluationTask:
    """Evaluate R at ``basis`` (B_c) for a trajectory of ``T`` seconds, averaged over ``seeds``.

    The same seeds are used for every basis (common random numbers), so differences between
    bases are not drowned by MPC sampling noise.
    """

    index: int
    basis: np.ndarray
    T: float
    seeds: tuple[int, ...]


@dataclass(frozen=True)
class EvaluationOutcome:
    """Result of one task: R is the mean over seeds (None when the evaluation failed)."""

    index: int
    R: float | None
    status: str
    wall_s: float
    worker: str
    R_seeds: tuple[float, ...] = field(default_factory=tuple)
    error: str | None = None


def failed(task: EvaluationTask, worker: str, wall_s: float, error: str) -> EvaluationOutcome:
    return EvaluationOutcome(task.index, None, "failed", wall_s, worker, (), error)


def evaluate_task(objective, task: EvaluationTask, worker: str) -> EvaluationOutcome:
    """Run ``objective(B_c, T, seed)`` for each seed of the task; exceptions become failures."""
    start = time.perf_counter()
    try:
        values = tuple(float(objective(task.basis, task.T, int(s))) for s in task.seeds)
    except Exception as exc:  # any objective fault is recorded, not raised: the run goes on
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return failed(task, worker, time.perf_counter() - start, last)
    wall = time.perf_counter() - start
    if not values or not all(math.isfinite(v) for v in values):
        return failed(task, worker, wall, f"non-finite R over seeds: {values}")
    return EvaluationOutcome(task.index, float(np.mean(values)), "ok", wall, worker, values)


class Executor(abc.ABC):
    """Runs evaluation tasks on ``workers`` workers; see the module docstring."""

    workers: int = 1

    @abc.abstractmethod
    def submit(self, task: EvaluationTask) -> Future:
        """Queue a task; the future resolves to its EvaluationOutcome."""

    def shutdown(self, wait: bool = True) -> None:  # noqa: B027 - optional hook
        """Stop the workers: queued tasks resolve as failed; running ones finish first when
        ``wait``, else they are cancelled and fail too."""

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # Leaving on an exception (Ctrl-C, SIGTERM) must not wait for evaluations in flight.
        self.shutdown(wait=exc_type is None)


class SerialExecutor(Executor):
    """Evaluates each task in the calling thread as it is submitted (no timeout, no isolation).

    For tests, synthetic objectives and debugging; a crash of the objective takes the
    optimiser down with it.
    """

    def __init__(self, objective):
        self.objective = objective
        self.workers = 1

    def submit(self, task: EvaluationTask) -> Future:
        future: Future = Future()
        future.set_result(evaluate_task(self.objective, task, "main"))
        return future
