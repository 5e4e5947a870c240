"""How softrom's own processes say a warning or a usage error: one line each.

In a command (``rbbo``, ``python -m controllers``) or in a worker process that softrom
started, nothing of the user's code is on the stack, and Python's display (a file and line of
the package, and its source) says nothing a user can act on. Shared by the three packages'
command lines, so it lives in the lowest of them.
"""

from __future__ import annotations

import argparse
import difflib
import sys
import warnings
from typing import NoReturn

__all__ = ["OneLineArgumentParser", "say_warnings_as"]


class OneLineArgumentParser(argparse.ArgumentParser):
    """An ``argparse.ArgumentParser`` whose usage errors are one ``<prog>: error: <message>``
    line on stderr and exit status 2 (argparse prints its usage block first; ``--help`` still
    shows it), as ``rbbo``'s are. Options are taken as spelled, never by a unique prefix
    (``allow_abbrev=False`` unless given): a prefix that works today would start meaning
    another option the day one is added."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        if message.startswith("unrecognized arguments: "):
            # without argparse's usage block, point at the option meant and at --help
            message += unknown_option_hint(self, message.split(": ", 1)[1].split())
        self.exit(2, f"{self.prog}: error: {message}\n")


def unknown_option_hint(parser: argparse.ArgumentParser, words: list[str]) -> str:
    """What follows "unrecognized arguments: ..." on one line: for each unknown ``--option``
    among ``words``, the option of ``parser`` meant (one it is a prefix of, which argparse
    would have taken were abbreviations allowed, or a close spelling), and where the options
    are listed: ``" (did you mean --seconds for --second? PROG --help lists the options)"``.
    """
    options = [o for action in parser._actions for o in action.option_strings]
    meant = []
    for word in (w.split("=")[0] for w in words if w.startswith("--")):
        match = [o for o in options if o.startswith(word)]
        match = match or difflib.get_close_matches(word, options, n=1)
        if match:
            meant.append(f"{match[0]} for {word}")
    hint = f"did you mean {', '.join(meant)}? " if meant else ""
    return f" ({hint}{parser.prog} --help lists the options)"


def say_warnings_as(who: str) -> None:
    """From now on, this process prints each warning it shows as one ``<who>: warning:
    <message> (<category>)`` line on stderr (for a process that is softrom's: a command line,
    a pool worker); the warning filters still decide which are shown."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"{who}: warning: {message} ({category.__name__})", file=file or sys.stderr)

    warnings.showwarning = show
