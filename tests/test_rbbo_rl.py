"""``rbbo baselines``: PPO and SAC beside the MPC, checkpointed, resumable, evaluated."""

import csv
import itertools
import json
import math
import os
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from rbbo import rl
from rbbo.cli import main
from rbbo.objective import EnvObjective
from rbbo.store import RunStore

ENV = "softrom_gym/CrossSwim-v0"  # the cheapest env
SMALL = ["--steps", "256", "--checkpoint-every", "128", "--eval-seeds", "2", "--seconds", "3",
         "--settle-time", "1", "--no-progress"]  # fmt: skip


def _lines(path):
    return [json.loads(x) for x in path.read_text().splitlines()]


def _watch_writes(monkeypatch):
    """Record each os.fsync, as ``("file", (inode, size))`` or ``("dir", path, names)``, and
    each os.replace, as ``("replace", name, (inode, size) of the source)``, in order: a power
    loss keeps only what was fsynced, and that is not observable without pulling the power."""
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            path = os.readlink(f"/proc/self/fd/{fd}")
            events.append(("dir", path, set(os.listdir(path))))
        else:
            events.append(("file", (st.st_ino, st.st_size)))
        real_fsync(fd)

    def replace(src, dst, **k):
        st = os.stat(src)
        events.append(("replace", Path(dst).name, (st.st_ino, st.st_size)))
        real_replace(src, dst, **k)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return events


def _assert_published_durably(events, folder, name):
    """``folder/name`` was written under another name, fsynced, renamed, and ``folder``
    fsynced after the rename: a kill leaves the old file or the new, and so does a power
    loss."""
    renames = [i for i, e in enumerate(events) if e[:2] == ("replace", name)]
    assert renames, f"{name} was not written under a temporary name and renamed"
    for i in renames:
        assert ("file", events[i][2]) in events[:i], f"{name} was not fsynced before its rename"
        later = [e for e in events[i + 1 :] if e[0] != "file"]
        assert later and later[0][:2] == ("dir", os.path.realpath(folder)), (
            f"{folder} was not fsynced after {name} was renamed into it"
        )


needs_proc = pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc")


def test_train_evaluate_and_resume(tmp_path, capsys, monkeypatch):
    import tempfile

    import stable_baselines3 as sb3

    out = tmp_path / "bl"
    scratch = tmp_path / "tmp"  # SB3 left to itself makes a folder here per learn()
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    assert main(["baselines", "CrossSwim-v0", "--algo", "ppo,sac", "--out", str(out), *SMALL]) == 0
    table = capsys.readouterr().out
    assert "mppi" in table and "ppo" in table and "sac" in table and "the MPC's" in table
    with open(out / "baselines.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    steps = {(r["method"], int(r["env_steps"])) for r in rows}
    assert steps == {("mppi", 0), ("ppo", 128), ("ppo", 256), ("sac", 128), ("sac", 256)}
    assert all(math.isfinite(float(r["distance_m"])) for r in rows)
    assert (out / "baselines.md").read_text().startswith("| env | method |")
    for algo in ("ppo", "sac"):
        folder = out / f"{algo}-identity"
        assert {p.name for p in (folder / "checkpoints").glob("step_*.zip")} == {
            "step_128.zip", "step_256.zip"}  # fmt: skip
        assert (folder / "final.zip").is_file()
        progress = _lines(folder / "progress.jsonl")
        assert [x["steps"] for x in progress] == [128, 256]
        assert progress[1]["physics_steps"] == 256 * 5 and len(progress[1]["distance"]) == 2
    assert sorted(p.name for p in (out / "sac-identity/checkpoints").glob("*.pkl")) == [
        "step_256_replay.pkl", "step_256_state.pkl"]  # fmt: skip
    # SB3's own log, in the run's folder and nowhere else (SAC writes one every 4 episodes:
    # none in these 256 steps)
    with open(out / "ppo-identity/sb3/from_step_0/progress.csv", newline="") as f:
        assert [int(r["time/total_timesteps"]) for r in csv.DictReader(f)] == [128, 256]
    assert (out / "sac-identity/sb3/from_step_0/progress.csv").is_file()
    assert not list(scratch.glob("SB3-*"))

    # Same command again: nothing is trained (or planned) again, the table is the same.
    def refuse(*args, **kwargs):
        raise AssertionError("retrained a finished run")

    monkeypatch.setattr(sb3.PPO, "learn", refuse)
    monkeypatch.setattr(sb3.SAC, "learn", refuse)
    monkeypatch.setattr("controllers.run_episode", refuse)
    assert main(["baselines", ENV, "--algo", "ppo,sac", "--out", str(out), *SMALL]) == 0
    assert capsys.readouterr().out == table
    assert len(_lines(out / "ppo-identity/progress.jsonl")) == 2
    assert sb3.PPO.load(out / "ppo-identity/final.zip").num_timesteps == 256
    monkeypatch.undo()

    # More steps: continues from the latest checkpoint, not from scratch.
    more = [*SMALL, "--no-mpc"]
    more[1] = "ppo=384"  # the per-algorithm form
    assert main(["baselines", ENV, "--algo", "ppo", "--out", str(out), *more]) == 0
    progress = _lines(out / "ppo-identity/progress.jsonl")
    assert [x["steps"] for x in progress] == [128, 256, 384]
    assert progress[2]["wall_s"] > progress[1]["wall_s"]
    model = sb3.PPO.load(out / "ppo-identity/final.zip")
    assert model.num_timesteps == 384 and model._n_updates == 3 * model.n_epochs
    assert sorted(p.name for p in (out / "ppo-identity/sb3").iterdir()) == [
        "from_step_0", "from_step_256"]  # fmt: skip
    capsys.readouterr()
    # ... and refuses another seed in the same OUT
    assert main(["baselines", ENV, "--algo", "ppo", "--out", str(out), *more, "--seed", "1"]) == 2
    assert "holds another run" in capsys.readouterr().err


def test_a_log_without_its_weights_reports_or_restarts(tmp_path, capsys, monkeypatch):
    """A committed reproduction keeps progress.jsonl, not the weights: a finished job is
    reported from its log without training again; an unfinished one starts over, its old log
    kept beside the new one."""
    import shutil

    import stable_baselines3 as sb3

    out = tmp_path / "bl"
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]
    assert main(args) == 0
    table = capsys.readouterr().out
    folder = out / "ppo-identity"
    first = _lines(folder / "progress.jsonl")
    shutil.rmtree(folder / "checkpoints")
    (folder / "final.zip").unlink()

    def refuse(*a, **k):
        raise AssertionError("retrained a finished run")

    monkeypatch.setattr(sb3.PPO, "learn", refuse)
    assert main(args) == 0
    assert capsys.readouterr().out == table
    monkeypatch.undo()

    more = [*args]
    more[more.index("256")] = "384"
    assert main(more) == 0
    assert _lines(folder / "progress-without-checkpoints-0.jsonl") == first
    assert [x["steps"] for x in _lines(folder / "progress.jsonl")] == [128, 256, 384]


