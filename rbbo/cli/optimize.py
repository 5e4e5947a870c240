"""``rbbo optimize``, ``rbbo resume`` and ``rbbo confirm``: start a search, continue it,
and measure a finished run's R_init and R* again.
"""

from __future__ import annotations

import sys
import time
from datetime import datetime
from pathlib import Path

from .arguments import _env_kwargs, merged_mpc_changes
from .errors import UsageError, _bad_input
from .execution import _execute, _make_executor
from .objectives import _check_controllers, _objective_of, _resolve_env
from .rollout import _measured_from, _measures_r


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


# How a run made without a stored "execution" (an early version's) runs its evaluations.
_EXECUTION_DEFAULTS = {"executor": "process", "workers": 1, "timeout_s": 600.0,
                       "address": None, "deterministic": False}  # fmt: skip


# optimize's and resume's refusal of --timeout for the serial executor
_SERIAL_TIMEOUT = ("--timeout is for --executor process or ray: the serial executor "
                   "evaluates in this process and cannot stop an evaluation")  # fmt: skip


def _stored_execution(store) -> dict:
    """The run's stored execution settings (config.json's "execution", defaults filled in),
    checked as ``rbbo optimize`` checks its options, so that a hand-edited one is named with
    its file rather than failing later (a traceback, or a negative per-evaluation limit).

    Raises
    ------
    RunDirectoryError
        When a setting is not one ``rbbo optimize`` could have stored.
    """
    import math

    from ..store import RunDirectoryError

    execution = {**_EXECUTION_DEFAULTS, **(store.config.get("execution") or {})}

    def bad(key: str, what: str) -> RunDirectoryError:
        return RunDirectoryError(f"{store.path}/config.json has invalid execution settings: "
                                 f"{key} must be {what}, got {execution[key]!r}")  # fmt: skip

    if execution["executor"] not in ("process", "ray", "serial"):
        raise bad("executor", "one of process, ray, serial")
    workers = execution["workers"]
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise bad("workers", "a positive integer")
    timeout = execution["timeout_s"]  # (None: no limit, as a library call may store)
    if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                or not 0 < timeout < math.inf):  # fmt: skip
        raise bad("timeout_s", "null or a positive number of seconds")
    if execution["address"] is not None and not isinstance(execution["address"], str):
        raise bad("address", "null or a Ray address")
    if not isinstance(execution["deterministic"], bool):
        raise bad("deterministic", "true or false")
    return execution


def cmd_optimize(args) -> int:
    from ..objective import make_objective, parse_objective_spec
    from ..optimizer import RBBO, RBBOConfig

    if args.control_dim > args.sim_dim:
        raise UsageError(f"--control-dim {args.control_dim} exceeds --sim-dim {args.sim_dim}")
    if args.t_min >= args.t_max and args.fidelity == "boca":
        raise UsageError(f"--t-min {args.t_min} must be below --t-max {args.t_max} (BOCA "
                         "searches episode lengths between them)")  # fmt: skip
    if args.address and args.executor != "ray":
        raise UsageError("--address is for --executor ray")
    # (the serial executor evaluates in this process and cannot stop an evaluation: a
    # --timeout given with it was ignored without a word)
    if args.timeout is not None and args.executor == "serial":
        raise UsageError(_SERIAL_TIMEOUT)
    timeout = _EXECUTION_DEFAULTS["timeout_s"] if args.timeout is None else args.timeout
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
        # on the env-step grid: --t-max 1.01 past a 1-s settle time is 40 steps of 25 ms, none
        # of them measured, and every evaluation failed after its episode
        for flag, seconds in (
            ("--t-max", args.t_max),
            *((("--t-min", args.t_min),) if args.fidelity == "boca" else ()),
        ):
            if not _measures_r(objective, seconds):
                raise UsageError(f"{flag} {seconds:g} leaves no env step from --settle-time "
                                 f"{args.settle_time:g} on (R is measured from the first "
                                 f"step at or after it, {_measured_from(objective):g} s, and "
                                 f"the episode runs whole steps): give more")  # fmt: skip
    out = args.out
    if out is None:
        name = args.env_id.split("/")[-1].split(":")[0]
        out = Path("runs") / f"{name}-{datetime.now():%Y%m%d-%H%M%S}"
    execution = {"executor": args.executor, "workers": args.workers,
                 "timeout_s": timeout, "address": args.address,
                 "deterministic": args.deterministic}  # fmt: skip
    executor = _make_executor(objective, execution)
    try:
        with _bad_input():
            opt = RBBO.create(out, config, objective_spec=objective.spec(),
                              extra={"execution": execution, "problem": problem})  # fmt: skip
    except BaseException:
        executor.shutdown(wait=False)
        raise
    try:
        return _optimize(opt, executor, args, spec, iterations, budget)
    finally:
        opt.close()  # (see cmd_resume)


