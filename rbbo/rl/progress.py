"""A job's folder: its claim (``run.json``) and its progress log (``progress.jsonl``).

:func:`_claim` refuses a folder that trained another env, basis or seed;
:func:`_read_progress` reads the append-only log (mending a last line torn by a kill);
:func:`_wall_at_checkpoint` is the training wall time a resumed job continues from.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..store import _atomic_write, _make_dirs


def _claim(folder: Path, meta: dict) -> None:
    """Claim ``folder`` for the run ``meta`` describes, or refuse it.

    Parameters
    ----------
    folder : Path
        The job's folder (made if missing); its ``run.json`` is the claim, written atomically.
    meta : dict
        What the job trains: env, env keyword arguments, algorithm, seed and basis.

    Raises
    ------
    RunDirectoryError
        ``run.json`` is another run's, or unreadable (torn by a kill or a power loss while an
        older version wrote it in place).
    """
    from ..store import RunDirectoryError

    _make_dirs(folder)
    path = folder / "run.json"
    text = json.dumps(meta)  # floats round-trip exactly: the basis compares bit for bit
    if not path.is_file():
        _atomic_write(path, (text + "\n").encode())
        return
    try:
        claimed = json.loads(path.read_text())
    except ValueError as exc:
        # written in place before it was written atomically, so a kill or power loss could
        # tear it: which run the folder's checkpoints are of is then the user's to say
        raise RunDirectoryError(
            f"{path} is unreadable, torn by a kill or power loss while it was written "
            f"({type(exc).__name__}: {exc}); if {folder} trained this env, basis and seed, "
            f"delete {path.name} to continue it, else choose another --out"
        ) from exc
    if claimed != json.loads(text):
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
        # the rows kept are rows already on disk: the mended file must not lose them to a
        # power loss after the rename
        _atomic_write(log, "".join(json.dumps(r) + "\n" for r in rows).encode())
    return rows


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
