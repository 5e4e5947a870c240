"""How softrom's own processes say a warning: one line, as their command line says its errors.

In a command (``rbbo``, ``python -m controllers``) or in a worker process that softrom
started, nothing of the user's code is on the stack, and Python's display (a file and line of
the package, and its source) says nothing a user can act on. Shared by the three packages'
command lines, so it lives in the lowest of them.
"""

from __future__ import annotations

import sys
import warnings

__all__ = ["say_warnings_as"]


def say_warnings_as(who: str) -> None:
    """From now on, this process prints each warning it shows as one ``<who>: warning:
    <message> (<category>)`` line on stderr (for a process that is softrom's: a command line,
    a pool worker); the warning filters still decide which are shown."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"{who}: warning: {message} ({category.__name__})", file=file or sys.stderr)

    warnings.showwarning = show
