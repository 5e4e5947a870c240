"""Ray executor: the same contract as the process pool, on a Ray cluster (``--executor ray``).

Each worker is a Ray actor holding the objective (so it builds its env once), placed anywhere
on the cluster. A supervisor thread hands tasks to idle actors and waits on their results; an
actor that dies or runs past ``timeout_s`` is killed and replaced and its task resolves as
``status="failed"``. Ray is imported lazily: without it, constructing the executor raises an
ImportError that names the ``[ray]`` extra.

As in the process pool, a task given to an actor that had come up and died while idle (a
stray kill, the OOM killer) never ran: it goes back to the front of the queue instead of
being recorded as failed. ``ray.init`` takes over the process's SIGTERM handler; the executor
puts back the one that was set (``rbbo``'s, which stops a run as Ctrl-C does).
"""

from __future__ import annotations

import signal
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._warn import say_warnings_as
from .base import EvaluationTask, Executor, evaluate_task, failed

__all__ = ["RayExecutor", "import_ray"]

# Tasks in a row that a slot's actors, each up and then dead before the task, could not take
# before the task fails (as the process pool's _MAX_LOST_SENDS): actors that keep dying idle
# must not keep a task waiting forever.
_MAX_LOST = 3


def import_ray():
    """Import ray, or raise an ImportError saying how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise ImportError(
            "the Ray executor needs ray: pip install 'softrom[ray]' (or pip install ray)"
        ) from exc
    return ray


class _Worker:
    """Ray actor body: keeps one objective, evaluates tasks."""

    def __init__(self, objective, name: str):
        self.objective = objective
        self.name = name
        # an actor owns its worker process, as a pool worker does (an env's warning in an
        # evaluation: one line naming the worker, after Ray's own prefix)
        say_warnings_as(f"rbbo {name}")

    def evaluate(self, task: EvaluationTask):
        return evaluate_task(self.objective, task, self.name)

    def ping(self) -> bool:
        """Answers once the actor is up (its process started, the objective unpickled)."""
        return True


@dataclass
class _Slot:
    number: int
    # a ray ActorHandle and ObjectRef (Any: ray is imported only when the executor is made)
    actor: Any = None
    ref: Any = None
    task: EvaluationTask | None = None
    future: Future | None = None
    started: float | None = 0.0  # when the task's clock started (None: the actor is not up)
    restarts: int = 0
    ready: Any = None  # the actor's ping while it starts; None once it has answered
    spawned: float = 0.0
    alive: Any = None  # a ping sent just before the task to an actor that was up (_lost)
    lost: int = 0  # tasks in a row this slot's actors died before taking

    @property
    def name(self) -> str:
        return f"ray-{self.number}" + (f".{self.restarts}" if self.restarts else "")


class RayExecutor(Executor):
    """Evaluate tasks on ``workers`` Ray actors.

    Parameters
    ----------
    objective : callable
        ``objective(B_c, T, seed) -> float``, picklable.
    workers : int
        Number of actors (one CPU each).
    address : str or None
        An existing cluster (``ray.init(address=...)``, e.g. "auto" or "ray://host:10001");
        None starts a local Ray with ``workers`` CPUs unless Ray is already initialised.
    timeout_s : float or None
        Wall-clock limit per task, from when its actor is up: an actor's start (a process,
        the package's imports, the objective unpickled) is not the task's, and on a loaded
        machine it took longer than a short limit. An actor that is not up within
        ``max(60, 10 timeout_s)`` seconds fails its task and is replaced.
    """

    def __init__(self, objective, workers: int = 1, address: str | None = None,
                 timeout_s: float | None = None):  # fmt: skip
        # (numpy's integers too: np.int64(2) was refused as "not a positive integer")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        workers = int(workers)
        if timeout_s is not None and not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0 or None, got {timeout_s!r}")
        ray = import_ray()
        self._ray = ray
        self._owns_ray = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if address is None:
                kwargs["num_cpus"] = workers
            # ray.init sets a SIGTERM handler of its own, sys.exit(15) (and its core worker one
            # that prints a stack dump): under `rbbo` a SIGTERM (`kill`, a scheduler's time
            # limit) then ended the run with status 15, its session recorded as "error:
            # SystemExit: 15" and no resume hint, where Ctrl-C, and SIGTERM with the process
            # executor, stop it as an interrupt (status 130, "interrupted"). The handler set
            # before is put back; Ray's stays only where there was none (SIG_DFL), as its exit
            # then at least shuts Ray down.
            main = threading.current_thread() is threading.main_thread()
            previous = signal.getsignal(signal.SIGTERM) if main else None
            try:
                ray.init(address=address, **kwargs)
            finally:
                if previous is not None and previous is not signal.SIG_DFL:
                    signal.signal(signal.SIGTERM, previous)
            self._owns_ray = True
        self.objective = objective
        self.workers = workers
        self.timeout_s = timeout_s
        self._actor_cls = ray.remote(num_cpus=1, max_restarts=0)(_Worker)
        self._objective_ref = ray.put(objective)
        self._slots = [_Slot(i) for i in range(workers)]
        for slot in self._slots:
            self._start(slot)
        self._queue: deque = deque()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closing = False
        self._abort = False
        self._thread = threading.Thread(target=self._supervise, name="rbbo-ray", daemon=True)
        self._thread.start()

    def _start(self, slot: _Slot) -> None:
        slot.actor = self._actor_cls.remote(self._objective_ref, slot.name)
        slot.ready, slot.spawned = slot.actor.ping.remote(), time.monotonic()

    def _clock(self, slot: _Slot, now: float) -> None:
        """Start a busy slot's clock once its actor is up; fail one that does not come up."""
        if slot.ready is None:
            return
        up, _ = self._ray.wait([slot.ready], num_returns=1, timeout=0)
        if up:
            slot.ready, slot.started = None, now
        elif self.timeout_s is not None and now - slot.spawned >= max(60.0, 10 * self.timeout_s):
            self._fail_and_replace(slot, f"worker did not start in {now - slot.spawned:.0f} s")

    def _finish(self, slot: _Slot, outcome) -> None:
        future, slot.future, slot.task, slot.ref = slot.future, None, None, None
        assert future is not None  # (a busy slot's)
        future.set_result(outcome)

    def _fail_and_replace(self, slot: _Slot, error: str) -> None:
        assert slot.task is not None  # (a busy slot's)
        begun = slot.spawned if slot.started is None else slot.started
        outcome = failed(slot.task, slot.name, time.monotonic() - begun, error)
        self._ray.kill(slot.actor, no_restart=True)
        slot.restarts += 1
        self._start(slot)
        self._finish(slot, outcome)

    def _lost(self, slot: _Slot) -> bool:
        """Whether the failed task of ``slot`` never ran: its actor had come up and died while
        idle. Its ping, sent just before the task, then failed too (an actor runs one caller's
        calls in order, so an actor that died in the task had answered it)."""
        if slot.alive is None:  # (the actor was starting: a death then fails the task)
            return False
        try:
            self._ray.get(slot.alive, timeout=10)
        except self._ray.exceptions.RayActorError:
            return True
        except self._ray.exceptions.RayError:  # (not answered in time: say the task failed)
            return False
        return False

    def _requeue(self, slot: _Slot) -> None:
        """Put the task of ``slot``, which never ran (:meth:`_lost`), back at the front of the
        queue, its future still running, and replace the dead actor; fail it instead at
        shutdown (the queue was drained) or after ``_MAX_LOST`` such deaths in a row."""
        slot.lost += 1
        with self._lock:
            if not self._closing and slot.lost < _MAX_LOST:
                self._queue.appendleft((slot.task, slot.future))
                slot.task = slot.future = slot.ref = None
        if slot.task is not None:
            slot.lost = 0
            self._fail_and_replace(slot, f"worker failed: ActorDiedError ({_MAX_LOST} actors "
                                   "in a row died before taking the task)")  # fmt: skip
            return
        self._ray.kill(slot.actor, no_restart=True)
        slot.restarts += 1
        self._start(slot)

    def _supervise(self) -> None:
        ray = self._ray
        while True:
            if self._abort:
                for slot in self._slots:
                    if slot.task is not None:
                        self._fail_and_replace(slot, "cancelled at shutdown")
                return
            with self._lock:
                for slot in self._slots:
                    if slot.task is None and self._queue:
                        task, future = self._queue.popleft()
                        # (a requeued task's future is running already: it cannot go back)
                        if not (future.running() or future.set_running_or_notify_cancel()):
                            continue
                        slot.task, slot.future = task, future
                        slot.started = None if slot.ready is not None else time.monotonic()
                        slot.alive = None if slot.ready is not None else slot.actor.ping.remote()
                        slot.ref = slot.actor.evaluate.remote(task)
                busy = [s for s in self._slots if s.task is not None]
                if self._closing and not busy and not self._queue:
                    return
            if not busy:
                self._wake.wait(0.5)
                self._wake.clear()
                continue
            ready, _ = ray.wait([s.ref for s in busy], num_returns=1, timeout=0.2)
            for slot in busy:
                if slot.ref not in ready:
                    self._clock(slot, time.monotonic())
                    if slot.task is None:  # (failed: the actor did not come up)
                        continue
                if slot.ref in ready:
                    try:
                        outcome = ray.get(slot.ref)
                    except ray.exceptions.RayError as exc:
                        if self._lost(slot):
                            self._requeue(slot)
                        else:
                            self._fail_and_replace(slot, f"worker failed: {type(exc).__name__}")
                        continue
                    # (an actor that answered is up, whether or not _clock saw its ping: the
                    # next task's is then sent with it, and its clock starts at once)
                    slot.lost, slot.ready = 0, None
                    self._finish(slot, outcome)
                elif (
                    self.timeout_s is not None
                    and slot.started is not None
                    and time.monotonic() - slot.started >= self.timeout_s
                ):
                    self._fail_and_replace(slot, f"timed out after {self.timeout_s:g} s")

    def submit(self, task: EvaluationTask) -> Future:
        future: Future = Future()
        with self._lock:
            if self._closing:
                raise RuntimeError("cannot submit to a RayExecutor that was shut down")
            self._queue.append((task, future))
        self._wake.set()
        return future

    def shutdown(self, wait: bool = True) -> None:
        with self._lock:
            if self._closing:
                return
            self._closing = True
            self._abort = not wait
            queued, self._queue = list(self._queue), deque()
        for task, future in queued:
            if future.set_running_or_notify_cancel():
                future.set_result(failed(task, "", 0.0, "cancelled at shutdown"))
        self._wake.set()
        self._thread.join()
        for slot in self._slots:
            self._ray.kill(slot.actor, no_restart=True)
        if self._owns_ray:
            self._ray.shutdown()
