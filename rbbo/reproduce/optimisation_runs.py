"""The optimisation runs of a reproduction: Table I's BOCA runs, the BO runs, the directions.

:func:`optimise` creates or resumes one ordinary RBBO run directory and runs it to its budget
and confirmation, refusing a run made with other settings or another objective;
:func:`_objective` and :func:`_config` build what a plan's run optimises and how,
:func:`_run_spec` reads a run's recorded objective and :func:`_r` prints an R for the log.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..config import RBBOConfig
from ..executors import make_executor
from ..objective import EnvObjective
from ..optimizer import RBBO
from ..provenance import source_version
from ..store import RunDirectoryError
from .plan import ReproducePlan
from .session_log import Log


def _run_spec(opt: RBBO) -> dict[str, Any]:
    """The objective a resumed run's config.json records (every run made here has one)."""
    store, spec = opt.store, opt.objective_spec
    assert store is not None  # (RBBO.resume opens the run's store)
    if spec is None:
        raise RunDirectoryError(f"{store.path}/config.json does not say what the objective is")
    return spec


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


def _expect_same_run(opt: RBBO, path: Path, config: RBBOConfig, objective: EnvObjective) -> None:
    """Refuse a stored run made for another plan or objective, naming what differs."""
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


def optimise(path: Path, plan: ReproducePlan, objective: EnvObjective, fidelity: str,
             budget_s: float, progress: bool, log: Log,
             heartbeat: Callable[[], None] | None = None, repeat: int = 0) -> Path:  # fmt: skip
    """Create or resume the RBBO run at ``path`` and run it to its budget and confirmation
    (``heartbeat()`` after each recorded evaluation); ``repeat`` k seeds it ``plan.seed + k``."""
    config = _config(plan, fidelity, budget_s, repeat)
    if (path / "config.json").exists():
        opt = RBBO.resume(path)
        try:  # (a refused run is closed at once: its lock, as after a run, see below)
            _expect_same_run(opt, path, config, objective)
        except BaseException:
            opt.close()
            raise
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

    try:
        executor = make_executor(plan.executor, objective, plan.workers, plan.timeout_s)
    except BaseException:
        opt.close()
        raise
    finished = False
    try:
        result = opt.run(executor=executor, max_evaluations=plan.iterations, budget_s=budget_s,
                         callback=callback, deterministic=plan.deterministic)  # fmt: skip
        finished = True
    finally:
        # On an interrupt the workers are killed, not waited for: they ignore the group's
        # SIGINT, and an evaluation in flight can take minutes.
        executor.shutdown(wait=finished)
        # (the run's lock, now rather than at garbage collection: a reproduction opens its
        # runs one after another in one process, and `rbbo resume DIR` may follow at once)
        opt.close()
        if bar is not None:
            bar.close()
    log(f"[{path.name}] done: {result.evaluations} evaluations, R_init {_r(result.R_init)}, "
        f"R* {_r(result.R_star)} ({result.wall_s / 60:.1f} min)")  # fmt: skip
    return path


def _r(value: float | None) -> str:
    """R as the log prints it: four significant digits, as the status and the other stages
    log it (the record keeps every digit), "-" when not measured (a failed confirmation)."""
    return "-" if value is None else f"{value:.4g}"
