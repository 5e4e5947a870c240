"""The RBBO loop (rbbo.optimizer): ask/tell, quality vs random search, BOCA, resume."""

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import types
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from rbbo import RBBO, RBBOConfig, RBBOResult, SyntheticObjective
from rbbo.baselines import random_search
from rbbo.executors import Executor, ProcessExecutor, SerialExecutor
from rbbo.executors.base import evaluate_task
from rbbo.grassmann import identity_basis, projection_distance, random_points, validate_basis
from rbbo.store import RunDirectoryError

# small, fast settings: tiny GPs, few acquisition starts
FAST = {"acq_random": 64, "acq_starts": 2, "acq_max_iterations": 30, "gp_restarts": 0}


def test_rbbo_beats_random_search_at_equal_evaluations():
    m, c, n = 10, 2, 20
    rbbo_values, random_values = [], []
    for seed in range(5):
        objective = SyntheticObjective(m, c, optimum_seed=100 + seed, noise=0.02)
        config = RBBOConfig(m, c, n_init=4, seed=seed, max_evaluations=n, n_confirm=0, **FAST)
        result = RBBO(config).run(objective)
        assert result.evaluations == n
        rbbo_values.append(objective.value(result.best_basis))
        # random search's pick: its best *observed* (noisy) value, judged noise-free
        evaluated = random_search(objective, m, c, n, T=10.0, rng=[seed, 99])
        best = max(evaluated, key=lambda e: e[1])[0]
        random_values.append(objective.value(best))
    assert np.mean(rbbo_values) > np.mean(random_values) + 0.1, (rbbo_values, random_values)


def test_ask_starts_with_the_identity_and_tell_records():
    opt = RBBO(RBBOConfig(6, 2, n_init=2, seeds=3, seed=5, **FAST))
    first = opt.ask()
    assert first.kind == "initial" and first.T == 10.0 and first.seeds == (5, 6, 7)
    np.testing.assert_array_equal(first.basis, identity_basis(6, 2))
    evaluation = opt.tell(first.index, 0.5, R_seeds=[0.4, 0.5, 0.6], worker="w")
    assert evaluation.R == 0.5 and opt.history == [evaluation] and not opt.pending
    with pytest.raises(ValueError, match="no pending proposal with index 0"):
        opt.tell(0, 1.0)
    second = opt.ask()
    failed = opt.tell(second.index, float("nan"))
    assert failed.status == "failed" and "non-finite" in failed.error
    # a bad status is refused with the proposal still pending, to be told again
    third = opt.ask()
    with pytest.raises(ValueError, match="status must be one of"):
        opt.tell(third.index, 1.0, status="weird")
    assert third.index in opt.pending
    assert opt.tell(third.index, 1.0).status == "ok"


def test_tell_takes_numpy_scalars_into_a_run_directory(tmp_path):
    # an np.int64 index (from an array of indices) or an np.float32 R (a torch or float32
    # model's) is recorded as Python's: the history is JSON
    opt = RBBO.create(tmp_path / "run", RBBOConfig(6, 2, n_init=2, **FAST))
    first, second = opt.ask(), opt.ask()
    told = [opt.tell(np.int64(first.index), np.float32(0.5)), opt.tell(second.index, np.int32(1))]
    assert [(e.index, e.R) for e in told] == [(0, 0.5), (1, 1.0)]
    assert all(type(e.index) is int and type(e.R) is float for e in told)
    assert [e.R for e in RBBO.resume(tmp_path / "run", read_only=True).history] == [0.5, 1.0]
    third = opt.ask()
    with pytest.raises(ValueError, match=r"R must be a number, got array\(\[0.3\]\)"):
        opt.tell(third.index, np.array([0.3]))
    assert third.index in opt.pending


def test_tell_with_a_non_finite_seed_records_a_failure_in_a_run_directory(tmp_path):
    # one seed's episode diverged: R (their mean) and R_seeds hold NaN, which JSON cannot
    opt = RBBO.create(tmp_path / "run", RBBOConfig(6, 2, n_init=2, **FAST))
    first, second = opt.ask(), opt.ask()
    failed = opt.tell(first.index, float("nan"), R_seeds=[0.4, float("nan")])
    assert failed.status == "failed" and failed.R_seeds == [] and "non-finite" in failed.error
    failed = opt.tell(second.index, 0.4, R_seeds=[0.4, float("inf")])
    assert failed.status == "failed" and failed.R is None
    assert failed.error == "non-finite R over seeds: (0.4, inf)"
    third = opt.ask()
    with pytest.raises(ValueError, match="wall_s must be a finite number of seconds, got nan"):
        opt.tell(third.index, 0.5, wall_s=float("nan"))
    assert third.index in opt.pending
    assert [e.status for e in RBBO.resume(tmp_path / "run", read_only=True).history] == [
        "failed", "failed"]  # fmt: skip


def test_a_serial_run_is_reproducible_and_answer_order_decides_the_next_proposal():
    def run(order):
        objective = SyntheticObjective(6, 2, optimum_seed=3, noise=0.01)
        opt = RBBO(RBBOConfig(6, 2, n_init=3, seed=1, **FAST))
        for _ in range(4):  # the initial design, answered in order
            p = opt.ask()
            opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
        pending = [opt.ask(), opt.ask()]  # two workers
        for p in pending if order == "ab" else pending[::-1]:
            opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
        return opt.ask().basis

    # Same settings, same answers in the same order: the same next proposal, bitwise.
    np.testing.assert_array_equal(run("ab"), run("ab"))
    # Answers arriving in the other order (what parallel workers do) change the GP's data
    # order, and so the proposal: why a run with --workers > 1 does not repeat exactly.
    assert not np.array_equal(run("ab"), run("ba"))


class _ScrambledExecutor(Executor):
    """Two threads whose evaluations finish out of proposal order: an index in ``slow`` waits
    until the proposal after it has finished (both are in flight together on 2 workers)."""

    def __init__(self, objective, slow, last):
        self.objective, self.slow, self.last, self.workers = objective, slow, last, 2
        self.finished: list[int] = []
        self._done = {i: threading.Event() for i in range(last + 1)}
        self._pool = ThreadPoolExecutor(2)

    def submit(self, task):
        def evaluate():
            if task.index in self.slow and task.index < self.last:
                # (a timeout went on silently, and the test failed later on the finish order)
                if not self._done[task.index + 1].wait(timeout=60.0):
                    raise AssertionError(f"task {task.index + 1} did not finish in 60 s")
            outcome = evaluate_task(self.objective, task, "thread")
            self.finished.append(task.index)
            self._done[task.index].set()
            return outcome

        return self._pool.submit(evaluate)

    def shutdown(self, wait=True):
        self._pool.shutdown(wait=wait)


def test_a_deterministic_parallel_run_repeats_whatever_order_results_arrive_in():
    def run(slow):
        objective = SyntheticObjective(6, 2, optimum_seed=2, noise=0.01)
        opt = RBBO(RBBOConfig(6, 2, n_init=3, seed=4, max_evaluations=10, n_confirm=0, **FAST))
        with _ScrambledExecutor(objective, slow, last=9) as executor:
            opt.run(executor=executor, deterministic=True)
        return opt.history, executor.finished

    first, finished_first = run(slow=set(range(0, 10, 2)))
    second, finished_second = run(slow=set(range(1, 10, 2)))
    # the workers finished in two different orders, neither of them the proposals' ...
    assert finished_first == [1, 0, 3, 2, 5, 4, 7, 6, 9, 8]
    assert finished_second == [0, 2, 1, 4, 3, 6, 5, 8, 7, 9]
    # ... and both runs told every result in proposal order and made the same run, bitwise
    assert [e.index for e in first] == [e.index for e in second] == list(range(10))
    assert [e.R for e in first] == [e.R for e in second]
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a.basis, b.basis)


def test_a_deterministic_parallel_run_resumed_after_an_interrupt_is_the_same_run(tmp_path):
    # The proposals in flight when the run stopped are recorded (proposals.jsonl) and handed
    # out again first, so with the same workers the resumed proposals see what the
    # uninterrupted run's saw. Without the record they would see every told result and no
    # fantasies, and part ways (checked below by deleting it).
    config = RBBOConfig(6, 2, n_init=3, seed=4, seeds=1, max_evaluations=10, n_confirm=0,
                        **FAST)  # fmt: skip
    objective = SyntheticObjective(6, 2, optimum_seed=2, noise=0.01)

    def interrupted_at(index):
        # one call per evaluation (one seed), started in proposal order: proposal k + 1 is
        # asked only after k - 1 is told, when k has started
        def evaluate(basis, t, seed):
            if calls.append(seed) or len(calls) == index + 1:
                raise KeyboardInterrupt  # (a thread's result: raised where it is told)
            return objective(basis, t, seed)

        calls: list[int] = []
        return evaluate

    slow = set(range(0, 10, 2))
    whole = RBBO.create(tmp_path / "whole", config, objective_spec=objective.spec())
    with _ScrambledExecutor(objective, slow, last=9) as executor:
        whole.run(executor=executor, deterministic=True)
    for name in ("resumed", "unrecorded"):
        broken = RBBO.create(tmp_path / name, config, objective_spec=objective.spec())
        with _ScrambledExecutor(interrupted_at(6), set(), last=9) as executor:
            with pytest.raises(KeyboardInterrupt):
                broken.run(executor=executor, deterministic=True)
        broken.store.close()
        assert [e.index for e in broken.evaluations] == list(range(6))
        in_flight = [r["index"] for r in broken.store.proposals()][6:]
        assert in_flight == [6, 7]  # handed out, never told
        if name == "unrecorded":
            (tmp_path / name / "proposals.jsonl").unlink()
        resumed = RBBO.resume(tmp_path / name)
        with _ScrambledExecutor(objective, slow, last=9) as executor:
            resumed.run(executor=executor, deterministic=True)
        assert [e.index for e in resumed.evaluations] == list(range(10))
        same = [np.array_equal(a.basis, b.basis) and (a.T, a.R) == (b.T, b.R)
                for a, b in zip(whole.evaluations, resumed.evaluations, strict=True)]  # fmt: skip
        assert all(same[:6])
        assert all(same) == (name == "resumed"), same


