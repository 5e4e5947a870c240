"""One record of history.jsonl: :class:`Evaluation`, its validation and its JSON form.

``STATUSES`` and ``KINDS`` are the values an evaluation's ``status`` and ``kind`` may take;
:meth:`Evaluation.from_json` reads a line (an edited one too: what is wrong is named).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

STATUSES = ("ok", "failed")
# Evaluation.kind: how the proposal was made (rbbo.config.CONFIRM_KINDS are the last two)
KINDS = ("initial", "random", "acquisition", "confirm-init", "confirm-best")


def _number_or_none(value: object) -> bool:
    """Whether ``value`` is None or a real number (not a bool): a GP hyperparameter's."""
    return value is None or (
        not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
    )


def _numbers(name: str, values, kinds: tuple[type, ...], what: str, cast: type) -> list:
    """``values``, a list (or tuple) of ``kinds`` (no bools), as a list of ``cast``; else
    ValueError naming the field ``name``."""
    if not isinstance(values, (list, tuple)) or any(
        isinstance(v, bool) or not isinstance(v, kinds) for v in values
    ):
        raise ValueError(f"{name} must be a list of {what}, got {values!r}")
    return [cast(v) for v in values]


@dataclass
class Evaluation:
    """One finished evaluation of the objective R(B_c, T).

    Attributes
    ----------
    index : int
        Order in which the evaluation was proposed (unique within the run).
    basis : (M, C) ndarray
        The control basis B_c evaluated.
    T : float
        Trajectory length (fidelity), seconds.
    R : float or None
        Mean reward over ``seeds`` (None when the evaluation failed).
    status : str
        "ok" or "failed" (crash, timeout, non-finite value).
    seeds : list of int
        The common random numbers used.
    wall_s : float
        Duration of the evaluation, seconds.
    elapsed_s : float
        Run time (over all sessions of the run) when the evaluation finished, seconds.
    worker : str
        Which worker ran it.
    kind : str
        "initial", "random", "acquisition", or "confirm-init" / "confirm-best" (the identity
        baseline and the recommendation evaluated on fresh seeds at the end of a run).
    error : str or None
        Why it failed.
    R_seeds : list of float
        R for each seed (their mean is R).
    gp : dict or None
        The GP hyperparameters fitted for the proposal (an acquisition's): a resumed run
        starts its next fit from them, as the uninterrupted run did.
    duplicates_skipped : int
        Acquisition optima passed over because their basis had been evaluated (or was in
        flight) at the same T (:data:`rbbo.proposing.DUPLICATE_DISTANCE`); in the JSON only
        when not 0.
    """

    index: int
    basis: np.ndarray
    T: float
    R: float | None
    status: str = "ok"
    seeds: list[int] = field(default_factory=list)
    wall_s: float = 0.0
    elapsed_s: float = 0.0
    worker: str = ""
    kind: str = "acquisition"
    error: str | None = None
    R_seeds: list[float] = field(default_factory=list)
    gp: dict[str, float | None] | None = None
    duplicates_skipped: int = 0

    def __post_init__(self) -> None:
        # (from_json reads an edited line too: what is wrong is named there, with the line)
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)):
            raise ValueError(f"index must be an integer, got {self.index!r}")
        self.index = int(self.index)
        real = (int, float, np.integer, np.floating)
        if isinstance(self.T, bool) or not isinstance(self.T, real) or not 0 < self.T < math.inf:
            raise ValueError(f"T must be a positive number of seconds, got {self.T!r}")
        self.T = float(self.T)
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {list(STATUSES)}, got {self.status!r}")
        if self.kind not in KINDS:  # (another kind would be counted as a search evaluation)
            raise ValueError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")
        self.basis = np.asarray(self.basis, dtype=float)
        if self.basis.ndim != 2:
            raise ValueError(f"basis must be an (M, C) array, got shape {self.basis.shape}")
        if not np.all(np.isfinite(self.basis)):
            raise ValueError("basis holds non-finite values")
        if self.R is not None:
            if isinstance(self.R, bool) or not isinstance(self.R, real):
                raise ValueError(f"R must be a number or null, got {self.R!r}")
            self.R = float(self.R)
        if self.status == "ok" and (self.R is None or not math.isfinite(self.R)):
            raise ValueError(f"an 'ok' evaluation needs a finite R, got {self.R!r}")
        # The rest is read by report, resume and confirm (sums, formats, comparisons): an
        # edited value of another type is named here, not met there as a TypeError.
        for name in ("wall_s", "elapsed_s"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, real)
                    or not 0 <= value < math.inf):  # fmt: skip
                raise ValueError(f"{name} must be a number of seconds >= 0, got {value!r}")
            setattr(self, name, float(value))
        self.seeds = _numbers("seeds", self.seeds, (int, np.integer), "integers", int)
        self.R_seeds = _numbers("R_seeds", self.R_seeds, real, "finite numbers", float)
        if not all(math.isfinite(r) for r in self.R_seeds):
            raise ValueError(f"R_seeds must be a list of finite numbers, got {self.R_seeds!r}")
        if not isinstance(self.worker, str):
            raise ValueError(f"worker must be a string, got {self.worker!r}")
        if self.error is not None and not isinstance(self.error, str):
            raise ValueError(f"error must be a string or null, got {self.error!r}")
        if self.gp is not None and not (
            isinstance(self.gp, dict) and all(map(_number_or_none, self.gp.values()))
        ):
            raise ValueError(f"gp must be null or an object of numbers, got {self.gp!r}")
        if (isinstance(self.duplicates_skipped, bool)
                or not isinstance(self.duplicates_skipped, (int, np.integer))
                or self.duplicates_skipped < 0):  # fmt: skip
            raise ValueError("duplicates_skipped must be an integer >= 0, got "
                             f"{self.duplicates_skipped!r}")  # fmt: skip
        self.duplicates_skipped = int(self.duplicates_skipped)

    def to_json(self) -> str:
        record = asdict(self)
        record["basis"] = self.basis.tolist()
        record["seeds"] = [int(s) for s in self.seeds]
        record["R_seeds"] = [float(r) for r in self.R_seeds]
        if self.gp is None:
            del record["gp"]  # records without a fit read as before
        if not self.duplicates_skipped:
            del record["duplicates_skipped"]
        return json.dumps(record, allow_nan=False)

    @classmethod
    def from_json(cls, line: str) -> Evaluation:
        record = json.loads(line)
        if not isinstance(record, dict):
            raise ValueError(f"expected a JSON object, got {type(record).__name__}")
        names = set(cls.__dataclass_fields__)
        missing = {"index", "basis", "T", "R"} - set(record)
        if missing:
            raise ValueError(f"missing keys {sorted(missing)}")
        return cls(**{k: v for k, v in record.items() if k in names})
