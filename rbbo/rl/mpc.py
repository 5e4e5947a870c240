"""One MPC job: the MPPI planner on a basis, beside the RL jobs, its row cached.

:func:`_mpc` runs the planner for one episode per evaluation seed, counting the physics steps
of its planning rollouts, and keeps the row in ``OUT/mppi-<basis>/episodes.json``, reused
while the env, basis, evaluation and planner are the same (an unreadable one is made again,
with a warning).
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from .._warn import outside_stacklevel
from ..store import _atomic_write, _make_dirs
from .envs import _make_env
from .table import _row

CACHE = "episodes.json"


def _mpc_row_recorded(folder: Path) -> bool:
    """Whether ``folder`` holds a readable MPC row (what ``--status`` counts as done; a torn
    cache is made again by the next run, so it is not)."""
    try:
        return isinstance(json.loads((folder / CACHE).read_text()).get("row"), dict)
    except (OSError, ValueError, AttributeError):
        return False


def _mpc(env_id, name, basis, folder, env_kwargs, evaluation, progress,
         threads: int | None = None, planner_kwargs: dict | None = None) -> dict:  # fmt: skip
    import gymnasium as gym

    import controllers
    from softrom_gym.registration import control_period

    from ..objective import planner_record

    seeds, seconds, settle = evaluation
    # not a benchmark: the shared defaults (controllers.GENERIC), as EnvObjective
    changes = dict(planner_kwargs or {})
    if threads is not None:
        changes["threads"] = threads
    dt = control_period(env_id, **env_kwargs)
    planner, every = controllers.planner_for(env_id, "mppi", dt=dt, **changes)
    meta = {"env_id": env_id, "env_kwargs": env_kwargs, "basis": np.asarray(basis).tolist(),
            "seeds": list(seeds), "seconds": seconds, "settle_time": settle,
            "planner": planner_record(planner, every)}  # fmt: skip
    meta = json.loads(json.dumps(meta))  # as stored: tuples are lists
    cache = folder / CACHE
    if cache.is_file():
        try:
            old = json.loads(cache.read_text())
            if old["meta"] == meta:  # (rows from before the planner was keyed are made again)
                return old["row"]
        except (ValueError, KeyError, TypeError) as exc:
            # torn by a kill mid-write (before it was written atomically): the row is only
            # a cache of episodes that can be run again
            warnings.warn(f"rbbo: ignoring the unreadable MPC cache {cache} "
                          f"({type(exc).__name__}: {exc}); its row is made again",
                          RuntimeWarning, stacklevel=outside_stacklevel())  # fmt: skip

    class CountRollouts(gym.Wrapper):
        """Counts the physics steps of the planner's rollouts (it finds rollout here)."""

        physics_steps = 0

        def rollout(self, state, controls, *args, **kwargs):
            b, h = np.shape(controls)[:2]
            self.physics_steps += b * h * self.env.get_wrapper_attr("frame_skip")
            return self.env.get_wrapper_attr("rollout")(state, controls, *args, **kwargs)

    from ..objective import NO_TIME_LIMIT

    # no time limit of its own: run_episode stops after ``seconds``
    env = CountRollouts(_make_env(env_id, basis, env_kwargs, False,
                                  max_episode_steps=NO_TIME_LIMIT))  # fmt: skip
    k = int(env.get_wrapper_attr("frame_skip"))
    dist, physics, wall = [], [], []
    for s in seeds:
        planner, every = controllers.planner_for(env_id, "mppi", dt=dt, **changes)
        env.physics_steps, t0 = 0, time.perf_counter()
        result = controllers.run_episode(env, planner, seconds, replan_every=every, seed=s,
                                         progress=progress)  # fmt: skip
        wall.append(time.perf_counter() - t0)
        dist.append(result.distance_between(min(settle, result.seconds)))
        physics.append(env.physics_steps + result.rewards.size * k)
    row = _row(env_id, "mppi", name, True, 0, float(np.mean(physics)), float(np.mean(wall)), dist,
               float(env.get_wrapper_attr("body_length")))  # fmt: skip
    env.close()
    _make_dirs(folder)
    _atomic_write(cache, (json.dumps({"meta": meta, "row": row}) + "\n").encode())
    return row