def test_a_resumed_run_hands_out_the_proposals_it_never_saw_told_first(tmp_path):
    config = RBBOConfig(4, 2, n_init=3, **FAST)
    opt = RBBO.create(tmp_path / "run", config)
    asked = [opt.ask() for _ in range(3)]
    opt.tell(asked[1].index, 0.5)
    opt.store.close()
    resumed = RBBO.resume(tmp_path / "run")
    again = [resumed.ask(), resumed.ask()]
    assert [p.index for p in again] == [0, 2]  # oldest first, with their records' values
    for p, q in zip(again, (asked[0], asked[2]), strict=True):
        np.testing.assert_array_equal(p.basis, q.basis)
        assert (p.T, p.seeds, p.kind) == (q.T, q.seeds, q.kind)
    assert resumed.ask().index == 3  # then new ones, numbered after them
    # a handed-out proposal counts against a limit; one not handed out again does not
    resumed.store.close()
    lowered = RBBO.resume(tmp_path / "run")
    assert lowered.can_submit(2, None) and lowered.ask().index == 0
    assert not lowered.can_submit(2, None)
    lowered.store.close()
    with open(tmp_path / "run" / "proposals.jsonl", "a") as f:
        f.write(json.dumps({"index": 9, "basis": [[1.0]], "T": 4.0, "seeds": [0],
                            "kind": "acquisition"}) + "\n")  # fmt: skip
    with pytest.raises(RunDirectoryError, match=r"proposal 9 is unreadable: basis of shape"):
        RBBO.resume(tmp_path / "run")


def test_pending_points_get_fantasies_so_parallel_proposals_differ():
    objective = SyntheticObjective(6, 2, optimum_seed=1)
    opt = RBBO(RBBOConfig(6, 2, n_init=4, **FAST))
    for _ in range(5):
        p = opt.ask()
        opt.tell(p.index, objective(p.basis, p.T, 0))
    a, b, c = opt.ask(), opt.ask(), opt.ask()  # three workers asking before any answer
    assert {a.kind, b.kind, c.kind} == {"acquisition"}
    for p, q in ((a, b), (a, c), (b, c)):
        assert projection_distance(p.basis, q.basis) > 0.05
    for p in (a, b, c):
        validate_basis(p.basis, 6, 2)


def test_boca_looks_cheaply_early_and_at_full_length_for_the_final_candidates():
    m, c = 6, 2
    late_full, early_low = [], []
    for seed in range(3):
        objective = SyntheticObjective(m, c, optimum_seed=seed, noise=0.0, bias=0.3)
        config = RBBOConfig(m, c, fidelity="boca", t_min=4.0, t_max=10.0, n_init=4, seed=seed,
                            max_evaluations=30, n_confirm=0, boca_candidates=2, **FAST)  # fmt: skip
        opt = RBBO(config)
        opt.run(objective)
        chosen = [e.T for e in opt.evaluations if e.kind == "acquisition"]
        early_low.append(np.mean(np.array(chosen[:8]) == 4.0))
        late_full.append(np.mean(np.array(chosen[-5:]) == 10.0))
        assert objective.value(opt.recommend().basis) > 0.8
    assert np.mean(early_low) >= 0.5, early_low
    assert np.mean(late_full) >= 0.7, late_full


def test_run_directory_records_everything(tmp_path):
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=8, n_confirm=2, **FAST)
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    result = opt.run(objective)
    lines = (tmp_path / "run" / "history.jsonl").read_text().splitlines()
    assert len(lines) == 8 + 2  # evaluations and the two confirmations
    kinds = [json.loads(line)["kind"] for line in lines]
    assert kinds[-2:] == ["confirm-init", "confirm-best"] or kinds[-2:] == [
        "confirm-best", "confirm-init"
    ]  # fmt: skip
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["evaluations"] == 8 and summary["R_star"] == result.R_star
    assert len(summary["R_init_seeds"]) == 2
    np.testing.assert_array_equal(np.load(tmp_path / "run" / "best_basis.npy"), result.best_basis)
    config_json = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config_json["objective"]["kind"] == "synthetic"
    # each session names its code and machine (the numbers of a run depend on both)
    (session,) = opt.store.sessions()
    assert session["command"] == "search" and session["max_evaluations"] == 8
    assert session["source"].startswith("softrom ") and " CPUs, " in session["machine"]
    assert session["machine"].endswith(" kernels") and session["numpy"] == np.__version__


KILL_SCRIPT = textwrap.dedent(
    """
    import sys
    from rbbo import RBBO, RBBOConfig, SyntheticObjective
    objective = SyntheticObjective(6, 2, noise=0.01, delay=0.05)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=200, n_confirm=0,
                        acq_random=64, acq_starts=2, acq_max_iterations=30, gp_restarts=0)
    RBBO.create(sys.argv[1], config, objective_spec=objective.spec()).run(objective)
    """
)


def test_resume_after_sigkill_loses_no_recorded_evaluation(tmp_path):
    run = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", KILL_SCRIPT, str(run)])
    history = run / "history.jsonl"
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline:
            if history.exists() and history.read_text().count("\n") >= 6:
                break
            time.sleep(0.05)
        else:
            pytest.fail("the optimisation did not record 6 evaluations in 60 s")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    before = history.read_bytes()
    complete = before[: before.rfind(b"\n") + 1].decode().splitlines()

    if before.endswith(b"\n"):
        opt = RBBO.resume(run)
    else:  # killed mid-write: the partial line goes, with a warning
        with pytest.warns(UserWarning, match="truncated last line"):
            opt = RBBO.resume(run)
    recorded = [json.loads(line)["index"] for line in complete]
    assert [e.index for e in opt.history] == recorded
    opt.run(SyntheticObjective(6, 2, noise=0.01), max_evaluations=len(recorded) + 3)
    after = history.read_text().splitlines()
    assert after[: len(complete)] == complete  # nothing recorded was lost or rewritten
    assert len(after) == len(complete) + 3
    indices = [json.loads(line)["index"] for line in after]
    assert len(set(indices)) == len(indices)


def test_a_resume_inside_the_initial_design_evaluates_every_design_point(tmp_path):
    """Confirmations share the index sequence: a run stopped inside its initial design and
    confirmed must still evaluate each design point once when it resumes."""
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=5, max_evaluations=3, n_confirm=2, **FAST)
    RBBO.create(tmp_path / "run", config).run(objective)
    opt = RBBO.resume(tmp_path / "run")
    assert [e.kind for e in opt.history][-2:] == ["confirm-init", "confirm-best"]
    opt.run(objective, max_evaluations=8, confirm=False)
    initial = [e.basis for e in opt.history if e.kind == "initial"]
    design = [basis for basis, _, _ in opt._initial]
    assert len(initial) == len(design) == 6
    for basis in design:
        assert sum(np.array_equal(basis, b) for b in initial) == 1


def test_a_run_whose_evaluations_all_fail_stops_with_the_reason(tmp_path):
    from rbbo.optimizer import EvaluationsFailing

    def broken(basis, T, seed):
        raise OSError("simulator library missing")

    opt = RBBO.create(tmp_path / "run", RBBOConfig(6, 2, n_init=3, max_evaluations=50, **FAST))
    with pytest.raises(EvaluationsFailing, match="last 10 evaluations all failed, the last "
                       "with: OSError: simulator library missing"):  # fmt: skip
        opt.run(broken)
    assert len(opt.evaluations) == 10  # not 50: it stopped
    # and says so in its summary (what `rbbo report` reads), with no best basis to save
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["evaluations"] == 10 and summary["failed"] == 10
    assert not (tmp_path / "run" / "best_basis.npy").exists()
    # one failure among successes is recorded and the run goes on: the count of failures in
    # a row starts again at each success (12 failures in all pass the limit of 10 in a row)
    calls = []

    def flaky(basis, T, seed):
        calls.append(1)
        if len(calls) % 2 == 0:
            raise OSError("transient")
        return float(basis[0, 0])

    result = RBBO(RBBOConfig(6, 2, n_init=23, max_evaluations=24, n_confirm=0, **FAST)).run(flaky)
    assert result.evaluations == 24 and result.failed == 12


def _with_basis(line, basis):
    return json.dumps({**json.loads(line), "basis": np.asarray(basis).tolist()})


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda lines: [lines[0], lines[1], lines[1]],
         "line 3 is corrupted: evaluation 1 is recorded on line 2 already"),
        (lambda lines: [lines[0], _with_basis(lines[1], np.eye(2))],
         r"line 2 is corrupted: its basis has shape \(2, 2\), expected"),
        (lambda lines: [lines[0], _with_basis(lines[1], 2 * np.eye(6)[:, :2])],
         "line 2 is corrupted: its basis is not orthonormal"),
    ],
)  # fmt: skip
def test_resume_names_a_history_line_that_does_not_belong_to_the_run(tmp_path, edit, match):
    opt = RBBO.create(tmp_path / "run", RBBOConfig(6, 2, n_init=2, **FAST))
    for _ in range(2):
        opt.tell(opt.ask().index, 0.5)
    opt.store.close()
    history = tmp_path / "run" / "history.jsonl"
    history.write_text("\n".join(edit(history.read_text().splitlines())) + "\n")
    with pytest.raises(RunDirectoryError, match=match):
        RBBO.resume(tmp_path / "run", read_only=True)


