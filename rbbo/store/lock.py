"""The run directory's lock: one process writes a run at a time.

:func:`_acquire_lock` takes an exclusive ``flock`` on ``DIR/.rbbo.lock`` (writing the owner's
pid into it) or refuses with :class:`RunDirectoryError` naming the process that holds it;
stores of one directory in one process share the lock, counted in ``_HELD_LOCKS``, and
:func:`_release_lock` lets it go when the last of them releases it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .errors import RunDirectoryError

LOCK = ".rbbo.lock"

if sys.platform != "win32":
    import fcntl
else:  # pragma: no cover - no flock: runs are not guarded against a second writer
    fcntl = None

# realpath of a run directory -> [lock file descriptor, stores of this process holding it]
_HELD_LOCKS: dict[str, list[int]] = {}


def _acquire_lock(path: Path) -> str:
    """Lock run directory ``path`` for this process (shared by its stores); the key to release."""
    key = os.path.realpath(path)
    held = _HELD_LOCKS.get(key)
    if held is not None:
        held[1] += 1
        return key
    try:
        fd = os.open(path / LOCK, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
    except OSError as exc:
        # a read-only directory or mount (an archived run): a writer cannot take the lock,
        # which is the user's to fix, not a traceback's; readers (rbbo report) take none
        raise _cannot_lock(path, exc) from exc
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
                raise RunDirectoryError(
                    f"{path} is in use by another process (pid {owner}): wait for it to "
                    "finish or stop it, then run the command again"
                ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    except BaseException as exc:
        # any failure (ENOLCK on a network file system, a full disk): the descriptor closed,
        # which also lets go of a lock already taken, so that no later store finds it held
        os.close(fd)
        if isinstance(exc, OSError):
            raise _cannot_lock(path, exc) from exc
        raise
    _HELD_LOCKS[key] = [fd, 1]
    return key


def _cannot_lock(path: Path, exc: OSError) -> RunDirectoryError:
    """The error for a lock the system refused (not one another process holds)."""
    reason = exc.strerror or str(exc)
    return RunDirectoryError(f"cannot lock {path} to write it ({path / LOCK}: {reason}): "
                             "a run is resumed or confirmed in a directory it can write; "
                             "rbbo report reads one it cannot")  # fmt: skip


def _release_lock(key: str) -> None:
    held = _HELD_LOCKS.get(key)
    if held is None:
        return
    held[1] -= 1
    if held[1] == 0:
        del _HELD_LOCKS[key]
        os.close(held[0])  # releases the flock
