"""The stages of a reproduction that measure rather than optimise (transfer: :mod:`.transfer`).

:func:`perturbation` walks the direction-0 B_c at offsets from its direction (on the run
:func:`_perturbation_base` picks, each offset's seeds spread over the workers by
:func:`_evaluate_seeds`), :func:`studies` measures cost and reward against C, and
:func:`rl_baselines` trains PPO/SAC beside MPC. Each resumes where a session stopped: the
first two append their CSV rows one by one, the RL jobs continue from their checkpoints.
"""

from __future__ import annotations

import math
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from ..executors import EvaluationTask, make_executor
from ..objective import EnvObjective
from ..optimizer import RBBO
from ..store import RunDirectoryError
from .csv_rows import _append_row, _supersede
from .optimisation_runs import _objective, _run_spec
from .plan import ReproducePlan
from .session_log import Log, _log_stderr
from .status import rl_bases
from .tables import basis_digest, read_rows


def _evaluate_seeds(plan: ReproducePlan, objective: EnvObjective, basis: np.ndarray,
                    seeds: tuple[int, ...], log: Log | None = None) -> list[float]:  # fmt: skip
    """R of ``basis`` at T_max on each seed, the seeds spread over the workers (nan for a
    seed whose evaluation failed, its error logged)."""
    with make_executor(plan.executor, objective, plan.workers, plan.timeout_s) as executor:
        futures = [executor.submit(EvaluationTask(i, basis, plan.t_max, (s,)))
                   for i, s in enumerate(seeds)]  # fmt: skip
        outcomes = [f.result() for f in futures]
    for seed, o in zip(seeds, outcomes, strict=True):
        if o.status != "ok" and log is not None:
            log(f"  seed {seed} failed: {o.error}")
    return [o.R if o.status == "ok" and o.R is not None else math.nan for o in outcomes]


def _has_failed_seed(row: dict[str, str]) -> bool:
    """A row one of whose seeds failed (written as nan by a version that recorded them)."""
    return any(math.isnan(float(v)) for v in row.get("R_seeds", "").split())


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
    # A row with a failed seed (a timeout, a crashed worker) was recorded as done, and its
    # mean taken over the seeds that survived: measured again instead.
    failed = _supersede(path, _has_failed_seed)
    if failed:
        log(f"[perturbation] {failed} offsets with a failed seed moved to "
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
        values = _evaluate_seeds(plan, objective, basis, seeds, log)
        if any(math.isnan(v) for v in values):
            log(f"[perturbation] {offset:+g} deg: {sum(map(math.isnan, values))} of "
                f"{len(values)} seeds failed (their errors above); not recorded, "
                "measured again by the next session")  # fmt: skip
            continue
        _append_row(path, {"offset_deg": offset, "direction_deg": base_deg + offset,
                           "R_mean": float(np.mean(values)),
                           "R_seeds": " ".join(f"{v:.6g}" for v in values),
                           "wall_s": time.perf_counter() - start,
                           "run": str(base_run), "basis_digest": digest})  # fmt: skip
        log(f"[perturbation] {offset:+g} deg: R = {np.mean(values):.4g}")
    return path


def studies(out: Path, plan: ReproducePlan, log: Log) -> Path:
    """Cost-vs-C and reward-vs-C on the direction robot, appended row by row (resumable)."""
    from controllers import GaussNewtonSettings
    from controllers.studies import gn_cost_against_c, reward_against_c

    folder = out / "studies"
    env_id = plan.env_id(plan.direction_env)
    cost_path = folder / "cost_vs_c.csv"
    # The cost study times Gauss-Newton whatever the plan's controller: pass on only the
    # overrides that are Gauss-Newton settings (horizon, knots, ...; not MPPI's samples).
    gn_fields = {f.name for f in fields(GaussNewtonSettings)}
    gn_changes = {k: v for k, v in plan.planner_kwargs.items() if k in gn_fields}
    # One curve is timed on one thread count: a session on other workers (a setting that may
    # change between sessions) moves the rows timed on another count aside, and times them
    # again, where they were mixed into one curve.
    threads = gn_changes.get("threads", plan.workers)
    moved = _supersede(cost_path, lambda r: str(r.get("threads", "")) not in ("", str(threads)))
    if moved:
        log(f"[cost vs C] {moved} rows timed on another thread count moved to "
            f"cost_vs_c-superseded.csv; timing them again on {threads}")  # fmt: skip
    done = {int(r["C"]) for r in read_rows(cost_path)}
    todo = [c for c in plan.cost_cs if c not in done]
    if todo:

        def cost_row(r: dict) -> None:
            _append_row(cost_path, r)
            log(f"[cost vs C] C = {r['C']}: {r['iteration_s']:.3f} s")

        gn_cost_against_c(env_id, todo, threads=plan.workers, planner_changes=gn_changes,
                          on_row=cost_row, env_kwargs={"sim_dim": plan.sim_dim})  # fmt: skip
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
                             on_row=reward_row,
                             env_kwargs={"sim_dim": plan.sim_dim})  # fmt: skip
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
        if len(bases) > 1:  # Table I's B_c lives in the simulation space its run recorded
            table_run = out / "runs" / plan.table_run(bench)
            recorded = _run_spec(RBBO.resume(table_run, read_only=True))
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
