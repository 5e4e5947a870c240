"""The ``rbbo`` command line (rbbo.cli): end to end on tiny budgets, and its usage errors."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys

import pytest

# the stand-in env and controllers of the objective tests drive the env path end to end
from test_rbbo_objective import _fake_controllers

from rbbo.cli import _terminate_as_interrupt, main, parse_duration

TINY = ["--sim-dim", "6", "--control-dim", "2", "--init", "3", "--confirm-seeds", "2",
        "--no-progress"]  # fmt: skip


def _history(run):
    return [json.loads(line) for line in (run / "history.jsonl").read_text().splitlines()]


def test_optimize_report_resume_rollout_on_a_synthetic_objective(tmp_path, capsys):
    run = tmp_path / "run"
    code = main(["optimize", "synthetic:noise=0.01", *TINY, "--iterations", "8",
                 "--executor", "serial", "--out", str(run)])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "R_init" in out and "improvement" in out and "synthetic:noise=0.01" in out
    assert (run / "convergence.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == 8

    (run / "convergence.png").unlink()
    assert main(["report", str(run)]) == 0
    out, err = capsys.readouterr()
    table = out.splitlines()
    assert err == f"{run}: plot {run / 'convergence.png'}, best basis {run / 'best_basis.npy'}\n"
    assert table[0].split() == ["problem", "N", "M", "C", "R_init", "R*", "improvement",
                                "evaluations", "wall", "time"]  # fmt: skip
    row = table[2].split()
    assert row[2:4] == ["6", "2"] and row[-2] == "8"
    assert (run / "convergence.png").exists()

    assert main(["resume", str(run), "--iterations", "10", "--no-progress"]) == 0
    capsys.readouterr()
    evaluations = [h for h in _history(run) if not h["kind"].startswith("confirm")]
    assert len(evaluations) == 10

    assert main(["rollout", str(run), "--seed", "7"]) == 0
    out = capsys.readouterr().out
    # the synthetic R is no rate: it printed "R = 0.7 per second" as an env run's does
    assert out.startswith("R = ") and "per second" not in out
    assert "(synthetic objective, T = 10 s, seed 7); optimum 1\n" in out

    # options the run's executor cannot take are refused as optimize refuses them (resume
    # dropped the address, and confirm ran a serial run's 4 "workers" one at a time)
    err = _error(capsys, ["resume", str(run), "--executor", "process", "--address", "auto"])
    assert "--address is for --executor ray" in err
    err = _error(capsys, ["confirm", str(run), "--workers", "4"])
    assert "--executor serial runs one evaluation at a time, in this process; --workers 4" in err
    assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == 10

    # confirm: the same bases measured again on the same fresh seeds, appended
    first = [h for h in _history(run) if h["kind"].startswith("confirm")]
    assert main(["confirm", str(run), "--workers", "1"]) == 0
    assert capsys.readouterr().out.startswith("R_init ")
    confirms = [h for h in _history(run) if h["kind"].startswith("confirm")]
    assert len(confirms) == len(first) + 2
    again = {h["kind"]: h for h in confirms[-2:]}
    latest = {h["kind"]: h for h in first}  # the last measurement of each kind
    for old in latest.values():
        new = again[old["kind"]]
        assert new["basis"] == old["basis"] and new["seeds"] == old["seeds"]
        assert new["R"] == pytest.approx(old["R"])  # the synthetic objective is seeded
    assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == 10


def test_deterministic_runs_on_two_workers_repeat_and_resume_so(tmp_path, capsys, monkeypatch):
    told = []
    from rbbo import optimizer

    real_run = optimizer.RBBO.run

    def spy(self, *args, **kwargs):
        told.append(kwargs.get("deterministic"))
        return real_run(self, *args, **kwargs)

    monkeypatch.setattr(optimizer.RBBO, "run", spy)
    runs = [tmp_path / "a", tmp_path / "b"]
    for run in runs:
        assert main(["optimize", "synthetic:noise=0.01", *TINY, "--iterations", "7",
                     "--workers", "2", "--deterministic", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    first, second = (_history(run) for run in runs)
    assert [h["index"] for h in first] == list(range(len(first)))  # told in proposal order
    assert [(h["basis"], h["R"]) for h in first] == [(h["basis"], h["R"]) for h in second]
    config = json.loads((runs[0] / "config.json").read_text())
    assert config["execution"]["deterministic"] is True
    assert main(["resume", str(runs[0]), "--iterations", "8", "--no-progress"]) == 0
    assert told == [True, True, True]  # the resumed session keeps the run's schedule


def test_optimize_an_env_with_mpc(tmp_path, capsys, monkeypatch):
    """The env path: ENV_ID resolution, node count, settled reward per second, config."""
    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers([]))
    run = tmp_path / "env-run"
    code = main(["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
                 "--init", "2", "--iterations", "4", "--t-max", "4", "--confirm-seeds", "1",
                 "--executor", "serial", "--no-progress", "--out", str(run)])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert " 623 " in out  # N, the robot's node count
    config = json.loads((run / "config.json").read_text())
    assert config["objective"] == {
        "kind": "env", "env_id": "rbbo_test/StandIn-v0", "sim_dim": 6, "control_dim": 2,
        "controller": "mppi", "settle_time": 2.0, "env_kwargs": {}, "planner_kwargs": {},
        "planner": {"name": "MPPI", "replan_every": 1, "settings": None},  # the stand-in's
    }  # fmt: skip
    # R is 0.1 B_c[0, 0] per 0.025 s step after settling: 4 B_c[0, 0] per second
    for record in _history(run):
        assert record["R"] == pytest.approx(4.0 * record["basis"][0][0])


def test_env_kwargs_reach_the_env_and_the_run_directory(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers([]))
    run = tmp_path / "env-run"
    argv = ["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
            "--init", "2", "--iterations", "3", "--t-max", "4", "--confirm-seeds", "1",
            "--executor", "serial", "--no-progress"]  # fmt: skip
    assert main([*argv, "--env-kwarg", "render_mode=null", "--out", str(run)]) == 0
    assert json.loads((run / "config.json").read_text())["objective"]["env_kwargs"] == {
        "render_mode": None
    }
    capsys.readouterr()
    err = _error(capsys, [*argv, "--env-kwarg", "robot=my.stl", "--out", str(tmp_path / "b")])
    assert "rbbo_test/StandIn-v0 takes no keyword 'robot'; its keywords: " in err
    assert "\n" not in err.strip()  # one line, not Gymnasium's quote of every value
    assert "expected KEY=VALUE" in _error(capsys, [*argv, "--env-kwarg", "robot"])
    assert "--env-kwarg is for an env" in _error(capsys, ["optimize", "synthetic",
                                                          "--env-kwarg", "a=1"])  # fmt: skip
    err = _error(capsys, ["optimize", "synthetic", "--executor", "serial", "--workers", "2"])
    assert "--executor serial runs one evaluation at a time" in err


def test_rollout_video_without_imageio_is_a_usage_error(tmp_path, capsys, monkeypatch):
    import controllers.episode  # noqa: F401 - the real checks, under the stand-in package below

    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers([]))
    run = tmp_path / "env-run"
    assert main(["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
                 "--init", "2", "--iterations", "2", "--t-max", "4", "--confirm-seeds", "1",
                 "--executor", "serial", "--no-progress", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    monkeypatch.setitem(sys.modules, "imageio", None)  # import imageio raises ImportError
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    err = _error(capsys, ["rollout", str(run), "--video", str(tmp_path / "a.mp4")])
    assert "--video: writing a video needs imageio: pip install 'softrom[video]'" in err
    assert not (tmp_path / "a.mp4").exists()


def test_rollout_video_that_could_not_be_written_is_a_usage_error_before_the_episode(
    tmp_path, capsys, monkeypatch
):
    # --video checked imageio only: without imageio-ffmpeg, or to a folder, the episode ran
    # whole and then failed to write (a traceback, or the episode's result lost)
    import controllers.episode  # noqa: F401 - the real checks, under the stand-in package below

    calls = []
    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers(calls))
    run = tmp_path / "env-run"
    assert main(["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
                 "--init", "2", "--iterations", "2", "--t-max", "4", "--confirm-seeds", "1",
                 "--executor", "serial", "--no-progress", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    episodes = len(calls)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import raises ImportError
    err = _error(capsys, ["rollout", str(run), "--video", str(tmp_path / "a.mp4")])
    assert "--video: writing a .mp4 video needs imageio-ffmpeg: pip install 'softrom[video]'" in err
    monkeypatch.delitem(sys.modules, "imageio_ffmpeg")
    (tmp_path / "clip.mp4").mkdir()
    err = _error(capsys, ["rollout", str(run), "--video", str(tmp_path / "clip.mp4")])
    assert f"--video {str(tmp_path / 'clip.mp4')!r} is a folder; give a file name" in err
    (tmp_path / "file").write_text("")
    video = tmp_path / "file" / "a.mp4"
    err = _error(capsys, ["rollout", str(run), "--video", str(video)])
    assert f"--video {video}: cannot create its folder {tmp_path / 'file'}" in err
    assert len(calls) == episodes  # refused before any episode


def test_rollout_video_of_the_settling_seconds_prints_no_r(tmp_path, capsys, monkeypatch):
    import rbbo.cli.rollout

    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers([]))
    # the stand-in controllers write no video: imageio is not needed
    monkeypatch.setattr(rbbo.cli.rollout, "_require_imageio", lambda suffix: None)
    run = tmp_path / "env-run"
    assert main(["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
                 "--init", "2", "--iterations", "2", "--t-max", "4", "--confirm-seeds", "1",
                 "--executor", "serial", "--no-progress", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    # the settle time is 2 s: a 1-s episode has no R, but its video is what was asked for
    video = tmp_path / "first.mp4"
    assert main(["rollout", str(run), "--video", str(video), "--seconds", "1"]) == 0
    note = "(1 s; no R, which is measured from the run's settle time 2 s on)"
    assert capsys.readouterr().out == f"video: {video} {note}\n"
    assert main(["rollout", str(run), "--video", str(video), "--seconds", "3"]) == 0
    assert capsys.readouterr().out.startswith("R = ")
    # without --video the replay is for R: refused, saying what to give instead
    err = _error(capsys, ["rollout", str(run), "--seconds", "2"])
    assert "--seconds 2 must exceed the run's settle time 2 s, from which R is measured" in err
    assert "give more (the run's T_max is 4 s), or add --video FILE" in err


def test_rollout_video_name_without_a_video_suffix_is_a_usage_error(tmp_path, capsys,
                                                                     monkeypatch):  # fmt: skip
    import controllers.episode  # the real suffixes, under the stand-in package below
    import rbbo.cli.rollout

    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers([]))
    monkeypatch.setattr(rbbo.cli.rollout, "_require_imageio", lambda suffix: None)
    run = tmp_path / "env-run"
    assert main(["optimize", "rbbo_test/StandIn-v0", "--sim-dim", "6", "--control-dim", "2",
                 "--init", "2", "--iterations", "2", "--t-max", "4", "--confirm-seeds", "1",
                 "--executor", "serial", "--no-progress", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    for name in ("clip", "clip.png"):
        video = tmp_path / "new" / name
        err = _error(capsys, ["rollout", str(run), "--video", str(video)])
        assert f"--video {video}: the file name must end in one of .avi" in err
        assert ".mp4" in err and sorted(controllers.episode._VIDEO_SUFFIXES)[0] == ".avi"
    assert not (tmp_path / "new").exists()


def _error(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("rbbo: error: ")
    return err


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        ([], "no COMMAND given: one of optimize, resume, confirm, report, rollout, baselines"),
        # options are taken as spelled: a prefix argparse would have taken gets its full name
        (
            ["optimize", "synthetic", "--iter", "3"],
            "unrecognized arguments: --iter 3 (did you mean --iterations for --iter? rbbo optimize",
        ),
        (
            ["resume", "run", "--wrkers=2", "extra"],
            "(did you mean --workers for --wrkers? rbbo resume --help lists",
        ),
        (["optimize", "synthetic", "--budget", "5q"], "invalid duration '5q'"),
        (["optimize", "synthetic", "--budget", "0m"], "duration must be positive"),
        (["optimize", "synthetic", "--budget", "-5m"], "duration must be positive, got '-5m'"),
        (["reproduce", "--timeout", "-1h30m"], "duration must be positive, got '-1h30m'"),
        (["optimize", "synthetic", "--control-dim", "25"], "--control-dim 25 exceeds --sim-dim 20"),
        (["optimize", "synthetic", "--workers", "0"], "expected a positive integer, got '0'"),
        (["optimize", "synthetic", "--fidelity", "mf"], "invalid choice: 'mf'"),
        (["optimize", "synthetic:foo=1"], "bad synthetic option 'foo=1'"),
        (["optimize", "Nope-v0"], "unknown ENV_ID 'Nope-v0'; registered: softrom_gym/BeamWalk-v0"),
        (["optimize", "synthetic", "--address", "auto"], "--address is for --executor ray"),
        (
            ["optimize", "synthetic", "--executor", "serial", "--timeout", "30s"],
            "--timeout is for --executor process or ray",
        ),
        (["optimize", "synthetic", "--fidelity", "boca", "--t-min", "12"], "--t-min 12.0 must be"),
        (["optimize", "synthetic", "--init", "-1"], "--init: expected an integer >= 0, got '-1'"),
        (["optimize", "synthetic", "--settle-time", "-1"], "--settle-time: expected a number >= 0"),
        (
            ["optimize", "synthetic", "--confirm-seeds", "-2"],
            "--confirm-seeds: expected an integer",
        ),
        (["optimize", "synthetic", "--seed", "-3"], "--seed: expected an integer >= 0, got '-3'"),
        (["baselines", "CrossSwim-v0", "--seed", "-1"], "--seed: expected an integer >= 0"),
        (["rollout", "run", "--seed", "-1"], "--seed: expected an integer >= 0"),
        (["report"], "the following arguments are required: DIR"),
        (["optimize", "CrossWalk-v0", "--t-max=2", "--settle-time=2"], "--t-max 2.0 must exceed"),
        (
            ["optimize", "CrossWalk-v0", "--fidelity=boca", "--t-min=2", "--settle-time=2"],
            "--t-min 2.0 must exceed --settle-time 2.0",
        ),
        # without BOCA, --t-min is unused and not checked: the next check speaks
        (["optimize", "Nope-v0", "--t-min=1", "--settle-time=2"], "unknown ENV_ID 'Nope-v0'"),
        (["report", "a", "b", "--png", "p.png"], "--png names one plot: give one DIR"),
        (
            ["optimize", "CrossWalk-v0", "--controller", "ilqr"],
            "unknown planner 'ilqr'; registered: gn, mppi (controllers.register_planner adds "
            "one), or an import path package.module:ClassName naming a Planner subclass",
        ),
        (
            ["optimize", "CrossWalk-v0", "--controller", "no_such_planners:CEM"],
            "planner 'no_such_planners:CEM': no module named 'no_such_planners'",
        ),
    ],
)
def test_bad_arguments_exit_2_with_one_line(capsys, argv, match):
    assert match in _error(capsys, argv)


def test_env_without_controllers_names_the_missing_piece(capsys, monkeypatch):
    import types

    monkeypatch.setitem(sys.modules, "controllers", types.ModuleType("controllers"))
    err = _error(capsys, ["optimize", "CrossWalk-v0"])
    assert "controllers has no run_episode, MPPI, GaussNewtonShooting: the module" in err
    assert "is not softrom's" in err


def test_run_directory_errors(tmp_path, capsys):
    assert "is not an RBBO run directory" in _error(capsys, ["resume", str(tmp_path)])
    (tmp_path / "reproduce.json").write_text("{}")  # a reproduction's folder says what to do
    assert (
        f"rbbo reproduce directory: rerun rbbo reproduce --out {tmp_path} to go on, or name "
        f"one of its runs, {tmp_path / 'runs'}/<run>" in _error(capsys, ["resume", str(tmp_path)])
    )
    (tmp_path / "reproduce.json").unlink()
    assert "is not a directory" in _error(capsys, ["report", str(tmp_path / "missing")])
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    err = _error(capsys, ["optimize", "synthetic", *TINY, "--iterations", "4", "--out", str(run)])
    assert "already holds a run; resume it" in err
    assert "--video needs an env run" in _error(capsys, ["rollout", str(run), "--video", "a.mp4"])


def test_resume_with_a_new_limit_replaces_the_stored_ones(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--budget", "1s", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    done = len([h for h in _history(run) if not h["kind"].startswith("confirm")])
    # the stored 1-s budget is spent; with only the old limits there is nothing to search
    assert main(["resume", str(run), "--no-progress", "--executor", "serial"]) == 0
    err = capsys.readouterr().err
    assert "has reached its limit (a budget of 1 s; it has" in err
    assert "resumed for" not in err  # (nothing was resumed: it printed "resumed for 0 s")
    # a new --iterations replaces the budget instead of stopping at it
    assert main(["resume", str(run), "--iterations", str(done + 3), "--no-progress",
                 "--executor", "serial"]) == 0  # fmt: skip
    capsys.readouterr()
    assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == done + 3
    # the new limit is the run's now: a plain resume (what an interrupted run's hint says)
    # stops at it, not at the old budget
    settings = json.loads((run / "config.json").read_text())["rbbo"]
    assert (settings["max_evaluations"], settings["budget_s"]) == (done + 3, None)
    assert main(["resume", str(run), "--no-progress", "--executor", "serial"]) == 0
    assert f"has reached its limit ({done + 3} evaluations; it has" in capsys.readouterr().err


def test_a_run_that_stores_no_limit_is_resumed_only_with_one(tmp_path, capsys):
    """RBBO.create without a limit, then run(max_evaluations=...), stores none: a plain
    rbbo resume searched with no limit at all, on a finished run too (a review, session 54)."""
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    run = tmp_path / "run"
    objective = SyntheticObjective(6, 2)
    with RBBO.create(run, RBBOConfig(6, 2, n_init=2, n_confirm=2),
                     objective_spec=objective.spec()) as opt:  # fmt: skip
        opt.run(objective, max_evaluations=4)
    before = (run / "history.jsonl").read_bytes()
    assert main(["resume", str(run), "--no-progress", "--executor", "serial"]) == 2
    assert f"{run} stores no limit: give --iterations or --budget" in capsys.readouterr().err
    assert (run / "history.jsonl").read_bytes() == before
    assert main(["resume", str(run), "--iterations", "5", "--no-progress",
                 "--executor", "serial"]) == 0  # fmt: skip
    assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == 5


def test_a_lowered_limit_given_to_resume_is_the_runs_from_then_on(tmp_path, capsys):
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=10, n_confirm=2, acq_random=64,
                        acq_starts=2, gp_restarts=0)  # fmt: skip
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    opt.run(objective, max_evaluations=5, confirm=False)  # as if stopped after 5 of 10
    opt.store.close()
    argv = ["resume", str(tmp_path / "run"), "--no-progress", "--executor", "serial"]
    # enough searched: the run stops at 5 (confirming R_init and R*), and says the limit moved
    assert main([*argv, "--iterations", "5"]) == 0
    err = capsys.readouterr().err
    assert "its limit is now 5 evaluations (was 10 evaluations), stored in config.json" in err
    assert "has reached its limit (5 evaluations; it has 5 evaluations" in err
    # its confirmation was never run: it is said to be measured now, and it is
    assert "nothing more to search; measuring R_init and R* (not finished before)" in err
    assert "resumed for" in err
    assert any(h["kind"].startswith("confirm") for h in _history(tmp_path / "run"))
    settings = json.loads((tmp_path / "run" / "config.json").read_text())["rbbo"]
    assert (settings["max_evaluations"], settings["budget_s"]) == (5, None)
    # a later plain resume keeps to it, instead of searching on to the old 10
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "has reached its limit (5 evaluations;" in err
    assert "nothing more to search; give a larger --budget or --iterations to go on" in err
    assert len([h for h in _history(tmp_path / "run") if not h["kind"].startswith("confirm")]) == 5


def test_an_interrupt_outside_the_search_is_a_clean_130_and_records_are_readable(
    tmp_path, capsys, monkeypatch
):
    # Ctrl-C while the report is being drawn (after the search and its records): no
    # traceback, status 130; the run's files are readable as the history beside them is
    import rbbo.report

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(rbbo.report, "plot_convergence", interrupted)
    run = tmp_path / "run"
    argv = ["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
            "--out", str(run)]  # fmt: skip
    assert main(argv) == 130
    assert capsys.readouterr().err.endswith("interrupted\n")
    modes = {p.name: p.stat().st_mode & 0o777 for p in run.iterdir() if p.is_file()}
    assert modes["config.json"] == modes["summary.json"] == modes["history.jsonl"]


def test_output_paths_that_cannot_be_written_are_usage_errors(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    err = _error(capsys, ["optimize", "synthetic", *TINY, "--iterations", "2",
                          "--executor", "serial", "--out", str(blocker / "run")])  # fmt: skip
    assert "cannot create the run directory" in err
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    png = tmp_path / "new" / "folder" / "plot.png"
    assert main(["report", str(run), "--png", str(png)]) == 0
    assert png.exists()


def test_report_png_that_matplotlib_cannot_write_is_a_usage_error(tmp_path, capsys):
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    # an unknown format, and none (matplotlib would write plot.png and report "plot")
    for name in ("plot.txt", "plot"):
        err = _error(capsys, ["report", str(run), "--png", str(tmp_path / name)])
        assert f"--png {tmp_path / name}: the file name must end in one of" in err
        assert ".png" in err and ".pdf" in err
    assert not (tmp_path / "plot.png").exists()
    folder = tmp_path / "taken.png"  # a folder where the plot should go
    folder.mkdir()
    err = _error(capsys, ["report", str(run), "--png", str(folder)])
    assert f"cannot write the plot {folder}" in err
    assert main(["report", str(run), "--png", str(tmp_path / "plot.PDF")]) == 0
    assert (tmp_path / "plot.PDF").read_bytes()[:4] == b"%PDF"


def test_help_prints_plain_text(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "rbbo: optimise a control space B_c from the command line." in out
    assert "``" not in out


def test_console_entry_point_exit_status():
    """The real process: ``python -m rbbo`` (what the ``rbbo`` script runs) exits with 2."""
    proc = subprocess.run([sys.executable, "-m", "rbbo", "optimize", "synthetic", "--budget",
                           "soon"], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip() == "rbbo: error: argument --budget: invalid duration 'soon'; use " \
        "e.g. 30m, 2h, 1h30m, 45s"  # fmt: skip


def test_the_console_script_says_a_warning_in_one_line(tmp_path, capsys):
    # Python's own display named the script's line and echoed it ("sys.exit(main())"); the
    # command says a warning as it says an error.
    run = tmp_path / "run"
    assert main(["optimize", "synthetic:noise=0.01", *TINY, "--iterations", "4",
                 "--executor", "serial", "--out", str(run), "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    with open(run / "history.jsonl", "a") as f:
        f.write('{"index": 9, "R')  # torn by a kill
    proc = subprocess.run([sys.executable, "-m", "rbbo", "resume", str(run), "--no-progress"],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert [x for x in lines if "warning" in x.lower()] == [
        f"rbbo: warning: {run}/history.jsonl: dropped a truncated last line (15 bytes, an "
        "evaluation that was being written when the run stopped); kept in "
        "history.jsonl.truncated (TruncatedHistoryWarning)"
    ]
    assert not any("sys.exit" in x for x in lines)


@pytest.mark.parametrize(
    ("text", "seconds"), [("30m", 1800), ("2h", 7200), ("1h30m", 5400), ("45s", 45), ("90", 90)]
)
def test_parse_duration(text, seconds):
    assert parse_duration(text) == seconds


def _start_and_wait(args: list[str], run, evaluations: int) -> subprocess.Popen:
    """``python -m rbbo ARGS`` in a session of its own (a signal can reach its group), once
    ``evaluations`` are recorded in ``run``; the test fails if none are within 90 s."""
    import time

    proc = subprocess.Popen([sys.executable, "-m", "rbbo", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)  # fmt: skip
    history = run / "history.jsonl"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and proc.poll() is None:
        if history.exists() and history.read_text().count("\n") >= evaluations:
            return proc
        time.sleep(0.02)
    proc.kill()
    pytest.fail(f"no {evaluations} evaluations recorded in 90 s: {proc.communicate()[1][-2000:]}")


@pytest.mark.parametrize(
    "how",
    [
        "SIGTERM to the process (a scheduler's time limit)",
        "SIGINT to the group (Ctrl-C)",
        "SIGTERM twice, to the process then its group (timeout)",
    ],
)
def test_a_signal_stops_a_run_cleanly_and_it_resumes(tmp_path, how):
    """The process pool's run stops through the interrupt path: status 130, the resume hint,
    no worker traceback and no evaluation recorded as failed by the stop."""
    import os
    import signal
    import time

    run = tmp_path / "run"
    proc = _start_and_wait(["optimize", "synthetic:delay=0.2", *TINY, "--workers", "2",
                            "--iterations", "500", "--out", str(run)], run, 4)  # fmt: skip
    if how.startswith("SIGTERM twice"):
        os.kill(proc.pid, signal.SIGTERM)
        time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGTERM)
    elif how.startswith("SIGTERM"):
        os.kill(proc.pid, signal.SIGTERM)
    else:
        os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("the run did not stop within 30 s of the signal")
    assert proc.returncode == 130, err
    assert f"interrupted; continue with: rbbo resume {run}" in err
    assert "Traceback" not in err, err
    recorded = _history(run)
    assert recorded and all(h["status"] == "ok" for h in recorded)
    assert main(["resume", str(run), "--iterations", str(len(recorded) + 1), "--workers", "1",
                 "--no-progress"]) == 0  # fmt: skip
    assert len(_history(run)) > len(recorded)
    # each session's record says how it ended (sessions.jsonl)
    from rbbo.store import RunStore

    sessions = RunStore.open(run, repair=False).sessions()
    assert [s["status"] for s in sessions] == ["interrupted", "finished"]


def test_a_deterministic_run_stopped_by_ctrl_c_resumes_into_the_uninterrupted_run(tmp_path):
    """The quick start's kind of run (process workers, --deterministic), stopped by SIGINT
    with evaluations in flight and resumed: its record is the uninterrupted run's, bitwise."""
    args = ["optimize", "synthetic:noise=0.01,delay=0.3", *TINY, "--workers", "2",
            "--deterministic", "--iterations", "12"]  # fmt: skip
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    assert main([*args, "--out", str(whole)]) == 0
    proc = _start_and_wait([*args, "--out", str(broken)], broken, 5)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    stopped = len(_history(broken))
    assert 5 <= stopped < 12 + 2  # stopped before its end: a resume has work left
    assert main(["resume", str(broken), "--no-progress"]) == 0
    key = [(h["index"], h["basis"], h["T"], h["R"], h["kind"]) for h in _history(whole)]
    assert [(h["index"], h["basis"], h["T"], h["R"], h["kind"]) for h in _history(broken)] == key


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_second_signal_does_not_break_off_the_shutdown(signum):
    # ``timeout`` (``-s INT`` too) signals the process and then its group: the second signal
    # arrives while the first one's shutdown runs and must not raise into it.
    shutdown_finished = False
    before = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(KeyboardInterrupt):
            with _terminate_as_interrupt():
                try:
                    os.kill(os.getpid(), signum)
                finally:
                    os.kill(os.getpid(), signum)  # inside the shutdown (the finally blocks)
                    os.kill(os.getpid(), signal.SIGINT)
                    shutdown_finished = True
        assert shutdown_finished
        # Ctrl-C works again for an in-process caller; a late SIGTERM finds the process
        # leaving. After a Ctrl-C, SIGTERM is as it was: left ignored, it was ignored in the
        # rest of this test session and in each process it started (a 120-s job outlived
        # its pool's terminate() in test_rbbo_rl when this test ran first).
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        expected = signal.SIG_IGN if signum == signal.SIGTERM else before
        assert signal.getsignal(signal.SIGTERM) is expected
    finally:
        signal.signal(signal.SIGTERM, before)


