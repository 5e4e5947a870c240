"""Run directories (rbbo.store): durable history, truncation repair, clear corruption errors."""

import json

import numpy as np
import pytest

from rbbo.store import Evaluation, RunDirectoryError, RunStore, TruncatedHistoryWarning


def _evaluation(i, r=1.0, status="ok"):
    return Evaluation(
        index=i, basis=np.eye(4)[:, :2] * (1 + 1e-17 * i), T=5.0, R=r if status == "ok" else None,
        status=status, seeds=[0, 1], wall_s=0.5, elapsed_s=float(i), worker="w0",
    )  # fmt: skip


def test_roundtrip_is_exact(tmp_path):
    store = RunStore.create(tmp_path / "run", {"sim_dim": 4, "control_dim": 2})
    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((4, 2)))[0]
    store.append(Evaluation(0, basis, 4.5, 0.123456789012345678, seeds=[3], kind="initial"))
    store.append(_evaluation(1, status="failed"))
    again = RunStore.open(tmp_path / "run", repair=False)  # (a reader, beside the writer)
    assert again.config == {"sim_dim": 4, "control_dim": 2}
    hist = again.history()
    np.testing.assert_array_equal(hist[0].basis, basis)
    assert hist[0].R == 0.123456789012345678 and hist[0].kind == "initial"
    assert hist[1].status == "failed" and hist[1].R is None
    store.save_best(basis)
    np.testing.assert_array_equal(again.best_basis(), basis)


def test_truncated_last_line_is_dropped_with_a_warning(tmp_path):
    store = RunStore.create(tmp_path, {})
    for i in range(3):
        store.append(_evaluation(i))
    with open(store.history_path, "a") as f:
        f.write(_evaluation(3).to_json()[:40])  # a write cut short by kill -9
    store.close()
    with pytest.warns(TruncatedHistoryWarning, match="dropped a truncated last line") as caught:
        reopened = RunStore.open(tmp_path)
    # it names the caller's line, not one inside rbbo (it named rbbo/restore.py's after the
    # optimizer was split, from a counted stacklevel)
    assert [w.filename for w in caught] == [__file__]
    assert [e.index for e in reopened.history()] == [0, 1, 2]
    assert (tmp_path / "history.jsonl.truncated").read_text().startswith('{"index": 3')
    reopened.append(_evaluation(4))  # appends land on a clean line
    assert [e.index for e in RunStore.open(tmp_path, repair=False).history()] == [0, 1, 2, 4]


def test_a_whole_last_line_without_its_newline_is_kept(tmp_path, recwarn):
    store = RunStore.create(tmp_path, {})
    for i in range(2):
        store.append(_evaluation(i))
    with open(store.history_path, "a") as f:
        f.write(_evaluation(2).to_json())  # the write stopped before its newline
    assert [e.index for e in RunStore.open(tmp_path, repair=False).history()] == [0, 1]
    store.close()
    reopened = RunStore.open(tmp_path)
    assert not recwarn.list and not (tmp_path / "history.jsonl.truncated").exists()
    assert [e.index for e in reopened.history()] == [0, 1, 2]
    reopened.append(_evaluation(3))
    assert [e.index for e in RunStore.open(tmp_path, repair=False).history()] == [0, 1, 2, 3]


def test_read_only_open_skips_a_line_being_written_and_changes_nothing(tmp_path):
    store = RunStore.create(tmp_path, {})
    store.append(_evaluation(0))
    with open(store.history_path, "a") as f:
        f.write('{"index": 1, "bas')  # another process is writing this line right now
    before = store.history_path.read_bytes()
    reader = RunStore.open(tmp_path, repair=False)
    assert [e.index for e in reader.history()] == [0]
    assert store.history_path.read_bytes() == before


def test_corrupted_line_in_the_middle_is_an_error(tmp_path):
    store = RunStore.create(tmp_path, {})
    store.append(_evaluation(0))
    with open(store.history_path, "a") as f:
        f.write("{not json}\n")
    store.append(_evaluation(2))
    store.close()
    with pytest.raises(RunDirectoryError, match=r"history.jsonl line 2 is corrupted"):
        RunStore.open(tmp_path).history()


