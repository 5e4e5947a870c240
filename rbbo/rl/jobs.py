"""The baselines as jobs: one per algorithm and basis, one per MPC basis, and their workers.

:func:`run_baselines` checks the arguments and claims the jobs' folders before any work, runs
the jobs (:func:`_run_jobs`: in this process, or in spawned worker processes, each job with
one torch thread) and writes ``OUT/baselines.csv`` and ``OUT/baselines.md``.
"""

from __future__ import annotations

import csv
import functools
import io
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .._warn import say_warnings_as
from ..store import _atomic_write, _make_dirs
from .algorithms import ALGOS, DEFAULT_STEPS, require_sb3, steps_per_algo
from .evaluation import EVAL_SEED0
from .mpc import _mpc
from .progress import _claim
from .table import _COLUMNS, format_table
from .training import _train


def run_baselines(
    env_id: str,
    bases: dict[str, np.ndarray],
    out: str | Path,
    *,
    algos: tuple[str, ...] = ALGOS,
    steps: int | dict[str, int] = DEFAULT_STEPS,
    checkpoint_every: int | None = None,
    eval_seeds: int = 5,
    seconds: float = 10.0,
    settle_time: float = 2.0,
    seed: int = 0,
    mpc: bool = True,
    env_kwargs: dict | None = None,
    progress: bool = True,
    workers: int = 1,
    planner_kwargs: dict | None = None,
) -> list[dict]:
    """Train (or resume) each algorithm on each basis, run the MPC beside them, write
    ``OUT/baselines.csv`` and ``OUT/baselines.md``.

    Parameters
    ----------
    env_id : str
        A registered id (``softrom_gym/CrossSwim-v0``).
    bases : dict of str to (M, C) arrays
        Control bases by name (see :func:`resolve_bases`).
    out : path
        Output directory; re-running with the same one continues from its checkpoints.
    algos : tuple of str
        Among ``"ppo"``, ``"sac"``.
    steps : int or dict of str to int
        Env steps to train each (PPO rounds up to whole rollouts), or per algorithm
        (``{"ppo": 500_000, "sac": 100_000}``).
    checkpoint_every : int or None
        Env steps between checkpoints (default: a fifth of each algorithm's ``steps``).
    eval_seeds, seconds, settle_time : int, float, float
        Evaluation episodes (seeds 1000, 1001, ...), their length and the settle time, s.
    seed : int
        Training seed.
    mpc : bool
        Also run ``controllers.default_planner(env_id, "mppi")`` on each basis.
    env_kwargs : dict, optional
        Extra ``gym.make`` arguments (an RBBO run's).
    progress : bool
        tqdm bars on stderr (with ``workers`` > 1 a line per finished job instead, always).
    planner_kwargs : dict, optional
        MPPI setting overrides for the MPC rows (an RBBO run's ``--mpc``, so that the MPC
        beside the RL rows is the planner the run's R* was measured with).
    workers : int
        Jobs (one per algorithm and basis, one per MPC basis) run at once, each in its own
        process with one thread; the rows, files and results are those of ``workers = 1``
        (each job is seeded and writes only its own folder), and each job's wall time is
        its own (on a machine with at least ``workers`` free cores it is comparable).

    Returns
    -------
    list of dict
        One row per RL checkpoint and one per MPC basis (keys: ``_COLUMNS``).
    """
    unknown = [a for a in algos if a not in ALGOS]
    if unknown:
        raise ValueError(f"unknown algorithm {unknown[0]!r}; valid: {', '.join(ALGOS)}")
    if not 0 <= settle_time < seconds:
        raise ValueError(f"settle time {settle_time} s must lie in [0, {seconds}) s")
    every = 1 if checkpoint_every is None else checkpoint_every  # (None: a fifth of steps)
    for what, value in (("workers", workers), ("eval_seeds", eval_seeds),
                        ("checkpoint_every", every)):  # fmt: skip
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{what} must be a positive integer, got {value!r}")
    if algos:
        require_sb3()
    per_algo = steps_per_algo(steps, tuple(algos))
    out, env_kwargs = Path(out), dict(env_kwargs or {})
    evaluation = (tuple(range(EVAL_SEED0, EVAL_SEED0 + eval_seeds)), float(seconds),
                  float(settle_time))  # fmt: skip
    for name, basis in bases.items():  # all refusals before any work
        for algo in algos:
            _claim(out / f"{algo}-{name}", {"env_id": env_id, "env_kwargs": env_kwargs,
                   "algo": algo, "seed": seed, "basis": np.asarray(basis).tolist()})  # fmt: skip
    jobs: list[tuple[str, tuple]] = []
    for name, basis in bases.items():
        if mpc:
            mpc_job = functools.partial(_mpc, planner_kwargs=dict(planner_kwargs or {}))
            jobs.append((f"mppi {name}", (mpc_job, env_id, name, basis, out / f"mppi-{name}",
                                          env_kwargs, evaluation)))  # fmt: skip
        for algo in algos:
            n = per_algo[algo]
            jobs.append((f"{algo} {name}", (_train, algo, env_id, name, basis,
                                            out / f"{algo}-{name}", env_kwargs, n,
                                            checkpoint_every or max(1, n // 5), evaluation,
                                            seed)))  # fmt: skip
    rows: list[dict] = []
    for result in _run_jobs(jobs, workers, progress):
        rows += result if isinstance(result, list) else [result]
    # both tables formatted before either is replaced, each replaced atomically: baselines.csv
    # says which jobs finished (`rbbo reproduce --status`), so a kill or an error while
    # writing must leave the last whole table, never a torn one
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=_COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
    markdown = format_table(rows, markdown=True) + "\n"
    _make_dirs(out)  # (a call with no RL job claims no folder in it)
    _atomic_write(out / "baselines.csv", table.getvalue().encode("utf-8"))
    _atomic_write(out / "baselines.md", markdown.encode("utf-8"))
    return rows


def _torch_threads(n: int) -> int:
    """Set torch's intra-op threads, returning the old count. These MLPs are too small to
    gain from threads, and on shared cores the threads' spin-waits made SAC 4x slower."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    return old


def _job(call: tuple, progress: bool, threads: int | None, label: str | None = None):
    """Run one job (``_mpc`` or ``_train`` and its arguments) with one torch thread; ``label``
    (in a worker process of :func:`_run_jobs`) names the job in its warnings' lines."""
    if label is not None:
        say_warnings_as(f"rbbo baselines ({label})")
    fn, *args = call
    old = _torch_threads(1)
    try:
        is_mpc = getattr(fn, "func", fn) is _mpc
        extra = {"threads": threads} if is_mpc and threads is not None else {}
        return fn(*args, progress, **extra)
    finally:
        _torch_threads(old)


def _run_jobs(jobs: list[tuple[str, tuple]], workers: int, progress: bool) -> list:
    """The jobs' results in job order: in this process, or ``workers`` at a time in spawned
    processes (a failed job does not stop the others; the first failure is raised after
    all have ended, and the finished jobs' folders keep their work)."""
    if workers == 1 or len(jobs) <= 1:
        return [_job(call, progress, None) for _, call in jobs]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    results: dict[int, Any] = {}
    errors: list[tuple[str, BaseException]] = []
    ctx = mp.get_context("spawn")
    before = set(mp.active_children())
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx)
    try:
        futures = {pool.submit(_job, call, False, 1, label): (i, label)
                   for i, (label, call) in enumerate(jobs)}  # fmt: skip
        for future in as_completed(futures):
            i, label = futures[future]
            try:
                results[i] = future.result()
            except Exception as exc:  # reported below, after the other jobs have finished
                errors.append((label, exc))
                print(f"[baselines] {label} failed: {exc}", file=sys.stderr, flush=True)
                continue
            print(f"[baselines] {label} done ({len(results)}/{len(jobs)})", file=sys.stderr,
                  flush=True)  # fmt: skip
    except BaseException:
        # An interrupt (Ctrl-C, SIGTERM): the jobs resume from their checkpoints, so stop the
        # workers now instead of waiting out training runs of an hour.
        pool.shutdown(wait=False, cancel_futures=True)
        for child in set(mp.active_children()) - before:
            child.terminate()
        raise
    pool.shutdown()
    if errors:
        label, error = errors[0]
        raise RuntimeError(f"baseline job {label!r} failed: {error}") from error
    return [results[i] for i in range(len(jobs))]
