"""Swapping the control space B_c of an env as ``gym.make`` or ``gym.make_vec`` returned it,
wrappers and all: the spec every wrapper reports follows the swap."""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
from gymnasium.vector import VectorEnv

from .soft_robot_env import SoftRobotEnv
from .vector_env import SoftRobotVectorEnv

__all__ = ["set_control_basis"]


def set_control_basis(
    env: gym.Env | VectorEnv,
    control_basis: np.ndarray | str | os.PathLike,
    orthonormalize: bool = False,
) -> None:
    """Swap the control space B_c of ``env``, a softrom_gym env wrapped or not, and have
    ``env.spec`` (and every wrapper's) describe the swapped env.

    ``env.unwrapped.set_control_basis`` swaps B_c and updates the env's own spec, but
    Gymnasium's wrappers (``gym.make``'s ``TimeLimit``, ``OrderEnforcing``,
    ``PassiveEnvChecker``, and any other ``gymnasium.Wrapper``) keep the copy of the spec they
    made at their first read of ``env.spec``: read before the swap, it names the old B_c
    afterwards, and ``gym.make(env.spec)`` would make an env with another control space.
    This function swaps B_c through the env's method and drops those copies, so the next
    read of ``env.spec`` copies the env's new spec (its wrappers' parts, such as
    ``max_episode_steps``, as before). A vector env's wrappers keep no copy: for one from
    ``gym.make_vec`` this is ``env.unwrapped.set_control_basis``.

    Parameters
    ----------
    env : gymnasium.Env or gymnasium.vector.VectorEnv
        A :class:`SoftRobotEnv` or :class:`SoftRobotVectorEnv`, or wrappers around one.
    control_basis : (M, C) array, or str or os.PathLike
        The new B_c (the same M x C), or the path of a ``.npy`` file holding it.
    orthonormalize : bool, default False
        Accept any full-rank matrix, replaced by the Q of its QR.

    Raises
    ------
    TypeError
        When ``env.unwrapped`` is neither env.
    ValueError
        As :meth:`SoftRobotEnv.set_control_basis`, naming the value; nothing changes then.
    """
    base = getattr(env, "unwrapped", env)
    if not isinstance(base, (SoftRobotEnv, SoftRobotVectorEnv)):
        raise TypeError(
            "env must be a softrom_gym env (a SoftRobotEnv or SoftRobotVectorEnv, wrapped or "
            f"not), got {type(base).__name__}"
        )
    base.set_control_basis(control_basis, orthonormalize)
    # Gymnasium has no public way to refresh a wrapper's spec: Wrapper.spec (and TimeLimit's,
    # PassiveEnvChecker's) returns _cached_spec once set, and copies the inner spec when None.
    layer = env
    while isinstance(layer, gym.Wrapper):
        layer._cached_spec = None
        layer = layer.env