def test_resume_rejects_bad_settings(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"rbbo": {"sim_dim": 4, "control_dim": 9}}))
    with pytest.raises(RunDirectoryError, match="invalid settings: control_dim = 9 exceeds"):
        RBBO.resume(tmp_path)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fidelity": "mf"}, r"unknown fidelity 'mf'; valid: \['bo', 'boca'\]"),
        ({"fidelity": "boca", "t_min": 12.0}, "need 0 < t_min < t_max for BOCA"),
        ({"seeds": 0}, "seeds must be an integer >= 1, got 0"),
        ({"budget_s": -1.0}, "budget_s must be > 0 seconds"),
        ({"optimizer": "adam"}, "unknown optimizer 'adam'"),
        ({"control_dim": 6}, r"control_dim = 6 must be below sim_dim = 6: Gr\(M, M\) is one"),
        ({"t_max": "10"}, "t_max must be a number, got '10'"),
        ({"budget_s": "10"}, "budget_s must be a number, got '10'"),
        ({"t_max": 0}, "t_max must be a positive number of seconds, got 0.0"),
        ({"t_max": float("nan")}, "t_max must be a positive number of seconds, got nan"),
        ({"t_max": float("inf")}, "t_max must be a positive number of seconds, got inf"),
        ({"fidelity": "boca", "t_min": 0.0}, "need 0 < t_min < t_max for BOCA, got 0.0, 10.0"),
        ({"max_evaluations": 0}, "max_evaluations must be an integer >= 1, got 0"),
        ({"budget_s": 0}, "budget_s must be > 0 seconds, got 0.0"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
        ({"boca_candidates": 1}, "boca_candidates must be an integer >= 2, got 1"),
        # config.json is strict JSON: these used to pass here and fail RBBO.create with
        # "config is not JSON-serialisable: Out of range float values"
        ({"budget_s": float("inf")}, r"budget_s must be a finite number of seconds \(None"),
        ({"t_min": float("nan")}, "t_min must be a finite number of seconds, got nan"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RBBOConfig(**{"sim_dim": 6, "control_dim": 2, **kwargs})


@pytest.mark.parametrize("cls", [RBBOConfig, RBBOResult])
def test_every_field_of_the_config_and_the_result_is_documented(cls):
    """RBBOResult's docstring described R_init, R_star and improvement_pct only: what
    evaluations, failed, wall_s, best_index and the per-seed lists hold was left to the
    source."""
    import dataclasses
    import re

    doc = cls.__doc__
    for f in dataclasses.fields(cls):
        assert re.search(rf"^    (\w+, )*{f.name}\b[^\n]*( :|$)", doc, flags=re.M), f.name


def test_every_parameter_of_rbbos_public_methods_is_documented():
    """tell's docstring named none of R, status, wall_s, worker, R_seeds and error (the ask/tell
    loop of the module's example uses it), create's neither objective_spec nor extra, and
    confirm_again's neither executor nor callback."""
    import inspect
    import re

    for name, member in vars(RBBO).items():
        function = getattr(member, "__func__", member)
        if name.startswith("_") or isinstance(member, property) or not callable(function):
            continue
        doc = function.__doc__ or ""
        for parameter in list(inspect.signature(function).parameters)[1:]:  # (self, cls)
            assert re.search(rf"\b{parameter}\b", doc), f"{name}: {parameter}"


def test_config_takes_numpy_numbers_and_stores_python_ones(tmp_path):
    config = RBBOConfig(np.int64(6), np.int32(2), max_evaluations=np.int64(5), t_max=np.float32(8))
    assert (type(config.sim_dim), type(config.max_evaluations), type(config.t_max)) == (
        int, int, float)  # fmt: skip
    RBBO.create(tmp_path / "run", config)  # config.json is JSON: no numpy scalars in it
    stored = json.loads((tmp_path / "run" / "config.json").read_text())["rbbo"]
    assert (stored["sim_dim"], stored["max_evaluations"], stored["t_max"]) == (6, 5, 8.0)


def test_run_validates_its_limits_and_objective():
    opt = RBBO(RBBOConfig(4, 2, **FAST))
    for limits, match in (({"max_evaluations": -5}, "max_evaluations must be an integer >= 1"),
                          ({"max_evaluations": 2.5}, "max_evaluations must be an integer >= 1"),
                          ({"budget_s": -1.0}, "budget_s must be > 0 seconds"),
                          ({"budget_s": 0}, "budget_s must be > 0 seconds, got 0")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            opt.run(SyntheticObjective(4, 2), **limits)
    with pytest.raises(TypeError, match="objective must be callable .* got int"):
        opt.run(5, max_evaluations=3)
    # the default executor's settings, named (workers=True ran as 1 worker, serially; a string
    # timeout failed on '>' between str and int)
    for options, match in (({"workers": True}, "workers must be an integer >= 1, got True"),
                           ({"workers": 2, "timeout_s": "5"}, "timeout_s must be a number"),
                           ({"timeout_s": 0}, "timeout_s must be > 0 seconds")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            opt.run(SyntheticObjective(4, 2), max_evaluations=3, **options)
    assert opt.history == []
    # numpy's integers are integers: np.int64(2) workers was refused by the process pool
    executor = ProcessExecutor(SyntheticObjective(4, 2), np.int64(2))
    try:
        assert executor.workers == 2 and type(executor.workers) is int
    finally:
        executor.shutdown()


def test_a_reader_cannot_write_into_a_run(tmp_path):
    # a run still going elsewhere holds the lock; a read-only view of it must not append
    # evaluations (their indices would collide with the writer's)
    writer = RBBO.create(tmp_path / "run", RBBOConfig(4, 2, **FAST))
    writer.tell(writer.ask().index, 0.5)
    reader = RBBO.resume(tmp_path / "run", read_only=True)
    proposal = reader.ask()
    with pytest.raises(RunDirectoryError, match="opened read-only; nothing can be recorded"):
        reader.tell(proposal.index, 0.9)
    assert proposal.index in reader.pending
    assert len((tmp_path / "run" / "history.jsonl").read_text().splitlines()) == 1


def test_run_needs_a_stopping_rule():
    with pytest.raises(ValueError, match="give max_evaluations or budget_s"):
        RBBO(RBBOConfig(4, 2)).run(SyntheticObjective(4, 2))
    # (math.inf is "no limit of this kind": both of them is no stopping rule either)
    with pytest.raises(ValueError, match="both unlimited"):
        RBBO(RBBOConfig(4, 2)).run(SyntheticObjective(4, 2), max_evaluations=math.inf,
                                   budget_s=math.inf)  # fmt: skip


def test_cma_es_baseline_updates_within_a_small_budget():
    # With the population sized to the budget, CMA-ES runs several generations: it evaluates
    # exactly the budget, every point is orthonormal, and it improves on its first generation.
    from rbbo.baselines import cma_es

    objective = SyntheticObjective(10, 2, optimum_seed=3)
    out = cma_es(objective, 10, 2, 24, T=10.0, seed=0)
    assert len(out) == 24
    for basis, _, _ in out:
        np.testing.assert_allclose(basis.T @ basis, np.eye(2), atol=1e-10)
    first = max(r for _, r, _ in out[:6])  # popsize max(4, min(13, 24 // 4)) = 6
    assert max(r for _, r, _ in out[6:]) > first
    with pytest.raises(ValueError, match="popsize"):
        cma_es(objective, 10, 2, 8, T=10.0, popsize=1)


def test_a_finished_run_keeps_its_confirmed_answer_when_reloaded(tmp_path, monkeypatch):
    # Reloading refits the GP, which may rank near-equal candidates otherwise; the basis that
    # was confirmed when the search ended stays the run's R*, and a rerun measures nothing new.
    objective = SyntheticObjective(6, 2, optimum_seed=1, noise=0.01)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=8, n_confirm=2, seed=0)
    done = RBBO.create(tmp_path / "run", config).run(objective)
    assert done.R_star is not None

    opt = RBBO.resume(tmp_path / "run")
    others = [e for e in opt.evaluations if not np.array_equal(e.basis, done.best_basis)]
    monkeypatch.setattr(RBBO, "recommend", lambda self: others[0])
    again = opt.result()
    assert again.R_star == done.R_star and again.best_index == done.best_index
    np.testing.assert_array_equal(again.best_basis, done.best_basis)
    lines = (tmp_path / "run" / "history.jsonl").read_text().count("\n")
    opt.run(objective)
    assert (tmp_path / "run" / "history.jsonl").read_text().count("\n") == lines


def test_ctrl_c_as_a_proposal_or_an_outcome_is_recorded_leaves_the_run_and_its_files_agreeing(
    tmp_path, monkeypatch
):
    """A Ctrl-C right after ask's or tell's line was written raised before the optimiser's
    bookkeeping: told, the proposal stayed pending though its outcome was in the history, and
    a run going on in this process evaluated and recorded it twice. It is raised once both
    agree."""
    from rbbo.store import RunStore

    config = RBBOConfig(6, 2, n_init=3, max_evaluations=10, **FAST)
    opt = RBBO.create(tmp_path / "run", config)

    def then_ctrl_c(method):
        def written(self, record):
            method(self, record)
            os.kill(os.getpid(), signal.SIGINT)

        return written

    monkeypatch.setattr(RunStore, "append_proposal", then_ctrl_c(RunStore.append_proposal))
    with pytest.raises(KeyboardInterrupt):
        opt.ask()
    assert list(opt.pending) == [0]
    monkeypatch.undo()
    monkeypatch.setattr(RunStore, "append", then_ctrl_c(RunStore.append))
    with pytest.raises(KeyboardInterrupt):
        opt.tell(0, 0.5)
    monkeypatch.undo()
    assert not opt.pending and [e.index for e in opt.history] == [0]
    assert opt.ask().index == 1  # (not 0 again)
    opt.close()
    again = RBBO.resume(tmp_path / "run")
    assert [e.index for e in again.history] == [0] and again.ask().index == 1  # (recorded)


def test_best_basis_file_holds_the_recommendation_written_when_the_run_stops(tmp_path, monkeypatch):
    # best_basis.npy is never the highest single R; it appears when the run ends, holding
    # R*'s basis. (The GP's recommendation under heavy noise was the best sample here after a
    # numpy/scipy update, which the test then could not tell apart: the recommendation is now
    # the lowest R at T_max, by construction never the best sample.)
    def lowest(self):
        return min((e for e in self._observations() if e.T == self.config.t_max),
                   key=lambda e: e.R)  # fmt: skip

    monkeypatch.setattr(RBBO, "recommend", lowest)
    objective = SyntheticObjective(6, 2, noise=0.5)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=10, n_confirm=2, **FAST)
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())

    def stop_after_six(evaluation):
        if len(opt.evaluations) == 6:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        opt.run(objective, callback=stop_after_six)
    assert not (tmp_path / "run" / "best_basis.npy").exists()
    opt.store.close()
    again = RBBO.resume(tmp_path / "run")
    assert not again.finished and again.result().best_basis is not None  # mid-run: current
    result = again.run(objective)
    assert again.finished
    np.testing.assert_array_equal(np.load(tmp_path / "run" / "best_basis.npy"), result.best_basis)
    best_sample = max(
        (e for e in again.evaluations if e.T == config.t_max), key=lambda e: e.R
    )  # fmt: skip
    recommended = again.recommend()
    assert recommended is not None and result.best_index == recommended.index
    assert best_sample.index != recommended.index  # the case the file must not follow


def test_boca_recommends_from_every_fidelity_and_the_report_names_a_design_pick():
    # Seen only at T_min, the neighbourhood of the optimum still has the highest posterior
    # mean at T_max: it is recommended (and confirmed at T_max), not the best of the
    # low-reward bases that happen to have run at T_max.
    from rbbo.acquisition import perturb
    from rbbo.report import format_table
    from rbbo.store import Evaluation

    m, c = 6, 2
    objective = SyntheticObjective(m, c, bias=0.3)
    config = RBBOConfig(m, c, fidelity="boca", t_min=4.0, t_max=10.0, n_init=2,
                        max_evaluations=20, n_confirm=0, **FAST)  # fmt: skip
    opt = RBBO(config)
    rng = np.random.default_rng(12345)  # not the objective's own seed: its optimum
    best = objective.optimum
    points = [(identity_basis(m, c), 10.0, "initial")]
    points += [(b, 10.0, "initial") for b in random_points(m, c, 3, rng)]
    points += [(perturb(best, s, rng), 4.0, "acquisition") for s in (0.0, 0.1, 0.2, 0.3)]
    points += [(b, 4.0, "acquisition") for b in random_points(m, c, 4, rng)]
    for i, (basis, t, kind) in enumerate(points):
        opt._record(Evaluation(index=i, basis=basis, T=t, R=objective.value(basis, t),
                               status="ok", seeds=[0], kind=kind), persist=False)  # fmt: skip
    chosen = opt.recommend()
    assert chosen.T == 4.0 and objective.value(chosen.basis) > 0.9
    at_t_max = max(objective.value(b) for b, t, _ in points if t == 10.0)
    assert at_t_max < 0.9  # the old rule's pool had nothing as good
    row = {"problem": "p", "run": "", "N": None, "M": m, "C": c, "R_init": 0.1,
           "R_star": 0.2, "improvement_pct": 100.0, "evaluations": 12, "failed": 0,
           "wall_s": 1.0, "best_index": 2, "best_kind": "initial"}  # fmt: skip
    assert "(R* of p: evaluation 2, a point of the initial design, not one the GP" in (
        format_table([row])
    )
    # a run not confirmed yet shows R* as "-": no note about what it is not
    assert "(R* of" not in format_table([{**row, "R_star": None, "improvement_pct": None}])


@pytest.mark.parametrize("fidelity", ["bo", "boca"])
def test_a_resumed_serial_run_proposes_what_the_uninterrupted_one_did(tmp_path, fidelity):
    # Each proposal records the GP hyperparameters its fit found; a resumed run's next fit
    # starts from them (not from the defaults), so with one worker the run is the same run,
    # an evaluation lost in flight included. Without the record the two part ways (checked:
    # the resumed fit from the defaults lands 1e-7 away and the acquisition amplifies it).
    objective = SyntheticObjective(8, 2, noise=0.05)
    config = RBBOConfig(8, 2, n_init=3, max_evaluations=14, n_confirm=0, fidelity=fidelity,
                        t_min=4.0, **{**FAST, "gp_restarts": 1})  # fmt: skip
    whole = RBBO.create(tmp_path / "whole", config, objective_spec=objective.spec())
    whole.run(objective)
    calls = []

    def interrupted(basis, t, seed):
        calls.append(t)
        if len(calls) == 9:  # the ninth evaluation never returns: lost in flight
            raise KeyboardInterrupt
        return objective(basis, t, seed)

    broken = RBBO.create(tmp_path / "broken", config, objective_spec=objective.spec())
    with pytest.raises(KeyboardInterrupt):
        broken.run(interrupted)
    broken.store.close()
    assert len(broken.evaluations) == 8
    resumed = RBBO.resume(tmp_path / "broken")
    resumed.run(objective)
    assert [e.index for e in resumed.evaluations] == [e.index for e in whole.evaluations]
    for a, b in zip(whole.evaluations, resumed.evaluations, strict=True):
        np.testing.assert_array_equal(a.basis, b.basis)
        assert (a.T, a.R) == (b.T, b.R)
    assert resumed.evaluations[-1].gp is not None and resumed.evaluations[0].gp is None


def test_sessions_are_recorded_when_they_evaluate_and_survive_a_torn_line(tmp_path):
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=5, n_confirm=2, **FAST)
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    opt.run(objective)
    opt.run(objective)  # finished and confirmed: evaluates nothing, records nothing
    assert [s["command"] for s in opt.store.sessions()] == ["search"]
    with open(tmp_path / "run" / "sessions.jsonl", "a") as f:
        f.write('{"command": "sea')  # a kill while a record was being written
    opt.run(objective, max_evaluations=6)
    sessions = opt.store.sessions()
    assert [s["command"] for s in sessions] == ["search", "search"]
    assert sessions[1]["max_evaluations"] == 6


