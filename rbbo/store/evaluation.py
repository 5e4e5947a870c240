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
        if self.status == "ok" and (self.R is None or not math.isfinite(self.R)):
            raise ValueError(f"an 'ok' evaluation needs a finite R, got {self.R!r}")

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
