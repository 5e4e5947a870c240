"""``run_episode``: a planner in closed loop on an env, recorded step by step."""

from __future__ import annotations

import importlib
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softrom_gym._durable import fsync_dir, temporary_name

from .planner import EnvAPI, Planner

__all__ = ["EpisodeResult", "run_episode"]


@dataclass
class EpisodeResult:
    """One closed-loop episode.

    ``planner`` is the planner's ``name`` ("mppi", "gn", or a planner of one's own), ``dt`` the
    env's control period (s), ``body_length`` the robot's (m, for distances in body lengths) and
    ``seed_gait`` the label of the gait the planner's gait seed chose at reset (None without
    one). Per env step t = 1..T (arrays of length T), as ``env.step`` reported them: ``rewards``
    (R per step, m, as any reward wrapper left it), ``orientation`` (rad), ``lateral`` (m),
    ``effort`` (|f_c / a|^2), ``actions`` (T, C). Per state t = 0..T: ``com`` (T + 1, 3) and
    ``distance`` (T + 1,) along d since reset (m), ``states`` (ReducedState copies). Per replan:
    ``replan_steps`` (the step it ran at), ``replan_wall_s`` and ``replan_records`` (the
    planner's ``last_`` after it: objectives, rollouts, and the planner's own terms, as
    :class:`~controllers.planner.Planner` lists them) and ``replan_every`` (the interval asked
    for, env steps). ``stop_reason`` says why the episode ended: "time" (its seconds ran out),
    "diverged", "truncated by the time limit" (the env's TimeLimit) or "interrupted" (Ctrl-C:
    :func:`run_episode` raises the KeyboardInterrupt with the steps recorded so far as its
    ``result``, and writes the video of them; interrupted in the reset or the planner's set-up,
    before the first state is recorded, its ``result`` is None).
    """

    planner: str
    dt: float
    body_length: float
    rewards: np.ndarray
    orientation: np.ndarray
    lateral: np.ndarray
    effort: np.ndarray
    actions: np.ndarray
    com: np.ndarray
    distance: np.ndarray
    states: list = field(repr=False)
    replan_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    replan_wall_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    replan_records: list[dict[str, Any]] = field(default_factory=list, repr=False)
    stop_reason: str = ""
    seed_gait: str | None = None
    replan_every: int = 1

    @property
    def seconds(self) -> float:
        """Simulated time (s)."""
        return self.rewards.size * self.dt

    @property
    def R(self) -> float:
        """The task reward: distance along d over the episode (m), without Λ. From the centre
        of mass, so a reward wrapper (which changes ``rewards``) cannot change it; on the env
        itself it equals ``rewards.sum()`` to round-off."""
        return float(self.distance[-1])

    @property
    def replans(self) -> int:
        """How many times the planner replanned (``plan`` calls in the episode)."""
        return int(self.replan_wall_s.size)

    def distance_between(self, t0: float, t1: float | None = None) -> float:
        """Distance along d between times t0 and t1 (default: the end), m."""
        n = self.rewards.size
        end = self.seconds if t1 is None else t1
        slack = 1e-9 * max(1.0, self.seconds)  # (n dt, the end, to round-off)
        # the times themselves, not their nearest steps: a time half a step outside counts
        if not -slack <= t0 <= end <= self.seconds + slack:
            raise ValueError(f"times ({t0}, {t1}) must lie in [0, {self.seconds:g}] s, in order")
        i0 = round(t0 / self.dt)
        i1 = n if t1 is None else round(t1 / self.dt)
        return float(self.distance[i1] - self.distance[i0])

    def realtime_factor(self, replan_every: int | None = None) -> float:
        """Simulated seconds advanced per replan (``replan_every`` env steps; default: the
        episode's) / wall seconds per replan: the planning's real-time factor (the episode's
        env steps and the gait seed at reset are not in it)."""
        if not self.replans:
            return float("nan")
        if replan_every is None:
            replan_every = self.replan_every
        return replan_every * self.dt / float(np.mean(self.replan_wall_s))

    def summary(self, start: float = 2.0) -> str:
        """One line: the distance along d from ``start`` (s; the whole episode if it is not
        longer) to the end, in m and body lengths, R, the mean orientation (rad), the
        sideways path length (m), the mean effort, the replans and their mean wall time, and
        why the episode stopped."""
        # the distance after the settling time, or over the whole of a shorter episode (an
        # empty window would print a distance of zero that says nothing)
        t0 = start if start < self.seconds else 0.0
        d = self.distance_between(t0)
        wall = float(np.mean(self.replan_wall_s)) if self.replans else float("nan")
        return (
            f"{self.planner}: {self.seconds:g} s, distance t={t0:g}..{self.seconds:g} s "
            f"{d:+.3f} m ({d / self.body_length:+.2f} body lengths), R {self.R:+.3f} m, "
            f"mean orientation {self.orientation.mean():.3f} rad, lateral "
            f"{self.lateral.sum():.3f} m, effort {self.effort.mean():.2f}, {self.replans} "
            f"replans at {wall:.2f} s wall each (stopped: {self.stop_reason or '-'})"
        )


