"""Registration of the softrom environments with Gymnasium (``import softrom_gym``)."""

from __future__ import annotations

import argparse
import inspect
import json
import math
import numbers
from typing import Any

import gymnasium as gym

ENTRY_POINT = "softrom_gym.envs.soft_robot_env:SoftRobotEnv"
VECTOR_ENTRY_POINT = "softrom_gym.envs.vector_env:SoftRobotVectorEnv"
MAX_EPISODE_STEPS = 400  # 10 s at the default frame_skip = 5, dt = 1/200 s

# The paper's Table I benchmarks.
BENCHMARKS = {
    "CrossSwim-v0": {"robot": "cross", "task": "swim"},
    "CrossWalk-v0": {"robot": "cross", "task": "walk"},
    "BeamWalk-v0": {"robot": "beam", "task": "walk"},
    "QuadrupedWalk-v0": {"robot": "quadruped", "task": "walk"},
    "TripodWalk-v0": {"robot": "tripod", "task": "walk"},
}


def register_envs() -> None:
    for name, kwargs in BENCHMARKS.items():
        env_id = f"softrom_gym/{name}"
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT,
                         kwargs=kwargs, max_episode_steps=MAX_EPISODE_STEPS)  # fmt: skip
    if "softrom_gym/SoftRobot-v0" not in gym.registry:
        gym.register("softrom_gym/SoftRobot-v0", entry_point=ENTRY_POINT,
                     vector_entry_point=VECTOR_ENTRY_POINT,
                     max_episode_steps=MAX_EPISODE_STEPS)  # fmt: skip


def parse_env_kwarg(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of a command line's ``--env-kwarg`` (``rbbo``, ``python -m controllers``)
    as a ``gym.make`` keyword: VALUE is JSON where it parses (numbers, lists, true, null), else
    the string itself (a mesh path, a robot name). An argparse ``type``."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, KEY a keyword name; got {text!r}")
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


def control_period(env_id: str, **kwargs: Any) -> float | None:
    """The control period (s per env step, ``frame_skip * dt``) of ``gym.make(env_id,
    **kwargs)``, read from the registration and the constructor's defaults without building
    the env. None for an env without both keywords, or values the env would refuse (it names
    them when it is made)."""
    spec = gym.spec(env_id)
    entry = spec.entry_point
    try:
        creator = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
        if creator is None:  # (an id registered without an entry point)
            return None
        params = inspect.signature(creator).parameters
    except (ImportError, AttributeError, TypeError, ValueError):
        return None
    merged = {**spec.kwargs, **kwargs}
    values = []
    for name in ("frame_skip", "dt"):
        if name in merged:
            values.append(merged[name])
        elif name in params and params[name].default is not inspect.Parameter.empty:
            values.append(params[name].default)
        else:
            return None
    # (numbers.Real: numpy's integers and floats, as the env takes them; not a bool)
    if any(isinstance(v, bool) or not isinstance(v, numbers.Real) for v in values):
        return None
    period = float(values[0]) * float(values[1])
    return period if math.isfinite(period) and period > 0 else None
