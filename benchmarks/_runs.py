"""Shared by the benchmark scripts that study a finished rbbo run's recommendation."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np


def run_objective(run: Path) -> tuple[Any, float, np.ndarray, dict]:
    """The run's objective as its config.json records it, T_max, its recommended basis
    (best_basis.npy) and its rbbo settings."""
    from rbbo.objective import make_objective

    config = json.loads((run / "config.json").read_text())
    settings = config["rbbo"]
    objective = make_objective(config["objective"], settings["sim_dim"], settings["control_dim"])
    return objective, float(settings["t_max"]), np.load(run / "best_basis.npy"), settings


def random_rotations(basis: np.ndarray, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n`` bases B Q of span(B), Q drawn from the Haar measure on O(C)."""
    c = basis.shape[1]
    out = []
    for _ in range(n):
        q, r = np.linalg.qr(rng.standard_normal((c, c)))
        out.append(basis @ (q * np.sign(np.diag(r))))
    return out
