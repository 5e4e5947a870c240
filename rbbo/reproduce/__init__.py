"""``rbbo reproduce``: the paper's results section, run and written up from one command.

Table I (RBBO with BOCA against the identity basis on every benchmark, R_init and R* on fresh
seeds with 95 % intervals), Table I's bases at a larger M (transfer), BO against BOCA, the
cross walking along eight directions, the direction-perturbation study, the two studies of C
and the RL baselines, into one resumable directory with a
REPORT.md whose every number is read from the runs (see :mod:`.runner`).
"""

from .plan import BENCHMARKS, PAPER_DIRECTIONS, PAPER_TABLE1, ReproducePlan
from .runner import reproduce
from .tables import confidence_interval, format_markdown, parse_markdown, table_row

__all__ = [
    "BENCHMARKS",
    "PAPER_DIRECTIONS",
    "PAPER_TABLE1",
    "ReproducePlan",
    "confidence_interval",
    "format_markdown",
    "parse_markdown",
    "reproduce",
    "table_row",
]
