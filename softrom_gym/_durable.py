"""Durable file-system steps shared by everything that writes a user's records: the run
store (``rbbo.store``), video (``controllers``) and mesh export. They live here, at the
bottom of the dependency order, so that each package above uses the same ones.

A file's fsync does not reach its name, which is an entry of its folder: a rename or a new
file is durable only once the folder is fsynced too (:func:`fsync_dir`), and a new folder
only once its parent is (:func:`make_dirs`).

A record is whole only if a signal cannot cut it: :func:`signals_deferred` holds Ctrl-C and
SIGTERM while one is written (and its in-memory twin updated), then delivers them.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

__all__ = ["fsync_dir", "make_dirs", "signals_deferred", "temporary_name"]

_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM (where a Python handler is set) until the block ends, then
    hand each one caught to the handler set at that time, in the order they came (each one,
    even where one before raised).

    A signal's handler raises (KeyboardInterrupt) between any two bytecodes: one that came
    between a history line's write and its fsync cut back a finished evaluation, and one
    between the file's append and the optimiser's bookkeeping left the record and the
    in-memory run disagreeing. Held, it is raised once the block's record is whole. Blocks
    nest (an inner one hands what it caught to the outer's hold). Off the main thread, or
    the main interpreter, this does nothing: Python runs signal handlers only there.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple[int, FrameType | None]] = []
    previous: dict[int, Any] = {}
    done = False

    def hold(signum: int, frame: FrameType | None) -> None:
        if not done:
            caught.append((signum, frame))
            return
        # the block is over: act as the handler it replaced (also where an interrupted
        # restore left this one installed, which then puts that handler back)
        if signal.getsignal(signum) is hold:
            signal.signal(signum, previous[signum])
        _deliver(signum, frame)

    try:
        for held in _HELD_SIGNALS:
            # (SIG_DFL: a kill leaves what was written in place and nothing in memory to
            # disagree; SIG_IGN: nothing comes; None, or a handler set below Python such as
            # faulthandler's: signal.signal would replace it for good)
            if callable(signal.getsignal(held)):
                try:
                    previous[held] = signal.signal(held, hold)
                except ValueError:  # (not the main interpreter: signals are not ours)
                    break
        yield
    finally:
        done = True
        try:
            for restored, handler in previous.items():
                signal.signal(restored, handler)
        finally:
            _deliver_all(caught)


def _deliver(signum: int, frame: FrameType | None) -> None:
    handler = signal.getsignal(signum)  # (now: one delivered before may have changed it)
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL:
        signal.raise_signal(signum)


def _deliver_all(caught: list[tuple[int, FrameType | None]]) -> None:
    """Each one, even where one before raised (the last exception propagates)."""
    if caught:
        try:
            _deliver(*caught[0])
        finally:
            _deliver_all(caught[1:])


def fsync_dir(path: Path) -> None:
    """Make ``path``'s entries (renames, new files) durable."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def make_dirs(path: Path) -> None:
    """``path.mkdir(parents=True, exist_ok=True)``, each folder it creates made durable.

    Without the parent's fsync a power loss could drop a new folder with every record
    fsynced in it.
    """
    created = []
    p = path
    while not p.exists() and p.parent != p:
        created.append(p)
        p = p.parent
    path.mkdir(parents=True, exist_ok=True)
    for d in created:
        fsync_dir(d.parent)


def temporary_name(path: Path, ending: str) -> Path:
    """A new, hidden name in ``path``'s folder, ``.<name>.<random><ending>``, created empty so
    that it stays this call's (an ``ending`` such as ``.tmp.mp4`` keeps a suffix a writer
    picks its format by)."""
    while True:
        candidate = path.with_name(f".{path.name}.{secrets.token_hex(4)}{ending}")
        try:
            os.close(os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:  # pragma: no cover - a 32-bit collision
            continue
        return candidate