def test_each_session_records_when_and_how_it_ended(tmp_path):
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=4, n_confirm=2, **FAST)
    path = tmp_path / "run"
    opt = RBBO.create(path, config, objective_spec=objective.spec())
    # a file from before the end records: its session reads as it did, with no end
    old = {"command": "search", "started": "2026-01-01T00:00:00+00:00", "max_evaluations": 2}
    (path / "sessions.jsonl").write_text(json.dumps(old) + "\n")

    def stopped_by(error):
        def callback(evaluation):
            raise error

        return callback

    with pytest.raises(KeyboardInterrupt):  # Ctrl-C (or SIGTERM, as rbbo raises it)
        opt.run(objective, callback=stopped_by(KeyboardInterrupt()))
    with pytest.raises(RuntimeError):
        opt.run(objective, callback=stopped_by(RuntimeError("disk on fire")))
    opt.run(objective)
    sessions = opt.store.sessions()
    assert [s.get("status") for s in sessions] == [None, "interrupted", "error", "finished"]
    assert sessions[0] == old and sessions[2]["error"] == "RuntimeError: disk on fire"
    assert all(s["command"] == "search" and s["ended"] >= s["started"] for s in sessions[1:])
    # appended after the lines before them, never rewriting one
    lines = [json.loads(x) for x in (path / "sessions.jsonl").read_text().splitlines()]
    assert lines[0] == old and [x.get("event") for x in lines[1:]] == [None, "end"] * 3


def test_rbbo_warnings_name_the_callers_line(tmp_path, monkeypatch):
    # Counted stacklevels named a line inside rbbo once the optimizer was split into modules
    # (rbbo/restore.py for a torn history); both warnings must name this file.
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=3, n_confirm=0, **FAST)
    RBBO.create(tmp_path / "run", config, objective_spec=objective.spec()).run(objective)
    with open(tmp_path / "run" / "history.jsonl", "a") as f:
        f.write('{"index": 3, "R"')  # torn by a kill
    with pytest.warns(UserWarning, match="truncated last line") as caught:
        opt = RBBO.resume(tmp_path / "run")
    assert [w.filename for w in caught] == [__file__]

    def full_disk(record):
        if record.get("event") == "end":
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(opt.store, "append_session", full_disk)
    with pytest.warns(RuntimeWarning, match="end of this session was not recorded") as caught:
        opt.run(objective, max_evaluations=4)
    assert [w.filename for w in caught] == [__file__]


