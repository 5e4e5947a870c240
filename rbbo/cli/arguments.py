"""Argument types of the ``rbbo`` command line, and the helpers that combine parsed values.

A type parses an option's text or raises :class:`argparse.ArgumentTypeError`, which the
parser reports as a usage error naming the option (``argument --budget: duration must be
positive, got '-5m'``). :func:`merged_mpc_changes` and :func:`_env_kwargs` turn repeated
``--mpc`` and ``--env-kwarg`` options into the dicts a run stores.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from pathlib import Path
from typing import Any

_DURATION = re.compile(r"^(?:(\d+(?:\.\d*)?)h)?(?:(\d+(?:\.\d*)?)m)?(?:(\d+(?:\.\d*)?)s)?$")


def user_path(text: str) -> Path:
    """A path option's value, ``~`` read as the home folder even where no shell expanded it
    (quoted, or in ``--out=~/run``): a robot's mesh path and ``control_basis`` read it so, and
    a folder named "~" in the working directory is never what was meant."""
    return Path(os.path.expanduser(text))


def parse_duration(text: str) -> float:
    """'30m', '2h', '1h30m', '45s' or a plain number of seconds -> seconds."""
    text = str(text).strip().lower()
    if text.startswith("-"):
        raise argparse.ArgumentTypeError(f"duration must be positive, got {text!r}")
    try:
        seconds = float(text)
    except ValueError:
        match = _DURATION.match(text)
        if not text or match is None:
            raise argparse.ArgumentTypeError(
                f"invalid duration {text!r}; use e.g. 30m, 2h, 1h30m, 45s"
            ) from None
        h, m, s = (float(g) if g else 0.0 for g in match.groups())
        seconds = 3600 * h + 60 * m + s
    if not (math.isfinite(seconds) and seconds > 0):
        raise argparse.ArgumentTypeError(f"duration must be positive, got {text!r}")
    return seconds


def _number_arg(kind: type, allowed, what: str):
    """An argparse type: ``kind`` (int or float) parsed from the text and checked by
    ``allowed``; either failure says what was expected and what was given."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = None
        if value is None or not allowed(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    return parse


_positive_int = _number_arg(int, lambda v: v >= 1, "a positive integer")
_nonnegative_int = _number_arg(int, lambda v: v >= 0, "an integer >= 0")
_positive_float = _number_arg(float, lambda v: math.isfinite(v) and v > 0, "a positive number")
_nonnegative_float = _number_arg(float, lambda v: math.isfinite(v) and v >= 0, "a number >= 0")


def mpc_changes_arg(text: str) -> dict[str, Any]:
    """``--mpc`` (``optimize``, ``reproduce``): key=value,... planner setting overrides."""
    from controllers.defaults import parse_changes

    return parse_changes(text)


def merged_mpc_changes(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The repeated ``--mpc`` options as one dict, a later key winning."""
    return {k: v for part in parts for k, v in part.items()}


def rl_steps_arg(text: str) -> int | dict[str, int]:
    """``--steps`` / ``--rl-steps``: N for every algorithm, or ppo=N,sac=N."""
    from ..rl import parse_steps

    try:
        steps = parse_steps(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    values = steps.values() if isinstance(steps, dict) else [steps]
    if any(n < 1 for n in values):
        raise argparse.ArgumentTypeError(f"env steps must be positive, got {text!r}")
    return steps


def _env_kwargs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """--env-kwarg pairs as a dict; ``robot=`` naming an existing mesh file is stored as an
    absolute path, so the run resumes from any working directory."""
    import os

    out = {}
    for key, value in pairs:
        path = os.path.expanduser(value) if key == "robot" and isinstance(value, str) else ""
        if os.path.splitext(path)[1] and os.path.isfile(path):  # a mesh file, not a name
            value = os.path.abspath(path)
        out[key] = value
    return out


def _env_kwarg(text: str) -> tuple[str, Any]:
    """--env-kwarg KEY=VALUE (softrom_gym.registration.parse_env_kwarg), imported only when
    the option is given: the envs take a second to import, and ``rbbo --help`` need not."""
    from softrom_gym.registration import parse_env_kwarg

    return parse_env_kwarg(text)