@pytest.mark.parametrize(
    ("setup", "match"),
    [
        (lambda p: None, "not an RBBO run directory \\(no config.json\\)"),
        (lambda p: (p / "config.json").write_text("{oops"), "config.json is corrupted"),
        (lambda p: (p / "config.json").write_text("[1, 2]"), "does not hold a JSON object"),
    ],
)
def test_bad_directories_give_clear_errors(tmp_path, setup, match):
    setup(tmp_path)
    with pytest.raises(RunDirectoryError, match=match):
        RunStore.open(tmp_path)


def test_missing_directory_and_existing_run(tmp_path):
    with pytest.raises(RunDirectoryError, match="is not a directory"):
        RunStore.open(tmp_path / "nope")
    RunStore.create(tmp_path / "run", {})
    with pytest.raises(RunDirectoryError, match="already holds a run; resume it"):
        RunStore.create(tmp_path / "run", {})


def test_history_record_has_the_documented_keys(tmp_path):
    store = RunStore.create(tmp_path, {})
    store.append(_evaluation(0))
    record = json.loads(store.history_path.read_text())
    assert {"basis", "T", "R", "wall_s", "elapsed_s", "worker", "status", "seeds"} <= set(record)


def test_evaluation_validation():
    with pytest.raises(ValueError, match="status must be one of"):
        _evaluation(0, status="weird")
    with pytest.raises(ValueError, match="an 'ok' evaluation needs a finite R, got nan"):
        Evaluation(0, np.eye(2), 1.0, float("nan"))


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("T", "5.0", "T must be a positive number of seconds, got '5.0'"),
        ("T", None, "T must be a positive number of seconds, got None"),
        ("T", 0, "T must be a positive number of seconds, got 0"),
        ("index", "1", "index must be an integer, got '1'"),
        ("index", 1.5, "index must be an integer, got 1.5"),
        ("basis", [[1.0, None], [0.0, 1.0]], "basis holds non-finite values"),
        ("kind", "bogus", "kind must be one of .*, got 'bogus'"),
        # (these were never checked: report, resume and confirm met them as TypeErrors)
        ("elapsed_s", "x", "elapsed_s must be a number of seconds >= 0, got 'x'"),
        ("elapsed_s", None, "elapsed_s must be a number of seconds >= 0, got None"),
        ("wall_s", "x", "wall_s must be a number of seconds >= 0, got 'x'"),
        ("wall_s", -1.0, "wall_s must be a number of seconds >= 0, got -1.0"),
        ("seeds", "ab", "seeds must be a list of integers, got 'ab'"),
        ("seeds", [0.5], r"seeds must be a list of integers, got \[0.5\]"),
        ("R_seeds", 3, "R_seeds must be a list of finite numbers, got 3"),
        ("R_seeds", ["a"], r"R_seeds must be a list of finite numbers, got \['a'\]"),
        ("R", "x", "R must be a number or null, got 'x'"),
        ("gp", "x", "gp must be null or an object of numbers, got 'x'"),
        ("gp", {"length_scale": "x"}, "gp must be null or an object of numbers"),
        ("duplicates_skipped", "x", "duplicates_skipped must be an integer >= 0, got 'x'"),
        ("worker", 5, "worker must be a string, got 5"),
        ("error", 5, "error must be a string or null, got 5"),
    ],
)
def test_an_edited_line_of_the_wrong_type_is_named(tmp_path, key, value, match):
    # parsed, but not an evaluation: refused where it is read, naming the line
    store = RunStore.create(tmp_path, {})
    store.append(_evaluation(0))
    record = json.loads(_evaluation(1).to_json())
    record[key] = value
    with open(store.history_path, "a") as f:
        f.write(json.dumps(record) + "\n")
    with pytest.raises(RunDirectoryError, match=rf"history.jsonl line 2 is corrupted \({match}"):
        RunStore.open(tmp_path, repair=False).history()


