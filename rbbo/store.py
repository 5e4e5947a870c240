"""A run directory: the durable record of one RBBO optimisation.

::

    DIR/config.json       settings (written atomically; rewritten only by
                          :meth:`RunStore.update_config`, e.g. ``rbbo resume`` with a new limit)
    DIR/history.jsonl     one JSON object per finished evaluation, append-only; each line is
                          flushed and fsynced before the optimiser moves on, so a kill -9
                          loses at most the results still in flight
    DIR/proposals.jsonl   one JSON object per search proposal when it is handed out, before
                          it is evaluated (index, basis, T, seeds, kind and the GP
                          hyperparameters its fit found), append-only and fsynced: a resumed
                          run evaluates the proposals that were in flight when it stopped
                          instead of proposing others in their place
    DIR/best_basis.npy    the recommended B_c, R*'s basis (replaced atomically when a session
                          of the run ends: a run interrupted before its first end has none)
    DIR/summary.json      R_init, R* and the rest of the report (written with it)
    DIR/sessions.jsonl    one JSON object when a session of the run (search or confirmation)
                          starts: when, the code (version, git commit) and the machine (CPU,
                          kernel set, numpy/scipy) it runs on; and one when it ends
                          (``"event": "end"``): when, and its status, "finished",
                          "interrupted" or "error" (a session killed outright has none);
                          append-only

A kill during a write can leave a partial last line; :meth:`RunStore.open` detects it, warns
(:class:`TruncatedHistoryWarning`), keeps the bytes in ``history.jsonl.truncated`` and cuts
the file back to its last complete line. Anything else unreadable raises
:class:`RunDirectoryError` naming the file and line.

A store that writes (:meth:`RunStore.create`, :meth:`RunStore.open` with ``repair``) holds an
exclusive lock on ``DIR/.rbbo.lock`` (``flock``; it holds the owner's pid) until
:meth:`RunStore.close` or the process ends, so a second process, e.g. ``rbbo resume`` while
the run still goes on under nohup, is refused instead of appending the same evaluation
indices. Readers (``repair=False``) take no lock. Stores of one directory in one process share
the lock.
"""

from __future__ import annotations

import io
import json
import math
import os
import sys
import tempfile
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "STATUSES",
    "Evaluation",
    "RunDirectoryError",
    "RunStore",
    "TruncatedHistoryWarning",
]

CONFIG = "config.json"
HISTORY = "history.jsonl"
BEST = "best_basis.npy"
SUMMARY = "summary.json"
SESSIONS = "sessions.jsonl"
PROPOSALS = "proposals.jsonl"
STATUSES = ("ok", "failed")
# Evaluation.kind: how the proposal was made (rbbo.config.CONFIRM_KINDS are the last two)
KINDS = ("initial", "random", "acquisition", "confirm-init", "confirm-best")
LOCK = ".rbbo.lock"

if sys.platform != "win32":
    import fcntl
else:  # pragma: no cover - no flock: runs are not guarded against a second writer
    fcntl = None

# realpath of a run directory -> [lock file descriptor, stores of this process holding it]
_HELD_LOCKS: dict[str, list[int]] = {}


class RunDirectoryError(ValueError):
    """A run directory is missing, not a run directory, or corrupted."""


class TruncatedHistoryWarning(UserWarning):
    """The last line of history.jsonl was incomplete (a write was interrupted) and dropped."""