def _optimize(opt, executor, args, spec: dict, iterations: int | None,
              budget: float | None) -> int:  # fmt: skip
    """:func:`cmd_optimize` once its run directory is made: notes, then the search."""
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


def _timeout_text(seconds: float | None) -> str:
    """A per-evaluation limit as resume prints it: '10 min', or 'none' (None: no limit)."""
    return "none" if seconds is None else _duration_text(seconds)


def cmd_resume(args) -> int:
    from ..optimizer import RBBO

    opt = RBBO.resume(args.run_dir)
    # Closed when the command returns, whichever way: the run directory's lock is given back
    # then, not when the collector finds the RBBO (an exception's traceback keeps it), so that
    # a caller in this process (a notebook, a test) may open the run again at once.
    try:
        return _resume(opt, args)
    finally:
        opt.close()


def _resume(opt, args) -> int:
    """:func:`cmd_resume` on the run ``opt`` it opened."""
    store = opt.store
    assert store is not None  # (resume opens the run's store)
    objective = _objective_of(opt)
    execution = _stored_execution(store)
    stored_timeout = execution["timeout_s"]
    if args.workers:
        execution["workers"] = args.workers
    if args.executor:
        if args.address and args.executor != "ray":
            raise UsageError("--address is for --executor ray")  # (as optimize says)
        execution["executor"] = args.executor
        execution["address"] = args.address if args.executor == "ray" else None
        if args.executor == "serial" and not args.workers:
            execution["workers"] = 1  # (the stored count was another executor's)
    elif args.address:
        if execution["executor"] != "ray":
            raise UsageError("--address is for --executor ray")
        execution["address"] = args.address
    if args.timeout is not None:
        # (as optimize refuses it: the serial executor, the run's or this session's, would
        # ignore it without a word)
        if execution["executor"] == "serial":
            raise UsageError(_SERIAL_TIMEOUT)
        execution["timeout_s"] = args.timeout
    started = time.monotonic()
    # built before a new limit is written: a command refused for its executor (--workers 2
    # with --executor serial, a missing Ray) changes nothing in the run
    executor = _make_executor(objective, execution)
    try:
        # A new limit replaces both stored ones: a run that stopped at its budget, resumed with
        # --iterations, would otherwise stop again at once. It is written to config.json, so a
        # later plain `rbbo resume` (the hint an interrupted run prints) goes on to it, or, for a
        # lowered limit that is already reached, stays stopped at it.
        iterations, budget = args.iterations, args.budget
        if iterations is None and budget is None:
            iterations, budget = opt.config.max_evaluations, opt.config.budget_s
            if iterations is None and budget is None:
                # (a run made by the library, RBBO.create without a limit and run() with one:
                # resumed without one it searched with none, finished or not)
                raise UsageError(f"{store.path} stores no limit: give --iterations or --budget")
        elif (iterations, budget) != (opt.config.max_evaluations, opt.config.budget_s):
            old = _limits_text(opt.config.max_evaluations, opt.config.budget_s)
            with _bad_input():
                opt.set_limits(iterations, budget)
            print(f"{store.path}: its limit is now {_limits_text(iterations, budget)} (was "
                  f"{old}), stored in config.json for later resumes", file=sys.stderr)  # fmt: skip
        if args.timeout is not None and args.timeout != stored_timeout:
            # The run's, as its limits are (written once they are known good): evaluations
            # that timed out are given longer, and a later plain `rbbo resume` (an interrupted
            # run's hint) keeps to it rather than spending evaluations on the old one.
            store.update_config({"execution": {"timeout_s": args.timeout}})
            print(f"{store.path}: its per-evaluation limit (--timeout) is now "
                  f"{_timeout_text(args.timeout)} (was {_timeout_text(stored_timeout)}), "
                  "stored in config.json for later resumes", file=sys.stderr)  # fmt: skip
        at_limit = not opt.can_submit(iterations, budget)
        # (a run at its limit whose confirmation is done has nothing left to resume; one
        # whose confirmation an interrupt cut short is confirmed below)
        nothing_to_do = at_limit and opt.finished
        if at_limit:
            done = len(opt.evaluations)
            then = ("give a larger --budget or --iterations to go on" if nothing_to_do else
                    "measuring R_init and R* (not finished before); a larger --budget or "
                    "--iterations would search on")  # fmt: skip
            print(f"{store.path} has reached its limit ({_limits_text(iterations, budget)}; it "
                  f"has {done} evaluations, {_duration_text(opt.elapsed_s)}): nothing more to "
                  f"search; {then}", file=sys.stderr)  # fmt: skip
    except BaseException:
        executor.shutdown(wait=False)
        raise
    code = _execute(opt, executor, iterations, budget, not args.no_progress,
                    bool(execution.get("deterministic", False)))  # fmt: skip
    if code == 0 and not nothing_to_do:
        print(f"resumed for {time.monotonic() - started:.0f} s", file=sys.stderr)
    return code


