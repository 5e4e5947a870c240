"""Local process pool: one long-lived worker process per slot, a timeout per evaluation.

Why not ``concurrent.futures.ProcessPoolExecutor``: it cannot stop one hung task (a future
that is running cannot be cancelled) and one crashed worker breaks the whole pool
(``BrokenProcessPool``). Here each worker owns a pipe; a supervisor thread hands tasks to
idle workers, and a worker that dies (segfault, os._exit, OOM kill) or runs past
``timeout_s`` is killed and replaced, its task resolving as ``status="failed"``. Workers are
started with the ``spawn`` method (safe with threads, the same on every OS), build the
objective once and keep it (e.g. its env) for all their tasks. Results still come back as
``concurrent.futures.Future`` objects.

A worker that dies while idle (no task of its own) is replaced; a task that could not be
handed to a worker, dead since it was last seen, never ran and goes back to the front of the
queue. A worker whose parent dies (a ``kill -9`` of the run) exits at once, quietly, instead
of running its evaluation on for nobody.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait

import numpy as np

from .._warn import say_warnings_as
from .base import EvaluationTask, Executor, evaluate_task, failed

__all__ = ["ProcessExecutor"]


# Tasks in a row that could not be handed to a slot's worker (each time dead since it was
# last seen) before the task fails: workers that keep dying before they take one must not
# keep it waiting forever.
_MAX_LOST_SENDS = 3

# How often a worker looks whether its parent still lives where the parent's sentinel is not
# available (a worker then outlives a killed run by at most this long), seconds.
_PARENT_POLL_S = 1.0


def _exit_with_parent() -> None:
    """Exit this worker process, quietly, as soon as the process that started it is gone.

    A ``kill -9`` of the run skips its shutdown: its workers would run their evaluations on
    (up to the evaluation's length) for nobody, then print a traceback for the result they
    could not send. A daemon thread waits on the parent's sentinel (a pipe that closes when
    the parent dies), and also looks whether the worker was handed to another parent.
    ``prctl(PR_SET_PDEATHSIG)`` is not used: it fires when the *thread* that started the
    worker ends, and replacement workers are started by the pool's supervisor thread.
    """
    parent = mp.parent_process()
    ppid = os.getppid()

    def watch() -> None:
        while True:
            if parent is not None:
                parent.join(timeout=_PARENT_POLL_S)  # (returns at once when the parent dies)
                if not parent.is_alive():
                    break
            else:  # pragma: no cover - every start method gives a spawned child a parent
                time.sleep(_PARENT_POLL_S)
            if os.getppid() != ppid:
                break
        os._exit(0)  # (the main thread may be deep in an evaluation: end the whole process)

    threading.Thread(target=watch, name="rbbo-parent-watch", daemon=True).start()


def _worker_main(conn, objective, name: str) -> None:
    """Loop in the worker process: say it is ready, then evaluate tasks as they come."""
    # Ctrl-C reaches the whole process group; the parent alone decides what an interrupt
    # means (it kills the workers at shutdown), so a worker must not die of it first and
    # have its task recorded as a crash, nor print a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    say_warnings_as(f"rbbo {name}")  # (an env's warning in an evaluation, say)
    try:
        conn.send("ready")  # imports and the objective are loaded: the timeout clock may start
    except (OSError, ValueError):  # the pool shut down while this worker was starting
        return
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        outcome = evaluate_task(objective, task, name)
        try:
            conn.send(outcome)
        except (OSError, ValueError):
            # the pool is gone (its process killed, or it killed this worker's pipe at
            # shutdown): nobody is left to tell, and a traceback here would only puzzle
            return


@dataclass
class _Slot:
    number: int
    process: mp.process.BaseProcess | None = None
    conn: Connection | None = None
    task: EvaluationTask | None = None
    future: Future | None = None
    started: float = 0.0
    restarts: int = 0
    ready: bool = False
    failed_starts: int = 0
    lost_sends: int = 0  # tasks in a row this slot's workers died before receiving

    @property
    def name(self) -> str:
        return f"process-{self.number}" + (f".{self.restarts}" if self.restarts else "")

    def live(self) -> tuple[mp.process.BaseProcess, Connection]:
        """The process and pipe of a started slot (one busy or starting)."""
        assert self.process is not None and self.conn is not None
        return self.process, self.conn


def _claim(future: Future) -> bool:
    """Whether a queued task's ``future`` is to be run: not cancelled. A task requeued after
    its worker could not be reached is running already (a future cannot go back to pending)."""
    return future.running() or future.set_running_or_notify_cancel()


def _exit_code(process, wait_s: float = 2.0) -> int | None:
    """The exit code of a worker whose pipe has closed.

    A dying worker's end of the pipe closes before the OS lets the parent reap it, so
    ``exitcode`` can still read ``None`` at the moment EOF arrives: wait briefly for it.
    """
    if process is None:
        return None
    process.join(timeout=wait_s)
    return process.exitcode


class ProcessExecutor(Executor):
    """Evaluate tasks on ``workers`` local processes.

    Parameters
    ----------
    objective : callable
        ``objective(B_c, T, seed) -> float``, picklable (a module-level class instance).
    workers : int
        Number of worker processes.
    timeout_s : float or None
        Wall-clock limit per task (all its seeds); None for no limit.
    start_method : str
        multiprocessing start method ("spawn" by default).
    """

    def __init__(self, objective, workers: int = 1, timeout_s: float | None = None,
                 start_method: str = "spawn"):  # fmt: skip
        # (numpy's integers too: np.int64(2) was refused as "not a positive integer")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        workers = int(workers)
        if timeout_s is not None and not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0 or None, got {timeout_s!r}")
        self.objective = objective
        self.workers = workers
        self.timeout_s = timeout_s
        self._ctx = mp.get_context(start_method)
        self._slots = [_Slot(i) for i in range(workers)]
        self._queue: deque = deque()
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = mp.Pipe(duplex=False)
        self._closing = False
        self._abort = False
        self._broken: str | None = None
        for slot in self._slots:
            self._start(slot)
        self._thread = threading.Thread(target=self._supervise, name="rbbo-pool", daemon=True)
        self._thread.start()

    # -- worker management ----------------------------------------------------------------
    def _start(self, slot: _Slot) -> None:
        parent, child = self._ctx.Pipe()
        # (typeshed's BaseContext, what get_context(str) returns, lacks the Process that every
        # concrete context has)
        process = self._ctx.Process(  # type: ignore[attr-defined]
            target=_worker_main, args=(child, self.objective, slot.name),
            name=f"rbbo-{slot.name}", daemon=True,
        )  # fmt: skip
        process.start()
        child.close()
        slot.process, slot.conn, slot.ready = process, parent, False

    def _stop(self, slot: _Slot, kill: bool) -> None:
        process, slot.process = slot.process, None
        if slot.conn is not None:
            slot.conn.close()
            slot.conn = None
        if process is None:
            return
        if kill and process.is_alive():
            process.kill()
        process.join(timeout=5)
        if process.is_alive():  # pragma: no cover - kill is not ignorable
            process.kill()
            process.join()

    def _finish(self, slot: _Slot, outcome) -> None:
        future, slot.future, slot.task = slot.future, None, None
        assert future is not None  # (a busy slot's)
        future.set_result(outcome)

    def _fail_and_replace(self, slot: _Slot, error: str) -> None:
        assert slot.task is not None  # (a busy slot's)
        outcome = failed(slot.task, slot.name, time.monotonic() - slot.started, error)
        self._stop(slot, kill=True)
        self._finish(slot, outcome)
        slot.restarts += 1
        if not self._closing:
            self._start(slot)

    # -- supervisor thread ----------------------------------------------------------------
    def _assign(self) -> None:
        with self._lock:
            for slot in self._slots:
                if slot.task is None and self._queue and slot.ready:
                    task, future = self._queue.popleft()
                    if not _claim(future):
                        continue
                    slot.task, slot.future, slot.started = task, future, time.monotonic()
                    try:
                        slot.live()[1].send(task)
                    except (OSError, ValueError) as exc:  # the worker died while idle
                        self._lost_send(slot, exc)

    def _lost_send(self, slot: _Slot, exc: BaseException) -> None:
        """The task just given to ``slot`` could not be sent: its worker died while idle.

        The task never ran, so it goes back to the front of the queue (its future stays
        running) for the slot's new worker or another, instead of being recorded as failed
        for good; only a slot whose workers keep dying before taking a task fails it.
        """
        slot.lost_sends += 1
        if slot.lost_sends >= _MAX_LOST_SENDS:
            slot.lost_sends = 0
            self._fail_and_replace(slot, f"could not reach the worker ({_MAX_LOST_SENDS} in "
                                   f"a row died before taking a task): {exc}")  # fmt: skip
            return
        task, future, slot.task, slot.future = slot.task, slot.future, None, None
        self._queue.appendleft((task, future))
        self._replace_idle(slot)

    def _replace_idle(self, slot: _Slot) -> None:
        """Replace the dead worker of ``slot``, which holds no task."""
        self._stop(slot, kill=True)
        slot.restarts += 1
        if not self._closing:
            self._start(slot)

    def _check_idle(self, slot: _Slot) -> None:
        """Replace the worker of idle ``slot`` if it died (OOM killer, a stray kill): its next
        task would otherwise find no one to take it."""
        # (is_alive reaps a dead one; its sentinel in ``ready`` only woke the loop)
        if not slot.live()[0].is_alive():
            self._replace_idle(slot)

    def _supervise(self) -> None:
        while True:
            if self._abort:
                for slot in self._slots:
                    if slot.task is not None:
                        self._fail_and_replace(slot, "cancelled at shutdown")
                return
            self._assign()
            busy = [s for s in self._slots if s.task is not None]
            starting = [s for s in self._slots if not s.ready and s.process is not None]
            idle = [s for s in self._slots
                    if s.ready and s.task is None and s.process is not None]  # fmt: skip
            with self._lock:
                if self._closing and not busy and not self._queue:
                    return
            waits: list[Connection | int] = [self._wake_r]
            for slot in busy + starting:
                process, conn = slot.live()
                waits += [conn, process.sentinel]
            waits += [slot.live()[0].sentinel for slot in idle]
            timeout = 0.5
            if self.timeout_s is not None and busy:
                now = time.monotonic()
                timeout = max(0.0, min(timeout, *(s.started + self.timeout_s - now for s in busy)))
            ready = wait(waits, timeout)
            if self._wake_r in ready:
                while self._wake_r.poll():
                    self._wake_r.recv_bytes()
            for slot in starting:
                self._check_start(slot, ready)
            for slot in busy:
                self._check(slot, ready)
            for slot in idle:
                self._check_idle(slot)

    def _check_start(self, slot: _Slot, ready) -> None:
        process, conn = slot.live()
        try:
            if (conn in ready or conn.poll()) and conn.recv() == "ready":
                slot.ready, slot.failed_starts = True, 0
                return
        except (EOFError, OSError):
            pass
        if process.is_alive():
            return
        code = _exit_code(slot.process)
        self._stop(slot, kill=True)
        slot.failed_starts += 1
        if slot.failed_starts < 3:
            slot.restarts += 1
            self._start(slot)
            return
        # the objective cannot even be loaded in a worker: no point retrying forever
        with self._lock:
            self._broken = (
                f"worker process could not start (exit code {code}; workers are spawned, so a "
                "script that starts a run must do so under `if __name__ == '__main__':`, and "
                "its objective must pickle)"
            )
            queued, self._queue = list(self._queue), deque()
        for task, future in queued:
            if _claim(future):
                future.set_result(failed(task, slot.name, 0.0, self._broken))

    def _check(self, slot: _Slot, ready) -> None:
        process, conn = slot.live()
        if conn in ready or conn.poll():
            try:
                outcome = conn.recv()
            except (EOFError, OSError):
                code = _exit_code(slot.process)
                self._fail_and_replace(slot, f"worker crashed (exit code {code})")
                return
            slot.lost_sends = 0
            self._finish(slot, outcome)
        elif not process.is_alive():
            self._fail_and_replace(slot, f"worker crashed (exit code {_exit_code(slot.process)})")
        elif self.timeout_s is not None and time.monotonic() - slot.started >= self.timeout_s:
            self._fail_and_replace(slot, f"timed out after {self.timeout_s:g} s")

    # -- public API -----------------------------------------------------------------------
    def submit(self, task: EvaluationTask) -> Future:
        future: Future = Future()
        with self._lock:
            if self._closing:
                raise RuntimeError("cannot submit to a ProcessExecutor that was shut down")
            if self._broken:
                future.set_running_or_notify_cancel()
                future.set_result(failed(task, "", 0.0, self._broken))
                return future
            self._queue.append((task, future))
        self._wake_w.send_bytes(b"x")
        return future

    def shutdown(self, wait: bool = True) -> None:
        """Stop the pool: queued tasks resolve as failed; running ones finish (within their
        timeout) when ``wait``, else their workers are killed and they fail too."""
        with self._lock:
            if self._closing:
                return
            self._closing = True
            self._abort = not wait
            queued, self._queue = list(self._queue), deque()
        for task, future in queued:
            if _claim(future):
                future.set_result(failed(task, "", 0.0, "cancelled at shutdown"))
        self._wake_w.send_bytes(b"x")
        self._thread.join()
        for slot in self._slots:
            if slot.conn is not None:
                try:
                    slot.conn.send(None)
                except (OSError, ValueError):
                    pass
            self._stop(slot, kill=False)
        self._wake_r.close()
        self._wake_w.close()