@dataclass
class Evaluation:
    """One finished evaluation of the objective R(B_c, T).

    Attributes
    ----------
    index : int
        Order in which the evaluation was proposed (unique within the run).
    basis : (M, C) ndarray
        The control basis B_c evaluated.
    T : float
        Trajectory length (fidelity), seconds.
    R : float or None
        Mean reward over ``seeds`` (None when the evaluation failed).
    status : str
        "ok" or "failed" (crash, timeout, non-finite value).
    seeds : list of int
        The common random numbers used.
    wall_s : float
        Duration of the evaluation, seconds.
    elapsed_s : float
        Run time (over all sessions of the run) when the evaluation finished, seconds.
    worker : str
        Which worker ran it.
    kind : str
        "initial", "random", "acquisition", or "confirm-init" / "confirm-best" (the identity
        baseline and the recommendation evaluated on fresh seeds at the end of a run).
    error : str or None
        Why it failed.
    R_seeds : list of float
        R for each seed (their mean is R).
    gp : dict or None
        The GP hyperparameters fitted for the proposal (an acquisition's): a resumed run
        starts its next fit from them, as the uninterrupted run did.
    duplicates_skipped : int
        Acquisition optima passed over because their basis had been evaluated (or was in
        flight) at the same T (:data:`rbbo.optimizer.DUPLICATE_DISTANCE`); in the JSON only
        when not 0.
    """

    index: int
    basis: np.ndarray
    T: float
    R: float | None
    status: str = "ok"
    seeds: list[int] = field(default_factory=list)
    wall_s: float = 0.0
    elapsed_s: float = 0.0
    worker: str = ""
    kind: str = "acquisition"
    error: str | None = None
    R_seeds: list[float] = field(default_factory=list)
    gp: dict[str, float | None] | None = None
    duplicates_skipped: int = 0

    def __post_init__(self) -> None:
        # (from_json reads an edited line too: what is wrong is named there, with the line)
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)):
            raise ValueError(f"index must be an integer, got {self.index!r}")
        self.index = int(self.index)
        real = (int, float, np.integer, np.floating)
        if isinstance(self.T, bool) or not isinstance(self.T, real) or not 0 < self.T < math.inf:
            raise ValueError(f"T must be a positive number of seconds, got {self.T!r}")
        self.T = float(self.T)
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {list(STATUSES)}, got {self.status!r}")
        if self.kind not in KINDS:  # (another kind would be counted as a search evaluation)
            raise ValueError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")
        self.basis = np.asarray(self.basis, dtype=float)
        if self.basis.ndim != 2:
            raise ValueError(f"basis must be an (M, C) array, got shape {self.basis.shape}")
        if not np.all(np.isfinite(self.basis)):
            raise ValueError("basis holds non-finite values")
        if self.status == "ok" and (self.R is None or not math.isfinite(self.R)):
            raise ValueError(f"an 'ok' evaluation needs a finite R, got {self.R!r}")

    def to_json(self) -> str:
        record = asdict(self)
        record["basis"] = self.basis.tolist()
        record["seeds"] = [int(s) for s in self.seeds]
        record["R_seeds"] = [float(r) for r in self.R_seeds]
        if self.gp is None:
            del record["gp"]  # records without a fit read as before
        if not self.duplicates_skipped:
            del record["duplicates_skipped"]
        return json.dumps(record, allow_nan=False)

    @classmethod
    def from_json(cls, line: str) -> Evaluation:
        record = json.loads(line)
        if not isinstance(record, dict):
            raise ValueError(f"expected a JSON object, got {type(record).__name__}")
        names = set(cls.__dataclass_fields__)
        missing = {"index", "basis", "T", "R"} - set(record)
        if missing:
            raise ValueError(f"missing keys {sorted(missing)}")
        return cls(**{k: v for k, v in record.items() if k in names})


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _append_line(path: Path, line: str, end_partial: bool = False) -> None:
    """Append ``line`` and a newline durably (written, flushed and fsynced); with
    ``end_partial``, after a newline if the file ends inside a line."""
    with open(path, "a+b") as f:
        data = line.encode() + b"\n"
        if end_partial and f.seek(0, os.SEEK_END) > 0:
            f.seek(-1, os.SEEK_END)
            if f.read(1) != b"\n":
                data = b"\n" + data
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