def test_a_reloaded_run_keeps_the_recommendation_its_session_ended_with(tmp_path, monkeypatch):
    # without confirmation seeds there is no confirmed answer: the summary's is kept (a GP
    # refitted in another process may rank near-equal bases otherwise)
    for seed in range(3):
        objective = SyntheticObjective(6, 2, noise=0.3)
        config = RBBOConfig(6, 2, n_init=3, max_evaluations=10, n_confirm=0, seed=seed, **FAST)
        path = tmp_path / f"run{seed}"
        result = RBBO.create(path, config, objective_spec=objective.spec()).run(objective)
        again = RBBO.resume(path, read_only=True)
        assert again.finished
        assert again.result().best_index == result.best_index
        np.testing.assert_array_equal(again.result().best_basis, np.load(path / "best_basis.npy"))
        # a refit that ranks another basis first (as one in another process may) changes
        # nothing: the answer is the one the session ended with
        other = next(e for e in again.evaluations if e.index != result.best_index)
        with monkeypatch.context() as patch:
            patch.setattr(RBBO, "recommend", lambda self, other=other: other)
            reloaded = RBBO.resume(path, read_only=True)
            assert reloaded.result().best_index == result.best_index


class _FarWorse:
    """An objective on which every new basis scores far below the recorded ones."""

    def __call__(self, basis, T, seed):
        return -100.0


def _confirmed_then_resumed_to_eight(path):
    """A 6-evaluation run, confirmed, then resumed with its limit raised to 8."""
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=3, max_evaluations=6, n_confirm=2, **FAST)
    first = RBBO.create(path, config, objective_spec=objective.spec()).run(objective)
    opt = RBBO.resume(path)
    opt.set_limits(8, None)
    return objective, first, opt


def test_a_run_in_memory_without_confirmation_seeds_is_finished_when_its_session_ends():
    """As a run directory's is (its summary.json): an in-memory run with n_confirm = 0 read
    finished = False after run() had ended, though it has no confirmation to wait for."""
    objective = SyntheticObjective(6, 2)
    opt = RBBO(RBBOConfig(6, 2, n_init=2, max_evaluations=4, n_confirm=0, **FAST))
    assert not opt.finished
    result = opt.run(objective)
    assert opt.finished and opt.result().best_index == result.best_index
    proposal = opt.ask()  # searched on since: not finished until a session ends again
    opt.tell(proposal.index, objective(proposal.basis, proposal.T, proposal.seeds[0]))
    assert not opt.finished
    # with confirmation seeds, a session that skipped the confirmation has not finished
    opt = RBBO(RBBOConfig(6, 2, n_init=2, max_evaluations=4, n_confirm=1, **FAST))
    opt.run(objective, confirm=False)
    assert not opt.finished


def test_the_convergence_plot_calls_only_an_env_runs_r_a_rate(tmp_path, monkeypatch):
    """The synthetic objective's R is no rate (rbbo rollout says so too); its plot's axis
    read "reward R per second" as an env run's does."""
    import rbbo.report

    labels = []

    def savefig(fig, path, **kwargs):
        labels.append(fig.axes[0].get_ylabel())
        return path

    monkeypatch.setattr(rbbo.report, "_atomic_savefig", savefig)
    objective = SyntheticObjective(6, 2)
    for spec in (objective.spec(), {"kind": "env", "env_id": "softrom_gym/CrossSwim-v0"}):
        opt = RBBO(RBBOConfig(6, 2, n_init=1, max_evaluations=2, n_confirm=0, **FAST),
                   objective_spec=spec)  # fmt: skip
        # (a function stands in for the env's objective: one without a spec() is not compared)
        opt.run(lambda basis, T, seed: objective(basis, T, seed))
        rbbo.report.plot_convergence(opt, tmp_path / "convergence.png")
    assert labels == ["R (synthetic objective)", "reward R per second"]


def test_a_resumed_run_whose_recommendation_stands_is_finished(tmp_path):
    # searched on, kept its confirmed recommendation (nothing new to confirm): finished, and
    # best_basis.npy is still that recommendation
    path = tmp_path / "run"
    _, first, opt = _confirmed_then_resumed_to_eight(path)
    again = opt.run(_FarWorse())
    assert len(opt.evaluations) == 8 and again.best_index == first.best_index
    assert again.R_star == first.R_star
    reloaded = RBBO.resume(path, read_only=True)
    assert reloaded.finished and reloaded.result().best_index == first.best_index
    np.testing.assert_array_equal(np.load(path / "best_basis.npy"), first.best_basis)


def test_a_confirmed_recommendation_evaluated_below_t_max_is_found_on_reload():
    from rbbo.store import Evaluation

    config = RBBOConfig(6, 2, fidelity="boca", t_min=4.0, t_max=10.0, n_init=2,
                        max_evaluations=5, n_confirm=2, **FAST)  # fmt: skip
    opt = RBBO(config)
    rng = np.random.default_rng(5)
    bases = random_points(6, 2, 4, rng)
    for i, (basis, t) in enumerate(zip(bases, (10.0, 4.0, 10.0, 4.0), strict=True)):
        kind = "initial" if i < 3 else "acquisition"
        opt._record(Evaluation(index=i, basis=basis, T=t, R=0.1 * i, seeds=[0], kind=kind),
                    persist=False)  # fmt: skip
    opt._record(Evaluation(index=4, basis=bases[3], T=10.0, R=0.5, seeds=[7, 8],
                           kind="confirm-best"), persist=False)  # fmt: skip
    assert opt.finished and opt.result().best_index == 3  # the T_min evaluation it confirmed


def test_a_proposal_on_an_evaluated_basis_gives_way_to_the_next_optimum_then_a_random_one(
    monkeypatch,
):
    # Under common random numbers a repeat returns the same R: it must not be proposed.
    import rbbo.proposing as proposing_module
    from rbbo.acquisition import AcquisitionResult

    m, c = 6, 2
    objective = SyntheticObjective(m, c, optimum_seed=3)
    opt = RBBO(RBBOConfig(m, c, n_init=3, seed=1, n_confirm=0, **FAST))
    for _ in range(4):  # the identity and three random points
        p = opt.ask()
        opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
    seen = opt.evaluations[1].basis
    # the same subspace, another basis of it (a rotation within the plane, a sign)
    repeat = seen @ np.array([[0.0, -1.0], [1.0, 0.0]])
    fresh = random_points(m, c, rng=77)
    optima = [
        type("Result", (), {"point": repeat, "cost": -2.0}),
        type("Result", (), {"point": fresh, "cost": -1.0}),
    ]

    def lands_on_a_repeat(*args, **kwargs):
        return AcquisitionResult(repeat, 2.0, "lrbfgs", results=list(optima))

    monkeypatch.setattr(proposing_module, "maximize_on_grassmann", lands_on_a_repeat)
    p = opt.ask()
    assert p.kind == "acquisition" and p.info["duplicates_skipped"] == 1
    assert p.info["acq_value"] == 1.0  # the next-best optimum's
    assert projection_distance(p.basis, fresh) < 1e-12
    # with that one in flight, both optima are taken: a random point, said so
    q = opt.ask()
    assert q.kind == "random" and q.info["duplicates_skipped"] == 2
    assert q.info["acq_value"] is None
    for taken in (*[e.basis for e in opt.evaluations], p.basis):
        assert projection_distance(q.basis, taken) > 1e-3
    # the history keeps it (and an ordinary proposal records nothing of the kind)
    told = [opt.tell(p.index, 0.0), opt.tell(q.index, 0.0)]
    assert [e.duplicates_skipped for e in told] == [1, 2]
    assert json.loads(told[0].to_json())["duplicates_skipped"] == 1
    monkeypatch.undo()
    ordinary = opt.ask()
    assert "duplicates_skipped" not in ordinary.info
    assert "duplicates_skipped" not in json.loads(opt.tell(ordinary.index, 0.0).to_json())


def test_a_resumed_run_goes_on_from_the_time_it_had_spent(tmp_path):
    # elapsed_s is the run's time over all its sessions: a resumed run must not restart its
    # clock, or --budget would be granted afresh by every resume and the history's elapsed_s
    # would run backwards. (The first session's clock is set forward, not waited for.)
    config = RBBOConfig(4, 2, n_init=3, **FAST)
    opt = RBBO.create(tmp_path / "run", config)
    opt._elapsed_offset = 1000.0
    p = opt.ask()
    assert opt.tell(p.index, 0.5).elapsed_s >= 1000.0
    opt.store.close()
    resumed = RBBO.resume(tmp_path / "run")
    assert resumed.elapsed_s >= 1000.0
    assert not resumed.can_submit(None, 500.0)  # its budget was spent in the first session
    assert resumed.result().wall_s >= 1000.0  # (the report's wall time: the run's, not a sum)
    q = resumed.ask()
    assert resumed.tell(q.index, 0.4).elapsed_s >= 1000.0


def test_a_corrupted_summary_does_not_keep_a_run_from_being_read_or_finished(tmp_path):
    """summary.json is what marks an unconfirmed run (n_confirm = 0) finished: a torn one is
    passed over (the GP's recommendation, the run unfinished), and a resume that has nothing
    left to search writes it anew."""
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=5, n_confirm=0, seed=0, **FAST)
    done = RBBO.create(tmp_path / "run", config).run(objective)
    (tmp_path / "run" / "summary.json").write_text('{"evaluations": 5, "best_')
    reader = RBBO.resume(tmp_path / "run", read_only=True)
    assert not reader.finished
    assert reader.result().best_index == done.best_index
    again = RBBO.resume(tmp_path / "run")
    assert again.run(objective).best_index == done.best_index
    assert again.finished and len(again.evaluations) == 5
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["best_index"] == done.best_index


