"""Running a search for ``rbbo optimize`` and ``rbbo resume``: the executor, the progress
bar, and the run itself, ending in its table and convergence plot (or a resume hint when
interrupted).
"""

from __future__ import annotations

import math
import sys

from .errors import UsageError, _bad_input


def _progress(opt, max_evaluations, budget_s, enabled: bool):
    """A tqdm bar: evaluations, best R at T_max, time left; returns (callback, close)."""
    if not enabled:
        return None, lambda: None
    from tqdm import tqdm

    done = len(opt.evaluations)
    bar = tqdm(total=max_evaluations, initial=done, unit="eval", dynamic_ncols=True,
               file=sys.stderr, desc="rbbo")  # fmt: skip
    best = [max((e.R for e in opt.evaluations
                 if e.status == "ok" and math.isclose(e.T, opt.config.t_max)),
                default=-math.inf)]  # fmt: skip

    def callback(evaluation) -> None:
        if evaluation.kind.startswith("confirm"):
            bar.set_description("rbbo (confirming R_init, R*)")
            return
        bar.update(1)
        if evaluation.status == "ok" and math.isclose(evaluation.T, opt.config.t_max):
            best[0] = max(best[0], evaluation.R)
        parts = [f"best R {best[0]:.4g}" if math.isfinite(best[0]) else "best R -"]
        if budget_s is not None:
            left = max(budget_s - opt.elapsed_s, 0.0)
            parts.append(f"{int(left // 60)}m{int(left % 60):02d}s left")
        bar.set_postfix_str(", ".join(parts))

    return callback, bar.close


def _make_executor(objective, execution: dict):
    """The run's executor, built before anything is written (a missing Ray or a wrong
    address is then a usage error that leaves no run directory behind)."""
    from ..executors import make_executor

    if execution["executor"] == "serial" and execution["workers"] != 1:
        raise UsageError(f"--executor serial runs one evaluation at a time, in this "
                         f"process; --workers {execution['workers']} needs --executor "
                         "process (or ray)")  # fmt: skip

    with _bad_input():
        return make_executor(execution["executor"], objective, execution["workers"],
                             execution["timeout_s"], execution.get("address"))  # fmt: skip


def _execute(opt, executor, max_evaluations, budget_s, progress: bool,
             deterministic: bool = False) -> int:  # fmt: skip
    from ..optimizer import EvaluationsFailing
    from ..report import format_table, plot_convergence, report_row
    from ..store import BEST

    callback, close = _progress(opt, max_evaluations, budget_s, progress)
    # None is "no limit" here; to run() it would mean "the limit stored in the config"
    unlimited = math.inf
    try:
        opt.run(executor=executor,
                max_evaluations=unlimited if max_evaluations is None else max_evaluations,
                budget_s=unlimited if budget_s is None else budget_s,
                callback=callback, deterministic=deterministic)  # fmt: skip
    except KeyboardInterrupt:
        close()
        executor.shutdown(wait=False)
        print(f"\ninterrupted; continue with: rbbo resume {opt.store.path}", file=sys.stderr)
        return 130
    except EvaluationsFailing:  # reported by main()
        close()
        executor.shutdown(wait=False)
        raise
    except OSError as exc:
        # a write the system refused (a full disk, a directory made read-only under the run):
        # the evaluations recorded before it are kept, and a resume goes on from them
        close()
        executor.shutdown(wait=False)
        print(f"rbbo: error: {opt.store.path}: {exc}; the run stopped (what it recorded is "
              f"kept: free space or fix the directory, then rbbo resume {opt.store.path})",
              file=sys.stderr)  # fmt: skip
        return 1
    close()
    executor.shutdown()
    print(format_table([report_row(opt)]))
    path = opt.store.path / "convergence.png"
    try:
        png = plot_convergence(opt, path)
    except OSError as exc:
        # the run has finished and recorded its result: only the picture is missing
        print(f"rbbo: warning: cannot write the plot {path}: {exc} (the run is recorded; "
              f"rbbo report {opt.store.path} --png FILE draws it)", file=sys.stderr)  # fmt: skip
        plot = "none"
    else:
        plot = png.name
    # (no best_basis.npy is written when no evaluation succeeded)
    best = BEST if (opt.store.path / BEST).is_file() else "none yet"
    print(f"run directory: {opt.store.path}  (best basis: {best}, plot: {plot})")
    return 0