def test_a_run_killed_before_its_history_existed_reads_as_empty(tmp_path):
    store = RunStore.create(tmp_path / "run", {"rbbo": {}})
    store.history_path.unlink()  # as if killed between writing config.json and the history
    assert RunStore.open(tmp_path / "run", repair=False).history() == []
    store.close()
    RunStore.open(tmp_path / "run")  # resuming makes it again
    assert (tmp_path / "run" / "history.jsonl").is_file()


LOCK_PROBE = """
import sys
from rbbo.store import RunDirectoryError, RunStore
try:
    RunStore.open(sys.argv[1], repair=sys.argv[2] == "write")
except RunDirectoryError as exc:
    print(exc)
else:
    print("opened")
"""


def test_a_second_process_cannot_write_a_run_directory(tmp_path):
    import os
    import subprocess
    import sys

    def probe(mode):
        return subprocess.run([sys.executable, "-c", LOCK_PROBE, str(run), mode],
                              capture_output=True, text=True, timeout=120).stdout  # fmt: skip

    run = tmp_path / "run"
    store = RunStore.create(run, {"sim_dim": 4, "control_dim": 2})
    assert f"is in use by another process (pid {os.getpid()})" in probe("write")
    assert probe("read") == "opened\n"  # readers take no lock
    store.close()
    assert probe("write") == "opened\n"


def test_a_second_writer_in_the_same_process_is_refused_and_readers_are_not(tmp_path):
    # Stores of one process shared the lock: a second RBBO.resume beside an open one handed
    # out the same evaluation index, both were told, and the next resume found the history
    # corrupted ("evaluation 4 is recorded on line 5 already").
    import os

    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    run = tmp_path / "run"
    fast = {"acq_random": 64, "acq_starts": 2, "acq_max_iterations": 30, "gp_restarts": 0}
    opt = RBBO.create(run, RBBOConfig(6, 2, n_init=3, max_evaluations=10, n_confirm=0, **fast))
    opt.run(SyntheticObjective(6, 2), max_evaluations=4, confirm=False)
    refused = (rf"{run} is in use by another writer in this process \(pid {os.getpid()}\): "
               r"close it first \(RBBO.close\(\), or leave its with block\)")  # fmt: skip
    with pytest.raises(RunDirectoryError, match=refused):
        RBBO.resume(run)
    (tmp_path / "link").symlink_to(run)  # (the same directory by another name)
    with pytest.raises(RunDirectoryError, match="in use by another writer in this process"):
        RunStore.open(tmp_path / "link")
    reader = RBBO.resume(run, read_only=True)  # readers take no lock
    assert [e.index for e in reader.history] == [0, 1, 2, 3]
    proposal = opt.ask()  # the open writer goes on, unharmed by the refusals
    opt.tell(proposal.index, 0.5)
    opt.close()
    with RBBO.resume(run) as again:  # once it is closed, a resume writes
        again.tell(again.ask().index, 0.6)
    assert [e.index for e in RBBO.resume(run, read_only=True).history] == [0, 1, 2, 3, 4, 5]


def test_update_config_merges_rewrites_and_needs_the_lock(tmp_path):
    store = RunStore.create(tmp_path / "run", {"rbbo": {"seed": 3, "max_evaluations": 8}, "x": 1})
    store.update_config({"rbbo": {"max_evaluations": 12, "budget_s": None}, "y": [2]})
    expected = {"rbbo": {"seed": 3, "max_evaluations": 12, "budget_s": None}, "x": 1, "y": [2]}
    assert store.config == expected
    assert json.loads((tmp_path / "run" / "config.json").read_text()) == expected
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        store.update_config({"z": float("nan")})
    assert store.config == expected  # a failed update changes nothing, in memory or on disk
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        store.update_config({"rbbo": {"budget_s": float("nan")}})  # (merged into a dict)
    assert store.config == expected
    assert json.loads((tmp_path / "run" / "config.json").read_text()) == expected
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [".rbbo.lock", "config.json",
                                                                    "history.jsonl"]  # fmt: skip
    store.close()
    # (a closed writer said "was opened read-only", which it never was)
    with pytest.raises(RunDirectoryError, match="run was closed; its config cannot change"):
        store.update_config({"x": 2})
    reader = RunStore.open(tmp_path / "run", repair=False)
    with pytest.raises(RunDirectoryError, match="read-only"):
        reader.update_config({"x": 2})