def test_a_checkpoint_killed_before_its_evaluation_is_evaluated_on_resume(tmp_path, capsys):
    out = tmp_path / "bl"
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]
    assert main(args) == 0
    folder = out / "ppo-identity"
    # as if killed while logging step 128's evaluation: its checkpoint saved, its row torn
    (folder / "checkpoints" / "step_256.zip").unlink()
    (folder / "final.zip").unlink()
    text = (folder / "progress.jsonl").read_text()
    wall_128 = _lines(folder / "progress.jsonl")[0]["wall_s"]
    (folder / "progress.jsonl").write_text(text[:30])
    assert main(args) == 0
    capsys.readouterr()
    lines = _lines(folder / "progress.jsonl")
    assert [x["steps"] for x in lines] == [128, 256]
    # its training wall time is the one saved with the checkpoint, and training goes on
    # from it (the column restarted at 0 before)
    assert lines[0]["wall_s"] == wall_128
    assert lines[1]["wall_s"] > wall_128
    # a checkpoint saved before its wall time was: the last logged time, a lower bound
    from rbbo.rl import _wall_at_checkpoint

    assert _wall_at_checkpoint(300, {128: 1.5, 256: 2.5}, tmp_path) == 2.5
    assert _wall_at_checkpoint(128, {}, tmp_path) == 0.0


def test_parallel_jobs_give_the_sequential_results(tmp_path, capsys):
    # each job is seeded and owns its folder, so two processes reproduce one process's rows
    tables = []
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}"
        assert main(["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL,
                     "--workers", workers]) == 0  # fmt: skip
        with open(out / "baselines.csv", newline="") as f:
            tables.append([{k: v for k, v in r.items() if k != "wall_s"}
                           for r in csv.DictReader(f)])  # fmt: skip
    assert [r["method"] for r in tables[0]] == ["mppi", "ppo", "ppo"]
    assert tables[1] == tables[0]
    assert "[baselines] ppo identity done" in capsys.readouterr().err


def _interrupted_at_first_evaluation(monkeypatch, args):
    """Run ``args`` until the first checkpoint's evaluation, as if Ctrl-C came there."""

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(rl.training, "evaluate_policy", interrupt)
    assert main(args) == 130
    monkeypatch.undo()


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_an_interrupted_job_resumes_as_the_job_trained_straight_through(
    algo, tmp_path, capsys, monkeypatch
):
    import stable_baselines3 as sb3

    def run(out):
        return main(["baselines", ENV, "--algo", algo, "--out", str(out), *SMALL, "--no-mpc"])

    assert run(tmp_path / "straight") == 0
    cut = ["baselines", ENV, "--algo", algo, "--out", str(tmp_path / "cut"), *SMALL, "--no-mpc"]
    _interrupted_at_first_evaluation(monkeypatch, cut)
    ckpts = tmp_path / "cut" / f"{algo}-identity" / "checkpoints"
    assert (ckpts / "step_128_state.pkl").is_file() and not (ckpts / "step_256.zip").exists()
    assert run(tmp_path / "cut") == 0
    capsys.readouterr()
    # only the latest checkpoint's state is kept, as with SAC's replay buffer
    assert sorted(p.name for p in ckpts.glob("*_state.pkl")) == ["step_256_state.pkl"]
    rows = [_lines(tmp_path / x / f"{algo}-identity/progress.jsonl") for x in ("straight", "cut")]
    assert [x["distance"] for x in rows[1]] == [x["distance"] for x in rows[0]]
    cls = sb3.PPO if algo == "ppo" else sb3.SAC
    weights = [cls.load(tmp_path / x / f"{algo}-identity/final.zip").policy.state_dict()
               for x in ("straight", "cut")]  # fmt: skip
    # bitwise: SB3's load alone seeds the generators again and resets the env (0.02-0.05 apart)
    assert all(bool((weights[0][k] == weights[1][k]).all()) for k in weights[0])


