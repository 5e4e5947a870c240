"""``rbbo reproduce``'s arguments and command (registered by :mod:`rbbo.cli.parser`).

::

    rbbo reproduce --budget-per-benchmark 45m --workers 2 --out runs/reproduce
    rbbo reproduce --benchmarks CrossSwim-v0 --budget-per-benchmark 5m --stages table,bo
    rbbo reproduce --out runs/reproduce --stages table --repeats 3   # 2 more runs per benchmark
    rbbo reproduce --out runs/reproduce --report-only     # rewrite REPORT.md from the runs
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path
from typing import Any

from .plan import _STAGES, BENCHMARKS, ReproducePlan, check_sessions

__all__ = ["add_parser", "command"]


def _int_list(text: str) -> list[int]:
    """'1-5', '1,2,4' or '1-3,8' -> a list of integers."""
    out: list[int] = []
    try:
        for part in filter(None, text.split(",")):
            low, sep, high = part.partition("-")
            out.extend(range(int(low), int(high) + 1) if sep else [int(low)])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected integers like 1-5 or 1,2,4, got {text!r}"
        ) from None
    if not out:
        raise argparse.ArgumentTypeError(f"expected at least one integer, got {text!r}")
    return out


def _float_list(text: str) -> list[float]:
    try:
        values = [float(v) for v in filter(None, text.split(","))]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 5,10,20, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def _names(valid: tuple[str, ...]):
    def parse(text: str) -> list[str]:
        names = [n.strip() for n in text.split(",") if n.strip()]
        short = [n.split("/")[-1] for n in names]
        bad = [n for n in short if n not in valid]
        if bad or not names:
            raise argparse.ArgumentTypeError(
                f"unknown {', '.join(bad) or repr(text)}; valid: {', '.join(valid)}"
            )
        return short

    return parse


def _one_name(valid: tuple[str, ...]):
    """One benchmark name (--direction-env A,B kept A without a word)."""
    names = _names(valid)

    def parse(text: str) -> str:
        given = names(text)
        if len(given) != 1:
            raise argparse.ArgumentTypeError(f"give one benchmark, got {', '.join(given)}")
        return given[0]

    return parse


def _mpc_changes(text: str) -> dict[str, Any]:
    from ..cli.arguments import mpc_changes_arg

    return mpc_changes_arg(text)


def _user_path(text: str) -> Path:
    from ..cli.arguments import user_path

    return user_path(text)


def _rl_steps(text: str) -> int | dict[str, int]:
    from ..cli.arguments import rl_steps_arg

    return rl_steps_arg(text)


class _NoBudget(argparse.Action):
    """``--budget``, which ``rbbo optimize`` takes and a reproduction has several of: a usage
    error naming them, not argparse's "unrecognized arguments"."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from ..cli.errors import UsageError

        raise UsageError(
            f"rbbo reproduce has no --budget (got {values}): --budget-per-benchmark DURATION "
            "is each benchmark's Table I run (and its BO run in stage bo), --direction-budget "
            "DURATION each direction's run; --stages table runs Table I alone"
        )


