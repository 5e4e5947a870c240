"""``rbbo``: optimise a control space B_c from the command line.

::

    rbbo optimize softrom_gym/CrossWalk-v0 --control-dim 3 --budget 30m --out runs/cross-walk
    rbbo resume runs/cross-walk               # after a kill: continues from history.jsonl
    rbbo confirm runs/cross-walk              # R_init and R* measured again, appended
    rbbo report runs/cross-walk               # table (Table I's columns) + convergence.png
    rbbo rollout runs/cross-walk --video cross.mp4
    rbbo reproduce --budget-per-benchmark 45m # the paper's results, into runs/reproduce

ENV_ID is a registered Gymnasium id (``CrossWalk-v0`` is short for
``softrom_gym/CrossWalk-v0``) or ``synthetic[:key=value,...]``, a Grassmann objective with a
known optimum that needs neither the simulator nor the controllers (keys: seed, noise, bias,
delay; see :mod:`rbbo.objective`). Bad arguments print one line naming the problem and exit
with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import re
import signal
import sys
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

__all__ = ["main", "parse_duration"]

_DURATION = re.compile(r"^(?:(\d+(?:\.\d*)?)h)?(?:(\d+(?:\.\d*)?)m)?(?:(\d+(?:\.\d*)?)s)?$")


class UsageError(Exception):
    """Bad command-line input: reported in one line, exit status 2."""


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
        raise UsageError(message)


def parse_duration(text: str) -> float:
    """'30m', '2h', '1h30m', '45s' or a plain number of seconds -> seconds."""
    text = str(text).strip().lower()
    if text.startswith("-"):
        raise argparse.ArgumentTypeError(f"duration must be positive, got {text!r}")
    try:
        seconds = float(text)
    except ValueError:
        match = _DURATION.match(text)
        if not text or match is None:
            raise argparse.ArgumentTypeError(
                f"invalid duration {text!r}; use e.g. 30m, 2h, 1h30m, 45s"
            ) from None
        h, m, s = (float(g) if g else 0.0 for g in match.groups())
        seconds = 3600 * h + 60 * m + s
    if not (math.isfinite(seconds) and seconds > 0):
        raise argparse.ArgumentTypeError(f"duration must be positive, got {text!r}")
    return seconds


def _duration_text(seconds: float) -> str:
    """Seconds as people read them: '45 s', '12.5 min' (a budget as --budget was given)."""
    return f"{seconds:.3g} s" if seconds < 120 else f"{seconds / 60:.3g} min"


def _limits_text(iterations: int | None, budget: float | None) -> str:
    """A run's stopping limits as a resume prints them: '30 evaluations and a budget of
    12.5 min' (either may be absent: None)."""
    limits = ([f"{iterations} evaluations"] if iterations is not None else []) + (
        [f"a budget of {_duration_text(budget)}"] if budget is not None else []
    )
    return " and ".join(limits) or "none"


def _number_arg(kind: type, allowed, what: str):
    """An argparse type: ``kind`` (int or float) parsed from the text and checked by
    ``allowed``; either failure says what was expected and what was given."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = None
        if value is None or not allowed(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    return parse


_positive_int = _number_arg(int, lambda v: v >= 1, "a positive integer")
_nonnegative_int = _number_arg(int, lambda v: v >= 0, "an integer >= 0")
_positive_float = _number_arg(float, lambda v: math.isfinite(v) and v > 0, "a positive number")
_nonnegative_float = _number_arg(float, lambda v: math.isfinite(v) and v >= 0, "a number >= 0")


def mpc_changes_arg(text: str) -> dict[str, Any]:
    """``--mpc`` (``optimize``, ``reproduce``): key=value,... planner setting overrides."""
    from controllers.defaults import parse_changes

    return parse_changes(text)


def merged_mpc_changes(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The repeated ``--mpc`` options as one dict, a later key winning."""
    return {k: v for part in parts for k, v in part.items()}