def test_proposals_survive_a_torn_line_and_name_a_corrupted_one(tmp_path):
    store = RunStore.create(tmp_path / "run", {})
    store.append_proposal({"index": 0, "basis": [[1.0], [0.0]], "T": 4.0})
    with open(tmp_path / "run" / "proposals.jsonl", "a") as f:
        f.write('{"index": 1, "basis": [[0.0')  # a kill while the record was written
    store.append_proposal({"index": 2, "basis": [[0.0], [1.0]], "T": 4.0})  # on a new line
    assert [r["index"] for r in store.proposals()] == [0, 2]
    assert RunStore.open(tmp_path / "run", repair=False).proposals() == store.proposals()
    with open(tmp_path / "run" / "proposals.jsonl", "a") as f:
        f.write('{"basis": []}\n')
    with pytest.raises(RunDirectoryError, match=r"proposals.jsonl line 4 is not a proposal"):
        store.proposals()
    reader = RunStore.open(tmp_path / "run", repair=False)
    assert store.writable and not reader.writable
    with pytest.raises(RunDirectoryError, match="opened read-only"):
        reader.append_proposal({"index": 3})


def _open_fds() -> set[str]:
    import os

    return set(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self/fd"), reason="needs /proc")
def test_failed_writes_and_locks_leak_no_descriptor_and_hold_no_lock(tmp_path, monkeypatch):
    import os

    from rbbo.store import _acquire_lock, _atomic_write, _release_lock

    run = tmp_path / "run"
    run.mkdir()

    def refuse(*args):
        raise OSError(37, "No locks available")  # (ENOLCK: flock on some NFS mounts)

    before = _open_fds()
    # _atomic_write: chmod of the temporary file fails; it is removed and its fd closed
    monkeypatch.setattr(os, "fchmod", refuse)
    with pytest.raises(OSError, match="No locks available"):
        _atomic_write(run / "config.json", b"{}")
    monkeypatch.undo()
    assert sorted(p.name for p in run.iterdir()) == []
    # _acquire_lock: the lock is taken, then writing the pid fails; the fd is closed, which
    # lets the lock go, so that a later store (here: this process) can take it; the error
    # names the lock file (a one-line error of the command line, not a traceback)
    monkeypatch.setattr(os, "ftruncate", refuse)
    with pytest.raises(RunDirectoryError, match=r"cannot lock .*\.rbbo\.lock: No locks available"):
        _acquire_lock(run)
    monkeypatch.undo()
    assert _open_fds() == before
    _release_lock(_acquire_lock(run))
    assert _open_fds() == before


def test_an_atomic_write_killed_before_its_rename_leaves_the_old_file(tmp_path, monkeypatch):
    # A kill between writing and renaming is simulated by a rename that fails: the old
    # config.json (or best basis, summary) must be untouched and no temporary file left.
    # A direct open()/write() over the file would leave it replaced (or torn) instead.
    import rbbo.store.files as files

    store = RunStore.create(tmp_path / "run", {"x": 1})
    store.save_best(np.eye(3)[:, :1])
    store.write_summary({"best": 1})
    before = {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()}

    def killed(*args):
        raise KeyboardInterrupt  # (BaseException, as a signal's handler raises)

    monkeypatch.setattr(files.os, "replace", killed)
    for write in (lambda: store.update_config({"x": 2}), lambda: store.save_best(np.eye(3)[:, 1:2]),
                  lambda: store.write_summary({"best": 2})):  # fmt: skip
        with pytest.raises(KeyboardInterrupt):
            write()
    monkeypatch.undo()
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()} == before
    assert store.config == {"x": 1}  # (and no temporary file is left: the names are the same)


