"""Where a reproduction stands (``rbbo reproduce --out DIR --status``): what each planned part
has done, read from the run directories without running anything, and the optimisation
budget still to spend. A reproduction of the default plan spans several sessions; this is how
the next one knows what is left."""

from __future__ import annotations

import shlex
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .plan import _STAGES, ReproducePlan
from .tables import basis_digest, read_rows
from .transfer import current_rows

__all__ = ["recorded_repeats", "recorded_stages", "rl_bases", "stage_progress", "status_lines"]


def _session_stages(session: dict[str, Any]) -> list[str]:
    """The stages one session of reproduce.json ran: as recorded with it, else (a session
    recorded before they were) read from its ``rbbo reproduce`` command, every stage
    without ``--stages``."""
    if "stages" in session:
        return list(session["stages"])
    try:
        words = shlex.split(str(session.get("command") or ""))  # (None would read stdin)
    except ValueError:
        return []
    if words[:2] != ["rbbo", "reproduce"]:  # a library call's sys.argv: not its plan
        return []
    stages = list(_STAGES)
    for word, value in zip(words, [*words[1:], ""], strict=True):
        flag, eq, given = word.partition("=")
        # Commands recorded before rbbo took options only as spelled were parsed with
        # argparse's prefixes: "--stag" is the shortest that named --stages alone.
        if len(flag) >= len("--stag") and "--stages".startswith(flag):
            stages = (given if eq else value).split(",")
    return [s.strip() for s in stages]


def recorded_stages(document: dict[str, Any]) -> list[str]:
    """The stages of a reproduction (reproduce.json's ``document``): its stored plan's and
    those of its earlier sessions, each of which may have run other stages."""
    named = set(document["plan"].get("stages", []))
    for session in document.get("sessions", []):
        named.update(_session_stages(session))
    return [s for s in _STAGES if s in named]


def recorded_repeats(document: dict[str, Any]) -> int:
    """The Table I runs per benchmark of a reproduction (reproduce.json's ``document``): the
    most that any session running stage "table" asked for (a later session may ask for fewer,
    or run other stages, and the runs made stay part of the record), else the stored plan's."""
    asked = [int(s.get("repeats", 1)) for s in document.get("sessions", [])
             if "table" in _session_stages(s)]  # fmt: skip
    return max(asked, default=int(document["plan"].get("repeats", 1)))


def _run_state(path: Path, budget_s: float, iterations: int | None) -> tuple[str, float, bool]:
    """One optimisation run's state, the budget it has left (seconds) and whether it is
    finished (searched its budget and confirmed)."""
    if not (path / "config.json").exists():
        return "not started", budget_s, False
    from ..report import load

    result = load(path).result()
    capped = iterations is not None and result.evaluations >= iterations
    left = 0.0 if capped else max(0.0, budget_s - result.wall_s)
    confirmed = bool(result.R_init_seeds and result.R_star_seeds)
    if confirmed and left == 0.0:
        return (f"done: {result.evaluations} evaluations in {result.wall_s / 60:.1f} min, "
                f"R_init {result.R_init:.4g}, R* {result.R_star:.4g}"), 0.0, True  # fmt: skip
    if confirmed:  # a larger budget than it ran to: it will search on and confirm again
        text = (f"confirmed after {result.evaluations} evaluations in "
                f"{result.wall_s / 60:.1f} min; {left / 60:.1f} min more to search")  # fmt: skip
        return text, left, False
    if left == 0.0:
        return f"confirming ({result.evaluations} evaluations)", 0.0, False
    return (f"searching: {result.evaluations} evaluations, {result.wall_s / 60:.1f} of "
            f"{budget_s / 60:g} min"), left, False  # fmt: skip


def _run_done(path: Path, budget_s: float, iterations: int | None) -> bool:
    return _run_state(path, budget_s, iterations)[2]


def _rl_benchmarks(out: Path, plan: ReproducePlan) -> list[str]:
    """The benchmarks with RL baselines: the plan's, then any other the record holds (an
    earlier session may have trained on benchmarks this one does not name)."""
    folder = out / "rl"
    held = sorted(p.name for p in folder.iterdir() if p.is_dir()) if folder.exists() else []
    return list(plan.rl_benchmarks) + [b for b in held if b not in plan.rl_benchmarks]