@pytest.mark.parametrize("iterations, noted", [(4, True), (5, False)])
def test_a_budget_the_initial_design_fills_is_noted(tmp_path, capsys, iterations, noted):
    # TINY's --init 3 with the identity basis first: 4 evaluations leave the GP none.
    code = main(["optimize", "synthetic", *TINY, "--iterations", str(iterations),
                 "--executor", "serial", "--out", str(tmp_path / "run")])  # fmt: skip
    assert code == 0
    kinds = [h["kind"] for h in _history(tmp_path / "run") if not h["kind"].startswith("confirm")]
    assert (set(kinds) == {"initial"}) == noted
    err = capsys.readouterr().err
    assert ("the GP proposes none" in err) == noted
    if noted:
        assert "--iterations 4 <= 1 + --init 3" in err


def test_rollout_of_an_unfinished_run_replays_its_current_recommendation(tmp_path, capsys):
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=6, n_confirm=2, acq_random=64,
                        acq_starts=2, gp_restarts=0)  # fmt: skip
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    opt.run(objective, confirm=False)  # stopped before its confirmation, as if interrupted
    opt.store.close()
    (tmp_path / "run" / "best_basis.npy").unlink()
    assert main(["rollout", str(tmp_path / "run"), "--seed", "3"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("R = ")
    assert "the run has not finished: replaying its current recommendation" in captured.err
    # confirm is for a finished run: this one is pointed to resume, which confirms at its end
    err = _error(capsys, ["confirm", str(tmp_path / "run")])
    assert "has not finished its search (6 evaluations recorded): rbbo resume" in err


def test_a_new_run_on_a_robot_of_your_own_records_its_planner_and_resumes(tmp_path, capsys):
    # (a regression of 2026-12-05's predecessor: the check that refuses a stored run from
    # before the planner record also refused every new run on a robot without tuned defaults)
    run = tmp_path / "own"
    args = ["optimize", "softrom_gym/SoftRobot-v0", "--env-kwarg", "robot=beam",
            "--sim-dim", "6", "--control-dim", "2", "--init", "1", "--iterations", "2",
            "--t-max", "1", "--settle-time", "0.5", "--confirm-seeds", "2", "--no-progress",
            "--mpc", "samples=4", "--mpc", "noise=0.2:0.1", "--out", str(run)]  # fmt: skip
    assert main(args) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["objective"]["planner"]["settings"]["seed_periods"] == [40 / 3, 10.0]
    # --mpc overrides are the run's: stored, recorded in its planner, kept on resume (a
    # per-dimension noise, a tuple, is stored as a JSON list and read back as the same)
    assert config["objective"]["planner_kwargs"] == {"samples": 4, "noise": [0.2, 0.1]}
    settings = config["objective"]["planner"]["settings"]
    assert (settings["samples"], settings["noise"]) == (4, [0.2, 0.1])
    assert main(["resume", str(run), "--iterations", "3", "--no-progress"]) == 0
    capsys.readouterr()
    # resumed, searched on, and ended with its summary: finished, whether or not the
    # recommendation changed (an unchanged one is not confirmed again)
    assert main(["rollout", str(run), "--seconds", "1"]) == 0
    assert "has not finished" not in capsys.readouterr().err


def test_a_bad_mpc_setting_is_a_usage_error_before_the_run(tmp_path, capsys):
    base = ["optimize", "softrom_gym/SoftRobot-v0", "--env-kwarg", "robot=beam",
            "--sim-dim", "6", "--control-dim", "2", "--iterations", "2",
            "--out", str(tmp_path / "r")]  # fmt: skip
    err = _error(capsys, [*base, "--mpc", "samplez=4"])
    assert "unknown MPPISettings setting 'samplez'" in err
    assert not (tmp_path / "r").exists()
    err = _error(capsys, [*base, "--mpc", "samples"])
    assert "expected key=value pairs, got 'samples'" in err
    err = _error(capsys, [*base, "--mpc", "noise=0.1:0.2:0.3"])
    assert (
        "noise has 3 standard deviations, one per control dimension, but the env has C = 2" in err
    )
    assert not (tmp_path / "r").exists()
    err = _error(capsys, ["optimize", "synthetic", "--iterations", "2", "--mpc", "samples=4",
                          "--out", str(tmp_path / "s")])  # fmt: skip
    assert "--mpc is for an env, not the synthetic objective" in err


def test_baselines_take_a_runs_mppi_overrides_for_their_mpc_rows(tmp_path, capsys):
    from rbbo import RBBO, RBBOConfig
    from rbbo.cli import _run_mppi_overrides

    for controller, expected in (("mppi", {"samples": 4}), ("gn", {})):
        spec = {
            "kind": "env",
            "env_id": "softrom_gym/BeamWalk-v0",
            "controller": controller,
            "planner_kwargs": {"samples": 4} if controller == "mppi" else {"fd_step": 0.2},
        }
        RBBO.create(tmp_path / controller, RBBOConfig(6, 2), objective_spec=spec)
        assert _run_mppi_overrides(tmp_path / controller) == expected
    # a Gauss-Newton run's overrides are not MPPI's: said, and left out
    assert "planned with gn and --mpc {'fd_step': 0.2}" in capsys.readouterr().err


def test_r_is_measured_from_the_first_env_step_after_the_settle_time():
    import types

    from rbbo.cli import _measured_from

    def objective(settle, **env_kwargs):
        return types.SimpleNamespace(env_id="softrom_gym/BeamWalk-v0", env_kwargs=env_kwargs,
                                     settle_time=settle)  # fmt: skip

    # (rollout --seconds 0.52 after a 0.51-s settle time was an empty span: a traceback)
    assert _measured_from(objective(0.51)) == pytest.approx(0.525)
    assert _measured_from(objective(2.0)) == pytest.approx(2.0)
    assert _measured_from(objective(0.51, frame_skip=10)) == pytest.approx(0.55)
    # (--t-max 1.01 after a 1-s settle time passed optimize's check, and every evaluation
    # then failed: the episode is round(1.01 / 0.025) = 40 whole steps, R counts from the 40th)
    from rbbo.cli.rollout import _measures_r

    assert not _measures_r(objective(1.0), 1.01)
    assert not _measures_r(objective(1.0), 1.0125)  # (40.5 steps round to 40)
    assert _measures_r(objective(1.0), 1.02)
    assert not _measures_r(objective(0.51), 0.52) and _measures_r(objective(0.51), 0.55)


def test_evaluations_that_keep_failing_exit_1_with_one_line(tmp_path, capsys, monkeypatch):
    """Status 1 (not 2, not a traceback) is how a script tells a broken objective from bad
    input; the record stays for a resume once the cause is fixed."""
    from rbbo.objective import SyntheticObjective

    def broken(self, basis, T, seed):
        raise OSError("simulator library missing")

    monkeypatch.setattr(SyntheticObjective, "__call__", broken)
    run = tmp_path / "run"
    code = main(["optimize", "synthetic", *TINY, "--iterations", "30", "--executor", "serial",
                 "--out", str(run)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1
    assert err == ("rbbo: error: the last 10 evaluations all failed, the last with: OSError: "
                   "simulator library missing; the run stopped (its record is kept; resume it "
                   f"with: rbbo resume {run})\n")  # fmt: skip
    assert len(_history(run)) == 10
    monkeypatch.undo()
    assert main(["resume", str(run), "--no-progress"]) == 0


def test_a_run_none_of_whose_evaluations_succeeded_names_no_best_basis(tmp_path, capsys,
                                                                     monkeypatch):  # fmt: skip
    """The closing line named best_basis.npy where no evaluation had succeeded and none was
    written (a review, session 54)."""
    from rbbo.objective import SyntheticObjective

    def broken(self, basis, T, seed):
        raise OSError("simulator library missing")

    monkeypatch.setattr(SyntheticObjective, "__call__", broken)
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "2", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert not (run / "best_basis.npy").exists()
    assert f"run directory: {run}  (best basis: none yet, plot:" in out


@pytest.mark.parametrize(("limit", "shown"), [(["--iterations", "5"], "5/5"),
                                              (["--budget", "1s"], "0m00s left")])  # fmt: skip
def test_the_default_progress_bar_shows_evaluations_best_r_and_time_left(tmp_path, capsys, limit,
                                                                        shown):  # fmt: skip
    """Every test ran with --no-progress, so the bar users see by default never ran."""
    argv = [a for a in TINY if a != "--no-progress"]
    assert main(["optimize", "synthetic", *argv, *limit, "--executor", "serial",
                 "--out", str(tmp_path / "run")]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert shown in err and "best R 0." in err and "rbbo (confirming R_init, R*)" in err
    if "5/5" in shown:
        # each search evaluation moves the bar one step and shows the best R so far; the
        # confirmations move it no further
        kinds = ("initial", "acquisition")
        search = [h["R"] for h in _history(tmp_path / "run") if h["kind"] in kinds]
        shown_best = dict(re.findall(r"(\d+)/5 \[[^]]*best R ([-\d.e]+)\]", err))
        running = [f"{max(search[: k + 1]):.4g}" for k in range(len(search))]
        assert list(shown_best) == [str(k) for k in range(1, 6)]
        assert list(shown_best.values()) == running
        assert re.search(r"\b5/5 \[", err.split("\r")[-1])  # (past its total: "7eval [")


def test_runs_that_cannot_do_what_is_asked_are_usage_errors(tmp_path, capsys):
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    spec = SyntheticObjective(6, 2).spec()
    RBBO.create(tmp_path / "new", RBBOConfig(6, 2, n_init=3), objective_spec=spec).store.close()
    err = _error(capsys, ["rollout", str(tmp_path / "new")])
    assert f"{tmp_path / 'new'} has no successful evaluation at T_max yet: no recommendation" in err
    RBBO.create(tmp_path / "bare", RBBOConfig(6, 2, n_init=3)).store.close()
    err = _error(capsys, ["resume", str(tmp_path / "bare")])
    assert f"{tmp_path / 'bare'}/config.json does not say what the objective is" in err
    # an objective record without its kind (a hand edit) says the same, not KeyError: 'kind'
    RBBO.create(tmp_path / "kindless", RBBOConfig(6, 2, n_init=3),
                objective_spec={"env_id": "CrossWalk-v0"}).store.close()  # fmt: skip
    err = _error(capsys, ["resume", str(tmp_path / "kindless")])
    assert f"{tmp_path / 'kindless'}/config.json does not say what the objective is" in err
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    # the run's executor is serial: an address alone (without --executor ray) is refused
    assert "--address is for --executor ray" in _error(capsys, ["resume", str(run), "--address",
                                                                "auto"])  # fmt: skip
    blocker = tmp_path / "file"
    blocker.write_text("")
    err = _error(capsys, ["report", str(run), "--png", str(blocker / "sub" / "p.png")])
    assert f"cannot write --png {blocker / 'sub' / 'p.png'}: " in err


def test_optimize_without_a_limit_runs_for_thirty_minutes(tmp_path, capsys, monkeypatch):
    import rbbo.cli.optimize

    limits = []

    def execute(opt, executor, iterations, budget, *args):
        executor.shutdown()
        limits.append((iterations, budget))
        return 0

    monkeypatch.setattr(rbbo.cli.optimize, "_execute", execute)
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--executor", "serial", "--out", str(run)]) == 0
    assert limits == [(None, 1800.0)]
    settings = json.loads((run / "config.json").read_text())["rbbo"]
    assert (settings["max_evaluations"], settings["budget_s"]) == (None, 1800.0)


def test_optimize_gives_the_run_its_seed_seeds_and_optimizer(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "2", "--seed", "7",
                 "--seeds", "2", "--optimizer", "cg", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    settings = json.loads((run / "config.json").read_text())["rbbo"]
    assert (settings["seed"], settings["seeds"], settings["optimizer"]) == (7, 2, "cg")
    search = [h for h in _history(run) if not h["kind"].startswith("confirm")]
    assert [h["seeds"] for h in search] == [[7, 8], [7, 8]]
    assert [len(h["R_seeds"]) for h in search] == [2, 2]


def test_resume_runs_on_the_workers_and_the_executor_it_is_given(tmp_path, capsys):
    from rbbo import RBBO, RBBOConfig, SyntheticObjective
    from rbbo.store import RunStore

    run = tmp_path / "run"
    execution = {"executor": "process", "workers": 2, "timeout_s": 600.0, "address": None,
                 "deterministic": False}  # fmt: skip
    RBBO.create(run, RBBOConfig(6, 2, n_init=3, max_evaluations=2, n_confirm=0),
                objective_spec=SyntheticObjective(6, 2).spec(),
                extra={"execution": execution}).store.close()  # fmt: skip
    assert main(["resume", str(run), "--workers", "1", "--no-progress"]) == 0
    # a serial session of a two-worker run: one worker, not a refusal of the stored count
    assert main(["resume", str(run), "--iterations", "3", "--executor", "serial",
                 "--no-progress"]) == 0  # fmt: skip
    sessions = RunStore.open(run, repair=False).sessions()
    assert [(s["workers"], s["status"]) for s in sessions] == [(1, "finished"), (1, "finished")]
    assert [h["worker"] for h in _history(run)] == ["process-0", "process-0", "main"]
    # a count of workers one executor cannot take is refused, not dropped
    capsys.readouterr()
    assert main(["resume", str(run), "--executor", "serial", "--workers", "2"]) == 2
    err = capsys.readouterr().err
    assert "rbbo: error: --executor serial runs one evaluation at a time, in this process; " \
        "--workers 2 needs --executor process" in err  # fmt: skip


def test_an_interrupted_confirm_exits_130_and_loses_nothing(tmp_path, capsys, monkeypatch):
    from rbbo.objective import SyntheticObjective
    from rbbo.store import RunStore

    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    before = (run / "history.jsonl").read_bytes()

    def interrupted(self, basis, T, seed):
        raise KeyboardInterrupt

    monkeypatch.setattr(SyntheticObjective, "__call__", interrupted)
    assert main(["confirm", str(run)]) == 130
    assert capsys.readouterr().err == (
        f"\ninterrupted; nothing is lost: run rbbo confirm {run} again\n"
    )
    assert (run / "history.jsonl").read_bytes() == before
    sessions = RunStore.open(run, repair=False).sessions()
    assert [(s["command"], s["status"]) for s in sessions][-1] == ("confirm", "interrupted")
    monkeypatch.undo()
    assert main(["confirm", str(run)]) == 0


def test_confirm_of_a_run_without_confirmation_seeds_says_so(tmp_path, capsys):
    # (not "resume finishes it and measures R_init and R*": it would measure neither)
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=4, n_confirm=0, acq_random=64,
                        acq_starts=2, gp_restarts=0)  # fmt: skip
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec(),
                      extra={"execution": {"executor": "serial", "workers": 1,
                                           "timeout_s": None}})  # fmt: skip
    opt.run(objective)
    opt.tell(opt.ask().index, 0.1)  # searched on after its summary: not finished
    opt.store.close()
    err = _error(capsys, ["confirm", str(tmp_path / "run")])
    assert "the run was made with no confirmation seeds (n_confirm = 0)" in err


def test_report_reads_a_run_that_is_still_writing_and_changes_nothing(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    with open(run / "history.jsonl", "a") as f:
        f.write('{"index": 9, "R')  # the line the run's process is writing right now
    before = (run / "history.jsonl").read_bytes()
    # as a run whose first session has not finished (both are written when one does)
    (run / "best_basis.npy").unlink()
    (run / "summary.json").unlink()
    assert main(["report", str(run)]) == 0
    assert (run / "history.jsonl").read_bytes() == before
    assert not (run / "best_basis.npy").exists()
    err = f"no best_basis.npy yet (no session has finished: rbbo resume {run})"
    assert err in capsys.readouterr().err
    assert not (run / "history.jsonl.truncated").exists()


def test_a_resume_refused_for_its_executor_changes_nothing_in_the_run(tmp_path, capsys):
    # (found by helper-58's audit) `resume --iterations 4 --executor serial --workers 2` wrote
    # the new limit to config.json, said so, and only then refused the executor: a refused
    # command changed the run
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    run = tmp_path / "run"
    RBBO.create(run, RBBOConfig(6, 2, n_init=3, max_evaluations=2, n_confirm=0),
                objective_spec=SyntheticObjective(6, 2).spec()).store.close()  # fmt: skip
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    err = _error(capsys, ["resume", str(run), "--iterations", "4", "--executor", "serial",
                          "--workers", "2"])  # fmt: skip
    assert err == ("rbbo: error: --executor serial runs one evaluation at a time, in this "
                   "process; --workers 2 needs --executor process (or ray)\n")  # fmt: skip
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before


def test_a_confirm_that_fails_stops_its_executor(tmp_path, capsys, monkeypatch):
    # (helper-58's audit) a confirm whose measurement raised left its executor's workers to
    # the interpreter's exit; it now stops them as the interrupted confirm does
    import rbbo.cli.optimize as cli_optimize
    from rbbo.optimizer import RBBO

    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    made = []

    def recording_executor(objective, execution):
        made.append(real(objective, execution))
        stops = made[-1].shutdown
        made[-1].stopped = []
        made[-1].shutdown = lambda wait=True: (made[-1].stopped.append(wait), stops(wait=wait))
        return made[-1]

    def fails(self, executor):
        raise RuntimeError("a worker failed")

    real = cli_optimize._make_executor
    monkeypatch.setattr(cli_optimize, "_make_executor", recording_executor)
    monkeypatch.setattr(RBBO, "confirm_again", fails)
    with pytest.raises(RuntimeError, match="a worker failed"):
        main(["confirm", str(run)])
    assert len(made) == 1 and made[0].stopped == [False]


def test_a_run_directory_that_cannot_be_locked_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    """A read-only run directory (an archived copy, a read-only mount) cannot take the writer's
    lock: resume and confirm say so in one line naming the lock file, not with a traceback,
    and report still reads it (found with a read-only bind mount of a finished run)."""
    import errno

    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if str(path).endswith(".rbbo.lock"):
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    for command in (["resume", str(run), "--no-progress"], ["confirm", str(run)]):
        err = _error(capsys, command)
        assert f"cannot lock {run} to write it" in err
        assert "Read-only file system" in err and ".rbbo.lock" in err
    assert main(["report", str(run), "--png", str(tmp_path / "plot.png")]) == 0


def test_a_disk_that_fills_during_a_run_is_a_one_line_error_and_the_run_resumes(
    tmp_path, capsys, monkeypatch
):
    """A write the system refuses mid-run (a full disk) stops the run with one line naming
    the run and how to go on, exit status 1, not a traceback; what was recorded is kept
    (found filling a 28 kB tmpfs under a run)."""
    import errno

    from rbbo.store import run_store

    real_append = run_store._append_line
    calls = []

    def filling(path, line, end_partial=False):
        calls.append(path)
        if len(calls) > 8:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_append(path, line, end_partial)

    monkeypatch.setattr(run_store, "_append_line", filling)
    run = tmp_path / "run"
    with pytest.warns(RuntimeWarning, match="end of this session was not recorded"):
        code = main(["optimize", "synthetic", *TINY, "--iterations", "8", "--executor",
                     "serial", "--out", str(run)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1
    assert err.count("\n") == 1 and err.startswith("rbbo: error: ")
    assert "No space left on device" in err and f"rbbo resume {run}" in err
    recorded = len(_history(run))
    monkeypatch.undo()
    assert main(["resume", str(run), "--no-progress"]) == 0
    assert len(_history(run)) > recorded
    # a confirm the disk refuses: one line too, and the run as it was
    capsys.readouterr()
    before = (run / "history.jsonl").read_bytes()

    def full(path, line, end_partial=False):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(run_store, "_append_line", full)
    code = main(["confirm", str(run)])
    err = capsys.readouterr().err
    assert code == 1
    assert err == (f"rbbo: error: {run}: [Errno 28] No space left on device; run rbbo "
                   f"confirm {run} again once it can be written\n")  # fmt: skip
    assert (run / "history.jsonl").read_bytes() == before


def test_a_plot_that_cannot_be_written_after_a_run_leaves_the_run_finished(
    tmp_path, capsys, monkeypatch
):
    """The convergence plot is drawn after the run has finished and recorded its result: a
    plot the disk refuses is a warning (rbbo report draws it later), and the table is
    printed; a run whose directory cannot take the plot is still readable by rbbo report
    (found with a full tmpfs and with a read-only bind mount)."""
    import errno

    from rbbo import report

    def refused(opt, path, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report, "plot_convergence", refused)
    run = tmp_path / "run"
    code = main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0
    assert "R_init" in out
    assert f"cannot write the plot {run / 'convergence.png'}" in err
    assert "No space left on device" in err and "Traceback" not in err
    assert (run / "summary.json").is_file() and (run / "best_basis.npy").is_file()
    # rbbo report of that run: the table, and the plot it cannot write named
    code = main(["report", str(run)])
    out, err = capsys.readouterr()
    assert code == 0
    assert "R_init" in out
    assert f"cannot write the plot {run / 'convergence.png'}" in err


def test_a_summary_edited_into_other_json_is_read_as_corrupted(tmp_path, capsys):
    """summary.json is rewritten when a session ends; one that does not parse is passed over
    by resume, and so must one that parses to something else than an object (an
    AttributeError traceback from rbbo resume; found hand-editing summary.json to [1, 2])."""
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    (run / "summary.json").write_text("[1, 2]\n")
    capsys.readouterr()
    assert main(["resume", str(run), "--iterations", "5", "--no-progress"]) == 0
    assert json.loads((run / "summary.json").read_text())["evaluations"] == 5


@pytest.mark.parametrize(("edit", "match"), [
    (lambda c: c.update(execution=5), "'execution' must be a JSON object, got 5"),
    (lambda c: c.update(objective=3), "'objective' must be a JSON object, got 3"),
    (lambda c: c["execution"].pop("workers"), None),  # (a default: one worker)
    (lambda c: c["execution"].update(workers="two"), "workers must be a positive integer, got "
                                                     "'two'"),
    (lambda c: c["execution"].update(timeout_s=-1), "timeout_s must be null or a positive "
                                                    "number of seconds, got -1"),
    (lambda c: c["execution"].update(executor="bogus"), "executor must be one of process, ray, "
                                                        "serial, got 'bogus'"),
])  # fmt: skip
def test_a_hand_edited_execution_or_objective_in_config_json_is_named(tmp_path, capsys, edit,
                                                                      match):  # fmt: skip
    """config.json's "execution" and "objective" were read unchecked: an edit that made one
    no object, or dropped workers, was a TypeError / KeyError / AttributeError traceback from
    resume, confirm or report, and a negative timeout_s was taken (found hand-editing the
    config.json of a finished synthetic run)."""
    run = tmp_path / "run"
    main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
          "--out", str(run)])  # fmt: skip
    config = json.loads((run / "config.json").read_text())
    edit(config)
    (run / "config.json").write_text(json.dumps(config))
    capsys.readouterr()
    if match is None:
        assert main(["resume", str(run), "--iterations", "5", "--no-progress"]) == 0
        return
    commands = [["resume", str(run), "--iterations", "5", "--no-progress"], ["confirm", str(run)]]
    if "objective" in match:
        commands.append(["report", str(run)])
    for command in commands:
        err = _error(capsys, command)
        assert f"{run}/config.json has invalid" in err and match in err
    assert len(_history(run)) == 6  # nothing evaluated


def test_a_quoted_home_folder_in_a_path_option_is_the_home_folder(tmp_path, capsys, monkeypatch):
    # no shell expands "~" quoted (or in --out=~/run): read as the home folder, as a robot's
    # mesh path and control_basis are, never as a folder named "~" in the working directory
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    args = ["optimize", "synthetic", *TINY, "--iterations", "3", "--executor", "serial"]
    assert main([*args, "--out", "~/run"]) == 0
    assert (tmp_path / "home" / "run" / "history.jsonl").is_file()
    assert main(["report", "~/run", "--png", "~/plots/run.png"]) == 0
    assert (tmp_path / "home" / "plots" / "run.png").is_file()
    assert not (tmp_path / "~").exists()
    capsys.readouterr()


def test_report_of_several_runs_reports_every_good_one_and_names_each_bad_one(tmp_path, capsys):
    # it stopped at the first bad directory: the good runs after it were never reported
    good = [tmp_path / "a", tmp_path / "b"]
    for run in good:
        assert main(["optimize", "synthetic", *TINY, "--iterations", "4",
                     "--executor", "serial", "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    empty, missing = tmp_path / "empty", tmp_path / "missing"
    empty.mkdir()
    code = main(["report", str(empty), str(good[0]), str(missing), str(good[1])])
    out, err = capsys.readouterr()
    assert code == 2
    assert len(out.splitlines()[2:4]) == 2 and all(" 6  2 " in r for r in out.splitlines()[2:4])
    errors = [line for line in err.splitlines() if line.startswith("rbbo: error: ")]
    assert errors == [f"rbbo: error: {empty} is not an RBBO run directory (no config.json)",
                      f"rbbo: error: {missing} is not a directory",
                      "rbbo: error: 2 of 4 run directories could not be reported"]  # fmt: skip
    assert all(f"{run}: plot " in err for run in good)
    # the status is the worst of them: a read the system refused (1) after a directory that
    # cannot be used (2) leaves it 2, and alone it is 1
    broken = tmp_path / "broken"
    shutil.copytree(good[0], broken)
    (broken / "history.jsonl").unlink()
    (broken / "history.jsonl").mkdir()
    assert main(["report", str(empty), str(broken)]) == 2
    assert main(["report", str(broken)]) == 1
    capsys.readouterr()
    # one bad directory alone is a one-line usage error, as before
    assert _error(capsys, ["report", str(missing)]) == (
        f"rbbo: error: {missing} is not a directory\n"
    )


def test_each_commands_help_says_what_it_does_and_what_its_arguments_are(capsys):
    # their --help printed no description, a bare DIR, and a --budget without its format or
    # that a new limit replaces both stored ones (a run's --iterations limit is dropped)
    for command, wanted in (
        ("report", ["Print the table and write convergence.png", "DIR a run directory",
                    "the others are still reported"]),
        ("resume", ["Continue a run from its directory", "DIR the run directory", "e.g. 30m, 2h",
                    "replaces both of the run's stored limits"]),
        # (as were those of optimize, confirm, rollout, baselines and reproduce)
        ("optimize", ["Optimise B_c for an env", "then measures R_init", "rbbo resume, report",
                      "with --budget too, the first limit reached ends it"]),
        ("confirm", ["Measure R_init and R* of a finished run again", "DIR the run directory"]),
        ("rollout", ["Replay the best B_c with MPC: one episode", "DIR the run directory"]),
        ("baselines", ["PPO and SAC (Stable-Baselines3) beside the MPC: trains", "[rl] extra"]),
        ("reproduce", ["Reproduce the paper's results", "resumes every part"]),
        # and `rbbo --help` listed the commands only: the overview's examples close it now
        (None, ["examples: rbbo optimize softrom_gym/CrossWalk-v0", "rbbo resume runs/"]),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            main([command, "--help"] if command else ["--help"])
        assert exit_.value.code == 0
        out = " ".join(capsys.readouterr().out.split())
        for text in wanted:
            assert " ".join(text.split()) in out, (command, text, out)


_OWN_PLANNER = """
import numpy as np

from controllers import Planner


class KeepOrRest(Planner):
    name = "keep-or-rest"

    def optimise(self, state):
        knots = self.spline.knots
        both = np.stack([knots, np.zeros_like(knots)])
        j = self.evaluate_knots(state, both).objective
        self.spline.knots = both[int(np.argmax(j))]
        self.last_.update(objective_start=float(j[0]), objective_best=float(j.max()))
"""


def test_optimize_and_resume_with_a_planner_of_ones_own_in_worker_processes(
    tmp_path, capsys, monkeypatch
):
    """--controller module:Class from the directory that holds the module (the console
    script does not put it on sys.path): the spawned worker imports it by the recorded name,
    and resume finds it again."""
    (tmp_path / "own_rbbo_planner.py").write_text(_OWN_PLANNER)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", os.getcwd())])
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "run"
    mpc = "horizon=4,window=4,knots=2,seed_horizon=4,threads=1"
    argv = ["optimize", "softrom_gym/SoftRobot-v0", "--env-kwarg", "robot=beam",
            "--env-kwarg", "task=swim", "--env-kwarg", "resolution=6", "--sim-dim", "6",
            "--control-dim", "2", "--controller", "own_rbbo_planner:KeepOrRest", "--mpc", mpc,
            "--t-max", "0.1", "--settle-time", "0", "--init", "1", "--iterations", "2",
            "--confirm-seeds", "1", "--workers", "1", "--no-progress",
            "--out", str(run)]  # fmt: skip
    try:
        assert main(argv) == 0, capsys.readouterr()
        objective = json.loads((run / "config.json").read_text())["objective"]
        assert objective["controller"] == "own_rbbo_planner:KeepOrRest"
        assert objective["planner"]["name"] == "keep-or-rest"
        history = _history(run)
        assert history and all(h["status"] == "ok" for h in history), history
        assert main(["resume", str(run), "--iterations", "3", "--no-progress"]) == 0
        assert len([h for h in _history(run) if not h["kind"].startswith("confirm")]) == 3
    finally:
        sys.modules.pop("own_rbbo_planner", None)


def test_resume_gives_a_run_a_new_timeout_and_keeps_it(tmp_path, capsys, monkeypatch):
    # rbbo resume had no --timeout: a run whose evaluations timed out could only be resumed
    # into more timeouts
    import rbbo.cli.optimize as cli_optimize
    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    run = tmp_path / "run"
    execution = {"executor": "process", "workers": 1, "timeout_s": 0.2, "address": None,
                 "deterministic": False}  # fmt: skip
    RBBO.create(run, RBBOConfig(6, 2, n_init=3, max_evaluations=1, n_confirm=0),
                objective_spec=SyntheticObjective(6, 2, delay=0.5).spec(),
                extra={"execution": execution}).close()  # fmt: skip
    made = []
    real = cli_optimize._make_executor
    monkeypatch.setattr(cli_optimize, "_make_executor",
                        lambda objective, execution: made.append(dict(execution))
                        or real(objective, execution))  # fmt: skip
    assert main(["resume", str(run), "--timeout", "1m", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert (f"{run}: its per-evaluation limit (--timeout) is now 60 s (was 0.2 s), stored in "
            "config.json for later resumes") in err  # fmt: skip
    assert [(h["status"], h["error"]) for h in _history(run)] == [("ok", None)]  # 0.5 s > 0.2 s
    assert json.loads((run / "config.json").read_text())["execution"]["timeout_s"] == 60.0
    # a later plain resume (an interrupted run's hint) keeps it
    assert main(["resume", str(run), "--iterations", "2", "--executor", "serial",
                 "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    assert [m["timeout_s"] for m in made] == [60.0, 60.0]
    # refused as optimize refuses it, changing nothing
    before = (run / "config.json").read_bytes()
    for argv in (["--executor", "serial", "--timeout", "5m"], ["--timeout", "-5m"],
                 ["--timeout", "5q"]):  # fmt: skip
        err = _error(capsys, ["resume", str(run), *argv])
        assert ("--timeout is for --executor process or ray" in err
                or "argument --timeout: duration must be positive, got '-5m'" in err
                or "argument --timeout: invalid duration '5q'" in err), err  # fmt: skip
    serial = tmp_path / "serial"
    RBBO.create(serial, RBBOConfig(6, 2, n_init=3, max_evaluations=1, n_confirm=0),
                objective_spec=SyntheticObjective(6, 2).spec(),
                extra={"execution": {**execution, "executor": "serial"}}).close()  # fmt: skip
    err = _error(capsys, ["resume", str(serial), "--timeout", "5m"])
    assert "--timeout is for --executor process or ray: the serial executor" in err
    assert (run / "config.json").read_bytes() == before
    assert len(made) == 2  # (each refused before its executor was made)
    # a resume refused for another reason stores no timeout either
    unlimited = tmp_path / "unlimited"
    RBBO.create(unlimited, RBBOConfig(6, 2, n_init=3, n_confirm=0),
                objective_spec=SyntheticObjective(6, 2).spec(),
                extra={"execution": execution}).close()  # fmt: skip
    kept = (unlimited / "config.json").read_bytes()
    assert "stores no limit" in _error(capsys, ["resume", str(unlimited), "--timeout", "5m"])
    assert (unlimited / "config.json").read_bytes() == kept


def test_edited_run_files_are_named_in_one_line(tmp_path, capsys):
    # an edited config.json's problem or version, or a history field of the wrong type, gave
    # tracebacks in report, resume and confirm (ValueError: Unknown format code 'd', TypeError)
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    config = json.loads((run / "config.json").read_text())
    history = (run / "history.jsonl").read_text()

    def edited(**changes):
        (run / "config.json").write_text(json.dumps({**config, **changes}))
        return [_error(capsys, [command, str(run)]) for command in ("report", "resume", "confirm")]

    for err in edited(problem={"env_id": 5, "N": None}):
        assert "config.json has invalid settings: problem env_id must be a string, got 5" in err
    for err in edited(problem={"env_id": "synthetic", "N": "abc"}):
        assert "problem N must be a count of nodes (an integer >= 0) or null, got 'abc'" in err
    for err in edited(version=99):
        assert (f"{run}/config.json is version 99, written by a newer rbbo (this one reads "
                "versions up to 1): upgrade rbbo to use this run") in err  # fmt: skip
    for err in edited(version="1"):
        assert "'version' must be a positive integer, got '1'" in err
    (run / "config.json").write_text(json.dumps({k: v for k, v in config.items()
                                                 if k != "version"}))  # fmt: skip
    assert main(["report", str(run)]) == 0  # (a run made before versions were recorded)
    capsys.readouterr()
    (run / "config.json").write_text(json.dumps(config))
    lines = history.splitlines()
    record = json.loads(lines[1])
    record["elapsed_s"] = "x"
    (run / "history.jsonl").write_text("\n".join([lines[0], json.dumps(record), *lines[2:]]) + "\n")
    for command in ("report", "resume", "confirm"):
        err = _error(capsys, [command, str(run)])
        assert (f"{run / 'history.jsonl'} line 2 is corrupted (elapsed_s must be a number of "
                "seconds >= 0, got 'x')") in err  # fmt: skip
    assert (run / "history.jsonl").read_text() != history  # (as edited: nothing rewritten)


def test_a_finished_run_whose_best_basis_was_deleted_says_so_and_resume_writes_it(tmp_path, capsys):
    # the report said "no session has finished" of a run that had
    from rbbo.store import RunDirectoryError, RunStore

    run = tmp_path / "run"
    assert main(["optimize", "synthetic", *TINY, "--iterations", "4", "--executor", "serial",
                 "--out", str(run)]) == 0  # fmt: skip
    capsys.readouterr()
    best = (run / "best_basis.npy").read_bytes()
    (run / "best_basis.npy").unlink()
    assert main(["report", str(run)]) == 0
    err = capsys.readouterr().err
    assert (f"best_basis.npy is missing (written when a session finished; rbbo resume {run} "
            "writes it again)") in err  # fmt: skip
    with pytest.raises(RunDirectoryError, match=r"best_basis.npy is missing: it was written "
                       rf"\(evaluation \d+'s basis\) when a session of the run finished; "
                       f"rbbo resume {run} writes it again"):  # fmt: skip
        RunStore.open(run, repair=False).best_basis()
    assert main(["resume", str(run), "--no-progress"]) == 0
    assert (run / "best_basis.npy").read_bytes() == best


INTERRUPTED_IMPORT = """
import sys


class Interrupt:  # Ctrl-C while the simulator's Python side loads
    def find_spec(self, name, path=None, target=None):
        if name == "softrom_gym":
            raise KeyboardInterrupt
        return None


sys.meta_path.insert(0, Interrupt())
from rbbo.cli import main  # as the console script does

sys.exit(main())
"""


def test_ctrl_c_while_the_command_line_starts_exits_130_without_a_traceback(tmp_path):
    # the imports ran before main's handler: a KeyboardInterrupt traceback, exit status -2
    proc = subprocess.run([sys.executable, "-c", INTERRUPTED_IMPORT, "report", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert (proc.returncode, proc.stderr) == (130, "\ninterrupted\n")