def add_parser(sub, parse_duration, positive_int, positive_float) -> argparse.ArgumentParser:
    """Add the ``reproduce`` subcommand to ``sub`` (rbbo.cli.parser's subparsers)."""
    about = (
        "the paper's results (Table I, BO vs BOCA, directions, studies of C, transfer to "
        "a larger M, perturbations, RL baselines) into one directory with a REPORT.md"
    )
    p = sub.add_parser("reproduce", help=about,
                       description=f"Reproduce {about}. The same command again resumes every part; "
                       "--stages picks parts, --status shows progress and runs "
                       "nothing.")  # fmt: skip
    defaults = ReproducePlan()
    p.add_argument("--benchmarks", type=_names(BENCHMARKS), default=list(BENCHMARKS),
                   help="comma list (default: all five)")  # fmt: skip
    p.add_argument("--budget-per-benchmark", type=parse_duration, default=defaults.budget_s,
                   help="wall time of each benchmark's RBBO run (default 45m)")  # fmt: skip
    p.add_argument("--budget", action=_NoBudget, help=argparse.SUPPRESS)
    p.add_argument("--repeats", type=int, default=defaults.repeats, metavar="N",
                   help="independent RBBO runs per benchmark in stage table, run k seeded "
                   "--seed + k, each with the full budget (default 1); Table I's row is run "
                   "0's, and so is the B_c the transfer, perturbation and RL stages use; with "
                   "N > 1 the report adds each run's improvement and their mean ± sample sd "
                   "and range. Stage bo stays one run per benchmark")  # fmt: skip
    p.add_argument("--iterations", type=positive_int, help="cap on evaluations per run")
    p.add_argument("--workers", type=positive_int, default=defaults.workers,
                   help=f"evaluations run at once (default {defaults.workers})")  # fmt: skip
    p.add_argument("--deterministic", action="store_true",
                   help="tell each optimisation run's results in proposal order, so that with "
                   "--iterations the runs repeat bitwise on one install (a worker may wait "
                   "for an older evaluation)")  # fmt: skip
    p.add_argument("--executor", choices=["process", "serial", "ray"], default="process",
                   help="where evaluations run (default process)")  # fmt: skip
    p.add_argument("--controller", default=defaults.controller, metavar="NAME",
                   help="the MPC planner: mppi, gn, or a planner of your own as an import "
                   "path package.module:ClassName (a controllers.Planner subclass; default "
                   f"{defaults.controller})")  # fmt: skip
    p.add_argument("--sim-dim", type=positive_int, default=defaults.sim_dim,
                   help=f"M (default {defaults.sim_dim})")  # fmt: skip
    p.add_argument("--control-dim", type=positive_int, default=defaults.control_dim,
                   help=f"C (default {defaults.control_dim})")  # fmt: skip
    p.add_argument("--t-min", type=positive_float, default=defaults.t_min,
                   help=f"shortest T of the BOCA runs, s (default {defaults.t_min:g})")  # fmt: skip
    p.add_argument("--t-max", type=positive_float, default=defaults.t_max,
                   help=f"full episode length T_max, s (default {defaults.t_max:g})")  # fmt: skip
    p.add_argument("--settle-time", type=float, default=defaults.settle_time,
                   help=f"R is measured from this time on, s (default "
                   f"{defaults.settle_time:g})")  # fmt: skip
    p.add_argument("--init", type=int, default=defaults.n_init,
                   help="random initial points after the identity basis (default "
                   f"{defaults.n_init})")  # fmt: skip
    p.add_argument("--confirm-seeds", type=int, default=defaults.confirm_seeds,
                   help="fresh seeds for R_init and R* (default 5)")  # fmt: skip
    p.add_argument("--seed", type=int, default=defaults.seed,
                   help=f"seeds every run (default {defaults.seed})")  # fmt: skip
    p.add_argument("--stages", type=_names(_STAGES), default=list(_STAGES),
                   help=f"comma list of {','.join(_STAGES)} (default: all)")  # fmt: skip
    p.add_argument("--transfer-sim-dim", type=positive_int, default=defaults.transfer_sim_dim,
                   help="M of the richer model the transfer stage measures Table I's bases in "
                   f"(default {defaults.transfer_sim_dim})")  # fmt: skip
    p.add_argument("--direction-env", type=_one_name(BENCHMARKS), default=defaults.direction_env,
                   help=f"benchmark of the directions stage (default "
                   f"{defaults.direction_env})")  # fmt: skip
    p.add_argument("--directions", type=positive_int, default=defaults.directions,
                   help="directions d of the polar study, evenly spaced from +x (default "
                   f"{defaults.directions})")  # fmt: skip
    p.add_argument("--direction-budget", type=parse_duration, default=defaults.direction_budget_s,
                   help="wall time of each direction's run (default 15m)")  # fmt: skip
    p.add_argument("--perturbations", type=_float_list, default=defaults.perturbations_deg,
                   help="offsets in degrees, each run at + and - (default 5,10,20,30)")  # fmt: skip
    p.add_argument("--cost-cs", type=_int_list, default=defaults.cost_cs, help="default 1-20")
    p.add_argument("--reward-cs", type=_int_list, default=defaults.reward_cs, help="default 1-10")
    p.add_argument("--study-seeds", type=positive_int, default=defaults.study_seeds,
                   help="seeds per C of the reward-vs-C study (default "
                   f"{defaults.study_seeds})")  # fmt: skip
    p.add_argument("--study-seconds", type=positive_float, default=defaults.study_seconds,
                   help=f"episode length of the reward-vs-C study, s (default "
                   f"{defaults.study_seconds:g})")  # fmt: skip
    p.add_argument("--rl-benchmarks", type=_names(BENCHMARKS), default=defaults.rl_benchmarks,
                   help="benchmarks of the RL baselines (default CrossSwim-v0)")  # fmt: skip
    p.add_argument("--rl-algos", type=_names(("ppo", "sac")), default=defaults.rl_algos,
                   help="comma list of ppo, sac (default "
                   f"{','.join(defaults.rl_algos)})")  # fmt: skip
    p.add_argument("--rl-steps", type=_rl_steps, default=defaults.rl_steps,
                   help="env steps per RL method and basis: N, or per method ppo=N,sac=N "
                   "(default 20000)")  # fmt: skip
    p.add_argument("--mpc", type=_mpc_changes, action="append", default=[],
                   help="MPC setting overrides, e.g. horizon=8,window=8,samples=4 "
                   "(repeatable)")  # fmt: skip
    p.add_argument("--timeout", type=parse_duration, default=defaults.timeout_s,
                   help="per-evaluation limit (default 30m)")  # fmt: skip
    p.add_argument("--out", type=_user_path, default=Path("runs/reproduce"),
                   help="the reproduction's directory (default runs/reproduce)")  # fmt: skip
    p.add_argument("--report-only", action="store_true",
                   help="rewrite tables, figures and REPORT.md from the runs in --out")  # fmt: skip
    p.add_argument("--report", type=_user_path, metavar="PATH",
                   help="also write the report here, its links relative to it "
                   "(e.g. docs/REPORT.md)")  # fmt: skip
    p.add_argument("--status", action="store_true",
                   help="print what each part of the reproduction in --out has done and the "
                   "budget left (the stages of the stored plan and of its earlier sessions; "
                   "--stages, --repeats, --iterations, --workers and budgets given here "
                   "override it, as a session given them would run, --benchmarks "
                   "narrows it to some of its benchmarks), and exit")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return p


