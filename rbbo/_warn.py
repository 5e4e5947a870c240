"""How rbbo's warnings reach a user: where they point, and how rbbo's own processes say them.

Where: ``warnings.warn(stacklevel=n)`` with a counted ``n`` names the right line only while the call
chain above it stays the same; a module split moves it into rbbo's own files, where a user
cannot act on it (and where the default filter shows it once per rbbo line, not per call site
of theirs). :func:`outside_stacklevel` counts the frames instead.

How: in the ``rbbo`` command and in the process pool's workers, nothing of the user's code is
on the stack, and Python's display (a file and line of the package, and its source) says
nothing a user can act on; :func:`say_warnings_as` (``softrom_gym._console``'s, which the
``python -m controllers`` command shares) prints ``<who>: warning: <message> (<category>)``
lines instead, as the command prints its errors.
"""

from __future__ import annotations

import contextlib
import os
import sys

from softrom_gym._console import say_warnings_as

__all__ = ["outside_stacklevel", "say_warnings_as"]

# rbbo's files, and contextlib's: a session's end is recorded in a context manager's exit
_SKIPPED = (os.path.dirname(os.path.abspath(__file__)) + os.sep, contextlib.__file__)


def outside_stacklevel() -> int:
    """The ``stacklevel`` that makes a ``warnings.warn`` in the calling function name the
    first frame outside the rbbo package (the caller's own code, or the ``rbbo`` script),
    passing over the context managers rbbo enters for it."""
    level = 1
    frame = sys._getframe(1)  # the function that will call warnings.warn: stacklevel 1
    while frame.f_back is not None and os.path.abspath(frame.f_code.co_filename).startswith(
        _SKIPPED
    ):
        frame = frame.f_back
        level += 1
    return level