def rl_steps_arg(text: str) -> int | dict[str, int]:
    """``--steps`` / ``--rl-steps``: N for every algorithm, or ppo=N,sac=N."""
    from .rl import parse_steps

    try:
        steps = parse_steps(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    values = steps.values() if isinstance(steps, dict) else [steps]
    if any(n < 1 for n in values):
        raise argparse.ArgumentTypeError(f"env steps must be positive, got {text!r}")
    return steps


def _parser() -> argparse.ArgumentParser:
    # (the docstring's reST quotes are not for a terminal)
    parser = _Parser(prog="rbbo", description=__doc__.split("\n\n")[0].replace("``", ""))
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    opt = sub.add_parser("optimize", help="optimise B_c for an env (or a synthetic objective)")
    opt.add_argument("env_id", metavar="ENV_ID",
                     help="a registered Gymnasium id (CrossWalk-v0 is short for "
                     "softrom_gym/CrossWalk-v0), or synthetic[:key=value,...] (keys seed, "
                     "noise, bias, delay): a Grassmann objective with a known optimum, no "
                     "simulator")  # fmt: skip
    opt.add_argument("--control-dim", type=_positive_int, default=3, help="C (default 3)")
    opt.add_argument("--sim-dim", type=_positive_int, default=20, help="M (default 20)")
    opt.add_argument("--controller", choices=["mppi", "gn"], default="mppi",
                     help="the MPC planner (default mppi)")  # fmt: skip
    opt.add_argument("--mpc", type=mpc_changes_arg, action="append", default=[],
                     metavar="KEY=VALUE[,...]",
                     help="planner setting overrides, e.g. samples=32,noise=0.2 (env steps; "
                     "repeatable; stored with the run)")  # fmt: skip
    opt.add_argument("--budget", type=parse_duration,
                     help="wall time, e.g. 30m, 2h (default 30m without --iterations)")  # fmt: skip
    opt.add_argument("--iterations", type=_positive_int, help="number of evaluations")
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
    opt.add_argument("--timeout", type=parse_duration, default=600.0,
                     help="per-evaluation limit (default 10m)")  # fmt: skip
    opt.add_argument("--seed", type=_nonnegative_int, default=0,
                     help="seeds the initial design, the acquisition's random starts and the "
                     "MPC seeds seed, seed + 1, ... (default 0)")  # fmt: skip
    opt.add_argument("--seeds", type=_positive_int, default=1,
                     help="common-random-number seeds per evaluation (default 1)")  # fmt: skip
    opt.add_argument("--confirm-seeds", type=_nonnegative_int, default=3,
                     help="fresh seeds for R_init and R* (default 3)")  # fmt: skip
    opt.add_argument("--optimizer", choices=["lrbfgs", "cg"], default="lrbfgs",
                     help="acquisition maximiser on the Grassmannian (default lrbfgs)")  # fmt: skip
    opt.add_argument("--out", type=Path, help="run directory (default runs/<env>-<time>)")
    opt.add_argument("--no-progress", action="store_true", help="no progress bar")

    res = sub.add_parser("resume", help="continue a run from its directory")
    res.add_argument("run_dir", type=Path, metavar="DIR")
    res.add_argument("--budget", type=parse_duration, help="new total wall-time budget")
    res.add_argument("--iterations", type=_positive_int, help="new total number of evaluations")
    res.add_argument("--workers", type=_positive_int, help="default: the run's")
    res.add_argument(
        "--executor",
        choices=["process", "ray", "serial"],
        help="run this session's evaluations elsewhere (default: the run's)",
    )
    res.add_argument("--address", help="Ray cluster address (with --executor ray)")
    res.add_argument("--no-progress", action="store_true", help="no progress bar")

    con = sub.add_parser("confirm", help="measure R_init and R* of a finished run again "
                         "(after an upgrade, or on another machine)")  # fmt: skip
    con.add_argument("run_dir", type=Path, metavar="DIR")
    con.add_argument("--workers", type=_positive_int, help="default: the run's")

    rep = sub.add_parser("report", help="print the table and write convergence.png")
    rep.add_argument("run_dirs", type=Path, nargs="+", metavar="DIR")
    rep.add_argument("--png", type=Path, help="plot path (default DIR/convergence.png)")

    rol = sub.add_parser("rollout", help="replay the best B_c with MPC")
    rol.add_argument("run_dir", type=Path, metavar="DIR")
    rol.add_argument("--video", type=Path, help="write an mp4 of the rollout")
    rol.add_argument("--seconds", type=_positive_float,
                     help="episode (and video) length, s (default the run's T_max); R is "
                     "measured from the run's settle time on, so an episode no longer than "
                     "it is only for --video, which then prints no R")  # fmt: skip
    rol.add_argument("--seed", type=_nonnegative_int, default=12345,
                     help="the MPC seed (default 12345)")  # fmt: skip

    bas = sub.add_parser("baselines", help="PPO and SAC (Stable-Baselines3) beside the MPC")
    bas.add_argument("env_id", metavar="ENV_ID", help="a registered Gymnasium id")
    bas.add_argument("--algo", default="ppo,sac", help="comma list of ppo, sac (default both)")
    bas.add_argument("--steps", type=rl_steps_arg, default=20_000,
                     help="env steps to train each, N or ppo=N,sac=N (default 20000)")  # fmt: skip
    bas.add_argument("--control-basis", default="identity",
                     help="comma list of identity, best (of --run) or PATH.npy (default "
                     "identity)")  # fmt: skip
    bas.add_argument("--run", type=Path, metavar="DIR", help="RBBO run directory (for best)")
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
    bas.add_argument("--out", type=Path, help="output directory (default runs/baselines-<env>)")
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

    from .reproduce.cli import add_parser as add_reproduce

    add_reproduce(sub, parse_duration, _positive_int, _positive_float)
    return parser


# -- helpers ------------------------------------------------------------------------------
@contextlib.contextmanager
def _bad_input():
    """Errors raised while validating the user's input are usage errors (exit status 2)."""
    try:
        yield
    except (ValueError, TypeError, ImportError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from exc


def _env_kwargs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """--env-kwarg pairs as a dict; ``robot=`` naming an existing mesh file is stored as an
    absolute path, so the run resumes from any working directory."""
    import os

    out = {}
    for key, value in pairs:
        path = os.path.expanduser(value) if key == "robot" and isinstance(value, str) else ""
        if os.path.splitext(path)[1] and os.path.isfile(path):  # a mesh file, not a name
            value = os.path.abspath(path)
        out[key] = value
    return out


def _env_kwarg(text: str) -> tuple[str, Any]:
    """--env-kwarg KEY=VALUE (softrom_gym.registration.parse_env_kwarg), imported only when
    the option is given: the envs take a second to import, and ``rbbo --help`` need not."""
    from softrom_gym.registration import parse_env_kwarg

    return parse_env_kwarg(text)


def _resolve_env(env_id: str, synthetic: bool = True) -> str:
    """A registered env id (short names get the softrom_gym/ namespace). ``synthetic``: the
    command also accepts the synthetic objective (the error message lists it)."""
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    if env_id not in gym.registry and f"softrom_gym/{env_id}" in gym.registry:
        env_id = f"softrom_gym/{env_id}"
    if env_id not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith("softrom_gym/"))
        also = ", synthetic" if synthetic else ""
        raise UsageError(f"unknown ENV_ID {env_id!r}; registered: {', '.join(known)}{also}")
    return env_id


def _check_controllers() -> None:
    try:
        import controllers
    except ImportError as exc:  # pragma: no cover - part of this package
        raise UsageError(f"the env objective needs the controllers package: {exc}") from None
    missing = [n for n in ("run_episode", "MPPI", "GaussNewtonShooting")
               if not hasattr(controllers, n)]  # fmt: skip
    if missing:
        # "controllers" is a common name: a user's own module of that name can shadow ours.
        where = getattr(controllers, "__file__", None) or "a module without a file"
        raise UsageError(
            f"controllers has no {', '.join(missing)}: the module imported as controllers "
            f"({where}) is not softrom's (another package or file of that name first on "
            "sys.path?); use ENV_ID 'synthetic' to try rbbo without the simulator"
        )


def _progress(opt, max_evaluations, budget_s, enabled: bool):
    """A tqdm bar: evaluations, best R at T_max, time left; returns (callback, close)."""
    if not enabled:
        return None, lambda: None
    from tqdm import tqdm

    done = len(opt.evaluations)
    bar = tqdm(total=max_evaluations, initial=done, unit="eval", dynamic_ncols=True,
               file=sys.stderr, desc="rbbo")  # fmt: skip
    best = [max((e.R for e in opt.evaluations
                 if e.status == "ok" and math.isclose(e.T, opt.config.t_max)),
                default=-math.inf)]  # fmt: skip

    def callback(evaluation) -> None:
        if evaluation.kind.startswith("confirm"):
            bar.set_description("rbbo (confirming R_init, R*)")
            return
        bar.update(1)
        if evaluation.status == "ok" and math.isclose(evaluation.T, opt.config.t_max):
            best[0] = max(best[0], evaluation.R)
        parts = [f"best R {best[0]:.4g}" if math.isfinite(best[0]) else "best R -"]
        if budget_s is not None:
            left = max(budget_s - opt.elapsed_s, 0.0)
            parts.append(f"{int(left // 60)}m{int(left % 60):02d}s left")
        bar.set_postfix_str(", ".join(parts))

    return callback, bar.close


def _make_executor(objective, execution: dict):
    """The run's executor, built before anything is written (a missing Ray or a wrong
    address is then a usage error that leaves no run directory behind)."""
    from .executors import make_executor

    if execution["executor"] == "serial" and execution["workers"] != 1:
        raise UsageError(f"--executor serial runs one evaluation at a time, in this "
                         f"process; --workers {execution['workers']} needs --executor "
                         "process (or ray)")  # fmt: skip

    with _bad_input():
        return make_executor(execution["executor"], objective, execution["workers"],
                             execution["timeout_s"], execution.get("address"))  # fmt: skip


def _execute(opt, executor, max_evaluations, budget_s, progress: bool,
             deterministic: bool = False) -> int:  # fmt: skip
    from .optimizer import EvaluationsFailing
    from .report import format_table, plot_convergence, report_row

    callback, close = _progress(opt, max_evaluations, budget_s, progress)
    # None is "no limit" here; to run() it would mean "the limit stored in the config"
    unlimited = math.inf
    try:
        opt.run(executor=executor,
                max_evaluations=unlimited if max_evaluations is None else max_evaluations,
                budget_s=unlimited if budget_s is None else budget_s,
                callback=callback, deterministic=deterministic)  # fmt: skip
    except KeyboardInterrupt:
        close()
        executor.shutdown(wait=False)
        print(f"\ninterrupted; continue with: rbbo resume {opt.store.path}", file=sys.stderr)
        return 130
    except EvaluationsFailing:  # reported by main()
        close()
        executor.shutdown(wait=False)
        raise
    close()
    executor.shutdown()
    print(format_table([report_row(opt)]))
    png = plot_convergence(opt, opt.store.path / "convergence.png")
    print(f"run directory: {opt.store.path}  (best basis: best_basis.npy, plot: {png.name})")
    return 0


# -- commands -----------------------------------------------------------------------------
def cmd_optimize(args) -> int:
    from .objective import make_objective, parse_objective_spec
    from .optimizer import RBBO, RBBOConfig

    if args.control_dim > args.sim_dim:
        raise UsageError(f"--control-dim {args.control_dim} exceeds --sim-dim {args.sim_dim}")
    if args.t_min >= args.t_max and args.fidelity == "boca":
        raise UsageError(f"--t-min {args.t_min} must be below --t-max {args.t_max} (BOCA "
                         "searches episode lengths between them)")  # fmt: skip
    if args.address and args.executor != "ray":
        raise UsageError("--address is for --executor ray")
    budget, iterations = args.budget, args.iterations
    if budget is None and iterations is None:
        budget = 30 * 60.0
    with _bad_input():
        spec = parse_objective_spec(args.env_id)
    problem = {"env_id": args.env_id, "N": None}
    if spec["kind"] == "env":
        if args.t_min <= args.settle_time and args.fidelity == "boca":
            raise UsageError(f"--t-min {args.t_min} must exceed --settle-time {args.settle_time}")
        if args.t_max <= args.settle_time:
            raise UsageError(f"--t-max {args.t_max} must exceed --settle-time {args.settle_time}")
        spec["env_id"] = _resolve_env(spec["env_id"])
        _check_controllers()
        spec.update(controller=args.controller, settle_time=args.settle_time)
        if args.env_kwarg:
            spec["env_kwargs"] = _env_kwargs(args.env_kwarg)
        if args.mpc:
            spec["planner_kwargs"] = merged_mpc_changes(args.mpc)
        problem["env_id"] = spec["env_id"]
    elif args.env_kwarg or args.mpc:
        flag = "--env-kwarg" if args.env_kwarg else "--mpc"
        raise UsageError(f"{flag} is for an env, not the synthetic objective")
    else:
        spec["t_max"] = args.t_max
    with _bad_input():
        config = RBBOConfig(
            sim_dim=args.sim_dim, control_dim=args.control_dim, fidelity=args.fidelity,
            t_min=args.t_min, t_max=args.t_max, n_init=args.init, seeds=args.seeds,
            seed=args.seed, n_confirm=args.confirm_seeds, max_evaluations=iterations,
            budget_s=budget, optimizer=args.optimizer,
        )  # fmt: skip
        objective = make_objective(spec, args.sim_dim, args.control_dim, new=True)
    if spec["kind"] == "env":
        with _bad_input():  # the env is made here: a bad --env-kwarg fails now, named
            problem["N"] = objective.node_count()
            objective.planner()  # and a bad --mpc setting, not as failed evaluations
    out = args.out
    if out is None:
        name = args.env_id.split("/")[-1].split(":")[0]
        out = Path("runs") / f"{name}-{datetime.now():%Y%m%d-%H%M%S}"
    execution = {"executor": args.executor, "workers": args.workers,
                 "timeout_s": args.timeout, "address": args.address,
                 "deterministic": args.deterministic}  # fmt: skip
    executor = _make_executor(objective, execution)
    try:
        with _bad_input():
            opt = RBBO.create(out, config, objective_spec=objective.spec(),
                              extra={"execution": execution, "problem": problem})  # fmt: skip
    except BaseException:
        executor.shutdown(wait=False)
        raise
    # notes once the input is known good (a usage error stays one line)
    if iterations is not None and iterations <= args.init + 1:
        print(f"note: --iterations {iterations} <= 1 + --init {args.init}: the initial design "
              f"(the identity basis, then {args.init} random points) takes every evaluation, "
              "and the GP proposes none", file=sys.stderr)  # fmt: skip
    if spec["kind"] == "env":
        import controllers

        if not controllers.has_defaults(spec["env_id"]):
            print(f"note: {spec['env_id']} has no tuned planner settings; {args.controller} "
                  "runs with the shared defaults (a 2, 3 or 4 Hz gait cycle picked at reset) "
                  "(controllers.GENERIC; the benchmarks' own rows: controllers.DEFAULTS)",
                  file=sys.stderr)  # fmt: skip
    return _execute(opt, executor, iterations, budget, not args.no_progress,
                    args.deterministic)  # fmt: skip


def _run_mppi_overrides(run_dir) -> dict[str, Any]:
    """The run's ``--mpc`` overrides, for the MPC rows beside the RL ones (MPPI): the planner
    its R* was measured with. A Gauss-Newton run's overrides are not MPPI's: said, not used."""
    from .store import RunStore

    objective = RunStore.open(run_dir, repair=False).config.get("objective") or {}
    overrides = dict(objective.get("planner_kwargs") or {})
    if overrides and objective.get("controller", "mppi") != "mppi":
        print(f"note: run {run_dir} planned with {objective.get('controller')} and --mpc "
              f"{overrides}; the MPC rows are MPPI's, with its defaults",
              file=sys.stderr)  # fmt: skip
        return {}
    return overrides


def _objective_of(opt):
    from .objective import make_objective

    spec = opt.objective_spec
    if not isinstance(spec, dict) or "kind" not in spec:
        raise UsageError(f"{opt.store.path}/config.json does not say what the objective is")
    if spec["kind"] == "env":
        _check_controllers()
    with _bad_input():
        return make_objective(spec, opt.config.sim_dim, opt.config.control_dim)


def cmd_resume(args) -> int:
    from .optimizer import RBBO

    opt = RBBO.resume(args.run_dir)
    store = opt.store
    assert store is not None  # (resume opens the run's store)
    objective = _objective_of(opt)
    execution = dict(store.config.get("execution") or {"executor": "process",
                     "workers": 1, "timeout_s": 600.0})  # fmt: skip
    if args.workers:
        execution["workers"] = args.workers
    if args.executor:
        execution["executor"] = args.executor
        execution["address"] = args.address if args.executor == "ray" else None
        if args.executor == "serial" and not args.workers:
            execution["workers"] = 1  # (the stored count was another executor's)
    elif args.address:
        if execution["executor"] != "ray":
            raise UsageError("--address is for --executor ray")
        execution["address"] = args.address
    # A new limit replaces both stored ones: a run that stopped at its budget, resumed with
    # --iterations, would otherwise stop again at once. It is written to config.json, so a
    # later plain `rbbo resume` (the hint an interrupted run prints) goes on to it, or, for a
    # lowered limit that is already reached, stays stopped at it.
    iterations, budget = args.iterations, args.budget
    if iterations is None and budget is None:
        iterations, budget = opt.config.max_evaluations, opt.config.budget_s
    elif (iterations, budget) != (opt.config.max_evaluations, opt.config.budget_s):
        old = _limits_text(opt.config.max_evaluations, opt.config.budget_s)
        with _bad_input():
            opt.set_limits(iterations, budget)
        print(f"{store.path}: its limit is now {_limits_text(iterations, budget)} (was "
              f"{old}), stored in config.json for later resumes", file=sys.stderr)  # fmt: skip
    if not opt.can_submit(iterations, budget):
        done = len(opt.evaluations)
        print(f"{store.path} has reached its limit ({_limits_text(iterations, budget)}; it "
              f"has {done} evaluations, {_duration_text(opt.elapsed_s)}): nothing more to "
              "search; give a larger --budget or --iterations to go on",
              file=sys.stderr)  # fmt: skip
    started = time.monotonic()
    executor = _make_executor(objective, execution)
    code = _execute(opt, executor, iterations, budget, not args.no_progress,
                    bool(execution.get("deterministic", False)))  # fmt: skip
    if code == 0:
        print(f"resumed for {time.monotonic() - started:.0f} s", file=sys.stderr)
    return code


def cmd_confirm(args) -> int:
    from .executors import make_executor
    from .optimizer import RBBO
    from .report import format_table, report_row

    opt = RBBO.resume(args.run_dir)
    store = opt.store
    assert store is not None  # (resume opens the run's store)
    if not opt.finished and opt.config.n_confirm > 0:
        # its R* would be a mid-search recommendation's, and the run would then read as
        # finished; the resume measures R_init and R* when the search ends
        n = len(opt.evaluations)
        raise UsageError(f"{args.run_dir} has not finished its search ({n} evaluations "
                         f"recorded): rbbo resume {args.run_dir} finishes it and measures "
                         "R_init and R*; confirm measures a finished run again")  # fmt: skip
    before = opt.result()
    objective = _objective_of(opt)
    execution = dict(store.config.get("execution") or {"executor": "process",
                     "workers": 1, "timeout_s": 600.0})  # fmt: skip
    workers = args.workers or execution["workers"]
    with _bad_input():
        executor = make_executor(execution["executor"], objective, workers,
                                 execution["timeout_s"], execution.get("address"))  # fmt: skip
    try:
        with _bad_input():
            after = opt.confirm_again(executor)
    except KeyboardInterrupt:
        executor.shutdown(wait=False)
        print(f"\ninterrupted; nothing is lost: run rbbo confirm {store.path} again",
              file=sys.stderr)  # fmt: skip
        return 130
    executor.shutdown()

    def fmt(value: float | None) -> str:
        return "-" if value is None else f"{value:.6g}"

    seeds = ", ".join(map(str, opt.config.fresh_seeds))
    print(f"R_init {fmt(before.R_init)} -> {fmt(after.R_init)}, R* {fmt(before.R_star)} -> "
          f"{fmt(after.R_star)} (fresh seeds {seeds})")  # fmt: skip
    print(format_table([report_row(opt)]))
    return 0


def cmd_report(args) -> int:
    from .report import format_table, load, plot_convergence, report_row

    if args.png is not None and len(args.run_dirs) > 1:
        raise UsageError("--png names one plot: give one DIR")
    rows = []
    if args.png is not None:
        # the suffix picks the format: one matplotlib cannot write would fail after the table
        # was computed, and none at all would write PNG.png, not the file named
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        formats = sorted(FigureCanvasAgg.get_supported_filetypes())
        if args.png.suffix.lower().lstrip(".") not in formats:
            raise UsageError(f"--png {args.png}: the file name must end in one of "
                             f"{', '.join('.' + f for f in formats)}")  # fmt: skip
        try:
            args.png.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"cannot write --png {args.png}: {exc}") from exc
    for run_dir in args.run_dirs:
        opt = load(run_dir)
        rows.append(report_row(opt))
        path = args.png or Path(run_dir) / "convergence.png"
        try:
            png = plot_convergence(opt, path)
        except OSError as exc:
            raise UsageError(f"cannot write the plot {path}: {exc}") from exc
        print(f"{run_dir}: plot {png}", file=sys.stderr)
    print(format_table(rows))
    return 0