def _plan(args) -> ReproducePlan:
    from ..cli.arguments import merged_mpc_changes

    return ReproducePlan(
        benchmarks=args.benchmarks, budget_s=args.budget_per_benchmark, repeats=args.repeats,
        iterations=args.iterations, workers=args.workers, deterministic=args.deterministic,
        executor=args.executor,
        controller=args.controller, sim_dim=args.sim_dim, control_dim=args.control_dim,
        t_min=args.t_min, t_max=args.t_max, settle_time=args.settle_time, n_init=args.init,
        confirm_seeds=args.confirm_seeds, seed=args.seed, stages=args.stages,
        transfer_sim_dim=args.transfer_sim_dim,
        direction_env=args.direction_env, directions=args.directions,
        direction_budget_s=args.direction_budget, perturbations_deg=args.perturbations,
        cost_cs=args.cost_cs, reward_cs=args.reward_cs, study_seeds=args.study_seeds,
        study_seconds=args.study_seconds, rl_benchmarks=args.rl_benchmarks,
        rl_algos=args.rl_algos, rl_steps=args.rl_steps, planner_kwargs=merged_mpc_changes(args.mpc),
        timeout_s=args.timeout,
    )  # fmt: skip


def _stored(out: Path, usage_error: type[Exception], missing: str) -> tuple[dict, ReproducePlan]:
    """reproduce.json of ``out`` and its plan; a missing or unreadable one is a usage error."""
    import json

    path = out / "reproduce.json"
    if not path.exists():
        raise usage_error(f"{out} has no reproduce.json: {missing}")
    try:
        document = json.loads(path.read_text())
        plan = ReproducePlan.from_dict(document["plan"])
        check_sessions(document)
        return document, plan
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise usage_error(f"{path} is not a reproduce plan: {exc}") from None


