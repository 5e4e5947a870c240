"""``rbbo``: optimise a control space B_c from the command line.

::

    rbbo optimize softrom_gym/CrossWalk-v0 --control-dim 3 --budget 30m --out runs/cross-walk
    rbbo resume runs/cross-walk               # after a kill: continues from history.jsonl
    rbbo confirm runs/cross-walk              # R_init and R* measured again, appended
    rbbo report runs/cross-walk               # table (Table I's columns) + convergence.png
    rbbo rollout runs/cross-walk --video cross.mp4
    rbbo reproduce --budget-per-benchmark 45m # the paper's results, into runs/reproduce

ENV_ID is a registered Gymnasium id (``CrossWalk-v0`` is short for
``softrom_gym/CrossWalk-v0``) or ``synthetic[:key=value,...]``, a Grassmann objective with a
known optimum that needs neither the simulator nor the controllers (keys: seed, noise, bias,
delay; see :mod:`rbbo.objective`). Bad arguments print one line naming the problem and exit
with status 2.
"""

# The command line, module by job: parser.py (the subcommands and their options), arguments.py
# (option types), errors.py (usage errors), objectives.py (ENV_ID and a run's objective),
# execution.py (running a search), one module per subcommand (optimize.py for optimize, resume
# and confirm; report.py, rollout.py, baselines.py; reproduce's is rbbo.reproduce.cli),
# signals.py (SIGTERM as Ctrl-C) and entry.py (main). The names below are re-exported so that
# ``rbbo.cli:main`` (the console script) and imports from rbbo.cli keep working; all but main
# are imported on first use: the modules behind them load numpy, scipy and the simulator's
# Python side, and ``main`` imports them itself, where Ctrl-C while they load is handled.
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .entry import main

if TYPE_CHECKING:
    from .arguments import merged_mpc_changes, mpc_changes_arg, parse_duration, rl_steps_arg
    from .baselines import _run_mppi_overrides as _run_mppi_overrides
    from .baselines import cmd_baselines
    from .entry import COMMANDS, cmd_reproduce
    from .errors import UsageError
    from .optimize import cmd_confirm, cmd_optimize, cmd_resume
    from .parser import _parser as _parser
    from .report import cmd_report
    from .rollout import _measured_from as _measured_from
    from .rollout import cmd_rollout
    from .signals import _terminate_as_interrupt as _terminate_as_interrupt

# a re-exported name -> the module of this package that defines it
_HOMES = {
    "merged_mpc_changes": "arguments", "mpc_changes_arg": "arguments",
    "parse_duration": "arguments", "rl_steps_arg": "arguments",
    "_run_mppi_overrides": "baselines", "cmd_baselines": "baselines",
    "COMMANDS": "entry", "cmd_reproduce": "entry", "UsageError": "errors",
    "cmd_confirm": "optimize", "cmd_optimize": "optimize", "cmd_resume": "optimize",
    "_parser": "parser", "cmd_report": "report", "_measured_from": "rollout",
    "cmd_rollout": "rollout", "_terminate_as_interrupt": "signals",
}  # fmt: skip


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "COMMANDS",
    "UsageError",
    "cmd_baselines",
    "cmd_confirm",
    "cmd_optimize",
    "cmd_report",
    "cmd_reproduce",
    "cmd_resume",
    "cmd_rollout",
    "main",
    "merged_mpc_changes",
    "mpc_changes_arg",
    "parse_duration",
    "rl_steps_arg",
]