def cmd_rollout(args) -> int:
    from .objective import EnvObjective
    from .optimizer import RBBO

    opt = RBBO.resume(args.run_dir, read_only=True)
    result = opt.result()  # the confirmed recommendation, or the current one mid-run
    if result.best_basis is None:
        raise UsageError(f"{args.run_dir} has no successful evaluation at T_max yet: no "
                         "recommendation to replay")  # fmt: skip
    basis = result.best_basis
    if not opt.finished:
        print(f"the run has not finished: replaying its current recommendation, evaluation "
              f"{result.best_index}", file=sys.stderr)  # fmt: skip
    objective = _objective_of(opt)
    seconds = args.seconds or opt.config.t_max
    # A video of the first seconds is worth having (how the robot settles); R, measured from
    # the settle time on, is what a replay without --video is for.
    if isinstance(objective, EnvObjective) and not seconds > _measured_from(objective):
        if not args.video:
            raise UsageError(f"--seconds {seconds:g} must exceed the run's settle time "
                             f"{objective.settle_time:g} s, from which R is measured (from "
                             f"the first env step at or after it, {_measured_from(objective):g}"
                             f" s): give more (the run's T_max is {opt.config.t_max:g} s), or "
                             "add --video FILE to watch the episode without R")  # fmt: skip
    if not isinstance(objective, EnvObjective):
        if args.video:
            raise UsageError("--video needs an env run; a synthetic objective has no robot")
        r = objective(basis, seconds, args.seed)
        print(f"R = {r:.6g} per second (T = {seconds:g} s, seed {args.seed}); "
              f"optimum {objective.value(objective.optimum):.6g}")  # fmt: skip
        return 0
    if args.video:
        _check_video_name(args.video)  # before the env is built and the episode run
        _require_imageio()  # before the episode, so a missing extra costs nothing
        return _rollout_video(objective, basis, seconds, args.seed, args.video)
    r = objective(basis, seconds, args.seed)
    print(f"R = {r:.6g} per second from t = {objective.settle_time:g} s "
          f"(T = {seconds:g} s, seed {args.seed})")  # fmt: skip
    return 0