def cmd_confirm(args) -> int:
    from ..optimizer import RBBO

    opt = RBBO.resume(args.run_dir)
    try:
        return _confirm(opt, args)
    finally:
        opt.close()  # (see cmd_resume)


def _confirm(opt, args) -> int:
    """:func:`cmd_confirm` on the run ``opt`` it opened."""
    from ..report import format_table, report_row

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
    execution = _stored_execution(store)
    # (checked as optimize and resume check it: --workers 4 on a serial run is refused)
    executor = _make_executor(
        objective, {**execution, "workers": args.workers or execution["workers"]}
    )
    try:
        with _bad_input():
            after = opt.confirm_again(executor)
    except KeyboardInterrupt:
        executor.shutdown(wait=False)
        print(f"\ninterrupted; nothing is lost: run rbbo confirm {store.path} again",
              file=sys.stderr)  # fmt: skip
        return 130
    except OSError as exc:
        # a write the system refused (a full disk): what was recorded before it is kept
        executor.shutdown(wait=False)
        print(f"rbbo: error: {store.path}: {exc}; run rbbo confirm {store.path} again once "
              "it can be written", file=sys.stderr)  # fmt: skip
        return 1
    except BaseException:
        # (a usage error from bad stored input, a failed worker: its processes are stopped,
        # not left to the interpreter's exit)
        executor.shutdown(wait=False)
        raise
    executor.shutdown()

    def fmt(value: float | None) -> str:
        return "-" if value is None else f"{value:.6g}"

    seeds = ", ".join(map(str, opt.config.fresh_seeds))
    print(f"R_init {fmt(before.R_init)} -> {fmt(after.R_init)}, R* {fmt(before.R_star)} -> "
          f"{fmt(after.R_star)} (fresh seeds {seeds})")  # fmt: skip
    print(format_table([report_row(opt)]))
    return 0