def rl_bases(out: Path, plan: ReproducePlan, bench: str) -> tuple[dict[str, np.ndarray], str]:
    """The bases the RL stage trains on for ``bench`` and, when that is the identity alone,
    why ("" otherwise).

    They are the identity and Table I's B_c, named by its bytes (``rbbo-<digest>``: a longer
    Table I run may recommend another B_c, which then trains afresh instead of resuming the
    older one's jobs). A B_c that is the identity itself (the search found nothing better)
    is trained once, as ``identity``.
    """
    identity = np.eye(plan.sim_dim)[:, : plan.control_dim]
    bases = {"identity": identity}
    run = Path(out) / "runs" / plan.table_run(bench)
    best = run / "best_basis.npy"
    if not best.exists():
        return bases, (f"Table I's run {run} has no best B_c yet, so only the identity is "
                       "trained; run stage rl again once stage table has run")  # fmt: skip
    basis = np.load(best)
    if basis.shape == identity.shape and np.array_equal(basis, identity):
        return bases, "Table I's B_c is the identity basis, so it is trained once, as identity"
    bases[f"rbbo-{basis_digest(basis)}"] = basis
    return bases, ""


def _rl_jobs_done(out: Path, plan: ReproducePlan, bench: str) -> bool:
    """Whether one benchmark's RL stage has finished for the bases it must cover
    (:func:`rl_bases`): its table (baselines.csv, written when every job of a call has
    finished) has each planned algorithm's final row on each of them, trained for the steps
    planned now (a later session may ask for more steps or another algorithm, which a
    check of the bases alone called done); for a plan without stage rl, rows of each."""
    from ..rl import steps_per_algo

    rows = read_rows(out / "rl" / bench / "baselines.csv")
    bases = rl_bases(out, plan, bench)[0]
    if "rl" not in plan.stages:
        # A session of other stages carries the RL defaults, not what was trained: the
        # stage is done when its table has rows for each basis.
        return bool(rows) and set(bases) <= {r["basis"] for r in rows}
    planned = steps_per_algo(plan.rl_steps, tuple(plan.rl_algos))
    trained = {(r["method"], r["basis"]): int(float(r["env_steps"] or 0)) for r in rows
               if str(r.get("final", "")).lower() == "true"}  # fmt: skip
    return all(trained.get((algo, basis), -1) >= steps
               for basis in bases for algo, steps in planned.items())  # fmt: skip