def test_a_figure_is_replaced_whole_or_not_at_all(tmp_path):
    # A figure whose drawing fails part-way (a kill, a full disk) leaves the old image, not a
    # torn one; a figure drawn whole is written in its suffix's format
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rbbo.store import _atomic_savefig

    fig = Figure(figsize=(2, 2))
    FigureCanvasAgg(fig)
    fig.subplots().plot([0, 1], [1, 0])
    png, pdf = tmp_path / "convergence.png", tmp_path / "convergence.pdf"
    assert _atomic_savefig(fig, png, dpi=50) == png
    assert _atomic_savefig(fig, str(pdf), dpi=50) == pdf
    assert png.read_bytes().startswith(b"\x89PNG") and pdf.read_bytes().startswith(b"%PDF")
    before = png.read_bytes()

    class TornFigure:
        def savefig(self, target, **kwargs):
            target.write(b"\x89PNG half an ima")
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _atomic_savefig(TornFigure(), png, dpi=50)
    assert png.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["convergence.pdf", "convergence.png"]


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self/fd"), reason="needs /proc")
def test_each_directory_a_new_run_creates_is_fsynced_in_its_parent(tmp_path, monkeypatch):
    """Fsyncing the files inside a new directory does not make the directory's own name
    durable: each directory ``create`` makes (``--out a/b/run`` makes three) must be listed by
    an fsync of its parent, else a power loss could drop the run with every record in it."""
    import os
    import stat

    listed = []
    real_fsync = os.fsync

    def spy(fd):
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            where = os.readlink(f"/proc/self/fd/{fd}")
            listed.append((where, set(os.listdir(where))))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    RunStore.create(tmp_path / "a" / "b" / "run", {"x": 1}).close()
    for parent, child in ((tmp_path, "a"), (tmp_path / "a", "b"), (tmp_path / "a" / "b", "run")):
        assert any(w == str(parent) and child in names for w, names in listed), (
            f"{parent} was not fsynced after {child} was made in it"
        )
    listed.clear()
    RunStore.create(tmp_path / "a" / "other", {"x": 1}).close()  # only "other" is new
    assert [w for w, _ in listed if w != str(tmp_path / "a" / "other")] == [str(tmp_path / "a")]


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self/fd"), reason="needs /proc")
def test_every_write_is_fsynced_with_its_data_before_it_returns(tmp_path, monkeypatch):
    # Durability is not observable without pulling the power, so this watches os.fsync (the
    # os module that rbbo.store.files and rbbo.store.run_store call it through): each write
    # must fsync the file it wrote, holding all its data (its inode and size at that
    # moment), and each new or renamed file must also have its directory fsynced once the
    # entry is there (the directory's listing at that moment).
    import os
    import stat

    import rbbo.store.files as files
    import rbbo.store.run_store as run_store

    assert files.os is os and run_store.os is os  # (one patch covers both modules)
    synced = []
    real_fsync = os.fsync

    def spy(fd):
        st = os.fstat(fd)
        names = None
        if stat.S_ISDIR(st.st_mode):
            names = set(os.listdir(os.readlink(f"/proc/self/fd/{fd}")))
        synced.append((st.st_ino, st.st_size, names))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    run = tmp_path / "run"

    def check(name, *, entry=False):
        st = (run / name).stat()
        assert (st.st_ino, st.st_size) in [(i, s) for i, s, _ in synced], f"{name} not fsynced"
        if entry:
            dir_ino = run.stat().st_ino
            assert any(i == dir_ino and name in n for i, s, n in synced if n is not None), (
                f"the directory was not fsynced after {name} was made"
            )
        synced.clear()

    store = RunStore.create(run, {"x": 1})
    dirs = [n for i, s, n in synced if n is not None]
    assert dirs and "history.jsonl" in dirs[-1], "the new history's entry was not fsynced"
    check("config.json", entry=True)
    store.append(_evaluation(0))
    check("history.jsonl")
    store.append_proposal({"index": 1})  # (the first: a new file, its entry fsynced too)
    check("proposals.jsonl", entry=True)
    store.append_session({"started": "now"})
    check("sessions.jsonl", entry=True)
    store.update_config({"x": 2})
    check("config.json", entry=True)
    store.save_best(np.eye(3)[:, :1])
    check("best_basis.npy", entry=True)
    store.write_summary({"best": 1})
    check("summary.json", entry=True)
    store.close()
    # the repairs of a resume: a whole last line ended, a torn one cut
    with open(run / "history.jsonl", "a") as f:
        f.write(_evaluation(1).to_json())
    RunStore.open(run).close()
    check("history.jsonl")
    with open(run / "history.jsonl", "a") as f:
        f.write(_evaluation(2).to_json()[:30])
    with pytest.warns(TruncatedHistoryWarning):
        RunStore.open(run).close()
    check("history.jsonl")
    assert [e.index for e in RunStore.open(run, repair=False).history()] == [0, 1]


