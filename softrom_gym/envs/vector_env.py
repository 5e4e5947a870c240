"""``SoftRobotVectorEnv``: n robots stepped together in one batched C++ call."""

from __future__ import annotations

import os
from typing import Any, cast

import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

import cpp_sim

from .._validate import real_array
from .arguments import spec_with_control_basis
from .soft_robot_env import SoftRobotEnv

__all__ = ["SoftRobotVectorEnv"]


class SoftRobotVectorEnv(VectorEnv):
    """``num_envs`` copies of :class:`SoftRobotEnv` sharing one reduced model.

    Each ``step`` advances every robot in a single batched C++ call (one rollout of one env
    step per robot, on a thread pool). Sub-environment i behaves exactly like a single
    :class:`SoftRobotEnv` reset with seed ``seed + i``. Episodes are truncated after
    ``max_episode_steps``. ``reset(options={"state": state})`` starts every robot from that
    ``ReducedState`` (an autoreset later starts it at rest, as a plain reset does), and
    ``reset(options={"reset_mask": mask})`` (a bool array of ``num_envs``) resets only the
    robots where ``mask`` is True, as Gymnasium's vector envs do.

    Autoreset follows ``autoreset_mode``, one of Gymnasium's modes (see
    https://farama.org/Vector-Autoreset-Mode; ``metadata["autoreset_mode"]`` says which):

    * ``AutoresetMode.NEXT_STEP`` (default): the step after an episode ends resets that robot
      and returns its first observation, with reward 0 and its reset info.
    * ``AutoresetMode.SAME_STEP``: the step that ends an episode resets the robot at once and
      returns its first observation; the episode's last observation and info are in
      ``info["final_obs"]`` and ``info["final_info"]`` (masks ``info["_final_obs"]``, ...).
    * ``AutoresetMode.DISABLED``: nothing is reset by ``step``; reset the robots whose
      episode ended with ``reset(options={"reset_mask": terminated | truncated})``. Stepping
      one that was not is a ``gymnasium.error.ResetNeeded`` naming it.

    ``set_control_basis(control_basis)`` swaps the control space B_c of every robot at once
    (they share one reduced model), as :meth:`SoftRobotEnv.set_control_basis` does one env's:
    the same C, each robot keeping its state, and ``spec`` following, so ``gym.make_vec(spec)``
    makes a vector env with the new B_c. ``control_basis`` is the B_c in use (read-only).

    Create it with ``gym.make_vec(id, num_envs=n, vectorization_mode="vector_entry_point")``;
    ``max_episode_steps`` (default 400), ``threads`` and ``autoreset_mode`` (an
    ``AutoresetMode`` or its value, ``"SameStep"``) are the vector env's own, and every other
    keyword is passed to :class:`SoftRobotEnv`.
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
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
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
        modes = [mode.value for mode in AutoresetMode]
        if isinstance(autoreset_mode, AutoresetMode):
            mode = autoreset_mode
        elif isinstance(autoreset_mode, str) and autoreset_mode in modes:
            mode = AutoresetMode(autoreset_mode)
        else:
            raise ValueError(
                f"autoreset_mode must be one of {modes} or an AutoresetMode, got {autoreset_mode!r}"
            )
        if env_kwargs.get("render_mode") is not None:
            raise ValueError(
                f"the vector env does not render (render_mode={env_kwargs['render_mode']!r}); "
                "render one robot with gym.make(id, render_mode='rgb_array')"
            )
        self.env = SoftRobotEnv(**env_kwargs)
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps
        self.threads = None if threads is None else int(threads)
        self.autoreset_mode = mode
        # per instance, as SyncVectorEnv's: the class's metadata stays every default's
        self.metadata = {**self.metadata, "autoreset_mode": mode}
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
        # Robots whose episode ended: reset by the next step (NEXT_STEP), or refused by it
        # until reset(options={"reset_mask": ...}) (DISABLED); never set under SAME_STEP.
        self._autoreset = np.zeros(num_envs, dtype=bool)
        # Robots no reset has started: step refuses them, as SyncVectorEnv's sub-envs do (they
        # stepped from rest, their distance counted from the origin, not their centre of mass)
        self._never_reset = np.ones(num_envs, dtype=bool)
        # each robot's last observation: what a reset_mask reset returns for those it skips
        self._last_obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]

    @property
    def control_basis(self) -> np.ndarray:
        """The control space B_c (M x C) every robot is actuated in: a read-only array."""
        return self.env.control_basis

    def set_control_basis(
        self, control_basis: np.ndarray | str | os.PathLike, orthonormalize: bool = False
    ) -> None:
        """Swap the control space B_c of every robot, keeping their states and episodes.

        The robots share one reduced model, whose B_c is swapped by
        :meth:`SoftRobotEnv.set_control_basis`: the same checks, errors and results, and the
        robots then step as single envs swapped to (or made with) this B_c would. The action
        space is unchanged: a basis of another C is refused, as the single env refuses it.

        Parameters
        ----------
        control_basis : (M, C) array, or str or os.PathLike
            The new B_c, or the path of a ``.npy`` file holding it (a run's
            ``best_basis.npy``).
        orthonormalize : bool, default False
            Accept any full-rank matrix, replaced by the Q of its QR.

        Raises
        ------
        ValueError
            For a wrong shape, non-finite entries or a basis that is not orthonormal to 1e-8
            (naming it); nothing changes then.
        FileNotFoundError
            For a path to no file.

        Notes
        -----
        ``spec`` (set by ``gym.make_vec``) follows, as the single env's does: its
        ``control_basis`` becomes this one (a path stays a path, an array is held as the B_c
        now used) in a new ``EnvSpec``; one read earlier is left as it was.
        """
        self.env.set_control_basis(control_basis, orthonormalize)
        self.spec = spec_with_control_basis(
            self.spec, control_basis, self.env.control_basis, orthonormalize
        )

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
        # (checked before any sub-env is reset; the caller's dict is left as it was)
        options, mask = self._reset_options(options)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            # VectorEnv.reset's own seeding: np_random and np_random_seed are the vector
            # env's, as Gymnasium's vector envs have them (the robots' streams are their own)
            super().reset(seed=int(seed))
        infos: dict[str, Any] = {}
        for i, s in enumerate(seeds):
            if not mask[i]:
                continue
            # Gymnasium's rule: an unseeded reset continues each sub-env's own stream.
            if s is not None:
                self._rngs[i] = seeding.np_random(int(s))[0]
            self._last_obs[i], info = self._reset_one(i, options)
            infos = self._add_info(infos, info, i)
        self._autoreset[mask] = False
        self._never_reset[mask] = False
        return self._last_obs.copy(), infos

    def _reset_options(self, options: dict | None) -> tuple[dict | None, np.ndarray]:
        """``options`` for each robot's reset, and the robots to reset (Gymnasium's
        ``reset_mask``, default all), or an error naming what is wrong."""
        if not options:
            return None, np.ones(self.num_envs, dtype=bool)
        if not isinstance(options, dict):
            raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
        unknown = sorted(set(options) - {"state", "reset_mask"})
        if unknown:
            raise ValueError(
                "reset takes the options 'state' (a ReducedState from get_state()) and "
                f"'reset_mask' (a bool array of num_envs = {self.num_envs}), got {unknown}"
            )
        rest = {key: value for key, value in options.items() if key != "reset_mask"}
        self.env._reset_start(rest)
        if "reset_mask" not in options:
            return rest, np.ones(self.num_envs, dtype=bool)
        mask = np.asarray(options["reset_mask"])
        if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
            raise ValueError(f"reset_mask must be {self.num_envs} booleans, got "
                             f"{mask.tolist()!r}")  # fmt: skip
        if not mask.any():
            raise ValueError("reset_mask resets no sub-environment (it is all False)")
        return rest, mask.copy()

    def step(self, actions: np.ndarray):
        a = real_array("actions", actions)
        if a.shape != self.action_space.shape:
            raise ValueError(f"actions has shape {a.shape}, expected {self.action_space.shape}")
        # Rows of sub-environments this step resets are ignored, as SyncVectorEnv ignores
        # them, so only the rows that are stepped must be finite.
        bad = ~np.isfinite(a).all(axis=1) & ~self._autoreset
        if bad.any():
            rows = np.flatnonzero(bad).tolist()
            raise ValueError(f"actions contains non-finite values (env indices {rows})")
        if self._never_reset.any():
            never = np.flatnonzero(self._never_reset).tolist()
            raise ResetNeeded(
                f"sub-environment(s) {never} were never reset: call reset() (or reset with a "
                "reset_mask that includes them) before step()"
            )
        if self.autoreset_mode is AutoresetMode.DISABLED and self._autoreset.any():
            pending = np.flatnonzero(self._autoreset).tolist()
            raise ResetNeeded(
                f"sub-environment(s) {pending} ended (terminated or truncated) and were not "
                "reset: with autoreset_mode DISABLED, reset them with "
                "reset(options={'reset_mask': mask}) before the next step"
            )
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
                                 float(out["orientation"][k, 0]),
                                 converged=bool(out["converged"][k]))  # fmt: skip
                if self.autoreset_mode is AutoresetMode.SAME_STEP and (
                    terminated[i] or truncated[i]
                ):
                    final = {"final_obs": obs[i].copy(), "final_info": info}
                    infos = self._add_info(infos, final, int(i))
                    obs[i], info = self._reset_one(int(i))
                infos = self._add_info(infos, info, int(i))
        ended = terminated | truncated
        # (under SAME_STEP the robots that ended are reset already)
        same_step = self.autoreset_mode is AutoresetMode.SAME_STEP
        self._autoreset = np.zeros_like(ended) if same_step else ended
        self._last_obs[:] = obs
        return obs, rewards, terminated, truncated, infos
