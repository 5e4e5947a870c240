"""The run directory's lock: one process writes a run at a time.

:func:`_acquire_lock` takes an exclusive ``flock`` on ``DIR/.rbbo.lock`` (writing the owner's
pid into it) or refuses with :class:`RunDirectoryError` naming the process that holds it;
:func:`_release_lock` lets it go. One writer per directory holds within a process too: a
directory this process has locked (``_HELD_LOCKS``) is refused to a second writer until the
first releases it (both would hand out the same evaluation indices). Readers take no lock.
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

# realpath of a run directory this process has locked -> the lock file's descriptor
_HELD_LOCKS: dict[str, int] = {}


def _acquire_lock(path: Path) -> str:
    """Lock run directory ``path`` for one writer; the key that releases it.

    Raises
    ------
    RunDirectoryError
        When another process holds the lock, or a writer of this one (an RBBO or store not
        yet closed) does, or the system refuses the lock.
    """
    key = os.path.realpath(path)
    if key in _HELD_LOCKS:
        # (two writers of one process would each number evaluations on their own and record
        # the same indices; a second flock would be refused as another process's, naming
        # this one's pid: said as it is instead)
        raise RunDirectoryError(
            f"{path} is in use by another writer in this process (pid {os.getpid()}): close "
            "it first (RBBO.close(), or leave its with block), then open the run again"
        )
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
    _HELD_LOCKS[key] = fd
    return key


def _cannot_lock(path: Path, exc: OSError) -> RunDirectoryError:
    """The error for a lock the system refused (not one another process holds)."""
    reason = exc.strerror or str(exc)
    return RunDirectoryError(f"cannot lock {path} to write it ({path / LOCK}: {reason}): "
                             "a run is resumed or confirmed in a directory it can write; "
                             "rbbo report reads one it cannot")  # fmt: skip


def _release_lock(key: str) -> None:
    """Let go of the lock :func:`_acquire_lock` returned ``key`` for (again: nothing)."""
    fd = _HELD_LOCKS.pop(key, None)
    if fd is not None:
        os.close(fd)  # releases the flock
