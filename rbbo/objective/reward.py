"""R from an MPC episode: the task reward per second from the settle time on.

:func:`settled_step` is the first env step R counts, :func:`measured_steps` how many it counts;
:func:`settled_reward_rate` the reward
per second from there to the episode's end, an early end counting as zero reward.
"""

from __future__ import annotations

import math

import numpy as np


def settled_step(step_seconds: float, settle_time: float) -> int:
    """The first env step that R counts: the first starting at or after the settle time."""
    return int(np.ceil(settle_time / step_seconds - 1e-9))


def measured_steps(step_seconds: float, settle_time: float, seconds: float) -> int:
    """The env steps R counts in an episode of ``seconds``: its ``round(seconds / dt)`` whole
    steps (``controllers.run_episode``) from :func:`settled_step` on; 0 or less when R would
    measure nothing (T = 1.01 s past a 1-s settle time at dt = 0.025 s is 40 steps, the
    settle time's 40)."""
    return max(1, round(seconds / step_seconds)) - settled_step(step_seconds, settle_time)


def settled_reward_rate(result, step_seconds: float, settle_time: float, seconds: float) -> float:
    """Task reward per second from ``settle_time`` to ``seconds``, from an EpisodeResult.

    Uses ``result.task_rewards`` when the controllers report the task term R separately,
    else ``result.rewards`` (per env step). Step k covers [k dt, (k + 1) dt); steps starting
    at or after t_settle count. An episode that ended early (diverged) counts the time it
    did not survive as zero reward, so a basis that makes the simulation blow up ranks low.

    The episode runs ``round(seconds / dt)`` whole steps (``controllers.run_episode``), so a
    ``seconds`` off that grid (BOCA's T = 2.667 s at dt = 0.025 s: 107 steps, 2.675 s) is
    divided by the time simulated, not the time asked for (which read R 0.5 % high there
    with a 1 s settle time, 1.25 % with the default 2 s).
    """
    rewards = getattr(result, "task_rewards", None)
    if rewards is None:
        rewards = result.rewards
    r = np.asarray(rewards, dtype=float).ravel()
    start = settled_step(step_seconds, settle_time)
    seconds = float(seconds)
    simulated = max(1, round(seconds / step_seconds)) * step_seconds
    if not math.isclose(simulated, seconds, rel_tol=1e-9):
        # (on the grid, seconds itself, as before: the same R to the bit as recorded runs')
        seconds = simulated
    span = seconds - start * step_seconds
    if span <= 0:
        raise ValueError(
            f"an episode of {seconds} s is not longer than the settle time {settle_time} s"
        )
    kept = r[start:]
    return float(kept[np.isfinite(kept)].sum() / span)
