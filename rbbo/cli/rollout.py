"""``rbbo rollout``: replay a run's best B_c with MPC, for its R or a video of the episode."""

from __future__ import annotations

import sys
from pathlib import Path

from .errors import UsageError
from .objectives import _objective_of


def cmd_rollout(args) -> int:
    from ..objective import EnvObjective
    from ..optimizer import RBBO

    opt = RBBO.resume(args.run_dir, read_only=True)
    result = opt.result()  # the confirmed recommendation, or the current one mid-run
    if result.best_basis is None:
        raise UsageError(f"{args.run_dir} has no successful evaluation at T_max yet: no "
                         "recommendation to replay")  # fmt: skip
    basis = result.best_basis
    if not opt.finished:
        print(f"the run has not finished: replaying its current recommendation, evaluation "
              f"{result.best_index}", file=sys.stderr)  # fmt: skip
    objective = _objective_of(opt)
    seconds = args.seconds or opt.config.t_max
    # A video of the first seconds is worth having (how the robot settles); R, measured from
    # the settle time on, is what a replay without --video is for.
    if isinstance(objective, EnvObjective) and not _measures_r(objective, seconds):
        if not args.video:
            raise UsageError(f"--seconds {seconds:g} must exceed the run's settle time "
                             f"{objective.settle_time:g} s, from which R is measured (from "
                             f"the first env step at or after it, {_measured_from(objective):g}"
                             f" s): give more (the run's T_max is {opt.config.t_max:g} s), or "
                             "add --video FILE to watch the episode without R")  # fmt: skip
    if not isinstance(objective, EnvObjective):
        if args.video:
            raise UsageError("--video needs an env run; a synthetic objective has no robot")
        r = objective(basis, seconds, args.seed)
        # (the synthetic R is a number on Gr(M, C), the optimum's 1: not a rate per second)
        print(f"R = {r:.6g} (synthetic objective, T = {seconds:g} s, seed {args.seed}); "
              f"optimum {objective.value(objective.optimum):.6g}")  # fmt: skip
        return 0
    if args.video:
        _check_video(args.video)  # before the env is built and the episode run
        return _rollout_video(objective, basis, seconds, args.seed, args.video)
    r = objective(basis, seconds, args.seed)
    print(f"R = {r:.6g} per second from t = {objective.settle_time:g} s "
          f"(T = {seconds:g} s, seed {args.seed})")  # fmt: skip
    return 0


def _measured_from(objective) -> float:
    """When R starts: the first env step at or after the settle time (settled_reward_rate's
    rule), so that --seconds just past a settle time between two steps is not an empty span."""
    from softrom_gym.registration import control_period

    from ..objective import settled_step

    step = control_period(objective.env_id, **objective.env_kwargs)
    if step is None:
        return objective.settle_time
    return settled_step(step, objective.settle_time) * step


def _measures_r(objective, seconds: float) -> bool:
    """Whether an episode of ``seconds`` has env steps from the settle time on
    (:func:`~rbbo.objective.measured_steps`): it runs round(seconds / dt) whole steps, so
    seconds just past the settle time (1.01 s after 1 s, at 0.025 s a step) may have none."""
    from softrom_gym.registration import control_period

    from ..objective import measured_steps

    step = control_period(objective.env_id, **objective.env_kwargs)
    if step is None:
        return seconds > objective.settle_time
    return measured_steps(step, objective.settle_time, seconds) > 0


def _check_video(video: Path) -> None:
    """Refuse, as a usage error before anything runs, a --video that could not be written
    after the episode: a name no video writer takes, a missing imageio (or imageio-ffmpeg,
    for a format written through ffmpeg), a folder, or a place that cannot be written. Its
    folder is created (as a run's --out is), so a new one is no error."""
    try:
        from controllers.episode import _VIDEO_SUFFIXES, _check_video_path
    except ImportError:  # a stand-in controllers module (the tests'): it writes no video
        _require_imageio(video.suffix)
        return
    if video.suffix.lower() not in _VIDEO_SUFFIXES:
        raise UsageError(f"--video {video}: the file name must end in one of "
                         f"{', '.join(sorted(_VIDEO_SUFFIXES))}")  # fmt: skip
    _require_imageio(video.suffix)
    try:
        video.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--video {video}: cannot create its folder {video.parent} "
                         f"({exc.strerror or exc})") from exc  # fmt: skip
    try:
        _check_video_path(video)
    except ValueError as exc:
        # (its messages begin "video 'PATH'": the option, as the user wrote it)
        raise UsageError(f"--{exc}") from exc


def _require_imageio(suffix: str) -> None:
    """Raise a usage error naming the extra when a video of ``suffix`` cannot be written:
    imageio, and for a format written through ffmpeg imageio-ffmpeg, which imageio imports
    only when it opens the file, after the episode.

    Only these imports are turned into a usage error: an ImportError raised inside the
    episode is a fault of the package and keeps its traceback.
    """
    try:
        from controllers.episode import _imageio
    except ImportError:  # (a stand-in controllers module: imageio alone, as it was)
        try:
            import imageio.v2  # noqa: F401
        except ImportError as exc:
            raise UsageError("--video needs imageio: pip install 'softrom[video]' (imageio "
                             "and imageio-ffmpeg)") from exc  # fmt: skip
        return
    try:
        _imageio(suffix)
    except ImportError as exc:
        # ("writing a ... video needs ...": said of --video)
        raise UsageError(f"--video: {exc}") from exc


def _rollout_video(objective, basis, seconds: float, seed: int, video: Path) -> int:
    import inspect

    import controllers

    from ..objective import settled_reward_rate

    video.parent.mkdir(parents=True, exist_ok=True)
    env = objective.make_env(basis, render_mode="rgb_array")
    if "video" in inspect.signature(controllers.run_episode).parameters:
        result = objective.episode(basis, seconds, seed, env=env, video=str(video))
    else:  # record through Gymnasium's wrapper
        import shutil
        import tempfile

        from gymnasium.wrappers import RecordVideo

        with tempfile.TemporaryDirectory() as folder:
            wrapped = RecordVideo(env, folder, episode_trigger=lambda _: True,
                                  name_prefix="rollout", disable_logger=True)  # fmt: skip
            result = objective.episode(basis, seconds, seed, env=wrapped)
            wrapped.close()
            clips = sorted(Path(folder).glob("*.mp4"))
            if not clips:
                raise UsageError("no video was written (does the env render rgb_array frames?)")
            shutil.move(str(clips[0]), video)
    if not _measures_r(objective, seconds):
        print(f"video: {video} ({seconds:g} s; no R, which is measured from the run's settle "
              f"time {objective.settle_time:g} s on)")  # fmt: skip
        return 0
    dt = getattr(result, "dt", None) or objective.step_seconds(env)
    r = settled_reward_rate(result, dt, objective.settle_time, seconds)
    print(f"R = {r:.6g} per second; video: {video}")
    return 0