def _measured_from(objective) -> float:
    """When R starts: the first env step at or after the settle time (settled_reward_rate's
    rule), so that --seconds just past a settle time between two steps is not an empty span."""
    from softrom_gym.registration import control_period

    from .objective import settled_step

    step = control_period(objective.env_id, **objective.env_kwargs)
    if step is None:
        return objective.settle_time
    return settled_step(step, objective.settle_time) * step


def _check_video_name(video: Path) -> None:
    """A --video name whose suffix no video writer takes is a usage error (its folder is
    created, so only the name is checked)."""
    try:
        from controllers.episode import _VIDEO_SUFFIXES
    except ImportError:  # a stand-in controllers module (the tests'): it writes no video
        return
    if video.suffix.lower() not in _VIDEO_SUFFIXES:
        raise UsageError(f"--video {video}: the file name must end in one of "
                         f"{', '.join(sorted(_VIDEO_SUFFIXES))}")  # fmt: skip


def _require_imageio() -> None:
    """Raise a usage error naming the extra when imageio cannot be imported.

    Only this import is turned into a usage error: an ImportError raised inside the episode
    is a fault of the package and keeps its traceback.
    """
    try:
        import imageio.v2  # noqa: F401
    except ImportError as exc:
        raise UsageError(
            "--video needs imageio: pip install 'softrom[video]' (imageio and imageio-ffmpeg)"
        ) from exc