def run_episode(
    env: Any,
    planner: Planner,
    seconds: float,
    replan_every: int = 1,
    seed: int | None = 0,
    progress: bool = True,
    video: str | os.PathLike | None = None,
) -> EpisodeResult:
    """Run ``planner`` on ``env`` in closed loop for ``seconds`` of simulated time.

    Parameters
    ----------
    env : gymnasium.Env
        A softrom env, wrapped or not, but in no action wrapper other than ``ClipAction``
        (the planners' actions are f_c in the robot's units, which ``RescaleAction`` would
        scale again); ``render_mode="rgb_array"`` for a video.
    planner : Planner
        Its ``plan`` and ``action`` must leave the env's state as they found it (they try
        plans with ``rollout``); one that moves it raises RuntimeError naming the method.
    seconds : float
        Simulated time; the episode stops early if the simulation diverges or the env's
        time limit truncates it.
    replan_every : int
        Env steps between replans (1: every control period).
    seed : int or None
        Seeds both ``env.reset`` and the planner. Both make their generator from the same
        integer as ``numpy.random.default_rng(seed)`` does, so their streams are the same
        bits: the planner's first draws are correlated with the reset's velocity noise (a
        uniform draw there, a normal one here). Kept so that recorded episodes and runs
        repeat; a planner that needs an independent stream can draw one from
        ``np.random.SeedSequence(seed).spawn``.
    progress : bool
        Show a tqdm progress bar.
    video : path, optional
        Write the episode as a video (needs an rgb_array env, and imageio, with
        imageio-ffmpeg for all but .gif: ``pip install 'softrom[video]'``); ``~`` is the home
        folder. The folder must exist and be writable, and the path must not be a folder:
        all checked before the episode. It is written under a temporary name and renamed
        into place, so that a failed write leaves an earlier video of that name as it was.
        A GIF keeps the frames whose delays (which GIF counts in 1/100 s) add up to the
        video's running time, so that it plays at the speed an .mp4 does.

    Returns
    -------
    EpisodeResult

    Raises
    ------
    KeyboardInterrupt
        Ctrl-C, with the steps recorded so far as its ``result`` (see :class:`EpisodeResult`).
    Exception
        A video that cannot be written after the episode (a full disk, say) raises the
        writer's error with the episode's :class:`EpisodeResult` as its ``result``: the
        episode is not lost to it.
    """
    if not isinstance(planner, Planner):
        raise TypeError(f"planner must be a controllers.Planner, got {type(planner).__name__}")
    if (
        isinstance(replan_every, bool)
        or not isinstance(replan_every, (int, np.integer))
        or (replan_every < 1)
    ):
        raise ValueError(f"replan_every must be a positive integer, got {replan_every!r}")
    if not (isinstance(seconds, (int, float, np.number)) and np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a positive number, got {seconds!r}")
    # named before env.reset, which would name it as gymnasium's seeding error (and a fresh
    # env's failed first reset leaves gymnasium's env checker failing the next episode's step)
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
    ):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
    if seed is not None:
        seed = int(seed)  # (gymnasium's reset refuses numpy integers, as np.arange gives them)
    if video is not None and getattr(env, "render_mode", None) != "rgb_array":
        raise ValueError("video needs an env made with render_mode='rgb_array'")
    if video is not None:
        # "~" is the home folder, as in a robot's mesh path and export_trajectory's path
        video = os.path.expanduser(os.fspath(video))
        _check_video_path(video)  # before the episode, not after it
        _imageio(Path(video).suffix)
    api = EnvAPI(env)  # (planner.reset refuses an action wrapper: check_physical_actions)
    steps = max(1, round(seconds / api.dt))
    try:
        env.reset(seed=seed)
        planner.reset(env, seed=seed)  # (a gait seed search can take seconds)
    except KeyboardInterrupt as interrupt:
        interrupt.result = None  # type: ignore[attr-defined]  # (nothing recorded yet)
        raise
    record: dict[str, list] = {k: [] for k in ("rewards", "orientation", "lateral", "effort",
                                               "actions")}  # fmt: skip
    com = [api.center_of_mass()]
    states = [api.get_state()]
    replan_steps: list[int] = []
    wall: list[float] = []
    records: list[dict[str, Any]] = []
    frames = [env.render()] if video is not None else []
    bar = _progress(steps, progress, planner.name)
    stop = "time"
    try:
        stop = _closed_loop(env, planner, api, steps, replan_every, record, com, states,
                            replan_steps, wall, records, frames, bar)  # fmt: skip
    except KeyboardInterrupt as interrupt:
        # what was recorded is the user's: handed back with the interrupt, not lost to it
        # (an attribute KeyboardInterrupt does not declare: the steps ride on the interrupt)
        interrupt.result = _result(  # type: ignore[attr-defined]
            planner, api, env, record, com, states, replan_steps, wall, records, "interrupted",
            replan_every,
        )  # fmt: skip
        if video is not None and len(frames) > 1:
            try:
                _write_video(video, frames, _fps(api.dt))  # the frames so far
            except (Exception, KeyboardInterrupt) as exc:  # (a second Ctrl-C skips it)
                # the interrupt, carrying the steps, is what the caller is owed; the video
                # is said, not raised in its place (which would drop the steps with it)
                warnings.warn(f"the video {video} of the steps so far was not written: "
                              f"{_one_line(exc)}", RuntimeWarning, stacklevel=2)  # fmt: skip
        raise
    finally:
        if bar is not None:
            bar.close()
    result = _result(planner, api, env, record, com, states, replan_steps, wall, records, stop,
                     replan_every)  # fmt: skip
    if video is not None:
        try:
            _write_video(video, frames, _fps(api.dt))
        except BaseException as exc:
            # the episode is the user's, and it ran: it rides on the error (a Ctrl-C in a
            # long video's encoding too), as an interrupt's steps ride on the interrupt
            exc.result = result  # type: ignore[attr-defined]
            raise
    return result


