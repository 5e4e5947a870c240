"""``SoftRobotVectorEnv``: n robots stepped together in one batched C++ call."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

import cpp_sim

from .._validate import real_array
from .soft_robot_env import SoftRobotEnv

__all__ = ["SoftRobotVectorEnv"]


class SoftRobotVectorEnv(VectorEnv):
    """``num_envs`` copies of :class:`SoftRobotEnv` sharing one reduced model.

    Each ``step`` advances every robot in a single batched C++ call (one rollout of one env
    step per robot, on a thread pool). Sub-environment i behaves exactly like a single
    :class:`SoftRobotEnv` reset with seed ``seed + i``. Autoreset follows Gymnasium's
    ``AutoresetMode.NEXT_STEP``: the step after an episode ends resets that robot and returns
    its first observation with reward 0. Episodes are truncated after ``max_episode_steps``.
    ``reset(options={"state": state})`` starts every robot from that ``ReducedState`` (an
    autoreset later starts it at rest, as a plain reset does).

    Create it with ``gym.make_vec(id, num_envs=n, vectorization_mode="vector_entry_point")``;
    ``max_episode_steps`` (default 400) and ``threads`` are the vector env's own, and every
    other keyword is passed to :class:`SoftRobotEnv`.
    """

    # Not a ClassVar: gymnasium's VectorEnv declares it per instance.
    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": [],
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }
    single_observation_space: spaces.Box
    single_action_space: spaces.Box
    observation_space: spaces.Box
    action_space: spaces.Box

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = 400,
        threads: int | None = None,
        **env_kwargs: Any,
    ) -> None:
        if (
            isinstance(num_envs, bool)
            or not isinstance(num_envs, (int, np.integer))
            or num_envs < 1
        ):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        num_envs = int(num_envs)
        if max_episode_steps is not None and (
            isinstance(max_episode_steps, bool)
            or not isinstance(max_episode_steps, (int, np.integer))
            or max_episode_steps < 1
        ):
            raise ValueError(
                f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}"
            )
        # (checked here: the core would name it only at the first step, after reset)
        if threads is not None and (
            isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1
        ):
            raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
        if env_kwargs.get("render_mode") is not None:
            raise ValueError(
                f"the vector env does not render (render_mode={env_kwargs['render_mode']!r}); "
                "render one robot with gym.make(id, render_mode='rgb_array')"
            )
        self.env = SoftRobotEnv(**env_kwargs)
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps
        self.threads = None if threads is None else int(threads)
        self.single_observation_space = self.env.observation_space
        self.single_action_space = self.env.action_space
        # (batch_space of a Box is a Box, of shape (num_envs, *shape))
        self.observation_space = cast(
            spaces.Box, batch_space(self.single_observation_space, num_envs)
        )
        self.action_space = cast(spaces.Box, batch_space(self.single_action_space, num_envs))
        self._states = [self.env.model.rest_state() for _ in range(num_envs)]
        self._com0 = np.zeros((num_envs, 3))
        self._elapsed = np.zeros(num_envs, dtype=np.int64)
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]

    def _reset_one(self, i: int, options: dict | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        env = self.env
        env._np_random = self._rngs[i]  # the sub-env's own stream, as a single env's
        obs, info = env.reset(options=options)
        self._rngs[i] = env.np_random
        self._states[i] = env.get_state()
        self._com0[i] = info["com"]
        self._elapsed[i] = 0
        return obs, info

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        elif isinstance(seed, (list, tuple, np.ndarray)):
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed list has {len(seeds)} entries, expected {self.num_envs}")
            for i, s in enumerate(seeds):  # (int() would read 1.5 as 1 and "3" as 3)
                if s is not None and (isinstance(s, (bool, np.bool_))
                                      or not isinstance(s, (int, np.integer))):  # fmt: skip
                    raise ValueError(f"seed list entry {i} must be an int or None, got {s!r}")
        else:
            raise ValueError(
                f"seed must be None, an int or a list of {self.num_envs} ints, got {seed!r}"
            )
        self.env._reset_start(options)  # (an error before any sub-env is reset)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            # VectorEnv.reset's own seeding: np_random and np_random_seed are the vector
            # env's, as Gymnasium's vector envs have them (the robots' streams are their own)
            super().reset(seed=int(seed))
        infos: dict[str, Any] = {}
        obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        for i, s in enumerate(seeds):
            # Gymnasium's rule: an unseeded reset continues each sub-env's own stream.
            if s is not None:
                self._rngs[i] = seeding.np_random(int(s))[0]
            obs[i], info = self._reset_one(i, options)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return obs, infos

    def step(self, actions: np.ndarray):
        a = real_array("actions", actions)
        if a.shape != self.action_space.shape:
            raise ValueError(f"actions has shape {a.shape}, expected {self.action_space.shape}")
        if not np.all(np.isfinite(a)):
            rows = sorted({int(i) for i in np.argwhere(~np.isfinite(a))[:, 0]})
            raise ValueError(f"actions contains non-finite values (env indices {rows})")
        obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        live = np.flatnonzero(~self._autoreset)
        for i in np.flatnonzero(self._autoreset):
            obs[i], info = self._reset_one(int(i))
            infos = self._add_info(infos, info, int(i))
        if live.size:
            env = self.env
            out = env.rollout([self._states[i] for i in live], a[live, None, :],
                              threads=self.threads)  # fmt: skip
            for k, i in enumerate(live):
                state = cpp_sim.ReducedState(out["q"][k], out["qdot"][k], out["impulses"][k])
                self._states[i] = state
                self._elapsed[i] += 1
                diverged = bool(out["diverged"][k])
                rewards[i] = out["rewards"][k, 0]
                terminated[i] = diverged
                if self.max_episode_steps is not None:
                    truncated[i] = self._elapsed[i] >= self.max_episode_steps
                obs[i] = env._obs(state)
                env._com0 = self._com0[i]
                info = env._info(state, float(out["lateral"][k, 0]),
                                 float(out["effort"][k, 0]), diverged,
                                 float(out["orientation"][k, 0]))  # fmt: skip
                infos = self._add_info(infos, info, int(i))
        self._autoreset = terminated | truncated
        return obs, rewards, terminated, truncated, infos
