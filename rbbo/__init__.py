"""rbbo: Riemannian Bayesian bilevel optimisation of the control space B_c (paper Alg. RBBO).

The public names are imported on first use, so that worker processes which only need
:mod:`rbbo.executors` and :mod:`rbbo.objective` start quickly.
"""

from __future__ import annotations

import importlib

__all__ = [
    "RBBO",
    "BOCAFidelity",
    "EnvObjective",
    "FidelityKernel",
    "GrassmannGP",
    "GrassmannKernel",
    "RBBOConfig",
    "RBBOResult",
    "RunStore",
    "SyntheticObjective",
]

_HOMES = {
    "RBBO": "optimizer",
    "RBBOConfig": "config",
    "RBBOResult": "config",
    "BOCAFidelity": "boca",
    "EnvObjective": "objective",
    "SyntheticObjective": "objective",
    "FidelityKernel": "kernels",
    "GrassmannKernel": "kernels",
    "GrassmannGP": "gp",
    "RunStore": "store",
}


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
