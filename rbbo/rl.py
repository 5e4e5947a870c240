"""RL baselines: Stable-Baselines3 PPO and SAC in the same control spaces B_c as the MPC.

Each (algorithm, basis) trains in ``OUT/<algo>-<basis>/``: ``checkpoints/step_<n>.zip`` every
``checkpoint_every`` env steps and at the end, with ``step_<n>.json`` (its training wall time)
beside it (SAC also keeps the latest replay buffer, so a resume continues the same run),
``final.zip``, ``run.json`` (what was trained: a re-run with
the same OUT continues from the latest checkpoint and refuses another env, basis or seed; a
larger ``steps`` trains the same run further, SAC keeping the replay-buffer size it was
created with, the oldest transitions replaced) and
``progress.jsonl`` (append-only: per checkpoint the env steps, the training wall time and the
evaluation), and SB3's own training log, ``sb3/from_step_<n>/progress.csv`` per training
segment (losses, entropy, fps; a resume starts a new one). Every checkpoint is evaluated, so
the table shows distance against simulator steps spent. The MPC planner
(``controllers.default_planner(env_id, "mppi")``) runs beside it on the same bases, seeds and
seconds; its results are cached in ``OUT/mppi-<basis>/``.

Evaluation: the deterministic policy, one episode of ``seconds`` from ``env.reset(seed=s)``
per seed; the score is the distance along the task direction from ``settle_time`` to the end
(m, and body lengths), mean ± 95 % t-interval over the seeds. Cost: for RL the env steps
trained and the physics steps (env steps x frame_skip) and training wall time (evaluation
excluded); for MPC, per episode, the physics steps of every planning rollout plus the
executed ones, and the episode's wall time.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from .intervals import confidence_interval

__all__ = ["ALGOS", "DEFAULT_STEPS", "evaluate_policy", "format_table", "parse_steps",
           "resolve_bases", "run_baselines", "steps_per_algo", "t_interval"]  # fmt: skip

ALGOS = ("ppo", "sac")
DEFAULT_STEPS = 20_000  # a few minutes per algorithm and basis on a 2-core laptop
EVAL_SEED0 = 1000  # evaluation seeds 1000, 1001, ...: apart from the training seed


def steps_per_algo(steps: int | dict[str, int], algos: tuple[str, ...]) -> dict[str, int]:
    """Env steps of each algorithm: one number for all, or a mapping (PPO usually wants many
    more samples than SAC, whose gradient steps cost more per sample)."""
    per = dict.fromkeys(algos, steps) if not isinstance(steps, dict) else dict(steps)
    missing, extra = set(algos) - set(per), set(per) - set(algos)
    if missing or extra:
        raise ValueError(f"steps per algorithm must name exactly {', '.join(algos)}; got "
                         f"{', '.join(sorted(per)) or 'none'}")  # fmt: skip
    for algo, n in per.items():
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"steps of {algo} must be a positive integer, got {n!r}")
    return per


def parse_steps(text: str) -> int | dict[str, int]:
    """``"20000"`` (every algorithm) or ``"ppo=500000,sac=100000"``."""
    text = text.strip()
    try:
        if "=" not in text:
            return int(text)
        pairs = [item.split("=", 1) for item in text.split(",") if item.strip()]
        per = {k.strip().lower(): int(v) for k, v in pairs}
    except ValueError:
        raise ValueError(f"steps must be N or ALGO=N[,ALGO=N], got {text!r}") from None
    if len(per) < len(pairs):  # (the last would win silently)
        raise ValueError(f"steps name an algorithm twice: {text!r}")
    return per


_COLUMNS = ["env", "method", "basis", "final", "env_steps", "physics_steps", "wall_s", "seeds",
            "distance_m", "ci95_m", "distance_bl", "ci95_bl"]  # fmt: skip


def require_sb3():
    """The ``stable_baselines3`` module, or ImportError saying how to install it."""
    try:
        import stable_baselines3
    except ImportError:
        raise ImportError(
            "the RL baselines need Stable-Baselines3: pip install 'softrom[rl]'"
        ) from None
    return stable_baselines3


def resolve_bases(
    specs: list[str],
    env_id: str,
    run_dir: str | Path | None = None,
    sim_dim: int | None = None,
    control_dim: int | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Control bases by name: ``identity`` (first C columns of eye(M)), ``best`` (the
    best_basis.npy of RBBO run ``run_dir``) or a path to an (M, C) ``.npy``.

    M and C of ``identity`` are the run's when ``run_dir`` is given, else the first ``.npy``'s,
    else ``sim_dim`` and ``control_dim`` (``--sim-dim``, ``--control-dim``; default 20 and
    3). A ``sim_dim`` or ``control_dim`` given beside a run or a ``.npy`` of another M or C is
    refused: their bases belong to those. Returns the bases and the run's ``env_kwargs`` ({}
    without a run). Raises ValueError (RunDirectoryError for a bad run directory) naming the
    problem.
    """
    from .store import RunDirectoryError, RunStore

    specs = [s.strip() for s in specs]
    dims = (20 if sim_dim is None else sim_dim, 3 if control_dim is None else control_dim)
    env_kwargs, store = {}, None
    if run_dir is not None:
        store = RunStore.open(run_dir, repair=False)
        settings, objective = store.config.get("rbbo") or {}, store.config.get("objective") or {}
        try:
            dims = (int(settings["sim_dim"]), int(settings["control_dim"]))
        except (KeyError, TypeError, ValueError):
            raise RunDirectoryError(f"{run_dir}/config.json has no sim_dim/control_dim") from None
        if sim_dim is not None and sim_dim != dims[0]:
            raise ValueError(f"--sim-dim {sim_dim} differs from run {run_dir}'s sim_dim "
                             f"{dims[0]}, the M its B_c was found in (leave --sim-dim out: "
                             "the run's is used)")  # fmt: skip
        if control_dim is not None and control_dim != dims[1]:
            raise ValueError(f"--control-dim {control_dim} differs from run {run_dir}'s "
                             f"control_dim {dims[1]}, the C of its B_c (leave --control-dim "
                             "out: the run's is used)")  # fmt: skip
        if objective.get("kind") != "env":
            raise ValueError(f"run {run_dir} optimised a {objective.get('kind') or 'non-env'} "
                             "objective, not an env: its bases belong to no robot")  # fmt: skip
        if objective.get("kind") == "env":
            if objective.get("env_id") != env_id:
                raise ValueError(f"run {run_dir} optimised {objective.get('env_id')}, not {env_id}")
            env_kwargs = dict(objective.get("env_kwargs") or {})
    bases: dict[str, np.ndarray] = {}
    for spec in specs:
        if spec == "best":
            if store is None:
                raise ValueError("--control-basis best needs --run DIR (an RBBO run directory)")
            bases["best"] = store.best_basis()
            _expect_run_space(store, env_id, env_kwargs, dims)
        elif spec.endswith(".npy"):
            try:
                b = np.load(spec, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise ValueError(f"cannot read control basis {spec}: {exc}") from None
            if b.ndim != 2 or b.shape[0] < b.shape[1]:
                raise ValueError(f"control basis {spec} has shape {b.shape}, expected (M, C)")
            if sim_dim is not None and b.shape[0] != sim_dim:
                raise ValueError(f"control basis {spec} has M = {b.shape[0]} rows, not "
                                 f"--sim-dim {sim_dim}")  # fmt: skip
            if control_dim is not None and b.shape[1] != control_dim:
                raise ValueError(f"control basis {spec} has C = {b.shape[1]} columns, not "
                                 f"--control-dim {control_dim}")  # fmt: skip
            if not np.all(np.isfinite(b)):
                raise ValueError(f"control basis {spec} contains non-finite values")
            sv = np.linalg.svd(b, compute_uv=False)
            if not sv[-1] > 1e-10 * sv[0]:  # as the env's orthonormalize=True (before any work)
                raise ValueError(
                    f"control basis {spec} is rank-deficient (singular values "
                    f"{np.array2string(sv, precision=3)}): its C columns must span C directions"
                )
            if Path(spec).stem in {*bases, *specs}:
                raise ValueError(f"two control bases are named {Path(spec).stem!r}")
            bases[Path(spec).stem] = b
            dims = b.shape if store is None and len(bases) == 1 else dims
        elif spec != "identity":
            raise ValueError(f"unknown control basis {spec!r}; use identity, best or PATH.npy")
    if "identity" in specs:
        if dims[0] < dims[1]:  # (only --sim-dim / --control-dim given so can be)
            raise ValueError(f"--sim-dim {dims[0]} is below C = {dims[1]}, the identity "
                             "basis's columns")  # fmt: skip
        bases = {"identity": np.eye(dims[0])[:, : dims[1]], **bases}
    return bases, env_kwargs


def _expect_run_space(store, env_id: str, env_kwargs: dict, dims: tuple[int, int]) -> None:
    """Refuse a run's B_c when the env now builds another simulation space than the run's."""
    from .objective import EnvObjective

    recorded = (store.config.get("objective") or {}).get("simulation_space")
    if recorded is not None:
        objective = EnvObjective(env_id, dims[0], dims[1], env_kwargs=env_kwargs)
        objective.expect_simulation_space(recorded)


def t_interval(values) -> tuple[float, float]:
    """Mean and half-width of the 95 % t-interval (nan with fewer than two values)."""
    return confidence_interval(values)


def evaluate_policy(model, env, seeds, seconds: float, settle_time: float) -> list[float]:
    """Distance (m) from ``settle_time`` to ``seconds`` of the deterministic policy, per seed.

    ``model`` has SB3's ``predict``; ``env`` is the [-1, 1]-rescaled env it acts in. An episode
    that diverges keeps its distance so far (the robot stops where it was): one that ends
    before ``settle_time`` scores 0, as R of an MPC episode does (no reward after the end).
    """
    dt = float(env.get_wrapper_attr("dt"))
    steps, settle = max(1, round(seconds / dt)), round(settle_time / dt)
    out = []
    for s in seeds:
        obs, info = env.reset(seed=int(s))
        start = info["distance"] if settle == 0 else math.nan
        for t in range(1, steps + 1):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            start = info["distance"] if t == settle else start
            if terminated or truncated:
                break
        if math.isnan(start):  # ended before the settle time: no distance after it
            start = info["distance"]
        out.append(float(info["distance"] - start))
    return out


def _torch_threads(n: int) -> int:
    """Set torch's intra-op threads, returning the old count. These MLPs are too small to
    gain from threads, and on shared cores the threads' spin-waits made SAC 4x slower."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    return old


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
    return gym.wrappers.RescaleAction(env, -one, one)


def _claim(folder: Path, meta: dict) -> None:
    """Refuse to continue a folder that trained something else."""
    from .store import RunDirectoryError

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "run.json"
    text = json.dumps(meta)  # floats round-trip exactly: the basis compares bit for bit
    if not path.is_file():
        path.write_text(text + "\n")
    elif json.loads(path.read_text()) != json.loads(text):
        raise RunDirectoryError(f"{folder} holds another run (env, basis or seed); choose "
                                "another --out")  # fmt: skip


def _read_progress(log: Path, mend: bool = True) -> list[dict]:
    """The rows of a training job's progress.jsonl. A last line torn by a kill mid-write is
    skipped, and with ``mend`` (when the job resumes) dropped from the file, since the next
    row would otherwise be glued onto it; its evaluation is made again with the checkpoint
    it belongs to, or was of one never saved."""
    if not log.exists():
        return []
    text = log.read_text(encoding="utf-8")
    rows, torn = [], False
    for line in text.splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            torn = torn or bool(line.strip())
    if mend and (torn or (text and not text.endswith("\n"))):
        tmp = log.with_name(log.name + ".tmp")
        tmp.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
        os.replace(tmp, log)
    return rows


def _atomic_json(path: Path, data: dict) -> None:
    tmp = path.with_name(f"tmp_{path.name}")
    tmp.write_text(json.dumps(data), encoding="utf-8")
    os.replace(tmp, path)


def _wall_at_checkpoint(n: int, logged: dict[int, float], ckpts: Path) -> float:
    """Training wall time at checkpoint ``n`` (0 for a fresh start): as logged; else, when the
    job was killed before logging it, as saved beside the checkpoint; else (a checkpoint saved
    before that was kept) the last logged time before it, which is a lower bound."""
    if n in logged:
        return logged[n]
    try:
        return float(json.loads((ckpts / f"step_{n}.json").read_text())["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return max((w for steps, w in logged.items() if steps < n), default=0.0)


def _row(env_id, method, basis, final, env_steps, physics, wall, distances, body) -> dict:
    mean, half = t_interval(distances)
    return {"env": env_id, "method": method, "basis": basis, "final": final,
            "env_steps": env_steps, "physics_steps": physics, "wall_s": wall,
            "seeds": len(distances), "distance_m": mean, "ci95_m": half,
            "distance_bl": mean / body, "ci95_bl": half / body}  # fmt: skip


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
    ckpts.mkdir(parents=True, exist_ok=True)
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
        # written under temporary names and renamed, replay buffer first: a step_<n>.zip
        # that exists is complete and so is its replay buffer, whenever the run was killed
        if save and algo == "sac":
            m.save_replay_buffer(ckpts / "tmp_replay.pkl")
            os.replace(ckpts / "tmp_replay.pkl", ckpts / f"step_{n}_replay.pkl")
        if save:
            # its training wall time beside it, for a resume whose log lost the row
            _atomic_json(ckpts / f"step_{n}.json", {"wall_s": wall})
            m.save(ckpts / "tmp_step.zip")
            os.replace(ckpts / "tmp_step.zip", ckpts / f"step_{n}.zip")
            clock["saved"] = n
            for old in ckpts.glob("step_*_replay.pkl"):  # only the latest is ever resumed
                if old.name != f"step_{n}_replay.pkl":
                    old.unlink()
        t0 = time.perf_counter()
        dist = evaluate_policy(m, eval_env, seeds, seconds, settle)
        clock["eval"] += time.perf_counter() - t0
        wall = wall if save else wall_at.get(n, wall)
        line = {"steps": n, "physics_steps": n * frame_skip, "wall_s": wall, **key,
                "distance": dist}  # fmt: skip
        with open(log, "a", encoding="utf-8") as f:
            f.write(json.dumps(line) + "\n")
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
        model.learn(steps - model.num_timesteps, callback=Checkpoints(),
                    reset_num_timesteps=not done)  # fmt: skip
        if bar is not None:
            bar.close()
        model.logger.close()
    n = model.num_timesteps
    if trained:
        checkpoint(model)
    elif not any(x["steps"] == n and {k: x[k] for k in key} == key for x in lines):
        checkpoint(model, save=False)  # evaluated before with other seeds or seconds
    if trained or not (folder / "final.zip").is_file():
        model.save(folder / "final.zip")
    train_env.close()
    eval_env.close()
    return rows_up_to(n)


def _mpc(env_id, name, basis, folder, env_kwargs, evaluation, progress,
         threads: int | None = None, planner_kwargs: dict | None = None) -> dict:  # fmt: skip
    import gymnasium as gym

    import controllers
    from softrom_gym.registration import control_period

    from .objective import planner_record

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
    cache = folder / "episodes.json"
    if cache.is_file():
        old = json.loads(cache.read_text())
        if old["meta"] == meta:  # (rows from before the planner was keyed are made again)
            return old["row"]

    class CountRollouts(gym.Wrapper):
        """Counts the physics steps of the planner's rollouts (it finds rollout here)."""

        physics_steps = 0

        def rollout(self, state, controls, *args, **kwargs):
            b, h = np.shape(controls)[:2]
            self.physics_steps += b * h * self.env.get_wrapper_attr("frame_skip")
            return self.env.get_wrapper_attr("rollout")(state, controls, *args, **kwargs)

    from .objective import NO_TIME_LIMIT

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
    folder.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({"meta": meta, "row": row}) + "\n")
    return row