def _status(args, wanted: ReproducePlan, usage_error: type[Exception]) -> int:
    """Print ``--status``: the stored plan, with what a session may change taken from the
    command line (``wanted``), and ``--benchmarks`` narrowing it to some of its benchmarks."""
    from dataclasses import replace

    from .status import recorded_repeats, recorded_stages, status_lines

    document, stored = _stored(args.out, usage_error, "no reproduction there yet")
    given = {a.split("=")[0] for a in args.argv if a.startswith("--")}
    # A setting that defines the experiment is the stored one: one given otherwise would be
    # ignored, and the status read as of another plan than the user's.
    defaults = ReproducePlan()
    ignored = [k for k in stored.differences(wanted) if k != "benchmarks"
               and getattr(wanted, k) != getattr(defaults, k)]  # fmt: skip
    if ignored:
        shown = ", ".join(f"{k} {getattr(stored, k)!r}" for k in ignored)
        raise usage_error(
            f"{args.out} was started with other settings ({shown}); --status reads them "
            "from its reproduce.json: leave those options out"
        )
    changes = {field: getattr(args, name) for flag, name, field in (
        ("--stages", "stages", "stages"), ("--budget-per-benchmark", "budget_per_benchmark",
         "budget_s"), ("--direction-budget", "direction_budget", "direction_budget_s"),
        ("--rl-benchmarks", "rl_benchmarks", "rl_benchmarks"), ("--rl-steps", "rl_steps",
         "rl_steps"), ("--rl-algos", "rl_algos", "rl_algos"),
        ("--repeats", "repeats", "repeats"), ("--iterations", "iterations", "iterations"),
        ("--workers", "workers", "workers")) if flag in given}  # fmt: skip
    if "--benchmarks" in given:
        unknown = [b for b in args.benchmarks if b not in stored.benchmarks]
        if unknown:
            raise usage_error(
                f"{', '.join(unknown)} is not part of the reproduction in {args.out} (its "
                f"benchmarks: {', '.join(stored.benchmarks)})"
            )
        changes["benchmarks"] = [b for b in stored.benchmarks if b in args.benchmarks]
    # The stored stages are the last session's; a status is of the whole reproduction, the
    # stages its earlier sessions ran too (not every stage: those it never ran are no part),
    # and as many Table I runs as any of them asked for.
    changes.setdefault("stages", recorded_stages(document))
    changes.setdefault("repeats", recorded_repeats(document))
    try:
        plan = replace(stored, **changes)
    except (ValueError, TypeError) as exc:
        raise usage_error(str(exc)) from exc
    print("\n".join(status_lines(args.out, plan)))
    return 0


