"""The record's CSV files (perturbation.csv, transfer.csv, the studies, the tables).

:func:`read_rows` reads one, :func:`write_csv` writes a whole table atomically,
:func:`_append_row` appends and fsyncs one row (widening an older file's header first),
:func:`_rewrite_csv` replaces a file atomically and :func:`_supersede` moves the rows of a B_c
that its run has since replaced to ``<stem>-superseded.csv``.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..store import _atomic_write, _fsync_dir, _make_dirs


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file written by :func:`write_csv` or appended row by row (none if
    it does not exist yet)."""
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    """Write ``rows`` (their keys, in the first row's order, are the header) to ``path``
    atomically: a kill mid-write leaves the table written before, never half of it."""
    _make_dirs(path.parent)
    _rewrite_csv(path, rows, list(rows[0]))
    return path


def _append_row(path: Path, row: dict[str, Any]) -> None:
    """Append one CSV row and fsync it (a finished measurement is never lost). A row with
    columns the file lacks (written by an older version) rewrites the file with the wider
    header first, the old rows' new cells left empty."""
    _make_dirs(path.parent)
    new = not path.exists()
    if not new:
        with open(path, newline="") as f:
            header = next(csv.reader(f), [])
        missing = [k for k in row if k not in header]
        if missing or not header:
            old = read_rows(path)
            fieldnames = header + missing
            _rewrite_csv(path, old, fieldnames)
        row = {k: row.get(k, "") for k in (header + missing)} | row
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)
        f.flush()
        os.fsync(f.fileno())
    if new:
        # the file's fsync does not make its name durable: a power loss could drop the new
        # file and its rows, and _supersede's rows are by then gone from where they were
        _fsync_dir(path.parent)


def _rewrite_csv(path: Path, rows: list[dict[str, Any]], fieldnames: list[str]) -> None:
    """Replace ``path`` by ``rows`` under ``fieldnames`` atomically (a kill leaves the old
    file or the new one, never half of either)."""
    import io

    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=fieldnames, restval="")
    writer.writeheader()
    writer.writerows(rows)
    _atomic_write(path, buffer.getvalue().encode())


def _supersede(path: Path, stale: Callable[[dict[str, str]], bool]) -> int:
    """Move the rows of ``path`` for which ``stale(row)`` holds to ``<stem>-superseded.csv``
    (appended there first, so a kill between the two writes duplicates a row, never loses
    one); returns how many moved."""
    rows = read_rows(path)
    old = [r for r in rows if stale(r)]
    if not old:
        return 0
    for r in old:
        _append_row(path.with_name(f"{path.stem}-superseded.csv"), r)
    with open(path, newline="") as f:
        header = next(csv.reader(f), [])
    _rewrite_csv(path, [r for r in rows if not stale(r)], header)
    return len(old)
