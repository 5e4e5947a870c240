"""The paper's two studies of the control-space dimension C, as functions returning rows.

- :func:`gn_cost_against_c` (the paper's cost figure): wall time of one Gauss-Newton
  iteration against C for identity bases B_c = the first C modes of B_r.
- :func:`reward_against_c` (the paper's reward-vs-C figure): the task reward R (distance
  along d from a start time, m, without Λ) of a closed-loop MPC episode against C.

The scripts ``benchmarks/study_cost_vs_c.py`` and ``benchmarks/study_reward_vs_c.py`` print
and plot these rows; ``rbbo reproduce`` regenerates both into its report.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from .defaults import default_planner
from .episode import run_episode

__all__ = ["gn_cost_against_c", "reward_against_c"]


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _check_cs(cs: Iterable[int]) -> list[int]:
    given = list(cs)  # (once: a generator is empty after it is read)
    if not given or not all(_is_int(c) and c >= 1 for c in given):
        raise ValueError(f"control dimensions must be integers >= 1, got {given!r}")
    return [int(c) for c in given]


def gn_cost_against_c(
    env_id: str = "softrom_gym/CrossWalk-v0",
    cs: Iterable[int] = range(1, 21),
    *,
    repeats: int = 1,
    threads: int | None = 2,
    planner_changes: dict[str, Any] | None = None,
    on_row: Callable[[dict], None] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> list[dict]:
    """Wall time of one Gauss-Newton iteration from the reset state, per C.

    One iteration is the K C + 1 finite-difference rollouts plus the batched line search, so
    its rollouts grow linearly in C and the normal equations cubically. ``planner_changes``
    override the benchmark's default settings (e.g. a shorter horizon); the gait seed is off
    so only the iteration is timed. Best of ``repeats``. ``env_kwargs`` go to ``gym.make``
    beside ``control_dim`` (e.g. ``sim_dim``). Returns one dict per C (keys C, K, H,
    rollouts, iteration_s, threads).
    """
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    if not _is_int(repeats) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    # (planner_changes win over the threads argument; each row reports the threads used)
    changes = {"threads": threads, "iterations": 1, "gait_seed": False,
               **(planner_changes or {})}  # fmt: skip
    rows = []
    for c in _check_cs(cs):
        env = gym.make(env_id, **{**(env_kwargs or {}), "control_dim": c})
        try:
            env.reset(seed=0)
            planner, _ = default_planner(env_id, "gn", **changes)
            walls = []
            for _ in range(repeats):
                planner.reset(env, seed=0)
                start = time.perf_counter()
                planner.plan(env)
                walls.append(time.perf_counter() - start)
        finally:
            env.close()
        row = {"C": c, "K": planner.settings.knots, "H": planner.settings.horizon,
               "rollouts": int(planner.last_["rollouts"]), "iteration_s": min(walls),
               "threads": planner.settings.threads}  # fmt: skip
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return rows


def reward_against_c(
    env_id: str = "softrom_gym/CrossWalk-v0",
    cs: Iterable[int] = range(1, 11),
    seeds: Iterable[int] = (0, 1, 2),
    *,
    planner: str = "mppi",
    seconds: float = 10.0,
    start: float = 2.0,
    threads: int | None = 2,
    planner_changes: dict[str, Any] | None = None,
    on_row: Callable[[dict], None] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> list[dict]:
    """Task reward R of one closed-loop episode per (C, seed), identity bases.

    R is the distance along d between t = ``start`` and the end (m), without Λ (a lean in the
    first seconds earns nothing). The env's registered time limit is raised to ``seconds``
    where it is shorter, so every episode runs the time asked for. An episode that diverges
    before ``start`` gets R = 0 (its row's ``stop`` says "diverged", ``seconds`` when). The
    ``threads`` argument is the planner's unless ``planner_changes`` sets its own;
    ``env_kwargs`` go to ``gym.make`` beside ``control_dim`` (e.g. ``sim_dim``). Returns
    one dict per episode (keys C, seed, R_m, R_bl, R_total_m, planner, seconds, start, stop,
    threads).
    """
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)
    from softrom_gym.registration import control_period

    # (isinstance first: np.isfinite of a str or None is numpy's TypeError, naming nothing)
    number = (int, float, np.integer, np.floating)
    if isinstance(seconds, bool) or not isinstance(seconds, number) or not 0 < seconds < np.inf:
        raise ValueError(f"seconds must be a positive number, got {seconds!r}")
    if isinstance(start, bool) or not isinstance(start, number) or not 0 <= start < seconds:
        raise ValueError(f"start must lie in [0, seconds = {seconds}) s, got {start!r}")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("give at least one seed")
    changes = {"threads": threads, **(planner_changes or {})}
    rows = []
    for c in _check_cs(cs):
        # the registered time limit (env steps) must not cut the seconds asked for short: a
        # 10.5-s episode was truncated at 10 s, and a start past 10 s then failed after it ran
        make_kwargs: dict[str, Any] = {**(env_kwargs or {}), "control_dim": c}
        period = control_period(env_id, **make_kwargs)
        limit = gym.spec(env_id).max_episode_steps
        if period is not None and limit is not None:
            make_kwargs["max_episode_steps"] = max(limit, math.ceil(seconds / period - 1e-9))
        for seed in seeds:
            env = gym.make(env_id, **make_kwargs)
            try:
                mpc, every = default_planner(env_id, planner, **changes)
                res = run_episode(env, mpc, seconds, replan_every=every, seed=seed,
                                  progress=False)  # fmt: skip
            finally:
                env.close()
            # (an episode that diverged before start travelled nothing after it)
            r = res.distance_between(min(start, res.seconds))
            row = {"C": c, "seed": seed, "R_m": r, "R_bl": r / res.body_length,
                   "R_total_m": res.R, "planner": planner, "seconds": res.seconds,
                   "start": start, "stop": res.stop_reason,
                   "threads": mpc.settings.threads}  # fmt: skip
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows
