"""``rbbo report``: the table of one or more runs, each run's convergence plot, and where its
best basis is.

Each DIR is reported on its own: one that cannot be read is named in a one-line error and the
others are still reported; the exit status is then non-zero (2 for a run directory that cannot
be used, 1 for a read the system refused), as for a single DIR.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .errors import UsageError


def cmd_report(args) -> int:
    from ..report import format_table, load, plot_convergence, report_row
    from ..store import BEST, RunDirectoryError

    if args.png is not None and len(args.run_dirs) > 1:
        raise UsageError("--png names one plot: give one DIR")
    rows = []
    if args.png is not None:
        # the suffix picks the format: one matplotlib cannot write would fail after the table
        # was computed, and none at all would write PNG.png, not the file named
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        formats = sorted(FigureCanvasAgg.get_supported_filetypes())
        if args.png.suffix.lower().lstrip(".") not in formats:
            raise UsageError(f"--png {args.png}: the file name must end in one of "
                             f"{', '.join('.' + f for f in formats)}")  # fmt: skip
        try:
            args.png.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"cannot write --png {args.png}: {exc}") from exc
    failed: list[Path] = []
    code = 0
    for run_dir in args.run_dirs:
        try:
            opt = load(run_dir)
            rows.append(report_row(opt))
        except (RunDirectoryError, OSError) as exc:
            # each run is reported on its own: one that cannot be read is named, and the
            # others are still reported (a corrupted run among many must not hide them)
            failed.append(run_dir)
            # (exit statuses as main() gives them: 2 for a run directory that cannot be
            # used, 1 for a read the system refused)
            code = max(code, 2 if isinstance(exc, RunDirectoryError) else 1)
            message = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
            if str(run_dir) not in message:
                message = f"{run_dir}: {message}"
            print(f"rbbo: error: {message}", file=sys.stderr)
            continue
        path = args.png or Path(run_dir) / "convergence.png"
        try:
            png = plot_convergence(opt, path)
        except OSError as exc:
            if args.png is not None:  # the file asked for
                raise UsageError(f"cannot write the plot {path}: {exc}") from exc
            # the default place, in a run directory that may be read-only (an archived copy):
            # the table is what is read from it, and still printed
            print(f"rbbo: warning: cannot write the plot {path}: {exc} (--png FILE writes "
                  "it elsewhere)", file=sys.stderr)  # fmt: skip
            png = None
        # the recommendation (R*'s B_c) is written when a session finishes, never by a report
        best = Path(run_dir) / BEST
        assert opt.store is not None  # (load opens the run's store)
        if best.is_file():
            found = f"best basis {best}"
        elif opt.store.summarised_best_index() is not None:
            # a session finished and wrote it with summary.json: it was deleted since
            found = (f"{BEST} is missing (written when a session finished; rbbo resume "
                     f"{run_dir} writes it again)")  # fmt: skip
        else:
            found = f"no {BEST} yet (no session has finished: rbbo resume {run_dir})"
        plot = "no plot" if png is None else f"plot {png}"
        print(f"{run_dir}: {plot}, {found}", file=sys.stderr)
    if rows:
        print(format_table(rows))
    if failed and len(args.run_dirs) > 1:
        # the errors may have scrolled past the table: the count closes the report
        print(f"rbbo: error: {len(failed)} of {len(args.run_dirs)} run directories could not "
              "be reported", file=sys.stderr)  # fmt: skip
    return code
