"""``rbbo baselines``: PPO and SAC (Stable-Baselines3) trained and evaluated beside the MPC."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .arguments import _env_kwargs
from .errors import UsageError, _bad_input
from .objectives import _check_controllers, _resolve_env


def cmd_baselines(args) -> int:
    from .. import rl
    from ..objective import _check_env_keywords

    env_id = _resolve_env(args.env_id, synthetic=False)
    algos = [a.strip().lower() for a in args.algo.split(",")]
    bad = [a for a in algos if a not in rl.ALGOS]
    if bad:
        raise UsageError(f"unknown --algo {bad[0]!r}; valid: {', '.join(rl.ALGOS)}")
    if not 0 <= args.settle_time < args.seconds:
        raise UsageError(f"--settle-time {args.settle_time} must lie in [0, --seconds)")
    if not args.no_mpc:
        _check_controllers()
    with _bad_input():
        rl.require_sb3()
        rl.steps_per_algo(args.steps, tuple(dict.fromkeys(algos)))
        bases, env_kwargs = rl.resolve_bases(args.control_basis.split(","), env_id, args.run,
                                             args.sim_dim, args.control_dim)  # fmt: skip
        given = _env_kwargs(args.env_kwarg)
        if given:
            _check_env_keywords(env_id, given, rl.SET_BY_BASELINES)
        for key, value in given.items():
            if args.run is not None and env_kwargs.get(key, value) != value:
                raise UsageError(f"--env-kwarg {key}={json.dumps(value)} differs from run "
                                 f"{args.run}'s {key}={json.dumps(env_kwargs[key])}, the env "
                                 "its B_c was found in")  # fmt: skip
            if args.run is not None and key not in env_kwargs:
                raise UsageError(f"--env-kwarg {key} was not given to run {args.run}, whose "
                                 "B_c was found in its env as it was")  # fmt: skip
        env_kwargs = {**env_kwargs, **given}
        # the env is made here: a bad --env-kwarg value fails now, named, not as a traceback
        # after the job folders are claimed
        for basis in bases.values():
            rl._make_env(env_id, basis, env_kwargs, False).close()
        planner_kwargs = _run_mppi_overrides(args.run) if args.run and not args.no_mpc else {}
    out = args.out or Path("runs") / f"baselines-{env_id.split('/')[-1]}"
    try:
        rows = rl.run_baselines(
            env_id, bases, out, algos=tuple(dict.fromkeys(algos)), steps=args.steps,
            checkpoint_every=args.checkpoint_every, eval_seeds=args.eval_seeds,
            seconds=args.seconds, settle_time=args.settle_time, seed=args.seed,
            mpc=not args.no_mpc, env_kwargs=env_kwargs, progress=not args.no_progress,
            workers=args.workers, planner_kwargs=planner_kwargs,
        )  # fmt: skip
    except KeyboardInterrupt:
        print("\ninterrupted; run the same command again to continue from the last "
              "checkpoint", file=sys.stderr)  # fmt: skip
        return 130
    print(rl.format_table(rows))
    print(f"results: {out / 'baselines.csv'}, {out / 'baselines.md'}", file=sys.stderr)
    return 0


def _run_mppi_overrides(run_dir) -> dict[str, Any]:
    """The run's ``--mpc`` overrides, for the MPC rows beside the RL ones (MPPI): the planner
    its R* was measured with. A Gauss-Newton run's overrides are not MPPI's: said, not used."""
    from ..store import RunStore

    objective = RunStore.open(run_dir, repair=False).config.get("objective") or {}
    overrides = dict(objective.get("planner_kwargs") or {})
    if overrides and objective.get("controller", "mppi") != "mppi":
        print(f"note: run {run_dir} planned with {objective.get('controller')} and --mpc "
              f"{overrides}; the MPC rows are MPPI's, with its defaults",
              file=sys.stderr)  # fmt: skip
        return {}
    return overrides