def _closed_loop(env, planner, api, steps, replan_every, record, com, states, replan_steps, wall,
                 records, frames, bar) -> str:  # fmt: skip
    """The episode's steps, appended to the lists given; returns why it stopped."""
    video = bool(frames)
    for t in range(steps):
        if t % replan_every == 0:
            start = time.perf_counter()
            planner.plan(env)
            wall.append(time.perf_counter() - start)
            _check_unchanged(planner, "plan", states[-1], api.get_state())
            replan_steps.append(t)
            records.append(dict(planner.last_))
        action = planner.action(env)
        _check_unchanged(planner, "action", states[-1], api.get_state())
        _, reward, terminated, truncated, info = env.step(action)
        for key, value in (("rewards", reward), ("orientation", info["orientation"]),
                           ("lateral", info["lateral"]), ("effort", info["effort"]),
                           ("actions", action)):  # fmt: skip
            record[key].append(value)
        com.append(np.asarray(info["com"], dtype=float))
        states.append(api.get_state())
        if video:
            frames.append(env.render())
        if bar is not None:
            bar.update(1)
            bar.set_postfix(distance=f"{info['distance']:+.3f} m", refresh=False)
        if terminated:
            return "diverged"
        if truncated and t < steps - 1:  # the limit ended it before the time asked for
            return "truncated by the time limit"
    return "time"


