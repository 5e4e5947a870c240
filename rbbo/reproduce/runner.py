"""``reproduce``: run every experiment of the paper's results section into one directory.

Layout of ``OUT`` (every part resumable: rerunning the same command continues it)::

    reproduce.json            the plan, and one entry per session (command, wall time)
    runs/<bench>-boca/        Table I's RBBO run (BOCA), one per benchmark (run 0)
    runs/<bench>-boca-run<k>/ its repeats k = 1 .. repeats - 1 (seed + k), with --repeats
    runs/<bench>-bo/          the plain-BO run beside it (the BO-vs-BOCA figure)
    runs/<env>-dir<deg>/      one RBBO run per walking direction
    transfer.csv              Table I's two bases measured again at M = transfer_sim_dim
    perturbation.csv          the direction-0 B_c evaluated off its direction
    *-superseded.csv          rows of a B_c that its run has since replaced (kept, not used)
    studies/                  cost_vs_c.csv, reward_vs_c.csv
    rl/<bench>/               the RL baselines (PPO, SAC) and MPPI on Table I's bases
                              (``rbbo baselines``' layout)
    reproduce.log             what each session printed
    .rbbo.lock                held by the session that runs (one at a time; --status and
                              --report-only read without it)
    table1.csv, table1_runs.csv, table1.md, transfer_table.csv, *.png, REPORT.md

Every optimisation run is an ordinary RBBO run directory (``rbbo report`` reads it); a
session killed at any moment loses at most the evaluations in flight.
"""

# The reproduction, module by job: this module runs a session (reproduce: the record
# reproduce.json, its heartbeat, the stages in order, the report), optimisation_runs.py the
# RBBO runs (Table I, BO, directions), stages.py the perturbation study, the studies of C and
# the RL baselines, csv_rows.py the record's CSV files and session_log.py the session's log.
# The names below are re-exported so that imports from this module keep working.
from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ..provenance import machine_description, source_version
from ..store import RunDirectoryError, _acquire_lock, _atomic_write, _make_dirs, _release_lock
from .csv_rows import _append_row as _append_row
from .csv_rows import _supersede as _supersede
from .optimisation_runs import _objective, optimise
from .optimisation_runs import _run_spec as _run_spec
from .plan import ReproducePlan, check_sessions
from .session_log import Log, _log_stderr, _tee
from .stages import _evaluate_seeds as _evaluate_seeds
from .stages import _perturbation_base, perturbation, rl_baselines, studies
from .transfer import measure_transfer

__all__ = ["reproduce"]

# How often a running session records its wall time in reproduce.json (seconds).
_HEARTBEAT_S = 60.0


def _load_plan(out: Path, plan: ReproducePlan) -> dict[str, Any]:
    path = out / "reproduce.json"
    if not path.exists():
        return {"plan": plan.to_dict(), "sessions": []}
    try:
        document = json.loads(path.read_text())
        stored = ReproducePlan.from_dict(document["plan"])
        check_sessions(document)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RunDirectoryError(f"{path} is not a reproduce plan: {exc}") from None
    differing = stored.differences(plan)
    if differing:
        raise RunDirectoryError(
            f"{out} was started with other settings ({', '.join(differing)}); use a new --out "
            "or the same settings (budgets, workers and stages may change)"
        )
    document["plan"] = plan.to_dict()
    return document


def reproduce(out: str | os.PathLike, plan: ReproducePlan, *, progress: bool = True,
              log: Log = _log_stderr, command: str | None = None,
              copy_report: str | os.PathLike | None = None) -> dict[str, Any]:  # fmt: skip
    """Run (or continue) every stage of ``plan`` into ``out`` and write the report (also to
    ``copy_report``, its links rewritten, when given).

    Returns a dict with the Table I rows and the paths written (see :mod:`.document`).
    """
    out = Path(out)
    try:
        _make_dirs(out)  # (the runs and tables in it are fsynced; so must its name be)
    except OSError as exc:  # (--out names a file, or a folder that cannot be made)
        raise RunDirectoryError(f"cannot create the reproduction directory {out}: {exc}") from exc
    # One session at a time: a second one (the same command in another terminal, or another
    # stage) would append the same rows to the CSV files, and each rewrites reproduce.json
    # from what it read at its start, dropping the other's session record. Each RBBO run
    # folder in it has its own lock besides; --status and --report-only take none.
    key = _acquire_lock(out)
    try:
        return _reproduce(out, plan, progress, log, command, copy_report)
    finally:
        _release_lock(key)


