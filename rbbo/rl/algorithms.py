"""The algorithms: which ones, the env steps each trains, and the library that trains them.

``ALGOS`` are the Stable-Baselines3 algorithms the baselines train. Their env steps are one
number for all or one per algorithm (``--steps 20000``, ``--steps ppo=500000,sac=100000``):
:func:`parse_steps` reads the text, :func:`steps_per_algo` checks it against the algorithms
trained. Stable-Baselines3 is an optional dependency (``softrom[rl]``): :func:`require_sb3`
imports it or says how to install it.
"""

from __future__ import annotations

ALGOS = ("ppo", "sac")
DEFAULT_STEPS = 20_000  # a few minutes per algorithm and basis on a 2-core laptop


def steps_per_algo(steps: int | dict[str, int], algos: tuple[str, ...]) -> dict[str, int]:
    """Env steps of each algorithm: one number for all, or a mapping (PPO usually wants many
    more samples than SAC, whose gradient steps cost more per sample)."""
    per = dict.fromkeys(algos, steps) if not isinstance(steps, dict) else dict(steps)
    missing, extra = set(algos) - set(per), set(per) - set(algos)
    if missing or extra:
        raise ValueError(f"steps per algorithm must name exactly {', '.join(algos)}; got "
                         f"{', '.join(sorted(per)) or 'none'}")  # fmt: skip
    for algo, n in per.items():
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"steps of {algo} must be a positive integer, got {n!r}")
    return per


def parse_steps(text: str) -> int | dict[str, int]:
    """``"20000"`` (every algorithm) or ``"ppo=500000,sac=100000"``."""
    text = text.strip()
    try:
        if "=" not in text:
            return int(text)
        pairs = [item.split("=", 1) for item in text.split(",") if item.strip()]
        per = {k.strip().lower(): int(v) for k, v in pairs}
    except ValueError:
        raise ValueError(f"steps must be N or ALGO=N[,ALGO=N], got {text!r}") from None
    if len(per) < len(pairs):  # (the last would win silently)
        raise ValueError(f"steps name an algorithm twice: {text!r}")
    return per


def require_sb3():
    """The ``stable_baselines3`` module, or ImportError saying how to install it."""
    try:
        import stable_baselines3
    except ImportError:
        raise ImportError(
            "the RL baselines need Stable-Baselines3: pip install 'softrom[rl]'"
        ) from None
    return stable_baselines3
