"""Durable writes: what a run directory's files are written with.

:func:`_append_line` appends a line, flushed and fsynced (ending a torn last line first when
asked); :func:`_atomic_write` writes a file under a temporary name, fsyncs it and renames it
over the old one, so a kill leaves the old file or the new (:func:`_atomic_savefig` so writes
a matplotlib figure); :func:`_fsync_dir` makes a directory's entries (a rename, a new file)
durable, and :func:`_make_dirs` makes a directory and the names of those it creates.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path
from typing import Any

from softrom_gym._durable import fsync_dir, make_dirs, signals_deferred

# (one implementation for every package that writes a user's records: softrom_gym's, under
# the names the store's modules use)
_fsync_dir = fsync_dir
_make_dirs = make_dirs
_signals_deferred = signals_deferred


def _append_line(path: Path, line: str, end_partial: bool = False) -> None:
    """Append ``line`` and a newline durably (written, flushed and fsynced; a file it creates
    has its directory fsynced too, which the file's fsync does not reach); with
    ``end_partial``, after a newline if the file ends inside a line.

    An append that fails (a full disk's short write, a failed fsync) is undone before the
    error propagates: the file is cut back to its length before it, so the caller may write
    the line again. (A torn fragment was left, and the retry's line glued onto it; a line
    whose fsync failed was written twice. Either made the history unreadable.) A signal
    (Ctrl-C, SIGTERM) is held until the line is durable, then raised: one that came between
    the write and the fsync cut back a finished evaluation.
    """
    with _signals_deferred():
        _append_whole_line(path, line, end_partial)


def _append_whole_line(path: Path, line: str, end_partial: bool) -> None:
    new = not path.exists()
    data = line.encode() + b"\n"
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        size = os.lseek(fd, 0, os.SEEK_END)
        if end_partial and size > 0:
            os.lseek(fd, size - 1, os.SEEK_SET)
            if os.read(fd, 1) != b"\n":
                data = b"\n" + data
        try:
            view = memoryview(data)
            while view:  # (a short write is not an error until the next one fails)
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        except BaseException:
            try:
                os.ftruncate(fd, size)
                os.fsync(fd)
            except OSError:
                pass  # (best effort: the error that matters is the append's)
            raise
    finally:
        os.close(fd)
    if new:
        _fsync_dir(path.parent)


# read once, at import (single-threaded): os.umask can only be read by setting it
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:  # (which closes fd whatever fails below)
            # mkstemp's file is private (0600); a run's record is as readable as the history
            # file beside it, which open() creates under the umask
            os.fchmod(f.fileno(), 0o666 & ~_UMASK)
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _atomic_savefig(fig: Any, path: Path | str, dpi: int) -> Path:
    """Write matplotlib figure ``fig`` to ``path`` as :func:`_atomic_write` writes bytes: a
    figure a kill interrupts is the old one or the new, never a torn image. The format is
    the file's suffix (".png" when it has none)."""
    path = Path(path)
    buffer = io.BytesIO()
    fig.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png", dpi=dpi)
    _atomic_write(path, buffer.getvalue())
    return path