def _reproduce(out: Path, plan: ReproducePlan, progress: bool, log: Log, command: str | None,
               copy_report: str | os.PathLike | None) -> dict[str, Any]:  # fmt: skip
    """:func:`reproduce` in ``out``, which this process has locked."""
    from .document import write_report

    log = _tee(log, out / "reproduce.log")
    document = _load_plan(out, plan)
    session: dict[str, Any] = {
        "command": command or " ".join(sys.argv), "started": time.time(), "wall_s": 0.0,
        "source": source_version(), "machine": machine_description(),
        "budget_s": plan.budget_s, "direction_budget_s": plan.direction_budget_s,
        "workers": plan.workers, "deterministic": plan.deterministic,
        "stages": plan.ordered_stages(), "repeats": plan.repeats,
    }  # fmt: skip
    document["sessions"].append(session)
    log(f"session {len(document['sessions'])}: {session['command']} ({session['source']})")
    started = time.perf_counter()

    saved = [started]
    lock = threading.Lock()

    def save() -> None:
        with lock:
            saved[0] = time.perf_counter()
            session["wall_s"] = saved[0] - started
            _atomic_write(out / "reproduce.json", json.dumps(document, indent=2).encode())

    def heartbeat() -> None:
        # A session killed outright (SIGKILL, a lost machine) keeps its wall time to the
        # last minute instead of to the end of its last finished benchmark.
        if time.perf_counter() - saved[0] >= _HEARTBEAT_S:
            save()

    save()
    # The optimisation runs call heartbeat() after each evaluation; the other stages (RL
    # training, the studies) run for long stretches without one, so a thread beats too.
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(max(_HEARTBEAT_S, 1.0)):
            heartbeat()

    if "older than its sources" in session["source"]:
        log(
            "warning: the compiled core is older than the C++ sources of this checkout; "
            "reinstall (pip install -e .) so that the recorded commit is the code that runs"
        )
    runs = out / "runs"
    stages = set(plan.stages)
    per_bench = plan.repeats * ("table" in stages) + ("bo" in stages)
    budget = len(plan.benchmarks) * per_bench * plan.budget_s
    budget += plan.directions * plan.direction_budget_s if "directions" in stages else 0.0
    # only what this session runs (a session of some stages is one of several)
    budgets = ""
    if per_bench or "directions" in stages:
        budgets = (f"; optimisation budgets add up to {budget / 3600:.2f} h on "
                   f"{plan.on_workers()}, plus {plan.besides_budgets()}")  # fmt: skip
    named = [f"table ({plan.repeats} runs per benchmark, seeds {plan.seed}-"
             f"{plan.seed + plan.repeats - 1})" if s == "table" and plan.repeats > 1 else s
             for s in plan.ordered_stages()]  # fmt: skip
    log(f"reproduce into {out}: stages {', '.join(named)}{budgets} (rerun the same command to "
        "resume)")  # fmt: skip
    # started where the finally that stops it covers it: a failure before (a log that cannot
    # be written) would leave it rewriting reproduce.json in a long-lived process
    threading.Thread(target=beat, name="reproduce-heartbeat", daemon=True).start()
    try:
        for bench in plan.benchmarks:
            objective = _objective(plan, bench)
            if "table" in stages:
                optimise(runs / plan.table_run(bench), plan, objective, "boca", plan.budget_s,
                         progress, log, heartbeat)  # fmt: skip
            if "bo" in stages:
                optimise(runs / f"{bench}-bo", plan, objective, "bo", plan.budget_s, progress,
                         log, heartbeat)  # fmt: skip
            if "transfer" in stages:
                boca = runs / plan.table_run(bench)
                if not (boca / "best_basis.npy").exists():
                    raise RunDirectoryError(f"the transfer stage needs {bench}'s finished "
                                            "Table I run (stage 'table')")  # fmt: skip
                measure_transfer(out, plan, bench, boca, log)
            save()
        # The repeats come after every benchmark's run 0 (and the stages that read it), one
        # round at a time, so that a session stopped early leaves Table I whole and the
        # benchmarks with as many runs each.
        for repeat in range(1, plan.repeats) if "table" in stages else ():
            for bench in plan.benchmarks:
                optimise(runs / plan.table_run(bench, repeat), plan, _objective(plan, bench),
                         "boca", plan.budget_s, progress, log, heartbeat, repeat)  # fmt: skip
                save()
        if "directions" in stages:
            for deg in plan.direction_angles_deg():
                optimise(runs / f"{plan.direction_env}-dir{deg:03.0f}", plan,
                         _objective(plan, plan.direction_env, deg), "boca",
                         plan.direction_budget_s, progress, log, heartbeat)  # fmt: skip
                save()
        if "perturbation" in stages:
            perturbation(out, plan, _perturbation_base(out, plan), log)
            save()
        if "studies" in stages:
            studies(out, plan, log)
            save()
        if "rl" in stages:
            rl_baselines(out, plan, progress, log)
    finally:
        stop.set()
        save()
    return write_report(out, plan, document, None if copy_report is None else Path(copy_report))
