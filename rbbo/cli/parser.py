"""The ``rbbo`` command line's argument parser: its subcommands and their options.

Parsing errors are usage errors (one line, exit status 2), not argparse's usage block, and
options are taken as spelled, never by a unique prefix. ``rbbo reproduce``'s options are
added by :func:`rbbo.reproduce.cli.add_parser`.
"""

from __future__ import annotations

import argparse
import re
import textwrap

from softrom_gym._console import unknown_option_hint

from .arguments import (
    _env_kwarg,
    _nonnegative_float,
    _nonnegative_int,
    _positive_float,
    _positive_int,
    mpc_changes_arg,
    parse_duration,
    rl_steps_arg,
    user_path,
)
from .errors import UsageError


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs) -> None:
        # Options are taken as spelled, not by unique prefix: a run's recorded command is
        # read again on resume (--status, which options were given), and "--stage table"
        # must not mean --stages there and nothing here; a prefix is a usage error instead.
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        # A negative duration ("--budget -5m") is read as a value, so that the option's own
        # check names it, not taken for an unknown option ("expected one argument").
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([hms][\d.hms]*)?$")

    def error(self, message: str):  # one line, not argparse's usage block
        if message.endswith("required: COMMAND"):  # (plain `rbbo`: say what to type)
            sub = next(a for a in self._actions if isinstance(a, argparse._SubParsersAction))
            commands = list(sub.choices)
            message = (f"no COMMAND given: one of {', '.join(commands)} (rbbo COMMAND --help "
                       "says what it takes)")  # fmt: skip
        raise UsageError(message)

    def parse_known_args(self, args=None, namespace=None):
        # A subcommand reports its own unknown options: argparse leaves them to the top
        # parser, whose one line could not say which command's --help lists the right ones,
        # and a prefix that argparse would have taken (--iter) deserves its full name.
        known, extras = super().parse_known_args(args, namespace)
        if extras and self._subparsers is None:
            raise UsageError(f"unrecognized arguments: {' '.join(extras)}"
                             f"{unknown_option_hint(self, extras)}")  # fmt: skip
        return known, extras


def _command(sub, name: str, about: str, details: str) -> argparse.ArgumentParser:
    """A subcommand: ``about`` is its line in ``rbbo --help``, and begins its own --help's
    description (first letter raised; the rest as written, B_c stays B_c), ``details`` after.
    (A subcommand's help is shown in ``rbbo --help`` only: its own --help needs a
    description.)"""
    return sub.add_parser(name, help=about, description=f"{about[0].upper()}{about[1:]}{details}")