def test_calls_that_have_nothing_to_work_on_are_named(tmp_path):
    from rbbo.executors import SerialExecutor

    opt = RBBO(RBBOConfig(4, 2, n_init=2, max_evaluations=3, **FAST))
    with pytest.raises(ValueError, match="give an objective or an executor"):
        opt.run()
    with pytest.raises(ValueError, match="the run has no evaluation to confirm yet"):
        opt.confirm_again(SerialExecutor(SyntheticObjective(4, 2)))
    with pytest.raises(ValueError, match="give max_evaluations or budget_s"):
        opt.set_limits(None, None)
    unconfirmed = RBBO(RBBOConfig(4, 2, n_init=2, max_evaluations=3, n_confirm=0, **FAST))
    unconfirmed.run(SyntheticObjective(4, 2))
    with pytest.raises(ValueError, match=r"made with no confirmation seeds \(n_confirm = 0\)"):
        unconfirmed.confirm_again(SerialExecutor(SyntheticObjective(4, 2)))
    (tmp_path / "config.json").write_text(json.dumps({"objective": {"kind": "synthetic"}}))
    with pytest.raises(RunDirectoryError, match="config.json has no 'rbbo' settings"):
        RBBO.resume(tmp_path)


def test_a_duplicate_is_the_same_subspace_at_the_same_t():
    """Within DUPLICATE_DISTANCE (a projection distance, compared as its square) at the same
    T; the same basis at another T is another fidelity's evaluation, not a repeat."""
    from rbbo.acquisition import perturb
    from rbbo.proposing import DUPLICATE_DISTANCE, _is_duplicate

    rng = np.random.default_rng(0)
    b = random_points(6, 2, rng=rng)
    near, far = (perturb(b, f * DUPLICATE_DISTANCE / np.sqrt(2.0), rng) for f in (0.5, 2.0))
    assert projection_distance(b, near) < DUPLICATE_DISTANCE < projection_distance(b, far)
    taken = [(random_points(6, 2, rng=rng), 10.0), (b, 10.0)]
    assert _is_duplicate(near, 10.0, taken) and _is_duplicate(b @ [[0, 1], [1, 0]], 10.0, taken)
    assert not _is_duplicate(far, 10.0, taken)
    assert not _is_duplicate(b, 4.0, taken)
    assert not _is_duplicate(b, 10.0, [])


def test_fantasies_under_boca_are_the_posterior_mean_at_their_own_fidelity():
    """The kriging believer observes a proposal in flight at (B, z(T)) at the posterior mean
    there, so the mean at that point stays and its sd shrinks; a confirmation in flight is no
    fantasy."""
    from rbbo.boca import BOCAFidelity
    from rbbo.gp import GrassmannGP
    from rbbo.proposing import _with_fantasies

    rng = np.random.default_rng(4)
    bases = random_points(6, 2, 8, rng)
    z = np.tile([0.0, 1.0], 4)
    y = np.sum(bases[:, :2, :] ** 2, axis=(1, 2)) - 0.5 * (1.0 - z)
    gp = GrassmannGP(6, 2, fidelity=True, random_state=0).fit(bases, y, z)
    b = random_points(6, 2, rng=rng)
    pending = {
        8: types.SimpleNamespace(kind="acquisition", basis=b, T=4.0),
        9: types.SimpleNamespace(kind="confirm-best", basis=bases[0], T=10.0),
    }
    opt = types.SimpleNamespace(pending=pending, _z=BOCAFidelity(4.0, 10.0).z)  # (what it reads)
    believer = _with_fantasies(opt, gp)
    assert believer.n_observations == 9
    (mu0, sd0), (mu1, sd1) = gp.predict(b, 0.0), believer.predict(b, 0.0)
    assert abs(mu0[0] - gp.predict(b, 1.0)[0][0]) > 1e-3  # (z matters here)
    np.testing.assert_allclose(mu1, mu0, atol=1e-8)
    assert sd1[0] < sd0[0]


def test_a_proposal_takes_the_best_other_optimum_orthonormalised_and_the_scheduled_beta(
    monkeypatch,
):
    """A maximiser's point that repeats an evaluation gives way to the best remaining local
    optimum (not merely another), re-orthonormalised; the acquisition maximised is GP-UCB at
    z = 1 with beta_t of the number of observations."""
    import rbbo.proposing as proposing_module
    from rbbo.acquisition import AcquisitionResult, ucb_beta
    from rbbo.grassmann import dimension

    m, c = 6, 2
    objective = SyntheticObjective(m, c, optimum_seed=3)
    opt = RBBO(RBBOConfig(m, c, n_init=3, seed=1, n_confirm=0, **FAST))
    for _ in range(4):
        p = opt.ask()
        opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
    seen = opt.evaluations[1].basis
    worse, better = random_points(m, c, 2, rng=5)
    optima = ((seen, -3.0), (worse, -1.0), (better * (1 + 1e-10), -1.5))  # (point, cost)
    results = [types.SimpleNamespace(point=point, cost=cost) for point, cost in optima]
    calls = []

    def lands_on_a_repeat(acquisition, *args, **kwargs):
        calls.append(acquisition)
        return AcquisitionResult(seen, 3.0, "lrbfgs", results=results)

    monkeypatch.setattr(proposing_module, "maximize_on_grassmann", lands_on_a_repeat)
    p = opt.ask()
    assert p.info["duplicates_skipped"] == 1 and p.info["acq_value"] == 1.5
    assert projection_distance(p.basis, better) < 1e-12
    assert np.abs(p.basis.T @ p.basis - np.eye(c)).max() < 1e-14  # (the optimum: 2e-10)
    (acquisition,) = calls
    assert acquisition.beta == ucb_beta(4, dimension(m, c)) and acquisition.z == 1.0


class _ManyWorkers(SerialExecutor):
    """Evaluates each task as it is submitted, in this thread, but has ``workers`` workers:
    the run keeps that many proposals in flight, all told together."""

    def __init__(self, objective, workers):
        super().__init__(objective)
        self.workers = workers


def test_a_blip_that_fails_every_evaluation_in_flight_on_many_workers_does_not_stop_the_run():
    # A passing outage (a lost node, a full scratch disk) fails every evaluation in flight
    # at once: with 12 workers that is 12 failures in a row, which must not stop the run. It
    # stops after twice its workers (and at least MAX_CONSECUTIVE_FAILURES) in a row.
    from rbbo.optimizer import EvaluationsFailing

    calls = []

    def blip(basis, T, seed):
        calls.append(seed)
        if len(calls) <= 12:
            raise OSError("node lost")
        return float(basis[0, 0])

    config = RBBOConfig(6, 2, n_init=11, max_evaluations=14, n_confirm=0, **FAST)
    result = RBBO(config).run(executor=_ManyWorkers(blip, 12))
    assert result.evaluations == 14 and result.failed == 12

    def broken(basis, T, seed):
        raise OSError("node lost")

    config = RBBOConfig(6, 2, n_init=30, max_evaluations=40, n_confirm=0, **FAST)
    opt = RBBO(config)
    with pytest.raises(EvaluationsFailing, match="the last 24 evaluations all failed, the last "
                       "with: OSError: node lost"):  # fmt: skip
        opt.run(executor=_ManyWorkers(broken, 12))
    assert len(opt.evaluations) == 24


def test_r_init_and_r_star_are_measured_at_t_max_on_fresh_seeds(tmp_path):
    # (the synthetic objective's R depends on T: its low-fidelity bias)
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, t_min=4.0, t_max=10.0, n_init=3, max_evaluations=6, n_confirm=3,
                        **FAST)  # fmt: skip
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    result = opt.run(objective)
    assert not np.array_equal(result.best_basis, identity_basis(6, 2))  # (two bases measured)
    measured = {e.kind: e for e in opt.history if e.kind.startswith("confirm")}
    bases = {"confirm-init": identity_basis(6, 2), "confirm-best": result.best_basis}
    for kind, basis in bases.items():
        e = measured[kind]
        np.testing.assert_array_equal(e.basis, basis)
        assert e.T == 10.0 and len(e.seeds) == 3
        assert set(e.seeds).isdisjoint(config.crn_seeds)  # none the search's own seeds
        assert e.R_seeds == [objective(basis, 10.0, s) for s in e.seeds]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["R_init_seeds"] == measured["confirm-init"].R_seeds
    assert summary["R_star_seeds"] == measured["confirm-best"].R_seeds
    assert (summary["R_init"], summary["R_star"]) == (result.R_init, result.R_star)
    assert result.R_init > 0
    assert summary["improvement_pct"] == pytest.approx(100 * (result.R_star / result.R_init - 1))


def test_the_improvement_is_given_over_a_positive_r_init_only():
    from rbbo.store import Evaluation

    config = RBBOConfig(6, 2, n_init=0, max_evaluations=1, n_confirm=2, **FAST)
    best = random_points(6, 2, rng=3)
    for r_init, improvement in ((0.4, 50.0), (-0.4, None), (0.0, None)):
        opt = RBBO(config)
        for evaluation in (
            Evaluation(0, best, 10.0, 0.5, seeds=[0], kind="acquisition"),
            Evaluation(1, identity_basis(6, 2), 10.0, r_init, seeds=[10**6, 10**6 + 1],
                       R_seeds=[r_init - 0.1, r_init + 0.1], kind="confirm-init"),
            Evaluation(2, best, 10.0, 0.6, seeds=[10**6, 10**6 + 1], R_seeds=[0.5, 0.7],
                       kind="confirm-best"),
        ):  # fmt: skip
            opt._record(evaluation, persist=False)
        result = opt.result()
        assert (result.R_init, result.R_star) == (r_init, 0.6)
        assert result.R_star_seeds == [0.5, 0.7]
        if improvement is None:  # (R* / R_init - 1 means nothing for R_init <= 0)
            assert result.improvement_pct is None
        else:
            assert result.improvement_pct == pytest.approx(improvement)


