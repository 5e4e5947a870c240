"""Usage errors of the ``rbbo`` command line: bad input, reported in one line, exit status 2.

:func:`rbbo.cli.entry.main` prints a :class:`UsageError` as ``rbbo: error: MESSAGE``;
:func:`_bad_input` turns the errors raised while checking the user's input into one.
"""

from __future__ import annotations

import contextlib


class UsageError(Exception):
    """Bad command-line input: reported in one line, exit status 2."""


@contextlib.contextmanager
def _bad_input():
    """Errors raised while validating the user's input are usage errors (exit status 2)."""
    try:
        yield
    except (ValueError, TypeError, ImportError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from exc