def run_baselines(
    env_id: str,
    bases: dict[str, np.ndarray],
    out: str | Path,
    *,
    algos: tuple[str, ...] = ALGOS,
    steps: int | dict[str, int] = DEFAULT_STEPS,
    checkpoint_every: int | None = None,
    eval_seeds: int = 5,
    seconds: float = 10.0,
    settle_time: float = 2.0,
    seed: int = 0,
    mpc: bool = True,
    env_kwargs: dict | None = None,
    progress: bool = True,
    workers: int = 1,
    planner_kwargs: dict | None = None,
) -> list[dict]:
    """Train (or resume) each algorithm on each basis, run the MPC beside them, write
    ``OUT/baselines.csv`` and ``OUT/baselines.md``.

    Parameters
    ----------
    env_id : str
        A registered id (``softrom_gym/CrossSwim-v0``).
    bases : dict of str to (M, C) arrays
        Control bases by name (see :func:`resolve_bases`).
    out : path
        Output directory; re-running with the same one continues from its checkpoints.
    algos : tuple of str
        Among ``"ppo"``, ``"sac"``.
    steps : int or dict of str to int
        Env steps to train each (PPO rounds up to whole rollouts), or per algorithm
        (``{"ppo": 500_000, "sac": 100_000}``).
    checkpoint_every : int or None
        Env steps between checkpoints (default: a fifth of each algorithm's ``steps``).
    eval_seeds, seconds, settle_time : int, float, float
        Evaluation episodes (seeds 1000, 1001, ...), their length and the settle time, s.
    seed : int
        Training seed.
    mpc : bool
        Also run ``controllers.default_planner(env_id, "mppi")`` on each basis.
    env_kwargs : dict, optional
        Extra ``gym.make`` arguments (an RBBO run's).
    progress : bool
        tqdm bars on stderr (with ``workers`` > 1 a line per finished job instead, always).
    planner_kwargs : dict, optional
        MPPI setting overrides for the MPC rows (an RBBO run's ``--mpc``, so that the MPC
        beside the RL rows is the planner the run's R* was measured with).
    workers : int
        Jobs (one per algorithm and basis, one per MPC basis) run at once, each in its own
        process with one thread; the rows, files and results are those of ``workers = 1``
        (each job is seeded and writes only its own folder), and each job's wall time is
        its own (on a machine with at least ``workers`` free cores it is comparable).

    Returns
    -------
    list of dict
        One row per RL checkpoint and one per MPC basis (keys: ``_COLUMNS``).
    """
    unknown = [a for a in algos if a not in ALGOS]
    if unknown:
        raise ValueError(f"unknown algorithm {unknown[0]!r}; valid: {', '.join(ALGOS)}")
    if not 0 <= settle_time < seconds:
        raise ValueError(f"settle time {settle_time} s must lie in [0, {seconds}) s")
    if algos:
        require_sb3()
    per_algo = steps_per_algo(steps, tuple(algos))
    out, env_kwargs = Path(out), dict(env_kwargs or {})
    evaluation = (tuple(range(EVAL_SEED0, EVAL_SEED0 + eval_seeds)), float(seconds),
                  float(settle_time))  # fmt: skip
    for name, basis in bases.items():  # all refusals before any work
        for algo in algos:
            _claim(out / f"{algo}-{name}", {"env_id": env_id, "env_kwargs": env_kwargs,
                   "algo": algo, "seed": seed, "basis": np.asarray(basis).tolist()})  # fmt: skip
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    jobs: list[tuple[str, tuple]] = []
    for name, basis in bases.items():
        if mpc:
            mpc_job = functools.partial(_mpc, planner_kwargs=dict(planner_kwargs or {}))
            jobs.append((f"mppi {name}", (mpc_job, env_id, name, basis, out / f"mppi-{name}",
                                          env_kwargs, evaluation)))  # fmt: skip
        for algo in algos:
            n = per_algo[algo]
            jobs.append((f"{algo} {name}", (_train, algo, env_id, name, basis,
                                            out / f"{algo}-{name}", env_kwargs, n,
                                            checkpoint_every or max(1, n // 5), evaluation,
                                            seed)))  # fmt: skip
    rows: list[dict] = []
    for result in _run_jobs(jobs, workers, progress):
        rows += result if isinstance(result, list) else [result]
    with open(out / "baselines.csv", "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    (out / "baselines.md").write_text(format_table(rows, markdown=True) + "\n")
    return rows


def _job(call: tuple, progress: bool, threads: int | None):
    """Run one job (``_mpc`` or ``_train`` and its arguments) with one torch thread."""
    fn, *args = call
    old = _torch_threads(1)
    try:
        is_mpc = getattr(fn, "func", fn) is _mpc
        extra = {"threads": threads} if is_mpc and threads is not None else {}
        return fn(*args, progress, **extra)
    finally:
        _torch_threads(old)


def _run_jobs(jobs: list[tuple[str, tuple]], workers: int, progress: bool) -> list:
    """The jobs' results in job order: in this process, or ``workers`` at a time in spawned
    processes (a failed job does not stop the others; the first failure is raised after
    all have ended, and the finished jobs' folders keep their work)."""
    if workers == 1 or len(jobs) <= 1:
        return [_job(call, progress, None) for _, call in jobs]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    results: dict[int, Any] = {}
    errors: list[tuple[str, BaseException]] = []
    ctx = mp.get_context("spawn")
    before = set(mp.active_children())
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx)
    try:
        futures = {pool.submit(_job, call, False, 1): (i, label)
                   for i, (label, call) in enumerate(jobs)}  # fmt: skip
        for future in as_completed(futures):
            i, label = futures[future]
            try:
                results[i] = future.result()
            except Exception as exc:  # reported below, after the other jobs have finished
                errors.append((label, exc))
                print(f"[baselines] {label} failed: {exc}", file=sys.stderr, flush=True)
                continue
            print(f"[baselines] {label} done ({len(results)}/{len(jobs)})", file=sys.stderr,
                  flush=True)  # fmt: skip
    except BaseException:
        # An interrupt (Ctrl-C, SIGTERM): the jobs resume from their checkpoints, so stop the
        # workers now instead of waiting out training runs of an hour.
        pool.shutdown(wait=False, cancel_futures=True)
        for child in set(mp.active_children()) - before:
            child.terminate()
        raise
    pool.shutdown()
    if errors:
        label, error = errors[0]
        raise RuntimeError(f"baseline job {label!r} failed: {error}") from error
    return [results[i] for i in range(len(jobs))]


def _reached(rows: list[dict]) -> list[str]:
    """Per RL method and basis: the first checkpoint at which it matched the MPC."""
    lines = []
    for ref in (r for r in rows if r["method"] == "mppi"):
        for algo in dict.fromkeys(r["method"] for r in rows if r["method"] != "mppi"):
            mine = [r for r in rows if r["method"] == algo and r["basis"] == ref["basis"]]
            hit = next((r for r in mine if r["distance_m"] >= ref["distance_m"]), None)
            goal = f"the MPC's {ref['distance_m']:.3f} m"
            lines.append(f"{algo} ({ref['basis']}) reached {goal} at {hit['env_steps']} env "
                         "steps" if hit else f"{algo} ({ref['basis']}) did not reach {goal} "
                         f"within {max(r['env_steps'] for r in mine)} env steps")  # fmt: skip
    return lines


def format_table(rows: list[dict], *, markdown: bool = False) -> str:
    """The baselines as a table (plain text: final rows only; markdown: every checkpoint),
    followed by when each RL method first reached the MPC's distance."""

    def pm(mean, half, spec):
        sd = spec.lstrip("+")
        return f"{mean:{spec}} ± {half:{sd}}" if math.isfinite(half) else f"{mean:{spec}}"

    header = ["env", "method", "basis", "env steps", "physics steps", "wall time",
              "distance (m)", "distance (BL)"]  # fmt: skip
    table = [header]
    for r in rows if markdown else [r for r in rows if r["final"]]:
        table.append([r["env"].split("/")[-1], r["method"], r["basis"],
                      str(r["env_steps"]) if r["method"] != "mppi" else "-",
                      f"{round(r['physics_steps']):,}", f"{r['wall_s']:.1f} s",
                      pm(r["distance_m"], r["ci95_m"], "+.3f"),
                      pm(r["distance_bl"], r["ci95_bl"], "+.2f")])  # fmt: skip
    notes = ["RL: training cost; MPC: physics steps (planning + executed) and wall time per "
             "episode", *_reached(rows)]  # fmt: skip
    if markdown:
        text = ["| " + " | ".join(row) + " |" for row in table]
        text.insert(1, "|" + "---|" * len(header))
        return "\n".join(text + [""] + [f"- {n}" for n in notes])
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    text = ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in table]
    text.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(text + notes)