def _check_unchanged(planner: Planner, method: str, before: Any, after: Any) -> None:
    """Raise RuntimeError if ``planner.<method>`` moved the env off the state it was given.

    A planner of one's own that steps the env to try a plan (and forgets to put it back)
    would otherwise move the robot between the episode's steps, unrecorded: the distance
    would count motion no recorded action made."""
    if all(np.array_equal(getattr(before, k), getattr(after, k))
           for k in ("q", "qdot", "impulses")):  # fmt: skip
        return
    raise RuntimeError(
        f"{type(planner).__name__}.{method} changed the env's state: a planner must leave "
        "the env as it found it. Try plans with the env's rollout(state, controls) (batched, "
        "and the env is left as it was), not step(), which also counts against the env's "
        "time limit; or restore the state with set_state(state) before returning"
    )


def _result(planner, api, env, record, com, states, replan_steps, wall, records, stop,
            replan_every) -> EpisodeResult:  # fmt: skip
    # An interrupt can land between a step's appends: keep the steps recorded whole.
    n = min(min(len(v) for v in record.values()), len(com) - 1, len(states) - 1)
    replans = min(len(replan_steps), len(wall), len(records))
    com_arr = np.array(com[: n + 1])
    return EpisodeResult(
        planner=planner.name,
        dt=api.dt,
        body_length=float(env.get_wrapper_attr("body_length")),
        rewards=np.array(record["rewards"][:n], dtype=float),
        orientation=np.array(record["orientation"][:n], dtype=float),
        lateral=np.array(record["lateral"][:n], dtype=float),
        effort=np.array(record["effort"][:n], dtype=float),
        actions=np.array(record["actions"][:n], dtype=float).reshape(-1, api.control_dim),
        com=com_arr,
        distance=(com_arr - com_arr[0]) @ api.direction,
        states=states[: n + 1],
        replan_steps=np.array(replan_steps[:replans], dtype=int),
        replan_wall_s=np.array(wall[:replans]),
        replan_records=records[:replans],
        stop_reason=stop,
        seed_gait=getattr(planner, "seed_", {}).get("gait"),
        replan_every=int(replan_every),
    )


_VIDEO_SUFFIXES = {".mp4", ".m4v", ".mov", ".mkv", ".avi", ".webm", ".gif"}


def _check_video_path(video: str | os.PathLike) -> None:
    """Raise ValueError, naming ``video``, if a video cannot be written there.

    Checked before the episode: a video path that was a folder, or in a folder one cannot
    write in, failed only once the whole episode had run, with a traceback that dropped the
    episode's result.
    """
    path = Path(os.path.expanduser(os.fspath(video)))  # (as run_episode reads it)
    if path.suffix.lower() not in _VIDEO_SUFFIXES:
        raise ValueError(f"video {os.fspath(video)!r}: the file name must end in one of "
                         f"{', '.join(sorted(_VIDEO_SUFFIXES))}")  # fmt: skip
    if not path.parent.is_dir():
        raise ValueError(f"video {os.fspath(video)!r}: the folder {os.fspath(path.parent)!r} "
                         "does not exist")  # fmt: skip
    if path.is_dir():
        raise ValueError(f"video {os.fspath(video)!r} is a folder; give a file name, e.g. "
                         f"{os.fspath(path / ('episode' + path.suffix))!r}")  # fmt: skip
    if path.exists() and not os.access(path, os.W_OK):
        raise ValueError(f"video {os.fspath(video)!r} exists and is read-only")
    try:  # the video is written under a temporary name in the folder: try one
        _temporary_name(path).unlink()
    except OSError as exc:
        where = os.fspath(path.parent)
        raise ValueError(f"video {os.fspath(video)!r}: cannot write in the folder {where!r} "
                         f"({exc.strerror or exc})") from None  # fmt: skip


