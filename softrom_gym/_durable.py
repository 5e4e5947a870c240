"""Durable file-system steps shared by everything that writes a user's records: the run
store (``rbbo.store``), video (``controllers``) and mesh export. They live here, at the
bottom of the dependency order, so that each package above uses the same ones.

A file's fsync does not reach its name, which is an entry of its folder: a rename or a new
file is durable only once the folder is fsynced too (:func:`fsync_dir`), and a new folder
only once its parent is (:func:`make_dirs`).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

__all__ = ["fsync_dir", "make_dirs", "temporary_name"]


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