# read once, at import (single-threaded): os.umask can only be read by setting it
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        # mkstemp's file is private (0600); a run's record is as readable as the history
        # file beside it, which open() creates under the umask
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _acquire_lock(path: Path) -> str:
    """Lock run directory ``path`` for this process (shared by its stores); the key to release."""
    key = os.path.realpath(path)
    held = _HELD_LOCKS.get(key)
    if held is not None:
        held[1] += 1
        return key
    fd = os.open(path / LOCK, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunDirectoryError(
                f"{path} is in use by another process (pid {owner}): wait for it to finish "
                "or stop it, then run the command again"
            ) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _HELD_LOCKS[key] = [fd, 1]
    return key


def _release_lock(key: str) -> None:
    held = _HELD_LOCKS.get(key)
    if held is None:
        return
    held[1] -= 1
    if held[1] == 0:
        del _HELD_LOCKS[key]
        os.close(held[0])  # releases the flock


class RunStore:
    """Reads and writes one run directory (see the module docstring).

    Use :meth:`create` for a new run and :meth:`open` for an existing one.
    """

    def __init__(self, path: str | os.PathLike, config: dict[str, Any]):
        self.path = Path(path)
        self.config = config
        self._lock_key: str | None = None

    def _lock(self) -> None:
        if self._lock_key is None:
            self._lock_key = _acquire_lock(self.path)

    def close(self) -> None:
        """Release this store's hold on the directory's lock (see the module docstring)."""
        if self._lock_key is not None:
            _release_lock(self._lock_key)
            self._lock_key = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown; the OS drops the lock
            pass

    @property
    def writable(self) -> bool:
        """Whether this store holds the directory's lock and may write (not a reader's)."""
        return self._lock_key is not None

    def _require_writer(self, what: str) -> None:
        """Refuse a write through a reader: it holds no lock, and the run may still be going
        in another process, which would then record the same evaluation indices."""
        if self._lock_key is None:
            raise RunDirectoryError(f"{self.path} was opened read-only; {what} (resume it to "
                                    "write: RBBO.resume without read_only)")  # fmt: skip

    @property
    def history_path(self) -> Path:
        return self.path / HISTORY

    @classmethod
    def create(cls, path: str | os.PathLike, config: dict[str, Any]) -> RunStore:
        """Start a new run directory (refuses one that already holds a run)."""
        path = Path(path)
        if (path / CONFIG).exists() or (path / HISTORY).exists():
            raise RunDirectoryError(
                f"{path} already holds a run; resume it (rbbo resume {path}) or choose "
                "another --out"
            )
        if path.exists() and not path.is_dir():
            raise RunDirectoryError(f"{path} exists and is not a directory")
        try:
            data = json.dumps(config, indent=2, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"config is not JSON-serialisable: {exc}") from exc
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunDirectoryError(f"cannot create the run directory {path}: {exc}") from exc
        store = cls(path, config)
        store._lock()
        if (path / CONFIG).exists():  # another process created it since the check above
            store.close()
            raise RunDirectoryError(f"{path} already holds a run; resume it (rbbo resume {path})")
        _atomic_write(path / CONFIG, (data + "\n").encode())
        (path / HISTORY).touch()
        _fsync_dir(path)
        return store

    @classmethod
    def open(cls, path: str | os.PathLike, *, repair: bool = True) -> RunStore:
        """Open an existing run directory.

        With ``repair`` (for resuming) a truncated last history line is cut with a warning
        (a whole evaluation that lacks only its newline is ended and kept); without (for
        reading a run that may still be writing) it is only skipped.
        """
        path = Path(path)
        if not path.is_dir():
            raise RunDirectoryError(f"{path} is not a directory")
        if not (path / CONFIG).is_file():
            raise RunDirectoryError(f"{path} is not an RBBO run directory (no {CONFIG})")
        try:
            config = json.loads((path / CONFIG).read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RunDirectoryError(f"{path / CONFIG} is corrupted: {exc}") from exc
        if not isinstance(config, dict):
            raise RunDirectoryError(f"{path / CONFIG} does not hold a JSON object")
        store = cls(path, config)
        if repair:
            store._lock()
            store._repair_tail()
        return store

    def _repair_tail(self) -> None:
        hist = self.history_path
        if not hist.exists():
            hist.touch()
            return
        data = hist.read_bytes()
        if not data:
            return
        cut = data.rfind(b"\n") + 1  # end of the last complete line
        tail = data[cut:]
        if not tail:
            return
        try:
            Evaluation.from_json(tail.decode("utf-8"))
        except (ValueError, TypeError, UnicodeDecodeError):
            pass  # cut short: dropped below
        else:
            # a whole evaluation whose write stopped before its newline: ended, not dropped
            with open(hist, "ab") as f:
                f.write(b"\n")
                f.flush()
                os.fsync(f.fileno())
            return
        warnings.warn(
            f"{hist}: dropped a truncated last line ({len(tail)} bytes, an evaluation that "
            f"was being written when the run stopped); kept in {HISTORY}.truncated",
            TruncatedHistoryWarning,
            stacklevel=3,
        )
        with open(self.path / f"{HISTORY}.truncated", "ab") as f:
            f.write(tail + b"\n")
        with open(hist, "r+b") as f:
            f.truncate(cut)
            f.flush()
            os.fsync(f.fileno())

    def update_config(self, changes: dict[str, Any]) -> None:
        """Merge ``changes`` into config.json, key by key (a dict value merges into the dict
        it replaces), and rewrite the file atomically: a kill leaves the old file or the new.

        Only a store that holds the directory's lock (one that writes) may do this.
        """
        self._require_writer("its config cannot change")
        config = json.loads(json.dumps(self.config))  # a deep copy: the old one if this fails
        for key, value in changes.items():
            if isinstance(value, dict) and isinstance(config.get(key), dict):
                config[key].update(value)
            else:
                config[key] = value
        try:
            data = json.dumps(config, indent=2, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"config is not JSON-serialisable: {exc}") from exc
        _atomic_write(self.path / CONFIG, (data + "\n").encode())
        self.config = config

    def append(self, evaluation: Evaluation) -> None:
        """Append one evaluation durably (written, flushed and fsynced before returning)."""
        self._require_writer("nothing can be recorded in it")
        # (a partial last line was cut back by open(): the history ends with a newline)
        _append_line(self.history_path, evaluation.to_json())

    def append_session(self, record: dict[str, Any]) -> None:
        """Append one session's record (:func:`rbbo.provenance.session_record`, or its end's:
        :func:`rbbo.provenance.session_end_record`) durably."""
        self._require_writer("nothing can be recorded in it")
        # nothing repairs this file: a partial line left by a kill is ended first
        _append_line(self.path / SESSIONS, json.dumps(record, sort_keys=True, allow_nan=False),
                     end_partial=True)  # fmt: skip

    def append_proposal(self, record: dict[str, Any]) -> None:
        """Append one proposal's record (a JSON object with ``index``) durably."""
        self._require_writer("nothing can be recorded in it")
        # a partial line left by a kill is ended first, and skipped when read
        _append_line(self.path / PROPOSALS, json.dumps(record, allow_nan=False),
                     end_partial=True)  # fmt: skip

    def proposals(self) -> list[dict[str, Any]]:
        """The proposals' records, in the order they were handed out (a run made before they
        were recorded has none); a partial line (a kill while writing) is left out."""
        path = self.path / PROPOSALS
        if not path.is_file():
            return []
        out: list[dict[str, Any]] = []
        lines = path.read_text(encoding="utf-8", errors="replace").split("\n")
        for number, line in enumerate(lines, start=1):
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # the torn end of a write a kill interrupted, or the final ""
            if not (isinstance(record, dict) and isinstance(record.get("index"), int)):
                raise RunDirectoryError(f"{path} line {number} is not a proposal: {line[:80]!r}")
            out.append(record)
        return out

    def sessions(self) -> list[dict[str, Any]]:
        """The sessions' records, oldest first (a run made before them has none), each with
        ``ended`` and ``status`` from its end's record where it has one (a session recorded
        before they were, killed outright, or still going has none); a partial line (a kill
        while writing) is left out."""
        path = self.path / SESSIONS
        if not path.is_file():
            return []
        out: list[dict[str, Any]] = []
        for line in path.read_text(encoding="utf-8", errors="replace").split("\n")[:-1]:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if not (isinstance(record, dict) and record.get("event") == "end"):
                out.append(record)
                continue
            # the lock keeps sessions apart: an end follows its own start (one whose start
            # line was torn ends nothing here, and stays in the file)
            last = out[-1] if out and isinstance(out[-1], dict) else {}
            if "ended" not in last and last.get("started") == record.get("started"):
                last.update({k: v for k, v in record.items() if k not in ("event", "started")})
        return out

    def history(self) -> list[Evaluation]:
        """All recorded evaluations, in the order they finished."""
        if not self.history_path.exists():
            # create() writes config.json, then an empty history: a run killed between the
            # two has recorded nothing, which a reader (report, status) sees as such
            return []
        out = []
        with open(self.history_path, encoding="utf-8", errors="strict") as f:
            try:
                lines = f.read().split("\n")
            except UnicodeDecodeError as exc:
                raise RunDirectoryError(f"{self.history_path} is not UTF-8 text: {exc}") from exc
        lines.pop()  # "" after the final newline, or a partial line still being written
        for number, line in enumerate(lines, start=1):
            try:
                out.append(Evaluation.from_json(line))
            except (ValueError, TypeError) as exc:
                # a partial last line was cut on open(); a complete line that does not parse
                # is corruption, not an interrupted write
                raise RunDirectoryError(
                    f"{self.history_path} line {number} is corrupted ({exc}): {line[:80]!r}"
                ) from exc
        return out

    def save_best(self, basis: np.ndarray) -> None:
        """Replace best_basis.npy (the recommendation) atomically."""
        self._require_writer("its best basis cannot change")
        buf = io.BytesIO()
        np.save(buf, np.asarray(basis, dtype=float))
        _atomic_write(self.path / BEST, buf.getvalue())

    def best_basis(self) -> np.ndarray:
        """The recommendation written when a session of the run last ended."""
        path = self.path / BEST
        if not path.is_file():
            raise RunDirectoryError(f"{self.path} has no {BEST} yet: no session of the run has "
                                    "ended (resume it with rbbo resume)")  # fmt: skip
        try:
            return np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise RunDirectoryError(f"{path} is corrupted: {exc}") from exc

    def write_summary(self, summary: dict[str, Any]) -> None:
        self._require_writer("its summary cannot change")
        data = json.dumps(summary, indent=2, sort_keys=True, allow_nan=False)
        _atomic_write(self.path / SUMMARY, (data + "\n").encode())

    def summary(self) -> dict[str, Any] | None:
        path = self.path / SUMMARY
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise RunDirectoryError(f"{path} is corrupted: {exc}") from exc
