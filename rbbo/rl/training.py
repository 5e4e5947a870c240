"""One RL job: train (or resume) an algorithm on a basis, checkpointed and evaluated.

:func:`_train` trains in ``OUT/<algo>-<basis>/``, saving a checkpoint every ``every`` env
steps and at the end, evaluating each and logging it to ``progress.jsonl``; a re-run resumes
from the latest checkpoint (see the package's docstring for the folder's layout).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import pickle
import random
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..store import _append_line, _atomic_write, _fsync_dir, _make_dirs
from .algorithms import require_sb3
from .envs import _make_env
from .evaluation import evaluate_policy
from .progress import _read_progress, _wall_at_checkpoint
from .table import _row


def _save_durably(save: Callable[[Path], object], tmp: Path, path: Path) -> None:
    """Write ``path`` with ``save`` atomically and durably.

    Parameters
    ----------
    save : callable
        Writes its argument in place and unsynced (SB3's ``save``, ``save_replay_buffer``).
    tmp : Path
        The temporary name, in ``path``'s folder, that ``save`` writes to.
    path : Path
        The name the file is published under once it is complete and on disk.
    """
    save(tmp)
    # a rename can reach the disk before the data it names: without this fsync a power
    # loss could leave ``path`` empty or torn
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


@contextlib.contextmanager
def _generators_kept() -> Iterator[None]:
    """Leave the global generators (Python's, numpy's, torch's) as they were found.

    An evaluation between two training segments must not move the training's random streams,
    or the job would depend on whether (and how often) it was evaluated.
    """
    import torch

    # (numpy's legacy global generator: SB3's buffers draw their minibatches from it)
    kept = random.getstate(), np.random.get_state(), torch.get_rng_state()  # noqa: NPY002
    try:
        yield
    finally:
        random.setstate(kept[0])
        np.random.set_state(kept[1])  # noqa: NPY002
        torch.set_rng_state(kept[2])


def _training_state(model) -> bytes:
    """What a checkpoint's zip leaves out and a resume needs to go on as if never stopped.

    SB3's ``load`` seeds every generator from the job's seed again and resets the env: the
    generators (Python's, numpy's, torch's, the action space's) and the training env itself
    (its episode part-way: the simulator's state, the time limit's count, the Monitor's
    returns, the env's own generator) are pickled here, with the observation the next action
    is taken from.
    """
    import torch

    return pickle.dumps({
        "python": random.getstate(), "numpy": np.random.get_state(),  # noqa: NPY002
        "torch": torch.get_rng_state(),
        "action_space": model.action_space.np_random.bit_generator.state,
        "env": model.get_env(), "last_obs": model._last_obs,
        "episode_starts": model._last_episode_starts,
    })  # fmt: skip


def _restore_training_state(model, path: Path) -> bool:
    """Put back what :func:`_training_state` saved, after SB3's ``load``; False if unreadable.

    A state that cannot be read (written by another version of a library it pickles) leaves
    the model as ``load`` made it: the job goes on from the checkpoint's weights, as before
    these states were kept, with a warning that it no longer repeats the job run straight
    through.
    """
    import torch

    try:
        state = pickle.loads(path.read_bytes())
        model.set_env(state["env"], force_reset=False)
    except Exception as e:  # any unpickling failure: the weights still resume
        warnings.warn(f"{path} could not be read ({type(e).__name__}: {e}); training goes on "
                      "from the checkpoint's weights with the env reset and the generators "
                      "seeded again, so it will not repeat a job trained straight through",
                      stacklevel=2)  # fmt: skip
        return False
    model._last_obs = state["last_obs"]
    model._last_episode_starts = state["episode_starts"]
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])  # noqa: NPY002
    torch.set_rng_state(state["torch"])
    model.action_space.np_random.bit_generator.state = state["action_space"]
    return True


def _train(algo, env_id, name, basis, folder, env_kwargs, steps, every, evaluation, seed,
           progress) -> list[dict]:  # fmt: skip
    sb3 = require_sb3()
    from stable_baselines3.common.callbacks import BaseCallback

    cls = sb3.PPO if algo == "ppo" else sb3.SAC
    from softrom_gym.registration import control_period

    seeds, seconds, settle = evaluation
    # Training episodes as long as the evaluated ones (the registered 400 env steps are the
    # benchmarks' 10 s only at the default control period: 2 s at frame_skip=1).
    dt = control_period(env_id, **env_kwargs)
    episode = {} if dt is None else {"max_episode_steps": max(1, round(seconds / dt))}
    train_env = _make_env(env_id, basis, env_kwargs, True, **episode)
    dt = float(train_env.get_wrapper_attr("dt"))
    eval_env = _make_env(env_id, basis, env_kwargs, True,
                         max_episode_steps=max(1, round(seconds / dt)))  # fmt: skip
    frame_skip = int(train_env.get_wrapper_attr("frame_skip"))
    body = float(train_env.get_wrapper_attr("body_length"))
    ckpts, log = folder / "checkpoints", folder / "progress.jsonl"
    _make_dirs(ckpts)
    lines = _read_progress(log)
    done = sorted(int(p.stem[5:]) for p in ckpts.glob("step_*.zip") if p.stem[5:].isdigit())
    key = {"seeds": list(seeds), "seconds": seconds, "settle_time": settle}

    def rows_up_to(n: int) -> list[dict]:
        rows = {}
        for x in lines:
            if {k: x[k] for k in key} == key and x["steps"] <= n:
                rows[x["steps"]] = _row(env_id, algo, name, x["steps"] == n, x["steps"],
                                        x["physics_steps"], x["wall_s"], x["distance"],
                                        body)  # fmt: skip
        return [rows[k] for k in sorted(rows)]

    if lines and not done:
        # The log without the checkpoints it describes: a committed reproduction keeps logs,
        # not weights. A job its log shows finished is reported from the log; an unfinished
        # one trains again from the start, its old log kept beside, not mixed into the new.
        logged = max((x["steps"] for x in lines if {k: x[k] for k in key} == key), default=0)
        if logged >= steps:
            train_env.close()
            eval_env.close()
            return rows_up_to(logged)
        count = len(list(folder.glob("progress-*")))
        os.replace(log, folder / f"progress-without-checkpoints-{count}.jsonl")
        lines = []
    if done:
        model = cls.load(ckpts / f"step_{done[-1]}.zip", env=train_env, device="cpu")
        if algo == "sac" and (ckpts / f"step_{done[-1]}_replay.pkl").is_file():
            model.load_replay_buffer(ckpts / f"step_{done[-1]}_replay.pkl")
        state = ckpts / f"step_{done[-1]}_state.pkl"
        # (a checkpoint from before these states were kept resumes from its weights alone)
        if state.is_file() and _restore_training_state(model, state):
            train_env.close()  # the model trains on in the env it was stopped in
            train_env = model.get_env()
    elif algo == "ppo":
        # Checkpoints fall on rollout ends (after the update): one rollout per checkpoint
        # interval, rounded up to the minibatch (64), at most SB3's default 2048.
        n_steps = min(2048, 64 * math.ceil(min(steps, every) / 64))
        model = cls("MlpPolicy", train_env, n_steps=n_steps, batch_size=64, seed=seed,
                    device="cpu")  # fmt: skip
    else:  # a buffer as long as the run: the default 1e6 would make each checkpoint ~400 MB
        model = cls("MlpPolicy", train_env, buffer_size=max(steps, 1000), seed=seed,
                    learning_starts=min(100, steps // 4), device="cpu")  # fmt: skip
    wall_at = {x["steps"]: x["wall_s"] for x in lines}
    clock = {"offset": _wall_at_checkpoint(model.num_timesteps, wall_at, ckpts),
             "start": time.perf_counter(), "eval": 0.0, "saved": model.num_timesteps}  # fmt: skip
    wall_at.setdefault(model.num_timesteps, clock["offset"])  # its row, if it must be logged

    def checkpoint(m, save: bool = True) -> None:
        n = m.num_timesteps
        wall = clock["offset"] + time.perf_counter() - clock["start"] - clock["eval"]
        # written durably under temporary names and renamed, replay buffer first: a
        # step_<n>.zip that exists is complete and so is its replay buffer, whenever the run
        # was killed or the power lost
        if save and algo == "sac":
            _save_durably(m.save_replay_buffer, ckpts / "tmp_replay.pkl",
                          ckpts / f"step_{n}_replay.pkl")  # fmt: skip
        if save:
            _atomic_write(ckpts / f"step_{n}_state.pkl", _training_state(m))
            # its training wall time beside it, for a resume whose log lost the row
            _atomic_write(ckpts / f"step_{n}.json", json.dumps({"wall_s": wall}).encode())
            _save_durably(m.save, ckpts / "tmp_step.zip", ckpts / f"step_{n}.zip")
            clock["saved"] = n
            # only the latest is ever resumed; the previous one goes only now that the new
            # checkpoint is on disk, else a power loss could leave the previous zip without
            # its buffer (and SAC would resume with an empty one)
            for old in [*ckpts.glob("step_*_replay.pkl"), *ckpts.glob("step_*_state.pkl")]:
                if old.name not in (f"step_{n}_replay.pkl", f"step_{n}_state.pkl"):
                    old.unlink()
        t0 = time.perf_counter()
        with _generators_kept():
            dist = evaluate_policy(m, eval_env, seeds, seconds, settle)
        clock["eval"] += time.perf_counter() - t0
        wall = wall if save else wall_at.get(n, wall)
        line = {"steps": n, "physics_steps": n * frame_skip, "wall_s": wall, **key,
                "distance": dist}  # fmt: skip
        # fsynced: a resume evaluates again only the latest checkpoint, so a row lost to a
        # power loss would be lost for good
        _append_line(log, json.dumps(line))
        lines.append(line)

    if done and not any(x["steps"] == model.num_timesteps and {k: x[k] for k in key} == key
                        for x in lines):  # fmt: skip
        # killed between saving this checkpoint and logging its evaluation (or mid-write):
        # evaluated now, before training on from it, so that its row is not lost
        checkpoint(model, save=False)

    class Checkpoints(BaseCallback):
        # At a rollout's start the previous update is done, so a resume from here loses
        # nothing (for SAC, with train_freq 1, that is every step).
        def _on_rollout_start(self) -> None:
            if self.model.num_timesteps // every > clock["saved"] // every:
                checkpoint(self.model)

        def _on_step(self) -> bool:
            if bar is not None:
                bar.update(self.num_timesteps - bar.n)
            return True

    bar, trained = None, model.num_timesteps < steps
    if trained:
        # SB3's own training log (losses, entropy, fps) kept beside ours, one file per
        # training segment so that a resume never overwrites one; left to itself, SB3 would
        # make an empty folder in the system's temporary directory on every learn().
        from stable_baselines3.common.logger import configure

        segment = folder / "sb3" / f"from_step_{model.num_timesteps}"
        tries = 1
        while segment.exists():  # a segment killed before its first checkpoint, run again
            tries += 1
            segment = segment.with_name(f"from_step_{model.num_timesteps}-{tries}")
        model.set_logger(configure(str(segment), ["csv"]))
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=steps, initial=model.num_timesteps, desc=f"{algo} {name}",
                       unit="step", file=sys.stderr, dynamic_ncols=True)  # fmt: skip
        try:
            model.learn(steps - model.num_timesteps, callback=Checkpoints(),
                        reset_num_timesteps=not done)  # fmt: skip
        finally:  # (an interrupt included: SB3's log file is closed, not left to the collector)
            if bar is not None:
                bar.close()
            model.logger.close()
    n = model.num_timesteps
    if trained:
        checkpoint(model)
    elif not any(x["steps"] == n and {k: x[k] for k in key} == key for x in lines):
        checkpoint(model, save=False)  # evaluated before with other seeds or seconds
    if trained or not (folder / "final.zip").is_file():
        # SB3 writes in place: a kill mid-save would leave a torn final.zip that the
        # is_file() above then keeps for good
        _save_durably(model.save, folder / "tmp_final.zip", folder / "final.zip")
    train_env.close()
    eval_env.close()
    return rows_up_to(n)