def test_a_checkpoint_whose_state_cannot_be_read_resumes_from_its_weights(
    tmp_path, capsys, monkeypatch
):
    out = tmp_path / "bl"
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]
    _interrupted_at_first_evaluation(monkeypatch, args)
    state = out / "ppo-identity" / "checkpoints" / "step_128_state.pkl"
    state.write_bytes(b"not a pickle")
    with pytest.warns(UserWarning, match="step_128_state.pkl could not be read"):
        assert main(args) == 0
    capsys.readouterr()
    assert [x["steps"] for x in _lines(out / "ppo-identity/progress.jsonl")] == [128, 256]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algo", "dqn"], "dqn"),
        (["--algo", "ppo,sac,dqn"], "dqn"),
        (["--control-basis", "best"], "--run"),
        (["--control-basis", "nope"], "nope"),
        (["--seconds", "2", "--settle-time", "3"], "--settle-time"),
        (["--steps", "0"], "--steps"),
        (["--steps", "ppo=x"], "--steps"),
        (["--steps", "ppo=0,sac=5"], "--steps"),
        (["--algo", "ppo", "--steps", "ppo=100,ppo=200"], "name an algorithm twice"),
        (["--algo", "ppo", "--steps", "sac=500"], "ppo"),
        (["--workers", "0"], "--workers"),
        (["--env-kwarg", "sim_dim=10"], "env keyword 'sim_dim' is set by rbbo itself"),
        (["--env-kwarg", "colour=3"], "takes no keyword 'colour'"),
        (["--env-kwarg", "frame_skip=0"], "frame_skip must be a positive integer, got 0"),
    ],
)
def test_bad_arguments(args, message, capsys, tmp_path):
    assert main(["baselines", ENV, "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rbbo: error:") and message in err[0]


def test_missing_stable_baselines3(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)
    assert main(["baselines", ENV, "--out", str(tmp_path)]) == 2
    assert "pip install 'softrom[rl]'" in capsys.readouterr().err


def test_resolve_bases(tmp_path):
    run = tmp_path / "run"
    store = RunStore.create(run, {"rbbo": {"sim_dim": 8, "control_dim": 2},
                                  "objective": {"kind": "env", "env_id": ENV,
                                                "env_kwargs": {"friction": 0.5}}})  # fmt: skip
    best = np.linalg.qr(np.random.default_rng(0).standard_normal((8, 2)))[0]
    store.save_best(best)
    np.save(tmp_path / "mine.npy", best[:, :1])
    bases, kwargs = rl.resolve_bases(["identity", "best", str(tmp_path / "mine.npy")], ENV, run)
    assert list(bases) == ["identity", "best", "mine"] and kwargs == {"friction": 0.5}
    np.testing.assert_array_equal(bases["identity"], np.eye(8)[:, :2])
    np.testing.assert_array_equal(bases["best"], best)
    with pytest.raises(ValueError, match="CrossWalk"):
        rl.resolve_bases(["best"], "softrom_gym/CrossWalk-v0", run)
    # a run recorded in another simulation space (a flipped mode) is refused by name
    other = tmp_path / "other"
    spec = {"kind": "env", "env_id": ENV, "env_kwargs": {"friction": 0.5}}
    signature = EnvObjective(ENV, 8, 2, env_kwargs=spec["env_kwargs"]).simulation_space()
    flipped = [*signature[:7], -signature[7], *signature[8:]]
    config = {"rbbo": {"sim_dim": 8, "control_dim": 2},
              "objective": {**spec, "simulation_space": flipped}}  # fmt: skip
    RunStore.create(other, config).save_best(best)
    with pytest.raises(ValueError, match=r"coordinates \[7\] differ"):
        rl.resolve_bases(["best"], ENV, other)
    with pytest.raises(ValueError, match="no best_basis"):
        (run / "best_basis.npy").unlink()
        rl.resolve_bases(["best"], ENV, run)
    # a synthetic run's basis belongs to no robot: refused, not trained on SoftRobot-v0's
    synthetic = tmp_path / "synthetic"
    RunStore.create(synthetic, {"rbbo": {"sim_dim": 8, "control_dim": 2},
                                "objective": {"kind": "synthetic"}}).save_best(best)  # fmt: skip
    with pytest.raises(ValueError, match="optimised a synthetic objective, not an env"):
        rl.resolve_bases(["best"], ENV, synthetic)
    # a basis the env would refuse is refused before any work, naming the file
    np.save(tmp_path / "flat.npy", np.ones((8, 2)))
    with pytest.raises(ValueError, match=r"control basis .*flat.npy is rank-deficient"):
        rl.resolve_bases([str(tmp_path / "flat.npy")], ENV)


def test_env_kwargs_reach_the_env_and_agree_with_the_run(tmp_path, capsys, monkeypatch):
    seen = {}
    monkeypatch.setattr(rl, "run_baselines", lambda *a, **k: seen.update(k) or [])
    args = ["baselines", ENV, "--no-mpc", "--out", str(tmp_path / "b"), "--env-kwarg"]
    assert main([*args, "frame_skip=4"]) == 0
    assert seen["env_kwargs"] == {"frame_skip": 4}
    run = tmp_path / "run"
    RunStore.create(run, {"rbbo": {"sim_dim": 8, "control_dim": 2},
                          "objective": {"kind": "env", "env_id": ENV,
                                        "env_kwargs": {"frame_skip": 4}}})  # fmt: skip
    assert main([*args, "frame_skip=4", "--run", str(run)]) == 0  # the run's own: agrees
    capsys.readouterr()
    assert main([*args, "frame_skip=3", "--run", str(run)]) == 2
    assert "--env-kwarg frame_skip=3 differs from run" in capsys.readouterr().err
    assert main([*args, "dt=0.01", "--run", str(run)]) == 2
    assert "--env-kwarg dt was not given to run" in capsys.readouterr().err


def test_sim_dim_sets_m_and_a_run_keeps_its_own(tmp_path, capsys, monkeypatch):
    seen = {}
    monkeypatch.setattr(
        rl, "run_baselines", lambda env_id, bases, *a, **k: seen.update(bases) or []
    )
    args = ["baselines", ENV, "--no-mpc", "--out", str(tmp_path / "b")]
    assert main([*args, "--sim-dim", "12"]) == 0
    np.testing.assert_array_equal(seen["identity"], np.eye(12)[:, :3])
    run = tmp_path / "run"
    RunStore.create(run, {"rbbo": {"sim_dim": 8, "control_dim": 2},
                          "objective": {"kind": "env", "env_id": ENV}})  # fmt: skip
    assert main([*args, "--run", str(run)]) == 0  # the run's M and C
    np.testing.assert_array_equal(seen["identity"], np.eye(8)[:, :2])
    assert main([*args, "--run", str(run), "--sim-dim", "8"]) == 0  # the same: agrees
    capsys.readouterr()
    assert main([*args, "--run", str(run), "--sim-dim", "12"]) == 2
    err = capsys.readouterr().err
    assert f"--sim-dim 12 differs from run {run}'s sim_dim 8, the M its B_c was found in" in err
    np.save(tmp_path / "mine.npy", np.eye(8)[:, :2])
    assert main([*args, "--control-basis", str(tmp_path / "mine.npy"), "--sim-dim", "12"]) == 2
    assert "mine.npy has M = 8 rows, not --sim-dim 12" in capsys.readouterr().err
    assert main([*args, "--sim-dim", "2"]) == 2
    assert "--sim-dim 2 is below C = 3" in capsys.readouterr().err
    # --control-dim sets C as --sim-dim sets M, and a run or a .npy keeps its own
    assert main([*args, "--sim-dim", "12", "--control-dim", "5"]) == 0
    np.testing.assert_array_equal(seen["identity"], np.eye(12)[:, :5])
    capsys.readouterr()
    assert main([*args, "--run", str(run), "--control-dim", "3"]) == 2
    err = capsys.readouterr().err
    assert f"--control-dim 3 differs from run {run}'s control_dim 2, the C of its B_c" in err
    assert main([*args, "--control-basis", str(tmp_path / "mine.npy"), "--control-dim", "3"]) == 2
    assert "mine.npy has C = 2 columns, not --control-dim 3" in capsys.readouterr().err
    assert main([*args, "--sim-dim", "4", "--control-dim", "5"]) == 2
    assert "--sim-dim 4 is below C = 5" in capsys.readouterr().err
    # C = M is accepted: a policy acting on all of B_r, the baseline without a control space
    assert main([*args, "--sim-dim", "3"]) == 0
    np.testing.assert_array_equal(seen["identity"], np.eye(3))


def test_baselines_do_not_offer_the_synthetic_objective(capsys, tmp_path):
    assert main(["baselines", "synthetic", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "unknown ENV_ID 'synthetic'" in err and not err.strip().endswith("synthetic")
    assert not (tmp_path / "b").exists()


def test_t_interval():
    mean, half = rl.t_interval([1.0, 2.0, 3.0])
    assert mean == 2.0 and half == pytest.approx(4.302653 / math.sqrt(3), rel=1e-6)
    assert math.isnan(rl.t_interval([1.0])[1])


def _sleep_job(seconds, progress):
    import time

    time.sleep(seconds)


def test_an_interrupt_stops_parallel_jobs_instead_of_waiting_for_them():
    import os
    import signal
    import threading
    import time

    jobs = [(f"job {i}", (_sleep_job, 120.0)) for i in range(2)]
    timer = threading.Timer(5.0, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            rl._run_jobs(jobs, 2, False)
    finally:
        timer.cancel()
    assert time.monotonic() - start < 60.0  # the jobs alone take 120 s


class _FullThrottle:
    """A policy that always pushes every control to the top of its range."""

    def predict(self, obs, deterministic=True):
        return np.ones(3, dtype=np.float32), None


@pytest.mark.filterwarnings("ignore:.*a tetrahedron is inverted")
@pytest.mark.filterwarnings("ignore:.*the robot has turned")
def test_an_episode_that_diverges_before_the_settle_time_scores_zero():
    # An action scale of 1000 body weights blows the beam up within the first 0.5 s (its
    # elements invert on the way, which the env warns of).
    env = rl._make_env("softrom_gym/BeamWalk-v0", np.eye(20)[:, :3], {"action_scale": 1000}, True)
    early = rl.evaluate_policy(_FullThrottle(), env, [0, 1], seconds=2.0, settle_time=0.5)
    assert early == [0.0, 0.0]
    from_start = rl.evaluate_policy(_FullThrottle(), env, [0], seconds=2.0, settle_time=0.0)
    assert np.isfinite(from_start[0]) and from_start[0] != 0.0


def test_cached_mpc_rows_are_keyed_by_the_planner(tmp_path, monkeypatch):
    # the MPC row of a basis is kept in episodes.json; another planner (other controllers
    # defaults, another control period) must not reuse it
    import controllers
    from rbbo.rl import _mpc

    basis = np.eye(6)[:, :2]
    args = ("softrom_gym/SoftRobot-v0", "identity", basis, tmp_path / "m")
    evaluation = ([0], 0.1, 0.05)
    kwargs = {"robot": "beam", "task": "walk"}
    row = _mpc(*args, kwargs, evaluation, False)
    calls = []
    real = controllers.run_episode
    monkeypatch.setattr(
        controllers, "run_episode", lambda *a, **k: calls.append(1) or real(*a, **k)
    )
    cached = _mpc(*args, kwargs, evaluation, False)
    assert cached == json.loads(json.dumps(row)) and not calls  # the same planner: cached
    _mpc(*args, {**kwargs, "frame_skip": 10}, evaluation, False)
    assert calls  # another control period, another planner: run again
    # a run's --mpc overrides make the rows with the planner its R* was measured with
    calls.clear()
    _mpc(*args, kwargs, evaluation, False, planner_kwargs={"samples": 4})
    meta = json.loads((tmp_path / "m" / "episodes.json").read_text())["meta"]
    assert calls and meta["planner"]["settings"]["samples"] == 4


def test_training_episodes_are_as_long_as_the_evaluated_ones(tmp_path, monkeypatch):
    # the registered 400 env steps are 10 s only at the default control period
    made = []

    class Made(Exception):
        pass

    def record(env_id, basis, env_kwargs, rescale, **extra):
        made.append(extra.get("max_episode_steps"))
        raise Made

    monkeypatch.setattr(rl.training, "_make_env", record)  # where _train looks it up
    for env_kwargs, steps in (({"frame_skip": 1}, 2000), ({}, 400), ({"frame_skip": 10}, 200)):
        with pytest.raises(Made):
            rl._train("ppo", "softrom_gym/BeamWalk-v0", "identity", np.eye(6)[:, :2],
                      tmp_path, env_kwargs, 64, 64, ([0], 10.0, 2.0), 0, False)  # fmt: skip
        assert made.pop() == steps


@pytest.mark.parametrize("bad", [{"workers": 0}, {"eval_seeds": 0}, {"checkpoint_every": 0},
                                 {"workers": 1.5}])  # fmt: skip
def test_run_baselines_refuses_bad_counts_before_claiming_any_folder(tmp_path, bad):
    # (the job folders were claimed, run.json written, before workers was checked, and
    # checkpoint_every = 0 failed inside training with a ZeroDivisionError)
    ((what, value),) = bad.items()
    with pytest.raises(ValueError, match=f"{what} must be a positive integer, got {value!r}"):
        rl.run_baselines(ENV, {"identity": np.eye(8)[:, :2]}, tmp_path / "out", algos=("ppo",),
                         **bad)  # fmt: skip
    assert not (tmp_path / "out").exists()


def _kill_ppo_saves(monkeypatch, when) -> None:
    """PPO.save killed mid-write wherever ``when(model, path)``: the start of a zip is
    written to ``path`` and KeyboardInterrupt raised, as a Ctrl-C or kill would leave it."""
    import stable_baselines3 as sb3

    real_save = sb3.PPO.save

    def killed_while_saving(self, path, *a, **k):
        if when(self, path):
            with open(path, "wb") as f:
                f.write(b"PK\x03\x04 torn")  # the start of a zip, and no more
            raise KeyboardInterrupt
        return real_save(self, path, *a, **k)

    monkeypatch.setattr(sb3.PPO, "save", killed_while_saving)


def test_a_checkpoint_torn_by_a_kill_while_saving_is_never_resumed_from(
    tmp_path, capsys, monkeypatch
):
    # A kill while step_256's weights are being written leaves a partial zip. It must be under
    # a temporary name (renamed when complete), so that the resume starts from step_128 and
    # does not load the torn file; saved straight to step_256.zip it would be loaded and fail.
    import stable_baselines3 as sb3

    out = tmp_path / "bl"
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]
    _kill_ppo_saves(monkeypatch, lambda m, path: m.num_timesteps == 256
                    and "final" not in str(path))  # fmt: skip
    assert main(args) == 130
    monkeypatch.undo()
    folder = out / "ppo-identity"
    assert [x["steps"] for x in _lines(folder / "progress.jsonl")] == [128]
    assert main(args) == 0
    capsys.readouterr()
    assert [x["steps"] for x in _lines(folder / "progress.jsonl")] == [128, 256]
    assert sb3.PPO.load(folder / "final.zip").num_timesteps == 256


def test_a_final_model_torn_by_a_kill_is_written_again_on_resume(tmp_path, capsys, monkeypatch):
    # SB3 writes final.zip in place, and a finished job keeps a final.zip that exists: a kill
    # mid-save must leave no final.zip (a temporary file instead), so that the re-run writes
    # it whole; saved straight under its name the torn file would be kept for good.
    from pathlib import Path

    import stable_baselines3 as sb3

    out = tmp_path / "bl"
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]
    _kill_ppo_saves(monkeypatch, lambda m, path: "final" in Path(path).name)
    assert main(args) == 130
    monkeypatch.undo()
    folder = out / "ppo-identity"
    assert [x["steps"] for x in _lines(folder / "progress.jsonl")] == [128, 256]
    assert main(args) == 0
    capsys.readouterr()
    assert sb3.PPO.load(folder / "final.zip").num_timesteps == 256


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self/fd"), reason="needs /proc")
def test_a_checkpoint_is_on_disk_before_it_is_published_and_before_the_last_is_pruned(
    tmp_path, capsys, monkeypatch
):
    # A power loss keeps only what was fsynced, and a rename may reach the disk before the
    # data it names: each file of a checkpoint (SAC's replay buffer, step_<n>.json, the zip)
    # and final.zip must be fsynced before the rename that publishes it, and its directory
    # fsynced before the next one is published or the previous replay buffer deleted, else
    # the disk could hold an empty step_<n>.zip, or step_128.zip without its buffer.
    # Durability is not observable without pulling the power, so this watches os.fsync,
    # os.replace and os.unlink.
    import os
    import re
    import stat
    from pathlib import Path

    published = re.compile(r"step_\d+(\.zip|\.json|_replay\.pkl|_state\.pkl)|final\.zip")
    events = []
    real_fsync, real_replace, real_unlink = os.fsync, os.replace, os.unlink

    def fsync(fd):
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            events.append(("dir", set(os.listdir(os.readlink(f"/proc/self/fd/{fd}")))))
        else:
            events.append(("file", (st.st_ino, st.st_size)))
        real_fsync(fd)

    def replace(src, dst, **k):
        if published.fullmatch(Path(dst).name):
            st = os.stat(src)
            events.append(("replace", Path(dst).name, (st.st_ino, st.st_size)))
        real_replace(src, dst, **k)

    def unlink(path, **k):
        if Path(path).name.endswith(("_replay.pkl", "_state.pkl")):
            events.append(("unlink", Path(path).name))
        real_unlink(path, **k)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    monkeypatch.setattr(os, "unlink", unlink)
    out = tmp_path / "bl"
    assert main(["baselines", ENV, "--algo", "sac", "--out", str(out), *SMALL, "--no-mpc"]) == 0
    monkeypatch.undo()
    capsys.readouterr()
    renames = [i for i, e in enumerate(events) if e[0] == "replace"]
    for i in renames:
        _, name, data = events[i]
        assert ("file", data) in events[:i], f"{name} was not fsynced before its rename"
        later = [j for j, e in enumerate(events) if j > i and e[0] != "file"]
        assert later and events[later[0]][0] == "dir" and name in events[later[0]][1], (
            f"the directory was not fsynced after {name} was published"
        )
    assert {events[i][1] for i in renames} == {
        "step_128_replay.pkl", "step_128_state.pkl", "step_128.json", "step_128.zip",
        "step_256_replay.pkl", "step_256_state.pkl", "step_256.json", "step_256.zip",
        "final.zip"}  # fmt: skip
    for kind in ("replay", "state"):
        pruned = events.index(("unlink", f"step_128_{kind}.pkl"))
        assert any(e[0] == "dir" and "step_256.zip" in e[1] for e in events[:pruned]), (
            f"step_128's {kind} file was deleted before step_256.zip was on disk"
        )
    # a published step_<n>.zip has its state beside it already
    for n in (128, 256):
        zip_at = next(i for i in renames if events[i][1] == f"step_{n}.zip")
        assert any(events[i][1] == f"step_{n}_state.pkl" for i in renames if i < zip_at)


@needs_proc
def test_every_progress_row_is_on_disk_before_training_goes_on(tmp_path, capsys, monkeypatch):
    # A resume evaluates again only the latest checkpoint: the row of an earlier one that a
    # power loss took from progress.jsonl would be lost for good. Each row must be fsynced
    # as it is appended, and the new file's name made durable (its folder fsynced) before
    # the next checkpoint's row.
    out = tmp_path / "bl"
    events = _watch_writes(monkeypatch)
    assert main(["baselines", ENV, "--algo", "ppo", "--out", str(out), *SMALL, "--no-mpc"]) == 0
    monkeypatch.undo()
    capsys.readouterr()
    folder = out / "ppo-identity"
    log = folder / "progress.jsonl"
    ino = log.stat().st_ino
    ends = list(itertools.accumulate(len(x) + 1 for x in log.read_bytes().splitlines()))
    assert len(ends) == 2
    for n, size in enumerate(ends):
        assert ("file", (ino, size)) in events, f"row {n} of {log} was not fsynced"
    first, second = (events.index(("file", (ino, size))) for size in ends)
    named = [e for e in events[first:second] if e[0] == "dir" and log.name in e[2]]
    assert any(e[1] == os.path.realpath(folder) for e in named), (
        f"{folder} was not fsynced holding {log.name} before the next row"
    )


@needs_proc
def test_a_mended_progress_log_is_on_disk_before_it_replaces_the_torn_one(tmp_path, monkeypatch):
    # The mend rewrites rows already on disk: renamed over the torn log unsynced, a power
    # loss could leave progress.jsonl empty, every row of the job's earlier checkpoints lost.
    log = tmp_path / "progress.jsonl"
    log.write_text('{"steps": 64}\n{"steps": 128}\n{"steps": 19')
    events = _watch_writes(monkeypatch)
    assert rl._read_progress(log) == [{"steps": 64}, {"steps": 128}]
    monkeypatch.undo()
    assert log.read_text() == '{"steps": 64}\n{"steps": 128}\n'
    _assert_published_durably(events, tmp_path, log.name)


@needs_proc
def test_the_mpc_row_is_cached_atomically_and_a_torn_cache_is_made_again(tmp_path, monkeypatch):
    # A kill mid-write of episodes.json left a torn file that every re-run then failed on
    # (JSONDecodeError): the cache must be written under another name, fsynced and renamed,
    # and one torn by an older version made again, with a warning naming it.
    import re

    from rbbo.rl import _mpc

    folder = tmp_path / "m"
    cache = folder / "episodes.json"
    args = ("softrom_gym/SoftRobot-v0", "identity", np.eye(6)[:, :2], folder,
            {"robot": "beam", "task": "walk"}, ([0, 1], 0.1, 0.05), False)  # fmt: skip
    events = _watch_writes(monkeypatch)
    row = _mpc(*args)
    monkeypatch.undo()
    _assert_published_durably(events, folder, cache.name)
    whole = cache.read_text()
    cache.write_text(whole[: len(whole) // 2])
    with pytest.warns(
        RuntimeWarning, match=f"MPC cache {re.escape(str(cache))} .*made again"
    ) as caught:
        again = _mpc(*args)
    assert [w.filename for w in caught] == [__file__]  # the caller's line, not rbbo's
    assert {k: v for k, v in again.items() if k != "wall_s"} == {
        k: v for k, v in row.items() if k != "wall_s"}  # fmt: skip
    assert json.loads(cache.read_text())["row"] == json.loads(json.dumps(again))


@needs_proc
def test_a_claim_is_written_atomically_and_a_torn_one_is_a_usage_error(
    tmp_path, capsys, monkeypatch
):
    # run.json written in place could be torn by a kill or power loss, and every re-run then
    # failed on it with a JSONDecodeError's traceback. It must be published whole by a
    # rename; a torn one (left by an older version) refused in one line that names it.
    folder = tmp_path / "bl" / "ppo-identity"
    meta = {"env_id": ENV, "env_kwargs": {}, "algo": "ppo", "seed": 0,
            "basis": np.eye(8)[:, :2].tolist()}  # fmt: skip
    events = _watch_writes(monkeypatch)
    rl._claim(folder, meta)
    monkeypatch.undo()
    _assert_published_durably(events, folder, "run.json")
    assert json.loads((folder / "run.json").read_text()) == meta
    rl._claim(folder, meta)  # the same run: continued
    (folder / "run.json").write_text('{"env_id": "softrom_gym/Cro')
    args = ["baselines", ENV, "--algo", "ppo", "--out", str(tmp_path / "bl"), *SMALL, "--no-mpc"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("rbbo: error:") and not any("Traceback" in x for x in err)
    assert f"{folder / 'run.json'} is unreadable, torn by a kill" in err[-1]


def test_control_basis_files_the_env_could_not_use_are_named_before_any_work(tmp_path):
    from rbbo.store import RunDirectoryError

    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((8, 2)))[0]
    (tmp_path / "text.npy").write_text("not an array")
    np.save(tmp_path / "flat.npy", basis.ravel())
    np.save(tmp_path / "wide.npy", basis.T)
    nan = basis.copy()
    nan[3, 1] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    for name, match in (("text", "cannot read control basis .*text.npy: "),
                        ("flat", r"flat.npy has shape \(16,\), expected \(M, C\)"),
                        ("wide", r"wide.npy has shape \(2, 8\), expected \(M, C\)"),
                        ("nan", "nan.npy contains non-finite values")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            rl.resolve_bases([str(tmp_path / f"{name}.npy")], ENV)
    # two files of one name would share a row label (and a training folder)
    (tmp_path / "other").mkdir()
    for folder in (tmp_path, tmp_path / "other"):
        np.save(folder / "mine.npy", basis)
    with pytest.raises(ValueError, match="two control bases are named 'mine'"):
        rl.resolve_bases([str(tmp_path / "mine.npy"), str(tmp_path / "other" / "mine.npy")], ENV)
    # a run directory whose config lost its dimensions
    lost = {"rbbo": {}, "objective": {"kind": "env", "env_id": ENV}}
    RunStore.create(tmp_path / "run", lost).close()
    with pytest.raises(RunDirectoryError, match="config.json has no sim_dim/control_dim"):
        rl.resolve_bases(["identity"], ENV, tmp_path / "run")


def test_a_control_basis_under_home_is_read_from_a_comma_list(tmp_path, monkeypatch):
    """--control-basis identity,~/mine.npy: the shell expands no ~ inside a comma list, and
    resolve_bases said 'cannot read control basis ~/mine.npy' (found by analogy with the
    env's control_basis="~/..." keyword); ~ is expanded, the row keeps the file's stem."""
    monkeypatch.setenv("HOME", str(tmp_path))
    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((8, 2)))[0]
    np.save(tmp_path / "mine.npy", basis)
    bases, _ = rl.resolve_bases(["identity", "~/mine.npy"], ENV)
    assert list(bases) == ["identity", "mine"]
    np.testing.assert_array_equal(bases["mine"], basis)


def _warning_job(progress):
    import warnings

    warnings.warn("the policy's reward is NaN", RuntimeWarning, stacklevel=1)
    return {"ok": True}


def test_a_worker_jobs_warning_is_one_line_naming_the_job(monkeypatch, capsys):
    # In a worker process of the parallel baselines a warning was Python's display: a line
    # inside the package, from a process the user never started. (In-process here: the
    # worker runs this same function, with its label.)
    import warnings

    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # restored after
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert rl.jobs._job((_warning_job,), False, 1, "ppo identity") == {"ok": True}
    assert capsys.readouterr().err.splitlines() == [
        "rbbo baselines (ppo identity): warning: the policy's reward is NaN (RuntimeWarning)"
    ]


@needs_proc
def test_the_tables_are_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    # baselines.csv marks the RL stage done (`rbbo reproduce --status`); it was rewritten in
    # place, so an error in the Markdown table after it, or a kill mid-write, left a new or
    # torn baselines.csv beside an old baselines.md
    from rbbo.rl.table import _row

    out, basis = tmp_path / "out", {"identity": np.eye(8)[:, :2]}
    out.mkdir()  # (as the jobs' folders make it)
    rows = [_row(ENV, "mppi", "identity", True, 0, 600, 1.5, [0.1, 0.2], 0.3)]
    monkeypatch.setattr(rl.jobs, "_run_jobs", lambda jobs, workers, progress: rows)
    events = _watch_writes(monkeypatch)
    rl.run_baselines(ENV, basis, out, algos=(), progress=False)
    for name in ("baselines.csv", "baselines.md"):
        _assert_published_durably(events, out, name)
    before = {p: (out / p).read_bytes() for p in ("baselines.csv", "baselines.md")}
    assert before["baselines.csv"].decode().splitlines()[0] == ",".join(rl.table._COLUMNS)

    rows = [_row(ENV, "mppi", "identity", True, 0, 600, 1.5, [0.5, 0.6], 0.3)]

    def fails(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(rl.jobs, "format_table", fails)
    with pytest.raises(RuntimeError, match="disk full"):
        rl.run_baselines(ENV, basis, out, algos=(), progress=False)
    assert {p: (out / p).read_bytes() for p in before} == before


def test_the_baselines_table_gives_distances_in_metres_and_body_lengths_and_when_rl_reached_mpc():
    # guards baselines.md: each row's mean ± t-interval in m and in body lengths (distance /
    # body length), "-" env steps for the MPC, and per basis the first checkpoint whose
    # distance matched the MPC's (a tie counts) or the last one tried
    from rbbo.rl.table import _row, format_table

    body = 0.5
    rows = [_row(ENV, "ppo", "identity", False, 1000, 5000, 10.0, [0.0, 0.25], body),
            _row(ENV, "ppo", "identity", True, 2000, 10000, 20.0, [0.25, 0.5, 0.75], body),
            _row(ENV, "ppo", "best", False, 1000, 5000, 10.0, [0.0, 0.0], body),
            _row(ENV, "ppo", "best", True, 2000, 10000, 20.0, [0.125], body),
            _row(ENV, "mppi", "identity", True, 0, 600, 1.5, [0.25, 0.75], body),
            _row(ENV, "mppi", "best", True, 0, 600, 1.5, [0.25, 0.5], body)]  # fmt: skip
    half3 = 4.302652729911275 * 0.25 / math.sqrt(3)  # t_{0.975, 2} s / sqrt(3)
    assert (rows[1]["distance_m"], rows[1]["ci95_m"]) == (0.5, pytest.approx(half3))
    assert (rows[1]["distance_bl"], rows[1]["ci95_bl"]) == (1.0, pytest.approx(half3 / body))
    assert rows[1]["seeds"] == 3 and math.isnan(rows[3]["ci95_m"])
    text = format_table(rows, markdown=True).splitlines()
    assert text[3] == ("| CrossSwim-v0 | ppo | identity | 2000 | 10,000 | 20.0 s | "
                       f"+0.500 ± {half3:.3f} | +1.00 ± {half3 / body:.2f} |")  # fmt: skip
    assert text[5] == "| CrossSwim-v0 | ppo | best | 2000 | 10,000 | 20.0 s | +0.125 | +0.25 |"
    assert text[6].startswith("| CrossSwim-v0 | mppi | identity | - | 600 | 1.5 s | +0.500 ± ")
    assert text[-2:] == [
        "- ppo (identity) reached the MPC's 0.500 m at 2000 env steps",
        "- ppo (best) did not reach the MPC's 0.375 m within 2000 env steps",
    ]
    plain = format_table(rows).splitlines()  # the final rows only
    assert len(plain) == 2 + 4 + 3 and plain[-2:] == [x[2:] for x in text[-2:]]


class _Track:
    """An env whose robot starts at 5 m and moves ``speed`` m each step of 0.1 s; its episode
    is truncated after ``limit`` steps."""

    def __init__(self, speed, limit=None):
        self.speed, self.limit, self.steps = speed, limit, 0

    def get_wrapper_attr(self, name):
        assert name == "dt"
        return 0.1

    def reset(self, seed):
        self.t = 0
        return np.zeros(3), {"distance": 5.0}

    def step(self, action):
        self.t += 1
        self.steps += 1
        done = self.limit is not None and self.t >= self.limit
        return np.zeros(3), 0.0, False, done, {"distance": 5.0 + self.speed * self.t}


def test_a_policys_distance_is_from_the_settle_time_to_the_end_of_the_episode():
    # guards evaluate_policy: seconds / dt steps, the distance measured from the step at
    # the settle time to the last one (signed: backwards is negative), an episode that ends
    # early keeps its distance so far, one that ends before the settle time scores 0
    policy = _FullThrottle()
    env = _Track(0.01)
    got = rl.evaluate_policy(policy, env, [0, 1], seconds=1.0, settle_time=0.3)
    assert got == [pytest.approx(0.07), pytest.approx(0.07)] and env.steps == 20
    assert rl.evaluate_policy(policy, _Track(0.01), [0], 1.0, 0.0) == [pytest.approx(0.1)]
    assert rl.evaluate_policy(policy, _Track(-0.01), [0], 1.0, 0.3) == [pytest.approx(-0.07)]
    env = _Track(0.01, limit=6)
    assert rl.evaluate_policy(policy, env, [0], 1.0, 0.3) == [pytest.approx(0.03)]
    assert env.steps == 6
    assert rl.evaluate_policy(policy, _Track(0.01, limit=2), [0], 1.0, 0.3) == [0.0]


def test_evaluate_policy_names_a_settle_time_outside_the_episode():
    """rl.evaluate_policy (public) scored every seed 0.0 when settle_time >= seconds, and
    nothing when seconds <= 0 or nan (found calling it with settle_time=2, seconds=1):
    run_baselines refused these, the function itself did not. Both are named, no step run."""
    for seconds, settle in ((1.0, 2.0), (1.0, 1.0), (0.0, 0.0), (-1.0, 0.0), (math.nan, 0.0),
                            (1.0, -0.1), (1.0, math.nan)):  # fmt: skip
        env = _Track(0.01)
        with pytest.raises(ValueError, match=r"seconds must be a finite number > 0, got "
                           r"|settle time .* s must lie in \[0, "):  # fmt: skip
            rl.evaluate_policy(_FullThrottle(), env, [0], seconds, settle)
        assert env.steps == 0


def test_a_basis_file_named_like_another_or_nearly_rank_deficient_is_refused(tmp_path):
    # guards resolve_bases: a file named identity.npy would take the identity's row (and its
    # training folder), a basis whose columns nearly coincide is one the env refuses, and
    # the identity takes its M and C from the file given
    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((8, 2)))[0]
    np.save(tmp_path / "identity.npy", basis)
    with pytest.raises(ValueError, match="two control bases are named 'identity'"):
        rl.resolve_bases(["identity", str(tmp_path / "identity.npy")], ENV)
    # without a run, the identity has the M and C of the first file given (not 20 and 3)
    np.save(tmp_path / "mine.npy", basis)
    bases, _ = rl.resolve_bases(["identity", str(tmp_path / "mine.npy")], ENV)
    assert list(bases) == ["identity", "mine"]
    np.testing.assert_array_equal(bases["identity"], np.eye(8)[:, :2])
    near = np.stack([basis[:, 0], basis[:, 0] + 1e-12 * basis[:, 1]], axis=1)
    np.save(tmp_path / "near.npy", near)
    with pytest.raises(ValueError, match="near.npy is rank-deficient"):
        rl.resolve_bases([str(tmp_path / "near.npy")], ENV)
