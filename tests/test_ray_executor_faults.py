"""The Ray executor under faults the process pool already handles: a SIGTERM to the run, an
actor killed while idle."""

import os
import signal
import time

import numpy as np
import pytest

from rbbo.executors import EvaluationTask, make_executor
from rbbo.testing import FaultyObjective

ray = pytest.importorskip("ray")


def _task(i, t=1.0):
    return EvaluationTask(i, np.eye(3)[:, :1], float(t), (0,))


def _actor_pid(executor, slot: int = 0) -> int:
    actor = executor._slots[slot].actor
    return ray.get(actor.__ray_call__.remote(lambda self: os.getpid()), timeout=60)


def test_starting_ray_keeps_the_processs_sigterm_handler():
    # ray.init put its own SIGTERM handler (sys.exit(15)) in place of rbbo's, which stops a
    # run as Ctrl-C does: `kill` of an `rbbo optimize --executor ray` then ended with status
    # 15 and a session recorded as "error: SystemExit: 15" instead of 130 and "interrupted".
    def handler(signum, frame):  # pragma: no cover - never called
        raise KeyboardInterrupt

    before = signal.signal(signal.SIGTERM, handler)
    executor = None
    try:
        assert not ray.is_initialized()
        executor = make_executor("ray", FaultyObjective(), workers=1, timeout_s=60)
        assert ray.is_initialized()  # (the executor started Ray itself)
        assert signal.getsignal(signal.SIGTERM) is handler
        assert executor.submit(_task(0)).result(timeout=60).status == "ok"
    finally:
        if executor is not None:
            executor.shutdown()
        signal.signal(signal.SIGTERM, before)
    assert not ray.is_initialized()


def test_a_task_given_to_an_actor_that_died_idle_runs_on_its_replacement():
    # As in the process pool: an actor killed while it had no task (the OOM killer, a stray
    # kill -9) made the next task given to it fail ("worker failed: ActorDiedError") though
    # it never ran; it now goes to a new actor. One killed in its task still fails it.
    executor = make_executor("ray", FaultyObjective(), workers=1, timeout_s=60)
    try:
        first = executor.submit(_task(0)).result(timeout=60)
        os.kill(_actor_pid(executor), signal.SIGKILL)
        time.sleep(1.0)  # (Ray sees the actor dead before the next task is given to it)
        after = executor.submit(_task(1)).result(timeout=60)
        crashed = executor.submit(_task(2, FaultyObjective.CRASH)).result(timeout=60)
    finally:
        executor.shutdown()
    assert (first.status, first.worker) == ("ok", "ray-0")
    assert (after.index, after.status, after.R, after.worker) == (1, "ok", 1.0, "ray-0.1")
    assert (crashed.status, crashed.error) == ("failed", "worker failed: ActorDiedError")