def _run_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=user_path, metavar="DIR",
                        help="the run directory (rbbo optimize's --out)")  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    from . import __doc__ as overview  # the package's docstring, the command line's overview

    # (the docstring's reST quotes are not for a terminal); its examples close `rbbo --help`,
    # so that a first look shows a whole session, not only the command names
    parts = overview.split("\n\n")
    parser = _Parser(prog="rbbo", description=parts[0].replace("``", ""),
                     epilog="examples:\n" + textwrap.indent(textwrap.dedent(parts[2]), "  "),
                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True,
                                parser_class=_Parser)  # fmt: skip

    about = "optimise B_c for an env (or a synthetic objective)"
    opt = _command(sub, "optimize", about, ": RBBO searches the "
                         "control spaces of ENV_ID within --budget or --iterations, then "
                         "measures R_init (the identity basis) and R* (the recommendation) on "
                         "fresh seeds. The run directory (--out) keeps everything: rbbo "
                         "resume, report, confirm and rollout take it.")  # fmt: skip
    opt.add_argument("env_id", metavar="ENV_ID",
                     help="a registered Gymnasium id (CrossWalk-v0 is short for "
                     "softrom_gym/CrossWalk-v0), or synthetic[:key=value,...] (keys seed, "
                     "noise, bias, delay): a Grassmann objective with a known optimum, no "
                     "simulator")  # fmt: skip
    opt.add_argument("--control-dim", type=_positive_int, default=3, help="C (default 3)")
    opt.add_argument("--sim-dim", type=_positive_int, default=20, help="M (default 20)")
    opt.add_argument("--controller", default="mppi", metavar="NAME",
                     help="the MPC planner: mppi, gn, or a planner of your own as an import "
                     "path package.module:ClassName (a controllers.Planner subclass, "
                     "importable here or from the current directory; recorded with the run, "
                     "so resume from where it imports; default mppi)")  # fmt: skip
    opt.add_argument("--mpc", type=mpc_changes_arg, action="append", default=[],
                     metavar="KEY=VALUE[,...]",
                     help="planner setting overrides, e.g. samples=32,noise=0.2 (env steps; "
                     "repeatable; stored with the run)")  # fmt: skip
    opt.add_argument("--budget", type=parse_duration,
                     help="wall time, e.g. 30m, 2h (default 30m without --iterations)")  # fmt: skip
    opt.add_argument("--iterations", type=_positive_int,
                     help="number of evaluations in the search (R_init and R* are measured "
                     "after it; with --budget too, the first limit reached ends it)")  # fmt: skip
    opt.add_argument("--fidelity", choices=["bo", "boca"], default="bo",
                     help="bo: every episode T_max long; boca: BOCA picks T in [--t-min, "
                     "--t-max] (default bo)")  # fmt: skip
    opt.add_argument("--t-min", type=_positive_float, default=4.0,
                     help="shortest T, s (BOCA; default 4)")  # fmt: skip
    opt.add_argument("--t-max", type=_positive_float, default=10.0,
                     help="full episode length T_max, s (default 10)")  # fmt: skip
    opt.add_argument("--settle-time", type=_nonnegative_float, default=2.0,
                     help="R is measured from this time on, s (default 2)")  # fmt: skip
    opt.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                     type=_env_kwarg,
                     help="a gym.make keyword for the env, repeatable; VALUE is read as JSON, "
                     "else as a string (e.g. --env-kwarg robot=my_robot.stl "
                     "--env-kwarg task=swim for softrom_gym/SoftRobot-v0)")  # fmt: skip
    opt.add_argument("--init", type=_nonnegative_int, default=5,
                     help="random initial points after the identity basis, before the GP proposes "
                     "(default 5)")  # fmt: skip
    opt.add_argument("--workers", type=_positive_int, default=1,
                     help="evaluations run at once (default 1)")  # fmt: skip
    opt.add_argument("--deterministic", action="store_true",
                     help="tell results in proposal order, so that a run with the same "
                     "--workers and --iterations repeats bitwise, interrupted and resumed "
                     "or not (a worker may wait for an older evaluation; default: a free "
                     "worker gets a new point at once)")  # fmt: skip
    opt.add_argument("--executor", choices=["process", "ray", "serial"], default="process",
                     help="where evaluations run (default process)")  # fmt: skip
    opt.add_argument("--address", help="Ray cluster address (with --executor ray)")
    opt.add_argument("--timeout", type=parse_duration, default=None,
                     help="per-evaluation limit (default 10m; not with --executor serial, "
                     "which cannot stop an evaluation)")  # fmt: skip
    opt.add_argument("--seed", type=_nonnegative_int, default=0,
                     help="seeds the initial design, the acquisition's random starts and the "
                     "MPC seeds seed, seed + 1, ... (default 0)")  # fmt: skip
    opt.add_argument("--seeds", type=_positive_int, default=1,
                     help="common-random-number seeds per evaluation (default 1)")  # fmt: skip
    opt.add_argument("--confirm-seeds", type=_nonnegative_int, default=3,
                     help="fresh seeds for R_init and R* (default 3)")  # fmt: skip
    opt.add_argument("--optimizer", choices=["lrbfgs", "cg"], default="lrbfgs",
                     help="acquisition maximiser on the Grassmannian (default lrbfgs)")  # fmt: skip
    opt.add_argument("--out", type=user_path, help="run directory (default runs/<env>-<time>)")
    opt.add_argument("--no-progress", action="store_true", help="no progress bar")

    about = "continue a run from its directory"
    res = _command(sub, "resume", about, ": it searches on to its limits "
                         "(the stored ones unless --budget or --iterations is given), then "
                         "measures R_init and R* on fresh seeds.")  # fmt: skip
    _run_dir(res)
    new_limit = ("; replaces both of the run's stored limits, and is stored for later "
                 "resumes")  # fmt: skip
    res.add_argument("--budget", type=parse_duration,
                     help="new total wall time, earlier sessions included, e.g. 30m, 2h"
                     + new_limit)  # fmt: skip
    res.add_argument("--iterations", type=_positive_int,
                     help="new total number of evaluations, earlier sessions included"
                     + new_limit)  # fmt: skip
    res.add_argument(
        "--workers", type=_positive_int, help="evaluations run at once (default: the run's)"
    )
    res.add_argument(
        "--executor",
        choices=["process", "ray", "serial"],
        help="run this session's evaluations elsewhere (default: the run's)",
    )
    res.add_argument("--address", help="Ray cluster address (with --executor ray)")
    res.add_argument("--timeout", type=parse_duration, default=None,
                     help="new per-evaluation limit, e.g. 20m (default: the run's; stored for "
                     "later resumes; not with --executor serial, which cannot stop an "
                     "evaluation)")  # fmt: skip
    res.add_argument("--no-progress", action="store_true", help="no progress bar")

    about = ("measure R_init and R* of a finished run again (after an upgrade, or on another "
             "machine)")  # fmt: skip
    con = _command(sub, "confirm", about, ", on the run's own "
                         "confirmation seeds, and print its table; the new measurement is "
                         "appended to the run.")  # fmt: skip
    _run_dir(con)
    con.add_argument(
        "--workers", type=_positive_int, help="evaluations run at once (default: the run's)"
    )

    about = "print the table and write convergence.png"
    rep = _command(sub, "report", about, " of each run (R_init, R* and the "
                         "improvement, as the paper's Table I). A DIR that cannot be read is "
                         "named in an error and the others are still reported; the exit "
                         "status is then non-zero.")  # fmt: skip
    rep.add_argument("run_dirs", type=user_path, nargs="+", metavar="DIR",
                     help="a run directory (several: one row each)")  # fmt: skip
    rep.add_argument("--png", type=user_path, help="plot path (default DIR/convergence.png)")

    about = "replay the best B_c with MPC"
    rol = _command(sub, "rollout", about, ": one episode with the run's "
                         "recommendation (its current one, said so, if the run has not "
                         "finished), printing R; --video records it.")  # fmt: skip
    _run_dir(rol)
    rol.add_argument("--video", type=user_path, help="write an mp4 of the rollout")
    rol.add_argument("--seconds", type=_positive_float,
                     help="episode (and video) length, s (default the run's T_max); R is "
                     "measured from the run's settle time on, so an episode no longer than "
                     "it is only for --video, which then prints no R")  # fmt: skip
    rol.add_argument("--seed", type=_nonnegative_int, default=12345,
                     help="the MPC seed (default 12345)")  # fmt: skip

    about = "PPO and SAC (Stable-Baselines3) beside the MPC"
    bas = _command(sub, "baselines", about, ": trains each --algo in each --control-basis, "
                         "evaluates every checkpoint as the MPC is evaluated, and writes "
                         "OUT/baselines.{csv,md}; the same command again continues from the "
                         "latest checkpoints. Needs stable-baselines3 (the [rl] "
                         "extra).")  # fmt: skip
    bas.add_argument("env_id", metavar="ENV_ID", help="a registered Gymnasium id")
    bas.add_argument("--algo", default="ppo,sac", help="comma list of ppo, sac (default both)")
    bas.add_argument("--steps", type=rl_steps_arg, default=20_000,
                     help="env steps to train each, N or ppo=N,sac=N (default 20000)")  # fmt: skip
    bas.add_argument("--control-basis", default="identity",
                     help="comma list of identity, best (of --run) or PATH.npy (default "
                     "identity)")  # fmt: skip
    bas.add_argument("--run", type=user_path, metavar="DIR", help="RBBO run directory (for best)")
    bas.add_argument("--sim-dim", type=_positive_int,
                     help="M of the identity basis and the env (default: the --run's, else a "
                     "PATH.npy basis's rows, else 20)")  # fmt: skip
    bas.add_argument("--control-dim", type=_positive_int,
                     help="C of the identity basis (default: the --run's, else a PATH.npy "
                     "basis's columns, else 3)")  # fmt: skip
    bas.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                     type=_env_kwarg,
                     help="a gym.make keyword for the env, repeatable, as optimize's "
                     "(with --run: the run's keywords are used; these must agree)")  # fmt: skip
    bas.add_argument("--out", type=user_path,
                     help="output directory (default runs/baselines-<env>)")  # fmt: skip
    bas.add_argument("--eval-seeds", type=_positive_int, default=5,
                     help="evaluation episodes (default 5)")  # fmt: skip
    bas.add_argument("--seconds", type=_positive_float, default=10.0,
                     help="evaluation episode length, s (default 10)")  # fmt: skip
    bas.add_argument("--settle-time", type=_nonnegative_float, default=2.0,
                     help="distance is measured from this time on, s (default 2)")  # fmt: skip
    bas.add_argument("--seed", type=_nonnegative_int, default=0,
                     help="training seed (default 0)")  # fmt: skip
    bas.add_argument("--workers", type=_positive_int, default=1,
                     help="jobs (one per method and basis) at once, one process each "
                     "(default 1)")  # fmt: skip
    bas.add_argument("--checkpoint-every", type=_positive_int,
                     help="env steps between checkpoints (default a fifth of --steps)")  # fmt: skip
    bas.add_argument("--no-mpc", action="store_true", help="RL only")
    bas.add_argument("--no-progress", action="store_true", help="no progress bars")

    from ..reproduce.cli import add_parser as add_reproduce

    add_reproduce(sub, parse_duration, _positive_int, _positive_float)
    return parser
