"""The env a job trains, evaluates or plans in: ``gym.make`` with the job's control basis.

:func:`_make_env` makes the registered env in the basis's control space (M its rows, C its
columns, orthonormalised), its action box rescaled to SB3's [-1, 1] for the RL jobs;
``SET_BY_BASELINES`` names the keywords it sets itself, which ``--env-kwarg`` may not.
"""

from __future__ import annotations

import numpy as np

# What _make_env passes to gym.make itself (rbbo baselines' --env-kwarg may not set these).
SET_BY_BASELINES = {
    "sim_dim": "M: the basis's rows, --sim-dim",
    "control_dim": "C: the basis's columns",
    "control_basis": "B_c: --control-basis",
    "orthonormalize": "True: a .npy basis is orthonormalised",
}


def _make_env(env_id: str, basis: np.ndarray, env_kwargs: dict, rescale: bool, **extra):
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    m, c = np.shape(basis)
    env = gym.make(env_id, control_basis=np.asarray(basis, dtype=float), sim_dim=m,
                   control_dim=c, orthonormalize=True, **env_kwargs, **extra)  # fmt: skip
    # SB3's policies act in [-1, 1]; the env's box is physical (± action_bound)
    if not rescale:
        return env
    box = env.action_space
    assert isinstance(box, gym.spaces.Box)  # (softrom's envs act in a Box, as RescaleAction needs)
    one = np.ones(box.shape, dtype=box.dtype)  # float: a cast warning
    return _unit_box(env, -one, one)


def _unit_box(env, low: np.ndarray, high: np.ndarray):
    """``gymnasium.wrappers.RescaleAction(env, low, high)``, picklable.

    A checkpoint pickles the training env (its episode part-way, its generator) so that a
    resumed job goes on as the job run straight through; gymnasium's wrapper holds its
    rescaling in closures, which pickle cannot store, so this one is rebuilt from its
    arguments (the same class's arithmetic, so the actions are bitwise those of the original).
    """
    import gymnasium as gym

    class PicklableRescaleAction(gym.wrappers.RescaleAction):
        def __reduce__(self):
            k = self._saved_kwargs
            return (_unit_box, (self.env, k["min_action"], k["max_action"]))

    return PicklableRescaleAction(env, low, high)
