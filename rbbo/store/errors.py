"""The run directory's exceptions.

:class:`RunDirectoryError`: a run directory is missing, not a run directory or corrupted (also
raised when another process writes it, or for a write through a read-only store);
:class:`TruncatedHistoryWarning`: a torn last line of history.jsonl was cut when the run was
opened to resume.
"""


class RunDirectoryError(ValueError):
    """A run directory is missing, not a run directory, or corrupted."""


class TruncatedHistoryWarning(UserWarning):
    """The last line of history.jsonl was incomplete (a write was interrupted) and dropped."""