def _current_offsets(out: Path, plan: ReproducePlan) -> list[dict[str, str]]:
    """perturbation.csv's rows of the B_c the stage walks now, which the status counts and
    the report shows: rows of a B_c its run no longer recommends (it searched on since) are
    measured again, so they are not done."""
    from ..store import RunDirectoryError
    from .runner import _perturbation_base

    rows = read_rows(out / "perturbation.csv")
    try:
        base = _perturbation_base(out, plan)
    except RunDirectoryError:
        return rows
    try:  # (np.load's own errors would end --status and --report-only in a traceback)
        best = np.load(base / "best_basis.npy", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise RunDirectoryError(f"{base / 'best_basis.npy'} is corrupted: {exc}") from exc
    digest = basis_digest(best)
    return [r for r in rows if Path(r["run"]).name == base.name
            and r.get("basis_digest", "") in ("", digest)]  # fmt: skip


def stage_progress(out: Path, plan: ReproducePlan) -> dict[str, tuple[int, int]]:
    """``{stage: (parts done, parts planned)}`` for every stage, whichever of them the last
    command named: a reproduction spans sessions that each run some stages, and its report
    says what the whole record holds. A part is one benchmark's run (table, bo, transfer,
    rl; table: each of its ``repeats`` runs), one direction, one perturbation offset or one
    study point."""
    runs = out / "runs"
    n_bench = len(plan.benchmarks)
    table = sum(_run_done(runs / plan.table_run(b, k), plan.budget_s, plan.iterations)
                for b in plan.benchmarks for k in range(plan.repeats))  # fmt: skip
    bo = sum(_run_done(runs / f"{b}-bo", plan.budget_s, plan.iterations) for b in plan.benchmarks)
    m = plan.transfer_sim_dim
    rows = current_rows(out, m)
    transfer = sum(sum(r["benchmark"] == b for r in rows) >= 2 for b in plan.benchmarks)
    angles = plan.direction_angles_deg()
    directions = sum(_run_done(runs / f"{plan.direction_env}-dir{deg:03.0f}",
                               plan.direction_budget_s, plan.iterations)
                     for deg in angles)  # fmt: skip
    n_offsets = 1 + 2 * len(plan.perturbations_deg)
    offsets = min(len(_current_offsets(out, plan)), n_offsets)
    n_study = len(plan.cost_cs) + len(plan.reward_cs) * plan.study_seeds
    study = min(len(read_rows(out / "studies" / "cost_vs_c.csv"))
                + len(read_rows(out / "studies" / "reward_vs_c.csv")), n_study)  # fmt: skip
    rl_benchmarks = _rl_benchmarks(out, plan)
    rl = sum(_rl_jobs_done(out, plan, b) for b in rl_benchmarks)
    return {"table": (table, n_bench * plan.repeats), "bo": (bo, n_bench),
            "transfer": (transfer, n_bench), "directions": (directions, len(angles)),
            "perturbation": (offsets, n_offsets), "studies": (study, n_study),
            "rl": (rl, len(rl_benchmarks))}  # fmt: skip


def _rl_state(folder: Path, plan: ReproducePlan) -> str:
    from ..rl import _read_progress, steps_per_algo
    from ..rl.mpc import _mpc_row_recorded

    if not folder.exists():
        return "not started"
    target = steps_per_algo(plan.rl_steps, tuple(plan.rl_algos))
    parts = []
    for run in sorted(p for p in folder.iterdir() if p.is_dir()):
        algo = run.name.split("-")[0]
        if algo == "mppi":
            parts.append(f"{run.name} {'done' if _mpc_row_recorded(run) else '-'}")
            continue
        steps = max(
            (x["steps"] for x in _read_progress(run / "progress.jsonl", mend=False)), default=0
        )
        parts.append(f"{run.name} {steps}/{target.get(algo, '?')} steps")
    return ", ".join(parts) or "not started"


def status_lines(out: Path, plan: ReproducePlan) -> list[str]:
    """One line per planned part of ``plan`` in ``out``, then the budget left."""
    runs = out / "runs"
    stages = set(plan.stages)
    lines, left = [], 0.0
    for bench in plan.benchmarks:
        for stage in ("table", "bo"):
            if stage not in stages:
                continue
            repeats = plan.repeats if stage == "table" else 1
            for k in range(repeats):
                name = plan.table_run(bench, k) if stage == "table" else f"{bench}-bo"
                state, rest, _ = _run_state(runs / name, plan.budget_s, plan.iterations)
                run = f"run {k} (seed {plan.seed + k}): " if repeats > 1 else ""
                lines.append(f"{stage:<12} {bench:<20} {run}{state}")
                left += rest
        if "transfer" in stages:
            m = plan.transfer_sim_dim
            done = [r for r in current_rows(out, m) if r["benchmark"] == bench]
            lines.append(f"{'transfer':<12} {bench:<20} {len(done)} of 2 bases measured at "
                         f"M = {plan.transfer_sim_dim}")  # fmt: skip
    if "directions" in stages:
        for deg in plan.direction_angles_deg():
            name = f"{plan.direction_env}-dir{deg:03.0f}"
            state, rest, _ = _run_state(runs / name, plan.direction_budget_s, plan.iterations)
            lines.append(f"{'directions':<12} {name:<20} {state}")
            left += rest
    if "perturbation" in stages:
        n = 1 + 2 * len(plan.perturbations_deg)
        lines.append(f"{'perturbation':<12} {plan.direction_env:<20} "
                     f"{len(_current_offsets(out, plan))} of {n} offsets")  # fmt: skip
    if "studies" in stages:
        cost = len(read_rows(out / "studies" / "cost_vs_c.csv"))
        reward = len(read_rows(out / "studies" / "reward_vs_c.csv"))
        lines.append(f"{'studies':<12} {plan.direction_env:<20} cost vs C {cost} of "
                     f"{len(plan.cost_cs)}, reward vs C {reward} of "
                     f"{len(plan.reward_cs) * plan.study_seeds}")  # fmt: skip
    if "rl" in stages:
        for bench in _rl_benchmarks(out, plan):
            lines.append(f"{'rl':<12} {bench:<20} {_rl_state(out / 'rl' / bench, plan)}")
    # only the work still to do: a stage whose parts are all done costs nothing more
    progress = stage_progress(out, plan)
    pending = [s for s in plan.ordered_stages() if progress[s][0] < progress[s][1]]
    besides = replace(plan, stages=pending).besides_budgets() if pending else ""
    lines.append(f"optimisation budget left: {left / 3600:.2f} h on {plan.on_workers()}"
                 + (f", plus {besides}" if besides else ""))  # fmt: skip
    return lines
