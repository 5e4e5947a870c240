"""The log of a reproduction session: to stderr, and into the record's own reproduce.log.

``Log`` is what every stage reports through (one message, perhaps of several lines);
:func:`_log_stderr` is the default one and :func:`_tee` adds the record's copy, each line
stamped with its UTC time.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

Log = Callable[[str], None]


def _log_stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _tee(log: Log, path: Path) -> Log:
    """``log``, and each message appended to ``path`` with its UTC time: the record keeps
    its own log, whatever the session's stderr went to."""

    def both(message: str) -> None:
        log(message)
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
        with open(path, "a", encoding="utf-8") as f:
            f.write("".join(f"{stamp} {line}\n" for line in message.splitlines() or [""]))

    return both
