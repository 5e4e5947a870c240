"""Where evaluations run: in-process, a local process pool (default) or Ray (lazily imported)."""

from __future__ import annotations

from .base import EvaluationOutcome, EvaluationTask, Executor, SerialExecutor, evaluate_task
from .process import ProcessExecutor

__all__ = [
    "EXECUTORS",
    "EvaluationOutcome",
    "EvaluationTask",
    "Executor",
    "ProcessExecutor",
    "RayExecutor",
    "SerialExecutor",
    "evaluate_task",
    "make_executor",
]

EXECUTORS = ("process", "ray", "serial")


def __getattr__(name: str):
    if name == "RayExecutor":  # ray's import is slow and optional: only on demand
        from .ray_executor import RayExecutor

        return RayExecutor
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def make_executor(kind: str, objective, workers: int = 1, timeout_s: float | None = None,
                  address: str | None = None) -> Executor:  # fmt: skip
    """Build an executor by name ("process", "ray" or "serial")."""
    if kind == "process":
        return ProcessExecutor(objective, workers, timeout_s)
    if kind == "ray":
        from .ray_executor import RayExecutor

        return RayExecutor(objective, workers, address=address, timeout_s=timeout_s)
    if kind == "serial":
        return SerialExecutor(objective)
    raise ValueError(f"unknown executor {kind!r}; valid: {list(EXECUTORS)}")