def _progress(total: int, enabled: bool, name: str):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=name, unit="step", leave=False)


def _imageio(suffix: str = ".gif"):
    """``imageio.v2``, once the packages a video of ``suffix`` needs are known importable.

    A container written through ffmpeg also needs imageio-ffmpeg, which imageio imports only
    when it opens the file: checked here, before the episode, not met after it.
    """
    try:
        import imageio.v2 as imageio
    except ImportError:
        raise ImportError(
            "writing a video needs imageio: pip install 'softrom[video]' (imageio and "
            "imageio-ffmpeg)"
        ) from None
    if suffix.lower() in _FFMPEG_SUFFIXES:
        try:
            importlib.import_module("imageio_ffmpeg")  # (it ships no type information)
        except ImportError:
            raise ImportError(
                f"writing a {suffix} video needs imageio-ffmpeg: pip install 'softrom[video]' "
                "(imageio and imageio-ffmpeg)"
            ) from None
    return imageio


# Containers written through ffmpeg: its default macro block of 16 would resize the renderer's
# 480 x 360 frames to 480 x 368 (with a warning); 2 keeps any even size as it is.
_FFMPEG_SUFFIXES = {".mp4", ".m4v", ".mov", ".mkv", ".avi", ".webm"}


def _fps(dt: float) -> int:
    """Frames per second of a video of env steps of ``dt`` s: one frame a step, at least 1
    (as the env's ``render_fps``: a control period over 2 s rounds to 0, which ffmpeg plays at
    its own rate and a GIF cannot be written at)."""
    return max(1, round(1.0 / dt))


def _gif_timing(count: int, fps: int) -> tuple[list[int], list[int]]:
    """Which of ``count`` frames a GIF shows at ``fps``, and for how long each (ms).

    GIF stores a frame's delay in 1/100 s, and a delay under 2/100 s is played by browsers as
    1/10 s: 1000 / 40 = 25 ms was stored as 20 ms, and a 40-fps episode played at 50 fps.
    Here frame i is due at i / fps, to the 1/100 s; each frame shown lasts until the next one
    kept is due, at least 2/100 s, so the delays add up to count / fps (to 1/100 s) and the
    GIF plays in real time, as the .mp4 of the frames does.
    """
    due = [round(i * 100 / fps) for i in range(count + 1)]  # (1/100 s)
    keep, delays = [], []
    i = 0
    while i < count:
        j = i + 1
        while j < count and due[j] - due[i] < 2:
            j += 1
        keep.append(i)
        delays.append(10 * max(2, due[j] - due[i]))
        i = j
    return keep, delays


def _write_video(path: str | os.PathLike, frames: list[np.ndarray], fps: int) -> None:
    """Write ``frames`` to ``path`` at ``fps``: under a temporary name in its folder (with its
    suffix, which picks the writer), fsynced, then renamed over ``path``, so that a failed or
    interrupted write leaves no truncated video and an earlier one of that name as it was."""
    path = Path(path)
    suffix = path.suffix.lower()
    imageio = _imageio(suffix)
    if suffix in _FFMPEG_SUFFIXES:
        timing: dict[str, Any] = {"fps": fps, "macro_block_size": 2}
    else:  # a GIF: imageio's pillow writer takes each frame's duration (ms); fps is deprecated
        keep, delays = _gif_timing(len(frames), fps)
        frames = [frames[i] for i in keep]
        timing = {"duration": delays}
    temp = _temporary_name(path)
    try:
        imageio.mimwrite(os.fspath(temp), frames, **timing)
        with open(temp, "rb+") as f:  # (the writer closed it; its data may not be on disk)
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def _temporary_name(path: Path) -> Path:
    """A new, hidden name beside ``path`` that keeps its suffix (ffmpeg picks the container
    by it), created empty so that it stays this call's."""
    return temporary_name(path.with_suffix(""), f".tmp{path.suffix}")


def _one_line(exc: BaseException) -> str:
    """The first line of an error's message (ffmpeg's add its command and output), or its
    type's name when it has none (a KeyboardInterrupt)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0] if lines else type(exc).__name__
