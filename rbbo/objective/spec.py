"""Objective specs: what ``rbbo optimize ENV_ID`` turns into an objective, and back.

:func:`parse_objective_spec` turns an ENV_ID argument into a spec dict (what a run's
config.json stores); :func:`make_objective` builds the objective a spec describes, checking
a stored one against the simulator and planner as they are now; :func:`objective_differences`
says where an objective differs from the one a run recorded.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from .env import EnvObjective
from .synthetic import SyntheticObjective

_SYNTHETIC_KEYS = {"seed": int, "noise": float, "bias": float, "delay": float}


def parse_objective_spec(env_id: str) -> dict[str, Any]:
    """Turn an ENV_ID argument into an objective spec dict (see the module docstring)."""
    if not isinstance(env_id, str) or not env_id:
        raise ValueError(f"ENV_ID must be a non-empty string, got {env_id!r}")
    if env_id == "synthetic" or env_id.startswith("synthetic:"):
        spec: dict[str, Any] = {"kind": "synthetic"}
        body = env_id.partition(":")[2]
        for item in filter(None, body.split(",")):
            key, sep, value = item.partition("=")
            if not sep or key not in _SYNTHETIC_KEYS:
                raise ValueError(
                    f"bad synthetic option {item!r}; use key=value with keys "
                    f"{sorted(_SYNTHETIC_KEYS)}"
                )
            try:
                spec["optimum_seed" if key == "seed" else key] = _SYNTHETIC_KEYS[key](value)
            except ValueError:
                kind = "an integer" if _SYNTHETIC_KEYS[key] is int else "a number"
                raise ValueError(f"synthetic option {key} needs {kind}, got {value!r}") from None
        return spec
    return {"kind": "env", "env_id": env_id}


def make_objective(spec: dict[str, Any], sim_dim: int, control_dim: int, *, new: bool = False,
                   **kwargs):  # fmt: skip
    """Build the objective a spec describes (``kwargs`` fill the spec's missing fields).

    A stored spec (a run's config.json) is checked against the simulator and planner as they
    are now (:class:`SimulationSpaceMismatch`, :class:`PlannerMismatch`); ``new=True``, for a
    spec a new run is about to record, skips the planner check: it records the planner.
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    spec.pop("sim_dim", None)
    spec.pop("control_dim", None)
    if kind == "synthetic":
        return SyntheticObjective(sim_dim, control_dim, **{**kwargs, **spec})
    if kind == "env":
        recorded = spec.pop("simulation_space", None)
        planner = spec.pop("planner", None)
        objective = EnvObjective(sim_dim=sim_dim, control_dim=control_dim, **{**kwargs, **spec})
        objective.expect_simulation_space(recorded)
        if not new:
            objective.expect_planner(planner)
        return objective
    raise ValueError(f"unknown objective kind {kind!r}; valid: ['synthetic', 'env']")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def objective_differences(recorded: dict[str, Any], objective: Any) -> list[str] | None:
    """Where ``objective`` differs from the objective spec a run recorded, one phrase each
    (``"noise 0.05 (recorded 0.01)"``); empty when it is the same objective.

    Parameters
    ----------
    recorded : dict
        The run's spec (config.json's ``"objective"``).
    objective : object
        The objective about to be evaluated.

    Returns
    -------
    list of str or None
        None for an objective without a ``spec()`` (a function, a wrapper that injects
        faults or logs): it cannot be compared. Else every recorded setting the
        objective's ``spec()`` does not match, but those of its ``COST_ONLY`` (settings that
        change what an evaluation costs, not its R, such as the synthetic objective's
        ``delay``). A setting its spec has and the record lacks is not one either: the run
        predates it, and rebuilding the recorded spec gives it its default. The simulation
        space is compared as :meth:`EnvObjective.expect_simulation_space` compares it (to
        1e-6: another machine's floating point), everything else exactly, as JSON holds it.
    """
    given = json_spec(objective)
    if given is None:
        return None
    # (a spec kept in memory, as RBBO.create was given it, may hold tuples)
    recorded = json.loads(json.dumps(recorded, default=_plain_json))
    cost_only = getattr(objective, "COST_ONLY", ())
    out = []
    for key, value in recorded.items():
        if key in cost_only:
            continue
        if key == "simulation_space" and callable(getattr(objective, "expect_simulation_space",
                                                          None)):  # fmt: skip
            try:
                objective.expect_simulation_space(value)
            except ValueError:
                out.append("simulation_space (another B_r)")
            continue
        if key not in given:
            out.append(f"{key} absent (recorded {_short(value)})")
        elif given[key] != value:
            out.append(f"{key} {_short(given[key])} (recorded {_short(value)})")
    return out


def json_spec(objective: Any) -> dict[str, Any] | None:
    """``objective.spec()`` as config.json holds it (tuples as lists, numpy's numbers as
    Python's), None for an objective without one."""
    spec = getattr(objective, "spec", None)
    if not callable(spec):
        return None
    return json.loads(json.dumps(spec(), default=_plain_json))


def _plain_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")
