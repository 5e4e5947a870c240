"""How REPORT.md words what the record says: numbers, machines, settings, progress, links.

:func:`_num` prints a number or "-"; :func:`_machine` names the machines the sessions ran on,
:func:`_session_values` a setting over the sessions and :func:`_told_in_order` which sessions
told results in proposal order (``--deterministic``); :func:`_relink` rewrites the report's
links for a copy in another folder (``--report``); :func:`_progress_lines` says which stages
have not finished.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any


def _num(x: float | None, spec: str = ".4g") -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:{spec}}"


def _machine(sessions: list[dict[str, Any]] | None = None) -> str:
    """The machines the sessions ran on, as recorded (since 2026-12-02): a session that
    recorded none is counted as such, not taken to have run where the report is written."""
    from ..provenance import machine_description

    if not sessions:
        return machine_description()
    seen = " / ".join(dict.fromkeys(s["machine"] for s in sessions if s.get("machine")))
    missing = sum(not s.get("machine") for s in sessions)
    if not missing:
        return seen
    unrecorded = f"{missing} session{'s' if missing > 1 else ''} whose machine was not recorded"
    return f"{seen} (and {unrecorded})" if seen else f"a machine not recorded ({unrecorded})"


def _session_values(sessions: list[dict[str, Any]], key: str, current: float) -> str:
    """A setting that may change between sessions, as the report prints it: one value, or
    each distinct value in the order the sessions used them."""
    values = list(dict.fromkeys(s.get(key, current) for s in sessions)) or [current]
    if key.endswith("_s"):
        return " / ".join(f"{v / 60:g}" for v in values)
    return " / ".join(f"{v:g}" for v in values)


def _told_in_order(sessions: list[dict[str, Any]], current: bool) -> str:
    """Which sessions told the optimisation runs' results in proposal order
    (``--deterministic``), as the report says it after the workers."""
    flags = [bool(s.get("deterministic", False)) for s in sessions] or [current]
    if not any(flags):
        return ""
    if all(flags):
        return " (results told in proposal order)"
    which = ", ".join(str(i + 1) for i, flag in enumerate(flags) if flag)
    return f" (results told in proposal order in session{'s' if ',' in which else ''} {which})"


def _relink(lines: list[str], out: Path, folder: Path) -> list[str]:
    """Rewrite the report's links (relative to ``out``) to be relative to ``folder``."""
    prefix = Path(os.path.relpath(out.resolve(), folder.resolve())).as_posix()
    if prefix == ".":
        return lines
    return [re.sub(r"\]\((?![a-z]+:)", f"]({prefix}/", line) for line in lines]


def _progress_lines(progress: dict[str, tuple[int, int]]) -> list[str]:
    """What the record does not hold yet: stages with no part finished, and stages with
    some. (A run still searching or not yet confirmed is not finished; the sections below
    show it with what it has, its R* as "-" until confirmed.)"""
    missing = [stage for stage, (done, n) in progress.items() if n and done == 0]
    partial = [f"{stage} ({done} of {n})" for stage, (done, n) in progress.items()
               if 0 < done < n]  # fmt: skip
    lines = []
    if missing:
        lines += [f"No part finished yet: {', '.join(missing)}.", ""]
    if partial:
        lines += [f"Under way (parts finished of those planned): {', '.join(partial)}.", ""]
    return lines
