"""What rbbo passes to ``gym.make`` itself, and the check of a run's env keywords.

``SET_BY_RBBO`` names the keywords rbbo sets (an env keyword may not set them);
``NO_TIME_LIMIT`` is the ``max_episode_steps`` of an env whose episodes the caller times
itself; :func:`_check_env_keywords` refuses a keyword the env's constructor does not take.
"""

from __future__ import annotations

from typing import Any

# What rbbo passes to gym.make itself: an env keyword argument may not set these.
SET_BY_RBBO = {
    "sim_dim": "M: --sim-dim, RBBOConfig.sim_dim",
    "control_dim": "C: --control-dim, RBBOConfig.control_dim",
    "control_basis": "B_c: the basis being evaluated",
}


# max_episode_steps for an env whose episodes the caller times itself (gym.make's None would
# keep the registered limit)
NO_TIME_LIMIT = 10**9


def _check_env_keywords(env_id: str, kwargs: dict[str, Any], set_here=SET_BY_RBBO) -> None:
    """Refuse a keyword the env's constructor does not take, naming those it does (Gymnasium's
    own error quotes every keyword's value, the basis array too), and one that rbbo sets
    itself (``set_here``: keyword -> what it is)."""
    import inspect

    import gymnasium as gym

    clash = [k for k in set_here if k in kwargs]
    if clash:
        raise ValueError(f"env keyword {clash[0]!r} is set by rbbo itself "
                         f"({set_here[clash[0]]}); {', '.join(set_here)} cannot be given as "
                         "env keywords")  # fmt: skip

    entry = gym.spec(env_id).entry_point
    try:
        creator = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
        if creator is None:  # (an id registered without an entry point: let gym.make say it)
            return
        params = inspect.signature(creator).parameters
    except (ImportError, AttributeError, TypeError, ValueError):  # let gym.make say it
        return
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = sorted(set(kwargs) - set(params))
    if unknown:
        known = ", ".join(
            k for k, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL
        )
        raise ValueError(f"{env_id} takes no keyword {', '.join(map(repr, unknown))}; its "
                         f"keywords: {known}")  # fmt: skip
