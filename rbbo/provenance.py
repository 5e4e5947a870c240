"""What code ran a run, and on what machine: the record of each session of a run directory
(``DIR/sessions.jsonl``) and of a reproduction (``reproduce.json``), so that every number a
report prints names its code and machine."""

from __future__ import annotations

import os
import platform
import subprocess
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

__all__ = [
    "cpu_model",
    "machine_description",
    "session_end_record",
    "session_record",
    "source_version",
]

# The code that decides a run's numbers (a record committed inside the checkout, its log, its
# histories, is not code).
_CODE_PATHS = ("cpp_sim", "softrom_gym", "controllers", "rbbo", "pyproject.toml", "CMakeLists.txt")


def source_version() -> str:
    """What code ran: the package version, and the git commit of the source tree when it is
    a checkout (``+dirty`` when its tracked code differs from it), so a report names its code."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        text = f"softrom {version('softrom')}"
    except PackageNotFoundError:
        text = "softrom (not installed)"
    root = Path(__file__).resolve().parents[1]
    if not ((root / ".git").exists() and (root / "pyproject.toml").is_file()):
        # an installed copy (site-packages), perhaps inside another project's checkout,
        # whose commit is not this code's
        return text
    try:
        run: dict[str, Any] = {
            "cwd": root,
            "capture_output": True,
            "text": True,
            "timeout": 10,
            "check": True,
        }
        commit = subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], **run).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                                *_CODE_PATHS], **run).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return text
    if not commit:
        return text
    return f"{text}, git {commit}{'+dirty' if dirty else ''}{_stale_build(root)}"


def _stale_build(root: Path) -> str:
    """``", compiled core older than its sources"`` when an editable install's extension
    module predates a C++ source of the checkout (the commit would then misname the physics
    that ran), else ``""``."""
    try:
        from softrom_gym import simulator_build

        built = Path(simulator_build()["core"]).stat().st_mtime
        sources = [*(root / "cpp_sim" / "src").glob("*.[ch]*"), root / "CMakeLists.txt"]
        newest = max(p.stat().st_mtime for p in sources if p.is_file())
    except (ImportError, OSError, ValueError):
        return ""
    return ", compiled core older than its sources" if newest > built else ""


def cpu_model() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in ("model name", "Model", "Hardware") and value.strip():
                    return " ".join(value.split())
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def machine_description() -> str:
    """The machine a session runs on, as a report prints it: CPU model, the CPUs this process
    may use, the OS, and the simulator's SIMD kernel set (round-off differs between sets)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    text = f"{cpu_model()}, {cpus} CPUs, {platform.system()}"
    try:
        from softrom_gym import simulator_build

        return f"{text}, {simulator_build()['kernels']} kernels"
    except ImportError:
        return text


def session_record(command: str) -> dict[str, Any]:
    """One session of a run: when it started, what it did, the code, the machine, and the
    numerical libraries beneath the subspace (their builds move round-off, see README)."""
    import numpy
    import scipy

    return {
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "command": command,
        "source": source_version(),
        "machine": machine_description(),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
    }


SESSION_ENDS = ("finished", "interrupted", "error")


def session_end_record(started: str, status: str, error: str | None = None) -> dict[str, Any]:
    """The end of the session that started at ``started`` (its :func:`session_record`'s stamp):
    when, and how it ended, ``status`` being "finished", "interrupted" (Ctrl-C, SIGTERM) or
    "error" (``error`` says which). A session killed outright (SIGKILL, a lost machine) has
    none."""
    if status not in SESSION_ENDS:
        raise ValueError(f"status must be one of {list(SESSION_ENDS)}, got {status!r}")
    record = {"event": "end", "started": started, "status": status,
              "ended": datetime.now(timezone.utc).isoformat(timespec="seconds")}  # fmt: skip
    if error is not None:
        record["error"] = error
    return record
