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
    table1.csv, table1.md, *.png, REPORT.md

Every optimisation run is an ordinary RBBO run directory (``rbbo report`` reads it); a
session killed at any moment loses at most the evaluations in flight.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RBBOConfig
from ..executors import EvaluationTask, make_executor
from ..objective import EnvObjective
from ..optimizer import RBBO
from ..provenance import machine_description, source_version
from ..store import RunDirectoryError, _atomic_write
from .plan import ReproducePlan
from .status import rl_bases
from .tables import basis_digest, read_rows
from .transfer import measure_transfer

__all__ = ["reproduce"]

Log = Callable[[str], None]

# How often a running session records its wall time in reproduce.json (seconds).
_HEARTBEAT_S = 60.0


def _run_spec(opt: RBBO) -> dict[str, Any]:
    """The objective a resumed run's config.json records (every run made here has one)."""
    store, spec = opt.store, opt.objective_spec
    assert store is not None  # (RBBO.resume opens the run's store)
    if spec is None:
        raise RunDirectoryError(f"{store.path}/config.json does not say what the objective is")
    return spec


def _log_stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _tee(log: Log, path: Path) -> Log:
    """``log``, and each message appended to ``path`` with its UTC time: the record keeps
    its own log, whatever the session's stderr went to."""

    def both(message: str) -> None:
        log(message)
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
        with open(path, "a", encoding="utf-8") as f:
            f.write("".join(f"{stamp} {line}\n" for line in message.splitlines() or [""]))

    return both


def _objective(plan: ReproducePlan, benchmark: str, direction_deg: float | None = None,
               sim_dim: int | None = None) -> EnvObjective:  # fmt: skip
    env_kwargs = {} if direction_deg is None else {"direction": math.radians(direction_deg)}
    return EnvObjective(plan.env_id(benchmark), sim_dim or plan.sim_dim, plan.control_dim,
                        controller=plan.controller, settle_time=plan.settle_time,
                        env_kwargs=env_kwargs,
                        planner_kwargs=dict(plan.planner_kwargs))  # fmt: skip


def _config(plan: ReproducePlan, fidelity: str, budget_s: float, repeat: int = 0) -> RBBOConfig:
    return RBBOConfig(sim_dim=plan.sim_dim, control_dim=plan.control_dim, fidelity=fidelity,
                      t_min=plan.t_min, t_max=plan.t_max, n_init=plan.n_init,
                      seed=plan.seed + repeat,
                      n_confirm=plan.confirm_seeds, max_evaluations=plan.iterations,
                      budget_s=budget_s)  # fmt: skip


def optimise(path: Path, plan: ReproducePlan, objective: EnvObjective, fidelity: str,
             budget_s: float, progress: bool, log: Log,
             heartbeat: Callable[[], None] | None = None, repeat: int = 0) -> Path:  # fmt: skip
    """Create or resume the RBBO run at ``path`` and run it to its budget and confirmation
    (``heartbeat()`` after each recorded evaluation); ``repeat`` k seeds it ``plan.seed + k``."""
    config = _config(plan, fidelity, budget_s, repeat)
    if (path / "config.json").exists():
        opt = RBBO.resume(path)
        stored = opt.config
        for name in ("sim_dim", "control_dim", "fidelity", "t_min", "t_max", "seed", "n_init",
                     "n_confirm"):  # fmt: skip
            if getattr(stored, name) != getattr(config, name):
                raise RunDirectoryError(f"{path} was made with {name} = "
                                        f"{getattr(stored, name)!r}, this plan has "
                                        f"{getattr(config, name)!r}")  # fmt: skip
        stored_spec = dict(_run_spec(opt))
        recorded = stored_spec.pop("simulation_space", None)
        planner = stored_spec.pop("planner", None)
        recorded_apart = ("simulation_space", "planner")  # checked on their own below
        spec = {k: v for k, v in objective.spec().items() if k not in recorded_apart}
        if stored_spec != spec:
            raise RunDirectoryError(f"{path} optimises another objective: {opt.objective_spec}")
        objective.expect_simulation_space(recorded)
        objective.expect_planner(planner)
    else:
        problem = {"env_id": objective.env_id, "N": objective.node_count()}
        execution = {"executor": plan.executor, "workers": plan.workers,
                     "timeout_s": plan.timeout_s,
                     "deterministic": plan.deterministic}  # fmt: skip
        opt = RBBO.create(path, config, objective_spec=objective.spec(),
                          extra={"execution": execution, "problem": problem})  # fmt: skip
    # The code is recorded per run as well as per session: each run starts fresh workers,
    # which import the checkout as it is then.
    log(f"[{path.name}] {fidelity.upper()}, budget {budget_s / 60:.1f} min, "
        f"{len(opt.evaluations)} evaluations so far ({source_version()})")  # fmt: skip
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc=path.name, unit="eval", initial=len(opt.evaluations), file=sys.stderr,
                   dynamic_ncols=True, leave=False)  # fmt: skip

    def callback(evaluation) -> None:
        if bar is not None:
            bar.update(1)
        if heartbeat is not None:
            heartbeat()

    executor = make_executor(plan.executor, objective, plan.workers, plan.timeout_s)
    finished = False
    try:
        result = opt.run(executor=executor, max_evaluations=plan.iterations, budget_s=budget_s,
                         callback=callback, deterministic=plan.deterministic)  # fmt: skip
        finished = True
    finally:
        # On an interrupt the workers are killed, not waited for: they ignore the group's
        # SIGINT, and an evaluation in flight can take minutes.
        executor.shutdown(wait=finished)
        if bar is not None:
            bar.close()
    log(f"[{path.name}] done: {result.evaluations} evaluations, R_init {_r(result.R_init)}, "
        f"R* {_r(result.R_star)} ({result.wall_s / 60:.1f} min)")  # fmt: skip
    return path


