"""SIGTERM stops an ``rbbo`` command as Ctrl-C does, through its interrupt path."""

from __future__ import annotations

import contextlib
import signal
import threading


@contextlib.contextmanager
def _terminate_as_interrupt():
    """Let SIGTERM stop a command as Ctrl-C does, and either signal stop it only once.

    A batch scheduler's time limit (SLURM, ``timeout``) or a plain ``kill`` sends SIGTERM,
    whose default action ends the process at once: the run's session record and the workers'
    shutdown in ``finally`` blocks would be skipped. Raised as KeyboardInterrupt, it goes
    through the same path as Ctrl-C (what was recorded stays, "interrupted; continue with").
    Signal handlers belong to the main thread, so elsewhere (a test's thread) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    stopping: list[int] = []

    def interrupt(signum, frame):
        # Once, for SIGTERM and SIGINT together: ``timeout`` (``-s INT`` too) signals the
        # process and then its whole group, so the process gets the signal twice, and a second
        # KeyboardInterrupt raised inside the shutdown the first one began would break it off
        # (a traceback, and the pool's supervisor thread still running at interpreter exit).
        if stopping:
            return
        stopping.append(signum)
        raise KeyboardInterrupt(f"signal {signum}")

    handled = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        handled.append(signal.SIGINT)  # not where SIGINT is ignored (a background job)
    previous = {s: signal.signal(s, interrupt) for s in handled}
    try:
        yield
    finally:
        # After a SIGTERM the process is on its way out: a late second one must not turn the
        # clean exit (status 130) into a kill. Ctrl-C works again for an in-process caller,
        # and after a Ctrl-C so does SIGTERM (ignored, it stayed ignored in the caller and in
        # every process it started after: a pool's terminate() then did nothing).
        for s in handled:
            ignore = stopping[:1] == [signal.SIGTERM] and s == signal.SIGTERM
            signal.signal(s, signal.SIG_IGN if ignore else previous[s])
