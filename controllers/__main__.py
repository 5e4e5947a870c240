"""Watch a planner walk: ``python -m controllers ENV_ID --planner mppi|gn --seconds 10``
(``--planner package.module:ClassName`` runs a planner of one's own).

Runs one closed-loop episode with the benchmark's defaults (:mod:`controllers.defaults`)
and prints a one-line summary: distance between t = 2 s (t = 0 in episodes of 2 s or less)
and the end (m and body lengths),
the task reward R, the mean tilt |theta|, the sideways path length, the mean effort, and the
wall time per replan; ``--video`` records the episode.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any

from softrom_gym._console import OneLineArgumentParser, say_warnings_as
from softrom_gym.registration import control_period, parse_env_kwarg

from .defaults import DEFAULTS, parse_changes, planner_for
from .planner import EnvAPI
from .registry import registered_planners, resolve_planner


def _window(text: str) -> int | None:
    if text == "all":
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number of env steps or 'all', got {text!r}"
        ) from None


def _registered(env_id: str, given: str) -> str:
    """``env_id`` as registered: one without its version is its latest (as gym.make reads it,
    and so that the planner is the one tuned for it)."""
    import gymnasium as gym

    if env_id in gym.registry:
        return env_id
    versions = sorted((k for k in gym.registry if k.rsplit("-v", 1)[0] == env_id),
                      key=lambda k: int(k.rsplit("-v", 1)[1]) if k.rsplit("-v", 1)[1].isdigit()
                      else -1)  # fmt: skip
    if versions:
        return versions[-1]
    raise ValueError(
        f"{given}: not a registered softrom env; this command runs softrom_gym's envs, e.g. "
        "CrossWalk-v0, or SoftRobot-v0 with --env-kwarg robot=..."
    )


def _parser() -> argparse.ArgumentParser:
    # options only as spelled, as `rbbo` takes them: a prefix such as --sample would start
    # meaning another option the day one is added, and a script that ran would mean another run
    # the docstring's first two paragraphs: what runs and what the printed line holds
    about = " ".join(" ".join(__doc__.split("\n\n")[:2]).split())
    about = about.replace(":mod:", "").replace("`", "")  # (reST is not for a terminal)
    p = OneLineArgumentParser(prog="python -m controllers", description=about)
    p.add_argument("env_id", help=f"a benchmark ({', '.join(sorted(DEFAULTS))}: tuned "
                   "defaults) or another softrom env, e.g. SoftRobot-v0 with --env-kwarg "
                   "robot=my_robot.stl (shared defaults; the gait seed picks a 2, 3 or 4 Hz "
                   "cycle)")  # fmt: skip
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   type=parse_env_kwarg,
                   help="a gym.make keyword, one per option; VALUE is read as JSON, else as "
                   "a string (e.g. --env-kwarg robot=my_robot.stl --env-kwarg "
                   "task=swim)")  # fmt: skip
    p.add_argument("--planner", default="mppi", metavar="NAME",
                   help=f"the MPC planner: {', '.join(registered_planners())}, or a planner "
                   "of your own as an import path package.module:ClassName (a Planner "
                   "subclass, e.g. examples.cem_planner:CEM run from the repository; default "
                   "mppi)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=10.0,
                   help="simulated time of the episode, s (default 10; the env's time limit "
                   "is raised to it)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the env's reset and the planner (default 0)")  # fmt: skip
    p.add_argument(
        "--control-basis",
        type=Path,
        help="B_c (M x C) as a .npy file; a full-rank one is orthonormalised",
    )
    p.add_argument("--video", type=Path, help="write the episode to this video file")
    p.add_argument("--replan-every", type=int, help="env steps between replans")
    p.add_argument("--horizon", type=int, help="override the default horizon (env steps)")
    p.add_argument("--window", type=_window, default=argparse.SUPPRESS,
                   help="env steps at the horizon's end over which R is counted, or 'all' "
                   "(default: the planner's; a --horizon shorter than it needs one)")  # fmt: skip
    p.add_argument("--samples", type=int, help="override MPPI's samples")
    p.add_argument("--iterations", type=int, help="override iterations per replan")
    p.add_argument("--threads", type=int, help="C++ rollout threads")
    p.add_argument("--mpc", type=parse_changes, action="append", default=[],
                   metavar="KEY=VALUE[,...]",
                   help="any planner setting, e.g. noise=0.3,temperature=0.05 or "
                   "knots=8,period=20; a tuple colon-separated, noise=0.3:0.1:0.1 (env steps; "
                   "repeatable; the flags above win)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m controllers``; returns the exit status.

    With ``argv=None`` (this process's command line) it also prints the process's warnings (an
    env's, say) as ``python -m controllers: warning:`` lines; a call with an argument list
    leaves the caller's warning display alone.
    """
    if argv is None:
        say_warnings_as("python -m controllers")
    parser = _parser()
    args = parser.parse_args(argv)
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        parser.error(f"--seconds must be a positive number, got {args.seconds}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    try:  # before the env is made (minutes for a new robot)
        planner_entry = resolve_planner(args.planner)
    except (ValueError, TypeError) as exc:
        parser.error(f"--planner: {exc}")
    # before gym.make, which builds a new robot's B_r and cubature (minutes) first
    if args.replan_every is not None and args.replan_every < 1:
        parser.error(f"--replan-every must be >= 1, got {args.replan_every}")
    if args.video is not None:
        from .episode import _check_video_path, _imageio

        try:
            _check_video_path(args.video)
            _imageio(args.video.suffix)  # a missing extra, named now, not after the episode
        except (ValueError, ImportError) as exc:
            parser.error(str(exc))
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    from .episode import EpisodeResult, _one_line, run_episode

    env_id = args.env_id if "/" in args.env_id else f"softrom_gym/{args.env_id}"
    kwargs: dict[str, Any] = dict(args.env_kwarg)
    if args.control_basis is not None:
        # the env reads the .npy and names what is wrong with it; as `rbbo baselines`, any
        # full-rank B_c, orthonormalised (its span is what counts)
        kwargs.update(control_basis=str(args.control_basis), orthonormalize=True)
    if args.video is not None:
        kwargs["render_mode"] = "rgb_array"
    changes: dict[str, Any] = {}
    for part in args.mpc:
        changes.update(part)
    changes.update({k: v for k, v in (("horizon", args.horizon), ("samples", args.samples),
                                      ("iterations", args.iterations), ("threads", args.threads))
                    if v is not None})  # fmt: skip
    if hasattr(args, "window"):
        changes["window"] = args.window  # (None: 'all')
    try:
        settings_fields = {f.name for f in dataclasses.fields(planner_entry.settings_class)}
        if "samples" in changes and "samples" not in settings_fields:
            raise ValueError(f"--samples applies to a planner with samples (mppi), not "
                             f"{args.planner}")  # fmt: skip
        env_id = _registered(env_id, args.env_id)
        # the registered time limit (env steps) must not cut the seconds asked for short
        period = control_period(env_id, **kwargs)
        limit = gym.spec(env_id).max_episode_steps
        if period is not None and limit is not None and "max_episode_steps" not in kwargs:
            kwargs["max_episode_steps"] = max(limit, math.ceil(args.seconds / period - 1e-9))
        env = gym.make(env_id, **kwargs)
        # the defaults' times are the same seconds at the env's control period
        planner, replan_every = planner_for(env_id, args.planner, dt=env.get_wrapper_attr("dt"),
                                            **changes)  # fmt: skip
        planner.settings.check_control_dim(EnvAPI(env).control_dim)
    except (ValueError, TypeError, FileNotFoundError, gym.error.Error) as exc:
        parser.error(str(exc))
    if args.replan_every is not None:
        replan_every = args.replan_every
    start = time.perf_counter()
    video_error: Exception | None = None
    try:
        result = run_episode(env, planner, args.seconds, replan_every=replan_every,
                             seed=args.seed, progress=not args.no_progress,
                             video=args.video)  # fmt: skip
    except KeyboardInterrupt as interrupt:
        partial: EpisodeResult | None = getattr(interrupt, "result", None)
        if partial is not None and partial.seconds > 0:
            print(f"{env_id.split('/')[-1]} {partial.summary()}")
        print("interrupted", file=sys.stderr)
        return 130
    except (OSError, ValueError, RuntimeError) as exc:
        # the episode ran, and its video could not be written (a full disk, say): its result
        # rides on the error, and is printed before the error, not lost in a traceback
        ran: EpisodeResult | None = getattr(exc, "result", None)
        if ran is None:
            raise
        result, video_error = ran, exc
    finally:
        env.close()
    wall = time.perf_counter() - start
    rtf = result.realtime_factor(replan_every)
    print(f"{env_id.split('/')[-1]} {result.summary()}; planning real-time factor {rtf:.3f} "
          f"(simulated s per wall s of replanning), episode wall {wall:.0f} s")  # fmt: skip
    if video_error is not None:
        print(f"{parser.prog}: error: the video {args.video} was not written: "
              f"{_one_line(video_error)}", file=sys.stderr)  # fmt: skip
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
