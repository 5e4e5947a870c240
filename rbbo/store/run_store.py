"""The run directory itself: :class:`RunStore` (see :mod:`rbbo.store` for its layout).

Its config, the append-only history, proposals and sessions, the best basis and the summary;
creating a run, opening one to resume (cutting a torn last history line) or to read, and the
lock that keeps a second process from writing it.
"""

from __future__ import annotations

import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .._warn import outside_stacklevel
from .errors import RunDirectoryError, TruncatedHistoryWarning
from .evaluation import Evaluation
from .files import _append_line, _atomic_write, _fsync_dir, _make_dirs
from .lock import _acquire_lock, _release_lock

CONFIG = "config.json"
HISTORY = "history.jsonl"
BEST = "best_basis.npy"
SUMMARY = "summary.json"
SESSIONS = "sessions.jsonl"
PROPOSALS = "proposals.jsonl"


class RunStore:
    """Reads and writes one run directory (see the module docstring).

    Use :meth:`create` for a new run and :meth:`open` for an existing one.
    """

    def __init__(self, path: str | os.PathLike, config: dict[str, Any]):
        self.path = Path(path)
        self.config = config
        self._lock_key: str | None = None
        self._closed = False  # (a writer that let go of its lock, told from a reader)

    def _lock(self) -> None:
        if self._lock_key is None:
            self._lock_key = _acquire_lock(self.path)

    def close(self) -> None:
        """Release this store's hold on the directory's lock (see the module docstring)."""
        if self._lock_key is not None:
            _release_lock(self._lock_key)
            self._lock_key = None
            self._closed = True

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
            how = "was closed" if self._closed else "was opened read-only"
            raise RunDirectoryError(f"{self.path} {how}; {what} (resume it to "
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
            _make_dirs(path)
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
            # (`rbbo resume` of a reproduction's folder is a natural first guess)
            whose = (f"; it is an rbbo reproduce directory: rerun rbbo reproduce --out {path} "
                     f"to go on, or name one of its runs, {path / 'runs'}/<run>"
                     if (path / "reproduce.json").is_file() else "")  # fmt: skip
            raise RunDirectoryError(f"{path} is not an RBBO run directory (no {CONFIG}){whose}")
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
            stacklevel=outside_stacklevel(),
        )
        with open(self.path / f"{HISTORY}.truncated", "ab") as f:
            f.write(tail + b"\n")
        with open(hist, "r+b") as f:
            f.truncate(cut)
            f.flush()
            os.fsync(f.fileno())

    def update_config(self, changes: dict[str, Any], *, merge: bool = True) -> None:
        """Merge ``changes`` into config.json, key by key (a dict value merges into the dict
        it replaces; ``merge=False``: replaces it whole), and rewrite the file atomically: a
        kill leaves the old file or the new.

        Only a store that holds the directory's lock (one that writes) may do this.
        """
        self._require_writer("its config cannot change")
        config = json.loads(json.dumps(self.config))  # a deep copy: the old one if this fails
        for key, value in changes.items():
            if merge and isinstance(value, dict) and isinstance(config.get(key), dict):
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
        """The recommendation written when a session of the run last finished (see
        :mod:`rbbo.store`: an interrupted session writes none)."""
        path = self.path / BEST
        if not path.is_file():
            index = self.summarised_best_index()
            if index is not None:  # (written with the summary, then deleted or lost)
                raise RunDirectoryError(f"{path} is missing: it was written (evaluation "
                                        f"{index}'s basis) when a session of the run finished; "
                                        f"rbbo resume {self.path} writes it again")  # fmt: skip
            raise RunDirectoryError(f"{self.path} has no {BEST} yet: no session of the run has "
                                    "finished (resume it with rbbo resume)")  # fmt: skip
        try:
            basis = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:  # (EOFError: an empty file)
            raise RunDirectoryError(f"{path} is corrupted: {exc}") from exc
        settings = self.config.get("rbbo")  # (an RBBO run's (M, C); a bare store has none)
        dims = (settings.get("sim_dim"), settings.get("control_dim")) if isinstance(
            settings, dict) else (None, None)  # fmt: skip
        expected = dims if all(isinstance(d, int) for d in dims) else None
        if (
            basis.ndim != 2
            or basis.dtype.kind != "f"
            or not np.all(np.isfinite(basis))
            or (expected is not None and basis.shape != expected)
        ):
            raise RunDirectoryError(
                f"{path} is corrupted: it holds a {basis.dtype} array of shape {basis.shape}, "
                f"not a finite B_c of shape {expected or '(M, C)'}"
            )
        return basis

    def summarised_best_index(self) -> int | None:
        """The evaluation summary.json names as the recommendation, whose basis was written to
        best_basis.npy with it when a session finished; None without a readable summary or
        without a recommendation in it (no evaluation had succeeded)."""
        try:
            summary = self.summary()
        except RunDirectoryError:
            return None
        index = (summary or {}).get("best_index")
        return index if isinstance(index, int) and not isinstance(index, bool) else None

    def write_summary(self, summary: dict[str, Any]) -> None:
        self._require_writer("its summary cannot change")
        data = json.dumps(summary, indent=2, sort_keys=True, allow_nan=False)
        _atomic_write(self.path / SUMMARY, (data + "\n").encode())

    def summary(self) -> dict[str, Any] | None:
        """summary.json (None before a session has written one); one that holds no JSON
        object raises :class:`RunDirectoryError`."""
        path = self.path / SUMMARY
        if not path.is_file():
            return None
        try:
            summary = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:  # (torn text, or bytes)
            raise RunDirectoryError(f"{path} is corrupted: {exc}") from exc
        if not isinstance(summary, dict):  # (a hand edit: its readers look keys up in it)
            raise RunDirectoryError(f"{path} is corrupted: it holds no JSON object")
        return summary