@pytest.mark.parametrize("fault", ["short write", "fsync"])
def test_a_failed_append_leaves_nothing_behind_so_it_can_be_written_again(
    tmp_path, monkeypatch, fault
):
    """A full disk's short write left a torn fragment, and a failed fsync a whole line, in
    the history; the evaluation stays pending, so RBBO.run or tell writes it again, after
    them, and every later resume refused the run as corrupted (a review, session 54)."""
    import errno
    import os

    store = RunStore.create(tmp_path / "run", {"x": 1})
    store.append(_evaluation(0))
    before = (tmp_path / "run" / "history.jsonl").read_bytes()
    real_write, real_fsync = os.write, os.fsync

    def short_write(fd, data):  # half the line reaches the file, then the disk is full
        monkeypatch.setattr(os, "write", failing_write)
        return real_write(fd, bytes(data[: len(data) // 2]))

    def failing_write(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    def failing_fsync(fd):
        monkeypatch.setattr(os, "fsync", real_fsync)  # (once: the undo's own fsync works)
        raise OSError(errno.EIO, "Input/output error")

    if fault == "short write":
        monkeypatch.setattr(os, "write", short_write)
    else:
        monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="No space left|Input/output"):
        store.append(_evaluation(1))
    monkeypatch.undo()
    assert (tmp_path / "run" / "history.jsonl").read_bytes() == before
    store.append(_evaluation(1))  # the same evaluation again, once the disk takes it
    store.close()
    assert [e.index for e in RunStore.open(tmp_path / "run", repair=False).history()] == [0, 1]


class _Terminated(Exception):
    """What a SIGTERM handler raises here (rbbo's raises KeyboardInterrupt)."""


def _raise_terminated(signum, frame):
    raise _Terminated


@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM", "SIGTERM ignored"])
def test_a_signal_during_an_append_is_raised_once_the_line_is_durable(tmp_path, monkeypatch,
                                                                      signum):  # fmt: skip
    """Ctrl-C between a history line's write and its fsync cut the finished evaluation back
    (the CI's deterministic-resume test saw 5 lines, signalled, and found 4): the signal is
    held until the line is durable, then raised by the handler that was set."""
    import os
    import signal

    store = RunStore.create(tmp_path / "run", {"x": 1})
    store.append(_evaluation(0))
    sig = signal.SIGINT if signum == "SIGINT" else signal.SIGTERM
    handler = {"SIGINT": signal.default_int_handler, "SIGTERM": _raise_terminated,
               "SIGTERM ignored": signal.SIG_IGN}[signum]  # fmt: skip
    before = signal.signal(sig, handler)
    real_fsync, synced = os.fsync, []

    def signalled_fsync(fd):  # the signal as the line reaches the disk
        os.kill(os.getpid(), sig)
        real_fsync(fd)
        synced.append(fd)

    monkeypatch.setattr(os, "fsync", signalled_fsync)
    try:
        if signum == "SIGTERM ignored":
            store.append(_evaluation(1))
        else:
            with pytest.raises(KeyboardInterrupt if signum == "SIGINT" else _Terminated):
                store.append(_evaluation(1))
        assert signal.getsignal(sig) is handler  # (handed back as it was)
    finally:
        signal.signal(sig, before)
        monkeypatch.undo()
    assert synced  # (the fsync ran whole)
    store.close()
    assert [e.index for e in RunStore.open(tmp_path / "run", repair=False).history()] == [0, 1]


def test_held_signals_reach_the_handler_set_when_each_is_delivered_even_after_one_raised():
    """Two signals held in one block: each goes to the handler set when it is handed on (a
    "Ctrl-C again to force" handler was called twice as it was before the block), and one
    whose handler raises does not drop the next."""
    import os
    import signal

    from softrom_gym._durable import signals_deferred

    calls = []

    def forced(signum, frame):
        calls.append("forced")

    def graceful(signum, frame):
        calls.append("graceful")
        signal.signal(signal.SIGINT, forced)  # (the next Ctrl-C forces)

    def terminated(signum, frame):
        calls.append("terminated")

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        signal.signal(signal.SIGINT, graceful)
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
            assert calls == []
        assert calls == ["graceful", "forced"]

        calls.clear()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, terminated)
        with pytest.raises(KeyboardInterrupt):
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGINT)
                os.kill(os.getpid(), signal.SIGTERM)
        assert calls == ["terminated"]
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


def test_a_ctrl_c_while_the_handlers_are_put_back_leaves_none_held(monkeypatch):
    """signal.signal runs pending handlers first: a Ctrl-C just after SIGINT's handler was put
    back raised out of putting back SIGTERM's, which stayed the block's hold, and every later
    SIGTERM was swallowed. The hold left behind now acts as the handler it replaced."""
    import os
    import signal

    from softrom_gym._durable import signals_deferred

    terms = []

    def terminated(signum, frame):
        terms.append(signum)

    real = signal.signal

    def then_ctrl_c(signum, handler):
        old = real(signum, handler)
        if signum == signal.SIGINT and handler is signal.default_int_handler:
            os.kill(os.getpid(), signal.SIGINT)  # the user's Ctrl-C, just then
        return old

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        real(signal.SIGINT, signal.default_int_handler)
        real(signal.SIGTERM, terminated)
        monkeypatch.setattr(signal, "signal", then_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            with signals_deferred():
                pass
        monkeypatch.undo()
        os.kill(os.getpid(), signal.SIGTERM)
        assert terms == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGTERM) is terminated
    finally:
        monkeypatch.undo()
        for s, handler in before.items():
            signal.signal(s, handler)


def test_more_corrupted_run_files_are_named(tmp_path):
    store = RunStore.create(tmp_path / "run", {})
    store.append(_evaluation(0))
    store.save_best(np.eye(4)[:, :2])
    store.close()
    history = tmp_path / "run" / "history.jsonl"
    good = history.read_bytes()
    for tail, match in ((b"[1, 2]\n", r"line 2 is corrupted \(expected a JSON object, got list\)"),
                        (b'{"index": 1}\n', r"line 2 is corrupted \(missing keys \['R', 'T', "
                                            r"'basis'\]\)"),
                        (b"\xff\xfe\n", "history.jsonl is not UTF-8 text")):  # fmt: skip
        history.write_bytes(good + tail)
        with pytest.raises(RunDirectoryError, match=match):
            RunStore.open(tmp_path / "run", repair=False).history()
    history.write_bytes(good)
    # (an empty file raised numpy's EOFError, a traceback; a vector was handed on as B_c)
    vector = tmp_path / "vector.npy"
    np.save(vector, np.ones(3))
    for data in (b"not an array", b"", vector.read_bytes()):
        (tmp_path / "run" / "best_basis.npy").write_bytes(data)
        with pytest.raises(RunDirectoryError, match="best_basis.npy is corrupted"):
            RunStore.open(tmp_path / "run", repair=False).best_basis()
    # (not UTF-8: a UnicodeDecodeError traceback in rbbo report and rbbo resume)
    for data in (b"{oops", b"[1, 2]", b"null", b"\xff\xfe{}"):  # (JSON, but no summary: an edit)
        (tmp_path / "run" / "summary.json").write_bytes(data)
        with pytest.raises(RunDirectoryError, match="summary.json is corrupted"):
            RunStore.open(tmp_path / "run", repair=False).summary()
    assert RunStore.open(tmp_path / "run", repair=False).sessions() == []  # none recorded
    # a B_c of another shape than the run's (M, C)
    store = RunStore.create(tmp_path / "run2", {"rbbo": {"sim_dim": 4, "control_dim": 2}})
    store.save_best(np.eye(4)[:, :3])
    with pytest.raises(RunDirectoryError, match=r"not a finite B_c of shape \(4, 2\)"):
        store.best_basis()
    store.save_best(np.eye(4)[:, :2])
    np.testing.assert_array_equal(store.best_basis(), np.eye(4)[:, :2])
    with pytest.raises(ValueError, match=r"basis must be an \(M, C\) array, got shape \(3,\)"):
        Evaluation(0, np.ones(3), 1.0, 1.0)


def test_a_run_directory_that_cannot_be_created_leaves_nothing_behind(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(RunDirectoryError, match="file exists and is not a directory"):
        RunStore.create(tmp_path / "file", {})
    for config, match in (({"x": float("nan")}, "Out of range float values"),
                          ({"x": object()}, "Object of type object")):  # fmt: skip
        with pytest.raises(ValueError, match=f"config is not JSON-serialisable: {match}"):
            RunStore.create(tmp_path / "run", config)
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_a_directory_with_a_history_but_no_config_is_not_made_a_new_run(tmp_path):
    # (config.json lost, or removed by hand): a new run there would append its evaluations,
    # numbered from 0 again, to the old ones
    store = RunStore.create(tmp_path / "run", {"x": 1})
    store.append(_evaluation(0))
    store.close()
    (tmp_path / "run" / "config.json").unlink()
    before = (tmp_path / "run" / "history.jsonl").read_bytes()
    with pytest.raises(RunDirectoryError, match="already holds a run; resume it"):
        RunStore.create(tmp_path / "run", {"x": 2})
    assert (tmp_path / "run" / "history.jsonl").read_bytes() == before
    assert not (tmp_path / "run" / "config.json").exists()


def test_a_store_opened_read_only_refuses_every_write_and_writes_nothing(tmp_path):
    # a reader holds no lock: the run may be going on in another process, whose records a
    # write from here would collide with or replace
    store = RunStore.create(tmp_path / "run", {"x": 1})
    store.append(_evaluation(0))
    before = {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()}
    reader = RunStore.open(tmp_path / "run", repair=False)
    writes = [
        lambda: reader.append(_evaluation(1)),
        lambda: reader.append_proposal({"index": 1}),
        lambda: reader.append_session({"started": "now"}),
        lambda: reader.save_best(np.eye(4)[:, :2]),
        lambda: reader.write_summary({"best_index": 0}),
        lambda: reader.update_config({"x": 2}),
    ]
    for write in writes:
        with pytest.raises(RunDirectoryError, match="run was opened read-only"):
            write()
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()} == before


def test_a_run_no_session_of_which_finished_says_it_has_no_best_basis_yet(tmp_path):
    store = RunStore.create(tmp_path / "run", {})
    store.append(_evaluation(0))
    with pytest.raises(RunDirectoryError, match=r"has no best_basis.npy yet: no session of the "
                       r"run has finished \(resume it with rbbo resume\)"):  # fmt: skip
        store.best_basis()