def test_the_report_shows_the_failures_the_spread_over_seeds_and_the_run_time():
    from rbbo.report import format_table, report_row
    from rbbo.store import Evaluation

    opt = RBBO(RBBOConfig(6, 2, n_init=0, max_evaluations=2, n_confirm=2, **FAST))
    best, fresh = random_points(6, 2, rng=3), [10**6, 10**6 + 1]
    for evaluation in (
        Evaluation(0, best, 10.0, 0.5, seeds=[0], kind="acquisition", elapsed_s=10.0),
        Evaluation(1, random_points(6, 2, rng=4), 10.0, None, status="failed", seeds=[0],
                   kind="acquisition", elapsed_s=20.0),
        Evaluation(2, identity_basis(6, 2), 10.0, 0.4, seeds=fresh, R_seeds=[0.3, 0.5],
                   kind="confirm-init", elapsed_s=5000.0),
        Evaluation(3, best, 10.0, 0.6, seeds=fresh, R_seeds=[0.5, 0.8], kind="confirm-best",
                   elapsed_s=5400.0),
    ):  # fmt: skip
        opt._record(evaluation, persist=False)
    row = report_row(opt)
    assert (row["evaluations"], row["failed"], row["wall_s"]) == (2, 1, 5400.0)
    # the sample standard deviation over the confirmation seeds
    assert row["R_init_sd"] == pytest.approx(np.sqrt(0.02))
    assert row["R_star_sd"] == pytest.approx(np.sqrt(0.045))
    lines = format_table([row]).splitlines()
    assert lines[2].split() == ["-", "-", "6", "2", "0.4±0.14", "0.6±0.21", "50.0", "%", "2",
                                "(1", "failed)", "1h30m00s"]  # fmt: skip
    assert format_table([{**row, "wall_s": 75.0}]).splitlines()[2].endswith(" 1m15s")


def test_an_invalid_limit_changes_nothing_in_the_run(tmp_path):
    # set_limits refuses before it writes: a limit written first would leave config.json with
    # settings that no later resume could read
    opt = RBBO.create(tmp_path / "run", RBBOConfig(4, 2, max_evaluations=5, **FAST))
    before = (tmp_path / "run" / "config.json").read_bytes()
    for limits, match in (((0, None), "max_evaluations must be an integer >= 1, got 0"),
                          ((None, -1.0), "budget_s must be > 0 seconds, got -1.0"),
                          ((None, float("inf")), "budget_s must be a finite number")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            opt.set_limits(*limits)
    assert (tmp_path / "run" / "config.json").read_bytes() == before
    assert (opt.config.max_evaluations, opt.config.budget_s) == (5, None)
    opt.store.close()
    assert RBBO.resume(tmp_path / "run").config.max_evaluations == 5


def test_a_run_that_searched_on_after_its_confirmation_is_not_finished(tmp_path, monkeypatch):
    # Confirmed, resumed with a larger limit and stopped after one more search evaluation:
    # not finished (rollout says so, confirm refuses), its answer the current recommendation,
    # with no R* until one is measured for it; the identity's R_init stands.
    path = tmp_path / "run"
    objective, first, opt = _confirmed_then_resumed_to_eight(path)

    def ctrl_c(evaluation):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        opt.run(objective, callback=ctrl_c)
    opt.store.close()
    reader = RBBO.resume(path, read_only=True)
    assert len(reader.evaluations) == 7 and reader.history[-1].kind == "acquisition"
    assert not reader.finished
    newest = reader.evaluations[-1]
    monkeypatch.setattr(RBBO, "recommend", lambda self: newest)
    result = reader.result()
    assert result.best_index == newest.index and result.R_star is None
    assert result.R_init == first.R_init and result.improvement_pct is None


def test_a_failed_confirmation_leaves_r_star_unset_and_is_no_failure_of_the_search(tmp_path):
    objective = SyntheticObjective(6, 2, noise=0.01)

    def diverges_on_fresh_seeds(basis, T, seed):
        if seed >= 10**6:  # (the confirmation's seeds)
            raise RuntimeError("episode diverged")
        return objective(basis, T, seed)

    config = RBBOConfig(6, 2, n_init=3, max_evaluations=5, n_confirm=2, **FAST)
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    result = opt.run(diverges_on_fresh_seeds)
    assert [e.status for e in opt.history if e.kind.startswith("confirm")] == ["failed"] * 2
    assert (result.evaluations, result.failed) == (5, 0)
    assert result.R_star is None and result.R_init is None and result.improvement_pct is None
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert (summary["evaluations"], summary["failed"], summary["R_star"]) == (5, 0, None)
    assert not opt.finished  # a resume measures them again


def test_a_run_without_proposal_records_numbers_new_proposals_after_every_recorded_one(tmp_path):
    # A run made before proposals.jsonl existed (or whose file is gone) may have lost an
    # evaluation in flight between two recorded ones: a new proposal must not take a
    # recorded index (the history would then hold it twice, and refuse the next resume).
    opt = RBBO.create(tmp_path / "run", RBBOConfig(4, 2, n_init=3, **FAST))
    first, _, third = opt.ask(), opt.ask(), opt.ask()
    opt.tell(first.index, 0.5)
    opt.tell(third.index, 0.4)
    opt.store.close()
    (tmp_path / "run" / "proposals.jsonl").unlink()
    resumed = RBBO.resume(tmp_path / "run")
    proposal = resumed.ask()
    assert proposal.index == 3
    resumed.tell(proposal.index, 0.3)
    resumed.store.close()
    assert [e.index for e in RBBO.resume(tmp_path / "run").history] == [0, 2, 3]


def test_a_proposal_record_without_its_seeds_is_named(tmp_path):
    opt = RBBO.create(tmp_path / "run", RBBOConfig(4, 2, n_init=3, **FAST))
    opt.ask()
    opt.store.close()
    with open(tmp_path / "run" / "proposals.jsonl", "a") as f:
        f.write(json.dumps({"index": 9, "basis": np.eye(4)[:, :2].tolist(), "T": 10.0,
                            "kind": "acquisition"}) + "\n")  # fmt: skip
    with pytest.raises(RunDirectoryError, match=r"proposals.jsonl: proposal 9 is unreadable: "
                       r"'seeds'"):  # fmt: skip
        RBBO.resume(tmp_path / "run")


def test_a_gp_record_of_another_version_is_passed_over_on_resume(tmp_path):
    # hyperparameters this version does not know (a later version's record): the next fit
    # starts from the defaults, as before the record existed, instead of failing the resume
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=5, n_confirm=0, **FAST)
    RBBO.create(tmp_path / "run", config, objective_spec=objective.spec()).run(objective)
    history = tmp_path / "run" / "history.jsonl"
    records = [json.loads(line) for line in history.read_text().splitlines()]
    assert records[-1]["gp"] is not None
    records[-1]["gp"]["warp"] = 0.5
    history.write_text("".join(json.dumps(r) + "\n" for r in records))
    opt = RBBO.resume(tmp_path / "run")
    opt.run(objective, max_evaluations=6)
    assert len(opt.evaluations) == 6


def test_a_run_may_have_no_random_initial_points():
    # (rbbo optimize --init 0): the identity, then the GP, from a random point while it has
    # fewer than two observations
    opt = RBBO(RBBOConfig(6, 2, n_init=0, max_evaluations=3, n_confirm=0, **FAST))
    opt.run(SyntheticObjective(6, 2))
    assert [e.kind for e in opt.evaluations] == ["initial", "random", "acquisition"]


def test_random_search_starts_from_the_identity_only_when_asked():
    objective = SyntheticObjective(6, 2)
    with_identity = random_search(objective, 6, 2, 3, T=10.0, rng=0)
    without = random_search(objective, 6, 2, 3, T=10.0, rng=0, include_identity=False)
    np.testing.assert_array_equal(with_identity[0][0], identity_basis(6, 2))
    assert not any(np.array_equal(b, identity_basis(6, 2)) for b, _, _ in without)


def _a_stopped_run(path, objective):
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=3, n_confirm=0, **FAST)
    opt = RBBO.create(path, config, objective_spec=objective.spec())
    opt.run(objective, max_evaluations=2)
    opt.store.close()
    return {p.name: p.read_bytes() for p in path.iterdir() if p.is_file()}