def _rollout_video(objective, basis, seconds: float, seed: int, video: Path) -> int:
    import inspect

    import controllers

    from .objective import settled_reward_rate

    video.parent.mkdir(parents=True, exist_ok=True)
    env = objective.make_env(basis, render_mode="rgb_array")
    if "video" in inspect.signature(controllers.run_episode).parameters:
        result = objective.episode(basis, seconds, seed, env=env, video=str(video))
    else:  # record through Gymnasium's wrapper
        import shutil
        import tempfile

        from gymnasium.wrappers import RecordVideo

        with tempfile.TemporaryDirectory() as folder:
            wrapped = RecordVideo(env, folder, episode_trigger=lambda _: True,
                                  name_prefix="rollout", disable_logger=True)  # fmt: skip
            result = objective.episode(basis, seconds, seed, env=wrapped)
            wrapped.close()
            clips = sorted(Path(folder).glob("*.mp4"))
            if not clips:
                raise UsageError("no video was written (does the env render rgb_array frames?)")
            shutil.move(str(clips[0]), video)
    if not seconds > _measured_from(objective):
        print(f"video: {video} ({seconds:g} s; no R, which is measured from the run's settle "
              f"time {objective.settle_time:g} s on)")  # fmt: skip
        return 0
    dt = getattr(result, "dt", None) or objective.step_seconds(env)
    r = settled_reward_rate(result, dt, objective.settle_time, seconds)
    print(f"R = {r:.6g} per second; video: {video}")
    return 0