def _r(value: float | None) -> str:
    """R as the log prints it: four significant digits, as the status and the other stages
    log it (the record keeps every digit), "-" when not measured (a failed confirmation)."""
    return "-" if value is None else f"{value:.4g}"


def _append_row(path: Path, row: dict[str, Any]) -> None:
    """Append one CSV row and fsync it (a finished measurement is never lost). A row with
    columns the file lacks (written by an older version) rewrites the file with the wider
    header first, the old rows' new cells left empty."""
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists()
    if not new:
        with open(path, newline="") as f:
            header = next(csv.reader(f), [])
        missing = [k for k in row if k not in header]
        if missing or not header:
            old = read_rows(path)
            fieldnames = header + missing
            _rewrite_csv(path, old, fieldnames)
        row = {k: row.get(k, "") for k in (header + missing)} | row
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)
        f.flush()
        os.fsync(f.fileno())


def _rewrite_csv(path: Path, rows: list[dict[str, Any]], fieldnames: list[str]) -> None:
    """Replace ``path`` by ``rows`` under ``fieldnames`` atomically (a kill leaves the old
    file or the new one, never half of either)."""
    import io

    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=fieldnames, restval="")
    writer.writeheader()
    writer.writerows(rows)
    _atomic_write(path, buffer.getvalue().encode())


def _supersede(path: Path, stale: Callable[[dict[str, str]], bool]) -> int:
    """Move the rows of ``path`` for which ``stale(row)`` holds to ``<stem>-superseded.csv``
    (appended there first, so a kill between the two writes duplicates a row, never loses
    one); returns how many moved."""
    rows = read_rows(path)
    old = [r for r in rows if stale(r)]
    if not old:
        return 0
    for r in old:
        _append_row(path.with_name(f"{path.stem}-superseded.csv"), r)
    with open(path, newline="") as f:
        header = next(csv.reader(f), [])
    _rewrite_csv(path, [r for r in rows if not stale(r)], header)
    return len(old)


def _evaluate_seeds(plan: ReproducePlan, objective: EnvObjective, basis: np.ndarray,
                    seeds: tuple[int, ...]) -> list[float]:  # fmt: skip
    """R of ``basis`` at T_max on each seed, the seeds spread over the workers."""
    with make_executor(plan.executor, objective, plan.workers, plan.timeout_s) as executor:
        futures = [executor.submit(EvaluationTask(i, basis, plan.t_max, (s,)))
                   for i, s in enumerate(seeds)]  # fmt: skip
        outcomes = [f.result() for f in futures]
    return [o.R if o.status == "ok" else math.nan for o in outcomes]


def perturbation(out: Path, plan: ReproducePlan, base_run: Path, log: Log) -> Path:
    """The direction-0 B_c walking at offsets ±p from its direction (perturbation.csv)."""
    path = out / "perturbation.csv"
    opt = RBBO.resume(base_run, read_only=True)
    assert opt.store is not None  # (resume opens the run's store)
    basis = opt.store.best_basis()
    if basis is None:
        raise RunDirectoryError(f"{base_run} has no best basis yet")
    digest = basis_digest(basis)
    # Rows of another B_c (the run searched on under a larger budget, or another base run)
    # are kept aside, not mixed into this one's curve. Rows without a digest predate it.
    moved = _supersede(path, lambda r: Path(r["run"]).name != base_run.name
                       or r.get("basis_digest", "") not in ("", digest))  # fmt: skip
    if moved:
        log(f"[perturbation] {moved} offsets of another B_c moved to "
            "perturbation-superseded.csv; measuring them again")  # fmt: skip
    base_deg = math.degrees(float((_run_spec(opt).get("env_kwargs") or {})
                                  .get("direction", 0.0)))  # fmt: skip
    seeds = opt.config.fresh_seeds
    # the basis is replayed in the env as built now: it must be the run's simulation space
    _objective(plan, plan.direction_env, base_deg).expect_simulation_space(
        _run_spec(opt).get("simulation_space")
    )
    done = {float(r["offset_deg"]) for r in read_rows(path)}
    offsets = [0.0] + [s * p for p in plan.perturbations_deg for s in (-1.0, 1.0)]
    for offset in offsets:
        if offset in done:
            continue
        objective = _objective(plan, plan.direction_env, base_deg + offset)
        start = time.perf_counter()
        values = _evaluate_seeds(plan, objective, basis, seeds)
        _append_row(path, {"offset_deg": offset, "direction_deg": base_deg + offset,
                           "R_mean": float(np.nanmean(values)),
                           "R_seeds": " ".join(f"{v:.6g}" for v in values),
                           "wall_s": time.perf_counter() - start,
                           "run": str(base_run), "basis_digest": digest})  # fmt: skip
        log(f"[perturbation] {offset:+g} deg: R = {np.nanmean(values):.4g}")
    return path


