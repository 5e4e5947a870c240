"""``rbbo reproduce`` end to end on one benchmark with a tiny budget and a tiny MPC horizon:
every table and figure written, the report's Table I parsed back against the run's history,
resume without new work, and its usage errors."""

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rbbo.cli import _parser, main
from rbbo.reproduce import ReproducePlan, confidence_interval, parse_markdown

TINY = [
    "reproduce", "--benchmarks", "CrossSwim-v0", "--direction-env", "CrossSwim-v0",
    "--directions", "2", "--iterations", "3", "--init", "1", "--confirm-seeds", "2",
    "--t-min", "1.5", "--t-max", "2", "--settle-time", "1", "--executor", "serial",
    "--workers", "1", "--cost-cs", "1,2", "--reward-cs", "1,2", "--study-seeds", "1",
    "--study-seconds", "2", "--perturbations", "10", "--no-progress", "--rl-steps", "64",
    "--rl-algos", "ppo", "--transfer-sim-dim", "24",
    "--mpc", "horizon=8,period=4,knots=2,window=4,samples=4,seed_horizon=8",
]  # fmt: skip


@pytest.fixture(scope="module")
def reproduction(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    assert main([*TINY, "--out", str(out)]) == 0
    return out


def _history(run_dir):
    return [json.loads(line) for line in (run_dir / "history.jsonl").read_text().splitlines()]


def test_writes_every_table_and_figure(reproduction):
    out = reproduction
    for name in ["REPORT.md", "table1.md", "table1.csv", "reproduce.json", "perturbation.csv",
                 "bo_vs_boca.png", "bo_vs_boca_simulated.png", "directions.png",
                 "perturbation.png",
                 "studies/cost_vs_c.csv", "studies/cost_vs_c.png", "studies/reward_vs_c.csv",
                 "studies/reward_vs_c.png", "transfer.csv", "transfer_table.csv"]:  # fmt: skip
        assert (out / name).is_file(), name
    for run in ["CrossSwim-v0-boca", "CrossSwim-v0-bo", "CrossSwim-v0-dir000",
                "CrossSwim-v0-dir180"]:  # fmt: skip
        assert (out / "runs" / run / "convergence.png").is_file(), run
        assert (out / "runs" / run / "best_basis.npy").is_file(), run
    assert (out / "perturbation.csv").read_text().count("\n") == 1 + 3  # header, 0 and ±10
    rl = out / "rl" / "CrossSwim-v0"
    assert (rl / "baselines.md").is_file() and (rl / "ppo-identity" / "final.zip").is_file()
    # the Table I basis trained too, unless it is the identity (trained once, and said so)
    best = np.load(out / "runs" / "CrossSwim-v0-boca" / "best_basis.npy")
    is_identity = np.array_equal(best, np.eye(20)[:, :3])
    assert len(list(rl.glob("ppo-rbbo-*"))) == (0 if is_identity else 1)
    rl_section = (out / "REPORT.md").read_text().split("## RL baselines on CrossSwim-v0")[1]
    assert ("so it is trained once, as identity" in rl_section) == is_identity
    log = (out / "reproduce.log").read_text()  # the record keeps its own log
    assert re.search(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d session 1: ", log, re.M)
    assert "[CrossSwim-v0-boca] BOCA, budget" in log and "(softrom 0.1.0" in log
    text = (out / "REPORT.md").read_text()
    assert "BO within BOCA's simulated time" in text.split("## BO vs BOCA")[1]
    assert list(_bo_table_matches_histories(text, out)) == ["CrossSwim-v0"]


def test_the_log_prints_r_to_four_significant_digits(reproduction):
    # (the run's summary.json keeps every digit; the log is read by people)
    log = (reproduction / "reproduce.log").read_text()
    done = next(x for x in log.splitlines() if "[CrossSwim-v0-boca] done: " in x)
    summary = json.loads((reproduction / "runs" / "CrossSwim-v0-boca" / "summary.json").read_text())
    assert f"R_init {summary['R_init']:.4g}, R* {summary['R_star']:.4g} (" in done


def _bo_table_matches_histories(text: str, folder, skip_stale: bool = False) -> dict:
    """Parse the report's BO-vs-BOCA table and recompute each cell from the runs' histories;
    returns the rows checked, by benchmark. ``skip_stale``: a row whose run has recorded more
    evaluations since the report was written (a run still going) is not checked."""
    section = text.split("## BO vs BOCA")[1].split("\n## ")[0]
    rows = {}
    for line in section.splitlines():
        if line.startswith("| ") and not line.startswith("| benchmark"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows[cells[0]] = cells
    checked = {}
    for bench, cells in rows.items():
        runs = {}
        for name in ("boca", "bo"):
            run = folder / "runs" / f"{bench}-{name}"
            t_max = json.loads((run / "config.json").read_text())["rbbo"]["t_max"]
            search = [e for e in _history(run) if not e["kind"].startswith("confirm")]
            runs[name] = (search, t_max)

        counts = [len(runs["boca"][0]), len(runs["bo"][0])]
        if skip_stale and [int(cells[6]), int(cells[7])] != counts:
            continue

        def full(evs, t_max):
            return [e for e in evs if e["status"] == "ok" and math.isclose(e["T"], t_max)]

        def minutes(evs):
            return np.cumsum([e["T"] * max(len(e["seeds"]), 1) for e in evs]) / 60.0

        for column, name in ((1, "boca"), (2, "bo")):
            best = max(e["R"] for e in full(*runs[name]))
            assert float(cells[column]) == pytest.approx(best, rel=1e-3), (bench, name)
        spent = {name: minutes(evs)[-1] for name, (evs, _) in runs.items()}
        bo, t_max = runs["bo"]
        within = [e["R"] for e, t in zip(bo, minutes(bo), strict=True)
                  if t <= spent["boca"] + 1e-9 and e["status"] == "ok"
                  and math.isclose(e["T"], t_max)]  # fmt: skip
        if within:
            assert float(cells[3]) == pytest.approx(max(within), rel=1e-3), bench
        boca_spent, bo_spent = (float(v) for v in cells[4].split(" / "))
        assert boca_spent == pytest.approx(spent["boca"], abs=0.051)
        assert bo_spent == pytest.approx(spent["bo"], abs=0.051)
        assert [int(cells[6]), int(cells[7])] == counts
        checked[bench] = cells
    return checked


def test_simulated_time_is_the_sum_of_episode_lengths_over_seeds():
    from types import SimpleNamespace

    from rbbo.reproduce.figures import simulated_minutes

    evs = [SimpleNamespace(T=6.0, seeds=[1]), SimpleNamespace(T=12.0, seeds=[2, 3])]
    assert simulated_minutes(evs).tolist() == [0.1, 0.5]


def test_report_table_matches_the_run_history(reproduction):
    rows = parse_markdown((reproduction / "REPORT.md").read_text())
    assert [r["robot"] for r in rows] == ["Cross"] and rows[0]["task"] == "Swim"
    row = rows[0]
    history = _history(reproduction / "runs" / "CrossSwim-v0-boca")
    confirm = {e["kind"]: e for e in history if e["kind"].startswith("confirm")}
    searched = [e for e in history if not e["kind"].startswith("confirm")]
    assert row["evaluations"] == len(searched) == 3
    for key, kind in (("R_init", "confirm-init"), ("R_star", "confirm-best")):
        mean, half = confidence_interval(confirm[kind]["R_seeds"])
        assert len(confirm[kind]["R_seeds"]) == 2
        assert row[key] == pytest.approx(mean, rel=1e-3, abs=1e-12)
        assert row[f"{key}_ci95"] == pytest.approx(half, rel=0.05)
    gains = np.subtract(confirm["confirm-best"]["R_seeds"], confirm["confirm-init"]["R_seeds"])
    mean, half = confidence_interval(gains)
    assert row["delta"] == pytest.approx(mean, rel=1e-3, abs=1e-9)
    if math.isfinite(half):
        assert row["delta_ci95"] == pytest.approx(half, rel=0.05, abs=1e-9)
    r_init, r_star = row["R_init"], row["R_star"]
    if r_init > 0:
        assert row["improvement_pct"] == pytest.approx(100 * (r_star / r_init - 1), abs=0.1)
    assert row["M"] == 20 and row["C"] == 3 and row["N"] > 0


def test_transfer_table_is_the_bases_measured_in_the_larger_model(reproduction):
    from rbbo.reproduce.tables import read_rows

    rows = read_rows(reproduction / "transfer.csv")
    assert [(r["benchmark"], r["basis"], r["M"]) for r in rows] == [
        ("CrossSwim-v0", "identity", "24"), ("CrossSwim-v0", "best", "24")]  # fmt: skip
    history = _history(reproduction / "runs" / "CrossSwim-v0-boca")
    seeds = next(e for e in history if e["kind"] == "confirm-init")["seeds"]
    assert all(r["seeds"].split() == [str(s) for s in seeds] for r in rows)  # fresh seeds
    init, best = ([float(v) for v in r["R_seeds"].split()] for r in rows)
    report = (reproduction / "REPORT.md").read_text()
    assert "## Table I's control spaces at M = 24" in report
    assert "), 1 worker, controller" in report  # one worker, not "1 workers"
    line = next(x for x in report.splitlines() if x.startswith("| CrossSwim-v0 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    mean, _ = confidence_interval(init)
    assert float(cells[2].split(" ± ")[0]) == pytest.approx(mean, rel=1e-3, abs=1e-12)
    mean, _ = confidence_interval(best)
    assert float(cells[3].split(" ± ")[0]) == pytest.approx(mean, rel=1e-3, abs=1e-12)


def test_status_says_what_each_part_has_done(reproduction, capsys, tmp_path):
    assert main(["reproduce", "--out", str(reproduction), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    table = next(x for x in lines if x.startswith("table "))
    assert "CrossSwim-v0" in table and "done: 3 evaluations" in table
    assert any("2 of 2 bases measured at M = 24" in x for x in lines)
    assert any(x.startswith("perturbation") and "3 of 3 offsets" in x for x in lines)
    assert any(x.startswith("rl ") and "ppo-identity 64/64 steps" in x for x in lines)
    # every stage done: no work besides the budgets is left either
    assert lines[-1] == "optimisation budget left: 0.00 h on 1 worker"
    # a longer budget given on the command line: a rerun would search on, so it is counted
    stored = json.loads((reproduction / "reproduce.json").read_text())
    stored["plan"]["iterations"] = None  # as a budget-bound plan: the budget decides
    (tmp_path / "budget").mkdir()
    (tmp_path / "budget" / "reproduce.json").write_text(json.dumps(stored))
    (tmp_path / "budget" / "runs").symlink_to(reproduction / "runs")
    assert main(["reproduce", "--out", str(tmp_path / "budget"), "--status", "--stages",
                 "table", "--budget-per-benchmark", "1h"]) == 0  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and "min more to search" in lines[0]
    assert 0.9 < float(lines[-1].split("left: ")[1].split(" h")[0]) <= 1.0
    assert main(["reproduce", "--out", str(tmp_path / "none"), "--status"]) == 2
    assert "no reproduce.json" in capsys.readouterr().err


def test_status_shows_the_stages_of_the_stored_plan_and_its_sessions(tmp_path, capsys):
    # a reproduction of Table I alone: no transfer, directions or RL to do, nor budget for them
    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"])
    document = {"plan": plan.to_dict(), "sessions": [{"command": "rbbo reproduce --stages table"}]}
    (tmp_path / "reproduce.json").write_text(json.dumps(document))
    assert main(["reproduce", "--out", str(tmp_path), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        "table        CrossSwim-v0         not started",
        "optimisation budget left: 0.75 h on 2 workers, plus the confirmations",
    ]
    # the stored plan is the last session's: the stages earlier ones ran (recorded with the
    # session, or named by the command of one recorded before they were) are shown too
    document["sessions"][:0] = [
        {"command": "rbbo reproduce --stages=perturbation --out x"},
        {"command": "rbbo reproduce --out x", "stages": ["bo"]},
        # parsed when rbbo still took option prefixes: "--stag" was --stages
        {"command": "rbbo reproduce --stag transfer --out x"},
    ]
    (tmp_path / "reproduce.json").write_text(json.dumps(document))
    assert main(["reproduce", "--out", str(tmp_path), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[:-1]] == ["table", "bo", "transfer", "perturbation"]
    assert lines[-1].endswith("plus the confirmations, the transfer and the perturbation study")


def test_status_narrows_to_the_benchmarks_given_and_refuses_other_settings(tmp_path, capsys):
    plan = ReproducePlan(benchmarks=["CrossSwim-v0", "BeamWalk-v0"], stages=["table"])
    document = {"plan": plan.to_dict(), "sessions": []}
    (tmp_path / "reproduce.json").write_text(json.dumps(document))
    out = ["reproduce", "--out", str(tmp_path), "--status"]
    assert main([*out, "--benchmarks", "softrom_gym/BeamWalk-v0"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "table        BeamWalk-v0          not started",
        "optimisation budget left: 0.75 h on 2 workers, plus the confirmations",
    ]
    assert main(out) == 0  # both, as stored
    assert len(capsys.readouterr().out.splitlines()) == 3
    assert main([*out, "--benchmarks", "TripodWalk-v0,BeamWalk-v0"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"rbbo: error: TripodWalk-v0 is not part of the reproduction in {tmp_path} (its "
        "benchmarks: CrossSwim-v0, BeamWalk-v0)"
    )
    # an experiment-defining setting other than the stored one would be silently ignored
    assert main([*out, "--sim-dim", "30"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"rbbo: error: {tmp_path} was started with other settings (sim_dim 20); --status reads "
        "them from its reproduce.json: leave those options out"
    )


def test_option_prefixes_are_usage_errors(tmp_path, capsys):
    # "--stage table" was taken for --stages here but not where the recorded command is read
    # again (which options a session gave): rbbo takes options only as spelled
    assert main(["reproduce", "--out", str(tmp_path), "--stage", "table", "--status"]) == 2
    assert "unrecognized arguments: --stage table" in capsys.readouterr().err
    # --budget, rbbo optimize's and DESIGN.md's, names the budgets a reproduction has instead;
    # nothing is written
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--budget", "20m"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rbbo: error: rbbo reproduce has no --budget (got 20m): ")
    assert "--budget-per-benchmark DURATION" in err and "--stages table" in err
    assert not (tmp_path / "r").exists()


def test_rerun_resumes_without_new_evaluations(reproduction):
    runs = reproduction / "runs"
    before = {p.name: len(_history(p)) for p in runs.iterdir()}
    measured = ["perturbation.csv", "studies/cost_vs_c.csv", "studies/reward_vs_c.csv"]
    tables = {name: (reproduction / name).read_text() for name in measured}
    assert main([*TINY, "--out", str(reproduction)]) == 0
    after = {p.name: len(_history(p)) for p in runs.iterdir()}
    assert after == before
    # nor is a perturbation offset or a point of the studies measured again
    assert {name: (reproduction / name).read_text() for name in measured} == tables
    assert (reproduction / "transfer.csv").read_text().count("\n") == 1 + 2  # none measured again
    document = json.loads((reproduction / "reproduce.json").read_text())
    assert len(document["sessions"]) == 2
    assert document["sessions"][0]["command"].startswith("rbbo reproduce --benchmarks")
    # every session names the code that ran, and the report says it beside the command
    assert all(s["source"].startswith("softrom ") for s in document["sessions"])
    made_by = (reproduction / "REPORT.md").read_text().split("```")[1]
    assert made_by.count("  # softrom ") == 2


def test_report_says_what_the_whole_record_holds_whichever_stages_ran_last(reproduction, tmp_path):
    # A later session that runs one stage, without the RL flags, rewrites the report from
    # every stage's results: nothing finished earlier is called unfinished, and the RL
    # section says what was trained, not the RL defaults of the last command.
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    cut = TINY.index("--rl-steps")
    later = TINY[:cut] + TINY[cut + 4 :]  # without --rl-steps 64 --rl-algos ppo
    assert main([*later, "--out", str(out), "--stages", "perturbation"]) == 0
    text = (out / "REPORT.md").read_text()
    assert "No part finished yet" not in text and "Under way" not in text
    assert "## Table I" in text and "## 2 walking directions" in text
    assert "## RL baselines on CrossSwim-v0" in text
    assert "PPO (Stable-Baselines3, 64 env steps each" in text
    sessions = json.loads((out / "reproduce.json").read_text())["sessions"]
    assert all(s["machine"] and s["workers"] == 1 for s in sessions[-1:])


def test_stage_progress_counts_parts_done_and_planned(reproduction, tmp_path):
    from rbbo.reproduce.document import _progress_lines
    from rbbo.reproduce.status import stage_progress

    plan = ReproducePlan.from_dict(
        json.loads((reproduction / "reproduce.json").read_text())["plan"]
    )
    done = stage_progress(reproduction, plan)
    assert done == {"table": (1, 1), "bo": (1, 1), "transfer": (1, 1), "directions": (2, 2),
                    "perturbation": (3, 3), "studies": (4, 4), "rl": (1, 1)}  # fmt: skip
    assert _progress_lines(done) == []
    empty = stage_progress(tmp_path, plan)
    assert all(d == 0 for d, _ in empty.values())
    assert _progress_lines(empty)[0].startswith("No part finished yet: table, bo, ")
    partial = _progress_lines({**done, "directions": (1, 2)})
    assert partial[0].startswith("Under way (parts finished of those planned): directions (1 of 2)")


def test_report_only_rewrites_the_report_and_its_copy(reproduction, tmp_path):
    (reproduction / "REPORT.md").unlink()
    copy = tmp_path / "docs" / "REPORT.md"
    assert main(["reproduce", "--out", str(reproduction), "--report-only",
                 "--report", str(copy)]) == 0  # fmt: skip
    assert parse_markdown((reproduction / "REPORT.md").read_text())
    text = copy.read_text()
    assert parse_markdown(text) == parse_markdown((reproduction / "REPORT.md").read_text())
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert links and all((copy.parent / link).is_file() for link in links), links


def test_other_settings_on_an_existing_directory_are_refused(reproduction, capsys):
    argv = [*TINY, "--out", str(reproduction)]
    argv[argv.index("--t-max") + 1] = "3"
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "t_max" in err[0]


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--benchmarks", "Nope-v0"], "Nope-v0"),
        (["--stages", "table,dance"], "dance"),
        (["--cost-cs", "1-x"], "1-x"),
        (["--confirm-seeds", "1"], "confirm_seeds"),
        (["--mpc", "horizon=0"], "horizon"),
        (["--t-min", "1", "--settle-time", "2"], "settle_time"),
        (["--settle-time", "-1"], "need 0 <= settle_time"),
        # the options, and which took their defaults (a tiny run's --t-max 2 under --t-min 4)
        (
            ["--t-max", "2", "--settle-time", "1"],
            "got --settle-time 1, --t-min 4 (default), "
            "--t-max 2: the BOCA runs search episode "
            "lengths T in [--t-min, --t-max]",
        ),
        (["--repeats", "0"], "repeats must be an integer >= 1, got 0"),
        (["--repeats", "two"], "'two'"),
        (["--stages", "studies", "--repeats", "3"], "--repeats 3 runs Table I's RBBO runs"),
        (["--perturbations", "5,x"], "expected numbers like 5,10,20, got '5,x'"),
        (["--perturbations", "5,nan"], "expected finite numbers, got '5,nan'"),
        (["--cost-cs", ","], "expected at least one integer, got ','"),
        (["--reward-cs", "0-3"], "reward_cs must be integers in 1..20, got [0, 1, 2, 3]"),
        (["--control-dim", "30"], "control_dim 30 exceeds sim_dim 20"),
        # C = M passed the plan, wrote reproduce.json, then RBBOConfig's traceback
        (["--control-dim", "20"], "control_dim 20 must be below sim_dim 20 for the RBBO runs"),
        # (A,B kept A without a word)
        (["--direction-env", "BeamWalk-v0,CrossWalk-v0"], "give one benchmark, got BeamWalk"),
        # a per-dimension setting of another length than C: stored, then a traceback in a run
        (["--mpc", "noise=0.3:0.1"], "noise has 2 standard deviations"),
        # of the right length, but the reward-vs-C study runs C = 1 with it
        (["--mpc", "noise=0.3:0.1:0.1"], "stage 'studies' runs the reward-vs-C study at C = 1"),
        (["--stages", "studies", "--study-seconds", "1.5"], "study_seconds 1.5 must exceed"),
    ],
)
def test_bad_arguments_are_one_line_usage_errors(argv, needle, tmp_path, capsys):
    assert main(["reproduce", "--out", str(tmp_path / "x"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rbbo: error:") and needle in err[0]
    assert not (tmp_path / "x").exists()


def test_an_rbbo_run_directory_is_no_reproduction_folder(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["optimize", "synthetic", "--sim-dim", "6", "--control-dim", "2", "--init", "2",
                 "--confirm-seeds", "2", "--iterations", "3", "--executor", "serial",
                 "--no-progress", "--out", str(run)]) == 0  # fmt: skip
    before = sorted(p.name for p in run.iterdir())
    capsys.readouterr()
    assert main([*TINY, "--out", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"rbbo: error: {run} is an RBBO run directory (rbbo optimize's --out); give "
                   "the reproduction a folder of its own with --out"]  # fmt: skip
    assert sorted(p.name for p in run.iterdir()) == before  # (nothing written into the run)


@pytest.mark.parametrize("flag", ["--status", "--report-only", "--no-progress"])
@pytest.mark.parametrize("text", ['{"plan": {"newthing": 1}, "sessions": []}', "{"])
def test_an_unreadable_record_is_a_usage_error_for_status_report_only_and_a_rerun(
    flag, text, tmp_path, capsys
):
    (tmp_path / "reproduce.json").write_text(text)
    assert main(["reproduce", "--out", str(tmp_path), flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a reproduce plan" in err[0]
    assert (tmp_path / "reproduce.json").read_text() == text  # kept for its owner to mend


def test_confidence_interval_is_the_t_interval():
    mean, half = confidence_interval([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert half == pytest.approx(4.302652729911275 / math.sqrt(3))  # t_{0.975, 2} s / sqrt(n)
    assert math.isnan(confidence_interval([1.0])[1])


def test_confidence_interval_of_nothing_is_nan_without_a_warning():
    """No values: NaN mean and half-width, not numpy's 'mean of empty slice' warning."""
    mean, half = confidence_interval([])
    assert math.isnan(mean) and math.isnan(half)


def test_plan_validates_and_round_trips():
    plan = ReproducePlan(benchmarks=["softrom_gym/BeamWalk-v0"], budget_s=60.0)
    assert plan.benchmarks == ["BeamWalk-v0"]
    assert ReproducePlan.from_dict(plan.to_dict()) == plan
    assert plan.differences(ReproducePlan(benchmarks=["BeamWalk-v0"], budget_s=99.0)) == []
    assert plan.differences(ReproducePlan(benchmarks=["BeamWalk-v0"], seed=1)) == ["seed"]
    longer_rl = ReproducePlan(benchmarks=["BeamWalk-v0"], rl_steps=10**5, rl_algos=["ppo"])
    assert plan.differences(longer_rl) == []  # RL runs continue from their checkpoints
    in_order = ReproducePlan(benchmarks=["BeamWalk-v0"], deterministic=True)
    assert plan.differences(in_order) == []  # how results are told, not what is measured
    assert ReproducePlan.from_dict(in_order.to_dict()) == in_order
    stored = plan.to_dict()
    del stored["deterministic"]  # a reproduce.json written before the setting existed
    assert ReproducePlan.from_dict(stored) == plan
    with pytest.raises(ValueError, match="deterministic must be True or False, got 'yes'"):
        ReproducePlan(deterministic="yes")
    np.testing.assert_allclose(ReproducePlan(directions=4).direction_angles_deg(),
                               [0, 90, 180, 270])  # fmt: skip
    with pytest.raises(ValueError, match="perturbations"):
        ReproducePlan(perturbations_deg=[0.0])
    with pytest.raises(
        ValueError, match="transfer_sim_dim must be an integer > sim_dim = 20, got 20"
    ):
        ReproducePlan(transfer_sim_dim=20)
    # C = M leaves RBBO nothing to search, but the studies and RL need no search
    assert ReproducePlan(control_dim=20, stages=["studies", "rl"]).control_dim == 20
    assert "transfer_sim_dim" in plan.differences(ReproducePlan(benchmarks=["BeamWalk-v0"],
                                                                transfer_sim_dim=60))  # fmt: skip
    # more Table I runs sit beside run 0 in folders of their own: a later session may add some
    assert plan.differences(ReproducePlan(benchmarks=["BeamWalk-v0"], repeats=3)) == []
    del stored["repeats"]  # a reproduce.json written before the setting existed: one run
    assert ReproducePlan.from_dict(stored).repeats == 1
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=f"repeats must be an integer >= 1, got {bad!r}"):
            ReproducePlan(repeats=bad)
    assert [plan.table_run("softrom_gym/BeamWalk-v0", k) for k in range(3)] == [
        "BeamWalk-v0-boca", "BeamWalk-v0-boca-run1", "BeamWalk-v0-boca-run2"]  # fmt: skip
    per_algo = ReproducePlan(rl_steps={"ppo": 500_000, "sac": 100_000})
    assert ReproducePlan.from_dict(per_algo.to_dict()) == per_algo
    with pytest.raises(ValueError, match="must name exactly ppo, sac; got ppo"):
        ReproducePlan(rl_steps={"ppo": 500_000})
    with pytest.raises(ValueError, match="steps of sac must be a positive integer, got 0"):
        ReproducePlan(rl_steps={"ppo": 5, "sac": 0})
    # a tuple setting (--mpc noise=0.3:0.1:0.1) is stored as a list: the same plan, not
    # "other settings" (no later session of such a reproduction could run; a review)
    tupled = ReproducePlan(planner_kwargs={"noise": (0.3, 0.1, 0.1)})
    assert tupled.differences(ReproducePlan.from_dict(json.loads(json.dumps(
        tupled.to_dict())))) == []  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"benchmarks": []}, r"unknown benchmark\(s\) \[\]; valid: CrossSwim-v0"),
        ({"benchmarks": ["Nope-v0"]}, r"unknown benchmark\(s\) \['Nope-v0'\]"),
        ({"rl_benchmarks": ["Nope-v0"]}, r"unknown RL benchmark\(s\) \['Nope-v0'\]"),
        ({"rl_algos": ["dqn"]}, r"unknown RL algorithm\(s\) \['dqn'\]; valid: ppo, sac"),
        ({"rl_algos": []}, r"unknown RL algorithm\(s\) \[\]"),
        ({"direction_env": "Nope-v0"}, "unknown direction_env 'Nope-v0'"),
        ({"stages": ["table", "dance"]}, r"unknown stage\(s\) \['dance'\]; valid: table, bo"),
        ({"budget_s": 0.0}, "budget_s must be a positive number, got 0.0"),
        ({"study_seconds": "10"}, "study_seconds must be a positive number, got '10'"),
        ({"iterations": 0}, "iterations must be an integer >= 1, got 0"),
        ({"control_dim": 21}, "control_dim 21 exceeds sim_dim 20"),
        ({"control_dim": 20, "stages": ["studies", "directions"]},
         "control_dim 20 must be below sim_dim 20 for the RBBO runs of stage\\(s\\) directions"),
        ({"cost_cs": [0, 1]}, r"cost_cs must be integers in 1..20, got \[0, 1\]"),
        ({"cost_cs": [1, 21]}, r"cost_cs must be integers in 1..20, got \[1, 21\]"),
        ({"reward_cs": []}, r"reward_cs must be integers in 1..20, got \[\]"),
        ({"controller": "ilqr"}, "unknown planner 'ilqr'; registered: gn, mppi .*import path"),
        ({"executor": "dask"}, "unknown executor 'dask'"),
        # (counted twice in the tables, or trained twice at once in one folder)
        ({"benchmarks": ["CrossSwim-v0", "softrom_gym/CrossSwim-v0"]},
         "benchmarks lists CrossSwim-v0 more than once"),
        ({"perturbations_deg": [10.0, 10.0]}, "perturbations_deg lists 10.0 more than once"),
        ({"rl_algos": ["ppo", "ppo"]}, "rl_algos lists ppo more than once"),
        ({"cost_cs": [1, 1]}, "cost_cs lists 1 more than once"),
        # (the reward-vs-C study failed hours in, and the fix was then "other settings")
        ({"study_seconds": 1.5}, "study_seconds 1.5 must exceed settle_time 2.0"),
    ],
)  # fmt: skip
def test_a_plan_names_each_bad_setting(kwargs, match):
    """Hand-edited reproduce.json files are read through these checks too (from_dict)."""
    with pytest.raises(ValueError, match=match):
        ReproducePlan(**kwargs)
    with pytest.raises(ValueError, match=match):
        ReproducePlan.from_dict({**ReproducePlan().to_dict(), **kwargs})


def test_a_plan_takes_a_planner_of_ones_own_by_its_import_path():
    # (the runs' objectives and the reward study find it by this name, as rbbo optimize's do)
    plan = ReproducePlan(controller="examples.cem_planner:CEM")
    assert ReproducePlan.from_dict(plan.to_dict()).controller == "examples.cem_planner:CEM"
    with pytest.raises(ValueError, match="module 'examples.cem_planner' has no 'CME'"):
        ReproducePlan(controller="examples.cem_planner:CME")


def test_deterministic_reaches_each_optimisation_run_its_record_and_the_report(
    tmp_path, monkeypatch
):
    from rbbo.optimizer import RBBO
    from rbbo.reproduce import document, runner
    from rbbo.reproduce.cli import _plan

    class Stop(Exception):
        pass

    told = []

    def run(self, **kwargs):  # the search itself is rbbo optimize's, tested there
        told.append(kwargs["deterministic"])
        raise Stop

    monkeypatch.setattr(RBBO, "run", run)
    for flag in (False, True):
        argv = [*TINY, "--stages", "table", *(["--deterministic"] if flag else [])]
        plan = _plan(_parser().parse_args(argv))
        assert plan.deterministic is flag
        path = tmp_path / f"run-{flag}"
        objective = runner._objective(plan, "CrossSwim-v0")
        with pytest.raises(Stop):
            runner.optimise(path, plan, objective, "boca", 60.0, False, lambda message: None)
        # recorded in the run, so that `rbbo resume` of it tells results the same way
        execution = json.loads((path / "config.json").read_text())["execution"]
        assert execution["deterministic"] is flag
    assert told == [False, True]
    sessions = [{"deterministic": False}, {"deterministic": True}, {"deterministic": True}]
    assert document._told_in_order(sessions[:1], False) == ""
    assert document._told_in_order(sessions[1:], False) == " (results told in proposal order)"
    assert document._told_in_order(sessions, True) == (
        " (results told in proposal order in sessions 2, 3)"
    )
    assert document._told_in_order([], True) == " (results told in proposal order)"


def test_rl_stage_without_stable_baselines3_is_a_usage_error(
    reproduction, monkeypatch, tmp_path, capsys
):
    import rbbo.rl

    def missing():
        raise ImportError("the RL baselines need Stable-Baselines3: pip install 'softrom[rl]'")

    monkeypatch.setattr(rbbo.rl, "require_sb3", missing)
    assert main(["reproduce", "--out", str(tmp_path / "x"), "--stages", "rl"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "softrom[rl]" in err[0] and "--stages" in err[0]
    # a status runs nothing, so it needs nothing: it reads what the RL stage wrote
    assert main(["reproduce", "--out", str(reproduction), "--status"]) == 0
    assert any(x.startswith("rl ") for x in capsys.readouterr().out.splitlines())


def test_a_measurement_with_a_failed_seed_is_not_recorded_as_done(
    reproduction, tmp_path, monkeypatch, capsys
):
    """A timeout or a crashed worker's seed was written as nan and the row counted done: a
    later session with a longer timeout skipped it, and the perturbation's mean was taken
    over the seeds that survived (a review, session 54). Such rows are measured again."""
    import shutil

    import rbbo.reproduce.stages as stages
    from rbbo.reproduce.csv_rows import _rewrite_csv
    from rbbo.reproduce.tables import read_rows

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    # a row as a version that recorded failed seeds wrote it
    rows = read_rows(out / "perturbation.csv")
    rows[1]["R_seeds"] = "nan " + rows[1]["R_seeds"].split(" ", 1)[1]
    _rewrite_csv(out / "perturbation.csv", rows, list(rows[0]))
    failing = {"on": True}
    real = stages._evaluate_seeds

    def one_seed_fails(plan, objective, basis, seeds, log=None):
        values = real(plan, objective, basis, seeds, log)
        return [math.nan, *values[1:]] if failing["on"] else values

    monkeypatch.setattr(stages, "_evaluate_seeds", one_seed_fails)
    assert main([*TINY, "--out", str(out), "--stages", "perturbation"]) == 0
    assert len(read_rows(out / "perturbation-superseded.csv")) == 1
    assert len(read_rows(out / "perturbation.csv")) == 2  # the failed offset not recorded
    assert "seeds failed (their errors above); not recorded" in capsys.readouterr().err
    failing["on"] = False
    assert main([*TINY, "--out", str(out), "--stages", "perturbation"]) == 0
    rows = read_rows(out / "perturbation.csv")
    assert len(rows) == 3 and not any("nan" in r["R_seeds"] for r in rows)


def test_the_studies_of_c_run_the_plans_m_and_time_one_curve_on_one_thread_count(
    tmp_path, monkeypatch
):
    """The studies built their envs at M = 20 whatever --sim-dim said, and a session on other
    workers appended cost rows timed on another thread count to the same curve (a review,
    session 54)."""
    import controllers.studies
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.stages import studies
    from rbbo.reproduce.tables import read_rows

    calls = []

    def cost(env_id, cs, **kwargs):
        calls.append(("cost", list(cs), kwargs["env_kwargs"], kwargs["threads"]))

    def reward(env_id, cs, seeds, **kwargs):
        calls.append(("reward", list(cs), kwargs["env_kwargs"]))

    monkeypatch.setattr(controllers.studies, "gn_cost_against_c", cost)
    monkeypatch.setattr(controllers.studies, "reward_against_c", reward)
    plan = ReproducePlan(sim_dim=10, cost_cs=[1, 2], reward_cs=[1], study_seeds=1, workers=1,
                         stages=["studies"])  # fmt: skip
    path = tmp_path / "studies" / "cost_vs_c.csv"
    _append_row(path, {"C": 1, "iteration_s": 0.5, "threads": 2})  # another session's
    _append_row(path, {"C": 2, "iteration_s": 0.5, "threads": 1})
    log = []
    studies(tmp_path, plan, log.append)
    assert calls == [("cost", [1], {"sim_dim": 10}, 1), ("reward", [1], {"sim_dim": 10})]
    assert [r["C"] for r in read_rows(tmp_path / "studies" / "cost_vs_c-superseded.csv")] == ["1"]
    assert any("timed on another thread count" in line for line in log)


def test_the_reports_budget_is_that_of_the_sessions_that_searched():
    # a --stages studies --budget-per-benchmark 5m session made the report read "Budget per
    # benchmark 45 / 5 min", though no run had 5 minutes (a review, session 54)
    from rbbo.reproduce.document import _searching
    from rbbo.reproduce.report_text import _session_values

    sessions = [
        {"stages": ["table", "bo"], "budget_s": 2700.0},
        {"stages": ["studies"], "budget_s": 300.0},
        {"budget_s": 1800.0},
    ]  # (recorded before sessions named their stages)
    assert _session_values(_searching(sessions), "budget_s", 2700.0) == "45 / 30"


def test_a_replaced_best_basis_is_measured_again_its_old_rows_kept(reproduction, tmp_path):
    import shutil

    from rbbo.reproduce.tables import basis_digest, read_rows

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    # as if a longer budget had made both runs recommend another B_c
    boca = out / "runs" / "CrossSwim-v0-boca" / "best_basis.npy"
    np.save(boca, np.load(boca)[:, ::-1].copy())
    base = out / "runs" / "CrossSwim-v0-dir000" / "best_basis.npy"
    np.save(base, -np.load(base))
    assert main([*TINY, "--out", str(out), "--stages", "transfer,perturbation"]) == 0
    old = read_rows(out / "transfer-superseded.csv")
    assert [r["basis"] for r in old] == ["best"]
    rows = read_rows(out / "transfer.csv")
    assert sorted(r["basis"] for r in rows) == ["best", "identity"]
    best = next(r for r in rows if r["basis"] == "best")
    assert best["basis_digest"] == basis_digest(np.load(boca))
    assert len(read_rows(out / "perturbation-superseded.csv")) == 3
    rows = read_rows(out / "perturbation.csv")
    assert len(rows) == 3 and {r["basis_digest"] for r in rows} == {basis_digest(np.load(base))}


def test_a_transfer_row_of_a_replaced_best_basis_is_neither_reported_nor_counted(
    reproduction, tmp_path, capsys
):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    # as if Table I's run had searched on under a larger budget (stage table alone): its
    # transfer row measured the old B_c, which Table I's R* no longer is
    boca = out / "runs" / "CrossSwim-v0-boca" / "best_basis.npy"
    np.save(boca, np.load(boca)[:, ::-1].copy())
    assert main(["reproduce", "--out", str(out), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any("1 of 2 bases measured at M = 24" in x for x in lines), lines
    assert main(["reproduce", "--out", str(out), "--report-only"]) == 0
    assert "R* at M = 24" not in (out / "REPORT.md").read_text()


def test_status_counts_no_offsets_of_a_replaced_base_basis(reproduction, tmp_path, capsys):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    # the direction-0 run searched on: the perturbation stage will measure every offset again
    base = out / "runs" / "CrossSwim-v0-dir000" / "best_basis.npy"
    np.save(base, -np.load(base))
    assert main(["reproduce", "--out", str(out), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(x.startswith("perturbation") and "0 of 3 offsets" in x for x in lines), lines
    assert lines[-1].endswith("plus the perturbation study")


def test_the_report_shows_only_the_offsets_of_the_base_basis_the_status_counts(
    reproduction, tmp_path, capsys
):
    # The direction-0 run searched on (its B_c replaced) and the perturbation stage, killed
    # part-way, measured two offsets of the new B_c: until the stage runs again,
    # perturbation.csv holds both B_c's rows. The report, like the status, must show the
    # new B_c's only, not the old one's as if they were current.
    import shutil

    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.tables import basis_digest, read_rows

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    base = out / "runs" / "CrossSwim-v0-dir000"
    old = read_rows(out / "perturbation.csv")
    assert {r["basis_digest"] for r in old} == {basis_digest(np.load(base / "best_basis.npy"))}
    np.save(base / "best_basis.npy", -np.load(base / "best_basis.npy"))
    digest = basis_digest(np.load(base / "best_basis.npy"))
    for offset, r_mean in ((0.0, 2.0), (-10.0, 1.5)):
        _append_row(out / "perturbation.csv", {**old[0], "offset_deg": offset,
                    "direction_deg": offset, "R_mean": r_mean, "basis_digest": digest})  # fmt: skip
    assert main(["reproduce", "--out", str(out), "--status"]) == 0
    assert any(x.startswith("perturbation") and "2 of 3 offsets" in x
               for x in capsys.readouterr().out.splitlines())  # fmt: skip
    assert main(["reproduce", "--out", str(out), "--report-only"]) == 0
    section = (out / "REPORT.md").read_text().split("## Direction perturbation")[1]
    section = section.split("\n## ")[0]
    offsets = [x for x in section.splitlines() if re.match(r"\| [+-]\d", x)]
    assert offsets == ["| -10 | 1.5 | 0.75 |", "| +0 | 2 | 1.00 |"], section


def test_a_row_with_new_columns_widens_the_csv_and_keeps_the_old_rows(tmp_path):
    from rbbo.reproduce.runner import _append_row
    from rbbo.reproduce.tables import read_rows

    path = tmp_path / "t.csv"
    path.write_text("a,b\n1,2\n")  # written by an older version
    _append_row(path, {"a": 3, "b": 4, "c": 5})
    _append_row(path, {"a": 6, "b": 7, "c": 8})
    assert read_rows(path) == [{"a": "1", "b": "2", "c": ""}, {"a": "3", "b": "4", "c": "5"},
                               {"a": "6", "b": "7", "c": "8"}]  # fmt: skip


def test_a_measured_row_is_fsynced_before_it_counts_as_done(tmp_path, monkeypatch):
    # A transfer or perturbation row is measured once: a resume skips it for being in the
    # CSV, so it must be on disk when _append_row returns. Durability cannot be observed
    # without pulling the power, so this watches os.fsync (through the os module that
    # rbbo.reproduce.csv_rows calls it with): the file must be fsynced holding the new row.
    import os

    import rbbo.reproduce.csv_rows as csv_rows
    from rbbo.reproduce.runner import _append_row

    assert csv_rows.os is os
    synced = []
    real_fsync = os.fsync

    def spy(fd):
        st = os.fstat(fd)
        synced.append((st.st_ino, st.st_size))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    path = tmp_path / "t.csv"
    for row in ({"a": 1, "b": 2}, {"a": 3, "b": 4}):
        synced.clear()
        _append_row(path, row)
        st = path.stat()
        assert (st.st_ino, st.st_size) in synced


def _supersede_fixture(tmp_path):
    from rbbo.reproduce.csv_rows import _append_row

    path = tmp_path / "t.csv"
    rows = [{"basis": b, "offset": str(i)} for i, b in enumerate(["old", "new", "old", "new"])]
    for r in rows:
        _append_row(path, r)
    return path, rows


def _killed_before_step(n, monkeypatch, call, *args):
    """Run ``call(*args)`` as if killed before its ``n``-th os.fsync or os.replace (counting
    from 0); whether the kill came (``call`` took more steps)."""
    import os

    steps = []

    def step(real):
        def wrapped(*args):
            if len(steps) == n:
                raise KeyboardInterrupt
            steps.append(real)
            return real(*args)

        return wrapped

    for name in ("fsync", "replace"):
        monkeypatch.setattr(os, name, step(getattr(os, name)))
    try:
        call(*args)
        return False
    except KeyboardInterrupt:
        return True
    finally:
        monkeypatch.undo()


def test_a_kill_anywhere_in_supersede_loses_no_row_and_a_rerun_finishes_it(tmp_path, monkeypatch):
    # Each filesystem step _supersede takes (each row's append to t-superseded.csv, each
    # fsync, the rename that rewrites t.csv) is a point a kill may stop it at: whatever
    # remains must still hold every row, and a rerun must leave the stale rows aside only.
    from rbbo.reproduce.csv_rows import _supersede
    from rbbo.reproduce.tables import read_rows

    def stale(r):
        return r["basis"] == "old"

    for n in range(20):
        case = tmp_path / str(n)
        case.mkdir()
        path, rows = _supersede_fixture(case)
        aside = case / "t-superseded.csv"
        killed = _killed_before_step(n, monkeypatch, _supersede, path, stale)
        left, moved = read_rows(path), read_rows(aside)
        assert all(r in left or r in moved for r in rows), n
        if not killed:
            break
        _supersede(path, stale)
        assert read_rows(path) == [r for r in rows if not stale(r)], n
        assert {tuple(r.values()) for r in read_rows(aside)} == {
            tuple(r.values()) for r in rows if stale(r)}, n  # fmt: skip
    else:
        raise AssertionError("_supersede took more steps than the test tries")


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc")
def test_superseded_rows_are_durable_before_they_leave_their_file(tmp_path, monkeypatch):
    # A power loss keeps only what was fsynced. t-superseded.csv is new here: its name must
    # be on disk (its directory fsynced) before the rename that drops the rows from t.csv,
    # else the disk could hold the rewritten t.csv and no t-superseded.csv. Durability is not
    # observable without pulling the power, so this watches os.fsync and os.replace.
    import os

    from rbbo.reproduce.csv_rows import _supersede

    path, _ = _supersede_fixture(tmp_path)
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        target = os.readlink(f"/proc/self/fd/{fd}")
        if os.path.isdir(target):
            events.append(("dir", set(os.listdir(target))))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", Path(dst).name))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    assert _supersede(path, lambda r: r["basis"] == "old") == 2
    monkeypatch.undo()
    published = events.index(("replace", "t.csv"))
    assert any(kind == "dir" and "t-superseded.csv" in names
               for kind, names in events[:published]), events  # fmt: skip


def test_a_progress_log_torn_by_a_kill_is_read_and_mended(tmp_path):
    from rbbo.rl import _read_progress

    log = tmp_path / "progress.jsonl"
    log.write_text('{"steps": 64}\n{"steps": 128}\n{"steps": 19')
    # a reader (status, report) skips the torn line and leaves the file as it is
    assert _read_progress(log, mend=False) == [{"steps": 64}, {"steps": 128}]
    assert log.read_text().endswith('{"steps": 19')
    assert _read_progress(log) == [{"steps": 64}, {"steps": 128}]
    assert log.read_text() == '{"steps": 64}\n{"steps": 128}\n'  # the next row starts a line


def test_the_committed_report_matches_its_run_histories():
    # docs/REPORT.md was written by `rbbo reproduce --report docs/REPORT.md` from the runs it
    # links to: every Table I number must be what those histories say.
    from pathlib import Path

    from rbbo.reproduce import PAPER_TABLE1

    docs = Path(__file__).resolve().parent.parent / "docs"
    text = (docs / "REPORT.md").read_text()
    rows = parse_markdown(text)
    assert rows
    # the run directory the report links to (docs/reproduction, or a longer run's folder)
    folder = docs / re.search(r"\]\(([^)]+)/runs/[^/)]+/history\.jsonl\)", text).group(1)
    names = {(v["robot"], v["task"]): k for k, v in PAPER_TABLE1.items()}
    for row in rows:
        history = _history(folder / "runs" / f"{names[row['robot'], row['task']]}-boca")
        confirm = {e["kind"]: e for e in history if e["kind"].startswith("confirm")}
        assert row["evaluations"] == sum(not e["kind"].startswith("confirm") for e in history)
        for key, kind in (("R_init", "confirm-init"), ("R_star", "confirm-best")):
            mean, half = confidence_interval(confirm[kind]["R_seeds"])
            assert row[key] == pytest.approx(mean, rel=1e-3), (row["robot"], key)
            assert row[f"{key}_ci95"] == pytest.approx(half, rel=0.05), (row["robot"], key)
        apart = (row["R_star"] - row["R_star_ci95"]) > (row["R_init"] + row["R_init_ci95"])
        assert row["apart"] == apart
    # and BO vs BOCA from its runs (a run that went on after the report: not yet reported)
    assert _bo_table_matches_histories(text, folder, skip_stale=True)


def test_a_compiled_core_older_than_its_sources_is_named(tmp_path, monkeypatch):
    import os

    import cpp_sim._core as core
    from rbbo.provenance import _stale_build

    (tmp_path / "cpp_sim" / "src").mkdir(parents=True)
    source = tmp_path / "cpp_sim" / "src" / "step.cpp"
    source.write_text("// a source")
    (tmp_path / "CMakeLists.txt").write_text("# build")
    module = tmp_path / "_core.so"
    module.write_bytes(b"")
    monkeypatch.setattr(core, "__file__", str(module))
    os.utime(module, (1_000_000, 1_000_000))
    assert _stale_build(tmp_path) == ", compiled core older than its sources"
    os.utime(module, (4_000_000_000, 4_000_000_000))
    assert _stale_build(tmp_path) == ""


def test_a_table_with_an_unconfirmed_benchmark_averages_like_with_like():
    from rbbo.reproduce.tables import format_markdown

    nan = math.nan
    row = {"robot": "Cross", "task": "Swim", "N": 555, "M": 20, "C": 3, "R_init": 1.0,
           "R_init_ci95": 0.1, "R_star": 2.0, "R_star_ci95": 0.1, "improvement_pct": 100.0,
           "delta": 1.0, "delta_ci95": 0.1, "evaluations": 9, "wall_s": 60.0, "apart": True,
           "paper_improvement_pct": 142.21}  # fmt: skip
    running = {**row, "task": "Walk", "R_init": nan, "R_star": nan, "improvement_pct": nan,
               "delta": nan, "apart": False, "paper_improvement_pct": 544.32}  # fmt: skip
    text = format_markdown([row, running])
    assert text.splitlines()[-1].endswith("| +100.0 % | | | | | +142.2 % |")  # not +343.3
    parsed = parse_markdown(text)
    assert [r["apart"] for r in parsed] == [True, False]
    assert "| - | +544.3 % |" in text.splitlines()[3]  # apart not yet known


def test_a_running_session_records_its_wall_time_as_it_goes(tmp_path, monkeypatch):
    """reproduce.json holds the session's wall time up to the last evaluation, so a session
    killed outright (SIGKILL, a lost machine) is not recorded as shorter than it ran."""
    import time

    from rbbo.reproduce import runner

    written = []
    write = runner._atomic_write

    def spy(path, data):
        write(path, data)
        if path.name == "reproduce.json":
            written.append(json.loads(data)["sessions"][-1]["wall_s"])

    def optimise(path, plan, objective, fidelity, budget_s, progress, log, heartbeat=None):
        for _ in range(3):  # three evaluations, then the machine is lost
            time.sleep(0.02)
            heartbeat()
        raise SystemExit("killed")

    monkeypatch.setattr(runner, "_atomic_write", spy)
    monkeypatch.setattr(runner, "_HEARTBEAT_S", 0.0)
    monkeypatch.setattr(runner, "optimise", optimise)
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"])
    with pytest.raises(SystemExit):
        runner.reproduce(tmp_path, plan, progress=False, log=lambda message: None)
    heartbeats = written[1:4]  # the first write opens the session, the last is `finally`
    assert len(heartbeats) == 3 and heartbeats == sorted(heartbeats)
    assert heartbeats[-1] >= 0.06


def test_a_session_that_fails_before_its_stages_leaves_no_heartbeat_running(tmp_path):
    import threading

    from rbbo.reproduce import runner

    def log(message: str) -> None:
        if message.startswith("reproduce into"):  # as a log that cannot be written
            raise OSError("disk full")

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"])
    before = set(threading.enumerate())  # (an earlier test's may still be on its way out)
    with pytest.raises(OSError, match="disk full"):
        runner.reproduce(tmp_path, plan, progress=False, log=log)
    # (the thread was started before the launch line, outside the finally that stops it)
    new = set(threading.enumerate()) - before
    assert not [t for t in new if t.name == "reproduce-heartbeat"]


def test_the_launch_line_names_only_the_stages_that_run(tmp_path, monkeypatch):
    from rbbo.reproduce import runner

    monkeypatch.setattr(runner, "optimise", lambda path, *args, **kwargs: path)
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    monkeypatch.setattr(runner, "studies", lambda out, plan, log: out / "studies")
    lines = []
    for stages in (["bo", "table"], ["studies"]):  # as --stages bo,table and --stages studies
        plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=stages, budget_s=1800.0)
        runner.reproduce(tmp_path / stages[0], plan, progress=False, log=lines.append)
    launch = [line.split(": ", 1)[1] for line in lines if line.startswith("reproduce into ")]
    assert launch == [
        "stages table, bo; optimisation budgets add up to 1.00 h on 2 workers, plus the "
        "confirmations (rerun the same command to resume)",
        "stages studies (rerun the same command to resume)",
    ]
    sessions = json.loads((tmp_path / "bo" / "reproduce.json").read_text())["sessions"]
    assert sessions[-1]["stages"] == ["table", "bo"]  # what --status reads back


def test_the_launch_line_counts_the_repeated_table_runs(tmp_path, monkeypatch):
    from rbbo.reproduce import runner

    made = []
    monkeypatch.setattr(runner, "optimise", lambda path, *args, **kwargs: made.append(
        (path.name, args[-1] if len(args) == 8 else 0)))  # fmt: skip
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    lines = []
    plan = ReproducePlan(benchmarks=["CrossSwim-v0", "BeamWalk-v0"], stages=["table", "bo"],
                         budget_s=1800.0, repeats=3, seed=4)  # fmt: skip
    runner.reproduce(tmp_path, plan, progress=False, log=lines.append)
    launch = next(line.split(": ", 1)[1] for line in lines if line.startswith("reproduce into "))
    # 2 benchmarks x (3 BOCA runs + 1 BO run) x 30 min
    assert launch == (
        "stages table (3 runs per benchmark, seeds 4-6), bo; optimisation budgets add up to "
        "4.00 h on 2 workers, plus the confirmations (rerun the same command to resume)"
    )
    # every benchmark's run 0 (and its BO run) first, then the repeats round by round
    assert made == [
        ("CrossSwim-v0-boca", 0), ("CrossSwim-v0-bo", 0), ("BeamWalk-v0-boca", 0),
        ("BeamWalk-v0-bo", 0), ("CrossSwim-v0-boca-run1", 1), ("BeamWalk-v0-boca-run1", 1),
        ("CrossSwim-v0-boca-run2", 2), ("BeamWalk-v0-boca-run2", 2),
    ]  # fmt: skip
    sessions = json.loads((tmp_path / "reproduce.json").read_text())["sessions"]
    assert sessions[-1]["repeats"] == 3


def test_the_repeats_of_a_record_are_the_most_a_table_session_asked_for():
    from rbbo.reproduce.status import recorded_repeats

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"]).to_dict()
    assert recorded_repeats({"plan": plan, "sessions": []}) == 1
    assert recorded_repeats({"plan": {**plan, "repeats": 2}, "sessions": []}) == 2
    sessions = [
        {"command": "rbbo reproduce --out x"},  # before repeats existed: one run
        {"command": "rbbo reproduce --out x", "stages": ["table"], "repeats": 3},
        {"command": "rbbo reproduce --out x", "stages": ["studies"], "repeats": 5},
        {"command": "rbbo reproduce --out x", "stages": ["table", "bo"], "repeats": 1},
    ]
    assert recorded_repeats({"plan": plan, "sessions": sessions}) == 3
    assert recorded_repeats({"plan": plan, "sessions": sessions[:1]}) == 1


def test_the_runs_table_gives_each_run_and_the_spread_over_those_confirmed():
    from rbbo.reproduce.tables import across_runs, format_runs_markdown

    def row(repeat, r_init, r_star):
        gain = 100 * (r_star / r_init - 1) if math.isfinite(r_star) else math.nan
        return {"benchmark": "CrossSwim-v0", "repeat": repeat, "seed": 7 + repeat,
                "R_init": r_init, "R_star": r_star, "improvement_pct": gain}  # fmt: skip

    rows = [row(0, 1.0, 2.0), row(1, 1.0, 1.5), row(2, 0.5, 1.5), row(3, 1.0, math.nan)]
    stats = across_runs(rows)
    assert stats["runs"] == 3
    assert stats["improvement_mean_pct"] == pytest.approx(np.mean([100, 50, 200]))
    assert stats["improvement_sd_pct"] == pytest.approx(np.std([100, 50, 200], ddof=1))
    assert (stats["improvement_min_pct"], stats["improvement_max_pct"]) == (50.0, 200.0)
    assert stats["R_star_sd"] == pytest.approx(np.std([2.0, 1.5, 1.5], ddof=1))
    line = format_runs_markdown(rows, 4).splitlines()[2]
    assert line == ("| CrossSwim-v0 | 3 of 4 | +100.0 % (7), +50.0 % (8), +200.0 % (9), - (10) | "
                    "+116.7 ± 76.4 % | +50.0 .. +200.0 % | 1.667 ± 0.29 |")  # fmt: skip
    one = format_runs_markdown(rows[:1], 1).splitlines()[2]  # no spread from one run
    assert one == "| CrossSwim-v0 | 1 | +100.0 % (7) | +100.0 % | +100.0 .. +100.0 % | 2 |"


@pytest.fixture(scope="module")
def repeated(tmp_path_factory):
    """Table I of one benchmark, made in one run, then given a second (``--repeats 2``) by a
    later session: the record as the first session left it, and the directory."""
    out = tmp_path_factory.mktemp("repeated")
    # (searched long enough to recommend other bases than the identity, whose gain is 0)
    argv = [*TINY, "--stages", "table", "--iterations", "6", "--init", "2", "--out", str(out)]
    assert main(argv) == 0
    first = {name: (out / name).read_bytes() for name in (
        "table1.csv", "table1.md", "runs/CrossSwim-v0-boca/history.jsonl")}  # fmt: skip
    first["REPORT.md"] = (out / "REPORT.md").read_text()
    first["runs"] = sorted(p.name for p in (out / "runs").iterdir())
    first["table1_runs.csv"] = (out / "table1_runs.csv").exists()
    assert main([*argv, "--repeats", "2"]) == 0
    return out, first


def test_one_run_is_table_one_as_before(repeated, reproduction):
    _, first = repeated
    assert first["runs"] == ["CrossSwim-v0-boca"]
    header = (reproduction / "table1.csv").read_text().splitlines()[0]
    assert header == ("benchmark,robot,task,N,M,C,R_init,R_init_ci95,R_star,R_star_ci95,seeds,"
                      "improvement_pct,apart,delta,delta_ci95,paired_apart,evaluations,failed,"
                      "wall_s,fidelity,paper_improvement_pct,run")  # fmt: skip
    assert first["table1.csv"].decode().splitlines()[0] == header
    assert first["table1.md"].decode().count("| benchmark | runs |") == 0
    assert "over 2 RBBO runs" not in first["REPORT.md"]
    assert "- Each benchmark has one RBBO run (seed 0), as the paper's" in first["REPORT.md"]
    assert not (reproduction / "table1_runs.csv").exists() and not first["table1_runs.csv"]
    log = (reproduction / "reproduce.log").read_text()
    assert "stages table, bo, transfer" in log and "runs per benchmark" not in log


def test_repeats_make_one_run_per_seed_and_leave_run_zero_alone(repeated):
    out, first = repeated
    runs = sorted(p.name for p in (out / "runs").iterdir())
    assert runs == ["CrossSwim-v0-boca", "CrossSwim-v0-boca-run1"]
    seeds = [json.loads((out / "runs" / r / "config.json").read_text())["rbbo"]["seed"]
             for r in runs]  # fmt: skip
    assert seeds == [0, 1]
    # the second session resumed run 0 without a new evaluation and made run 1 whole
    assert (out / "runs/CrossSwim-v0-boca/history.jsonl").read_bytes() == first[
        "runs/CrossSwim-v0-boca/history.jsonl"
    ]
    history = _history(out / "runs" / "CrossSwim-v0-boca-run1")
    assert sum(not e["kind"].startswith("confirm") for e in history) == 6
    fresh = [next(e["seeds"] for e in _history(out / "runs" / r) if e["kind"] == "confirm-init")
             for r in runs]  # fmt: skip
    assert fresh[0] != fresh[1]  # each run confirmed on its own fresh seeds
    log = (out / "reproduce.log").read_text()
    assert "stages table (2 runs per benchmark, seeds 0-1); optimisation budgets add up to " \
        "1.50 h on 1 worker," in log  # fmt: skip
    assert "[CrossSwim-v0-boca-run1] BOCA, budget" in log


def test_the_table_gives_the_improvement_over_the_runs(repeated):
    from rbbo.reproduce.tables import read_rows

    out, first = repeated
    gains, stars = [], []
    for r in ("CrossSwim-v0-boca", "CrossSwim-v0-boca-run1"):
        confirm = {e["kind"]: e["R_seeds"] for e in _history(out / "runs" / r)
                   if e["kind"].startswith("confirm")}  # fmt: skip
        r_init, r_star = np.mean(confirm["confirm-init"]), np.mean(confirm["confirm-best"])
        gains.append(100 * (r_star / r_init - 1))
        stars.append(r_star)
    assert all(math.isfinite(g) for g in gains)
    rows = read_rows(out / "table1_runs.csv")
    assert [(r["repeat"], r["seed"], Path(r["run"]).name) for r in rows] == [
        ("0", "0", "CrossSwim-v0-boca"), ("1", "1", "CrossSwim-v0-boca-run1")]  # fmt: skip
    for r, gain, star in zip(rows, gains, stars, strict=True):
        assert float(r["improvement_pct"]) == pytest.approx(gain)
        assert float(r["R_star"]) == pytest.approx(star)
    # Table I stays run 0's row, its columns as before, the spread over the runs beside it
    assert (out / "table1.md").read_text().startswith(first["table1.md"].decode())
    before = first["table1.csv"].decode().splitlines()
    after = (out / "table1.csv").read_text().splitlines()
    assert [x.startswith(y) for x, y in zip(after, before, strict=True)] == [True, True]
    (table,) = read_rows(out / "table1.csv")
    assert float(table["improvement_pct"]) == pytest.approx(gains[0])
    assert table["runs"] == "2"
    assert float(table["improvement_mean_pct"]) == pytest.approx(np.mean(gains))
    assert float(table["improvement_sd_pct"]) == pytest.approx(np.std(gains, ddof=1))
    assert float(table["improvement_min_pct"]) == pytest.approx(min(gains))
    report = (out / "REPORT.md").read_text()
    assert [r["improvement_pct"] for r in parse_markdown(report)] == pytest.approx(
        [gains[0]], abs=0.05
    )
    section = report.split("### Table I over 2 RBBO runs per benchmark")[1].split("\n## ")[0]
    assert "run 0 (seed 0), whose B_c the later stages (transfer, perturbation, RL) use" in section
    line = next(x for x in section.splitlines() if x.startswith("| CrossSwim-v0 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1] == "2"
    assert cells[2] == f"{gains[0]:+.1f} % (0), {gains[1]:+.1f} % (1)"
    assert cells[3] == f"{np.mean(gains):+.1f} ± {np.std(gains, ddof=1):.1f} %"
    assert cells[4] == f"{min(gains):+.1f} .. {max(gains):+.1f} %"
    assert "(BOCA, each of its 2 runs)" in report
    assert "- Each benchmark has 2 RBBO runs (seeds 0-1) where the paper has one" in report
    assert (out / "table1.md").read_text().count("| CrossSwim-v0 | 2 |") == 1
    assert (out / "runs" / "CrossSwim-v0-boca-run1" / "convergence.png").is_file()


def test_a_rerun_with_repeats_resumes_every_run_and_prints_the_spread(repeated, capsys):
    out, _ = repeated
    runs = sorted((out / "runs").iterdir())
    before = [p.joinpath("history.jsonl").read_bytes() for p in runs]
    again = [*TINY, "--stages", "table", "--iterations", "6", "--init", "2", "--out", str(out)]
    assert main([*again, "--repeats", "2"]) == 0
    assert [p.joinpath("history.jsonl").read_bytes() for p in runs] == before
    printed = capsys.readouterr().out
    assert "| Cross | Swim |" in printed and "| CrossSwim-v0 | 2 |" in printed
    # a later session of one run per benchmark keeps the record's two in the report
    assert main(again) == 0
    assert [p.joinpath("history.jsonl").read_bytes() for p in runs] == before
    assert "### Table I over 2 RBBO runs per benchmark" in (out / "REPORT.md").read_text()


def test_status_shows_each_repeated_run(repeated, capsys, tmp_path):
    import shutil

    out, _ = repeated
    assert main(["reproduce", "--out", str(out), "--status"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [x.split(": done: ")[0] for x in lines[:2]] == [
        "table        CrossSwim-v0         run 0 (seed 0)",
        "table        CrossSwim-v0         run 1 (seed 1)",
    ]
    assert all(": done: 6 evaluations" in x for x in lines[:2])
    assert lines[2].startswith("optimisation budget left: 0.00 h")
    # a run not made yet is counted, in the status, its budget and the report's progress
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "runs" / "CrossSwim-v0-boca-run1")
    assert main(["reproduce", "--out", str(copy), "--status", "--repeats", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [x.split(": ", 1)[1] for x in lines[1:3]] == ["not started", "not started"]
    assert lines[2].startswith("table        CrossSwim-v0         run 2 (seed 2): ")
    assert lines[3].startswith("optimisation budget left: 1.50 h")  # 2 x 45 min
    assert main(["reproduce", "--out", str(copy), "--report-only"]) == 0
    report = (copy / "REPORT.md").read_text()
    assert "Under way (parts finished of those planned): table (1 of 2)" in report
    assert "| CrossSwim-v0 | 1 of 2 |" in report


def test_an_interrupt_does_not_wait_for_the_evaluations_in_flight():
    """Ctrl-C during a confirmation kills the workers (which ignore the group's SIGINT)
    instead of waiting out their minute-long evaluations."""
    import os
    import signal
    import threading
    import time

    from rbbo import SyntheticObjective
    from rbbo.reproduce import runner

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], executor="process", workers=2)
    objective = SyntheticObjective(6, 2, delay=120.0, t_max=plan.t_max)
    basis = np.eye(6)[:, :2]
    timer = threading.Timer(3.0, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            runner._evaluate_seeds(plan, objective, basis, (1, 2))
    finally:
        timer.cancel()
    assert time.monotonic() - start < 60.0  # the evaluations alone take 120 s


def test_a_run_in_another_simulation_space_is_refused(reproduction, tmp_path, capsys):
    """Resumed in an env that builds other reduced coordinates (here: a recorded fingerprint
    with one mode flipped, as another BLAS kernel gave before cache version 4), the run's
    bases would mean other actuations: refused with one error line, nothing evaluated."""
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(reproduction, copy)
    config_path = copy / "runs" / "CrossSwim-v0-boca" / "config.json"
    config = json.loads(config_path.read_text())
    config["objective"]["simulation_space"][7] *= -1.0
    config_path.write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
    before = _history(copy / "runs" / "CrossSwim-v0-boca")
    argv = [*TINY, "--out", str(copy)]
    assert main([*argv, "--stages", "table"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("rbbo: error: ") and "coordinates [7] differ" in err[-1]
    assert _history(copy / "runs" / "CrossSwim-v0-boca") == before


def test_an_installed_copy_inside_another_checkout_names_no_commit(tmp_path):
    # site-packages inside a user's own git repository: that repository's commit is not the
    # code that ran, so the record names the package version only
    import importlib.util
    import shutil
    import subprocess

    import rbbo.provenance

    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    package = tmp_path / "site-packages" / "rbbo"
    package.mkdir(parents=True)
    shutil.copy(rbbo.provenance.__file__, package / "provenance.py")
    spec = importlib.util.spec_from_file_location("provenance_copy", package / "provenance.py")
    copy = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(copy)
    assert copy.source_version().startswith("softrom ")
    assert "git" not in copy.source_version()
    if (Path(rbbo.provenance.__file__).parents[1] / ".git").exists():
        assert "git " in rbbo.provenance.source_version()  # a checkout names its commit


def test_rl_stage_trains_the_identity_once_and_says_why_it_is_alone(tmp_path, monkeypatch):
    import rbbo.rl
    from rbbo.reproduce.runner import rl_baselines
    from rbbo.reproduce.status import rl_bases
    from rbbo.reproduce.tables import basis_digest

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], rl_benchmarks=["CrossSwim-v0"])
    trained: list[list[str]] = []
    monkeypatch.setattr(
        rbbo.rl, "run_baselines", lambda env, bases, *a, **k: trained.append(list(bases))
    )
    logged: list[str] = []
    # no Table I run yet: the identity alone, and the log says so
    rl_baselines(tmp_path, plan, False, logged.append)
    assert trained.pop() == ["identity"]
    assert logged.pop() == (
        f"[rl] CrossSwim-v0: Table I's run {tmp_path}/runs/CrossSwim-v0-boca has no best B_c "
        "yet, so only the identity is trained; run stage rl again once stage table has run"
    )
    # a search that found nothing better recommends the identity itself: trained once
    run = tmp_path / "runs" / "CrossSwim-v0-boca"
    run.mkdir(parents=True)
    np.save(run / "best_basis.npy", np.eye(20)[:, :3])
    bases, why = rl_bases(tmp_path, plan, "CrossSwim-v0")
    assert list(bases) == ["identity"]
    assert why == "Table I's B_c is the identity basis, so it is trained once, as identity"
    # any other B_c is trained beside the identity, named by its bytes
    other = np.linalg.qr(np.random.default_rng(0).standard_normal((20, 3)))[0]
    np.save(run / "best_basis.npy", other)
    bases, why = rl_bases(tmp_path, plan, "CrossSwim-v0")
    assert list(bases) == ["identity", f"rbbo-{basis_digest(other)}"] and why == ""
    np.testing.assert_array_equal(bases[f"rbbo-{basis_digest(other)}"], other)


def test_a_corrupted_base_basis_is_named_by_the_status_and_the_report(
    reproduction, tmp_path, capsys
):
    # The perturbation rows are told apart by the digest of the direction-0 run's B_c: an
    # unreadable best_basis.npy ended --status and --report-only in np.load's traceback.
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(reproduction, out)
    best = out / "runs" / "CrossSwim-v0-dir000" / "best_basis.npy"
    best.write_bytes(b"not an array")
    for flag in ("--status", "--report-only"):
        assert main(["reproduce", "--out", str(out), flag]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith(f"rbbo: error: {best} is corrupted: "), err
        assert not any("Traceback" in x for x in err)


def test_rl_status_counts_an_mpc_job_done_only_when_its_row_reads(tmp_path):
    # A torn episodes.json (a kill while an older version wrote it in place) was shown as
    # done, though the next run makes that row again.
    from rbbo.reproduce.status import _rl_state

    whole, torn = tmp_path / "mppi-identity", tmp_path / "mppi-best"
    for folder in (whole, torn):
        folder.mkdir()
    text = json.dumps({"meta": {}, "row": {"algo": "mppi"}})
    (whole / "episodes.json").write_text(text)
    (torn / "episodes.json").write_text(text[:20])
    assert _rl_state(tmp_path, ReproducePlan()) == "mppi-best -, mppi-identity done"


def test_a_table_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    # write_csv wrote Table I and the transfer table in place: a kill mid-write left half a
    # table where the last whole one had been.
    import os

    from rbbo.reproduce.tables import read_rows, write_csv

    path = tmp_path / "new" / "table1.csv"
    write_csv([{"benchmark": "a", "R": 1.5}, {"benchmark": "b", "R": 2.5}], path)
    before = path.read_bytes()

    def killed(src, dst):
        raise OSError("killed before the rename")

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(OSError, match="killed before the rename"):
        write_csv([{"benchmark": "c", "R": 0.5}], path)
    monkeypatch.undo()
    assert path.read_bytes() == before and os.listdir(path.parent) == ["table1.csv"]
    assert read_rows(path) == [{"benchmark": "a", "R": "1.5"}, {"benchmark": "b", "R": "2.5"}]


@pytest.mark.parametrize("name", ["table1.md", "REPORT.md", "copy"])
def test_the_report_and_its_copy_are_replaced_whole_or_not_at_all(
    name, reproduction, tmp_path, monkeypatch, capsys
):
    # table1.md, REPORT.md and its copy (docs/REPORT.md in a repository) were rewritten in
    # place: a kill mid-write left half a report where the last whole one had been. (The
    # failed write is a one-line error, exit status 1.)
    import os
    import shutil

    out, copy = tmp_path / "out", tmp_path / "docs" / "REPORT.md"
    shutil.copytree(reproduction, out)
    argv = ["reproduce", "--out", str(out), "--report-only", "--report", str(copy)]
    target = copy if name == "copy" else out / name
    target.parent.mkdir(exist_ok=True)
    target.write_bytes(b"the last whole report")
    real_replace = os.replace

    def killed(src, dst):
        if Path(dst) == target:
            raise OSError("killed before the rename")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", killed)
    capsys.readouterr()
    assert main(argv) == 1
    assert capsys.readouterr().err == "rbbo: error: killed before the rename\n"
    monkeypatch.undo()
    assert target.read_bytes() == b"the last whole report"
    assert not [p for p in os.listdir(target.parent) if p.startswith(f".{target.name}.")]


def test_a_checkout_whose_code_differs_from_its_commit_is_named_dirty(tmp_path):
    # +dirty when tracked code differs from the commit; a changed note, an untracked file or a
    # changed file outside the code paths (a record, a log) leaves the name clean
    import importlib.util
    import shutil
    import subprocess

    import rbbo.provenance

    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t",
                        *args], check=True, capture_output=True)  # fmt: skip

    (tmp_path / "rbbo").mkdir()
    shutil.copy(rbbo.provenance.__file__, tmp_path / "rbbo" / "provenance.py")
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'x'\n")
    (tmp_path / "NOTES.md").write_text("a note\n")
    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "first")
    spec = importlib.util.spec_from_file_location("provenance_dirty", tmp_path / "rbbo" /
                                                  "provenance.py")  # fmt: skip
    copy = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(copy)
    clean = copy.source_version()
    assert re.search(r", git [0-9a-f]{10}$", clean), clean
    (tmp_path / "NOTES.md").write_text("another note\n")
    (tmp_path / "rbbo" / "untracked.py").write_text("x = 1\n")
    assert copy.source_version() == clean
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'y'\n")
    assert copy.source_version() == clean + "+dirty"


# --- Table I's numbers, by hand (mutation audit of rbbo/reproduce) -----------------------

_T2 = 4.302652729911275  # t_{0.975, 2}: the 95 % t-quantile of three seeds


def test_compare_seeds_gives_the_t_intervals_the_improvement_and_the_paired_gain():
    # guards Table I's row: each mean ± t_{0.975, n-1} s / sqrt(n), the improvement from the
    # means, the paired gain R* - R_init per seed (not R_init - R*) and both "apart" tests
    from scipy import stats

    from rbbo.reproduce.tables import compare_seeds

    assert stats.t.ppf(0.975, 2) == pytest.approx(_T2)
    init, star = [1.0, 1.2, 0.8], [1.5, 2.1, 1.2]  # gains 0.5, 0.9, 0.4
    got = compare_seeds(init, star)
    assert got["R_init"] == pytest.approx(1.0)
    assert got["R_init_ci95"] == pytest.approx(_T2 * 0.2 / math.sqrt(3))
    assert got["R_star"] == pytest.approx(1.6)
    assert got["R_star_ci95"] == pytest.approx(_T2 * math.sqrt(0.21) / math.sqrt(3))
    assert got["improvement_pct"] == pytest.approx(60.0)
    assert got["delta"] == pytest.approx(0.6)
    assert got["delta_ci95"] == pytest.approx(_T2 * math.sqrt(0.07) / math.sqrt(3))
    # R* = 1.6 lies above R_init's interval (1.0 + 0.50) but its own lower end (0.46) does
    # not: not apart; the paired gain's interval (0.6 ± 0.66) reaches below 0: nor is it
    assert (got["apart"], got["paired_apart"]) == (False, False)
    # a clear gain: both intervals apart, and the paired one
    got = compare_seeds([1.0, 1.1, 0.9], [3.0, 3.2, 2.9])
    assert (got["apart"], got["paired_apart"]) == (True, True)
    # the paired interval alone can tell a gain the unpaired test cannot
    got = compare_seeds(init, [1.3, 1.6, 1.1])  # gains 0.3, 0.4, 0.3
    assert got["delta"] == pytest.approx(1 / 3)
    assert got["delta_ci95"] == pytest.approx(_T2 * math.sqrt(1 / 300) / math.sqrt(3))
    assert (got["apart"], got["paired_apart"]) == (False, True)


def test_compare_seeds_leaves_out_what_the_seeds_cannot_tell():
    # guards the missing-value branches: no percentage of a mean that is not positive, no
    # paired gain of seeds that do not pair up, nothing apart before R* is measured
    from rbbo.reproduce.tables import compare_seeds

    got = compare_seeds([-1.0, -0.5], [0.5, 1.0])
    assert math.isnan(got["improvement_pct"]) and got["delta"] == pytest.approx(1.5)
    got = compare_seeds([1.0, 2.0, 3.0], [2.0, 3.0])
    assert math.isnan(got["delta"]) and math.isnan(got["delta_ci95"])
    assert got["improvement_pct"] == pytest.approx(25.0) and not got["paired_apart"]
    got = compare_seeds([1.0, 2.0], [])
    assert math.isnan(got["R_star"]) and math.isnan(got["improvement_pct"])
    assert not got["apart"] and not got["paired_apart"]


def _table_row(**changes):
    row = {"robot": "Cross", "task": "Swim", "N": 623, "M": 20, "C": 3, "R_init": 1.0,
           "R_init_ci95": 0.4968, "R_star": 1.6, "R_star_ci95": 1.138, "improvement_pct": 60.0,
           "delta": 0.6, "delta_ci95": 0.657, "evaluations": 12, "wall_s": 95.0,
           "apart": False, "paper_improvement_pct": 142.21}  # fmt: skip
    return {**row, **changes}


def test_table_one_prints_each_row_and_averages_the_confirmed_ones():
    # guards the cells a reader of REPORT.md compares with the paper: N, the intervals to two
    # significant digits, the signed improvement, apart, and the average row (the mean of
    # ours, the paper's over the same benchmarks)
    from rbbo.reproduce.tables import format_markdown

    rows = [_table_row(), _table_row(task="Walk", R_star=0.8, improvement_pct=-20.0, N=None,
                                     apart=True, paper_improvement_pct=544.32),
            _table_row(task="Run", improvement_pct=140.0, paper_improvement_pct=40.66)]  # fmt: skip
    lines = format_markdown(rows).splitlines()
    assert lines[2] == ("| Cross | Swim | 623 | 20 | 3 | 1 ± 0.5 | 1.6 ± 1.1 | +60.0 % | "
                        "0.6 ± 0.66 | 12 | 1m35s | no | +142.2 % |")  # fmt: skip
    assert lines[3].startswith("| Cross | Walk | - | 20 | 3 | 1 ± 0.5 | 0.8 ± 1.1 | -20.0 % |")
    assert lines[3].endswith("| yes | +544.3 % |")
    # the mean of +60, -20 and +140 (not the median, +60), the paper's likewise
    cells = [c.strip() for c in lines[-1].strip("|").split("|")]
    assert (cells[7], cells[12]) == ("+60.0 %", f"+{np.mean([142.21, 544.32, 40.66]):.1f} %")
    rows[2]["improvement_pct"] = 200.0  # mean +80.0, median +60.0
    cells = [c.strip() for c in format_markdown(rows).splitlines()[-1].strip("|").split("|")]
    assert cells[7] == "+80.0 %"
    # nothing confirmed yet: no average of ours, and the paper's over every benchmark
    nan = math.nan
    waiting = [{**r, "R_star": nan, "improvement_pct": nan, "delta": nan} for r in rows]
    cells = [c.strip() for c in format_markdown(waiting).splitlines()[-1].strip("|").split("|")]
    assert (cells[7], cells[12]) == ("-", f"+{np.mean([142.21, 544.32, 40.66]):.1f} %")


def test_a_table_with_negative_distances_reads_back_as_written():
    # guards parse_markdown (how the report is checked against the runs): a robot that moved
    # backwards has a negative R and gain, which must not read back as missing
    from rbbo.reproduce.tables import format_markdown

    row = _table_row(R_init=-0.25, R_init_ci95=0.1, R_star=-0.75, R_star_ci95=0.2,
                     improvement_pct=math.nan, delta=-0.5, delta_ci95=0.05)  # fmt: skip
    (back,) = parse_markdown("text before\n\n" + format_markdown([row]) + "\n\ntext after")
    assert (back["R_init"], back["R_init_ci95"]) == (-0.25, 0.1)
    assert (back["R_star"], back["R_star_ci95"]) == (-0.75, 0.2)
    assert (back["delta"], back["delta_ci95"]) == (-0.5, 0.05)
    assert math.isnan(back["improvement_pct"]) and back["N"] == 623 and not back["apart"]


def test_the_runs_table_lists_the_runs_in_their_order_whatever_order_they_come_in():
    # guards format_runs_markdown: each run's improvement (its seed in brackets) in run order
    from rbbo.reproduce.tables import format_runs_markdown

    rows = [{"benchmark": "BeamWalk-v0", "repeat": k, "seed": 10 + k, "R_star": 1.0 + k,
             "improvement_pct": 10.0 * (k + 1)} for k in (2, 0, 1)]  # fmt: skip
    line = format_runs_markdown(rows, 3).splitlines()[2]
    assert line.startswith("| BeamWalk-v0 | 3 | +10.0 % (10), +20.0 % (11), +30.0 % (12) | ")


def test_a_run_row_names_the_seed_its_run_was_made_with(tmp_path, monkeypatch):
    # guards table1_runs.csv's seed column: read from the run (seed + k), not the index k
    from rbbo.reproduce import tables

    monkeypatch.setattr(tables, "table_row", lambda bench, run: {"benchmark": bench, "R_star": 2.0})
    (tmp_path / "config.json").write_text(json.dumps({"rbbo": {"seed": 7}}))
    row = tables.run_row("CrossSwim-v0", 2, tmp_path)
    assert row == {"benchmark": "CrossSwim-v0", "repeat": 2, "seed": 7, "R_star": 2.0}


def _write_transfer(out, rows):
    from rbbo.reproduce.csv_rows import _append_row

    for benchmark, basis, m, seeds, digest in rows:
        _append_row(out / "transfer.csv", {"benchmark": benchmark, "basis": basis, "M": m,
                                           "R_mean": float(np.mean(seeds)),
                                           "R_seeds": " ".join(str(s) for s in seeds),
                                           "seeds": "7 8 9", "wall_s": 1.0, "run": "r",
                                           "basis_digest": digest})  # fmt: skip


def test_the_transfer_table_compares_the_bases_measured_at_the_larger_m(tmp_path):
    # guards transfer_rows and its table: R_init and R* at M' from their own rows (those at
    # another M' left out), the improvement and paired gain there beside Table I's at M,
    # "apart" as Table I says it (the unpaired test)
    from rbbo.reproduce.transfer import format_transfer_markdown, transfer_rows

    _write_transfer(tmp_path, [("CrossSwim-v0", "identity", 40, [1.0, 1.2, 0.8], ""),
                               ("CrossSwim-v0", "best", 40, [1.3, 1.6, 1.1], ""),
                               ("BeamWalk-v0", "identity", 40, [1.0, 1.0, 1.0], ""),
                               ("CrossSwim-v0", "best", 30, [9.0, 9.0, 9.0], "")])  # fmt: skip
    table = [{"benchmark": b, "M": 20, "R_init": 1.0, "R_star": 2.0, "improvement_pct": 100.0}
             for b in ("CrossSwim-v0", "BeamWalk-v0")]  # fmt: skip
    (row,) = transfer_rows(tmp_path, table, 40)  # BeamWalk's R* is not measured yet
    assert (row["benchmark"], row["M_from"], row["M"]) == ("CrossSwim-v0", 20, 40)
    assert row["R_init"] == pytest.approx(1.0) and row["R_star"] == pytest.approx(4 / 3)
    assert row["R_init_ci95"] == pytest.approx(_T2 * 0.2 / math.sqrt(3))
    assert row["improvement_pct"] == pytest.approx(100 / 3)
    assert row["delta"] == pytest.approx(1 / 3)
    assert (row["apart"], row["paired_apart"]) == (False, True)
    lines = format_transfer_markdown([row]).splitlines()
    assert lines[0] == ("| benchmark | improvement at M = 20 | R_init at M = 40 | R* at M = 40 | "
                        "improvement at M = 40 | R* - R_init (paired) | apart |")  # fmt: skip
    assert lines[2] == ("| CrossSwim-v0 | +100.0 % | 1 ± 0.5 | 1.333 ± 0.63 | +33.3 % | "
                        "0.3333 ± 0.14 | no |")  # fmt: skip


def test_transfer_rows_of_the_current_best_basis_count_and_others_do_not(tmp_path):
    # guards current_rows: a "best" row of a B_c that Table I's run no longer recommends is
    # left out; the identity's row and rows without a digest (older) are kept
    from rbbo.reproduce.tables import basis_digest
    from rbbo.reproduce.transfer import current_rows

    best = np.linalg.qr(np.random.default_rng(1).standard_normal((20, 3)))[0]
    eye = basis_digest(np.eye(20)[:, :3])
    _write_transfer(tmp_path, [("CrossSwim-v0", "identity", 40, [1.0], eye),
                               ("CrossSwim-v0", "best", 40, [2.0], "0badc0de"),
                               ("BeamWalk-v0", "best", 40, [3.0], "")])  # fmt: skip
    # Table I's run has not recommended a B_c yet: nothing tells the best row stale
    assert [r["R_seeds"] for r in current_rows(tmp_path, 40)] == ["1.0", "2.0", "3.0"]
    run = tmp_path / "runs" / "CrossSwim-v0-boca"
    run.mkdir(parents=True)
    np.save(run / "best_basis.npy", best)
    assert [r["R_seeds"] for r in current_rows(tmp_path, 40)] == ["1.0", "3.0"]
    _write_transfer(tmp_path, [("CrossSwim-v0", "best", 40, [4.0], basis_digest(best))])
    assert [r["R_seeds"] for r in current_rows(tmp_path, 40)] == ["1.0", "3.0", "4.0"]
    assert current_rows(tmp_path, 30) == []


def test_a_transfer_row_keeps_its_seeds_to_six_digits(reproduction):
    # guards transfer.csv: the per-seed R the transfer table's intervals come from are
    # written to six significant digits, so their mean is R_mean's
    from rbbo.reproduce.tables import read_rows

    for r in read_rows(reproduction / "transfer.csv"):
        seeds = [float(v) for v in r["R_seeds"].split()]
        assert np.mean(seeds) == pytest.approx(float(r["R_mean"]), rel=2e-6, abs=1e-9), r


def test_status_counts_each_benchmarks_transfer_and_every_study_seed(tmp_path):
    # guards the transfer and studies lines of --status and the report's progress: a
    # benchmark's transfer is done with both bases measured (each benchmark counted apart),
    # the reward study planned is C values x seeds, and the work left is named
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.status import stage_progress, status_lines

    plan = ReproducePlan(benchmarks=["CrossSwim-v0", "BeamWalk-v0"], stages=["transfer", "studies"],
                         cost_cs=[1, 2], reward_cs=[1, 2], study_seeds=2)  # fmt: skip
    _write_transfer(tmp_path, [("CrossSwim-v0", "identity", 40, [1.0], ""),
                               ("CrossSwim-v0", "best", 40, [2.0], ""),
                               ("BeamWalk-v0", "identity", 40, [1.0], "")])  # fmt: skip
    for c in (1, 2):
        _append_row(tmp_path / "studies" / "cost_vs_c.csv", {"C": c, "iteration_s": 0.1 * c})
    for c, seed in ((1, 0), (1, 1), (2, 0)):
        _append_row(tmp_path / "studies" / "reward_vs_c.csv", {"C": c, "seed": seed, "R_m": 0.1})
    assert status_lines(tmp_path, plan) == [
        "transfer     CrossSwim-v0         2 of 2 bases measured at M = 40",
        "transfer     BeamWalk-v0          1 of 2 bases measured at M = 40",
        "studies      CrossWalk-v0         cost vs C 2 of 2, reward vs C 3 of 4",
        "optimisation budget left: 0.00 h on 2 workers, plus the transfer and the studies of C",
    ]
    progress = stage_progress(tmp_path, plan)
    assert (progress["transfer"], progress["studies"]) == ((1, 2), (5, 6))


def test_status_tells_a_run_confirming_searching_or_past_its_budget(reproduction, tmp_path):
    # guards _run_state: a run that searched its evaluations but has no confirmation yet is
    # not done (nor counted so); one budget-bound with budget left counts that budget; one
    # that ran past its budget and confirmed is done, with no budget (not a negative one) left
    import shutil
    from dataclasses import replace

    from rbbo.reproduce.status import stage_progress, status_lines

    plan = ReproducePlan.from_dict(
        json.loads((reproduction / "reproduce.json").read_text())["plan"]
    )
    plan = replace(plan, stages=["table"])
    run = tmp_path / "runs" / "CrossSwim-v0-boca"
    shutil.copytree(reproduction / "runs" / "CrossSwim-v0-boca", run)
    history = (run / "history.jsonl").read_text().splitlines()
    searched = [x for x in history if not json.loads(x)["kind"].startswith("confirm")]
    (run / "history.jsonl").write_text("\n".join(searched) + "\n")
    lines = status_lines(tmp_path, plan)
    assert lines[0] == "table        CrossSwim-v0         confirming (3 evaluations)"
    assert lines[1] == "optimisation budget left: 0.00 h on 1 worker, plus the confirmations"
    assert stage_progress(tmp_path, plan)["table"] == (0, 1)
    lines = status_lines(tmp_path, replace(plan, iterations=None))  # budget-bound: 45 min
    assert lines[0].startswith("table        CrossSwim-v0         searching: 3 evaluations, ")
    assert lines[0].endswith(" of 45 min")
    assert 0.7 < float(lines[1].split("left: ")[1].split(" h")[0]) <= 0.75
    (run / "history.jsonl").write_text("\n".join(history) + "\n")
    lines = status_lines(tmp_path, replace(plan, iterations=None, budget_s=1e-6))
    assert lines[0].startswith("table        CrossSwim-v0         done: 3 evaluations in ")
    assert lines[1] == "optimisation budget left: 0.00 h on 1 worker"


def test_status_counts_each_directions_own_budget(reproduction, tmp_path):
    # guards the budget --status adds up for stage directions: each direction's run has the
    # direction budget (not Table I's), and what it has not spent counts
    from dataclasses import replace

    from rbbo.reproduce.status import status_lines

    plan = ReproducePlan.from_dict(
        json.loads((reproduction / "reproduce.json").read_text())["plan"]
    )
    plan = replace(plan, stages=["directions"], iterations=None, direction_budget_s=3600.0)
    (tmp_path / "runs").symlink_to(reproduction / "runs")
    lines = status_lines(tmp_path, plan)
    assert [x.split("  ")[0] for x in lines[:2]] == ["directions"] * 2
    assert all(x.endswith("min; 60.0 min more to search") for x in lines[:2]), lines
    assert 1.9 < float(lines[2].split("left: ")[1].split(" h")[0]) <= 2.0  # 2 x 1 h, less spent


def test_the_rl_stage_is_done_when_every_basis_it_trains_has_its_rows(tmp_path):
    # guards stage_progress's rl count: a benchmark is done when baselines.csv has rows of
    # the identity and of Table I's B_c (not the identity's alone), and a benchmark trained
    # by an earlier session is counted beside the plan's
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.status import rl_bases, stage_progress

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], rl_benchmarks=["CrossSwim-v0"],
                         stages=["rl"], rl_algos=["ppo"], rl_steps=64)  # fmt: skip
    run = tmp_path / "runs" / "CrossSwim-v0-boca"
    run.mkdir(parents=True)
    np.save(
        run / "best_basis.npy", np.linalg.qr(np.random.default_rng(2).standard_normal((20, 3)))[0]
    )
    table = tmp_path / "rl" / "CrossSwim-v0" / "baselines.csv"

    def final(env, basis, steps=64, method="ppo"):
        return {"env": env, "method": method, "basis": basis, "final": True, "env_steps": steps}

    _append_row(table, final("CrossSwim-v0", "identity"))
    assert stage_progress(tmp_path, plan)["rl"] == (0, 1)
    (other,) = (name for name in rl_bases(tmp_path, plan, "CrossSwim-v0")[0] if name != "identity")
    _append_row(table, {**final("CrossSwim-v0", other, 32), "final": False})  # a checkpoint
    assert stage_progress(tmp_path, plan)["rl"] == (0, 1)
    _append_row(table, final("CrossSwim-v0", other))
    assert stage_progress(tmp_path, plan)["rl"] == (1, 1)
    # a later session that trains longer, or another algorithm, is not done by these rows
    # (its status and report called it done; a review, session 54)
    for more in ({"rl_steps": 128}, {"rl_algos": ["ppo", "sac"]}):
        assert stage_progress(tmp_path, replace(plan, **more))["rl"] == (0, 1), more
    (tmp_path / "rl" / "BeamWalk-v0").mkdir()  # an earlier session's, not finished
    assert stage_progress(tmp_path, plan)["rl"] == (1, 2)
    # finished: its Table I run has no B_c, so the identity's rows are all it trains
    _append_row(tmp_path / "rl" / "BeamWalk-v0" / "baselines.csv",
                final("BeamWalk-v0", "identity"))  # fmt: skip
    assert stage_progress(tmp_path, plan)["rl"] == (2, 2)


def test_a_library_calls_command_names_no_stages():
    # guards recorded_stages: only an `rbbo reproduce` command is read for --stages (a
    # session started from Python recorded its own sys.argv)
    from rbbo.reproduce.status import recorded_stages

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"]).to_dict()
    sessions = [{"command": "python my_script.py --stages rl"},
                {"command": "rbbo reproduce --stages bo"}]  # fmt: skip
    assert recorded_stages({"plan": plan, "sessions": sessions}) == ["table", "bo"]


def test_status_counts_the_offsets_of_the_base_run_and_older_rows_without_a_digest(tmp_path):
    # guards _current_offsets: perturbation rows of another run are not the base B_c's
    # offsets; rows written before rows carried a digest are the base run's own
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.status import status_lines
    from rbbo.reproduce.tables import basis_digest

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], direction_env="CrossSwim-v0",
                         stages=["perturbation"], perturbations_deg=[10.0])  # fmt: skip
    base = tmp_path / "runs" / "CrossSwim-v0-dir000"
    base.mkdir(parents=True)
    np.save(base / "best_basis.npy", np.eye(20)[:, :3])
    digest = basis_digest(np.eye(20)[:, :3])
    for offset, run, row_digest in ((0.0, base, digest), (10.0, base, ""),
                                    (-10.0, tmp_path / "runs" / "CrossSwim-v0-boca", digest),
                                    (-10.0, base, "0badc0de")):  # fmt: skip
        _append_row(tmp_path / "perturbation.csv", {"offset_deg": offset, "run": str(run),
                                                   "basis_digest": row_digest})  # fmt: skip
    assert status_lines(tmp_path, plan)[0] == "perturbation CrossSwim-v0         2 of 3 offsets"


def test_stage_progress_counts_every_repeated_table_run(repeated):
    # guards stage_progress's table count: each of the repeats' runs is a part
    from dataclasses import replace

    from rbbo.reproduce.status import stage_progress

    out, _ = repeated
    plan = ReproducePlan.from_dict(json.loads((out / "reproduce.json").read_text())["plan"])
    assert stage_progress(out, replace(plan, repeats=2))["table"] == (2, 2)
    assert stage_progress(out, replace(plan, repeats=3))["table"] == (2, 3)


def test_rl_status_shows_how_far_each_job_has_trained(tmp_path):
    # guards _rl_state: a job's steps are its latest progress row's, of its algorithm's target
    from rbbo.reproduce.status import _rl_state

    plan = ReproducePlan(rl_algos=["ppo", "sac"], rl_steps={"ppo": 300, "sac": 100})
    for job, steps in (("ppo-identity", (100, 200)), ("sac-identity", (50,))):
        (tmp_path / job).mkdir()
        (tmp_path / job / "progress.jsonl").write_text(
            "".join(json.dumps({"steps": n, "wall_s": 1.0}) + "\n" for n in steps)
        )
    assert _rl_state(tmp_path, plan) == "ppo-identity 200/300 steps, sac-identity 50/100 steps"


def test_the_runs_section_names_the_seeds_of_every_run():
    # guards _across_runs' text: run k is seeded seed + k, so the runs' seeds span
    # seed .. seed + repeats - 1, and each run's convergence figure is linked
    from rbbo.reproduce.report_sections import _across_runs

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], repeats=3, seed=5)
    per_run = [{"benchmark": "CrossSwim-v0", "repeat": k, "run": f"/x/runs/CrossSwim-v0-boca{s}"}
               for k, s in ((0, ""), (1, "-run1"), (2, "-run2"))]  # fmt: skip
    text = "\n".join(_across_runs(per_run, "TABLE", plan))
    assert "its run 0 (seed 5)" in text and "run k seeded 5 + k (seeds 5-7)" in text
    assert "- CrossSwim-v0 convergence: [run 0](runs/CrossSwim-v0-boca/convergence.png), " \
        "[run 1](runs/CrossSwim-v0-boca-run1/convergence.png), " \
        "[run 2](runs/CrossSwim-v0-boca-run2/convergence.png)" in text  # fmt: skip


def _ev(T, R, wall_s, elapsed_s, status="ok"):
    from types import SimpleNamespace

    return SimpleNamespace(T=T, R=R, wall_s=wall_s, elapsed_s=elapsed_s, seeds=[1], status=status)


def test_the_bo_vs_boca_row_is_computed_from_the_evaluations(tmp_path):
    # guards the BO-vs-BOCA table's numbers: best R over the T_max evaluations that ran, BO's
    # best within the simulated time BOCA spent (failed evaluations spend time but give no
    # R), simulated minutes over every evaluation, the median wall time of a T_max one
    from rbbo.reproduce.report_sections import _bo_vs_boca

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"])  # T_max = 10 s
    boca = [_ev(4.0, 9.0, 0.4, 1), _ev(10.0, 2.0, 1.0, 2), _ev(10.0, 3.0, 2.0, 3),
            _ev(10.0, 5.0, 6.0, 4)]  # fmt: skip
    bo = [_ev(10.0, math.nan, 0.5, 1, "failed"), _ev(10.0, 1.0, 1.0, 2), _ev(10.0, 4.0, 1.0, 3),
          _ev(10.0, 7.0, 1.0, 4)]  # fmt: skip
    written = {"figures": []}
    confirmed = {"CrossSwim-v0": {"boca": (2.5, False), "bo": (None, False)}}
    lines = _bo_vs_boca({"CrossSwim-v0": {"boca": boca, "bo": bo}}, confirmed, tmp_path, plan,
                        written)  # fmt: skip
    row = next(x for x in lines if x.startswith("| CrossSwim-v0 |"))
    # BOCA spent 34 s (0.57 min): BO's first three evaluations (30 s) fit, one failed
    assert row == "| CrossSwim-v0 | 5 | 7 | 4 | 0.6 / 0.7 | 2 / 1 | 4 | 4 | 2.5 / - |"
    assert not any("The BOCA runs of" in x for x in lines)
    confirmed = {"CrossSwim-v0": {"boca": (2.5, True), "bo": (3.0, False)}}
    lines = _bo_vs_boca({"CrossSwim-v0": {"boca": boca, "bo": bo}}, confirmed, tmp_path, plan,
                        written)  # fmt: skip
    assert any(x.startswith("The BOCA runs of CrossSwim-v0 searched the simulation space")
               for x in lines)  # fmt: skip


def test_the_studies_of_c_report_the_slope_and_each_cs_seeds(tmp_path):
    # guards the studies' sections: the log-log slope of the cost (and whether it is
    # superlinear), and per C of the reward study its mean, sd and seeds, C in order
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.report_sections import _studies

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"])
    for c in (1, 2, 4):
        _append_row(tmp_path / "studies" / "cost_vs_c.csv",
                    {"C": c, "rollouts": 8, "iteration_s": 0.1 * c**1.5})  # fmt: skip
    for c, r_m in ((2, 0.5), (1, 0.1), (2, 0.6), (3, 0.2), (1, 0.3), (2, 0.7)):
        _append_row(tmp_path / "studies" / "reward_vs_c.csv", {"C": c, "seed": 0, "R_m": r_m})
    text = "\n".join(_studies(tmp_path, plan, {"figures": []}))
    assert "log-log slope 1.50 (1 = linear in C): superlinear, as the paper's." in text
    rows = [x for x in text.splitlines() if re.match(r"\| \d \| [+-]", x)]
    # (the sample sd, n - 1, as the runs spread's; none for one seed)
    assert rows == ["| 1 | +0.2000 | 0.1414 | 2 |", "| 2 | +0.6000 | 0.1000 | 3 |",
                    "| 3 | +0.2000 | - | 1 |"]  # fmt: skip
    assert "The mean distance is highest at C = 2;" in text
    (tmp_path / "studies" / "cost_vs_c.csv").unlink()
    for c in (1, 4):
        _append_row(tmp_path / "studies" / "cost_vs_c.csv",
                    {"C": c, "rollouts": 8, "iteration_s": 0.1 * c**0.5})  # fmt: skip
    text = "\n".join(_studies(tmp_path, plan, {"figures": []}))
    assert "log-log slope 0.50 (1 = linear in C): not superlinear, unlike the paper's." in text
    _append_row(tmp_path / "studies" / "cost_vs_c.csv", {"C": 2, "rollouts": 8, "iteration_s": 0})
    text = "\n".join(_studies(tmp_path, plan, {"figures": []}))  # a timing of 0: no slope
    assert "| 2 | 8 | 0.000 |" in text and "log-log slope" not in text


def test_the_report_names_each_machine_and_setting_once_in_session_order():
    # guards REPORT.md's "on <machines>" and budget/workers lines: each distinct value once,
    # in the order the sessions used it, budgets in minutes, sessions without a machine counted
    from rbbo.reproduce.report_text import _machine, _session_values

    sessions = [{"machine": "a", "budget_s": 2700.0, "workers": 2},
                {"machine": "b", "budget_s": 2700.0, "workers": 4},
                {"machine": "a", "budget_s": 3600.0}]  # fmt: skip
    assert _machine(sessions) == "a / b"
    assert _machine([*sessions, {}]) == "a / b (and 1 session whose machine was not recorded)"
    assert _machine([{}, {}]) == (
        "a machine not recorded (2 sessions whose machine was not recorded)"
    )
    assert _session_values(sessions, "budget_s", 60.0) == "45 / 60"
    assert _session_values(sessions, "workers", 1) == "2 / 4 / 1"  # the last as now given


def test_the_progress_lines_skip_stages_with_nothing_planned_and_relinks_keep_urls(tmp_path):
    # guards _progress_lines (a stage with no part planned is not "not finished") and
    # _relink (a report copied elsewhere points at the record; web links stay as they are)
    from rbbo.reproduce.report_text import _progress_lines, _relink

    assert _progress_lines({"table": (0, 0), "bo": (0, 1), "rl": (1, 1)}) == [
        "No part finished yet: bo.", ""]  # fmt: skip
    out = tmp_path / "out"
    out.mkdir()
    lines = ["![a](runs/x/convergence.png) and [b](https://example.org/a)"]
    assert _relink(lines, out, tmp_path / "docs") == [
        "![a](../out/runs/x/convergence.png) and [b](https://example.org/a)"]  # fmt: skip


def test_an_appended_row_without_some_columns_leaves_their_cells_empty(tmp_path):
    # guards _append_row: a row lacking columns of the file (written by a newer version)
    # lines its cells up under the file's header, not shifted left
    from rbbo.reproduce.csv_rows import _append_row
    from rbbo.reproduce.tables import read_rows

    path = tmp_path / "t.csv"
    _append_row(path, {"benchmark": "CrossSwim-v0", "basis": "best", "basis_digest": "abc"})
    _append_row(path, {"benchmark": "BeamWalk-v0", "basis_digest": "def"})
    assert read_rows(path)[1] == {"benchmark": "BeamWalk-v0", "basis": "", "basis_digest": "def"}


def test_the_perturbation_study_walks_the_direction_zero_run_before_table_ones(tmp_path):
    # guards _perturbation_base: the directions stage's direction-0 run is the base when it
    # has a B_c, Table I's run of the same robot only without it
    from rbbo.reproduce.stages import _perturbation_base

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], direction_env="CrossSwim-v0")
    runs = tmp_path / "runs"
    for name in ("CrossSwim-v0-boca", "CrossSwim-v0-dir000"):
        (runs / name).mkdir(parents=True)
    np.save(runs / "CrossSwim-v0-boca" / "best_basis.npy", np.eye(20)[:, :3])
    assert _perturbation_base(tmp_path, plan) == runs / "CrossSwim-v0-boca"
    np.save(runs / "CrossSwim-v0-dir000" / "best_basis.npy", np.eye(20)[:, :3])
    assert _perturbation_base(tmp_path, plan) == runs / "CrossSwim-v0-dir000"


def test_the_rl_stage_evaluates_as_table_one_measures(tmp_path, monkeypatch):
    # guards rl_baselines' settings: RL and MPC are evaluated on episodes of T_max from the
    # settle time on the plan's number of fresh seeds, as Table I's R is
    import rbbo.rl
    from rbbo.reproduce.runner import rl_baselines

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], rl_benchmarks=["CrossSwim-v0"],
                         confirm_seeds=4, t_min=3.0, t_max=7.0, settle_time=1.5,
                         seed=3)  # fmt: skip
    calls = []
    monkeypatch.setattr(rbbo.rl, "run_baselines", lambda *a, **k: calls.append(k))
    rl_baselines(tmp_path, plan, False, lambda message: None)
    (kwargs,) = calls
    assert {k: kwargs[k] for k in ("eval_seeds", "seconds", "settle_time", "seed")} == {
        "eval_seeds": 4, "seconds": 7.0, "settle_time": 1.5, "seed": 3}  # fmt: skip


def test_a_second_session_on_the_same_directory_is_refused_and_changes_nothing(
    tmp_path, capsys, monkeypatch
):
    """Two sessions in one --out at once (the same command in a second terminal while the
    first runs under nohup) would append the same CSV rows and each rewrite reproduce.json
    from what it had read, one session's record lost: the second is refused in one line and
    writes nothing (found running rbbo reproduce twice on one --out; reproduce.json kept one
    of the two sessions). A folder that is a file is named too."""
    import subprocess
    import sys

    from rbbo.reproduce import runner

    monkeypatch.setattr(runner, "optimise", lambda path, *args, **kwargs: path)
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    argv = ["reproduce", "--benchmarks", "CrossSwim-v0", "--stages", "table", "--no-progress"]
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    holder = subprocess.Popen(  # a session still running in another process
        [sys.executable, "-c", "import fcntl, os, sys, time\n"
         f"fd = os.open({str(out / '.rbbo.lock')!r}, os.O_RDWR | os.O_CREAT)\n"
         "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline() == "held\n"
        code = main([*argv, "--out", str(out)])
        err = capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    assert code == 2
    assert err.startswith("rbbo: error: ") and err.count("\n") == 1
    assert f"{out} is in use by another process" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert main([*argv, "--out", str(out)]) == 0  # once it has ended
    sessions = json.loads((out / "reproduce.json").read_text())["sessions"]
    assert len(sessions) == 2
    capsys.readouterr()
    (tmp_path / "file").write_text("")
    code = main([*argv, "--out", str(tmp_path / "file")])
    err = capsys.readouterr().err
    assert code == 2
    assert f"cannot create the reproduction directory {tmp_path / 'file'}" in err


def test_status_reads_iterations_and_workers_given_as_a_session_would_run(
    reproduction, tmp_path, capsys
):
    """--status with a larger --iterations than the stored cap said 'done' and no budget
    left, as if the option were not there, though a session given it searches on; its
    --workers were ignored too (found with rbbo reproduce --iterations 5 --status after a
    session of --iterations 3)."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(reproduction, out)
    status = ["reproduce", "--out", str(out), "--status", "--stages", "table"]
    capsys.readouterr()
    assert main(status) == 0
    stored = capsys.readouterr().out.splitlines()
    assert "done: 3 evaluations" in stored[0] and stored[-1].startswith(
        "optimisation budget left: 0.00 h on 1 worker"
    )
    assert main([*status, "--iterations", "5", "--workers", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "done" not in lines[0] and "min more to search" in lines[0]
    assert not lines[-1].startswith("optimisation budget left: 0.00 h")
    assert "on 2 workers" in lines[-1]


@pytest.mark.parametrize(
    ("argv", "noted"),
    [(["--iterations", "3"], True), (["--iterations", "7"], False),
     (["--iterations", "3", "--init", "1"], False)],
)  # fmt: skip
def test_iterations_the_initial_design_fills_are_noted(tmp_path, capsys, monkeypatch, argv, noted):
    """rbbo optimize notes an --iterations that the initial design fills (no GP proposal);
    rbbo reproduce said nothing, and its report calls such runs RBBO's (found with the tiny
    reproduce of --iterations 3 under the default --init 5: every evaluation 'initial')."""
    from rbbo.reproduce import runner

    monkeypatch.setattr(runner, "optimise", lambda path, *args, **kwargs: path)
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    code = main(["reproduce", "--benchmarks", "CrossSwim-v0", "--stages", "table",
                 "--no-progress", "--out", str(tmp_path / "out"), *argv])  # fmt: skip
    assert code == 0
    err = capsys.readouterr().err
    assert ("the initial design (the identity basis, then 5 random points) takes every "
            "evaluation of the runs of stage(s) table" in err) is noted  # fmt: skip


@pytest.mark.parametrize(
    ("sessions", "match"),
    [(5, "'sessions' must be a list, got 5"),
     ([1], "session 1 is not a record with its command: 1"),
     ([{"command": "rbbo reproduce", "wall_s": "x"}], "session 1's wall_s is 'x'"),
     ([{"command": "rbbo reproduce", "stages": "table"}], "session 1's stages is 'table'")],
)  # fmt: skip
def test_a_hand_edited_session_record_is_named_for_status_report_only_and_a_rerun(
    sessions, match, tmp_path, capsys, monkeypatch
):
    """reproduce.json's sessions were read unchecked: a hand edit that made them no list, or
    a record no object or with a wall time that is no number, was a TypeError or
    AttributeError traceback of --status, --report-only and a rerun (found editing the
    reproduce.json of a tiny reproduction)."""
    from rbbo.reproduce import runner

    monkeypatch.setattr(runner, "optimise", lambda path, *args, **kwargs: path)
    monkeypatch.setattr(runner, "_objective", lambda plan, bench, *args: None)
    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"])
    text = json.dumps({"plan": plan.to_dict(), "sessions": sessions})
    (tmp_path / "reproduce.json").write_text(text)
    out = ["reproduce", "--out", str(tmp_path)]
    rerun = ["--benchmarks", "CrossSwim-v0", "--stages", "table", "--no-progress"]
    for argv in (["--status"], ["--report-only"], rerun):
        assert main([*out, *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "reproduce.json is not a reproduce plan" in err[0]
        assert match in err[0]
        assert (tmp_path / "reproduce.json").read_text() == text  # kept for its owner to mend


def test_an_optimisation_run_stopped_by_an_error_releases_its_run_directory(tmp_path):
    # optimise() left the run's lock to the garbage collector: while the error that stopped
    # it was being handled (its traceback holds the run), another process, such as an
    # `rbbo resume DIR` started from the message, was refused as "in use"
    import subprocess
    import sys

    from rbbo import SyntheticObjective
    from rbbo.reproduce.optimisation_runs import optimise

    class Named(SyntheticObjective):
        env_id = "synthetic"

        def node_count(self):
            return 0

    plan = ReproducePlan(sim_dim=6, control_dim=2, cost_cs=[1, 2], reward_cs=[1, 2], n_init=2,
                         iterations=3, confirm_seeds=2, executor="serial")  # fmt: skip

    def heartbeat():
        raise RuntimeError("stopped after the first evaluation")

    run = tmp_path / "run"
    # (`stopped` holds the traceback, and through it optimise()'s run, as a handler would)
    with pytest.raises(RuntimeError, match="stopped after the first evaluation") as stopped:
        optimise(run, plan, Named(6, 2, t_max=plan.t_max), "bo", 60.0, False, lambda line: None,
                 heartbeat=heartbeat)  # fmt: skip
    assert stopped.tb is not None
    code = "import sys; from rbbo import RBBO; print(len(RBBO.resume(sys.argv[1]).history))"
    child = subprocess.run([sys.executable, "-c", code, str(run)], capture_output=True,
                           text=True, timeout=120)  # fmt: skip
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == "1"


def test_a_run_refused_for_another_plan_is_closed_so_the_next_try_gets_the_same_answer(
    tmp_path,
):
    # A run of another plan is refused by name; it must also be closed at once: a second
    # writer in one process is refused, so a run left open by the refusal made the next
    # attempt read "in use by another writer in this process" instead.
    from rbbo import RBBO
    from rbbo.reproduce.optimisation_runs import _config, _objective, optimise
    from rbbo.store import RunDirectoryError

    plan = ReproducePlan(benchmarks=["CrossSwim-v0"], stages=["table"])
    objective = _objective(plan, "CrossSwim-v0")
    path = tmp_path / "run"
    other = _config(plan, "boca", 60.0, repeat=1)  # another seed
    RBBO.create(path, other, objective_spec=objective.spec()).close()
    kept = []  # (the tracebacks kept, as a caller's handler may: they hold the frame's run)
    for _ in range(2):
        with pytest.raises(RunDirectoryError, match="was made with seed = 1, this plan has 0") as e:
            optimise(path, plan, objective, "boca", 60.0, False, lambda line: None)
        kept.append(e)
