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

import sys

from .._warn import say_warnings_as
from .baselines import cmd_baselines
from .errors import UsageError
from .optimize import cmd_confirm, cmd_optimize, cmd_resume
from .parser import _parser
from .report import cmd_report
from .rollout import cmd_rollout
from .signals import _terminate_as_interrupt


def cmd_reproduce(args) -> int:
    from ..reproduce.cli import command

    return command(args, UsageError)


COMMANDS = {"optimize": cmd_optimize, "resume": cmd_resume, "confirm": cmd_confirm,
            "report": cmd_report,
            "rollout": cmd_rollout, "baselines": cmd_baselines,
            "reproduce": cmd_reproduce}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rbbo`` console script; returns the exit status.

    With ``argv=None`` (the command line of this process: the console script, ``python -m
    rbbo``) it also prints the warnings of the process as ``rbbo: warning:`` lines; a call
    with an argument list leaves the caller's warning display alone.
    """
    from ..objective import ObjectiveMismatch, SimulationSpaceMismatch
    from ..optimizer import EvaluationsFailing
    from ..store import RunDirectoryError

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
