"""The ``rbbo`` console script's entry point (``rbbo.cli:main``): parse the command line, run
the subcommand, and turn its errors into one-line messages and exit statuses.

Exit status 2: bad input (a usage error, a run directory that cannot be used, a simulation
space or an objective that does not match the run's); 1: evaluations kept failing, or the
system refused a read or write (a full disk); 130: interrupted (Ctrl-C or SIGTERM), with what
was recorded kept. Run as the console script (or ``python -m rbbo``),
warnings are printed as ``rbbo: warning: ...`` lines, as its errors are, without Python's
source location.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def cmd_reproduce(args) -> int:
    from ..reproduce.cli import command
    from .errors import UsageError

    return command(args, UsageError)


def _command(module: str, name: str) -> Callable[[Any], int]:
    """Subcommand ``name`` of module ``module`` of this package, imported when it runs: the
    commands' modules import numpy, scipy and the simulator's Python side (a second or more),
    which `import rbbo.cli` must not, so that an interrupt while they load reaches
    :func:`main`'s handler."""

    def command(args) -> int:
        return getattr(importlib.import_module(f".{module}", __package__), name)(args)

    command.__name__ = command.__qualname__ = name
    return command


COMMANDS = {"optimize": _command("optimize", "cmd_optimize"),
            "resume": _command("optimize", "cmd_resume"),
            "confirm": _command("optimize", "cmd_confirm"),
            "report": _command("report", "cmd_report"),
            "rollout": _command("rollout", "cmd_rollout"),
            "baselines": _command("baselines", "cmd_baselines"),
            "reproduce": cmd_reproduce}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rbbo`` console script; returns the exit status.

    With ``argv=None`` (the command line of this process: the console script, ``python -m
    rbbo``) it also prints the warnings of the process as ``rbbo: warning:`` lines; a call
    with an argument list leaves the caller's warning display alone.
    """
    try:
        # Imported here, not with the module: they take a second or more (numpy, scipy, the
        # simulator's Python side), and Ctrl-C while they load is an interrupt like any other
        # (status 130, one line), not a KeyboardInterrupt traceback.
        from .._warn import say_warnings_as
        from ..objective import ObjectiveMismatch, SimulationSpaceMismatch
        from ..optimizer import EvaluationsFailing
        from ..store import RunDirectoryError
        from .errors import UsageError
        from .parser import _parser
        from .signals import _terminate_as_interrupt
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130

    if argv is None:
        say_warnings_as("rbbo")
    try:
        args = _parser().parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        with _terminate_as_interrupt():
            return COMMANDS[args.command](args)
    except (UsageError, RunDirectoryError, SimulationSpaceMismatch, ObjectiveMismatch) as exc:
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"rbbo: error: {message}", file=sys.stderr)
        return 2
    except EvaluationsFailing as exc:  # rbbo optimize, resume, or a stage of reproduce
        print(f"rbbo: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        # a read or write the system refused (a full disk, a file made unreadable) outside a
        # search, which reports its own: what was recorded before it is kept
        print(f"rbbo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # outside a command's own handler (building the objective, plotting after the run):
        # whatever was recorded is kept, as on any interrupt
        print("\ninterrupted", file=sys.stderr)
        return 130