def cmd_baselines(args) -> int:
    from . import rl
    from .objective import _check_env_keywords

    env_id = _resolve_env(args.env_id, synthetic=False)
    algos = [a.strip().lower() for a in args.algo.split(",")]
    bad = [a for a in algos if a not in rl.ALGOS]
    if bad:
        raise UsageError(f"unknown --algo {bad[0]!r}; valid: {', '.join(rl.ALGOS)}")
    if not 0 <= args.settle_time < args.seconds:
        raise UsageError(f"--settle-time {args.settle_time} must lie in [0, --seconds)")
    if not args.no_mpc:
        _check_controllers()
    with _bad_input():
        rl.require_sb3()
        rl.steps_per_algo(args.steps, tuple(dict.fromkeys(algos)))
        bases, env_kwargs = rl.resolve_bases(args.control_basis.split(","), env_id, args.run,
                                             args.sim_dim, args.control_dim)  # fmt: skip
        given = _env_kwargs(args.env_kwarg)
        if given:
            _check_env_keywords(env_id, given, rl.SET_BY_BASELINES)
        for key, value in given.items():
            if args.run is not None and env_kwargs.get(key, value) != value:
                raise UsageError(f"--env-kwarg {key}={json.dumps(value)} differs from run "
                                 f"{args.run}'s {key}={json.dumps(env_kwargs[key])}, the env "
                                 "its B_c was found in")  # fmt: skip
            if args.run is not None and key not in env_kwargs:
                raise UsageError(f"--env-kwarg {key} was not given to run {args.run}, whose "
                                 "B_c was found in its env as it was")  # fmt: skip
        env_kwargs = {**env_kwargs, **given}
        # the env is made here: a bad --env-kwarg value fails now, named, not as a traceback
        # after the job folders are claimed
        for basis in bases.values():
            rl._make_env(env_id, basis, env_kwargs, False).close()
        planner_kwargs = _run_mppi_overrides(args.run) if args.run and not args.no_mpc else {}
    out = args.out or Path("runs") / f"baselines-{env_id.split('/')[-1]}"
    try:
        rows = rl.run_baselines(
            env_id, bases, out, algos=tuple(dict.fromkeys(algos)), steps=args.steps,
            checkpoint_every=args.checkpoint_every, eval_seeds=args.eval_seeds,
            seconds=args.seconds, settle_time=args.settle_time, seed=args.seed,
            mpc=not args.no_mpc, env_kwargs=env_kwargs, progress=not args.no_progress,
            workers=args.workers, planner_kwargs=planner_kwargs,
        )  # fmt: skip
    except KeyboardInterrupt:
        print("\ninterrupted; run the same command again to continue from the last "
              "checkpoint", file=sys.stderr)  # fmt: skip
        return 130
    print(rl.format_table(rows))
    print(f"results: {out / 'baselines.csv'}, {out / 'baselines.md'}", file=sys.stderr)
    return 0


