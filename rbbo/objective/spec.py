"""Objective specs: what ``rbbo optimize ENV_ID`` turns into an objective, and back.

:func:`parse_objective_spec` turns an ENV_ID argument into a spec dict (what a run's
config.json stores); :func:`make_objective` builds the objective a spec describes, checking
a stored one against the simulator and planner as they are now.
"""

from __future__ import annotations

from typing import Any

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
