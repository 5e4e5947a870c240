"""Evaluation of a policy: its distance per seed, and their mean with a 95 % t-interval.

:func:`evaluate_policy` runs the deterministic policy for one episode per evaluation seed
(``EVAL_SEED0``, ``EVAL_SEED0 + 1``, ...) and measures the distance from the settle time to
the end; :func:`t_interval` summarises the seeds.
"""

from __future__ import annotations

import math

from ..intervals import confidence_interval

EVAL_SEED0 = 1000  # evaluation seeds 1000, 1001, ...: apart from the training seed


def t_interval(values) -> tuple[float, float]:
    """Mean and half-width of the 95 % t-interval (nan with fewer than two values)."""
    return confidence_interval(values)


def evaluate_policy(model, env, seeds, seconds: float, settle_time: float) -> list[float]:
    """Distance (m) from ``settle_time`` to ``seconds`` of the deterministic policy, per seed.

    ``model`` has SB3's ``predict``; ``env`` is the [-1, 1]-rescaled env it acts in. An episode
    that diverges keeps its distance so far (the robot stops where it was): one that ends
    before ``settle_time`` scores 0, as R of an MPC episode does (no reward after the end).
    Raises ValueError unless ``seconds`` > 0 and 0 <= ``settle_time`` < ``seconds``.
    """
    # (else every seed would silently score 0.0: named here, as run_baselines does)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a finite number > 0, got {seconds}")
    if not 0 <= settle_time < seconds:
        raise ValueError(f"settle time {settle_time} s must lie in [0, {seconds}) s")
    dt = float(env.get_wrapper_attr("dt"))
    steps, settle = max(1, round(seconds / dt)), round(settle_time / dt)
    out = []
    for s in seeds:
        obs, info = env.reset(seed=int(s))
        start = info["distance"] if settle == 0 else math.nan
        for t in range(1, steps + 1):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            start = info["distance"] if t == settle else start
            if terminated or truncated:
                break
        if math.isnan(start):  # ended before the settle time: no distance after it
            start = info["distance"]
        out.append(float(info["distance"] - start))
    return out