def cmd_reproduce(args) -> int:
    from .reproduce.cli import command

    return command(args, UsageError)


COMMANDS = {"optimize": cmd_optimize, "resume": cmd_resume, "confirm": cmd_confirm,
            "report": cmd_report,
            "rollout": cmd_rollout, "baselines": cmd_baselines,
            "reproduce": cmd_reproduce}  # fmt: skip


@contextlib.contextmanager
def _terminate_as_interrupt():
    """Let SIGTERM stop a command as Ctrl-C does, and either signal stop it only once.

    A batch scheduler's time limit (SLURM, ``timeout``) or a plain ``kill`` sends SIGTERM,
    whose default action ends the process at once: the run's session record and the workers'
    shutdown in ``finally`` blocks would be skipped. Raised as KeyboardInterrupt, it goes
    through the same path as Ctrl-C (what was recorded stays, "interrupted; continue with").
    Signal handlers belong to the main thread, so elsewhere (a test's thread) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    stopping: list[int] = []

    def interrupt(signum, frame):
        # Once, for SIGTERM and SIGINT together: ``timeout`` (``-s INT`` too) signals the
        # process and then its whole group, so the process gets the signal twice, and a second
        # KeyboardInterrupt raised inside the shutdown the first one began would break it off
        # (a traceback, and the pool's supervisor thread still running at interpreter exit).
        if stopping:
            return
        stopping.append(signum)
        raise KeyboardInterrupt(f"signal {signum}")

    handled = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        handled.append(signal.SIGINT)  # not where SIGINT is ignored (a background job)
    previous = {s: signal.signal(s, interrupt) for s in handled}
    try:
        yield
    finally:
        # After a SIGTERM the process is on its way out: a late second one must not turn the
        # clean exit (status 130) into a kill. Ctrl-C works again for an in-process caller.
        for s in handled:
            ignore = stopping and s == signal.SIGTERM
            signal.signal(s, signal.SIG_IGN if ignore else previous[s])


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rbbo`` console script; returns the exit status."""
    from .objective import SimulationSpaceMismatch
    from .optimizer import EvaluationsFailing
    from .store import RunDirectoryError

    try:
        args = _parser().parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        with _terminate_as_interrupt():
            return COMMANDS[args.command](args)
    except (UsageError, RunDirectoryError, SimulationSpaceMismatch) as exc:
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"rbbo: error: {message}", file=sys.stderr)
        return 2
    except EvaluationsFailing as exc:  # rbbo optimize, resume, or a stage of reproduce
        print(f"rbbo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # outside a command's own handler (building the objective, plotting after the run):
        # whatever was recorded is kept, as on any interrupt
        print("\ninterrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