def studies(out: Path, plan: ReproducePlan, log: Log) -> Path:
    """Cost-vs-C and reward-vs-C on the direction robot, appended row by row (resumable)."""
    from controllers import GaussNewtonSettings
    from controllers.studies import gn_cost_against_c, reward_against_c

    folder = out / "studies"
    env_id = plan.env_id(plan.direction_env)
    cost_path = folder / "cost_vs_c.csv"
    done = {int(r["C"]) for r in read_rows(cost_path)}
    todo = [c for c in plan.cost_cs if c not in done]
    if todo:
        # The cost study times Gauss-Newton whatever the plan's controller: pass on only the
        # overrides that are Gauss-Newton settings (horizon, knots, ...; not MPPI's samples).
        gn_fields = {f.name for f in fields(GaussNewtonSettings)}
        gn_changes = {k: v for k, v in plan.planner_kwargs.items() if k in gn_fields}

        def cost_row(r: dict) -> None:
            _append_row(cost_path, r)
            log(f"[cost vs C] C = {r['C']}: {r['iteration_s']:.3f} s")

        gn_cost_against_c(env_id, todo, threads=plan.workers, planner_changes=gn_changes,
                          on_row=cost_row)  # fmt: skip
    reward_path = folder / "reward_vs_c.csv"

    def reward_row(r: dict) -> None:
        _append_row(reward_path, r)
        log(f"[reward vs C] C = {r['C']} seed {r['seed']}: {r['R_m']:+.4f} m")

    done_pairs = {(int(r["C"]), int(r["seed"])) for r in read_rows(reward_path)}
    for c in plan.reward_cs:
        seeds = [s for s in range(plan.study_seeds) if (c, s) not in done_pairs]
        if seeds:
            reward_against_c(env_id, [c], seeds, planner=plan.controller,
                             seconds=plan.study_seconds, start=plan.settle_time,
                             threads=plan.workers, planner_changes=dict(plan.planner_kwargs),
                             on_row=reward_row)  # fmt: skip
    return folder


def rl_baselines(out: Path, plan: ReproducePlan, progress: bool,
                 log: Log = _log_stderr) -> list[Path]:  # fmt: skip
    """PPO/SAC on the identity and on each benchmark's Table I B_c, MPC beside them."""
    from .. import rl

    folders = []
    for bench in plan.rl_benchmarks:
        bases, identity_only = rl_bases(out, plan, bench)
        if identity_only:
            log(f"[rl] {bench}: {identity_only}")
        best = out / "runs" / plan.table_run(bench)
        if len(bases) > 1:  # Table I's B_c lives in the simulation space its run recorded
            recorded = _run_spec(RBBO.resume(best, read_only=True))
            _objective(plan, bench).expect_simulation_space(recorded.get("simulation_space"))
        folder = out / "rl" / bench
        rl.run_baselines(plan.env_id(bench), bases, folder, algos=tuple(plan.rl_algos),
                         steps=plan.rl_steps, eval_seeds=plan.confirm_seeds,
                         seconds=plan.t_max, settle_time=plan.settle_time, seed=plan.seed,
                         progress=progress, workers=plan.workers,
                         # the MPC rows: the planner Table I's R* was measured with
                         planner_kwargs=plan.planner_kwargs if plan.controller == "mppi"
                         else None)  # fmt: skip
        folders.append(folder)
    return folders


def _perturbation_base(out: Path, plan: ReproducePlan) -> Path:
    """The run whose B_c the perturbation study walks off its direction: the one its rows
    already used, else the direction-0 run of the directions stage, else Table I's run of
    the direction robot (the same task), whichever has finished first."""
    runs = out / "runs"
    used = {Path(r["run"]).name for r in read_rows(out / "perturbation.csv")}
    candidates = [runs / name for name in sorted(used)]
    candidates += [runs / f"{plan.direction_env}-dir000", runs / plan.table_run(plan.direction_env)]
    for run in candidates:
        if (run / "best_basis.npy").exists():
            return run
    raise RunDirectoryError(
        f"the perturbation study needs a finished {plan.direction_env} run "
        "(stage 'directions' or 'table')"
    )


def _load_plan(out: Path, plan: ReproducePlan) -> dict[str, Any]:
    path = out / "reproduce.json"
    if not path.exists():
        return {"plan": plan.to_dict(), "sessions": []}
    try:
        document = json.loads(path.read_text())
        stored = ReproducePlan.from_dict(document["plan"])
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
    from .document import write_report

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
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

    threading.Thread(target=beat, name="reproduce-heartbeat", daemon=True).start()
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