def test_a_run_resumed_from_python_with_another_objective_is_refused_naming_what_differs(
    tmp_path,
):
    # RBBO.resume(...).run(objective) never compared the objective with the one the run
    # recorded: a user resuming with another noise level silently mixed two objectives' R
    from rbbo.objective import ObjectiveMismatch

    run = tmp_path / "run"
    before = _a_stopped_run(run, SyntheticObjective(6, 2, noise=0.01))
    other = SyntheticObjective(6, 2, noise=0.05, optimum_seed=3)
    for call in (lambda opt: opt.run(other), lambda opt: opt.run(executor=SerialExecutor(other))):
        opt = RBBO.resume(run)
        with pytest.raises(ObjectiveMismatch) as error:
            call(opt)
        message = str(error.value)
        assert str(run) in message and "allow_objective_change=True" in message
        assert "noise 0.05 (recorded 0.01)" in message and "optimum_seed 3 (recorded 0)" in message
        assert "bias" not in message  # (the same)
        opt.store.close()
        assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before

    def plain(basis, T, seed):
        return 0.0

    # one without a spec() cannot be compared (a wrapper that injects faults must go on),
    # and the same objective goes on
    opt = RBBO.resume(run)
    assert opt.run(plain, max_evaluations=3).evaluations == 3
    assert opt.run(SyntheticObjective(6, 2, noise=0.01), max_evaluations=4).evaluations == 4
    opt.store.close()


def test_allow_objective_change_goes_on_and_keeps_the_objective_it_replaced(tmp_path):
    run = tmp_path / "run"
    old = SyntheticObjective(6, 2, noise=0.01)
    _a_stopped_run(run, old)
    # (delay changes only the cost of an evaluation, not R: a run may be resumed with another)
    slower = SyntheticObjective(6, 2, noise=0.01, delay=0.001)
    opt = RBBO.resume(run)
    assert opt.run(slower, max_evaluations=3).evaluations == 3
    assert opt.objective_spec == old.spec()
    opt.store.close()
    new = SyntheticObjective(6, 2, noise=0.02)
    opt = RBBO.resume(run)
    assert opt.run(new, max_evaluations=4, allow_objective_change=True).evaluations == 4
    assert opt.objective_spec == new.spec()
    opt.store.close()
    config = json.loads((run / "config.json").read_text())
    assert config["objective"] == new.spec()  # what rbbo resume rebuilds from now on
    # the first three lines of history.jsonl were evaluated with the old one, still recorded
    assert config["replaced_objectives"] == [{"objective": old.spec(), "history_lines": 3}]
    # a run made without a spec has nothing to compare with: any objective is taken
    bare = RBBO.create(tmp_path / "bare", RBBOConfig(6, 2, n_init=2, n_confirm=0, **FAST))
    assert bare.run(new, max_evaluations=2).evaluations == 2


def test_every_objective_a_confirmed_run_replaced_is_kept_and_confirm_again_checks_it(tmp_path):
    # A replaced objective's history_lines counts the lines of history.jsonl evaluated under
    # it, its confirmations too; a second change keeps the first one's record beside its own;
    # confirm_again refuses another objective as run does (it mixed two objectives' R*), and
    # so does a closed RBBO.
    from rbbo.objective import ObjectiveMismatch

    def lines():
        return len((run / "history.jsonl").read_text().splitlines())

    class WithoutNoise(SyntheticObjective):
        def spec(self):
            return {k: v for k, v in super().spec().items() if k != "noise"}

    run = tmp_path / "run"
    first = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=3, n_confirm=2, **FAST)
    with RBBO.create(run, config, objective_spec=first.spec()) as opt:
        opt.run(first)
    confirmed = lines()
    assert confirmed > len(opt.evaluations) == 3  # (R_init and R* are lines too)
    second = SyntheticObjective(6, 2, noise=0.02)
    with RBBO.resume(run) as opt:
        with pytest.raises(ObjectiveMismatch, match=r"noise 0.02 \(recorded 0.01\)"):
            opt.confirm_again(SerialExecutor(second))
        # (a setting the record has and the objective's spec() lacks is a difference too)
        with pytest.raises(ObjectiveMismatch, match=r"noise absent \(recorded 0.01\)"):
            opt.run(WithoutNoise(6, 2, noise=0.01))
        assert lines() == confirmed  # nothing evaluated
        opt.confirm_again(SerialExecutor(second), allow_objective_change=True)
    confirmed_again = lines()
    assert confirmed_again > confirmed
    third = SyntheticObjective(6, 2, noise=0.03)
    with RBBO.resume(run) as opt:
        opt.run(third, max_evaluations=4, allow_objective_change=True)
    stored = json.loads((run / "config.json").read_text())
    assert stored["objective"] == third.spec()
    assert stored["replaced_objectives"] == [
        {"objective": first.spec(), "history_lines": confirmed},
        {"objective": second.spec(), "history_lines": confirmed_again},
    ]
    with pytest.raises(ValueError, match=f"RBBO of {run} is closed"):
        opt.confirm_again(SerialExecutor(third))


def test_close_releases_the_run_directory_and_a_closed_rbbo_refuses_to_go_on(tmp_path):
    # an RBBO held its run directory's lock until it was garbage-collected: a second
    # RBBO.resume of the run in the same program after `del` or a finished `with` depended on
    # the collector, and another process was refused until this one exited
    run = tmp_path / "run"
    objective = SyntheticObjective(6, 2)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=3, n_confirm=0, **FAST)
    with RBBO.create(run, config, objective_spec=objective.spec()) as opt:
        assert not opt.closed
        opt.run(objective)
        kept = opt  # (a reference the collector cannot take away)
    assert kept.closed and kept.store is not None and not kept.store.writable
    # another process may now write the run
    code = ("import sys; from rbbo import RBBO; opt = RBBO.resume(sys.argv[1]); "
            "print(len(opt.evaluations))")  # fmt: skip
    child = subprocess.run([sys.executable, "-c", code, str(run)], capture_output=True,
                           text=True, timeout=120)  # fmt: skip
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == "3"
    # what it recorded is still read; nothing more is asked, told or run
    assert len(kept.evaluations) == 3 and kept.result().evaluations == 3
    for call in (kept.ask, lambda: kept.tell(0, 1.0), lambda: kept.run(objective),
                 lambda: kept.set_limits(5, None)):  # fmt: skip
        with pytest.raises(ValueError, match=f"RBBO of {run} is closed; RBBO.resume"):
            call()
    kept.close()  # (again: nothing)
    # left by an exception, the lock is released too, and an in-memory RBBO closes alike
    with pytest.raises(KeyError), RBBO.resume(run) as again:
        raise KeyError
    assert again.closed
    RBBO.resume(run).close()
    with RBBO(config) as memory:
        memory.ask()
    with pytest.raises(ValueError, match="this RBBO is closed"):
        memory.ask()


def test_run_evaluates_the_proposals_asked_and_never_told_and_counts_them_once(tmp_path):
    # they counted against run()'s max_evaluations (can_submit counts those pending) but run()
    # never evaluated them: asked once and not told, a run of 5 recorded 4 evaluations
    objective = SyntheticObjective(6, 2, noise=0.01)
    config = RBBOConfig(6, 2, n_init=2, max_evaluations=5, n_confirm=0, **FAST)
    opt = RBBO.create(tmp_path / "run", config, objective_spec=objective.spec())
    first, second = opt.ask(), opt.ask()
    opt.tell(first.index, objective(first.basis, first.T, first.seeds[0]))
    result = opt.run(objective)
    assert result.evaluations == 5 and not opt.pending
    assert [e.index for e in opt.evaluations] == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(opt.evaluations[1].basis, second.basis)
    # a run already at its limit leaves one asked and not told to its caller to tell
    third = RBBO(config)
    asked = [third.ask() for _ in range(5)]
    third.tell(asked[0].index, 0.5)
    assert third.run(objective, max_evaluations=1).evaluations == 1
    assert sorted(third.pending) == [1, 2, 3, 4]
    third.tell(asked[4].index, 0.25)
    opt.close()
    # beside a resumed run's proposals left in flight, all in index order
    run = tmp_path / "resumed"
    stopped = RBBO.create(run, config, objective_spec=objective.spec())
    stopped.ask(), stopped.ask()
    stopped.close()
    resumed = RBBO.resume(run)
    assert resumed.ask().index == 0  # (1 is still to be handed out again)
    assert resumed.run(objective, max_evaluations=1).evaluations == 1
    assert list(resumed.pending) == [] and [p.index for p in resumed._restored] == [1]
    assert resumed.run(objective).evaluations == 5
    resumed.close()


def test_boca_reads_tau_from_the_believer_with_the_proposals_in_flight(monkeypatch):
    """T is chosen by BOCA on the GP conditioned on the search proposals in flight (the
    kriging believer), as the acquisition is: a second worker's look at a basis near one in
    flight sees the shrunken uncertainty there. Handing BOCA the fitted GP instead (the one
    without fantasies) passed every test."""
    m, c = 6, 2
    objective = SyntheticObjective(m, c, optimum_seed=3)
    opt = RBBO(RBBOConfig(m, c, fidelity="boca", t_min=4.0, t_max=10.0, n_init=3, seed=1,
                          n_confirm=0, **FAST))  # fmt: skip
    for _ in range(4):  # the initial design, told
        p = opt.ask()
        opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
    first = opt.ask()  # in flight from here on
    assert first.kind == "acquisition"
    seen = []
    choose = opt._boca.choose

    def spy(gp, basis, pending=()):
        seen.append((gp, list(pending)))
        return choose(gp, basis, pending)

    monkeypatch.setattr(opt._boca, "choose", spy)
    opt.ask()
    assert seen, "BOCA chose no T"
    gp, pending = seen[0]
    assert pending == [first.T]
    assert gp.n_observations == 4 + 1  # the told four and the fantasy of the one in flight
    fitted = opt.fit()
    z = opt._z([first.T])
    (mu0, sd0), (mu1, sd1) = fitted.predict(first.basis[None], z), gp.predict(first.basis[None], z)
    np.testing.assert_allclose(mu1, mu0, atol=1e-8)  # observed at its posterior mean
    assert sd1[0] < 0.5 * sd0[0]