def command(args, usage_error: type[Exception]) -> int:
    """Run ``rbbo reproduce``; bad input raises ``usage_error`` (one line, exit status 2)."""

    from .document import write_report
    from .runner import reproduce
    from .tables import format_markdown

    try:
        given = {a.split("=")[0] for a in args.argv if a.startswith("--")}
        if not 0 <= args.settle_time < args.t_min < args.t_max:
            # (the plan says it with its field names; here the options, and which of them
            # took their defaults: "--t-max 2 --settle-time 1" is refused for --t-min's 4)
            def shown(flag: str, value: float) -> str:
                return f"{flag} {value:g}" + ("" if flag in given else " (default)")

            got = ", ".join(
                [
                    shown("--settle-time", args.settle_time),
                    shown("--t-min", args.t_min),
                    shown("--t-max", args.t_max),
                ]
            )
            raise ValueError(
                f"need 0 <= settle_time < t_min < t_max, got {got}: the BOCA runs search "
                "episode lengths T in [--t-min, --t-max] and measure R from --settle-time on"
            )
        plan = _plan(args)
        if "--repeats" in given and "table" not in plan.stages and not args.status:
            raise ValueError(f"--repeats {args.repeats} runs Table I's RBBO runs again: it "
                             "needs stage table in --stages (e.g. --stages table)")  # fmt: skip
        if "rl" in plan.stages and not (args.report_only or args.status):
            from ..rl import require_sb3

            try:
                require_sb3()
            except ImportError as exc:
                others = ",".join(s for s in plan.stages if s != "rl")
                raise ValueError(f"{exc} (or leave the stage out: --stages {others})") from None
        if plan.planner_kwargs:  # checked now, not as a failed evaluation in a worker
            from controllers import default_planner

            for bench in plan.benchmarks:
                planner, _ = default_planner(plan.env_id(bench), plan.controller,
                                             **plan.planner_kwargs)  # fmt: skip
                # (a per-dimension setting of another length than C failed as a traceback
                # once a run started, after reproduce.json had stored it)
                planner.settings.check_control_dim(plan.control_dim)
                if "studies" in plan.stages:  # the reward-vs-C study runs each C
                    for c in plan.reward_cs:
                        try:
                            planner.settings.check_control_dim(c)
                        except ValueError as exc:
                            raise ValueError(
                                f"{exc} (stage 'studies' runs the reward-vs-C "
                                f"study at C = {c} with the same --mpc; give one "
                                "number, or leave the stage out)"
                            ) from None
    except (ValueError, TypeError) as exc:
        raise usage_error(str(exc)) from exc
    if args.status:
        return _status(args, plan, usage_error)
    if (args.out / "config.json").is_file() and not (args.out / "reproduce.json").exists():
        # its files and a reproduction's (runs/, REPORT.md, reproduce.json) would share a folder
        raise usage_error(f"{args.out} is an RBBO run directory (rbbo optimize's --out); give "
                          "the reproduction a folder of its own with --out")  # fmt: skip
    searching = [s for s in plan.ordered_stages() if s in ("table", "bo", "directions")]
    if (
        not args.report_only
        and plan.iterations is not None
        and searching
        and (plan.iterations <= plan.n_init + 1)
    ):
        # as rbbo optimize notes it: the report would call these RBBO runs, which they are not
        print(f"note: --iterations {plan.iterations} <= 1 + --init {plan.n_init}: the initial "
              f"design (the identity basis, then {plan.n_init} random points) takes every "
              f"evaluation of the runs of stage(s) {', '.join(searching)}, and the GP "
              "proposes none", file=sys.stderr)  # fmt: skip
    if args.report_only:
        document, stored = _stored(args.out, usage_error, "nothing to report")
        written = write_report(args.out, stored, document, args.report)
    else:
        command_line = "rbbo " + " ".join(shlex.quote(a) for a in args.argv)
        try:
            written = reproduce(args.out, plan, progress=not args.no_progress,
                                command=command_line, copy_report=args.report)  # fmt: skip
        except KeyboardInterrupt:
            print(f"\ninterrupted; continue with the same command (--out {args.out})",
                  file=sys.stderr)  # fmt: skip
            return 130
    if written.get("table"):
        print(format_markdown(written["table"]))
    if written.get("runs_markdown"):
        print("\n" + written["runs_markdown"])
    print(f"report: {written['report']}" + (f" (and {written['copy']})" if "copy" in written
                                             else ""))  # fmt: skip
    return 0
