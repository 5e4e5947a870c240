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
                          of the run finishes, or stops because its evaluations keep failing;
                          one interrupted or ended by an error writes none, so a run that
                          never finished a session has none)
    DIR/summary.json      R_init, R* and the rest of the report (written with it)
    DIR/sessions.jsonl    one JSON object when a session of the run (search or confirmation)
                          submits its first evaluation (a session that evaluates nothing
                          records nothing): when, the code (version, git commit) and the
                          machine (CPU, kernel set, numpy/scipy) it runs on; and one when it
                          ends
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
indices. So is a second writer in the same process (a second ``RBBO.resume`` beside an open
one), until the first is closed. Readers (``repair=False``) take no lock.
"""

# The run directory, module by job: errors.py (RunDirectoryError, TruncatedHistoryWarning),
# evaluation.py (Evaluation: one record of history.jsonl, its validation and its JSON form),
# files.py (durable writes: fsynced appends, atomic replacement), lock.py (one writer per run
# directory: its flock, and one store of this process holding it) and run_store.py (RunStore: the
# directory's files, created, opened, resumed, read and written). The names below are
# re-exported so that imports from rbbo.store keep working.
from .errors import RunDirectoryError, TruncatedHistoryWarning
from .evaluation import KINDS as KINDS
from .evaluation import STATUSES, Evaluation
from .files import _UMASK as _UMASK
from .files import _append_line as _append_line
from .files import _atomic_savefig as _atomic_savefig
from .files import _atomic_write as _atomic_write
from .files import _fsync_dir as _fsync_dir
from .files import _make_dirs as _make_dirs
from .lock import _HELD_LOCKS as _HELD_LOCKS
from .lock import LOCK as LOCK
from .lock import _acquire_lock as _acquire_lock
from .lock import _release_lock as _release_lock
from .run_store import BEST as BEST
from .run_store import CONFIG as CONFIG
from .run_store import HISTORY as HISTORY
from .run_store import PROPOSALS as PROPOSALS
from .run_store import SESSIONS as SESSIONS
from .run_store import SUMMARY as SUMMARY
from .run_store import RunStore

__all__ = [
    "STATUSES",
    "Evaluation",
    "RunDirectoryError",
    "RunStore",
    "TruncatedHistoryWarning",
]
